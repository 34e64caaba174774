"""A client's way to a server on this machine: its local lane (`al5d.owner.client.Remote`: no
discovery, no DDS), opened again when it has closed and a server takes it; and `Way`, what
`al5d.ros.client.Client` needs of either of its ways (the other: `al5d.ros.rosway.RosWay`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

from al5d.arm.instruction import Instruction, Kind, Outcome
from al5d.clock import Deadline
from al5d.interrupts import ctrl_c_after
from al5d.owner import quick, where
from al5d.owner.client import WELCOME_S, LaneClosed, Remote
from al5d.owner.lane import outcome_in
from al5d.ros.answers import (
    ANSWER_MIN_S,
    GIVE_UP_WORD_S,
    SILENCE_SAID_S,
    Answer,
    LaneLost,
    NoOutcome,
    NoServer,
    elsewhere,
    no_outcome,
    said_late,
    wait_ms,
)
from al5d.ros.names import Names
from al5d.ros.reading import ArmView, follow_lane

if TYPE_CHECKING:
    from al5d.arm.config import ArmConfig

log = logging.getLogger("al5d")

#: A wait for an outcome looks at the owner's silence this often (`LaneWay._silence`).
WATCH_EVERY_S = 0.25
#: A lane found closed is tried again this often while a call waits for its server.
REOPEN_EVERY_S = 0.1
#: The least a new client waits for the owner's welcome, whatever its `wait_s`: an idle
#: owner welcomes in milliseconds, a loaded one may take a second.
WELCOME_MIN_S = 3.0


class Way(Protocol):
    """How a client reaches its server: by the local lane (`LaneWay`), or over ROS 2
    (`al5d.ros.rosway.RosWay`). `Client` says what each call means."""

    via: str
    discovery_s: float
    matched: bool

    def wait_for_server(self, timeout: float) -> None: ...
    def no_server(self, name: str, timeout: float) -> NoServer: ...
    def lost_contact(self) -> float | None: ...
    def out_of_contact(self) -> str | None: ...
    def send(self, instr: Instruction, wait_s: float) -> None: ...
    def watch(self, ident: str, watcher: Callable[[Outcome], None]) -> None: ...
    def outcome(self, ident: str, timeout: float) -> Outcome | None: ...
    def execute(self, instr: Instruction, timeout: float) -> Outcome: ...
    def forget(self, ident: str) -> None: ...
    def sent(self, ident: str) -> bool: ...
    def pending(self) -> list[str]: ...
    def cancel(self, ident: str, reason: str) -> bool: ...
    def config(self) -> ArmConfig: ...
    def view(self) -> ArmView: ...
    def ask(self, kind: Kind, timeout: float) -> Answer: ...
    def close(self, halt: str = "") -> None: ...


class LaneWay:
    """A client's way to a server on this machine: its local lane (`Remote`: no discovery,
    no DDS), opened by `connect`. Each instruction's outcome is a future. A lane that
    closed (its server ended) is opened again by the next call once a server is there
    (one started again): what was in flight on the old one is unknown, and said so
    (`LaneLost`); `wait_s`: how long a call waits for that server."""

    matched = True
    discovery_s = 0.0

    def __init__(self, connect: Callable[[float], Remote], names: Names, wait_s: float) -> None:
        self._connect = connect
        # Within the client's own wait for a server, not the owner's (a stalled one: an
        # outside try's `al5d send --wait 2` waited 10 s).
        self.lane = connect(max(wait_s, WELCOME_MIN_S))
        self.names = names
        self.wait_s = wait_s
        self.via = f"the local lane {where.path(names.namespace)}"
        self._futures: dict[str, Future[Outcome]] = {}
        #: Watched before they are sent: told once they are.
        self._watchers: dict[str, Callable[[Outcome], None]] = {}
        self._view: ArmView | None = None
        self._reopening = threading.Lock()
        self._closed = False
        #: Each instruction sent: its name and when its sender gives up on it (monotonic).
        self._waits: dict[str, tuple[str, float]] = {}
        #: The silence said (`_silence`: once each, by its lane and first sign unanswered).
        self._silence_said: tuple[Remote, float] | None = None
        self._said_lock = threading.Lock()

    def _open(self, what: str, patience: float) -> Remote:
        """The lane for `what` (an instruction's name), opened again if it has closed and a
        server takes it within `patience` s (an outside try: a client stayed dead after
        its server was started again, its stop refused as "the lane to the owner is
        closed" for as long as it ran). Raises `NoServer` where none does: nothing sent."""
        deadline = Deadline(patience)
        reopened = False
        lost_why = self.lane.lost_why  # the old lane's, if the owner said why it closed it
        if self._reopening.acquire(timeout=max(patience, 0.0)):
            try:
                while self.lane.closed.is_set() and not self._closed:
                    try:
                        lane = self._connect(max(min(WELCOME_S, deadline.left()), 0.1))
                    except LaneClosed:
                        if deadline.expired:
                            break
                        time.sleep(min(REOPEN_EVERY_S, max(deadline.left(), 0.0)))
                        continue
                    if self._closed:  # closed meanwhile: the new lane is not kept
                        lane.close()
                        break
                    self.lane, reopened = lane, True
            finally:
                self._reopening.release()
        lane, view = self.lane, self._view
        if reopened and lost_why:
            log.warning(
                "the server had taken this client for lost (%s) and closed its lane; opened "
                "again: it halted what this client had commanded",
                lost_why,
            )
        elif reopened:
            log.warning(
                "the server's lane had closed (the server ended); opened again: what was "
                "in flight on the old one is unknown"
            )
            if view is not None:  # outside the lock: the view's listeners may call back
                follow_lane(lane, view)
        if lane.closed.is_set():
            raise NoServer(
                f"{what}: not sent: the lane to the server is closed and no al5d server took "
                f"it again within {patience:g} s ({where.path(self.names.namespace)})"
            )
        return lane

    def reopen(self, patience: float) -> None:
        """The lane opened again if it has closed and a server takes it within `patience` s
        (`_open`); NoServer where none does."""
        self._open("the arm's news", patience)

    def wait_for_server(self, timeout: float) -> None:
        pass  # the lane answered when it was opened

    def no_server(self, name: str, timeout: float) -> NoServer:
        return NoServer(
            f"no al5d server answers on {name} within {timeout:g} s{elsewhere(self.names, None)}"
        )

    def lost_contact(self) -> float | None:
        return None  # a lane that closes ends what waits on it (`LaneLost`)

    def out_of_contact(self) -> str | None:
        if not self.lane.closed.is_set():
            return None
        if why := self.lane.lost_why:  # the server goes on: it took this client for lost
            return f"the server took this client for lost ({why}) and closed its lane"
        return "the server on this machine closed its lane (it ended or restarted)"

    def send(self, instr: Instruction, wait_s: float) -> None:
        lane = self._open(f"{instr.name} [{instr.id}]", self.wait_s)
        instr = replace(instr, wait_ms=wait_ms(wait_s))
        with ctrl_c_after():
            future = self._futures[instr.id] = lane.submit(instr)
            # 0: waited for for ever (`wait_ms`), so never given up on.
            give_up = time.monotonic() + wait_s if instr.wait_ms else math.inf
            self._waits[instr.id] = (instr.name, give_up)
            watcher = self._watchers.pop(instr.id, None)
            if watcher is not None:
                _watch(future, watcher)

    def watch(self, ident: str, watcher: Callable[[Outcome], None]) -> None:
        future = self._futures.get(ident)
        if future is not None:
            _watch(future, watcher)
        else:
            self._watchers[ident] = watcher

    def outcome(self, ident: str, timeout: float) -> Outcome | None:
        future = self._futures.get(ident)
        if future is None:
            return None
        try:
            return self._result(future, timeout, ident)
        except LaneClosed as e:
            # The owner's word on why, where it said it, holds what became of it.
            said = "" if self.lane.lost_why else ": whether it ran is unknown"
            raise LaneLost(f"[{ident}]: {e}{said}") from None

    def _result(
        self, future: Future[Outcome], timeout: float, ident: str, name: str = "instruction"
    ) -> Outcome | None:
        """`future`'s outcome (of instruction `ident`) within `timeout` s, else None; the
        owner's silence said meanwhile (`_silence`)."""
        deadline = Deadline(timeout)
        while True:
            with contextlib.suppress(FutureTimeout):
                outcome = future.result(max(min(deadline.left(), WATCH_EVERY_S), 0.0))
                with self._said_lock:  # the owner spoke: what follows says a silence over
                    self._silence_said = None
                return outcome
            self._silence(ident, name)  # also for a glance (`LinkWatch`'s at a background line)
            if deadline.expired:
                return None

    def _silence(self, ident: str, name: str) -> None:
        """A silence of the owner (`Remote.quiet`) said at once, a WARNING once an outage,
        while `ident` waits: a frozen server's lane stays open and says nothing (an outside
        try: a client's move waited 16.5 s without a word). The wait goes on: the owner
        gives the move up at its sender's deadline (`Instruction.wait_ms`), however late
        it turns again."""
        lane = self.lane
        name, give_up = self._waits.get(ident, (name, math.inf))
        # Under the lock: a look that read the silence before another said it over would
        # say it again.
        with self._said_lock:
            since = lane.unanswered  # read once: this silence's, which is said once
            quiet = lane.quiet()
            said, over = self._silence_said, None
            if said is not None and (said[0] is not lane or said[1] != since):
                self._silence_said = None  # only the owner's word moves it on
                if said[0] is lane:
                    over = lane.silence
            warn = False
            if since is not None and (quiet or 0.0) > SILENCE_SAID_S and not self._silence_said:
                self._silence_said, warn = (lane, since), True
        if said is not None and over is not None:
            after = f", after {over[1] - said[1]:.1f} s" if over[0] == said[1] else ""
            log.warning(
                "%s [%s]: the server on this machine's lane answers again%s; still waiting",
                name,
                ident,
                after,
            )
        if not warn:
            return
        left = give_up - time.monotonic()
        if left == math.inf:
            then = ""
        elif left > 0:
            then = f", up to {left:.1f} s more: the server does not go on with it after that"
        else:  # said in the margin after its sender's wait (`GIVE_UP_WORD_S`)
            then = ": its sender's wait is over, and the server gives it up as it turns again"
        log.warning(
            "%s [%s]: no word from the server on this machine's lane for %.1f s (busy or "
            "stalled: a frozen process?); still waiting%s",
            name,
            ident,
            quiet,
            then,
        )

    def execute(self, instr: Instruction, timeout: float) -> Outcome:
        self.send(instr, timeout)
        try:
            outcome = self.outcome(instr.id, timeout + GIVE_UP_WORD_S)
        except LaneLost as e:
            self.forget(instr.id)
            raise LaneLost(f"{instr.name} {e}") from None
        # Kept on Ctrl-C (KeyboardInterrupt), which cancels what is pending.
        self.forget(instr.id)
        if outcome is None:
            raise no_outcome(f"{instr.name} [{instr.id}]", timeout)
        return outcome

    def forget(self, ident: str) -> None:
        self._futures.pop(ident, None)
        self._waits.pop(ident, None)

    def sent(self, ident: str) -> bool:
        return ident in self._futures

    def pending(self) -> list[str]:
        return [ident for ident, f in self._futures.items() if not f.done()]

    def cancel(self, ident: str, reason: str) -> bool:
        return self.lane.cancel(ident, reason)

    def config(self) -> ArmConfig:
        return self.lane.config

    def view(self) -> ArmView:
        view = ArmView(self.lane.config.model, live=lambda: self.lane.positions())
        follow_lane(self.lane, view)
        self._view = view
        return view

    def ask(self, kind: Kind, timeout: float) -> Answer:
        deadline, instr = Deadline(timeout), Instruction(kind)
        outcome = self._stop(deadline, instr.id, timeout) if kind is Kind.STOP else None
        if outcome is None:  # not a stop, or one whose connection of its own was not taken
            lane = self._open(kind.value, timeout)
            name = f"{kind.value} [{instr.id}]"
            unknown = "whether the server obeyed is unknown"
            future = self._hand(lane, instr, deadline, name, timeout)
            try:
                # A lane opened again late in the wait still gives the answer its moment.
                answer = self._result(
                    future, max(deadline.left(), ANSWER_MIN_S), instr.id, kind.value
                )
            except LaneClosed as e:
                raise NoOutcome(f"{name}: {e} ({unknown})") from None
            if answer is None:
                if kind is Kind.STOP:  # obeyed however late: said if its answer comes
                    _said_when_late(future, instr.id, deadline.at - timeout)
                raise NoOutcome(
                    f"{name}: no answer on the local lane within {timeout:g} s ({unknown})"
                )
            outcome = answer
        message = outcome.reason or f"{kind.value}: {outcome.result.value}"
        return Answer(kind.value, outcome.ok, message, "the local lane", ident=outcome.id)

    @staticmethod
    def _hand(
        lane: Remote, instr: Instruction, deadline: Deadline, name: str, timeout: float
    ) -> Future[Outcome]:
        """`instr` handed to the owner on this client's lane within `deadline`: its outcome's
        future. Raises NoOutcome where it is not: the lane's buffer full behind another
        thread's send (a trajectory's bytes) to an owner that reads nothing (frozen), its
        send still waiting to go."""
        handed: list[Future[Outcome]] = []
        sender = threading.Thread(
            target=lambda: handed.append(lane.submit(instr)), name="al5d-hand", daemon=True
        )
        sender.start()
        sender.join(max(deadline.left(), ANSWER_MIN_S))  # as the answer's wait
        if not handed:
            raise NoOutcome(
                f"{name}: not handed over within {timeout:g} s: this client's lane to the "
                "server is full (the server busy or stalled); it goes when the server reads "
                "the lane"
            )
        return handed[0]

    def _stop(self, deadline: Deadline, ident: str, timeout: float) -> Outcome | None:
        """The stop `ident` on a connection of its own (`quick.hand_stop`), as the web view's
        and `al5d send stop`'s: not behind what this client's lane carries (a trajectory's
        bytes on their way, another thread's send holding the lane). A server started
        again meanwhile takes it: the lane is looked for again until `deadline`. None
        where the server takes no new connection (`quick.LaneFull`: busy or stalled): this
        client's own connection, taken long since, is then the way."""
        path = where.path(self.names.namespace)
        asked = time.monotonic()
        try:
            while (sock := quick.hand_stop(path, ident, max(deadline.left(), 0.1))) is None:
                if deadline.expired or self._closed:
                    raise NoServer(
                        f"stop: not sent: no al5d server takes its lane within {timeout:g} s "
                        f"({path})"
                    )
                time.sleep(REOPEN_EVERY_S)
            left = max(deadline.left(), ANSWER_MIN_S)

            def unanswered() -> None:
                log.warning(
                    "stop [%s]: no answer in %g s by the local lane (the server busy or "
                    "stalled); still waiting, up to %.1f s more: whether the arm has stopped "
                    "is unknown",
                    ident,
                    quick.UNANSWERED_S,
                    left - quick.UNANSWERED_S,
                )

            def late(answer: dict[str, object]) -> None:
                try:
                    told = outcome_in(answer)
                except ValueError:  # garbled: nothing to tell of it
                    return
                after = time.monotonic() - asked
                said_late(ident, after, told.ok, told.result.value, told.reason)

            outcome = outcome_in(quick.answer(sock, left, unanswered, late))
        except quick.LaneFull as e:
            log.warning("stop [%s]: %s; it goes on this client's own connection to it", ident, e)
            return None
        except TimeoutError:
            raise NoOutcome(
                f"stop [{ident}]: no answer on the local lane within {timeout:g} s (whether the "
                "server obeyed is unknown; it obeys a stop however late it takes it, and this "
                "client says so if the answer comes)"
            ) from None
        except (OSError, EOFError, ValueError) as e:  # a garbled answer: LaneError, JSON's
            raise NoOutcome(
                f"stop [{ident}]: no answer on the local lane: {e} (whether the server obeyed "
                "is unknown)"
            ) from None
        # The client's own lane, closed by a server that ended, is opened again to the one
        # that answered, as any call opens it (its reads hear the stopped arm).
        with contextlib.suppress(NoServer):
            self._open("stop", ANSWER_MIN_S)
        return outcome

    def close(self, halt: str = "") -> None:
        self._closed = True
        with self._reopening:
            self.lane.close(bye=not halt, left_by=halt)


def _said_when_late(future: Future[Outcome], stop: str, asked: float) -> None:
    """The answer to the stop `stop` (asked at `asked`, monotonic) said if it comes after
    its client gave up on it (`said_late`), as the stop's own connection's is."""

    def told(done: Future[Outcome]) -> None:
        if done.cancelled() or done.exception() is not None:  # the lane closed: none came
            return
        outcome = done.result()
        after = time.monotonic() - asked
        said_late(stop, after, outcome.ok, outcome.result.value, outcome.reason)

    future.add_done_callback(told)


def _watch(future: Future[Outcome], watcher: Callable[[Outcome], None]) -> None:
    def told(done: Future[Outcome]) -> None:
        if done.exception() is None:
            watcher(done.result())

    future.add_done_callback(told)
