"""A stop asked of a server over ROS 2 by a client (`StopCall`): copies of one stop on the
instruction topic, sent again until one is answered. Only `al5d.ros.rosway` imports this
module; what a stop needs of its client's way is `StopWay`.

Not by the stop service: `std_srvs/Trigger` names no stop, so a call made again, or one
held on its way (a slow link, a stop process that stalled), that reaches the server after
another client's release is a new stop, and locks the arm again behind that release
(seen: the web view's page, which called the service beside the topic, had its arm
stopped again once the stop process ran after the release). The copies on the topic name
this client and one stop, which the server obeys once, however many of them come, and
before or after whichever release. The web view's STOP goes the same way
(`al5d.web.link`); the service is there for every other client (`ros2 service call`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Protocol

from al5d.arm.instruction import Instruction, Kind, Outcome
from al5d.clock import Deadline
from al5d.owner import quick
from al5d.ros.answers import ANSWER_MIN_S, Answer, NoOutcome, NoServer, said_late
from al5d.ros.convert import COPY_MARK
from al5d.ros.leasing import HELD_S, LOST_AFTER_LEASE_S, Leaser

log = logging.getLogger("al5d")

#: A stop unanswered this long is sent again (its copies: `StopCall`).
STOP_RETRY_S = 1.0
#: In a stop's first second its copy on the topic goes this often: a server just found (a
#: restart) may not have matched our writer yet, and drops what comes before (seen beside
#: two busy loops: a restarted server's stop obeyed 1.01 s after it was asked, by the copy
#: sent again after a second).
STOP_FIRST_COPIES_S = 0.25
#: A stop unanswered this long is said to be so at once (a WARNING), while it is still
#: sent, as by the local lane (`quick.UNANSWERED_S`): after a server's restart its side may
#: take seconds to find this client (beside busy loops, a stop was obeyed 2.15 s after it
#: was asked), and whoever asked must not believe the arm stopped meanwhile. Under a
#: second, so that a stop not obeyed within one is said before the second is up (an idle
#: CI run: a restarted server's stop obeyed 1.012 s after it was asked, answered before a
#: warning at 1 s could be said).
STOP_UNANSWERED_S = quick.UNANSWERED_S


class StopWay(Protocol):
    """What a stop needs of its client's way to the server (`al5d.ros.rosway.RosWay`)."""

    wait_s: float
    #: Seconds spent waiting for the server to be discovered (a stop adds its own).
    discovery_s: float
    lease: Leaser

    @property
    def topic(self) -> str:
        """The instruction topic's name."""
        ...

    @property
    def readers_matched(self) -> int:
        """Readers of our stops ever matched."""
        ...

    def server_seen(self) -> bool: ...

    def no_server(self, name: str, timeout: float, seen: str = "") -> NoServer: ...

    def others(self) -> str:
        """The servers seen under other namespaces, as `al5d.ros.answers.others` says them."""
        ...

    def send_copy(self, ident: str, heard: Callable[[Outcome], None]) -> None:
        """Publish a copy `ident` of a stop, with this client's lease; its outcome to
        `heard`."""
        ...

    def drop_copies(self, idents: Iterable[str]) -> None:
        """Forget the copies of a stop: their outcomes, if they come, are no one's."""
        ...


class StopCall:
    """One stop asked of the server on `way`: on the instruction topic at once, and again
    every `STOP_RETRY_S` until a copy is answered (every `STOP_FIRST_COPIES_S` in the first
    second), and the moment a new reader of the topic matches. The copies are one stop
    (`<stop>~<n>`, this client's: `al5d.ros.convert.stop_key`): the server obeys the first
    to come and answers each, so a copy still on its way when another client releases the
    arm does not lock it again. `timeout` counts from when the server is found; if it is
    not within the way's `wait_s`, `NoServer` where no copy reached a reader, else
    `NoOutcome` (`_unfound`).

    The server's stop watcher (its stop path's DDS participant, ahead of the rest) and its
    node both read the topic, and either obeys the first copy that reaches it. A copy sent
    before our writer matched a new server's reader reached nobody: a stop asked of a
    server just restarted goes again once our writer has matched its reader (the stop
    watcher's, best effort, takes the copies sent after its reader matched ours; the
    node's, reliable, asks for what it missed at the writer's next heartbeat). On a lossy
    link a reliable writer's lost sample is sent again only at its next heartbeat (Fast
    DDS: every 3 s; measured: stops obeyed 3.5 and 6.0 s late at 13 to 17 % loss), and
    what the writer sent after it waits behind it. The stop watcher reads the topic best
    effort: each copy that gets through is obeyed at once, whatever was lost."""

    def __init__(self, way: StopWay, timeout: float) -> None:
        self.way = way
        # As on a lane: a stop asked with no time to wait (0) had its answer, due in tens of
        # ms, looked for once after 20 ms, and raised `NoOutcome` when it came later (once in
        # a CI run on an idle machine).
        self.timeout = max(timeout, ANSWER_MIN_S)
        self._answered = threading.Event()
        self._answered_at = math.inf  # when (monotonic) the first answer came
        self._told: list[Outcome] = []
        # One stop, however many copies: each names this client and is `<stop>~<n>`, so
        # that the server obeys the first to come and answers each (a copy whose answer
        # was lost is answered again), and a copy that comes after another client's release
        # is the stop obeyed already (`convert.stop_key`).
        self._stop = Instruction(Kind.STOP).id
        self._copies: list[str] = []
        self._copied = -STOP_RETRY_S  # when (monotonic) the last copy went
        self._matched = -1  # the readers matched when the last copy went
        self._reached = False  # a copy went out while a reader of the topic was matched
        self._deadline: Deadline | None = None  # `timeout`, from when the server is found
        self._found: float | None = None  # when the server was found (monotonic)
        self._looked = -STOP_FIRST_COPIES_S  # when (monotonic) the graph was last looked at
        self._asked = time.monotonic()
        # Once this call has given up (when, monotonic), a copy's answer that comes later
        # is said, not taken (`_heard`); the lock keeps the two apart.
        self._gave_up: float | None = None
        self._late_said = False
        self._lock = threading.Lock()

    def run(self) -> Answer:
        """Send the stop until it is answered; its answer. `NoOutcome` if none came within
        `timeout` (whether the server obeyed is unknown), `NoServer` as the class says."""
        start = self._asked = time.monotonic()
        finding = Deadline(self.way.wait_s)
        warned = False
        try:
            while True:
                # The copy first: whether the server is found (the graph's answer) takes
                # its time, and the stop waits for nothing.
                at = time.monotonic()
                self._copy(at, at - start)
                self._look(at)
                waited = time.monotonic()
                if self._answered.wait(0.02):
                    break
                # This client's own hold (Ctrl-Z) is no time the server took to answer:
                # counted from its end, and judged once the lease's thread has looked.
                lease = self.way.lease
                lease.woke(waited, 0.02)
                start = max(start, lease.held_until or start)
                looked = time.monotonic() - lease.looked <= HELD_S
                if not warned and looked and time.monotonic() - start >= STOP_UNANSWERED_S:
                    warned = True
                    # Said by a thread of its own: it looks at this machine's lanes and the
                    # graph (`others`), which the stop's copies must not wait for.
                    threading.Thread(target=self._warn, name="al5d-stop-warn", daemon=True).start()
                if self._deadline is None and finding.expired:
                    raise self._unfound()
                if self._deadline is not None and self._deadline.expired:
                    break
        finally:
            self.way.discovery_s += max(0.0, (self._found or time.monotonic()) - start)
            with self._lock:
                if not self._told:
                    self._gave_up = time.monotonic()
            if self._gave_up is None:
                self.way.drop_copies(self._copies)
            # Else the copies are listened for on: one that is obeyed later, however late
            # (a stop always is), is said (an outside try: a stop given up on during an
            # outage locked the arm when the link came back, with nobody told).
        return self._answer()

    def _look(self, at: float) -> None:
        """Whether the server is found, every `STOP_FIRST_COPIES_S` until it is (the graph's
        answer takes its time): the timeout starts then."""
        if self._deadline is not None or at - self._looked < STOP_FIRST_COPIES_S:
            return
        self._looked = at
        if self.way.server_seen():
            self._deadline = Deadline(self.timeout)
            self._found = time.monotonic()

    def _heard(self, outcome: Outcome) -> None:
        with self._lock:
            late = self._gave_up is not None
            if not late:
                self._told.append(outcome)
                self._answered_at = min(self._answered_at, time.monotonic())
                self._answered.set()
        if late:
            self.way.drop_copies(self._copies)  # one answer is the stop's: the rest go
            self._said_late(outcome)

    def _said_late(self, outcome: Outcome) -> None:
        """The answer to a stop this call gave up on, said once, as a WARNING."""
        if self._late_said:
            return
        self._late_said = True
        after = time.monotonic() - self._asked
        stop = outcome.id.partition(COPY_MARK)[0]
        said_late(stop, after, outcome.ok, outcome.result.value, outcome.reason)

    def _copy(self, at: float, since_start: float) -> None:
        """The stop's next copy on the topic, where one is due or a new reader matched."""
        matched = self.way.readers_matched
        every = STOP_FIRST_COPIES_S if since_start < 1.0 else STOP_RETRY_S
        if at - self._copied < every and matched <= self._matched:
            return
        self._matched = matched
        ident = f"{self._stop}{COPY_MARK}{len(self._copies) + 1}"
        self._copies.append(ident)
        self._reached = self._reached or matched > 0
        self.way.send_copy(ident, self._heard)
        self._copied = at

    def _warn(self) -> None:
        # Counted from a hold of this client's own (resumed after Ctrl-Z), as its way does.
        since = self.way.lease.silent_since()
        # A stop meant for another arm must say so at once, not when it gives up: with only
        # /left and /right running, `al5d send stop` waited 10 s before it named them.
        others = self.way.others() if self._found is None else ""
        unfound = (
            f"the server not found yet, or its side has not found this client yet{others}"
            if self._found is None
            # Found, on a link that loses or delays (an outside try at 20 % loss: "not
            # found yet" of a server it had found).
            else "the server found, but its answer not heard yet: a slow or lossy link, or "
            "its side has not found this client yet"
        )
        quiet = 0.0 if since is None else time.monotonic() - since
        why = (
            unfound
            if quiet <= LOST_AFTER_LEASE_S
            else f"nothing heard from the server for {quiet:.1f} s: the link may be lost"
        )
        if self._answered_at - self._asked < STOP_UNANSWERED_S:
            # Answered before the warning was due. One answered while this looked (the
            # graph, on a busy host, takes its time) is said all the same, true when due:
            # a restarted server's stop obeyed 1.01 s after it was asked went unsaid.
            return
        log.warning(
            "stop [%s]: no answer in %g s (%s); still sending it: whether the arm has stopped "
            "is unknown",
            self._stop,
            STOP_UNANSWERED_S,
            why,
        )

    def _answer(self) -> Answer:
        """The outcome of the first copy answered; `NoOutcome` if none was."""
        topic = self.way.topic
        if self._told:
            told = self._told[0]
            message = told.reason or f"stop: {told.result.value}"
            return Answer("stop", told.ok, message, topic, False, self._stop)
        raise NoOutcome(
            f"stop [{self._stop}]: no answer on {topic} within {self.timeout:g} s (whether "
            "the server obeyed is unknown)"
        )

    def _unfound(self) -> NoOutcome | NoServer:
        """No server found to answer the stop within `wait_s`: `NoServer` where its copies
        reached nobody, `NoOutcome` where one went out while a reader of the topic was
        matched (something may have obeyed: whether the arm stopped is unknown)."""
        wait_s, topic = self.way.wait_s, self.way.topic
        if not self._reached:
            return NoServer(f"stop: reached nobody: {self.way.no_server(topic, wait_s)}")
        return NoOutcome(
            f"stop [{self._stop}]: sent {len(self._copies)} times on {topic}, which a reader "
            f"took, but no al5d server was found within {wait_s:g} s to answer it (whether "
            "the arm has stopped is unknown)"
        )
