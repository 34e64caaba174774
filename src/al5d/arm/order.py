"""The order across channels: what the arm's protocol remembers to judge each instruction by
when it was sent, not when it arrived (`core`, rules 1 to 3).

`ChannelOrder` is owned by the core and called only under its lock. It keeps, in
sending times (CLOCK_REALTIME ns), the last event that dropped every pending move
(and why), the last stop (or reset) that holds the lock (and what it was), the last
release, and the identities of the stops obeyed.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from concurrent.futures import Future

from al5d.arm.instruction import Outcome

#: Stop identities remembered, so that a stop both readers see is obeyed once.
STOPS_REMEMBERED = 1024


class ChannelOrder:
    """The sending times the rules judge by, and the stops obeyed."""

    def __init__(self) -> None:
        self._dropped_ns = -1
        self._dropped_why = ""
        self._locked_ns = -1
        self._locked_by = ""
        self._released_ns = -1
        self._stops: OrderedDict[Hashable, Future[Outcome]] = OrderedDict()

    # -- what happened -------------------------------------------------------------------

    def dropped(self, why: str, sent_ns: int) -> None:
        """Every pending move was dropped by an event sent at `sent_ns`."""
        if sent_ns >= self._dropped_ns:
            self._dropped_ns, self._dropped_why = sent_ns, why

    def locked(self, by: str, sent_ns: int, already: bool) -> None:
        """The arm was locked (or `already` was) by an event sent at `sent_ns`: a release must
        be sent after the latest such event."""
        if not already or sent_ns >= self._locked_ns:
            self._locked_ns, self._locked_by = sent_ns, by

    def released(self, sent_ns: int) -> None:
        self._released_ns = max(self._released_ns, sent_ns)

    def obeyed(self, key: Hashable, future: Future[Outcome]) -> Future[Outcome] | None:
        """Rule 3: the future of a stop obeyed already under `key`, or None (it is now)."""
        known = self._stops.get(key)
        if known is not None:
            return known
        self._stops[key] = future
        if len(self._stops) > STOPS_REMEMBERED:
            self._stops.popitem(last=False)
        return None

    # -- the rules -----------------------------------------------------------------------

    def cancelled(self, sent_ns: int) -> str:
        """Rule 2: why a move sent at `sent_ns` is cancelled by an event since, or ""."""
        return f"{self._dropped_why} (it was sent before)" if sent_ns < self._dropped_ns else ""

    def sent_while_locked(self, sent_ns: int) -> str:
        """Rule 2: why a move sent at `sent_ns` between a stop and its release is refused."""
        if sent_ns >= self._released_ns:
            return ""
        return (
            f"it was sent while the arm was locked ({self._locked_by}), before the release: "
            "send it again"
        )

    def release_too_old(self, sent_ns: int) -> str:
        """Rule 1: why a release sent at `sent_ns` may not unlock the arm, or ""."""
        if sent_ns >= self._locked_ns:
            return ""
        return (
            f"this release was sent before {self._locked_by} that locked the arm: "
            "the arm stays locked; send release again to unlock it"
        )
