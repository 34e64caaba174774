"""What the arm's protocol (`core.Core`) hands back for its callers to do outside its lock.

An event decides under the core's lock and returns one of these: a move's admission, a
STOP to write, the jobs it ended (their outcomes to set, a board to close), the worker's
next task. The state changes it made are announced afterwards, in the order they were
made (`Announcer`): the log lines (INF01, INF02) and the state listeners.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import Enum
from typing import TypeVar

from al5d.arm.instruction import Result
from al5d.arm.jobs import Job, Motion, finish
from al5d.arm.states import Event, State, Task
from al5d.clock import Deadline
from al5d.ssc32u.driver import SSC32U

log = logging.getLogger("al5d")
T = TypeVar("T")


def tell(listeners: Iterable[Callable[[T], None]], value: T, what: str) -> None:
    """Hand `value` to every listener; one that raises is logged and the rest still hear it.

    Listeners run in the driver's threads (the worker's among them): a failing one
    must never stop a move from completing or a state from being announced.
    """
    for listener in list(listeners):
        try:
            listener(value)
        except Exception:
            log.exception("%s listener %r failed; the driver goes on", what, listener)


class Verdict(Enum):
    """What became of a move at its admission."""

    QUEUED = "waits for the worker"
    WRITE = "the caller writes its first step now (an idle arm)"
    REFUSED = "refused"
    CANCELLED = "cancelled by an event after it was sent"
    UNCHANGED = "a set-point where the arm is, or is going already: nothing to write"
    SUPERSEDES = "a set-point takes the running one's place: the worker writes it next"


@dataclass(frozen=True, slots=True)
class Admission:
    verdict: Verdict
    reason: str = ""
    board: SSC32U | None = None  # with WRITE
    #: A set-point of the same stream that waited, replaced by this one (its outcome is
    #: the caller's to set).
    replaced: Job | None = None
    #: With SUPERSEDES: the running set-point it took the place of (its outcome is the
    #: caller's to set, as a replaced one's).
    superseded: Job | None = None


@dataclass(frozen=True, slots=True)
class Ended:
    """Jobs an event has ended, whose outcomes its caller sets (outside the lock), and a
    board it has let go of, for the caller to close."""

    jobs: tuple[Job, ...] = ()
    reason: str = ""
    board: SSC32U | None = None

    def settle(self) -> None:
        """Outside the lock: close the board let go of, and cancel every job ended."""
        if self.board is not None:
            self.board.close()
        for job in self.jobs:
            finish(job, Result.CANCELLED, self.reason)


@dataclass(frozen=True, slots=True)
class Halt:
    """A STOP to write outside the lock (`board` None: no board to write it on)."""

    board: SSC32U | None
    channels: tuple[int, ...]
    ended: Ended
    #: An emergency stop's (written at once); a cancelled move's waits for the wire's turn.
    urgent: bool = True


@dataclass(frozen=True, slots=True)
class Work:
    """The worker's next task, with its job where it has one."""

    task: Task
    job: Job | None = None


@dataclass(frozen=True, slots=True)
class LinkView:
    """What a link check needs to judge the pulse it reads back: the joint written least
    recently, where the driver believes it is, and a token that tells whether a caller's
    write began while the check asked (None: one is under way now)."""

    joint: str
    pose: float
    motion: Motion | None
    way: tuple[float, float] | None
    token: int | None


class Announcer:
    """The state changes, logged (INF01, INF02) and told to the state listeners outside the
    core's lock, in the order they were made, whichever thread announces them."""

    def __init__(self, listeners: list[Callable[[State], None]], first: State) -> None:
        self._listeners = listeners
        self._notes: list[tuple[Event, State, State]] = []
        self._notes_lock = threading.Lock()  # taken inside the core's lock, never around it
        self._announcing = threading.Lock()
        self._cv = threading.Condition()
        self._announced = first  # the state last logged and told

    @property
    def announced(self) -> State:
        return self._announced

    def note(self, event: Event, old: State, new: State) -> None:
        """A transition made (under the core's lock), to announce."""
        with self._notes_lock:
            self._notes.append((event, old, new))

    def announce(self) -> None:
        """Log the transitions noted so far and tell the listeners, in order."""
        if not self._notes:  # read without the lock: a note made meanwhile is its maker's
            return
        with self._announcing:
            with self._notes_lock:
                notes, self._notes = self._notes, []
            for event, old, new in notes:
                log.debug("EVENT: %s", event.value)
                if new is not old:
                    log.info("STATE: %s", new.value)
                    tell(self._listeners, new, "state")
                with self._cv:
                    self._announced = new
                    self._cv.notify_all()

    def wait(self, state: State, timeout: float, now_in: Callable[[], State]) -> None:
        """Until `state` has been announced; TimeoutError (saying `now_in()`) after `timeout`."""
        deadline = Deadline(timeout)
        with self._cv:
            while self._announced is not state:
                if deadline.expired:
                    raise TimeoutError(
                        f"state {state.value} not reached in {timeout} s (now {now_in().value})"
                    )
                self._cv.wait(deadline.left())
