"""The page's Calibrate tab: the guided calibration of `al5d.arm.calibration` in the browser.

Pick a joint and start: the arm goes to the joint's first reference pose and the ghost
shows where the joint should stand. Nudge (-10, -1, +1, +10 steps of 5 us, toward
-angle or +angle as the configuration has it) until the real joint stands where the
ghost is, then "it is there"; then the second reference. The joint's result (its
offsets, REVERSED, or why it is refused) stays listed; "write" puts every joint found
into the configuration file `al5d web --config` names, once the server says it runs
with that file (a backup beside it, the diff shown). Every nudge is a move sent to the
server, judged whole there, and waited for.

It works under the page's lock (the page calls it from the ROS thread with its lock
held; its handlers take the same lock), and hooks into the page only by
`Page.calibration` (the ghost when no move is pending, and the outcomes).
"""

from __future__ import annotations

import html
import logging
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import viser

from al5d.arm.calfile import shipped_problem, write_calibration
from al5d.arm.calibration import (
    DEFAULT_STEP_US,
    Awaiting,
    CalibrationRefused,
    JointCalibration,
    Procedure,
)
from al5d.arm.instruction import Instruction, Kind, Outcome, Result
from al5d.model import ArmModel, ModelError, joint_positions
from al5d.model.transforms import Vec3

if TYPE_CHECKING:
    from al5d.web.page import Page

log = logging.getLogger("al5d.web")

#: The move to a reference pose takes at least this long: a walk, not the servos' top speed.
REFERENCE_MOVE_MS = 1500
NUDGES = ("-10", "-1", "+1", "+10")
#: The elements the tests read, by id.
STATUS = "al5d-cal-status"
RESULTS = "al5d-cal-results"


def _html(ident: str, body: str, colour: str = "#495057") -> str:
    return (
        f'<div id="{ident}" style="color:{colour};font-size:0.85em;overflow-wrap:anywhere;'
        f'padding:0 0.6em">{body}</div>'
    )


def idle_text(path: Path) -> str:
    """What the tab says before a calibration: the file it writes, or, where that is the
    shipped configuration, that it cannot be written there (before a joint is calibrated
    for nothing: `write` would refuse it)."""
    said = f"pick a joint and start; the file: {path}"
    problem = shipped_problem(path)
    return f"{said}. What is found cannot be written there: {problem}" if problem else said


class CalibrationTab:
    """The tab's widgets and the procedure of the joint being calibrated."""

    def __init__(
        self, page: Page, path: Path, tabs: Any, served: Callable[[], Path | None]
    ) -> None:
        self.page = page
        self.path = path
        #: Asks the server which file it was started with (None: it did not say).
        self.served = served
        self.lock = page.lock
        self.procedure: Procedure | None = None
        #: The id of the move sent and not yet answered: no nudge until its outcome.
        self.waiting: str | None = None
        self.results: dict[str, JointCalibration] = {}
        self.notes: list[str] = []
        #: Where the arm physically stands, where an emulated arm says it (None: not said),
        #: and the status's last note (shown again when that changes).
        self.physical: dict[str, float] | None = None
        self._said: tuple[str, bool | None] = ("", None)
        gui = page.server.gui
        with tabs.add_tab("Calibrate", viser.Icon.RULER_MEASURE):
            self.joint = gui.add_dropdown("joint", tuple(page.config.joints))
            self.start = gui.add_button("start", icon=viser.Icon.PLAYER_PLAY)
            self.status = gui.add_html(_html(STATUS, html.escape(self._idle_text())))
            self.nudge = gui.add_button_group("nudge", NUDGES)
            self.accept = gui.add_button("it is there", icon=viser.Icon.CHECK)
            self.cancel = gui.add_button("cancel", icon=viser.Icon.X)
            self.results_html = gui.add_html(_html(RESULTS, ""))
            self.write = gui.add_button("write", icon=viser.Icon.DEVICE_FLOPPY, disabled=True)
        self.start.on_click(lambda event: self._on_start(event.client))
        self.nudge.on_click(lambda event: self._on_nudge(int(str(event.target.value))))
        self.accept.on_click(lambda _: self._on_accept())
        self.cancel.on_click(lambda _: self._on_cancel())
        self.write.on_click(lambda _: self._on_write())
        #: What a lost server turns off with the page's other controls.
        self.controls = [self.joint, self.start, self.accept, self.cancel]

    def _idle_text(self) -> str:
        return idle_text(self.path)

    # -- the page's hooks (under its lock) -------------------------------------------

    def ghost(self) -> dict[str, float] | None:
        """Where the model shows the arm: the joint at its reference (None: no procedure)."""
        if self.procedure is None or self.procedure.step is Awaiting.DONE:
            return None
        return self.procedure.reference_pose()

    def on_physical(self, degrees: dict[str, float] | None) -> None:
        """Where the emulated arm truly stands (None: nothing says any more): the status
        says how far the joint is off the ghost, and a needle shows it beside the ghost's,
        so that the nudges visibly close it."""
        before = self._physical_line()
        self.physical = degrees
        if self._physical_line() != before:
            self._show(*self._said)
        else:
            self._show_needles()

    def _show_needles(self) -> None:
        procedure = self.procedure
        shown: dict[str, tuple[Vec3, Vec3]] = {}
        if procedure is not None and procedure.step is Awaiting.NUDGE:
            ghost = procedure.reference_pose()
            name = procedure.joint.name
            for which, pose in (("ghost", ghost), ("physical", self.physical)):
                needle = None if pose is None else joint_needle(self.page.model, pose, name)
                if needle is not None:
                    shown[which] = needle
        self.page.scene.show_needles(shown)

    def _physical_line(self) -> str:
        procedure = self.procedure
        if self.physical is None or procedure is None or procedure.step is not Awaiting.NUDGE:
            return ""
        joint, ref = procedure.joint.name, procedure.reference
        true = self.physical.get(joint)
        if true is None:
            return ""
        return (
            f"The emulated arm (orange) truly stands at {true:.1f} deg: "
            f"{true - ref.deg:+.1f} deg off the ghost."
        )

    def on_outcome(self, outcome: Outcome) -> None:
        if self.procedure is None or outcome.id != self.waiting:
            return
        self.waiting = None
        if outcome.result is Result.DONE:
            self.procedure.moved()
            self._show()
        else:
            self.procedure.not_moved()
            self._show(f"not moved: {outcome}", ok=False)

    # -- the user's input (viser's threads) ------------------------------------------

    def _on_start(self, client: Any) -> None:
        with self.lock:
            name = str(self.joint.value)
            self.procedure = Procedure(self.page.config, (name,), DEFAULT_STEP_US)
            self.results.pop(name, None)
            self._go(REFERENCE_MOVE_MS)
            if client is not None:
                # The view turns to the joint, from where its turn shows best.
                look_at, position = joint_view(
                    self.page.model, self.procedure.reference_pose(), name
                )
                self.page.scene.aim(client, look_at, position)

    def _on_nudge(self, steps: int) -> None:
        with self.lock:
            if self.procedure is None or self.procedure.step is Awaiting.DONE:
                return
            if self.waiting is not None:
                self._show("wait: the last move has no outcome yet", ok=False)
                return
            try:
                self.procedure.nudge(steps)
            except CalibrationRefused as e:
                self._show(f"not moved: {e}", ok=False)
                return
            self._go(None)

    def _on_accept(self) -> None:
        with self.lock:
            procedure = self.procedure
            if procedure is None or procedure.step is Awaiting.DONE or self.waiting is not None:
                return
            name = procedure.joint.name
            try:
                result = procedure.accept()
            except CalibrationRefused as e:
                self.notes.append(f"refused: {e}")
                self.procedure = None
                self._show_results()
                self._show(f"{name}: refused (below)", ok=False)
                self.page.refresh_ghost()
                return
            if result is None:  # on to the second reference
                self._go(REFERENCE_MOVE_MS)
                return
            self.results[name] = result
            self.procedure = None
            self._show_results()
            self._show(f"{name}: found (below); write it, or calibrate another joint", ok=True)
            self.page.refresh_ghost()

    def _on_cancel(self) -> None:
        with self.lock:
            self.procedure = None
            self.waiting = None
            self._show(self._idle_text())
            self.page.refresh_ghost()

    def _on_write(self) -> None:
        served = self.served()  # a service call: not under the page's lock
        with self.lock:
            results = list(self.results.values())
            if not results:
                return
            if served is None:
                self._show(
                    "not written: the server did not say which file it runs with (no answer "
                    "in time); write again",
                    ok=False,
                )
                return
            if served.resolve() != self.path.resolve():
                self._show(
                    f"not written: the server runs with {served}, this page with {self.path}: "
                    f"start al5d web --config {served}",
                    ok=False,
                )
                return
            try:
                written = write_calibration(self.path, results)
            except (CalibrationRefused, OSError) as e:
                self._show(f"not written: {e}", ok=False)
                return
            self.results.clear()
            self.notes = [
                f"written: {written.path} (the file as it was: {written.backup}); restart "
                "al5d serve to drive the arm with it"
            ]
            self._show_results(written.diff)
            self._show("written", ok=True)
            log.info("web: calibration written into %s (backup %s)", written.path, written.backup)

    # -- under the lock ----------------------------------------------------------------

    def _go(self, time_ms: int | None) -> None:
        """Send the move to the procedure's pulse; its outcome comes to `on_outcome`."""
        assert self.procedure is not None
        move = Instruction(Kind.MOVE, joints=tuple(self.procedure.pose().items()), time_ms=time_ms)
        self.waiting = move.id
        self._show("moving...")
        self.page.refresh_ghost()
        if not self.page.send_instruction(move):
            self.waiting = None
            self.procedure.not_moved()
            self._show("not sent: no contact with the server", ok=False)

    def _show(self, note: str = "", ok: bool | None = None) -> None:
        self._said = (note, ok)
        procedure = self.procedure
        lines = []
        if procedure is not None and procedure.step is Awaiting.NUDGE:
            joint, ref = procedure.joint, procedure.reference
            offset = procedure.pulse - joint.to_us(ref.deg)
            lines.append(
                f"{joint.name}, reference {procedure.reference_index + 1} of 2: {ref.deg:g} deg: "
                f"{ref.looks} (the ghost). At {procedure.pulse} us ({offset:+.0f} us from the "
                f"config's {ref.deg:g} deg): nudge until the arm matches the ghost."
            )
            physical = self._physical_line()
            if physical:
                lines.append(physical)
        if note:
            lines.append(note)
        colour = {True: "#2b8a3e", False: "#c92a2a", None: "#495057"}[ok]
        body = "<br>".join(html.escape(line) for line in lines)
        self.status.content = _html(STATUS, body, colour)
        self._show_needles()

    def _show_results(self, diff: str = "") -> None:
        lines = [r.describe() for r in self.results.values()] + self.notes
        body = "<br>".join(html.escape(line) for line in lines)
        if diff:
            body += (
                '<pre style="font-size:0.85em;white-space:pre-wrap">' + html.escape(diff) + "</pre>"
            )
        self.results_html.content = _html(RESULTS, body)
        self.write.disabled = not self.results


#: From where each joint's turn shows best, as an offset (metres, base_link) from the middle
#: of its needle (the hand's: from its tool): the base from above, the pitch joints from the
#: side, the hand from above it.
VIEWS: dict[str, Vec3] = {
    "base": (-0.05, -0.2, 0.42),
    "shoulder": (0.02, -0.5, 0.05),
    "elbow": (0.02, -0.5, 0.05),
    "wrist": (0.02, -0.5, 0.05),
    "wrist_rotate": (0.05, -0.07, 0.28),
    "gripper": (0.08, -0.2, 0.12),
}


def joint_view(model: ArmModel, pose: dict[str, float], joint: str) -> tuple[Vec3, Vec3]:
    """The point to look at `joint` of the arm at `pose` (its needle's middle, or the
    tool), and where from."""
    needle = joint_needle(model, pose, joint)
    if needle is None:
        at = joint_positions(model.geometry, pose)["tool0"]
    else:
        (ax, ay, az), (bx, by, bz) = needle
        at = ((ax + bx) / 2, (ay + by) / 2, (az + bz) / 2)
    dx, dy, dz = VIEWS.get(joint, VIEWS["wrist_rotate"])
    return at, (at[0] + dx, at[1] + dy, at[2] + dz)


#: A needle's length (metres): long enough that a degree shows (5 mm at its tip).
NEEDLE_M = 0.3
#: The base's needle lies on the turntable, this high (metres).
BASE_NEEDLE_Z = 0.045
#: The pitch joints' needles run from the joint to the next joint's point.
NEXT_POINT = {"shoulder": "elbow", "elbow": "wrist", "wrist": "tool0"}


def joint_needle(
    model: ArmModel, pose: Mapping[str, float], joint: str
) -> tuple[Vec3, Vec3] | None:
    """Where `joint` of the arm at `pose` points: a needle from its axis NEEDLE_M long (the
    base's across the turntable, a pitch joint's along its link); None for a joint whose
    turn no needle shows (the wrist rotate, the gripper)."""
    if joint == "base" and "base" in pose:
        angle = math.radians(-pose["base"])  # +deg turns right, toward -y
        start = (0.0, 0.0, BASE_NEEDLE_Z)
        return start, (NEEDLE_M * math.cos(angle), NEEDLE_M * math.sin(angle), BASE_NEEDLE_Z)
    if joint not in NEXT_POINT:
        return None
    try:
        points = joint_positions(model.geometry, pose)
    except ModelError:
        return None
    (ax, ay, az), (bx, by, bz) = points[joint], points[NEXT_POINT[joint]]
    length = math.dist((ax, ay, az), (bx, by, bz))
    if length == 0:
        return None
    k = NEEDLE_M / length
    return (ax, ay, az), (ax + (bx - ax) * k, ay + (by - ay) * k, az + (bz - az) * k)


def attach(page: Page, path: Path, served: Callable[[], Path | None]) -> CalibrationTab:
    """The Calibrate tab on `page`, writing into `path` if `served` says it is the server's."""
    with page.lock:
        tab = CalibrationTab(page, path, page.panel.tabs, served)
        page.calibration = tab
        page.panel.controls.extend(tab.controls)
        page.panel.set_enabled(not page.lost)
    return tab
