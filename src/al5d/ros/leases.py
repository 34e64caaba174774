"""The leases of the ROS clients that command the arm: which are still there, and their clocks.

A client of `al5d.ros.client` sends its lease (`ClientLease`) on `~/clients` a few times a
second and names it in each instruction it sends (`ArmInstruction.client`). The server
keeps one `Lease` per client here:

- **Lost.** No lease heard for `server.client_lease_s`: the client is lost (cut off,
  killed, hung), and what it commanded is halted (`al5d.arm.core`'s `Gone`). A client
  that closes says so (`every_ms` 0) and is forgotten: what it commanded goes on, unless
  its last word says it left by an error (`left_by`: halted at once, `al5d.ros.node`). A lease
  shows the client was there when it was sent, which is when it is read unless it waited
  (a server frozen for seconds reads what waited for it at once): it counts from the last
  lease's time on as far as its client's clock went on between the two, never later than
  now (`PACE_SLACK`).
- **Its clock.** Each lease and each instruction is a sample of when it was sent (the
  client's clock) against when it came (the server's): the least difference over the
  last samples is the client's clock offset plus the quickest trip, the one-way half of
  what NTP measures. A request's age is its own difference less that least one: how much
  longer than the quickest trip it took, whatever the client's clock says. Times of
  sending are put on the server's clock by it, so that stops and releases from clients
  whose clocks differ are ordered as they were sent (to within the quickest trip).
- **Stale.** A request that took longer than its sender waits for it (`wait_ms`), or that
  comes late while its client is lost, or was sent before a lost client was heard again,
  is stale: its sender has given up on it, and it never moves the arm. A request that
  comes on time while its client is lost (sent since the link came back, before any of
  its leases) is a sign of the client: it is back.

Pure bookkeeping: no ROS, no thread, no clock of its own (each call says when it is).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

#: Samples of a client's clock kept (a few seconds of leases).
SAMPLES = 64
#: A lost client is forgotten this long after it was last heard: a server that runs for
#: months meets many clients cut off for good.
FORGET_S = 600.0
#: A lease counts from the last one's on by what its client's clock went on between them,
#: this much more: clocks whose rates differ never add up to a lease, even while NTP slews
#: one (chrony's fastest slew is 8.3 %, and the server's monotonic clock is slewed too).
#: Differences of one client's own times only, never the client's clock against the
#: server's: a clock stepped back gives no time (a lease later), one stepped forward gives
#: its step at most once (as any lease did before). Counting from when a lease was sent on
#: the server's clock (its offset measured) took a clock stepped back by more than half a
#: lease for a lost client, for as long as its old samples were kept.
PACE_SLACK = 1.25


@dataclass
class Lease:
    """What the server knows of one client."""

    key: str
    #: Until when the client is known to have been there (monotonic s, the server's): when
    #: its last lease was sent, as far as the server can tell.
    heard: float
    #: When its last lease was sent (its own clock, ns), None before its first.
    sent_ns: int | None = None
    #: (came, server's realtime ns) - (sent, client's realtime ns) of the last samples.
    gaps: deque[int] = field(default_factory=lambda: deque(maxlen=SAMPLES))
    #: Lost: no lease heard for the lease's time; said once (`lapsed`).
    lost: bool = False
    #: The client's time of sending of the first lease heard after it was lost: what it
    #: sent before that, it had given up on.
    back_ns: int | None = None

    @property
    def offset_ns(self) -> int:
        """The server's clock less the client's, plus the quickest trip seen."""
        return min(self.gaps)


@dataclass(frozen=True)
class Verdict:
    """A request judged (`Leases.judge`)."""

    #: The clients lost meanwhile, each with how long none of its leases was heard (s):
    #: what they commanded is halted, before the request is taken.
    lost: tuple[tuple[str, float], ...]
    #: Why the request is stale (`Leases.stale`); None: it is not.
    stale: str | None


class Leases:
    """Every client's lease, for a server whose lease is `lease_s` seconds."""

    def __init__(self, lease_s: float) -> None:
        self.lease_s = lease_s
        self._leases: dict[str, Lease] = {}

    def __len__(self) -> int:
        return len(self._leases)

    def heard(self, key: str, sent_ns: int, every_ms: int, t: float, wall_ns: int) -> None:
        """A lease of client `key`, sent at `sent_ns` (its clock), come at `t` (monotonic s)
        and `wall_ns` (the server's realtime); `every_ms` 0: it is closing."""
        if every_ms == 0:
            self._leases.pop(key, None)
            return
        lease = self._leases.get(key)
        if lease is None:
            lease = self._leases[key] = Lease(key, t)
        heard = t
        if lease.sent_ns is not None:
            went_s = max(0, sent_ns - lease.sent_ns) / 1e9 * PACE_SLACK
            heard = min(t, lease.heard + went_s)
        if not lease.lost:
            lease.heard, lease.sent_ns = heard, sent_ns
        elif t - heard <= self.lease_s or not lease.gaps or self._on_time(lease, sent_ns, wall_ns):
            # Back: sent since the loss, by its clock's pace from its last lease before the
            # loss or as a request is judged (`stale`; a clock stepped back meanwhile).
            lease.lost, lease.back_ns, lease.heard, lease.sent_ns = False, sent_ns, t, sent_ns
        # Else one that waited (sent before the loss, read after a stall) says nothing of
        # the client now: lost it stays, and the next counts from before the loss again.
        lease.gaps.append(wall_ns - sent_ns)

    def lapsed(self, t: float) -> list[tuple[str, float]]:
        """The clients lost at `t`, each once: no lease of theirs heard for `lease_s`; with
        how long none has been (s)."""
        lost = []
        for lease in list(self._leases.values()):
            if not lease.lost and t - lease.heard > self.lease_s:
                lease.lost = True
                lost.append((lease.key, t - lease.heard))
            elif lease.lost and t - lease.heard > FORGET_S:
                del self._leases[lease.key]
        return lost

    def _on_time(self, lease: Lease, sent_ns: int, wall_ns: int) -> bool:
        """A request that took at most half a lease longer than the quickest trip."""
        return wall_ns - sent_ns - lease.offset_ns <= self.lease_s * 5e8

    def offset(self, key: str) -> int | None:
        """Client `key`'s `Lease.offset_ns`, or None before any sample of its clock."""
        lease = self._leases.get(key)
        return lease.offset_ns if lease is not None and lease.gaps else None

    def on_server_clock(self, key: str, sent_ns: int) -> int:
        """`sent_ns` of client `key`'s clock, on the server's (as it is, for an unknown client)."""
        lease = self._leases.get(key)
        return sent_ns if lease is None or not lease.gaps else sent_ns + lease.offset_ns

    def judge(self, key: str, sent_ns: int, wait_ms: int, t: float, wall_ns: int) -> Verdict:
        """A request, as `stale` says, after the clients lost by `t` (`lapsed`): the loss of
        its own client, which the caller halts what that client commanded for, comes before
        the request is taken, never after it (a request that came after its client's lease
        had run out but before anyone looked was taken, then halted with that loss)."""
        lost = tuple(self.lapsed(t))
        return Verdict(lost, self.stale(key, sent_ns, wait_ms, t, wall_ns))

    def stale(self, key: str, sent_ns: int, wait_ms: int, t: float, wall_ns: int) -> str | None:
        """Why a request of client `key` (empty: none named), sent at `sent_ns` on its clock,
        waited for `wait_ms` ms by its sender (0: for ever) and come at `t` (monotonic s) and
        `wall_ns`, is stale; None if it is not. The request is a sample of the client's clock
        too, and a sign of it: a client whose request comes before any lease of its own (its
        lease's writer not yet matched) is lost if none follows within the lease."""
        lease = None
        if key:
            lease = self._leases.get(key)
            if lease is None:
                lease = self._leases[key] = Lease(key, t)
        if lease is not None:
            if lease.lost and lease.gaps and self._on_time(lease, sent_ns, wall_ns):
                # Sent since the link came back (it took no longer than a trip does): the
                # client is back, though none of its leases has come yet.
                lease.lost, lease.back_ns, lease.heard = False, sent_ns, t
            if lease.lost:
                return (
                    f"its client {key} is lost (no lease heard for more than "
                    f"{self.lease_s:g} s): sent before the contact was lost, it is not run"
                )
            if lease.back_ns is not None and sent_ns < lease.back_ns:
                return (
                    f"sent while its client {key} was out of contact, which has given up on "
                    "it: not run"
                )
            lease.gaps.append(wall_ns - sent_ns)
        if wait_ms == 0:
            return None
        quickest = lease.offset_ns if lease is not None else wall_ns - sent_ns
        late_ms = (wall_ns - sent_ns - quickest) / 1e6
        if late_ms <= wait_ms:
            return None
        return (
            f"it reached the server {late_ms:.0f} ms after it was sent, and its sender waits "
            f"{wait_ms} ms for an outcome: stale, not run"
        )
