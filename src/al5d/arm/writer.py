"""One step of a move onto the wire: plan its time, write its bytes, and check for a stop.

Used by the worker for every step, and by the caller's thread for the first
(only) step of a move given to an idle arm (the fast path, `driver.ArmDriver`),
so that both follow one rule: a job is current and of the current epoch before
its bytes are written, and the epoch is checked again after the write; if a
stop came in between, its STOP may have gone out before our move, so the STOP
is written again. A move that predates a stop never stays in effect after it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

from al5d.arm.instruction import Kind
from al5d.arm.jobs import Job, Motion, Sent, Written, stop_order
from al5d.arm.shared import Shared, tell
from al5d.arm.translate import Translator
from al5d.arm.validate import Step
from al5d.clock import now
from al5d.ssc32u.driver import SSC32U

log = logging.getLogger("al5d")


class StepWriter:
    """Plans and writes the steps of jobs for one arm."""

    def __init__(self, shared: Shared, translator: Translator, channels: dict[str, int]) -> None:
        self.shared = shared
        self.translator = translator
        self.channel_of = channels
        #: A test's seam: called with "checked" before a step is written, and from inside
        #: the write (see tests/test_arm_fast_path.py); None in use.
        self.race_hook: Callable[[str], None] | None = None

    def plan(
        self, job: Job, step: Step, arrival: Callable[[int], float] | None = None
    ) -> tuple[bytes, int]:
        """The bytes and the time to send (ms), from where the arm is.

        A step after the first (given `arrival`, when bytes written now reach the board)
        is timed to end when the schedule says, `step.time_ms` after the one before was
        due to end, however early or late it takes effect."""
        pose = self.shared.pose
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
                self._warn_line(job)
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

    def _warn_line(self, job: Job) -> None:
        """INF03 once for a line whose `time` the servos cannot hold (not once per hop)."""
        asked = job.instr.time_ms
        if not asked:
            return
        here: Mapping[str, float | None] = self.shared.pose
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
        """Write one step of a current job; None if a stop came first (its STOP stands).

        Raises SerialFault when the write fails; the caller hands that to the worker.
        """
        shared = self.shared
        data, time_ms = self.plan(job, step, board.arrival)
        job.expected_ms += time_ms
        start = {j: v for j, v in shared.pose.items() if v is not None}
        if self.race_hook is not None:
            self.race_hook("checked")
        t_write = now()
        # The move starts when its CR reaches the board: after whatever was still on the
        # wire (a stop's STOPs, a query) and its own wire time.
        t_sent = board.write_command(data)
        motion = Motion(start, step.target, t_sent, time_ms / 1000.0)
        with shared.lock:
            raced = job.epoch != shared.epoch or job.cancel.is_set()
            if not raced:
                motion = motion.after(shared.motion, t_write)
                shared.motion = motion
        if raced:
            board.stop(stop_order(motion, now(), self.channel_of))
            return None
        t_end = t_sent + time_ms / 1000.0
        job.t_due = max(t_end, job.t_due + (step.time_ms or 0) / 1000.0) if job.step else t_end
        if shared.motion_listeners:
            sent = Sent(job.instr, data, job.t_submit, t_write, motion)
            tell(shared.motion_listeners, sent, "motion")
        return Written(motion, t_end, board.wire_time_s(data))
