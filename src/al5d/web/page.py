"""The page, built with viser: the arm in 3D, its controls, and what happened.

Every browser that opens the page shares it (one arm, one panel). Three kinds of
threads touch it: the ROS executor (joint states, state, outcomes, instructions
seen), viser (the user's clicks and drags: STOP on viser's event loop, the rest
in its thread pool) and the page's own loop (the watchdog, the debounced slider
moves, the plot). One lock keeps what they share consistent.
"""

from __future__ import annotations

import html
import io
import logging
import math
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np
import viser
import yourdfpy
from viser import uplot
from viser.extras import ViserUrdf

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Instruction, Kind, Outcome, Result, move_to, preset
from al5d.model import JOINTS, ModelError
from al5d.web.plan import Debouncer, JointHistory, OutcomeLog, Planner, Target

log = logging.getLogger("al5d.web")

#: No joint states for this long: the server is lost (banner, controls off but STOP).
LOST_AFTER_S = 1.0
#: A slider still for this long has been let go: its move is sent (one drag, one move).
QUIET_S = 0.3
#: The page's loop: the watchdog, the debounce and the sliders following the arm.
LOOP_S = 0.05
#: The plot is redrawn this often (each redraw sends the whole window of samples).
PLOT_EVERY_S = 0.25
#: Sliders follow the arm once nobody has touched them for this long and it is not moving.
FOLLOW_AFTER_S = 1.5
#: The gizmo stays where the user left it this long (a refused target stays in view).
TARGET_KEPT_S = 5.0

STATE_COLOURS = {
    "ready": "#2b8a3e",
    "moving": "#1971c2",
    "stopped": "#c92a2a",
    "fault": "#e67700",
    "initializing": "#868e96",
    "shutting_down": "#868e96",
}
JOINT_COLOURS = ("#e03131", "#1971c2", "#2f9e44", "#f08c00", "#9c36b5", "#0c8599")
GHOST_RGBA = (0.25, 0.55, 1.0, 0.35)


class Commands(Protocol):
    """What the page asks of the server (the ROS link)."""

    def send(self, instr: Instruction) -> None: ...

    def stop(self) -> str: ...

    def release(self) -> Any: ...


def _state_html(state: str) -> str:
    colour = STATE_COLOURS.get(state, "#495057")
    return (
        f'<div id="al5d-state" style="font-size:2.4em;font-weight:800;text-align:center;'
        f'letter-spacing:0.06em;color:{colour}">{html.escape(state.upper())}</div>'
    )


def _banner_html(text: str) -> str:
    return (
        '<div id="al5d-banner" style="background:#c92a2a;color:#fff;padding:0.6em 0.8em;'
        f'font-weight:700;border-radius:4px;margin:0 0.6em">{html.escape(text)}</div>'
    )


def _status_html(text: str, ok: bool | None) -> str:
    colour = {True: "#2b8a3e", False: "#c92a2a", None: "#495057"}[ok]
    return (
        f'<div id="al5d-target-status" style="color:{colour};font-size:0.85em;'
        f'overflow-wrap:anywhere;padding:0 0.6em">{html.escape(text)}</div>'
    )


class Page:
    """The control panel and the 3D view of one arm, on a viser server."""

    def __init__(self, server: viser.ViserServer, config: ArmConfig, title: str) -> None:
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
        self.pending: dict[str, Target] = {}
        self.page_move_to: str | None = None
        self.history = JointHistory(tuple(JOINTS))
        self.outcomes = OutcomeLog()
        self.debouncer = Debouncer(QUIET_S)
        self.touched = -math.inf
        self.target_touched = -math.inf
        self.arrivals: list[float] = []
        self.last_change_t = -math.inf
        self.urdf_text: str | None = None
        self.robot: ViserUrdf | None = None
        self.ghost: ViserUrdf | None = None
        self._build_scene()
        self._build_gui(title)
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="al5d-web-page", daemon=True)
        self._thread.start()

    # -- building ----------------------------------------------------------------------

    def _build_scene(self) -> None:
        scene = self.server.scene
        self.server.initial_camera.position = (0.42, -0.36, 0.34)
        self.server.initial_camera.look_at = (0.04, 0.0, 0.15)
        scene.add_grid("/grid", width=0.8, height=0.8, cell_size=0.05, section_size=0.2)
        self.robot_root = scene.add_frame("/arm", show_axes=False)
        self.ghost_root = scene.add_frame("/ghost", show_axes=False, visible=False)
        self.path = scene.add_line_segments(
            "/path", np.zeros((1, 2, 3)), (230, 120, 0), thickness=0.004, visible=False
        )
        self.target = scene.add_transform_controls(
            "/target", scale=0.09, disable_rotations=True, depth_test=False, visible=False
        )
        self.target.on_update(self._on_target_drag)

    def _build_gui(self, title: str) -> None:
        gui = self.server.gui
        gui.configure_theme(show_share_button=False, show_logo=False, control_width="large")
        gui.set_panel_label(title)
        gui.main_panel.dock_right()
        # STOP first, outside the tabs: always in view, whatever tab is open.
        self.stop_button = gui.add_button(
            "STOP", color="red", icon=viser.Icon.HAND_STOP, hint="emergency stop (any state)"
        )
        self.stop_button.on_click(self._on_stop)
        # viser has no button size: a style rule makes STOP big (its element id is the
        # handle's uuid; without it the button is just of normal size).
        uuid = getattr(getattr(self.stop_button, "_impl", None), "uuid", None)
        if isinstance(uuid, str) and uuid.replace("-", "").isalnum():
            gui.add_html(
                f'<style>[id="{uuid}"]{{height:3.6rem!important;font-size:1.6rem!important;'
                "font-weight:800!important;letter-spacing:0.12em}</style>"
            )
        self.state_html = gui.add_html(_state_html(self.state))
        self.banner = gui.add_html(_banner_html("waiting for the server..."))
        self.tool_html = gui.add_html("")
        self.last_html = gui.add_html("")
        tabs = gui.add_tab_group()
        self.controls: list[Any] = []
        with tabs.add_tab("Joints", viser.Icon.ADJUSTMENTS):
            self.sliders: dict[str, Any] = {}
            for name, joint in self.config.joints.items():
                lo, hi = joint.range_deg
                start = min(max(0.0, lo), hi)
                slider = gui.add_slider(
                    name, min=float(lo), max=float(hi), step=0.5, initial_value=float(start)
                )
                slider.on_update(self._slider_handler(name))
                self.sliders[name] = slider
            self.time_ms = gui.add_number(
                "time (ms)",
                initial_value=0,
                min=0,
                max=self.config.server.max_move_time_ms,
                step=100,
                hint="0: as fast as the servos allow",
            )
            self.presets = gui.add_button_group("presets", tuple(self.config.presets))
            self.presets.on_click(self._on_preset)
            self.release_button = gui.add_button("release", icon=viser.Icon.LOCK_OPEN)
            self.release_button.on_click(self._on_release)
            self.controls += [*self.sliders.values(), self.time_ms]
            self.controls.append(self.release_button)
        with tabs.add_tab("Target", viser.Icon.TARGET):
            self.xyz: dict[str, Any] = {
                axis: gui.add_number(f"{axis} (mm)", initial_value=0.0, step=1.0)
                for axis in ("x", "y", "z")
            }
            for number in self.xyz.values():
                number.on_update(self._on_xyz_typed)
            self.line = gui.add_checkbox("straight line", initial_value=False)
            self.move_to_button = gui.add_button("move to", icon=viser.Icon.ARROW_RIGHT)
            self.move_to_button.on_click(lambda _: self._send_target())
            self.target_status = gui.add_html(
                _status_html("drag the gizmo at the tool, or type a point", None)
            )
            self.controls += [*self.xyz.values(), self.line, self.move_to_button]
        with tabs.add_tab("History", viser.Icon.HISTORY):
            self.plot = gui.add_uplot(
                self.history.series(time.monotonic()),
                (
                    uplot.Series(label="s"),
                    *(
                        uplot.Series(label=j, stroke=c, width=1.5)
                        for j, c in zip(JOINTS, JOINT_COLOURS, strict=True)
                    ),
                ),
                title="joint angles (deg), last 10 s",
                scales={"x": {"time": False}},
                aspect=1.4,
            )
            self.outcomes_html = gui.add_html(self.outcomes.html())
        self._set_controls(enabled=False)

    # -- from the server (ROS executor thread) ---------------------------------------

    def on_description(self, urdf: str) -> None:
        with self._lock:
            if urdf == self.urdf_text:
                return
            self.urdf_text = urdf
            if self.robot is not None and self.ghost is not None:
                self.robot.remove()
                self.ghost.remove()
            self.robot = ViserUrdf(self.server, _load_urdf(urdf), root_node_name="/arm")
            self.ghost = ViserUrdf(
                self.server,
                _load_urdf(urdf),
                root_node_name="/ghost",
                mesh_color_override=GHOST_RGBA,
            )
            if self.degrees is not None:
                self._show_arm(self.degrees)
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
                # An idle arm's states repeat 20 times a second: nothing to redraw.
                self.last_change_t = t
                self._show_arm(self.degrees)
            if first:
                self._follow(force=True)
                self._target_to_tool()
            if self.lost:
                self._set_lost(False)

    def on_state(self, state: str) -> None:
        with self._lock:
            self.state = state
            self.state_html.content = _state_html(state)
            if state in ("stopped", "fault", "shutting_down"):
                # Nothing queued survives these: a stop cancels all, a fault too.
                self.pending.clear()
                self._show_ghost()

    def on_outcome(self, outcome: Outcome) -> None:
        with self._lock:
            self.outcomes.add(outcome)
            self.outcomes_html.content = self.outcomes.html()
            self.last_html.content = self.outcomes.html().split("</div>", 1)[0] + "</div>"
            if self.pending.pop(outcome.id, None) is not None:
                self._show_ghost()
            if outcome.id == self.page_move_to:
                ok = outcome.result is Result.DONE
                self.target_status.content = _status_html(f"server: {outcome}", ok)
                if ok:
                    self._target_to_tool()

    def on_instruction(self, instr: Instruction) -> None:
        """An instruction seen on the topic (ours or anyone's): its target is the ghost."""
        with self._lock:
            start = self._planning_start()
            if start is None:
                return
            target = self.planner.target_of(instr, start)
            if isinstance(target, Target):
                self.pending[instr.id] = target
                self._show_ghost()

    # -- showing -------------------------------------------------------------------

    def _urdf_cfg(self, urdf: ViserUrdf, degrees: Mapping[str, float]) -> np.ndarray:
        values = self.model.to_urdf(degrees)
        return np.array([values.get(n, 0.0) for n in urdf.get_actuated_joint_names()])

    def _show_arm(self, degrees: Mapping[str, float]) -> None:
        with self.server.atomic():
            if self.robot is not None:
                self.robot.update_cfg(self._urdf_cfg(self.robot, degrees))
            self._show_tool(degrees)

    def _show_tool(self, degrees: Mapping[str, float]) -> None:
        """The tool's position and the joint states' rate, under the state: each arm update
        changes it (the benchmark counts its changes in the browser)."""
        tool = self.planner.tool_of(degrees)
        if tool is None:
            return
        x, y, z = (v * 1000 for v in tool)
        now = time.monotonic()
        rate = sum(1 for a in self.arrivals if a > now - 1.0)
        self.tool_html.content = (
            '<div id="al5d-tool" style="font-family:monospace;font-size:0.85em;'
            f'padding:0 0.6em">tool (mm) x {x:.1f} y {y:.1f} z {z:.1f}<br>'
            f"joint states {rate}/s</div>"
        )

    def _planning_start(self) -> dict[str, float] | None:
        """Where the next instruction starts: the last pending target, else where the arm is."""
        if self.pending:
            return dict(next(reversed(self.pending.values())).degrees)
        return None if self.degrees is None else dict(self.degrees)

    def _show_ghost(self) -> None:
        if not self.pending or self.ghost is None:
            self.ghost_root.visible = False
            self.path.visible = False
            return
        target = next(reversed(self.pending.values()))
        with self.server.atomic():
            self.ghost.update_cfg(self._urdf_cfg(self.ghost, target.degrees))
            self.ghost_root.visible = True
            if len(target.line) >= 2:
                pts = np.array(target.line)
                self.path.points = np.stack([pts[:-1], pts[1:]], axis=1)
                self.path.visible = True
            else:
                self.path.visible = False

    def _set_lost(self, lost: bool, age_s: float | None = None) -> None:
        self.lost = lost
        if lost:
            since = "never heard from it" if age_s is None else f"no joint states for {age_s:.0f} s"
            self.banner.content = _banner_html(
                f"No contact with the server ({since}). Controls are off; STOP still works."
            )
        self.banner.visible = lost
        self._set_controls(enabled=not lost)
        if lost:
            self.debouncer.drop()

    def _set_controls(self, enabled: bool) -> None:
        for control in self.controls:
            control.disabled = not enabled
        self.presets.visible = enabled  # viser cannot disable a button group: hidden instead
        self.target.visible = enabled and self.degrees is not None

    def _follow(self, force: bool = False) -> None:
        """Sliders show the arm when nobody is at them and it is not moving (a slider that
        followed a moving arm would fight the user's hand)."""
        if self.degrees is None:
            return
        idle = self.state != "moving" and not self.pending
        quiet = not self.debouncer.busy and time.monotonic() - self.touched > FOLLOW_AFTER_S
        if not force and not (idle and quiet):
            return
        for name, slider in self.sliders.items():
            deg = self.degrees.get(name)
            if deg is not None and abs(slider.value - deg) > 0.25:
                lo, hi = self.config.joints[name].range_deg
                # Programmatic: our own handler sees no client and sends nothing.
                slider.value = min(max(round(deg * 2) / 2, lo), hi)
        # The gizmo goes back to the tool too, once a refused target has been seen a while.
        if force or time.monotonic() - self.target_touched > TARGET_KEPT_S:
            tool = self.planner.tool_of(self.degrees)
            if tool is not None and np.linalg.norm(np.subtract(self.target.position, tool)) > 1e-3:
                self._target_to_tool()

    def _target_to_tool(self) -> None:
        if self.degrees is None:
            return
        tool = self.planner.tool_of(self.degrees)
        if tool is None:
            return
        self.target.position = tool
        self.target.visible = not self.lost
        for axis, v in zip("xyz", tool, strict=True):
            self.xyz[axis].value = round(v * 1000, 1)

    # -- the user's input (viser's threads) --------------------------------------------

    async def _on_stop(self, event: Any) -> None:
        # On viser's event loop itself, not its thread pool: the stop goes out as the
        # click's message is read, whatever else the pool is busy with.
        self.debouncer.drop()
        if self.commands is not None:
            way = self.commands.stop()
            log.info("web: STOP clicked (sent by %s)", way)

    def _slider_handler(self, joint: str) -> Any:
        def handler(event: Any) -> None:
            if event.client is None:
                return  # set by the page itself (following the arm), not by a user
            with self._lock:
                if self.lost:
                    return
                self.touched = time.monotonic()
                self.debouncer.put(joint, float(event.target.value))

        return handler

    def _time_ms(self) -> int | None:
        return int(self.time_ms.value) or None

    def _send(self, instr: Instruction) -> None:
        if self.commands is None or self.lost:
            return
        self.commands.send(instr)

    def _on_preset(self, event: Any) -> None:
        self._send(preset(str(event.target.value), time_ms=self._time_ms()))

    def _on_release(self, event: Any) -> None:
        if self.commands is not None and not self.lost:
            self.commands.release()

    def _target_instr(self, xyz_mm: Sequence[float]) -> Instruction:
        x, y, z = xyz_mm
        return move_to(x, y, z, line=bool(self.line.value), time_ms=self._time_ms())

    def _precheck(self, instr: Instruction) -> str:
        """The reason the server would refuse `instr` from where the arm is, or ''."""
        with self._lock:
            start = self._planning_start()
        if start is None:
            return "the arm's pose is not known yet"
        target = self.planner.target_of(instr, start)
        return target if isinstance(target, str) else ""

    def _on_target_drag(self, event: Any) -> None:
        if event.client is None or self.lost:
            return
        self.target_touched = time.monotonic()
        xyz = [round(v * 1000, 1) for v in event.target.position]
        for axis, v in zip("xyz", xyz, strict=True):
            self.xyz[axis].value = v
        if event.phase == "end":
            self._send_target()
        else:
            reason = self._precheck(self._target_instr(xyz))
            self.target_status.content = _status_html(
                f"unreachable: {reason}" if reason else "reachable: release to move", not reason
            )

    def _on_xyz_typed(self, event: Any) -> None:
        if event.client is None:
            return
        self.target_touched = time.monotonic()
        xyz = [float(self.xyz[a].value) for a in "xyz"]
        self.target.position = tuple(v / 1000 for v in xyz)
        reason = self._precheck(self._target_instr(xyz))
        point = "x {:g} y {:g} z {:g} mm".format(*xyz)
        self.target_status.content = _status_html(
            f"{point}: unreachable: {reason}" if reason else f"{point}: reachable", not reason
        )

    def _send_target(self) -> None:
        """`move_to` the target; the local check shows the reason at once, and the move goes
        to the server all the same: its outcome is the word that counts."""
        instr = self._target_instr([self.xyz[a].value for a in "xyz"])
        reason = self._precheck(instr)
        self.target_touched = time.monotonic()
        with self._lock:
            self.page_move_to = instr.id
            text = f"will be refused: {reason}" if reason else f"sent: {instr}"
            self.target_status.content = _status_html(text, False if reason else None)
        self._send(instr)

    # -- the page's loop -------------------------------------------------------------

    def _loop(self) -> None:
        last_plot = last_readout = 0.0
        while self._running:
            time.sleep(LOOP_S)
            now = time.monotonic()
            with self._lock:
                if self.last_joints_t is not None:
                    age = now - self.last_joints_t
                    if age > LOST_AFTER_S and (not self.lost or int(age) != int(age - LOOP_S)):
                        self._set_lost(True, age)
                batch = self.debouncer.poll() if not self.lost else {}
                if not batch:
                    self._follow()
                if self.degrees is not None and now - last_readout >= 1.0:
                    if now - self.last_change_t >= 1.0:  # moving, each state refreshes it
                        self._show_tool(self.degrees)
                    last_readout = now
            if batch:
                self._send(
                    Instruction(Kind.MOVE, joints=tuple(batch.items()), time_ms=self._time_ms())
                )
            # While the arm is still the plot is flat lines already: redraws would only
            # slide the time axis, at a window of samples each.
            recent = now - self.last_change_t < self.history.seconds + PLOT_EVERY_S
            if now - last_plot >= PLOT_EVERY_S and recent and not self.lost:
                last_plot = now
                with self._lock:
                    self.plot.data = self.history.series(now)

    def close(self) -> None:
        self._running = False
        self._thread.join(2)


def _load_urdf(text: str) -> yourdfpy.URDF:
    """A URDF from its text; its primitives (boxes, cylinders) become meshes."""
    return yourdfpy.URDF.load(
        io.StringIO(text),
        build_scene_graph=True,
        load_meshes=True,
        build_collision_scene_graph=False,
        load_collision_meshes=False,
    )
