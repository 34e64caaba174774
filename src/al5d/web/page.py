"""The page: what it knows of the arm, and what it does with the user's input.

Every browser that opens the page shares it (one arm, one panel). Three kinds of
threads touch it: the ROS executor (joint states, state, outcomes, instructions
seen), viser (the user's clicks and drags: STOP on viser's event loop, the rest
in its thread pool) and the page's own loop (the watchdog, the jog's set-points, the
plot). One lock keeps what they share consistent; the 3D view
(scene.py), the widgets (panel.py), the jog (jog.py) and the view's hold (viewhold.py)
are only called under it.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import viser

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Instruction, Outcome, Result, preset
from al5d.model import JOINTS, ModelError
from al5d.model.transforms import Transform
from al5d.web.jog import Jog
from al5d.web.panel import (
    NO_CONTACT,
    PULSE_S,
    RELEASABLE,
    STATE_WORDS,
    Panel,
    TimeNotTaken,
    held,
)
from al5d.web.plan import JointHistory, OutcomeLog, Planner, Target
from al5d.web.scene import ArmScene
from al5d.web.sliders import SliderInput
from al5d.web.target import TargetTab
from al5d.web.viewhold import ViewHold, arrived

log = logging.getLogger("al5d.web")

#: No joint states for this long: the server is lost (banner, controls off but STOP).
LOST_AFTER_S = 1.0
#: The page's loop: the watchdog, the jog's set-points (20 a second at most: the server
#: writes the newest as soon as the wire allows) and the sliders following the arm.
LOOP_S = 0.05
#: The plot is redrawn this often (each redraw sends the whole window of samples).
PLOT_EVERY_S = 0.25
#: The arm as it physically stands is hidden once nothing has said it for this long.
PHYSICAL_FRESH_S = 1.0


class Commands(Protocol):
    """What the page asks of the server (the ROS link)."""

    #: The ids of the jog's set-points start with it (their refusals come back by it).
    jog_prefix: str

    def send(self, instr: Instruction) -> None: ...

    def jog(self, degrees: Mapping[str, float]) -> bool:
        """Sends a set-point; False when no server reads them yet."""
        ...

    def server_lost(self) -> None:
        """The page has lost the server: a set-point is read again only by a server whose
        reader matched after this."""
        ...

    def stop(self) -> str: ...

    def release(self) -> None: ...


class Page:
    """The control panel and the 3D view of one arm, on a viser server."""

    #: The Calibrate tab (`web.calibrate`) once attached: its ghost and its moves' outcomes.
    calibration: Any = None

    def __init__(
        self, server: viser.ViserServer, config: ArmConfig, title: str, joint_prefix: str = ""
    ) -> None:
        self.server = server
        self.config = config
        self.model = config.model
        self.planner = Planner(config)
        self.commands: Commands | None = None
        self._lock = threading.RLock()
        self.degrees: dict[str, float] | None = None
        self.last_joints_t: float | None = None
        self.state = "unknown"
        self.lost = True
        #: Targets of the instructions that will move the arm, oldest first, by id.
        self.pending: dict[str, tuple[str, Target]] = {}
        self.page_move_to: str | None = None
        self.history = JointHistory(tuple(JOINTS))
        self.outcomes = OutcomeLog()
        #: The jog: the sliders' targets, sent as set-points of the server's stream
        #: (`joint_commands`).
        self.jog = Jog({name: joint.speed_deg_s for name, joint in config.joints.items()})
        #: The sliders' values as the user moves them, into the jog.
        self.sliders = SliderInput(self)
        #: The Target tab's input and its gizmo.
        self.target_tab = TargetTab(self)
        self.arrivals: list[float] = []
        self.last_change_t = -math.inf
        #: When the 3D view may change, and what it has to show then.
        self.hold = ViewHold(server)
        self.arm_due = self.ghost_due = False
        #: Where the arm physically stands (an emulated arm's truth), when that is said, and
        #: since when; whether the 3D view has yet to show it.
        self.physical: dict[str, float] | None = None
        self.physical_t = -math.inf
        self.physical_due = False
        self.scene = ArmScene(server, self.model, config.presets.values(), joint_prefix)
        self.panel = Panel(server, config, title)
        self.panel.show_outcomes(self.outcomes)
        self._wire()
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="al5d-web-page", daemon=True)
        self._thread.start()

    def _wire(self) -> None:
        panel = self.panel
        panel.stop.on_click(self._on_stop)
        panel.release.on_click(self._on_release)
        for name, slider in panel.sliders.items():
            slider.on_update(self.sliders.handler(name))
        panel.on_preset(self._on_preset)
        target = self.target_tab
        for number in (*panel.xyz_numbers.values(), *panel.tool_texts.values()):
            number.on_update(target.on_typed)
        panel.target_time_number.on_update(target.on_typed)
        panel.move_to.on_click(lambda _: target.send())
        self.scene.on_target_drag(target.on_drag)

    # -- from the server (ROS executor thread) ---------------------------------------

    def on_description(self, urdf: str) -> None:
        with self._lock:
            if not self.scene.load(urdf):
                return
            # The server's speeds, not this process's configuration's: the jog keeps the
            # arm going for as long as the server takes to get it there.
            speeds = self.model.speeds_from_urdf(self.scene.velocities)
            self.jog.new_speeds(speeds, time.monotonic(), self.degrees)
            if self.degrees is not None:
                self.scene.show_arm(self.degrees)
            self._show_ghost()
        log.info("web: robot description received (%d characters)", len(urdf))

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None:
        try:
            degrees = self.model.from_urdf(dict(zip(names, positions, strict=True)))
        except (ModelError, ValueError):
            return  # not our arm's joints: nothing true to show
        with self._lock:
            first = self.degrees is None
            before = self.degrees or {}
            changed = any(j not in before or abs(v - before[j]) > 1e-6 for j, v in degrees.items())
            self.degrees = {**before, **degrees}
            self.last_joints_t = t
            self.history.add(t, self.degrees)
            self.arrivals = [a for a in self.arrivals if a > t - 1.0] + [t]
            if changed:
                # An idle arm's states repeat 25 times a second: nothing to redraw.
                self.last_change_t = t
                if self._arrived():
                    self.hold.arrival()
                self._show_arm()
            if first:
                self._follow(force=True)
            if self.lost:
                self._set_lost(False)

    def on_state(self, state: str) -> None:
        with self._lock:
            before, self.state = self.state, state
            self._show_state(state)
            if state in ("stopped", "fault", "shutting_down"):
                # Nothing queued survives these: a stop cancels all, a fault too.
                self.pending.clear()
                self._show_ghost()
            if state in RELEASABLE and before not in RELEASABLE:
                # The jog is over (the server refuses every move until a release): the
                # sliders go to where the arm stopped, and follow it from there.
                self.jog.let_go()
                self.panel.show_joints_status(
                    f"{STATE_WORDS.get(state, state)}: the sliders show where the arm is; "
                    "release it to move it again",
                    False,
                )
                self._follow(force=True)
            elif before in RELEASABLE and state not in RELEASABLE:
                self.panel.show_joints_status("drag a slider to move", None)

    def on_answer(self, text: str, ok: bool | None) -> None:
        # In the link's thread of its own; one widget, which nothing else writes: no lock.
        self.panel.show_answer(text, ok)

    def on_outcome(self, outcome: Outcome) -> None:
        with self._lock:
            self.hold.hold()
            self.outcomes.add(outcome)
            self.panel.show_outcomes(self.outcomes)
            if self.pending.pop(outcome.id, None) is not None:
                self._show_ghost()
            if self.calibration is not None:
                self.calibration.on_outcome(outcome)
            if (
                outcome.result is Result.REFUSED
                and self.commands is not None
                and outcome.id.startswith(self.commands.jog_prefix)
                and self.jog.target is not None
            ):
                # The server refused the jog: the sliders go back to where the arm is.
                self.jog.let_go()
                self.panel.show_joints_status(
                    f"refused: {outcome.reason} (the sliders show where the arm is)", False
                )
                self._follow(force=True)
            if outcome.id == self.page_move_to:
                ok = outcome.result is Result.DONE
                self.panel.show_status(f"server: {outcome}", ok)
                if ok:
                    self.target_tab.to_tool()

    def on_instruction(self, instr: Instruction) -> None:
        """An instruction seen on a topic (ours or anyone's): its target is the ghost."""
        with self._lock:
            start = self._planning_start()
            if start is None:
                return
            target = self.planner.target_of(instr, start)
            if isinstance(target, Target):
                self.hold.hold()
                self.pending[instr.id] = (f"{instr.name} [{instr.id}]", target)
                self._show_ghost()

    def on_physical(self, degrees: dict[str, float]) -> None:
        """Where the arm physically stands, as an emulated arm says (`physical_joint_states`):
        drawn beside the arm the model believes in, and told to the Calibrate tab."""
        with self._lock:
            before = self.physical or {}
            self.physical_t = time.monotonic()
            if before and all(abs(v - before.get(j, math.inf)) < 0.05 for j, v in degrees.items()):
                return  # at rest it repeats 20 times a second: nothing to redraw
            self.physical = dict(degrees)
            self.physical_due = True
            self._show_scene()
            if self.calibration is not None:
                self.calibration.on_physical(self.physical)

    def on_mount(self, parent: str, mount: Transform) -> None:
        """Where the arm's base_link stands in `parent` (its mount, on /tf_static)."""
        with self._lock:
            self.scene.place_arm(mount)
        log.info("web: the arm is mounted in %s at %s", parent, mount.translation)

    # -- showing (under the lock) ----------------------------------------------------

    def _arrived(self) -> bool:
        """The arm is at the last target on its way (its READY is due), while moving."""
        if self.state != "moving" or not self.pending or self.degrees is None:
            return False
        return arrived(self.degrees, next(reversed(self.pending.values()))[1].degrees)

    def _show_state(self, state: str) -> None:
        """The state, sent at once and alone: the 3D view holds its updates a moment."""
        if self.panel.show_state(state):
            self.hold.state_sent()
            self.server.flush()

    def _show_arm(self) -> None:
        self.arm_due = True
        self._show_scene()

    def _show_scene(self) -> None:
        """The arm's pose and the ghost, as they are due; nothing while the view is held."""
        if self.hold.held():
            self._show_tool()
            return
        with self.server.atomic():
            if self.arm_due and self.degrees is not None:
                self.scene.show_arm(self.degrees)
            if self.ghost_due:
                self.scene.show_ghost(self._ghost())
            if self.physical_due:
                self.scene.show_physical(self.physical)
            self._show_tool()
        self.arm_due = self.ghost_due = self.physical_due = False
        # Sent now, not in viser's next window (1/60 s): a state that comes a moment later
        # would share that window, and wait with the pose for a frame.
        self.server.flush()

    def _show_held(self) -> None:
        """The ghost, and what the 3D view held back while a state went out (the page's
        loop)."""
        if (self.arm_due or self.ghost_due or self.physical_due) and not self.hold.held():
            self._show_scene()

    def _show_tool(self) -> None:
        """The tool's position, the joint states' rate and the ghost's instruction, under
        the state: each arm update changes it (the benchmark counts its changes)."""
        tool = None if self.degrees is None else self.planner.tool_of(self.degrees)
        if tool is None:
            return
        x, y, z = (v * 1000 for v in tool)
        now = time.monotonic()
        rate = sum(1 for a in self.arrivals if a > now - 1.0)
        ghost = next(reversed(self.pending.values()))[0] if self.pending else ""
        self.panel.show_tool((x, y, z), rate, ghost)

    def _planning_start(self) -> dict[str, float] | None:
        """Where the next instruction starts: the last pending target, else where the arm is."""
        if self.pending:
            return dict(next(reversed(self.pending.values()))[1].degrees)
        return None if self.degrees is None else dict(self.degrees)

    def _show_ghost(self) -> None:
        """The ghost with the arm's next pose or at the page's loop's next tick; the readout
        of its instruction now."""
        self.ghost_due = True
        self._show_tool()

    def _ghost(self) -> Target | None:
        ghost = next(reversed(self.pending.values()))[1] if self.pending else None
        if ghost is None and self.calibration is not None:  # where the joint should stand
            pose = self.calibration.ghost()
            ghost = None if pose is None else Target("calibration", pose)
        return ghost

    @property
    def lock(self) -> threading.RLock:
        return self._lock

    def refresh_ghost(self) -> None:
        with self._lock:
            self._show_ghost()

    def _set_lost(self, lost: bool, age_s: float | None = None) -> None:
        """The banner (its text again each second while lost); the controls on a change."""
        changed = lost != self.lost
        self.lost = lost
        ended = lost and self.state in ("shutting_down", "ended")
        if ended:
            # Its last word was that it shuts down, and it has gone quiet: it has ended.
            self.state = "ended"
            self._show_state("ended")
        text = lost_text(ended, age_s) if lost else None
        if changed and not ended:
            self._show_state(NO_CONTACT if lost else self.state)
        if changed and not lost:
            self.jog.contact_back(time.monotonic())
        with self.server.atomic():
            self.panel.show_lost(text)
            if changed:
                self.panel.set_enabled(not lost)
                self.scene.set_target_enabled(not lost)
        if changed and lost and self.commands is not None:
            self.commands.server_lost()
        if changed:
            log.log(
                logging.WARNING if lost else logging.INFO,
                "web: %s",
                "contact with the server lost: controls off" if lost else "the server answers",
            )

    def _follow(self, force: bool = False) -> None:
        """Sliders show the arm when nobody is at them and it is not moving (a slider that
        followed a moving arm would fight the user's hand)."""
        if self.degrees is None:
            return
        idle = self.state != "moving" and not self.pending
        quiet = self.jog.quiet(time.monotonic())
        if not force and not (idle and quiet):
            return
        for name in self.panel.sliders:
            if name in self.degrees:
                self.panel.set_slider(name, self.degrees[name])
        self.target_tab.follow(force)

    # -- the user's input (viser's threads) --------------------------------------------

    async def _on_stop(self, event: Any) -> None:
        # On viser's event loop itself, not its thread pool: the stop goes out as the
        # click's message is read, whatever else the pool is busy with.
        self.jog.end()
        if self.commands is not None:
            try:
                way = self.commands.stop()
            except Exception:
                # Never raised: viser would then skip the click's other callbacks (the
                # Teach tab's, which ends its play) and only say so when the task is freed.
                log.exception("web: STOP clicked, and it could not be sent")
                return
            log.info("web: STOP clicked (sent by %s)", way)

    def send_instruction(self, instr: Instruction) -> bool:
        """Send `instr` to the server; False when there is none to send it to."""
        if self.commands is None or self.lost:
            return False
        with self._lock:
            self.jog.end()  # another instruction ends the jog: its target is not sent again
        self.commands.send(instr)
        return True

    def _on_preset(self, event: Any) -> None:
        with self._lock:
            if self.state in RELEASABLE:
                # As a slider then: the server refuses every move until a release.
                self.panel.show_joints_status(held(self.state), False)
                return
        try:
            time_ms = self.panel.time_ms()
        except TimeNotTaken as e:
            with self._lock:
                self.panel.show_joints_status(f"not sent: {e}", False)
            return
        self.send_instruction(preset(str(event.target.value), time_ms=time_ms))

    def _on_release(self, event: Any) -> None:
        if self.commands is not None and not self.lost:
            self.commands.release()

    def precheck(self, instr: Instruction | str) -> str:
        """The reason the server would refuse `instr` from where the arm is, or ''."""
        if isinstance(instr, str):
            return instr
        with self._lock:
            start = self._planning_start()
        if start is None:
            return "the arm's pose is not known yet"
        target = self.planner.target_of(instr, start)
        return target if isinstance(target, str) else ""

    # -- the page's loop -------------------------------------------------------------

    def _loop(self) -> None:
        last_plot = last_readout = last_beat = 0.0
        beats = itertools.count(1)
        while self._running:
            time.sleep(LOOP_S)
            now = time.monotonic()
            with self._lock:
                if now - last_beat >= PULSE_S:
                    self.panel.beat(next(beats))
                    last_beat = now
                if self.last_joints_t is not None:
                    age = now - self.last_joints_t
                    if age > LOST_AFTER_S and (not self.lost or int(age) != int(age - LOOP_S)):
                        self._set_lost(True, age)
                if self.physical is not None and now - self.physical_t > PHYSICAL_FRESH_S:
                    self.physical, self.physical_due = None, True  # nothing says it any more
                    if self.calibration is not None:
                        self.calibration.on_physical(None)
                self._show_held()
                moving = self.state == "moving"
                jogging = self.jog.target is not None
                jog, said = (None, "") if self.lost else self.jog.due(now, moving, self.degrees)
                if said:
                    self.panel.show_joints_status(said, False)
                elif jogging and self.jog.target is None:  # over: it said "jogging" since
                    self.panel.show_joints_status("drag a slider to move", None)
                if jog is None and not self.hold.held():  # the gizmo is in the 3D view
                    self._follow()
                if self.degrees is not None and now - last_readout >= 1.0:
                    if now - self.last_change_t >= 1.0:  # moving, each state refreshes it
                        self._show_tool()
                    last_readout = now
            if jog is not None and self.commands is not None and not self.commands.jog(jog):
                with self._lock:  # nobody read it: due again at the next tick
                    self.jog.unread()
            # While the arm is still the plot is flat lines already: redraws would only
            # slide the time axis, at a window of samples each.
            recent = now - self.last_change_t < self.history.seconds + PLOT_EVERY_S
            if now - last_plot >= PLOT_EVERY_S and recent and not self.lost:
                last_plot = now
                with self._lock:
                    self.panel.show_plot(self.history.series(now))

    def close(self) -> None:
        self._running = False
        self._thread.join(2)
        self.sliders.close()


def lost_text(ended: bool, age_s: float | None) -> str:
    """The banner's text: the server ended, or not heard from for `age_s` (None: never)."""
    if ended:
        return (
            "The server has ended (it shut down, the arm parked). Start it again "
            "(al5d serve) to go on. Controls are off; STOP is still sent."
        )
    since = "never heard from it" if age_s is None else f"no joint states for {age_s:.0f} s"
    # Across a network the server may be running and the way to it cut: STOP is sent, but
    # nothing here can say that it arrived.
    return (
        f"No contact with the server ({since}). Controls are off; STOP is still sent, "
        "and stops the arm if it reaches the server."
    )
