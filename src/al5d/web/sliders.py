"""The Joints tab's sliders as the user moves them: each value read as it arrives, then
taken into the page's jog (`jog.py`) and judged as the server will judge it.

Called from viser's event loop; what it shares with the rest of the page is the page's,
under its lock (`PageParts.lock`).
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

from al5d.arm.instruction import Instruction, Kind
from al5d.web.panel import RELEASABLE, TimeNotTaken, held

if TYPE_CHECKING:
    from al5d.web.parts import PageParts

log = logging.getLogger("al5d.web")


class SliderInput:
    """The sliders' values on one page, taken in the order they came: the newest of each
    slider not yet taken, set by viser's event loop."""

    def __init__(self, page: PageParts) -> None:
        self._page = page
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="al5d-web-slider")
        self._due: dict[str, float] = {}

    def handler(self, joint: str) -> Any:
        """viser's handler of `joint`'s slider."""

        async def handler(event: Any) -> None:
            if event.client is None:
                return  # set by the page itself (following the arm), not by a user
            # Read on viser's event loop as the value arrives. A handler in viser's thread
            # pool read the slider whenever the pool got to it, and by then the page's loop
            # could have put the arm's position back in it (the user's hand not yet taken,
            # the sliders following the idle arm): the jog went to where the arm already
            # was. The sliders stop following at once; the rest waits for a thread of its
            # own, in order, as the event loop must not wait for the page's lock.
            self._due[joint] = float(event.target.value)
            self._page.jog.hold(time.monotonic())
            self._thread.submit(self._take, joint).add_done_callback(_logged)

        return handler

    def _take(self, joint: str) -> None:
        """The user moved `joint`'s slider: the jog goes to its newest value (values that
        came faster than they are judged are passed over)."""
        value = self._due.pop(joint, None)
        if value is None:
            return  # taken already, by the turn of an earlier value
        page = self._page
        with page.lock:
            if page.lost:
                # The number box beside a slider cannot be disabled (viser 1.1.1): what was
                # typed there is undone, and nothing is sent.
                if page.degrees is not None and joint in page.degrees:
                    page.panel.set_slider(joint, page.degrees[joint])
                return
            if page.state in RELEASABLE:
                # The server refuses every move until a release: nothing is sent, and the
                # slider goes back to where the arm is.
                page.jog.let_go()
                if page.degrees is not None and joint in page.degrees:
                    page.panel.set_slider(joint, page.degrees[joint])
                page.panel.show_joints_status(
                    f"{held(page.state)} (the sliders show where it is)", False
                )
                return
            try:
                time_ms = page.panel.time_ms()
            except TimeNotTaken as e:
                page.panel.show_joints_status(f"will not be sent: {e}", False)
                return
            jog = page.jog.take(joint, value, time.monotonic())
            move = Instruction(Kind.MOVE, joints=tuple(jog.items()), time_ms=time_ms)
        # Judged while dragging, as the server will judge it: a set-point it would refuse
        # is not sent (the arm stays at the last one it took), and the page says why.
        reason = page.precheck(move)
        with page.lock:
            if page.jog.judge(jog, reason):
                page.panel.show_joints_status(
                    f"will not be sent: {reason}" if reason else "jogging", not reason
                )

    def close(self) -> None:
        self._thread.shutdown(wait=False, cancel_futures=True)


def _logged(done: Future[None]) -> None:
    """What a slider's thread raised, in the log (a future's error is otherwise lost)."""
    if not done.cancelled() and (error := done.exception()) is not None:
        log.error("web: a slider's value could not be taken", exc_info=error)
