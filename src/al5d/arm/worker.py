"""The arm driver's worker thread: connect, park, run each move until done, recover from faults.

It takes its tasks from the shared state (`Shared.next_task`) and does the
board I/O that may take long: the moves, the wait for their completion (their
time, then `Q`), and, through its `link.Link`, the read-backs, the idle checks
and the reconnects. It never holds the lock during I/O. The caller's side may
stop the arm at any moment; the worker then finds its job's epoch old or its
cancel flag set, and lets go.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from concurrent.futures import Future

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Result
from al5d.arm.jobs import Job, Mode, Written, finish
from al5d.arm.link import Link
from al5d.arm.shared import Shared
from al5d.arm.states import Event, State, Task
from al5d.arm.validate import Limits, Step, planned
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
    """The one thread that runs the moves, in order, and owns the board's connection."""

    def __init__(
        self,
        config: ArmConfig,
        shared: Shared,
        port: str,
        baud: int,
        writer: StepWriter,
    ) -> None:
        self.config = config
        self.shared = shared
        self.port = port
        self.settings = config.server
        self.link = Link(config, shared, port, baud)
        self.writer = writer
        self.limits = Limits.of(config)

    def run(self) -> None:
        shared = self.shared
        try:
            self.link.connect()
            while True:
                task, job, written = shared.next_task(self.settings.idle_check_interval_s)
                if task is Task.SHUTDOWN:
                    assert job is not None
                    self._park_and_end(job)
                    return
                if task is Task.RECOVER:
                    if shared.state is not State.FAULT and shared.fault is not None:
                        self.link.enter_fault(shared.fault)  # a stop found the link dead
                    self.link.recover()
                elif task is Task.STARTUP:
                    self._startup_park()
                elif task is Task.READBACK:
                    self._read_back()
                elif task is Task.WATCH:
                    self._guarded(self.link.check)
                elif job is not None:
                    self._guarded(functools.partial(self._run_job, job, Mode.QUEUE, written))
        except Exception:
            log.exception("the worker failed; the server ends")
            raise
        finally:
            shared.finished.set()
            with shared.cv:
                shared.cv.notify_all()

    def _guarded(self, work: Callable[[], object]) -> None:
        """Run board work; a serial failure becomes the fault state, never a dead worker."""
        try:
            work()
        except SerialFault as e:
            self.link.enter_fault(e)

    def _read_back(self) -> None:
        """The pose after a stop or a cancel, from the board. Until it is read, it is a guess
        from the halted motion, which a link check would take for a reset: so a read that
        stops kept interrupting is tried again (a fault reads it back on reconnecting)."""
        shared = self.shared
        done = False
        try:
            done = self.link.read_back()
        except SerialFault as e:
            done = True
            self.link.enter_fault(e)
        finally:
            with shared.cv:
                shared.readback = not done and shared.board is not None
                shared.cv.notify_all()

    def _startup_park(self) -> None:
        """D1, VE03: park once, at half speed where the board allows it, before `ready`."""
        shared = self.shared
        self._guarded(self.link.read_back)
        if shared.board is None:
            return
        # A joint with no pulse yet goes at full speed (D1): the writer warns of it.
        park = (Step(dict(self.config.presets["park"]), None),)
        fraction = self.settings.startup_speed_fraction
        job = Job(ins.preset("park", id="startup"), park, Future(), shared.epoch, now(), fraction)
        self._guarded(lambda: self._run_job(job, Mode.STARTUP))

    def _run_job(self, job: Job, mode: Mode = Mode.QUEUE, first: Written | None = None) -> bool:
        """Send a job's moves and wait for them; True when it completed (its outcome is then
        set). With `first`, the caller's thread is current and has written the first step
        (the fast path): the worker sees the job through from there."""
        shared = self.shared
        if not job.steps and not self._plan_now(job):
            return False
        with shared.lock:
            board = shared.board
            stale = job.epoch != shared.epoch or board is None or shared.state not in mode.states
            if not stale and first is None:
                shared.current = job
                if mode is Mode.QUEUE:
                    shared.fire(Event.MOVE)
        if stale or board is None:
            if mode is not Mode.SHUTDOWN:
                finish(job, Result.CANCELLED, "cancelled by stop")
            with shared.lock:
                if shared.current is job:
                    shared.current = None
            return False
        shared.announce()
        try:
            return self._drive(job, board, mode, first)
        except SerialFault as e:
            job.cancel.set()
            if mode is not Mode.SHUTDOWN:  # the shutdown reports its own outcome
                reason = str(e) if isinstance(e, BoardReset) else f"the serial link is lost: {e}"
                finish(job, Result.CANCELLED, reason)
            raise
        finally:
            with shared.lock:
                if shared.current is job:
                    shared.current = None
                    shared.cv.notify_all()

    def _plan_now(self, job: Job) -> bool:
        """Plan a Cartesian move from where the arm is now; refuse it (False) if it cannot be."""
        with self.shared.lock:
            pose = dict(self.shared.pose)
        steps = planned(job.instr, pose, self.limits, self.writer.translator)
        if isinstance(steps, str):
            log.warning("refused %s [%s]: %s", job.instr.name, job.instr.id, steps)
            finish(job, Result.REFUSED, steps)
            return False
        job.steps = steps
        return True

    def _drive(self, job: Job, board: SSC32U, mode: Mode, first: Written | None = None) -> bool:
        """Run the job's steps in order; True when the last is done (its outcome is then set).

        A step after another starts when the one before has run its time (the board's
        pulses are there); only the last waits for `Q` to confirm. `first` is a first
        step the caller's thread has written already (the fast path).
        """
        shared = self.shared
        last = len(job.steps) - 1
        for k, step in enumerate(job.steps):
            job.step = k
            written = first if k == 0 and first is not None else self.writer.write(job, step, board)
            if written is None:
                return False  # a stop or a cancel came first: its STOP stands, its outcome set
            with shared.lock:
                shared.note_written(written.motion, written.t_end)
            # The next step goes out one wire time early, so that it takes effect as this one
            # ends (its bytes are about as many as this one's).
            until = written.t_end if k == last else written.t_end - written.wire_s
            if not self._wait_done(job, board, until, confirm=k == last):
                return False  # cancelled: whoever cancelled has set the outcome
            with shared.lock:
                if job.epoch != shared.epoch:
                    return False
                shared.pose.update(step.target)
        with shared.lock:
            shared.motion = None
            shared.current = None
            if mode is Mode.STARTUP:
                shared.parked = True
                shared.fire(Event.MOVE_DONE)
            elif mode is Mode.QUEUE:
                shared.fire(Event.MOVE_DONE)
        shared.announce()
        finish(job, Result.DONE)
        return True

    def _wait_done(self, job: Job, board: SSC32U, t_end: float, confirm: bool = True) -> bool:
        """Wait out the move's time, then (with `confirm`) until `Q` says done. False if
        cancelled. During a long move a `Q` every `moving_check_interval_s` finds a dead
        link early."""
        every = self.settings.moving_check_interval_s
        while (left := t_end - now()) > 0:
            if job.cancel.wait(min(left, every)):
                return False
            if t_end - now() > every / 2:
                try:
                    self.link.watch(board)
                except Interrupted:
                    return False
        if not confirm or now() < self.shared.q_unreliable_until:
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

    def _halt_and_read_back(self) -> None:
        board = self.shared.board
        if board is not None:
            self.link.halt_what_was_cancelled(board, "shutdown")
            self.link.read_back(board)

    def _park_and_end(self, job: Job) -> None:
        """D2: park, wait until parked, then end (the worker returns after this)."""
        shared = self.shared
        if shared.board is not None:
            self._guarded(self._halt_and_read_back)  # the arm may be anywhere
        done = False
        if shared.board is not None:
            try:
                done = self._run_job(job, Mode.SHUTDOWN)
            except SerialFault as e:
                self.link.enter_fault(e)
        if done:
            log.info("shutdown: parked")
            return
        if shared.board is None:
            reason = f"the serial link is lost ({shared.fault}): the arm is not parked"
        else:
            reason = "stopped before the arm reached park: the arm is not parked"
        finish(job, Result.CANCELLED, reason)
        log.error("shutdown: %s", reason)
