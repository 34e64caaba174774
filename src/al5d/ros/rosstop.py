"""A stop asked of a server over ROS 2 by a client (`StopCall`): its copies on the
instruction topic and its call of the stop service, each sent again until one is answered;
and the stop calls whose answers are still on their way (`InFlight`), which the client's
release waits for.

Only `al5d.ros.rosway` imports this module; what a stop needs of its client's way is
`StopWay`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, Protocol

from std_srvs.srv import Trigger

from al5d.arm.instruction import Instruction, Kind, Outcome
from al5d.clock import Deadline
from al5d.ros.answers import Answer, NoOutcome, NoServer
from al5d.ros.convert import COPY_MARK
from al5d.ros.leasing import Leaser

log = logging.getLogger("al5d")

#: A stop's service call unanswered this long is made again. rmw_fastrtps drops an answer
#: whose client it has not matched 100 ms after the request (ros2/rmw_fastrtps#390), which
#: on a loaded machine can befall a new client's first call. A second stop is harmless; a
#: second release could undo a stop sent in between, so a release is never sent twice.
STOP_RETRY_S = 1.0
#: In a stop's first second its copy on the topic goes this often: a server just found (a
#: restart) may not have matched our writer yet, and drops what comes before (seen beside
#: two busy loops: a restarted server's stop obeyed 1.01 s after it was asked, by the copy
#: sent again after a second).
STOP_FIRST_COPIES_S = 0.25
#: A stop unanswered this long is said to be so at once (a WARNING), while it is still
#: sent: after a server's restart its side may take seconds to find this client (beside
#: busy loops, a stop was obeyed 2.15 s after it was asked), and whoever asked must not
#: believe the arm stopped meanwhile.
STOP_UNANSWERED_S = 1.0
#: A release waits at most this long for the answers of its client's stops still on their
#: way (`InFlight.wait`): a lost request is sent again at the writer's next heartbeat, 3 s
#: on; a server gone never answers, and must not cost the release its timeout.
STOPS_ANSWERED_S = 4.0


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
        """Readers of our instructions ever matched."""
        ...

    def server_seen(self) -> bool: ...

    def no_server(self, name: str, timeout: float, seen: str = "") -> NoServer: ...

    def send_copy(self, ident: str, heard: Callable[[Outcome], None]) -> None:
        """Publish a copy `ident` of a stop, with this client's lease; its outcome to
        `heard`."""
        ...

    def drop_copies(self, idents: Iterable[str]) -> None:
        """Forget the copies of a stop: their outcomes, if they come, are no one's."""
        ...


class InFlight:
    """The stop service's calls not yet answered: each is a stop the server may still obey.
    Kept by the client's way, for its next release to wait for (`wait`)."""

    def __init__(self) -> None:
        self._futures: list[Any] = []

    def add(self, futures: Iterable[Any]) -> None:
        self._futures.extend(f for f in futures if not f.done())

    def wait(self, deadline: Deadline, service: Any) -> None:
        """Wait (until `deadline`, `STOPS_ANSWERED_S` at most) for the answers of the stops
        still on their way. On a slow or lossy link a stop asked again arrives after the
        first is answered: were the release sent at once, that stop, sent before it, would
        lock the arm again behind it, with nobody to release it. Answered, it is obeyed
        before the release. Those unanswered are given up on `service`."""
        until = Deadline(min(deadline.left(), STOPS_ANSWERED_S))
        while self._futures and not until.expired:
            if self._futures[0].done():
                self._futures.pop(0)
            else:
                time.sleep(0.02)
        for future in self._futures:  # lost with its server, or too late
            service.remove_pending_request(future)
        self._futures.clear()


class StopCall:
    """One stop asked of the server on `way`: on the instruction topic at once and by its
    service `name` as soon as that is found, both sent again every `STOP_RETRY_S` until one
    is answered (the copy every `STOP_FIRST_COPIES_S` in the first second), and on the
    topic again the moment a reader of it matches. The copies are one stop
    (`<stop>~<n>`, this client's): the server obeys the first to come and takes the others
    for it (each answered), so a copy still on its way when another client releases the
    arm does not lock it again. `timeout` counts from when the server is found; if it is
    not within the way's `wait_s`, `NoServer` where no copy reached a reader, else
    `NoOutcome` (`_unfound`).

    Nothing waits for the service: the server's stop path is a DDS participant of its own,
    found apart from its node (after a restart, under load, seconds apart), and the node
    obeys the topic's copy too. A copy sent before our writer matched a new server's
    reader reached nobody: a stop asked of a server just restarted goes again once our
    writer has matched its reader (the stop watcher's, best effort, takes the copies sent
    after its reader matched ours; the node's, reliable, asks for what it missed at the
    writer's next heartbeat). On a lossy link a reliable writer's lost sample is sent again
    only at its next heartbeat (Fast DDS: every 3 s; measured: stops obeyed 3.5 and 6.0 s
    late at 13 to 17 % loss), and what the writer sent after it waits behind it. The stop
    watcher reads the topic best effort: each copy that gets through is obeyed at once,
    whatever was lost."""

    def __init__(
        self, way: StopWay, name: str, service: Any, timeout: float, in_flight: InFlight
    ) -> None:
        self.way = way
        self.name = name
        self.service = service
        self.timeout = timeout
        self.in_flight = in_flight
        self._answered = threading.Event()
        self._told: list[Outcome] = []
        self._futures: list[Any] = []
        # One stop, however many copies: each names this client and is `<stop>~<n>`, so
        # that the server obeys the first to come and answers each (a copy whose answer
        # was lost is answered again), and a copy that comes after another client's release
        # is the stop obeyed already (`convert.stop_key`).
        self._stop = Instruction(Kind.STOP).id
        self._copies: list[str] = []
        self._copied = self._called = -STOP_RETRY_S  # when (monotonic) last sent, each way
        self._matched = -1  # the readers matched when the last copy went
        self._reached = False  # a copy went out while a reader of the topic was matched
        self._deadline: Deadline | None = None  # `timeout`, from when the server is found
        self._found: float | None = None  # when the server was found (monotonic)

    def run(self) -> Answer:
        """Send the stop until it is answered; its answer. `NoOutcome` if none came within
        `timeout` (whether the server obeyed is unknown), `NoServer` as the class says."""
        start = time.monotonic()
        finding = Deadline(self.way.wait_s)
        warned = False
        try:
            while True:
                # The copy first: the graph's answers below (is the service there, the
                # server) take their time, and the stop waits for nothing.
                at = time.monotonic()
                self._copy(at, at - start)
                self._call(at)
                if self._answered.wait(0.02):
                    break
                if not warned and time.monotonic() - start >= STOP_UNANSWERED_S:
                    warned = True
                    self._warn()
                if self._deadline is None and finding.expired:
                    raise self._unfound()
                if self._deadline is not None and self._deadline.expired:
                    break
        finally:
            self.way.discovery_s += (self._found or time.monotonic()) - start
            self.in_flight.add(self._futures)
            self.way.drop_copies(self._copies)
        return self._answer()

    def _heard(self, outcome: Outcome) -> None:
        self._told.append(outcome)
        self._answered.set()

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

    def _call(self, at: float) -> None:
        """The stop service called, where it is found and a call is due; the timeout starts
        once the server is found."""
        if at - self._called < STOP_RETRY_S:
            return
        ready = self.service.service_is_ready()
        if self._deadline is None and (ready or self.way.server_seen()):
            self._deadline = Deadline(self.timeout)
            self._found = time.monotonic()
        if ready:
            future = self.service.call_async(Trigger.Request())
            future.add_done_callback(lambda _: self._answered.set())
            self._futures.append(future)
            self._called = at

    def _warn(self) -> None:
        last = self.way.lease.heard
        why = (
            "the server not found yet, or its side has not found this client yet"
            if last is None or not self.way.lease.deaf()
            else f"nothing heard from the server for {time.monotonic() - last:.1f} s: the "
            "link may be lost"
        )
        log.warning(
            "stop: no answer in %g s (%s); still sending it: whether the arm has stopped is "
            "unknown",
            STOP_UNANSWERED_S,
            why,
        )

    def _answer(self) -> Answer:
        """The service's answer, else the topic's outcome of a copy; `NoOutcome` if none."""
        for future in self._futures:
            if future.done() and future.result() is not None:
                response = future.result()
                return Answer("stop", bool(response.success), str(response.message), self.name)
        if self._told:
            told = self._told[0]
            message = told.reason or f"stop: {told.result.value}"
            return Answer("stop", told.ok, message, self.way.topic, False)
        raise NoOutcome(
            f"stop: no answer from {self.name} or {self.way.topic} within {self.timeout:g} s "
            "(whether the server obeyed is unknown)"
        )

    def _unfound(self) -> NoOutcome | NoServer:
        """No server found to answer the stop within `wait_s`: `NoServer` where its copies
        reached nobody, `NoOutcome` where one went out while a reader of the topic was
        matched (something may have obeyed: whether the arm stopped is unknown)."""
        wait_s = self.way.wait_s
        if not self._reached:
            return NoServer(f"stop: reached nobody: {self.way.no_server(self.name, wait_s)}")
        return NoOutcome(
            f"stop: sent {len(self._copies)} times on {self.way.topic}, which a reader took, "
            f"but no al5d server was found within {wait_s:g} s to answer it (whether the "
            "arm has stopped is unknown)"
        )
