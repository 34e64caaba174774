"""Moves on their way through the driver: the job, the motion it makes, and its one outcome.

Data handed between the caller's side (`driver`), the protocol (`core`) and the
worker (`worker`), and the two helpers that make and set an outcome exactly once.
A job belongs to the thread the protocol gives it to (the caller writing an idle
arm's first step, then the worker): only that thread writes its running fields.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass, field, replace
from enum import Enum

from al5d.arm.instruction import MAX_ID, MAX_QUOTE, Instruction, Outcome, Result
from al5d.arm.states import State
from al5d.arm.validate import Steps
from al5d.clock import now


class Mode(Enum):
    """Why the worker runs a move, and the states in which it may still be sent."""

    STARTUP = (State.INITIALIZING,)
    QUEUE = (State.READY, State.MOVING)
    SHUTDOWN = (State.SHUTTING_DOWN,)

    @property
    def states(self) -> tuple[State, ...]:
        return self.value  # type: ignore[no-any-return]


@dataclass(slots=True)
class Job:
    """A motion instruction on its way: its validated steps, its future, its epoch.

    A move or a preset is one step (one group move); a trajectory one per point; a
    Cartesian move has none until it is planned, from where the arm is when it starts.
    """

    instr: Instruction
    steps: Steps
    future: Future[Outcome]
    epoch: int
    t_submit: float
    speed_fraction: float = 1.0
    mode: Mode = Mode.QUEUE
    #: When it was sent (CLOCK_REALTIME ns): the instruction's, or when the driver took it.
    sent_ns: int = 0
    cancel: threading.Event = field(default_factory=threading.Event)
    #: A set-point of this stream (`joint_commands`): a newer one of the same stream
    #: replaces it while it waits ("" for every other move).
    stream: str = ""
    #: A newer set-point of its stream took its place while it ran (`core`, the lane of
    #: set-points): what it wrote stays the board's motion, which the newer one retargets.
    superseded: bool = False
    expected_ms: float = 0.0
    step: int = 0  # the step running now
    #: The step written last: the worker waits for its end (a step the caller wrote, too).
    written: Written | None = None
    #: When the step written last is due to end by the schedule (CLOCK_MONOTONIC): the timed
    #: steps after the first keep to the schedule of the first, so that a late wake-up, or
    #: a point faster than the servos, does not make every later point late too.
    t_due: float = 0.0


@dataclass(frozen=True, slots=True)
class Motion:
    """The move the board is running: from where, to where, when, for how long."""

    start: Mapping[str, float]
    target: Mapping[str, float]
    t0: float
    duration_s: float
    #: The move the board is still finishing when this one takes effect: a trajectory's
    #: next step is written one wire time early, and until its `t0` the arm is where the
    #: step before puts it, not already at this one's start.
    before: Motion | None = None

    def progress(self, t: float) -> float:
        return 1.0 if self.duration_s <= 0 else min(1.0, max(0.0, (t - self.t0) / self.duration_s))

    def at(self, t: float) -> dict[str, float]:
        if t < self.t0 and self.before is not None:
            return {**self.start, **self.before.at(t)}
        f = self.progress(t)
        return {j: s + (self.target.get(j, s) - s) * f for j, s in self.start.items()}

    def moving(self, t: float) -> list[str]:
        """The joints still moving at `t`, the fastest (deg/s) first (those of the step
        the board is finishing, then this one's)."""
        if self.duration_s <= 0 or t >= self.t0 + self.duration_s:
            return []
        speed = {j: abs(self.target[j] - s) for j, s in self.start.items() if j in self.target}
        own = sorted((j for j, d in speed.items() if d > 0), key=lambda j: -speed[j])
        if t < self.t0 and self.before is not None:
            first = self.before.moving(t)
            return first + [j for j in own if j not in first]
        return own

    def after(self, previous: Motion | None, t: float) -> Motion:
        """This motion, knowing what the board runs until it takes effect (only the step
        just before matters: one link, so that a long trajectory makes no chain)."""
        if previous is None or previous.t0 + previous.duration_s <= t:
            return self
        return replace(self, before=replace(previous, before=None))


def stop_order(motion: Motion | None, t: float, channels: Mapping[str, int]) -> list[int]:
    """The channels in the order to STOP them: the moving joints first, fastest first, then
    the others in channel order. Each STOP is 7 bytes (7.3 ms at 9600 baud): a servo that
    moves should not wait behind five that do not."""
    first = [channels[j] for j in (motion.moving(t) if motion is not None else [])]
    return first + sorted(ch for ch in channels.values() if ch not in first)


@dataclass(frozen=True, slots=True)
class Written:
    """A step on its way: its bytes, the motion it makes on the board, when its time is over."""

    motion: Motion
    t_end: float
    #: Its bytes' time on the wire: the next step is written this much before `t_end`, so
    #: that it takes effect as this one ends (the steps of a trajectory run back to back).
    wire_s: float
    data: bytes = b""
    t_write: float = 0.0  # when its bytes were written


@dataclass(frozen=True, slots=True)
class Sent:
    """A move as it left for the board: for listeners that measure (the demo's QoS table)."""

    instr: Instruction
    data: bytes
    t_submit: float  # when the instruction reached the driver
    t_write: float  # when its bytes were written
    motion: Motion


def outcome(job_or_instr: Job | Instruction, result: Result, reason: str, t0: float) -> Outcome:
    instr = job_or_instr.instr if isinstance(job_or_instr, Job) else job_or_instr
    expected = job_or_instr.expected_ms if isinstance(job_or_instr, Job) else 0.0
    return Outcome(
        id=instr.id[:MAX_ID],
        instruction=instr.name[:MAX_QUOTE],
        result=result,
        reason=reason,
        elapsed_ms=(now() - t0) * 1000.0,
        expected_ms=expected,
    )


def resolve(future: Future[Outcome], result: Outcome) -> bool:
    """Set the one outcome; False if another thread was first (stop racing completion)."""
    try:
        future.set_result(result)
    except InvalidStateError:
        return False
    return True


def finish(job: Job, result: Result, reason: str = "") -> bool:
    """Resolve a job's future with its outcome, timed from its submission."""
    return resolve(job.future, outcome(job, result, reason, job.t_submit))
