"""One step of a move onto the wire: plan its time, write its bytes, and check for a stop.

Used by the worker for every step, and by the caller's thread for the first
(only) step of a move given to an idle arm (the fast path, `driver.ArmDriver`),
so that both follow one rule. A stop ends the epoch (under the shared lock)
before it writes its STOP, and the STOP takes the board's write lock; a step is
written only if its job's epoch still holds when the step has the write lock
(`SSC32U.write_command`'s `unless`). So either the step goes out before the STOP,
which then halts it, or it does not go out at all: no byte of a move that
predates a stop ever reaches the board after that stop's STOP.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

from al5d.arm.instruction import Kind, Result
from al5d.arm.jobs import Job, Motion, Sent, Written, finish
from al5d.arm.shared import Shared, tell
from al5d.arm.translate import Translator
from al5d.arm.validate import Step
from al5d.clock import now
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import SerialFault

log = logging.getLogger("al5d")


class StepWriter:
    """Plans and writes the steps of jobs for one arm."""

    def __init__(self, shared: Shared, translator: Translator) -> None:
        self.shared = shared
        self.translator = translator
        #: A test's seam (tests/test_arm_fast_path.py); None in use. Called with "judged" when
        #: the driver has judged a move, before it checks the state and the epoch; with
        #: "checked" before a step is written; and with "locked" when the step holds the
        #: board's write lock, just before the epoch's last check.
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
        """Write one step of a current job; None if a stop (or a cancel) came first.

        Raises SerialFault when the write fails; the caller hands that to the worker.
        """
        shared = self.shared
        data, time_ms = self.plan(job, step, board.arrival)
        start = {j: v for j, v in shared.pose.items() if v is not None}
        hook = self.race_hook
        if hook is not None:
            hook("checked")

        def overtaken() -> bool:
            # Read without the shared lock, which is never taken inside the write lock:
            # a stop has ended the epoch (or set the cancel) before it asks for the write
            # lock, so if it is waiting for it, or has had it, we see that here.
            if hook is not None:
                hook("locked")
            return job.epoch != shared.epoch or job.cancel.is_set()

        t_write = now()
        # The move starts when its CR reaches the board: after whatever was still on the
        # wire (a stop's STOPs, a query) and its own wire time.
        t_sent = board.write_command(data, unless=overtaken)
        if t_sent is None:
            return None  # the stop's STOP stands; nothing of this step went out
        job.expected_ms += time_ms
        motion = Motion(start, step.target, t_sent, time_ms / 1000.0)
        with shared.lock:
            if job.epoch != shared.epoch or job.cancel.is_set():
                # A stop that came after the write lock was ours writes its STOP after our
                # bytes, so it halts this step, but it took the pose from the motion before
                # (its read-back corrects that). Q answers "moving" until this step's time
                # is over, even halted (UG-38): the next move is judged by time till then.
                shared.distrust_q(motion)
                return None
            motion = motion.after(shared.motion, t_write)
            shared.motion = motion
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
        if shared.motion_listeners:
            sent = Sent(job.instr, data, job.t_submit, t_write, motion)
            tell(shared.motion_listeners, sent, "motion")
        return Written(motion, t_end, board.wire_time_s(data))

    def write_alone(self, job: Job, board: SSC32U) -> None:
        """The fast path: the caller's thread writes an idle arm's move (its only step),
        without the hand-over to the worker (a thread wake and the GIL, most of the server's
        share of the latency), then hands the waiting for completion to the worker. The
        caller has made the job current, of this epoch, inside `begin_write`."""
        shared = self.shared
        try:
            written = self.write(job, job.steps[0], board)
        except SerialFault as e:
            with shared.cv:
                shared.end_write()
                if shared.current is job:
                    shared.current = None
                shared.fault = shared.fault or e  # the worker enters the fault
                shared.cv.notify_all()
            job.cancel.set()
            finish(job, Result.CANCELLED, f"the serial link is lost: {e}")
            return
        with shared.cv:
            shared.end_write()
            if written is None or job.epoch != shared.epoch:
                if shared.current is job:  # a stop took it: its outcome is set
                    shared.current = None
            else:
                shared.handed = (job, written)
            shared.cv.notify_all()
        shared.announce()
