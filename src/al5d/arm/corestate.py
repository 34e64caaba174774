"""The fields of the arm's protocol, what may be read of them, and the steps its events are
made of: the state behind `core.Core`, whose events (`core`) are the only writers.

Everything with a leading underscore here is called by an event, under the core's lock.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from enum import Enum

from al5d.arm.config import ArmConfig
from al5d.arm.effects import Announcer, Ended, Halt, LinkView
from al5d.arm.jobs import Job, Mode, Motion, Written, stop_order
from al5d.arm.order import ChannelOrder
from al5d.arm.pose import PoseBook
from al5d.arm.states import (
    Event,
    Guards,
    State,
    TransitionError,
    next_state,
)
from al5d.clock import now, wall_ns
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import BoardReset, SerialFault


class Runner(Enum):
    """Who runs the current job."""

    CALLER = "its caller writes its first step"
    HANDED = "written by its caller, for the worker to see through"
    WORKER = "the worker"
    NEXT = "took a running set-point's place: the worker writes it as soon as the wire allows"


class CoreState:
    """Every field of one arm's driver (`core.Core` adds the events that change them).

    What it owns besides its own fields, each written only under its lock: the pose
    (`pose.PoseBook`), the sending times the order across channels is judged by
    (`order.ChannelOrder`), and the transitions still to announce (`effects.Announcer`).
    """

    def __init__(self, config: ArmConfig, state_listeners: list[Callable[[State], None]]) -> None:
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._channels = {name: j.channel for name, j in config.joints.items()}
        #: Half a pulse microsecond per joint, in degrees: a set-point closer than this to
        #: where a joint is going writes the same pulse, so it changes nothing.
        self._same_deg = {name: 0.5 / abs(j.us_per_deg) for name, j in config.joints.items()}
        self._capacity = config.server.queue_capacity
        self._state = State.INITIALIZING
        self._announcer = Announcer(state_listeners, self._state)
        self._locked = False  # a stop (or a board's reset) and no release since
        self._epoch = 0  # counts the events that dropped every pending move
        # Why the streams of set-points are held (empty: they are not). A stream's source
        # (ros2_control's hardware) sends its last target again and again while the arm is
        # off it: after a stop, that target must not drive the arm once it is released.
        self._streams_held = ""
        #: When a set-point of each stream last came (CLOCK_MONOTONIC): the watchdog holds
        #: the arm where it is once none has come for `server.stream_timeout_s`.
        self._stream_seen: dict[str, float] = {}
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
        self._order = ChannelOrder()
        #: Writes from a caller's thread (a fast-path step, a STOP) begun, and under way: a
        #: link check or a read-back judges what it reads only if none began meanwhile.
        self._writes = 0
        self._writing = 0
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
    def fault(self) -> SerialFault | None:
        return self._fault

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

    def start_pose(self, job: Job, t: float) -> dict[str, float | None]:
        """The pose a job's step is planned from: the pose at rest, but for a set-point that
        retargets a motion under way (the first step of a job while the board still runs
        the set-point it superseded): where that motion has the arm at `t`, when the new
        bytes take effect."""
        with self._lock:
            pose = self._book.pose
            motion = self._book.motion
            if job.step == 0 and job.stream and motion is not None:
                pose.update(motion.at(t))
            return pose

    def stream_quiet(self, job: Job) -> float:
        """Seconds since a set-point of the job's stream last came, or since the job was
        written if that is later (one that waited behind other moves starts afresh)."""
        with self._lock:
            return self._quiet(job)

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
            return self._book.link_view(now(), self._token())

    def write_token(self) -> int | None:
        """A token of the callers' writes so far, for `untouched` (None: one is under way)."""
        with self._lock:
            return self._token()

    def untouched(self, token: int | None) -> bool:
        """No caller's write began since `token` was taken (and none was under way then)."""
        with self._lock:
            return self._untouched(token)

    # -- the state machine and its announcements -------------------------------------------

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
        self._announcer.note(event, old, new)
        self._cv.notify_all()
        return new

    def announce(self) -> None:
        """Log the transitions made so far (INF01, INF02) and tell the listeners, in order."""
        self._announcer.announce()

    def wait_announced(self, state: State, timeout: float) -> None:
        self._announcer.wait(state, timeout, lambda: self._state)

    @property
    def announced(self) -> State:
        return self._announcer.announced

    # -- helpers (lock held) -----------------------------------------------------------

    def _token(self) -> int | None:
        return None if self._writing else self._writes

    def _untouched(self, token: int | None) -> bool:
        return token is not None and token == self._writes and not self._writing

    def _holds(self, job: Job) -> bool:
        """The job is still the current one, of this epoch, not cancelled."""
        return job is self._current and job.epoch == self._epoch and not job.cancel.is_set()

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

    def _heading(self) -> dict[str, float | None] | None:
        """Where the arm rests once the current job is done (the pose at rest when none
        runs); None when that is not known yet: moves wait (a Cartesian one is planned
        from where the arm is when it starts), or the pose is to be read back."""
        if self._queue or self._readback:
            return None
        pose = self._book.pose
        job = self._current
        if job is not None:
            if job.mode is not Mode.QUEUE or not job.steps:
                return None
            pose.update(job.steps[-1].target)
        return pose

    def _unchanged(self, job: Job) -> bool:
        """A one-step job whose target is where the arm is heading already."""
        heading = self._heading()
        if heading is None or len(job.steps) != 1:
            return False
        for name, deg in job.steps[0].target.items():
            there = heading.get(name)
            if there is None or abs(deg - there) > self._same_deg[name]:
                return False
        return True

    def _quiet(self, job: Job) -> float:
        seen = self._stream_seen.get(job.stream, -math.inf)
        written = job.written.t_write if job.written is not None else -math.inf
        return now() - max(seen, written)

    def _supersede(self, job: Job) -> Job | None:
        """A set-point takes the place of the running one of its stream, where nothing waits
        before it and nothing is to be read back: that one ends (none of its bytes still to
        go is written) and this one is the current job, for the worker to write as soon as
        the wire allows; the board retargets a group move mid-move. The one it took the
        place of; None where it may not (it is then admitted as any move)."""
        running = self._current
        if (
            not job.stream
            or running is None
            or running.stream != job.stream
            or running.mode is not Mode.QUEUE
            or self._queue
            or self._readback
            or self._board is None
            or self._state is not State.MOVING
        ):
            return None
        running.superseded = True
        running.cancel.set()
        self._current, self._runner = job, Runner.NEXT
        self._cv.notify_all()
        return running

    def _drop(self, why: str, sent_ns: int) -> Ended:
        """End the epoch: the current job and every waiting one are never to be written. The
        shutdown's park is left to the worker, which reports it. `sent_ns`: when the event
        that drops them was sent."""
        self._epoch += 1
        self._order.dropped(why, sent_ns)
        self._streams_held = why
        jobs = list(self._queue)
        self._queue.clear()
        current, self._current, self._runner = self._current, None, None
        if current is not None:
            current.cancel.set()
            if current is not self._shutdown:
                jobs.insert(0, current)
        return Ended(tuple(jobs), why)

    def _halt(self, ended: Ended, urgent: bool = True) -> Halt:
        """A STOP of every channel, the moving joints first (lock held; written outside);
        `urgent` but for a cancelled move's."""
        t = now()
        channels = tuple(stop_order(self._book.motion, t, self._channels))
        self._book.halted(t)
        self._writes += 1
        self._writing += 1
        self._readback = True
        return Halt(self._board, channels, ended, urgent)

    def _lock_arm(self, by: str, sent_ns: int) -> None:
        """Lock (or keep locked), by an event sent at `sent_ns`: a release must be sent later."""
        self._order.locked(by, sent_ns, self._locked)
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

    def _written(self, job: Job, written: Written) -> Motion | None:
        if not self._holds(job) and not (job.superseded and job.epoch == self._epoch):
            # Q answers "moving" until this step's time is over, even halted (UG-38).
            self._book.distrust_q(written.motion)
            return None
        # A superseded set-point's bytes that went out are the board's motion all the same:
        # the one that took its place is written only after this is told (the worker waits
        # for a caller's write; its own it reports first), and retargets it.
        motion = self._book.moving(written.motion, written.t_write)
        self._book.written(motion, written.t_end)
        job.written = written
        if self._board is not None and self._board.gated:  # for the stop process's STOP
            order = stop_order(motion, written.t_write, self._channels)
            self._board.plan_stops(order, motion.t0 + motion.duration_s)
        return motion
