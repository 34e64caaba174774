"""What the core believes the board holds: the pose, the motion under way, and its traces.

`PoseBook` is a value (frozen): each change returns a new one. It answers the
questions the protocol and the link checks ask: where the joints are at a time
(estimated along the motion), which joint was written least recently, what a
pulse read back may be, and whether `Q` can be believed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

from al5d.arm.jobs import Motion

#: How long after a step's end (by the owner's clock) the board may still be on its way.
SETTLE_GRACE_S = 0.25

Pose = Mapping[str, float | None]


@dataclass(frozen=True, slots=True)
class PoseBook:
    """The pose (degrees; None where the board has no pulse since power-up) and the motion."""

    pose: Pose
    #: Per joint, when it was last written (a count of the steps written): a move after a
    #: reset restores only its own channels, so the check reads back the stalest one.
    stamps: Mapping[str, int]
    #: Per joint, the degrees its recent steps went through, and until when the board may
    #: still be on that way (see `moving`).
    ways: Mapping[str, tuple[float, float, float]]
    motion: Motion | None = None
    #: After a STOP inside a timed move the board answers Q with '+' until that move's
    #: time is over (UG-38); until then a move's completion is judged by time alone.
    q_unreliable_until: float = 0.0
    steps_written: int = 0
    #: The joints whose pulse the core knows only to within a step of `QP` (10 us, rounded
    #: down: up to 1 degree): read back, or estimated at a halt or a lost link while they
    #: moved. A path judged from such a pose is not the board's (near the table, 1 degree
    #: is up to 2 mm of depth): the next job's first line puts them first where the core
    #: believes them (`held`), with no time, so that its path starts where it was judged.
    unsure: frozenset[str] = frozenset()

    @classmethod
    def unknown(cls, joints: Mapping[str, object]) -> PoseBook:
        return cls(dict.fromkeys(joints), dict.fromkeys(joints, 0), {})

    # -- reading ---------------------------------------------------------------------

    def positions(self, t: float) -> dict[str, float]:
        """Estimated joint angles at `t` (degrees; NaN where unknown since power-up)."""
        pose, motion = self.pose, self.motion
        if motion is not None:
            est = motion.at(t)
            return {j: est.get(j, v if v is not None else math.nan) for j, v in pose.items()}
        return {j: (v if v is not None else math.nan) for j, v in pose.items()}

    def q_believed(self, t: float) -> bool:
        """Whether `Q` says anything of the move now under way (not a stopped one counting down)."""
        return t >= self.q_unreliable_until

    def way(self, joint: str, t: float) -> tuple[float, float] | None:
        """The degrees `joint` may still be passing through at `t` on its recent steps."""
        way = self.ways.get(joint)
        return (way[0], way[1]) if way is not None and t < way[2] else None

    def stalest(self) -> str | None:
        """The joint of known pose written least recently (the first in the configuration
        among equals), or None when no pose is known."""
        known = [j for j, v in self.pose.items() if v is not None]
        return min(known, key=self.stamps.__getitem__, default=None)

    def heading(self, target: Mapping[str, float] | None) -> dict[str, float | None]:
        """The pose at rest, with `target` (a step on its way) reached."""
        return {**self.pose, **(target or {})}

    # -- changes -----------------------------------------------------------------------

    def moving(self, motion: Motion, t_write: float, t_end: float) -> PoseBook:
        """A step's bytes went out: the board runs `motion` (knowing the step before it),
        its time over at `t_end` by the owner's clock.

        Its joints are the freshest now. Their way (with the way of a step before that was
        not over when this one began) is kept until `SETTLE_GRACE_S` after `t_end`: the
        board's own timing lags the owner's estimate by its link and its host, and a move
        whose end is judged by the clock alone (a step of a trajectory, or any move while
        `Q` still counts a stopped one down) may be still on its way when the pose says it
        is there."""
        n = self.steps_written + 1
        until = t_end + SETTLE_GRACE_S
        stamps, ways = dict(self.stamps), dict(self.ways)
        for joint, target in motion.target.items():
            stamps[joint] = n
            start = motion.start.get(joint, target)
            low, high = min(start, target), max(start, target)
            way = ways.get(joint)
            if way is not None and way[2] - SETTLE_GRACE_S > motion.t0:
                low, high = min(low, way[0]), max(high, way[1])
            ways[joint] = (low, high, until)
        return replace(
            self,
            motion=motion.after(self.motion, t_write),
            steps_written=n,
            stamps=stamps,
            ways=ways,
            unsure=self.unsure - set(motion.target),  # its line puts them at their target
        )

    def reached(self, target: Mapping[str, float]) -> PoseBook:
        """A step's time is over: its joints are where it sent them."""
        return replace(self, pose={**self.pose, **target})

    def at_rest(self) -> PoseBook:
        """The last step of a job is done: no motion is under way."""
        return replace(self, motion=None)

    def halted(self, t: float) -> PoseBook:
        """A STOP is written: the pose is where the motion is at `t` (until the read-back
        says exactly where), and `Q` counts the stopped move down."""
        # A joint still on its way (its step's time over by the owner's clock, the board a
        # little behind it) stops short of where the pose says too.
        unsure = self.unsure | {j for j in self.ways if self.way(j, t) is not None}
        motion = self.motion
        if motion is None:
            return replace(self, unsure=unsure)
        book = replace(self, pose={**self.pose, **motion.at(t)}, motion=None, unsure=unsure)
        return book.distrust_q(motion)

    def distrust_q(self, stopped: Motion) -> PoseBook:
        return replace(self, q_unreliable_until=max(self.q_unreliable_until, stopped.end))

    def lost(self) -> PoseBook:
        """The link went (the board may go on with its move): Q counts that move down, and
        where it has its joints is known once read back."""
        motion = self.motion
        if motion is None:
            return self
        moved = set(motion.target) | (set(motion.before.target) if motion.before else set())
        return replace(self.distrust_q(motion), motion=None, unsure=self.unsure | moved)

    def read_back(self, pose: Pose, exact: frozenset[str] = frozenset()) -> PoseBook:
        """Where the board says the servos are; `exact`: the joints whose own pose the core
        knows to the microsecond and the board's answer agrees with (kept, not rounded)."""
        read = {j: v for j, v in pose.items() if j not in exact}
        unsure = (self.unsure - exact) | {j for j, v in read.items() if v is not None}
        return replace(self, pose={**self.pose, **read}, motion=None, unsure=unsure)

    def held(self) -> PoseBook:
        """A line put every joint of unsure pose where the core believes it."""
        return replace(self, unsure=frozenset())

    def forget(self) -> PoseBook:
        """After a board's reset: no pose is known until it is read back."""
        return replace(self, pose=dict.fromkeys(self.pose), motion=None, unsure=frozenset())
