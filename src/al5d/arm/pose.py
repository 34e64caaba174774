"""What the driver believes the board holds: the pose, the motion under way, and its traces.

`PoseBook` is owned by the arm's protocol (`core.Core`), which calls it only
under its lock; nothing else writes it. It answers the questions the protocol
and the link checks ask: where the joints are now (estimated along the motion),
which joint was written least recently, what a pulse read back may be, and
whether `Q` can be believed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from al5d.arm.effects import LinkView
from al5d.arm.jobs import Motion
from al5d.clock import now

#: How long after a step's end (by the driver's clock) the board may still be on its way.
SETTLE_GRACE_S = 0.25


class PoseBook:
    """The pose (degrees; None where the board has no pulse since power-up) and the motion."""

    def __init__(self, joints: Mapping[str, object]) -> None:
        self._pose: dict[str, float | None] = dict.fromkeys(joints)
        self._motion: Motion | None = None
        #: After a STOP inside a timed move the board answers Q with '+' until that move's
        #: time is over (UG-38); until then a move's completion is judged by time alone.
        self._q_unreliable_until = 0.0
        #: Per joint, when it was last written (a count of the steps written): a move after a
        #: reset restores only its own channels, so the check reads back the stalest one.
        self._written = dict.fromkeys(joints, 0)
        self._steps_written = 0
        #: Per joint, the degrees its recent steps went through, and until when the board may
        #: still be on that way (see `written`).
        self._ways: dict[str, tuple[float, float, float]] = {}

    # -- reading ---------------------------------------------------------------------

    @property
    def pose(self) -> dict[str, float | None]:
        """A copy of the pose at rest (the last target reached, or read back)."""
        return dict(self._pose)

    @property
    def motion(self) -> Motion | None:
        return self._motion

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles (degrees; NaN where unknown since power-up)."""
        pose, motion = self._pose, self._motion
        if motion is not None:
            est = motion.at(now() if t is None else t)
            return {j: est.get(j, v if v is not None else math.nan) for j, v in pose.items()}
        return {j: (v if v is not None else math.nan) for j, v in pose.items()}

    def q_believed(self, t: float) -> bool:
        """Whether `Q` says anything of the move now under way (not a stopped one counting down)."""
        return t >= self._q_unreliable_until

    def way(self, joint: str, t: float) -> tuple[float, float] | None:
        """The degrees `joint` may still be passing through at `t` on its recent steps."""
        way = self._ways.get(joint)
        return (way[0], way[1]) if way is not None and t < way[2] else None

    def link_view(self, t: float, token: int | None) -> LinkView | None:
        """What a link check at `t` reads back and judges: the stalest joint, where it is
        believed to be, on what way (None: no pose is known)."""
        joint = self.stalest()
        if joint is None:
            return None
        pose = self._pose[joint]
        assert pose is not None
        return LinkView(joint, pose, self._motion, self.way(joint, t), token)

    def stalest(self) -> str | None:
        """The joint of known pose written least recently (the first in the configuration
        among equals), or None when no pose is known."""
        known = [j for j, v in self._pose.items() if v is not None]
        return min(known, key=self._written.__getitem__, default=None)

    # -- changes (the protocol's, under its lock) --------------------------------------

    def moving(self, motion: Motion, t_write: float) -> Motion:
        """A step's bytes went out: the board runs `motion` (knowing the step before it)."""
        self._motion = motion.after(self._motion, t_write)
        return self._motion

    def written(self, motion: Motion, t_end: float) -> None:
        """A step is on the board, its time over at `t_end` by the driver's clock.

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

    def reached(self, target: Mapping[str, float]) -> None:
        """A step's time is over: its joints are where it sent them."""
        self._pose.update(target)

    def at_rest(self) -> None:
        """The last step of a job is done: no motion is under way."""
        self._motion = None

    def halted(self, t: float) -> Motion | None:
        """A STOP is about to be written: the pose is where the motion is at `t` (until the
        read-back says exactly where), and `Q` counts the stopped move down. The motion."""
        motion, self._motion = self._motion, None
        if motion is not None:
            self._pose.update(motion.at(t))
            self.distrust_q(motion)
        return motion

    def distrust_q(self, stopped: Motion) -> None:
        self._q_unreliable_until = max(self._q_unreliable_until, stopped.t0 + stopped.duration_s)

    def lost(self) -> None:
        """The link went (the board may go on with its move): Q counts that move down."""
        if self._motion is not None:
            self.distrust_q(self._motion)
        self._motion = None

    def read_back(self, pose: Mapping[str, float | None]) -> None:
        """Where the board says the servos are."""
        self._pose.update(pose)
        self._motion = None

    def forget(self) -> None:
        """After a board's reset: no pose is known until it is read back."""
        self._pose = dict.fromkeys(self._pose)
        self._motion = None
