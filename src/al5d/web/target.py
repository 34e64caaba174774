"""The page's Target tab: the gizmo dragged and the numbers typed, each judged as the
server will judge it, and `move_to` sent.

Called from viser's threads; what it shares with the rest of the page is the page's, under
its lock (`PageParts.lock`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from al5d.arm.instruction import Instruction, move_to
from al5d.model.transforms import Vec3
from al5d.web.panel import RELEASABLE, TimeNotTaken, held

if TYPE_CHECKING:
    from al5d.web.parts import PageParts


#: The gizmo stays where the user left it this long (a refused target stays in view).
TARGET_KEPT_S = 5.0


class TargetTab:
    """The Target tab's input on one page, and where its gizmo stands."""

    def __init__(self, page: PageParts) -> None:
        self._page = page
        #: When the user last set the target, and where the tool was when the gizmo was
        #: last put at it (None: never).
        self.touched = -math.inf
        self.tool: Vec3 | None = None

    def follow(self, force: bool) -> None:
        """The gizmo goes back to the tool once the arm has moved from where it put it, and
        a target the user set (a refused one too) has been in view a while (under the
        page's lock)."""
        page = self._page
        tool = None if page.degrees is None else page.planner.tool_of(page.degrees)
        if tool is None:
            return
        moved = self.tool is None or float(np.linalg.norm(np.subtract(tool, self.tool))) > 1e-3
        kept = time.monotonic() - self.touched < TARGET_KEPT_S
        if force or (moved and not kept):
            self.to_tool()

    def to_tool(self) -> None:
        """The gizmo and the numbers at the tool (under the page's lock)."""
        page = self._page
        tool = None if page.degrees is None else page.planner.tool_of(page.degrees)
        if tool is None:
            return
        self.tool = tool
        page.scene.place_target(tool)
        page.panel.set_xyz([v * 1000 for v in tool])

    def instr(self, xyz_mm: Sequence[float]) -> Instruction | str:
        """The Target tab's `move_to`, or what is wrong with one of its fields."""
        page = self._page
        x, y, z = xyz_mm
        tool = page.panel.tool_fields()
        if isinstance(tool, str):
            return tool
        try:
            time_ms = page.panel.target_time_ms()
        except TimeNotTaken as e:
            return str(e)
        return move_to(
            x,
            y,
            z,
            pitch=tool["pitch"],
            roll=tool["roll"],
            gripper=tool["gripper"],
            line=page.panel.line(),
            time_ms=time_ms,
        )

    def on_drag(self, event: Any) -> None:
        page = self._page
        if event.client is None:
            return
        with page.lock:
            if page.lost or page.state in RELEASABLE:
                # A gizmo cannot be disabled (it has no handle left to grab): were it
                # moved all the same, it goes back, and nothing is sent.
                self.to_tool()
                if not page.lost:
                    page.panel.show_status(held(page.state), False)
                return
            self.touched = time.monotonic()
            xyz = [round(v * 1000, 1) for v in page.scene.target_position]
            page.panel.set_xyz(xyz)
        if event.phase == "end":
            self.send()
        else:
            reason = page.precheck(self.instr(xyz))
            with page.lock:
                page.panel.show_status(
                    f"unreachable: {reason}" if reason else "reachable: release to move",
                    not reason,
                )

    def on_typed(self, event: Any) -> None:
        page = self._page
        if event.client is None:
            return
        with page.lock:
            if page.lost:
                return
            self.touched = time.monotonic()
            xyz = page.panel.xyz()
            x, y, z = xyz
            page.scene.place_target((x / 1000, y / 1000, z / 1000))
        instr = self.instr(xyz)
        reason = page.precheck(instr)
        point = "x {:g} y {:g} z {:g} mm".format(*xyz)
        if not isinstance(instr, str) and instr.tool is not None:
            tool = instr.tool
            given = (
                ("pitch", tool.pitch_deg),
                ("roll", tool.roll_deg),
                ("gripper", tool.gripper_deg),
            )
            point += "".join(f", {k} {v:g}" for k, v in given if v is not None)
            point += f", {instr.time_ms} ms" if instr.time_ms else ""
        with page.lock:
            page.panel.show_status(
                f"{point}: unreachable: {reason}" if reason else f"{point}: reachable", not reason
            )

    def send(self) -> None:
        """`move_to` the target; the local check shows the reason at once, and the move goes
        to the server all the same: its outcome is the word that counts."""
        page = self._page
        with page.lock:
            if page.lost:
                return
            if page.state in RELEASABLE:
                # As a slider then: the server refuses every move until a release.
                page.panel.show_status(held(page.state), False)
                return
            instr = self.instr(page.panel.xyz())
            self.touched = time.monotonic()
        reason = page.precheck(instr)
        if isinstance(instr, str):
            with page.lock:
                page.panel.show_status(f"not sent: {instr}", False)
            return
        with page.lock:
            page.page_move_to = instr.id
            text = f"will be refused: {reason}" if reason else f"sent: {instr}"
            page.panel.show_status(text, False if reason else None)
        page.send_instruction(instr)
