"""The page's jog: the sliders' targets, sent as set-points of the server's stream, and
when each is due.

Rules and state only (no viser, no ROS): the page (page.py) calls it under its lock,
from the sliders' handler and from its loop, and sends what `due` gives.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

log = logging.getLogger("al5d.web")

#: A slider still for this long has been let go (viser 1.1.1 tells the server no slider
#: release, only values): until then the jog's set-point is sent again each tick.
QUIET_S = 0.3
#: Sliders follow the arm once nobody has touched them for this long and it is not moving;
#: a jog let go with the arm idle short of its target is given up after as long.
FOLLOW_AFTER_S = 1.5
#: A jog let go with the arm idle short of its target (degrees) is sent again this often.
JOG_THERE_DEG = 0.5
JOG_RESEND_S = 0.3
#: A jog goes on after the server was lost if the sliders were let go at most this long ago.
JOG_KEPT_LOST_S = 5.0


@dataclass
class Jog:
    """The sliders' targets since the user took them (`target`; None: no jog), the newest
    replacing any not yet written; `speeds` in degrees a second, by joint."""

    speeds: Mapping[str, float]
    target: dict[str, float] | None = None
    #: False while the latest target is still to be sent.
    sent: bool = True
    #: Why the latest target would be refused (the table, a limit), or "": such a target is
    #: not sent, and once the sliders are let go they go back to the arm.
    refused: str = ""
    #: False while the latest target waits for its judgement (`judge`): it is not sent
    #: before it has one.
    judged: bool = True
    #: When the sliders were last moved by the user (-inf: not since the jog ended).
    touched: float = -math.inf
    #: When the latest target was set (the user's hand, or sent again), and since when the
    #: arm has been idle short of it (None: it is not).
    set_t: float = -math.inf
    short_t: float | None = field(default=None)
    #: Until when the arm, moving, is on the latest target's way: the target's way at the
    #: servos' speeds from where the arm stood when it was sent as new (or while the user
    #: was at it, or sent again after the arm stopped short), and FOLLOW_AFTER_S.
    way_until: float = -math.inf

    def take(self, joint: str, degrees: float, now: float) -> dict[str, float]:
        """The user moved `joint`'s slider to `degrees`: the jog's whole target now."""
        self.touched = self.set_t = now
        self.short_t = None
        # A new dict, set whole: STOP ends the jog from viser's event loop, without the
        # page's lock, and must find either the old target or the new one.
        target = {**(self.target or {}), joint: degrees}
        self.target = target
        self.sent, self.judged, self.refused = False, False, ""
        return dict(target)

    def judge(self, target: Mapping[str, float], reason: str) -> bool:
        """`target` (as `take` gave it) judged: `reason` why the server would refuse it, or
        "". False, and nothing changed, where it is no longer the jog's target (a newer
        one, or the jog ended: a STOP does not wait for a judgement)."""
        if self.target != target:
            return False
        self.refused, self.judged = reason, True
        return True

    def new_speeds(
        self, speeds: Mapping[str, float], now: float, degrees: Mapping[str, float] | None
    ) -> None:
        """The servos' speeds are `speeds` (the server's, by joint; others kept): a target on
        its way is kept alive for as long as its way takes at them, from `degrees`."""
        self.speeds = {**self.speeds, **speeds}
        if self.target is not None and self.sent:
            way = FOLLOW_AFTER_S + self._way_s(self.target, degrees or {})
            self.way_until = max(self.way_until, now + way)

    def hold(self, now: float) -> None:
        """A slider's new value has come and is not taken yet: the sliders do not follow the
        arm meanwhile. One assignment: viser's event loop calls it without the page's lock."""
        self.touched = now

    def end(self) -> None:
        """Another instruction, a stop: the jog's target is not sent again."""
        self.target = None

    def let_go(self) -> None:
        """The jog is over whatever the user's hand does (the arm stopped, or the server
        refused it): nothing more is sent, and the sliders may follow the arm at once."""
        self.target, self.refused, self.touched, self.short_t = None, "", -math.inf, None

    def unread(self) -> None:
        """Nobody read the set-point sent: it is due again at the next tick."""
        self.sent, self.short_t = False, None

    def quiet(self, now: float) -> bool:
        """No jog, and the sliders let go FOLLOW_AFTER_S ago: they may follow the arm."""
        return self.target is None and now - self.touched > FOLLOW_AFTER_S

    def contact_back(self, now: float) -> None:
        """The server answers again: a jog is kept over a short loss (this page's own
        process stalled, on a busy host), and goes on; not over a long one."""
        if now - self.touched > JOG_KEPT_LOST_S:
            self.target = None

    def due(
        self, now: float, moving: bool, degrees: Mapping[str, float] | None
    ) -> tuple[dict[str, float] | None, str]:
        """The set-point to send now (or None), and what to tell the user ("": nothing).

        A new one as soon as the sliders changed; the same one again while the user is at
        them or the arm is on its way, which writes nothing and keeps the server's watchdog
        from holding the arm (were the page to stop, the arm would be held where it is).
        The jog ends once the sliders are let go and the arm is there."""
        jog = self.target
        if jog is None or not self.judged:
            # A target is sent once judged: taken and sent before its judgement, one the
            # server refused went out while the page said it would not be sent.
            return None, ""
        at_it = now - self.touched < QUIET_S
        if self.refused:
            if at_it:
                return None, ""
            # Let go where the server would refuse it: nothing more is sent.
            said = f"not sent: {self.refused}"
            self.target, self.refused, self.touched = None, "", -math.inf
            return None, said
        here = degrees or {}
        if not self.sent or at_it:
            # A set-point goes at the servos' speed: there within FOLLOW_AFTER_S of its way's
            # time from here (a move of another client's that runs after is not the jog's to
            # keep alive). Measured from where the arm is now, not at each keep-alive: the way
            # left shrinks as the arm goes, and a window of the way left ended halfway there.
            self.way_until = now + FOLLOW_AFTER_S + self._way_s(jog, here)
        if not self.sent or at_it or (moving and now < self.way_until):
            self.sent = True
            self.short_t = None
            return dict(jog), ""
        if moving:
            self.short_t = None
            return None, ""
        if all(j in here and abs(here[j] - v) <= JOG_THERE_DEG for j, v in jog.items()):
            # Over at once: a move of another client's that comes next is not the jog's to
            # undo (kept on, the jog sent the arm back to its target after that move).
            self.target, self.short_t = None, None
            return None, ""
        # Let go, and the arm idle short of the target: the server's watchdog held it (the
        # page's loop lagged more than server.stream_timeout_s behind, on a busy host) or
        # the set-point was lost. Sent again, a while; then the sliders go back to the arm.
        if self.short_t is None:
            self.short_t = now
        if now - self.short_t > FOLLOW_AFTER_S:
            self.target, self.short_t, self.touched = None, None, -math.inf
            return None, ""
        if now - self.set_t < JOG_RESEND_S:
            return None, ""
        self.set_t = now
        self.way_until = now + FOLLOW_AFTER_S + self._way_s(jog, here)
        log.info("web: the jog stopped short of its target: sent again")
        return dict(jog), ""

    def _way_s(self, jog: Mapping[str, float], here: Mapping[str, float]) -> float:
        """How long the arm takes from `here` to `jog`, at its servos' speed."""
        return max(
            (abs(v - here[j]) / self.speeds[j] for j, v in jog.items() if j in here),
            default=0.0,
        )
