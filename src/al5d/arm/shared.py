"""The arm driver's shared state: one lock, the state machine, the queue, the pose.

The caller's side (`driver.ArmDriver`) and the move worker (`worker.Worker`)
meet only here. The rules:

- One lock (`lock`, and its condition `cv`) guards every field. It is never
  held during serial I/O, so that a stop never waits behind a read.
- State changes happen under the lock (`fire`, which asks the state table);
  their log lines (INF01, INF02) and the state listeners follow outside it,
  in order (`announce`).
- An emergency stop bumps `epoch`: a job of an older epoch is never written.
- A write to the board from the caller's thread (the fast path, a stop, a cancel) is
  bracketed by `begin_write` and `end_write`, so that the worker's link check can tell
  a pulse it reads back while a write races it from a board that has reset.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Iterable
from typing import TypeVar

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome
from al5d.arm.jobs import Job, Motion, Sent, Written
from al5d.arm.states import Event, Guards, State, Task, TransitionError, next_state
from al5d.clock import Deadline, now
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import SerialFault

log = logging.getLogger("al5d")
T = TypeVar("T")
#: How long after a step's end (by the driver's clock) the board may still be on its way.
SETTLE_GRACE_S = 0.25


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


class Shared:
    """Everything both threads of the driver read and write, behind one lock."""

    def __init__(self, config: ArmConfig) -> None:
        self.lock = threading.Lock()
        self.cv = threading.Condition(self.lock)
        self._announce_lock = threading.Lock()
        self._notes: list[tuple[Event, State, State]] = []
        self.state = State.INITIALIZING
        self.announced = State.INITIALIZING  # the state last logged and told to the listeners
        self.locked = False  # stop was pressed and release has not come yet
        self.epoch = 0
        self.queue: deque[Job] = deque()
        self.current: Job | None = None
        #: A move the caller's thread has written on an idle arm (the fast path), for the
        #: worker to see through: wait for it, then set its outcome.
        self.handed: tuple[Job, Written] | None = None
        self.board: SSC32U | None = None
        self.fault: SerialFault | None = None
        #: The worker is to read the pose back from the board, or is reading it: no move
        #: may be written meanwhile, or the pose read would be a snapshot of it.
        self.readback = False
        self.shutdown_job: Job | None = None
        self.parked = False  # the start-up park has been done
        self.pose: dict[str, float | None] = dict.fromkeys(config.joints)
        self.motion: Motion | None = None
        # After a STOP inside a timed move the board answers Q with '+' until that move's
        # time is over (UG-38); until then a move's completion is judged by time alone.
        self.q_unreliable_until = 0.0
        #: Writes from the caller's thread begun (`writes`), and those whose effect is not yet
        #: in `pose` and `motion` (`writing`): a link check judges the pulse it reads back
        #: only if no write began while it asked and none was under way when it began.
        self.writes = 0
        self.writing = 0
        #: Per joint, when it was last written (a count of the steps written): a move after a
        #: reset restores only its own channels, so the check reads back the stalest one.
        self._written = dict.fromkeys(config.joints, 0)
        self._steps_written = 0
        #: Per joint, the degrees its recent steps went through, and until when the board may
        #: still be on that way (see `note_written`).
        self._ways: dict[str, tuple[float, float, float]] = {}
        self.finished = threading.Event()
        self.outcome_listeners: list[Callable[[Outcome], None]] = []
        self.state_listeners: list[Callable[[State], None]] = []
        self.motion_listeners: list[Callable[[Sent], None]] = []

    # -- the state machine (lock held) ------------------------------------------------

    def guards(self) -> Guards:
        return Guards(queue_empty=not self.queue, locked=self.locked, parked=self.parked)

    def fire(self, event: Event) -> State:
        """Take the transition the table gives for `event`; its log lines follow in `announce`."""
        old = self.state
        new = next_state(old, event, self.guards())
        if new is None:
            raise TransitionError(f"no transition from {old.value} on {event.value}")
        self.state = new
        self._notes.append((event, old, new))
        self.cv.notify_all()
        return new

    def begin_write(self) -> None:
        """A write to the board is about to begin in the caller's thread (lock held)."""
        self.writes += 1
        self.writing += 1

    def end_write(self) -> None:
        """That write is done and `pose` and `motion` say what it did (lock held)."""
        self.writing -= 1

    def note_written(self, motion: Motion, t_end: float) -> None:
        """A step went to the board, its time over at `t_end` by the driver's clock (lock held).

        Its joints are the freshest now. Their way (with the way of a step before that was
        not over when this one began) is kept until `SETTLE_GRACE_S` after `t_end`: the
        board's own timing lags the driver's estimate by its link and its host, and a move
        whose end is judged by the clock alone (a step of a trajectory, or any move while
        `Q` still counts a stopped one down) may be still on its way when the pose says it
        is there."""
        self._steps_written += 1
        until = t_end + SETTLE_GRACE_S
        for joint, target in motion.target.items():
            self._written[joint] = self._steps_written
            start = motion.start.get(joint, target)
            low, high = min(start, target), max(start, target)
            way = self._ways.get(joint)
            if way is not None and way[2] - SETTLE_GRACE_S > motion.t0:
                low, high = min(low, way[0]), max(high, way[1])
            self._ways[joint] = (low, high, until)

    def way(self, joint: str, t: float) -> tuple[float, float] | None:
        """The degrees `joint` may still be passing through at `t` on its recent steps, if any
        (lock held)."""
        way = self._ways.get(joint)
        return (way[0], way[1]) if way is not None and t < way[2] else None

    def stalest(self) -> str | None:
        """The joint of known pose written least recently (the first in the configuration
        among equals), or None when no pose is known (lock held)."""
        known = [j for j, v in self.pose.items() if v is not None]
        return min(known, key=self._written.__getitem__, default=None)

    def take_pending(self) -> tuple[Job | None, list[Job]]:
        """End the epoch: the running job and the queued ones, which are never to be sent."""
        self.epoch += 1
        dropped = list(self.queue)
        self.queue.clear()
        self.handed = None  # a move the caller wrote is the current one: cancelled with it
        return self.current, dropped

    # -- outside the lock -------------------------------------------------------------

    def announce(self) -> None:
        """Log the transitions made so far (INF01, INF02) and tell the listeners, in order."""
        with self._announce_lock:
            with self.lock:
                notes, self._notes = self._notes, []
            for event, old, new in notes:
                log.debug("EVENT: %s", event.value)
                if new is not old:
                    log.info("STATE: %s", new.value)
                    tell(self.state_listeners, new, "state")
                with self.cv:
                    self.announced = new
                    self.cv.notify_all()

    def wait_announced(self, state: State, timeout: float) -> None:
        deadline = Deadline(timeout)
        with self.cv:
            while self.announced is not state:
                if deadline.expired:
                    raise TimeoutError(
                        f"state {state.value} not reached in {timeout} s (now {self.state.value})"
                    )
                self.cv.wait(deadline.left())

    def next_task(self, watch_every: float) -> tuple[Task, Job | None, Written | None]:
        """The worker's next task (waits for one): a shutdown first, then faults, then moves;
        WATCH when the arm has been idle on a connected board for `watch_every` seconds.
        With FOLLOW comes the written first step of the job (the fast path's)."""
        idle = Deadline(watch_every)
        with self.cv:
            while True:
                if self.shutdown_job is not None:
                    return Task.SHUTDOWN, self.shutdown_job, None
                if self.fault is not None or self.state is State.FAULT:
                    return Task.RECOVER, None, None
                if self.state is State.INITIALIZING and not self.parked:
                    return Task.STARTUP, None, None
                if self.handed is not None:
                    (job, written), self.handed = self.handed, None
                    return Task.FOLLOW, job, written
                if self.readback:  # cleared by the worker once the pose is read
                    return Task.READBACK, None, None
                # While the caller's thread writes a move (it is current and not yet
                # handed over), nothing else may go out.
                if self.queue and self.current is None:
                    return Task.MOVE, self.queue.popleft(), None
                if idle.expired:
                    if self.board is not None and self.current is None:
                        return Task.WATCH, None, None
                    idle = Deadline(watch_every)
                self.cv.wait(idle.left())

    def distrust_q(self, stopped: Motion) -> None:
        self.q_unreliable_until = max(self.q_unreliable_until, stopped.t0 + stopped.duration_s)

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles (degrees; NaN where unknown since power-up)."""
        motion = self.motion
        pose = self.pose
        if motion is not None:
            est = motion.at(now() if t is None else t)
            return {j: est.get(j, v if v is not None else math.nan) for j, v in pose.items()}
        return {j: (v if v is not None else math.nan) for j, v in pose.items()}
