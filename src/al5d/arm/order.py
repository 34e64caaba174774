"""The order across channels: what the core remembers to judge each instruction by when it
was sent, not when it arrived (`core`, rules 1 to 3).

`Order` is a value (frozen): each change returns a new one. It keeps, in sending
times (CLOCK_REALTIME ns), the last event that dropped every pending move (and
why), the last stop (or reset) that holds the lock (and what it was), the last
release, and the outcomes of the stops obeyed, by their message's identity.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field, replace

from al5d.arm.instruction import Outcome

#: Stop identities remembered, so that a stop both readers see is obeyed once.
STOPS_REMEMBERED = 1024
#: How much earlier the other reader's time for a stop may put its lock (`seen_earlier`):
#: the two readers' measures of one client's clock differ by milliseconds; by more, one of
#: them had no measure yet (the stop watcher takes the client's own clock then).
SEEN_EARLIER_NS = 50_000_000


@dataclass(frozen=True, slots=True)
class Order:
    """The sending times the rules judge by, and the stops obeyed."""

    dropped_ns: int = -1
    dropped_why: str = ""
    locked_ns: int = -1
    locked_by: str = ""
    #: The key of the stop that holds the lock, where it has one (`Ask.key`).
    locked_key: Hashable | None = None
    #: The time of the event that held the lock before that stop took it (-1: none): its
    #: other sighting (`seen_earlier`) lowers the lock no further.
    lock_floor_ns: int = -1
    released_ns: int = -1
    #: The stops obeyed by key, oldest first, with their outcomes.
    stops: Mapping[Hashable, Outcome] = field(default_factory=dict)

    # -- what happened -------------------------------------------------------------------

    def dropped(self, why: str, sent_ns: int) -> Order:
        """Every pending move was dropped by an event sent at `sent_ns`."""
        if sent_ns < self.dropped_ns:
            return self
        return replace(self, dropped_ns=sent_ns, dropped_why=why)

    def locked(self, by: str, sent_ns: int, already: bool, key: Hashable | None = None) -> Order:
        """The arm was locked (or `already` was) by an event sent at `sent_ns` (a stop known
        by `key`): a release must be sent after the latest such event."""
        if already and sent_ns < self.locked_ns:
            # Held by a later event: the lock may no longer go below this one's time.
            return self if key == self.locked_key else replace(self, locked_key=None)
        # Taken from an event that held it (sent at the same time, or earlier): the lock
        # never goes below that one's time (a CI run's model-based test: two stops sent at
        # once, the second seen earlier by the other reader, lowered it below the first).
        floor = self.locked_ns if already and key != self.locked_key else -1
        return replace(self, locked_ns=sent_ns, locked_by=by, locked_key=key, lock_floor_ns=floor)

    def seen_earlier(self, key: Hashable, sent_ns: int) -> Order:
        """The stop known by `key` seen again by the other reader of its topic, as sent at
        `sent_ns`: where it holds the lock, the lock counts from the earlier of the two.
        Each reader (the node `al5d` and the stop watcher, two processes) puts a client's
        times on this machine's clock by its own measure of that client's clock, and the
        two measures differ by milliseconds: a release sent by the same client right after
        its stop, judged by the node, was taken for older than the stop as the watcher
        judged it (a CI run: a replay's stop and release, recorded 1 ns apart). Never by
        more than `SEEN_EARLIER_NS`, nor below another event that holds the lock too."""
        if key != self.locked_key or sent_ns >= self.locked_ns:
            return self
        lowest = max(sent_ns, self.locked_ns - SEEN_EARLIER_NS, self.lock_floor_ns)
        return replace(self, locked_ns=lowest)

    def released(self, sent_ns: int) -> Order:
        return replace(self, released_ns=max(self.released_ns, sent_ns))

    def obeyed(self, key: Hashable, outcome: Outcome) -> Order:
        """Rule 3: the stop known by `key` is obeyed, with `outcome`."""
        stops = dict(self.stops)
        stops[key] = outcome
        while len(stops) > STOPS_REMEMBERED:
            del stops[next(iter(stops))]
        return replace(self, stops=stops)

    # -- the rules -----------------------------------------------------------------------

    def cancelled(self, sent_ns: int) -> str:
        """Rule 2: why a move sent at `sent_ns` is cancelled by an event since, or ""."""
        return f"{self.dropped_why} (it was sent before)" if sent_ns < self.dropped_ns else ""

    def sent_while_locked(self, sent_ns: int) -> str:
        """Rule 2: why a move sent at `sent_ns` between a stop and its release is refused."""
        if sent_ns >= self.released_ns:
            return ""
        return (
            f"it was sent while the arm was locked ({self.locked_by}), before the release: "
            "send it again"
        )

    def release_too_old(self, sent_ns: int) -> str:
        """Rule 1: why a release sent at `sent_ns` may not unlock the arm, or ""."""
        if sent_ns >= self.locked_ns:
            return ""
        return (
            f"this release was sent before {self.locked_by} that locked the arm: "
            "the arm stays locked; send release again to unlock it"
        )
