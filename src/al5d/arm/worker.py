"""The arm driver's worker thread: connect, park, run each move until done, recover from faults.

It takes its tasks from the protocol (`core.Core.next_task`) and does the board
I/O that may take long: the moves, the wait for their completion (their time,
then `Q`), and, through its `link.LinkKeeper`, the read-backs, the idle checks and the
reconnects. What it learns it reports to the core, which may have ended the job
meanwhile (a stop, a cancel, a fault): the worker then lets go.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from concurrent.futures import Future

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.core import Core
from al5d.arm.effects import Halt
from al5d.arm.instruction import Result
from al5d.arm.jobs import Job, Mode, finish
from al5d.arm.link import LinkKeeper
from al5d.arm.states import Task
from al5d.arm.validate import Step
from al5d.arm.writer import StepWriter
from al5d.clock import Deadline, now
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import BoardReset, Interrupted, SerialFault

log = logging.getLogger("al5d")

#: How often `Q` is asked once a move's time is over.
POLL_INTERVAL_S = 0.002
#: A move whose `Q` still says moving this long after its time is taken as a fault.
COMPLETION_GRACE_S = 2.0


class Worker:
    """The one thread that runs the moves, in order, and keeps the board's connection."""

    def __init__(
        self,
        config: ArmConfig,
        core: Core,
        port: str,
        baud: int,
        writer: StepWriter,
        refuse: Callable[[Job, str], None],
        write_halt: Callable[[Halt], SerialFault | None],
    ) -> None:
        self.config = config
        self.core = core
        self.port = port
        self.settings = config.server
        self.link = LinkKeeper(config, core, port, baud)
        self.writer = writer
        self._refuse = refuse
        self._write_halt = write_halt
        #: When the link was last checked at the end of a set-point (CLOCK_MONOTONIC).
        self._watched = 0.0

    def run(self) -> None:
        core = self.core
        try:
            self.link.connect()
            while True:
                work = core.next_task(self.settings.idle_check_interval_s)
                task, job = work.task, work.job
                if task is Task.SHUTDOWN:
                    assert job is not None
                    self._park_and_end(job)
                    return
                if task is Task.RECOVER:
                    self.link.recover()
                elif task is Task.STARTUP:
                    self._startup_park()
                elif task is Task.READBACK:
                    self._read_back()
                elif task is Task.WATCH:
                    self._guarded(self.link.check)
                elif job is not None:  # MOVE or FOLLOW: the job is current, the worker's
                    self._guarded(functools.partial(self._run_job, job, task is Task.FOLLOW))
        except Exception as e:
            log.exception("the worker failed; the server ends")
            ended = core.worker_failed(SerialFault(self.port, f"the driver failed: {e!r}"))
            core.announce()
            ended.settle()
            raise
        finally:
            core.worker_ended()

    def _guarded(self, work: Callable[[], object]) -> None:
        """Run board work; a serial failure becomes the fault state, never a dead worker."""
        try:
            work()
        except SerialFault as e:
            self.link.enter_fault(e)

    def _read_back(self) -> None:
        """The pose after a stop or a cancel, from the board. Until it is read, it is a guess
        from the halted motion, which a link check would take for a reset: a read that a
        stop interrupted is asked again (the core keeps the task)."""
        try:
            if not self.link.read_back():
                log.debug("read-back interrupted by a stop: asked again")
        except SerialFault as e:
            self.link.enter_fault(e)

    def _startup_park(self) -> None:
        """D1, VE03: park once, at half speed where the board allows it, before `ready`."""
        core = self.core
        board = core.board
        if board is None:
            return
        self._guarded(lambda: self.link.read_back(board))
        # A joint with no pulse yet goes at full speed (D1): the writer warns of it.
        park = (Step(dict(self.config.presets["park"]), None),)
        fraction = self.settings.startup_speed_fraction
        job = Job(
            ins.preset("park", id="startup"),
            park,
            Future(),
            core.epoch,
            now(),
            fraction,
            Mode.STARTUP,
        )
        if core.start(job) is not None:
            self._guarded(lambda: self._run_job(job))

    def _run_job(self, job: Job, follow: bool = False) -> bool:
        """Run the current job's steps and wait for them; True when it completed (its outcome
        is then set). `follow`: its caller has written its first step (the fast path)."""
        core = self.core
        reason = self.writer.prepare(job)
        if reason:
            if core.let_go(job):
                self._refuse(job, reason)
            return False
        try:
            done = self._drive(job, start=1 if follow else 0)
        except SerialFault as e:
            job.cancel.set()
            if job.mode is not Mode.SHUTDOWN:  # the shutdown reports its own outcome
                reason = str(e) if isinstance(e, BoardReset) else f"the serial link is lost: {e}"
                finish(job, Result.CANCELLED, reason)
            raise
        # Not done: whoever ended it (a stop, a cancel, a fault) sets its outcome.
        if not done and core.let_go(job) and job.mode is Mode.QUEUE:
            finish(job, Result.CANCELLED, "cancelled: the board did not take it")
        core.announce()
        return done

    def _drive(self, job: Job, start: int = 0) -> bool:
        """Run the job's steps from `start`; True when the last is done (its outcome is then
        set). A step after another starts when the one before has run its time (the
        board's pulses are there); only the last waits for `Q` to confirm."""
        core = self.core
        last = len(job.steps) - 1
        for k in range(len(job.steps)):
            job.step = k
            board = core.board_for(job)
            if board is None:
                return False
            if k >= start:
                written = self.writer.write(job, job.steps[k], board)
                if written is None:
                    return False  # a stop or a cancel came first: its STOP stands
                motion = core.step_written(job, written)
                if motion is None:
                    return False
                self.writer.told(job, written, motion)
            written = job.written
            assert written is not None
            # The next step goes out one wire time early, so that it takes effect as this one
            # ends (its bytes are about as many as this one's).
            until = written.t_end if k == last else written.t_end - written.wire_s
            if not self._wait_done(job, board, until, confirm=k == last):
                return False
            if not core.reached(job, job.steps[k].target):
                return False
        if not core.done(job):
            return False
        finish(job, Result.DONE)
        return True

    def _wait_done(self, job: Job, board: SSC32U, t_end: float, confirm: bool = True) -> bool:
        """Wait out the move's time, then (with `confirm`) until `Q` says done. False if
        cancelled. During a long move a `Q` every `moving_check_interval_s` finds a dead
        link early."""
        every = self.settings.moving_check_interval_s
        while (left := t_end - now()) > 0:
            wait = min(left, every)
            if job.stream:
                quiet = self.settings.stream_timeout_s - self.core.stream_quiet(job)
                if quiet <= 0:
                    self._hold(job)
                    return False
                wait = min(wait, quiet)
            if job.cancel.wait(wait):
                return False
            if t_end - now() > every / 2:
                try:
                    self.link.watch(board)
                except Interrupted:
                    return False
        if job.stream:
            return self._set_point_over(board)
        if not confirm or not self.core.q_believed():
            return True  # Q still counts down a stopped move: its '+' says nothing of this one
        deadline = Deadline(COMPLETION_GRACE_S, start=t_end)
        while True:
            try:
                if board.is_done():
                    return True
            except Interrupted:
                return False
            if job.cancel.wait(POLL_INTERVAL_S):
                return False
            if deadline.expired:
                raise SerialFault(
                    self.port, f"Q still says moving {COMPLETION_GRACE_S} s after the move's time"
                )

    def _set_point_over(self, board: SSC32U) -> bool:
        """A set-point is done when its time is over, without `Q`: its stream's next one,
        due any moment, must not wait for a query's answer (up to the USB link's 16 ms
        latency timer) in this thread. The link is still checked every
        `moving_check_interval_s` of a stream (a reset or a pulled cable is a fault then, as
        during any move). False if a stop interrupted the check."""
        if now() - self._watched < self.settings.moving_check_interval_s:
            return True
        self._watched = now()
        try:
            self.link.watch(board)
        except Interrupted:
            return False
        return True

    def _hold(self, job: Job) -> None:
        """The watchdog: the stream of the running set-point has gone quiet mid-move (its
        source stopped, or lost its link): the arm is held where it is, once, as a cancelled
        move is halted (no lock: the next set-point moves it again)."""
        timeout = self.settings.stream_timeout_s
        reason = (
            f"the stream {job.stream} went quiet (no set-point for {timeout:g} s, "
            "server.stream_timeout_s): the arm is held where it is"
        )
        halt = self.core.watchdog(job, timeout, reason)
        if halt is None:
            return  # a set-point came meanwhile, or an event ended the job
        self._write_halt(halt)
        log.warning("watchdog: %s [%s]: %s", job.instr.name, job.instr.id, reason)
        self.core.announce()
        finish(job, Result.CANCELLED, reason)

    def _park_and_end(self, job: Job) -> None:
        """D2: park, wait until parked, then end (the worker returns after this)."""
        core = self.core
        board = core.board
        if board is not None:
            # The arm may be anywhere, still on a move the shutdown cancelled.
            def halt_and_read() -> None:
                self.link.halt_what_was_cancelled(board, "shutdown")
                self.link.read_back(board)

            self._guarded(halt_and_read)
        done = False
        if core.start(job) is not None:
            try:
                done = self._drive(job)
            except SerialFault as e:
                self.link.enter_fault(e)
            core.let_go(job)
            core.announce()
        if done:
            log.info("shutdown: parked")
            return
        if core.board is None:
            reason = f"the serial link is lost ({core.fault}): the arm is not parked"
        else:
            reason = "stopped before the arm reached park: the arm is not parked"
        finish(job, Result.CANCELLED, reason)
        log.error("shutdown: %s", reason)
