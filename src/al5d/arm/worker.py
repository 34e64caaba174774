"""The arm driver's worker thread: connect, park, run each move until done, recover from faults.

It takes its tasks from the shared state (`Shared.next_task`) and does the
board I/O that may take long: the moves, the wait for their completion (their
time, then `Q`), the read-backs and the reconnects. It never holds the lock
during I/O. The caller's side may stop the arm at any moment; the worker then
finds its job's epoch old or its cancel flag set, and lets go.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
from collections.abc import Callable
from concurrent.futures import Future

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Result
from al5d.arm.jobs import Job, Mode, Motion, Sent, finish, stop_order
from al5d.arm.shared import Shared, tell
from al5d.arm.states import Event, State, Task
from al5d.arm.translate import Translator
from al5d.arm.validate import Step
from al5d.clock import Deadline, now
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import Interrupted, NotAnSSC32U, SerialFault

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
    ) -> None:
        self.config = config
        self.shared = shared
        self.port = port
        self.baud = baud
        self.settings = config.server
        self.translator = Translator(config)
        self.channels = config.channels
        self._channel_of = {name: j.channel for name, j in config.joints.items()}

    def run(self) -> None:
        shared = self.shared
        try:
            self._connect()
            while True:
                task, job = shared.next_task(self.settings.idle_check_interval_s)
                if task is Task.SHUTDOWN:
                    assert job is not None
                    self._park_and_end(job)
                    return
                if task is Task.RECOVER:
                    if shared.state is not State.FAULT and shared.fault is not None:
                        self._enter_fault(shared.fault)  # a stop found the link dead
                    self._recover()
                elif task is Task.STARTUP:
                    self._startup_park()
                elif task is Task.READBACK:
                    self._guarded(self._read_back)
                elif task is Task.WATCH:
                    self._guarded(self._check_link)
                elif job is not None:
                    self._guarded(functools.partial(self._run_job, job))
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
            self._enter_fault(e)

    def _connect(self) -> None:
        try:
            board = SSC32U(self.port, self.baud)
        except SerialFault as e:
            self._enter_fault(e)
            return
        log.info("connected to %s on %s at %d baud", board.firmware, self.port, self.baud)
        with self.shared.lock:
            self.shared.board = board

    def _check_link(self) -> None:
        """An idle arm's link is checked too (a `Q` is 3 bytes: every 0.5 s is 0.6 % of the
        wire at 9600 baud), so that a pulled cable or a silent board is a fault at once, not
        at the next move. A stop never waits for it (the query lock is not the stop's)."""
        board = self.shared.board
        if board is not None:
            with contextlib.suppress(Interrupted):  # a stop flushed the answer: the link lives
                board.is_done()

    def _read_back(self, board: SSC32U | None = None) -> None:
        """Learn where the servos are from the board (after a stop, at start, after a reconnect)."""
        board = board or self.shared.board
        if board is None:
            return
        for _ in range(3):
            try:
                pulses = board.read_pulses(self.channels)
                break
            except Interrupted:
                continue  # another stop flushed the query: ask again
        else:
            return
        pose = self.translator.degrees(pulses)
        with self.shared.lock:
            self.shared.pose.update(pose)
            self.shared.motion = None
        log.debug(
            "read back: %s", {j: (None if v is None else round(v, 1)) for j, v in pose.items()}
        )

    def _startup_park(self) -> None:
        """D1, VE03: park once, at half speed where the board allows it, before `ready`."""
        shared = self.shared
        self._guarded(self._read_back)
        if shared.board is None:
            return
        unknown = [j for j, v in shared.pose.items() if v is None]
        if unknown:
            log.warning(
                "D1: first command since the board powered up (no pulse on %s): the board "
                "ignores speed and time for it, so this park goes at full servo speed",
                ", ".join(unknown),
            )
        park = (Step(dict(self.config.presets["park"]), None),)
        fraction = self.settings.startup_speed_fraction
        job = Job(ins.preset("park", id="startup"), park, Future(), shared.epoch, now(), fraction)
        self._guarded(lambda: self._run_job(job, Mode.STARTUP))

    def _plan(self, job: Job, step: Step) -> tuple[bytes, int]:
        """The bytes and the time to send (ms), from where the arm is."""
        minimum = self.translator.minimum_ms(self.shared.pose, step.target, job.speed_fraction)
        min_ms = math.ceil(minimum - 1e-9)
        requested = step.time_ms or 0
        time_ms = max(requested, min_ms)
        if requested and requested < min_ms:
            point = f" point {job.step}" if len(job.steps) > 1 else ""
            log.warning(
                "INF03: %s [%s]%s cannot be done in the requested %d ms; expected %d ms",
                job.instr.name,
                job.instr.id,
                point,
                requested,
                time_ms,
            )
        return self.translator.encode(step.target, time_ms), time_ms

    def _run_job(self, job: Job, mode: Mode = Mode.QUEUE) -> bool:
        """Send one move and wait for it; True when it completed (its outcome is then set)."""
        shared = self.shared
        with shared.lock:
            board = shared.board
            stale = job.epoch != shared.epoch or board is None or shared.state not in mode.states
            if not stale:
                shared.current = job
                if mode is Mode.QUEUE:
                    shared.fire(Event.MOVE)
        if stale or board is None:
            if mode is not Mode.SHUTDOWN:
                finish(job, Result.CANCELLED, "cancelled by stop")
            return False
        shared.announce()
        try:
            return self._drive(job, board, mode)
        except SerialFault as e:
            job.cancel.set()
            if mode is not Mode.SHUTDOWN:  # the shutdown reports its own outcome
                finish(job, Result.CANCELLED, f"the serial link is lost: {e}")
            raise
        finally:
            with shared.lock:
                if shared.current is job:
                    shared.current = None
                    shared.cv.notify_all()

    def _drive(self, job: Job, board: SSC32U, mode: Mode) -> bool:
        """Run the job's steps in order; True when the last is done (its outcome is then set).

        A step after another starts when the one before has run its time (the board's
        pulses are there); only the last waits for `Q` to confirm.
        """
        shared = self.shared
        last = len(job.steps) - 1
        for k, step in enumerate(job.steps):
            job.step = k
            data, time_ms = self._plan(job, step)
            job.expected_ms += time_ms
            start = {j: v for j, v in shared.pose.items() if v is not None}
            t_write = now()
            board.write_command(data)
            # The move starts when its CR reaches the board, one wire time after the write.
            t_sent = t_write + board.wire_time_s(data)
            motion = Motion(start, step.target, t_sent, time_ms / 1000.0)
            with shared.lock:
                raced = job.epoch != shared.epoch or job.cancel.is_set()
                if not raced:
                    shared.motion = motion
            if raced:
                # A stop came between our check and our write: its STOP may be older than
                # our move.
                board.stop(stop_order(motion, now(), self._channel_of))
                return False
            if shared.motion_listeners:
                sent = Sent(job.instr, data, job.t_submit, t_write, motion)
                tell(shared.motion_listeners, sent, "motion")
            if not self._wait_done(job, board, t_sent + time_ms / 1000.0, confirm=k == last):
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
                    board.is_done()
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

    def _enter_fault(self, error: SerialFault) -> None:
        shared = self.shared
        log.error("serial fault: %s", error)
        with shared.lock:
            shared.fault = error
            board, shared.board = shared.board, None
            current, dropped = shared.take_pending()
            if shared.motion is not None:  # Q counts it down still, if the board goes on with it
                shared.distrust_q(shared.motion)
            shared.motion = None
            if shared.state is not State.FAULT:
                shared.fire(Event.SERIAL_FAULT)
        shared.announce()
        if board is not None:
            board.close()
        reason = f"the serial link is lost: {error}"
        for job in ([current] if current is not None else []) + dropped:
            if job is not shared.shutdown_job:
                job.cancel.set()
                finish(job, Result.CANCELLED, reason)

    def _recover(self) -> None:
        """Reconnect every few tenths of a second; re-learn the positions; no stale move replays."""
        shared = self.shared
        interval = self.settings.reconnect_interval_s
        while True:
            with shared.cv:
                if shared.shutdown_job is not None:
                    return
                shared.cv.wait(interval)
                if shared.shutdown_job is not None:
                    return
            try:
                board = SSC32U(self.port, self.baud)
            except SerialFault as e:
                self._reconnect_failed(e)
                continue
            try:
                self._halt_what_was_cancelled(board)
                self._read_back(board)
            except (SerialFault, Interrupted) as e:
                log.debug("reconnect failed: %s", e)
                board.close()  # it holds the port exclusively: the next try must open it
                continue
            with shared.lock:
                shared.board = board
                shared.fault = None
                shared.fire(Event.RECONNECTED)  # to `initializing` if never parked: see run()
            shared.announce()
            log.info("reconnected to %s on %s", board.firmware, self.port)
            return

    def _halt_what_was_cancelled(self, board: SSC32U) -> None:
        """A board back from a lost link may still be running the move it had: that move was
        cancelled (and its client told so) when the link went, so it is halted here, and the
        pose read back is where the arm stopped, not where a cancelled move was going."""
        if now() < self.shared.q_unreliable_until or not board.is_done():
            board.stop(self.channels)
            log.warning("reconnect: halted the move the board was still running (cancelled)")

    def _reconnect_failed(self, error: SerialFault) -> None:
        """Keep trying; but a device that is not a board is said clearly, once, and becomes
        the fault's reason (a missing port is the usual unplugged cable: quiet)."""
        shared = self.shared
        known = shared.fault
        if not isinstance(error, NotAnSSC32U):
            log.debug("reconnect failed: %s", error)
            return
        if isinstance(known, NotAnSSC32U) and known.received == error.received:
            log.debug("reconnect failed: %s", error)
            return
        log.warning("reconnect: %s", error)
        with shared.lock:
            shared.fault = error

    def _park_and_end(self, job: Job) -> None:
        """D2: park, wait until parked, then end (the worker returns after this)."""
        shared = self.shared
        if shared.board is not None:
            self._guarded(self._read_back)  # the arm may have stopped anywhere
        done = False
        if shared.board is not None:
            try:
                done = self._run_job(job, Mode.SHUTDOWN)
            except SerialFault as e:
                self._enter_fault(e)
        if done:
            log.info("shutdown: parked")
            return
        if shared.board is None:
            reason = f"the serial link is lost ({shared.fault}): the arm is not parked"
        else:
            reason = "stopped before the arm reached park: the arm is not parked"
        finish(job, Result.CANCELLED, reason)
        log.error("shutdown: %s", reason)
