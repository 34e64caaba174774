"""The arm's protocol: the one owner of the driver's state, and every event that changes it.

Threads
-------
Callers (a ROS executor, the command line, a Python program) submit, stop,
release, cancel and shut down. One worker thread (`worker.Worker`) parks, runs
the moves that wait, watches the link, reads the pose back and reconnects. None
of them owns a field of the arm's state: `Core` does. Each public method of it
is one event, handled whole under one lock: it asks the state table
(`states.TABLE`) for the next state, updates the fields, and returns what its
caller must do outside the lock (write a STOP, write a step, hand out outcomes).
The lock is never held during serial I/O, and nothing outside this module
writes a field of it.

The lanes
---------
- **The stop** is taken first, whoever is doing what. `stop` ends the epoch
  (every job of an older epoch is dropped and never written), locks the arm and
  returns the STOP to write; its caller writes it at once, with no hand-over to
  the worker: it waits only for this lock and for the board's write lock, each
  held for microseconds. A step is written only if its job's epoch still holds
  when the step has the board's write lock (`SSC32U.write_command`'s `unless`,
  which reads `epoch` without this lock). So either a step goes out before the
  STOP, which halts it, or it does not go out at all.
- **Moves** are admitted (`admit`) in the order they come. An idle arm's move
  is written at once by its caller (the fast path: no thread hand-over), which
  then hands the job to the worker to see it through (`first_written`). Others
  wait in the queue; the worker takes them one at a time (`next_task`), and a
  job is the current one from the moment it is taken until it ends. Only the
  current job's steps are written; whoever ends it (done, stop, cancel, fault,
  shutdown) makes it not current, in one event.
- **The worker's own work** (`next_task`, in this order): the shutdown, the
  recovery from a fault, the start-up park, a job the caller wrote, the
  read-back of the pose after a halt, the next queued move, and a check of
  the idle link. While a caller writes (a fast-path step, a STOP), the worker
  waits for it: what comes next depends on what the write did.

The order across channels
-------------------------
Stops, releases and moves come by several channels (the instruction topic, in
order behind a flood; the services; the stop watcher; actions; Python calls),
so a message can arrive after one sent later. Each instruction carries when it
was sent (`Instruction.sent_ns`: a DDS message's source timestamp, on this
host's CLOCK_REALTIME; when the driver took it, where the channel does not
say). The order of sending, not of arriving, decides:

1. A release unlocks only if it was sent after every stop that holds the lock;
   an older one is refused with a reason naming that stop. So a stop is never
   undone by a release sent before it, whatever the channels.
2. A move sent before the last event that dropped every pending move (a stop,
   a fault, the shutdown) is cancelled by that event, as it would have been had
   it waited in the queue; a move sent between a stop and the release that
   unlocked the arm is refused, as it would have been had it arrived then.
3. A stop that two readers of one topic both see (the node, in order; the stop
   watcher, at once) is one stop: it is known by its message's identity
   (`key`), obeyed once and answered once.

A fault, a board's reset and the shutdown are the driver's own events: they
count as sent when the driver takes them. Clients on other machines are judged
on their own clocks (the server is closed to the network by default).
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict, deque
from collections.abc import Callable, Hashable, Iterable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from enum import Enum
from typing import TypeVar

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome, Result
from al5d.arm.jobs import Job, Mode, Motion, Written, finish, stop_order
from al5d.arm.pose import PoseBook
from al5d.arm.states import (
    Event,
    Guards,
    State,
    Task,
    TransitionError,
    next_state,
    refusal,
    release_refusal,
)
from al5d.clock import Deadline, now, wall_ns
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import BoardReset, SerialFault

log = logging.getLogger("al5d")
T = TypeVar("T")

#: Stop identities remembered, so that a stop both readers see is obeyed once.
STOPS_REMEMBERED = 1024


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


@dataclass(frozen=True, slots=True)
class Admission:
    verdict: Verdict
    reason: str = ""
    board: SSC32U | None = None  # with WRITE


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


class Runner(Enum):
    """Who runs the current job."""

    CALLER = "its caller writes its first step"
    HANDED = "written by its caller, for the worker to see through"
    WORKER = "the worker"


class Core:
    """Every field of one arm's driver, and the events that change them (see the module)."""

    def __init__(self, config: ArmConfig, state_listeners: list[Callable[[State], None]]) -> None:
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._channels = {name: j.channel for name, j in config.joints.items()}
        self._capacity = config.server.queue_capacity
        self._state_listeners = state_listeners
        self._announce_lock = threading.Lock()
        self._notes: list[tuple[Event, State, State]] = []
        self._state = State.INITIALIZING
        self._announced = State.INITIALIZING  # the state last logged and told
        self._locked = False  # a stop (or a board's reset) and no release since
        self._epoch = 0  # counts the events that dropped every pending move
        self._queue: deque[Job] = deque()
        self._current: Job | None = None
        self._runner: Runner | None = None
        self._board: SSC32U | None = None
        self._fault: SerialFault | None = None
        #: The pose is to be read back from the board (after a halt): nothing is written
        #: until it has been, or the pose read would be a snapshot of a motion.
        self._readback = False
        self._shutdown: Job | None = None
        self._shutdown_taken = False  # the worker has begun the shutdown
        self._parked = False  # the start-up park has been done
        self._book = PoseBook(config.joints)
        #: Writes from a caller's thread (a fast-path step, a STOP) begun, and under way: a
        #: link check or a read-back judges what it reads only if none began meanwhile.
        self._writes = 0
        self._writing = 0
        #: The order across channels (see the module), in sending times (CLOCK_REALTIME ns):
        #: of the last event that dropped every pending move, and why; of the last stop (or
        #: reset) that holds the lock, and what it was; and of the last release.
        self._dropped_ns = -1
        self._dropped_why = ""
        self._locked_ns = -1
        self._locked_by = ""
        self._released_ns = -1
        self._stops: OrderedDict[Hashable, Future[Outcome]] = OrderedDict()
        #: Set when the worker has ended (after the shutdown, or if it failed).
        self.finished = threading.Event()

    # -- reading (a snapshot each) -----------------------------------------------------

    @property
    def state(self) -> State:
        return self._state

    @property
    def locked(self) -> bool:
        return self._locked

    @property
    def epoch(self) -> int:
        """Read without the lock (one int) by a step's last check under the write lock."""
        return self._epoch

    @property
    def board(self) -> SSC32U | None:
        return self._board

    @property
    def shutdown_job(self) -> Job | None:
        return self._shutdown

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles (degrees; NaN where unknown since power-up)."""
        with self._lock:
            return self._book.positions(t)

    def pose(self) -> dict[str, float | None]:
        """The pose at rest, as a step is planned from it."""
        with self._lock:
            return self._book.pose

    def progress(self, ident: str) -> float | None:
        """0..1 of the running job `ident` (by its steps), or None if it is not running."""
        with self._lock:
            job, motion = self._current, self._book.motion
            if job is None or motion is None or job.instr.id != ident or not job.steps:
                return None
            return (job.step + motion.progress(now())) / len(job.steps)

    def q_believed(self) -> bool:
        with self._lock:
            return self._book.q_believed(now())

    def link_view(self) -> LinkView | None:
        """What the next link check reads back and judges (None: no pose is known)."""
        with self._lock:
            joint = self._book.stalest()
            if joint is None:
                return None
            pose = self._book.known(joint)
            assert pose is not None
            return LinkView(
                joint,
                pose,
                self._book.motion,
                self._book.way(joint, now()),
                None if self._writing else self._writes,
            )

    def untouched(self, token: int | None) -> bool:
        """No caller's write began since `token` was taken (and none was under way then)."""
        with self._lock:
            return token is not None and token == self._writes and not self._writing

    # -- the state machine -------------------------------------------------------------

    def _guards(self) -> Guards:
        running = self._current is not None and self._current.mode is Mode.QUEUE
        return Guards(
            queue_empty=not self._queue and not running, locked=self._locked, parked=self._parked
        )

    def _fire(self, event: Event) -> State:
        old = self._state
        new = next_state(old, event, self._guards())
        if new is None:
            raise TransitionError(f"no transition from {old.value} on {event.value}")
        self._state = new
        self._notes.append((event, old, new))
        self._cv.notify_all()
        return new

    def announce(self) -> None:
        """Log the transitions made so far (INF01, INF02) and tell the listeners, in order."""
        if not self._notes:  # read without the lock: a note made meanwhile is its maker's
            return
        with self._announce_lock:
            with self._lock:
                notes, self._notes = self._notes, []
            for event, old, new in notes:
                log.debug("EVENT: %s", event.value)
                if new is not old:
                    log.info("STATE: %s", new.value)
                    tell(self._state_listeners, new, "state")
                with self._cv:
                    self._announced = new
                    self._cv.notify_all()

    def wait_announced(self, state: State, timeout: float) -> None:
        deadline = Deadline(timeout)
        with self._cv:
            while self._announced is not state:
                if deadline.expired:
                    raise TimeoutError(
                        f"state {state.value} not reached in {timeout} s (now {self._state.value})"
                    )
                self._cv.wait(deadline.left())

    @property
    def announced(self) -> State:
        return self._announced

    # -- helpers (lock held) -----------------------------------------------------------

    def _idle(self) -> bool:
        """At rest on a board: nothing runs, is written, waits or is to be read back."""
        return (
            self._state is State.READY
            and self._board is not None
            and self._current is None
            and not self._queue
            and not self._readback
            and not self._writing
        )

    def _drop(self, why: str, sent_ns: int) -> Ended:
        """End the epoch: the current job and every waiting one are never to be written. The
        shutdown's park is left to the worker, which reports it. `sent_ns`: when the event
        that drops them was sent."""
        self._epoch += 1
        if sent_ns >= self._dropped_ns:
            self._dropped_ns, self._dropped_why = sent_ns, why
        jobs = list(self._queue)
        self._queue.clear()
        current, self._current, self._runner = self._current, None, None
        if current is not None:
            current.cancel.set()
            if current is not self._shutdown:
                jobs.insert(0, current)
        return Ended(tuple(jobs), why)

    def _halt(self, ended: Ended) -> Halt:
        """A STOP of every channel, the moving joints first (lock held; written outside)."""
        t = now()
        channels = tuple(stop_order(self._book.motion, t, self._channels))
        self._book.halted(t)
        self._writes += 1
        self._writing += 1
        self._readback = True
        return Halt(self._board, channels, ended)

    def _lock_arm(self, by: str, sent_ns: int) -> None:
        """Lock (or keep locked), by an event sent at `sent_ns`: a release must be sent later."""
        if not self._locked or sent_ns >= self._locked_ns:
            self._locked_ns, self._locked_by = sent_ns, by
        self._locked = True

    def _lose(self, error: SerialFault) -> Ended:
        """The fault: the link is gone (or the board reset); everything pending ends."""
        reset = isinstance(error, BoardReset)
        self._fault = error
        t = wall_ns()
        if reset:
            # A safety event: nothing moves again until a person has looked at the arm.
            self._lock_arm("the board's reset", t)
            self._book.forget()
        board, self._board = self._board, None
        why = str(error) if reset else f"the serial link is lost: {error}"
        ended = self._drop(why, t)
        self._book.lost()
        self._readback = False  # reconnecting reads the pose back
        if self._state is not State.FAULT:
            self._fire(Event.SERIAL_FAULT)
        return Ended(ended.jobs, why, board)

    def _end_current(self, job: Job, completed: bool = False) -> bool:
        """The current job ends (completed: its last step is done); False if it was not
        current (an event ended it before)."""
        if job is not self._current:
            return False
        self._current, self._runner = None, None
        if job.mode is Mode.STARTUP and completed:
            self._parked = True
            self._fire(Event.MOVE_DONE)
        elif job.mode is Mode.QUEUE and self._state is State.MOVING:
            self._fire(Event.MOVE_DONE)
        self._cv.notify_all()
        return True

    # -- callers' events ----------------------------------------------------------------

    def admit(self, job: Job) -> Admission:
        """A validated move comes: it is cancelled, refused, queued, or written now."""
        with self._lock:
            if job.sent_ns < self._dropped_ns:
                return Admission(Verdict.CANCELLED, f"{self._dropped_why} (it was sent before)")
            reason = (
                "the server is shutting down"
                if self._shutdown is not None
                else refusal(self._state, self._fault)
            )
            if not reason and job.sent_ns < self._released_ns:
                reason = (
                    f"it was sent while the arm was locked ({self._locked_by}), before the "
                    "release: send it again"
                )
            if reason:
                return Admission(Verdict.REFUSED, reason)
            job.epoch = self._epoch
            if self._idle():
                self._current, self._runner = job, Runner.CALLER
                self._writes += 1
                self._writing += 1
                self._fire(Event.MOVE)
                return Admission(Verdict.WRITE, board=self._board)
            if len(self._queue) >= self._capacity:
                return Admission(
                    Verdict.REFUSED, f"the queue is full ({self._capacity} moves wait)"
                )
            self._queue.append(job)
            if self._state is State.READY:
                self._fire(Event.MOVE)
            if len(self._queue) == 1:  # the worker may wait for one; it takes the rest in turn
                self._cv.notify_all()
            return Admission(Verdict.QUEUED)

    def first_written(
        self, job: Job, written: Written | None, error: SerialFault | None = None
    ) -> tuple[Motion | None, Ended]:
        """The caller has written (or not) the first step of the job `admit` gave it: the
        worker sees it through from here. The motion on the board, and what a fault ended."""
        with self._cv:
            self._writing -= 1
            self._cv.notify_all()
            if error is not None:
                return None, self._lose(error)
            motion = self._written(job, written) if written is not None else None
            if motion is not None:
                self._runner = Runner.HANDED
            elif job is self._current:  # nothing of it went out, and nothing ended it: it ends
                self._end_current(job)
            return motion, Ended()

    def stop(
        self, future: Future[Outcome], sent_ns: int, key: Hashable | None = None
    ) -> Halt | Future[Outcome]:
        """The emergency stop (sent at `sent_ns`): drop everything, lock, and the STOP to write
        at once. A stop already obeyed under the same `key` is not obeyed again: its future
        comes back."""
        with self._lock:
            if key is not None:
                known = self._stops.get(key)
                if known is not None:
                    return known
                self._stops[key] = future
                if len(self._stops) > STOPS_REMEMBERED:
                    self._stops.popitem(last=False)
            ended = self._drop("cancelled by stop", sent_ns)
            self._lock_arm("the stop", sent_ns)
            halt = self._halt(ended)
            self._fire(Event.STOP)
            return halt

    def halt_written(self, error: SerialFault | None) -> Ended:
        """A STOP (a stop's or a cancel's) has been written, or could not be: a fault then."""
        with self._cv:
            self._writing -= 1
            self._cv.notify_all()
            if error is None or self._board is None:
                return Ended()
            return self._lose(error)

    def release(self, sent_ns: int) -> str:
        """Unlock (a release sent at `sent_ns`); the reason it cannot, or ""."""
        with self._lock:
            state = self._state
            if next_state(state, Event.RELEASE, self._guards()) is None:
                return release_refusal(state)
            if sent_ns < self._locked_ns:
                return (
                    f"this release was sent before {self._locked_by} that locked the arm: "
                    "the arm stays locked; send release again to unlock it"
                )
            self._fire(Event.RELEASE)
            self._locked = False
            self._released_ns = max(self._released_ns, sent_ns)
            return ""

    def cancel(self, ident: str) -> Job | Halt | None:
        """Cancel one move: a waiting one is dropped (it comes back); a running one is halted
        where it is, without the lock (its STOP comes back). None if it is not here."""
        with self._lock:
            job = next((j for j in self._queue if j.instr.id == ident), None)
            if job is not None:
                self._queue.remove(job)
                if self._current is None and not self._queue and self._state is State.MOVING:
                    self._fire(Event.MOVE_DONE)
                return job
            job = self._current
            if job is None or job.instr.id != ident or job.mode is not Mode.QUEUE:
                return None
            job.cancel.set()
            halt = self._halt(Ended((job,)))
            self._end_current(job)
            return halt

    def shutdown(self, job: Job) -> Ended | None:
        """Park and end: everything pending ends; None if a shutdown is under way already."""
        with self._lock:
            if self._shutdown is not None:
                return None
            ended = self._drop("cancelled by shutdown", job.sent_ns)
            job.epoch = self._epoch
            self._shutdown = job
            self._fire(Event.SHUTDOWN)
            return ended

    # -- the worker's events ------------------------------------------------------------

    def next_task(self, watch_every: float) -> Work:
        """The worker's next task (waits for one), in the order of the module's docstring;
        WATCH when the arm has been idle on a board for `watch_every` seconds."""
        idle = Deadline(watch_every)
        with self._cv:
            while True:
                work = self._choose(idle.expired)
                if work is not None:
                    return work
                if idle.expired:
                    idle = Deadline(watch_every)
                self._cv.wait(idle.left())

    def _choose(self, idle: bool) -> Work | None:
        if self._shutdown is not None and not self._shutdown_taken:
            self._shutdown_taken = True
            return Work(Task.SHUTDOWN, self._shutdown)
        if self._state is State.FAULT:
            return Work(Task.RECOVER)
        if self._writing:
            return None  # a caller writes: what it did decides what comes next
        if self._current is not None:
            if self._runner is not Runner.HANDED:
                return None
            self._runner = Runner.WORKER
            return Work(Task.FOLLOW, self._current)
        if self._state is State.INITIALIZING and not self._parked:
            return Work(Task.STARTUP)
        if self._readback:
            return Work(Task.READBACK)
        if self._queue and self._state is not State.INITIALIZING:
            job = self._queue.popleft()
            self._current, self._runner = job, Runner.WORKER
            return Work(Task.MOVE, job)
        if idle and self._board is not None:
            return Work(Task.WATCH)
        return None

    def start(self, job: Job) -> SSC32U | None:
        """The worker's own park (at start-up or shutdown) becomes the current job: the
        board to run it on, or None if an event since it was made has ended it."""
        with self._lock:
            board = self._board
            if job.epoch != self._epoch or job.cancel.is_set() or board is None:
                return None
            if self._state not in job.mode.states or self._current is not None:
                return None
            self._current, self._runner = job, Runner.WORKER
            return board

    def board_for(self, job: Job) -> SSC32U | None:
        """The board to write the job's next step on; None if the job has been ended."""
        with self._lock:
            if job is not self._current or job.epoch != self._epoch or job.cancel.is_set():
                return None
            return self._board

    def step_written(self, job: Job, written: Written) -> Motion | None:
        """A step's bytes went out: the motion on the board, or None if the job was ended
        meanwhile (then a STOP came after the bytes and halted them)."""
        with self._lock:
            return self._written(job, written)

    def _written(self, job: Job, written: Written) -> Motion | None:
        if job is not self._current or job.epoch != self._epoch or job.cancel.is_set():
            # Q answers "moving" until this step's time is over, even halted (UG-38).
            self._book.distrust_q(written.motion)
            return None
        motion = self._book.moving(written.motion, written.t_write)
        self._book.written(motion, written.t_end)
        job.written = written
        return motion

    def reached(self, job: Job, target: Mapping[str, float]) -> bool:
        """A step's time is over (and, for the last, `Q` said done); False if ended meanwhile."""
        with self._lock:
            if job is not self._current or job.epoch != self._epoch:
                return False
            self._book.reached(target)
            return True

    def done(self, job: Job) -> bool:
        """The job has completed (its outcome is DONE); False if it was ended meanwhile."""
        with self._lock:
            if job is not self._current or job.epoch != self._epoch or job.cancel.is_set():
                return False
            self._book.at_rest()
            return self._end_current(job, completed=True)

    def let_go(self, job: Job) -> bool:
        """The job ends without completing (refused at its start, or its runner found it
        ended): no longer current. True if it still was (its outcome is then the caller's)."""
        with self._lock:
            return self._end_current(job)

    def lose(self, error: SerialFault) -> Ended:
        """A serial fault, seen by any thread: everything pending ends; the board is let go
        (the caller closes it). Nothing more if the fault is known already."""
        with self._lock:
            if self._state is State.FAULT and self._board is None:
                if isinstance(error, BoardReset) and not isinstance(self._fault, BoardReset):
                    self._fault = error
                return Ended()
            return self._lose(error)

    def connected(self, board: SSC32U) -> None:
        with self._lock:
            self._board = board

    def unreachable(self, error: SerialFault) -> None:
        """The board could not be reached (at start, or a device that is not a board at a
        reconnect): the fault's reason, and the state `fault`."""
        with self._lock:
            self._fault = error
            if self._state is not State.FAULT:
                self._fire(Event.SERIAL_FAULT)

    @property
    def fault(self) -> SerialFault | None:
        return self._fault

    def reconnected(self, board: SSC32U, pose: Mapping[str, float | None], reset: bool) -> None:
        """The board is back, its pose read; `reset`: it restarted while the link was down."""
        with self._lock:
            if reset:
                self._lock_arm("the board's reset", wall_ns())
                self._book.forget()
            self._book.read_back(pose)
            self._board = board
            self._fault = None
            self._readback = False
            if self._state is State.FAULT:  # not if a shutdown came meanwhile: it parks now
                self._fire(Event.RECONNECTED)

    def read_token(self) -> int:
        with self._lock:
            return self._writes

    def read_back(self, pose: Mapping[str, float | None], token: int | None) -> bool:
        """The pose read from the board. With `token` (from `read_token` before the read),
        it stands only if no caller's write began meanwhile (else read it again)."""
        with self._cv:
            if token is not None and (token != self._writes or self._writing):
                return False
            self._book.read_back(pose)
            if self._current is None:
                self._readback = False
            self._cv.notify_all()
            return True

    def wait_unless_shutdown(self, timeout: float) -> bool:
        """Sleep `timeout` (a reconnect's interval); False if a shutdown came."""
        with self._cv:
            if self._shutdown is None:
                self._cv.wait(timeout)
            return self._shutdown is None

    def worker_failed(self, error: SerialFault) -> Ended:
        """The worker has died of a bug: everything pending ends (the shutdown too), so that
        nothing waits for an outcome that would never come."""
        with self._lock:
            ended = self._lose(error)
            shutdown = self._shutdown
            if shutdown is not None and shutdown not in ended.jobs:
                ended = Ended((*ended.jobs, shutdown), ended.reason, ended.board)
            return ended

    def worker_ended(self) -> None:
        self.finished.set()
        with self._cv:
            self._cv.notify_all()
