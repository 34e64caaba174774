"""One step of a move onto the wire: plan its time, write its bytes unless a stop came first.

Used by whichever thread the protocol (`core`) gives a job to: the caller's for
an idle arm's first step, the worker's for the rest. It never changes the arm's
state; it reads the pose from the core and reports what it wrote to it. A step is
written only if its job's epoch still holds, and its cancel is not set, when the
step has the board's write lock (`SSC32U.write_command`'s `unless`); a stop ends
the epoch before it asks for that lock, so no byte of a move that predates a
stop ever reaches the board after that stop's STOP.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

from al5d.arm.core import Core
from al5d.arm.effects import tell
from al5d.arm.instruction import Kind
from al5d.arm.jobs import Job, Mode, Motion, Sent, Written
from al5d.arm.translate import Translator
from al5d.arm.validate import Limits, Step, from_start, planned
from al5d.clock import now
from al5d.ssc32u.driver import SSC32U

log = logging.getLogger("al5d")
#: A set-point of a stream is written only once the wire is free: one written earlier, behind
#: the line on the wire, could no longer be superseded by a newer one (at 9600 baud a
#: line is 32 ms of wire, and a 50 Hz stream sends a newer set-point every 20 ms).
STREAM_HORIZON_S = 0.0


class StepWriter:
    """Plans and writes the steps of jobs for one arm."""

    def __init__(
        self,
        core: Core,
        translator: Translator,
        limits: Limits,
        motion_listeners: list[Callable[[Sent], None]],
    ) -> None:
        self.core = core
        self.translator = translator
        self.limits = limits
        self.motion_listeners = motion_listeners
        #: A test's seam (tests/test_arm_fast_path.py); None in use. Called with "judged"
        #: when the driver has judged a move, before its admission; with "checked" before
        #: a step is written; and with "locked" when the step holds the board's write lock,
        #: just before the epoch's last check.
        self.race_hook: Callable[[str], None] | None = None

    def prepare(self, job: Job) -> str:
        """A Cartesian move is planned when it starts, from where the arm is then (the
        current job's pose cannot change under it but by an event that ends it): its
        steps, or the reason to refuse it whole (""). Any other move's path is judged
        against the table from there (the worker's own parks are not: they are how the
        server makes the arm safe)."""
        if job.steps:
            if job.mode is not Mode.QUEUE:
                return ""
            return from_start(job.instr, job.steps, self.core.pose(), self.limits)
        steps = planned(job.instr, self.core.pose(), self.limits, self.translator)
        if isinstance(steps, str):
            return steps
        job.steps = steps
        return ""

    def plan(
        self,
        job: Job,
        step: Step,
        pose: Mapping[str, float | None],
        arrival: Callable[[int], float] | None = None,
    ) -> tuple[bytes, int]:
        """The bytes and the time to send (ms), from `pose`.

        A step after the first (given `arrival`, when bytes written now reach the board)
        is timed to end when the schedule says, `step.time_ms` after the one before was
        due to end, however early or late it takes effect."""
        unknown = [j for j in step.target if pose.get(j) is None]
        if unknown:
            log.warning(
                "D1: %s [%s]: first command for %s since the board powered up (or reset): "
                "the board ignores speed and time for it, so they go at full servo speed",
                job.instr.name,
                job.instr.id,
                ", ".join(unknown),
            )
        minimum = self.translator.minimum_ms(pose, step.target, job.speed_fraction)
        min_ms = math.ceil(minimum - 1e-9)
        requested = step.time_ms or 0
        if requested and job.step > 0 and arrival is not None:
            due = job.t_due + requested / 1000.0
            # Its bytes with the time asked (the time sent may have a digit more or less:
            # a millisecond at 9600 baud, within the rounding to whole ms).
            length = len(self.translator.encode(step.target, requested))
            requested = max(1, round((due - arrival(length)) * 1000.0))
        time_ms = max(requested, min_ms)
        if self._line(job):
            if job.step == 0:
                self._warn_line(job, pose)
        elif step.time_ms and requested < min_ms:
            point = f" point {job.step}" if len(job.steps) > 1 else ""
            # A later step may have less than it asked: what is left of its schedule.
            left = "" if requested == step.time_ms else f" ({requested} ms left of its schedule)"
            log.warning(
                "INF03: %s [%s]%s cannot be done in the requested %d ms%s; expected %d ms",
                job.instr.name,
                job.instr.id,
                point,
                step.time_ms,
                left,
                time_ms,
            )
        return self.translator.encode(step.target, time_ms), time_ms

    @staticmethod
    def _line(job: Job) -> bool:
        """A straight line's hops: its time is judged once, for the whole line."""
        return job.instr.kind is Kind.MOVE_TO and len(job.steps) > 1

    def _warn_line(self, job: Job, pose: Mapping[str, float | None]) -> None:
        """INF03 once for a line whose `time` the servos cannot hold (not once per hop)."""
        asked = job.instr.time_ms
        if not asked:
            return
        here: Mapping[str, float | None] = pose
        expected = 0
        for step in job.steps:
            need = self.translator.minimum_ms(here, step.target, job.speed_fraction)
            expected += max(step.time_ms or 0, math.ceil(need - 1e-9))
            here = {**here, **step.target}
        if expected > asked:
            log.warning(
                "INF03: %s [%s] cannot be done in the requested %d ms; expected %d ms",
                job.instr.name,
                job.instr.id,
                asked,
                expected,
            )

    def write(self, job: Job, step: Step, board: SSC32U) -> Written | None:
        """Write one step of the current job; None if a stop (or a cancel) came first.

        Raises SerialFault when the write fails; the caller reports it to the core.
        """
        core = self.core
        if job.stream and job.step == 0:
            # A set-point may retarget the one it superseded mid-move: planned from where
            # that one has the arm when these bytes take effect.
            length = len(self.translator.encode(step.target, 0))
            pose = core.start_pose(job, board.arrival(length))
        else:
            pose = core.pose()
        data, time_ms = self.plan(job, step, pose, board.arrival)
        start = {j: v for j, v in pose.items() if v is not None}
        hook = self.race_hook
        if hook is not None:
            hook("checked")

        def overtaken() -> bool:
            # Read without the core's lock, which is never taken inside the write lock: a
            # stop has ended the epoch (or a cancel set the flag) before it asks for the
            # write lock, so if it is waiting for it, or has had it, we see that here.
            if hook is not None:
                hook("locked")
            return job.epoch != core.epoch or job.cancel.is_set()

        t_write = now()
        # The move starts when its CR reaches the board: after whatever was still on the
        # wire (a stop's STOPs, a query) and its own wire time.
        if job.stream:
            t_sent = board.write_command(data, unless=overtaken, horizon_s=STREAM_HORIZON_S)
        else:
            t_sent = board.write_command(data, unless=overtaken)
        if t_sent is None:
            return None  # the stop's STOP stands; nothing of this step went out
        job.expected_ms += time_ms
        t_end = t_sent + time_ms / 1000.0
        # The schedule: a timed step is due `time_ms` after the one before was due (the first,
        # after it took effect), however late that one ended; a point the servos could not
        # reach in its time leaves the next less time, which catches up where it can.
        if not step.time_ms:
            job.t_due = t_end
        elif job.step:
            job.t_due += step.time_ms / 1000.0
        else:
            job.t_due = t_sent + step.time_ms / 1000.0
        motion = Motion(start, step.target, t_sent, time_ms / 1000.0)
        return Written(motion, t_end, board.wire_time_s(data), data, t_write)

    def told(self, job: Job, written: Written, motion: Motion) -> None:
        """The motion listeners hear of a step the core took as written (whoever wrote it)."""
        if self.motion_listeners:
            sent = Sent(job.instr, written.data, job.t_submit, written.t_write, motion)
            tell(self.motion_listeners, sent, "motion")
