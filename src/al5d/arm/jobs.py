"""Moves on their way through the core: the job, the motion it makes, and its one outcome.

Data only (frozen), handed between the protocol (`core`) and what it runs (`running`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from enum import Enum
from typing import TypeAlias

from al5d.arm.instruction import MAX_ID, MAX_QUOTE, Instruction, Outcome, Result
from al5d.arm.resample import Follow
from al5d.arm.states import State
from al5d.arm.validate import Steps


class Mode(Enum):
    """Why a move runs, and the states in which it may still be sent."""

    STARTUP = (State.INITIALIZING,)
    QUEUE = (State.READY, State.MOVING)
    SHUTDOWN = (State.SHUTTING_DOWN,)

    @property
    def states(self) -> tuple[State, ...]:
        return self.value  # type: ignore[no-any-return]


@dataclass(frozen=True, slots=True)
class Job:
    """A motion instruction on its way: its validated steps and who asked for it.

    A move or a preset is one step (one group move); a trajectory one per point; a
    Cartesian move has none until it is planned, from where the arm is when it starts.
    """

    ref: int  # the owner's handle of the request (its outcome goes there)
    instr: Instruction
    steps: Steps
    t_submit: float
    #: When it was sent (CLOCK_REALTIME ns): the instruction's, or when the owner took it.
    sent_ns: int
    epoch: int = 0
    speed_fraction: float = 1.0
    mode: Mode = Mode.QUEUE
    #: A set-point of this stream (`joint_commands`): a newer one of the same stream
    #: replaces it while it waits ("" for every other move).
    stream: str = ""
    #: Who sent it (the owner's handle of a client; 0: the owner itself).
    client: int = 0
    #: Its outcome is told to the outcome listeners too (a stream's set-points are not).
    tell: bool = True
    #: A trajectory's tolerances, as its sender gave them.
    follow: Follow | None = None
    #: When its sender gives up on it (the owner's clock, s; inf: never): `Instruction.wait_ms`.
    give_up_at: float = math.inf
    #: Not written before this (the owner's clock, s): `Instruction.start_ns`.
    start_at: float = -math.inf


#: A list of jobs as nested pairs (first, rest): adding to its head shares its tail.
Chain: TypeAlias = "tuple[Job, Chain] | None"


def _reversed(chain: Chain) -> Chain:
    out: Chain = None
    while chain is not None:
        out = (chain[0], out)
        chain = chain[1]
    return out


@dataclass(frozen=True, slots=True, eq=False, repr=False)
class Jobs:
    """The jobs that wait, oldest first, as a persistent queue (two chains, the oldest
    first and the newest first, as Okasaki's banker's queue): adding one and taking the
    first cost O(1) amortized however many wait. The core's queue was a tuple copied
    whole at each of them: 50,000 queued moves were taken at 5,700 a second (27,000
    before the core was a pure transition), and an owner with a long queue spent its
    turns copying it."""

    front: Chain = None  # the oldest first; empty only when the queue is
    back: Chain = None  # the newest first
    size: int = 0

    @classmethod
    def of(cls, jobs: Iterable[Job]) -> Jobs:
        """`jobs` in their order."""
        chain: Chain = None
        size = 0
        for job in jobs:
            chain = (job, chain)
            size += 1
        return cls(_reversed(chain), None, size)

    # Equality, hashing and repr by the jobs in order, not by the chains: the same jobs
    # may be split between the two differently, and a chain thousands deep would take
    # Python's recursion past its limit.
    def __eq__(self, other: object) -> bool:
        return isinstance(other, Jobs) and self.size == other.size and tuple(self) == tuple(other)

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        ids = [job.instr.id for job in self]
        shown = ids if len(ids) <= 10 else [*ids[:5], "...", *ids[-5:]]
        return f"Jobs({len(ids)}: {', '.join(shown)})"

    def __len__(self) -> int:
        return self.size

    def __bool__(self) -> bool:
        return self.size > 0

    def __iter__(self) -> Iterator[Job]:
        chain = self.front
        while chain is not None:
            yield chain[0]
            chain = chain[1]
        chain = _reversed(self.back)
        while chain is not None:
            yield chain[0]
            chain = chain[1]

    def add(self, job: Job) -> Jobs:
        """With `job` last."""
        if self.front is None:
            return Jobs((job, None), None, 1)
        return Jobs(self.front, (job, self.back), self.size + 1)

    def first(self) -> Job:
        """The oldest; IndexError if none waits."""
        if self.front is None:
            raise IndexError("no job waits")
        return self.front[0]

    def rest(self) -> Jobs:
        """Without the oldest; IndexError if none waits."""
        if self.front is None:
            raise IndexError("no job waits")
        front = self.front[1]
        if front is None:
            return Jobs(_reversed(self.back), None, self.size - 1)
        return Jobs(front, self.back, self.size - 1)

    def where(self, keep: Callable[[Job], bool]) -> Jobs:
        """Only the jobs `keep` says to keep, in their order."""
        return Jobs.of(job for job in self if keep(job))


#: No job waits.
NO_JOBS = Jobs()


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

    @property
    def end(self) -> float:
        return self.t0 + self.duration_s

    def moving(self, t: float) -> list[str]:
        """The joints still moving at `t`, the fastest (deg/s) first (those of the step
        the board is finishing, then this one's)."""
        if self.duration_s <= 0 or t >= self.end:
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
        if previous is None or previous.end <= t:
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
    data: bytes
    t_write: float  # when its first bytes were written


@dataclass(frozen=True, slots=True)
class Sent:
    """A step as it left for the board: for listeners that follow or measure motion (the
    trajectory action's feedback, the demo's QoS table, the joint states' rate)."""

    instr: Instruction
    data: bytes
    t_submit: float  # when the instruction reached the owner
    t_write: float  # when its bytes were written
    motion: Motion
    step: int = 0
    steps: int = 1


def outcome(
    instr: Instruction, result: Result, reason: str, t0: float, t: float, expected: float = 0.0
) -> Outcome:
    """The outcome of `instr`, timed from `t0` (when it came) to `t`."""
    return Outcome(
        id=instr.id[:MAX_ID],
        instruction=instr.name[:MAX_QUOTE],
        result=result,
        reason=reason,
        elapsed_ms=(t - t0) * 1000.0,
        expected_ms=expected,
    )
