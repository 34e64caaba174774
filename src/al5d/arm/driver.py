"""The arm driver's caller side: instructions in, one outcome each; the stop that never waits.

A plain Python API, usable without ROS:

    driver = ArmDriver(config, port)      # port of the board (or of the emulator)
    driver.start()                        # connects and parks (STATE: initializing -> ready)
    outcome = driver.execute(move(base=30, elbow=90))
    driver.submit(stop())                 # a Future[Outcome], resolved at once

Everything here runs in the caller's thread: validation, queueing, stop,
release, cancel and shutdown. The board I/O that may take long is the
worker's (`al5d.arm.worker`); the two meet in `al5d.arm.shared`. An emergency
stop writes STOP itself, without waiting for the worker, the queue or a serial
read, then bumps the epoch so that nothing queued before it is ever sent.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import MAX_ID, MAX_QUOTE, Instruction, Kind, Outcome, Result
from al5d.arm.jobs import Job, Motion, Sent, finish, outcome, resolve, stop_order
from al5d.arm.shared import Shared, tell
from al5d.arm.states import Event, State, next_state, refusal, release_refusal
from al5d.arm.translate import Translator
from al5d.arm.validate import Limits, Step, Steps, check, planned
from al5d.arm.worker import Worker
from al5d.arm.writer import StepWriter
from al5d.clock import now
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import LinkLost, SerialFault

log = logging.getLogger("al5d")

#: How long the outcomes of moves cancelled by a stop wait, so the stop is answered first.
CANCEL_DELAY_S = 0.005
#: Refusals logged a second at most; the rest are counted and said in one line.
REFUSALS_LOGGED_PER_S = 20


class RefusalLog:
    """WARNING lines for refusals, at most REFUSALS_LOGGED_PER_S a second.

    A flood of ten thousand refused instructions a second is one reason ten
    thousand times: the first few are logged, then one line says how many more
    there were. Every refusal still has its outcome; only the log is thinned.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._second = -1
        self._logged = 0
        self._quiet = 0
        self._last = ""

    def refused(self, name: str, ident: str, reason: str) -> None:
        second = int(now())
        with self._lock:
            if second != self._second:
                quiet, last = self._quiet, self._last
                self._second, self._logged, self._quiet = second, 0, 0
            else:
                quiet = 0
            speak = self._logged < REFUSALS_LOGGED_PER_S
            if speak:
                self._logged += 1
            else:
                self._quiet += 1
                self._last = reason
        if quiet:
            log.warning("refused %d more instruction(s) in that second (the last: %s)", quiet, last)
        if speak:
            log.warning("refused %s [%s]: %s", name, ident, reason)

    def close(self) -> None:
        with self._lock:
            quiet, self._quiet = self._quiet, 0
        if quiet:
            log.warning("refused %d more instruction(s) (the last: %s)", quiet, self._last)


class ArmDriver:
    """The arm: instructions in, group moves and stops out, one outcome per instruction."""

    def __init__(self, config: ArmConfig, port: str, baud: int | None = None) -> None:
        self.config = config
        self.port = port
        self.baud = baud or config.server.baud
        self.settings = config.server
        self.translator = Translator(config)
        self.limits = Limits.of(config)
        self.channels = config.channels
        self._channel_of = {name: j.channel for name, j in config.joints.items()}
        self.shared = Shared(config)
        self._refusals = RefusalLog()
        self.writer = StepWriter(self.shared, self.translator)
        self._worker = Worker(config, self.shared, port, self.baud, self.writer)
        self._thread = threading.Thread(target=self._worker.run, name="al5d-worker", daemon=True)
        self.finished = self.shared.finished
        self.outcome_listeners: list[Callable[[Outcome], None]] = self.shared.outcome_listeners
        self.state_listeners: list[Callable[[State], None]] = self.shared.state_listeners
        self.motion_listeners: list[Callable[[Sent], None]] = self.shared.motion_listeners
        #: Told every instruction as it is submitted, before it is judged (the demo's table).
        self.submit_listeners: list[Callable[[Instruction], None]] = []

    # -- public API ---------------------------------------------------------------

    def start(self) -> None:
        """Start the worker: it connects, parks (D1, VE03), then the arm is ready."""
        log.info("STATE: %s", self.shared.state.value)
        log.debug("EVENT: %s", Event.START.value)
        self._thread.start()

    @property
    def state(self) -> State:
        return self.shared.state

    @property
    def locked(self) -> bool:
        return self.shared.locked

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles now (degrees; NaN where unknown since power-up)."""
        return self.shared.positions(t)

    def progress(self, instr_id: str) -> float | None:
        """0..1 of the instruction `instr_id` if it is the one running (by its steps)."""
        job, motion = self.shared.current, self.shared.motion
        if job is None or motion is None or job.instr.id != instr_id:
            return None
        return (job.step + motion.progress(now())) / len(job.steps)

    def validate(self, instr: Instruction) -> Steps | str:
        """The steps of a motion instruction, or the reason to refuse it whole (D3)."""
        return check(instr, self.limits)

    @property
    def epoch(self) -> int:
        """Counts the events that drop every pending move (a stop, a fault, the shutdown)."""
        return self.shared.epoch

    def submit(
        self, instr: Instruction, taken_at: int | None = None, *, listeners: bool = True
    ) -> Future[Outcome]:
        """Hand over an instruction; its Future resolves to its one outcome.

        `taken_at` is the `epoch` when the caller took the instruction in (an action's goal
        accepted): if a stop (or a fault) came since, the move is cancelled by it, as it
        would have been had it waited in the queue. With `listeners=False` no listener
        hears of it (an instruction obeyed a second time, whose outcome was told)."""
        t0 = now()
        future: Future[Outcome] = Future()
        kind = instr.kind
        if kind is Kind.STOP:
            self._stop(instr, future, t0)  # before any listener: a stop waits for nothing
        if self.submit_listeners and listeners:
            tell(self.submit_listeners, instr, "submit")
        if self.outcome_listeners and listeners:
            future.add_done_callback(self._tell_outcome)
        if kind is Kind.RELEASE:
            self._release(instr, future, t0)
        elif kind is Kind.SHUTDOWN:
            self._shutdown(instr, future, t0)
        elif kind is not Kind.STOP:
            self._enqueue(instr, future, t0, taken_at)
        return future

    def refuse(self, ident: str, name: str, reason: str) -> Outcome:
        """Refuse what never became an instruction (a malformed message): logged like any
        refusal, and its outcome told to the outcome listeners (so it is published)."""
        refused = Outcome(ident[:MAX_ID], name[:MAX_QUOTE], Result.REFUSED, reason)
        log.debug("EVENT: %s", Event.REFUSED.value)
        self._refusals.refused(refused.instruction, refused.id, reason)
        tell(self.outcome_listeners, refused, "outcome")
        return refused

    def execute(self, instr: Instruction, timeout: float | None = None) -> Outcome:
        """Submit and wait for the outcome."""
        return self.submit(instr).result(timeout)

    def cancel(self, instr_id: str, reason: str = "cancelled by the client") -> bool:
        """Cancel one move: drop it if it waits; halt the arm (without the lock) if it runs.

        False when the move has already ended (or was never here).
        """
        shared = self.shared
        with shared.lock:
            job = next((j for j in shared.queue if j.instr.id == instr_id), None)
            if job is not None:
                shared.queue.remove(job)
                shared.cv.notify_all()
            else:
                current = shared.current
                job = current if current and current.instr.id == instr_id else None
                if job is None or job is shared.shutdown_job:
                    return False
                job.cancel.set()
                shared.begin_write()
                board = shared.board
                motion, shared.motion = shared.motion, None
                if shared.state is State.MOVING:
                    shared.fire(Event.MOVE_DONE)  # the move has ended: it did not complete
        if job.cancel.is_set():  # it was running: halt where it is
            error = self._halt(board, motion)
            shared.announce()
            with shared.cv:
                shared.end_write()
                if error is None:
                    shared.readback = True
                else:
                    shared.fault = shared.fault or error
                shared.cv.notify_all()
        finish(job, Result.CANCELLED, reason)
        return True

    @property
    def parked_at_end(self) -> bool | None:
        """After a shutdown: whether the arm reached park (None while no shutdown has ended)."""
        job = self.shared.shutdown_job
        if job is None or not job.future.done():
            return None
        return job.future.result().ok

    def wait_for_state(self, state: State, timeout: float = 10.0) -> None:
        """Wait until `state` has been entered and announced (logged, listeners told)."""
        self.shared.wait_announced(state, timeout)

    def close(self, timeout: float = 30.0) -> None:
        """Shut down (park first) unless that has happened, and wait for the worker."""
        if self._thread.is_alive() and self.shared.shutdown_job is None:
            self.submit(ins.shutdown())
        if self._thread.is_alive():
            self._thread.join(timeout)
        board = self.shared.board
        if board is not None:
            board.close()
        self._refusals.close()
        self.finished.set()

    # -- the caller's side ------------------------------------------------------------

    def _tell_outcome(self, future: Future[Outcome]) -> None:
        tell(self.outcome_listeners, future.result(), "outcome")

    def _refuse(self, instr: Instruction, future: Future[Outcome], reason: str, t0: float) -> None:
        log.debug("EVENT: %s", Event.REFUSED.value)
        self._refusals.refused(instr.name[:MAX_QUOTE], instr.id[:MAX_ID], reason)
        resolve(future, outcome(instr, Result.REFUSED, reason, t0))

    def _enqueue(
        self, instr: Instruction, future: Future[Outcome], t0: float, taken_at: int | None = None
    ) -> None:
        steps = check(instr, self.limits)
        if isinstance(steps, str):
            self._refuse(instr, future, steps, t0)
            return
        shared = self.shared
        pose: dict[str, float | None] | None = None
        if not steps:  # a Cartesian move: planned now if the arm is idle, else at its start
            with shared.lock:
                pose = dict(shared.pose) if self._idle() else None
            if pose is not None:
                steps = planned(instr, pose, self.limits, self.translator)
                if isinstance(steps, str):
                    self._refuse(instr, future, steps, t0)
                    return
        if self.writer.race_hook is not None:
            self.writer.race_hook("judged")
        board = None
        with shared.lock:
            if pose is not None and (shared.pose != pose or not self._idle()):
                steps = ()  # another move came first: plan again from where it ends
            if taken_at is not None and taken_at != shared.epoch:
                reason = ""
                cancelled = "cancelled: a stop (or a fault) came after it was accepted"
            elif shared.shutdown_job is not None:
                reason, cancelled = "the server is shutting down", ""
            else:
                reason, cancelled = refusal(shared.state, shared.fault), ""
            if not reason and not cancelled:
                job = Job(instr, steps, future, shared.epoch, t0)
                capacity = self.settings.queue_capacity
                if self._idle() and len(steps) == 1:
                    board = shared.board  # the fast path: this thread writes the move
                    shared.current = job
                    shared.begin_write()
                    shared.fire(Event.MOVE)
                elif len(shared.queue) >= capacity:
                    reason = f"the queue is full ({capacity} moves wait)"
                else:
                    shared.queue.append(job)
                    shared.cv.notify_all()
                    return
        if cancelled:
            resolve(future, outcome(instr, Result.CANCELLED, cancelled, t0))
        elif reason:
            self._refuse(instr, future, reason, t0)
        elif board is not None:
            self.writer.write_alone(job, board)

    def _idle(self) -> bool:
        """An arm at rest with its board: no move runs, is being written, or waits, and its
        pose is not being read back (lock held)."""
        shared = self.shared
        return (
            shared.state is State.READY
            and shared.board is not None
            and shared.current is None
            and shared.handed is None
            and not shared.queue
            and not shared.readback
        )

    def _stop(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        """VE01/D4: halt at once, drop the queue, lock. Never waits for the worker."""
        shared = self.shared
        with shared.lock:
            current, dropped = shared.take_pending()
            shared.locked = True
            shared.begin_write()
            board = shared.board
            motion, shared.motion = shared.motion, None
            shared.fire(Event.STOP)
        error = self._halt(board, motion)
        if board is None:
            error = LinkLost(self.port, "no board connected")
        shared.announce()
        reason = "cancelled by stop"
        if current is not None:
            current.cancel.set()
            if current is not shared.shutdown_job:  # shutdown still ends, with its own outcome
                finish(current, Result.CANCELLED, reason)
        if dropped:
            # A thousand outcomes to hand out (and publish) must not hold up the caller,
            # which may be the ROS executor that has to answer the stop service.
            threading.Thread(
                target=self._cancel_all, args=(dropped, reason), name="al5d-cancel", daemon=True
            ).start()
        with shared.cv:
            shared.end_write()
            if error is None:
                shared.readback = True
            elif shared.fault is None and shared.state is not State.FAULT:
                shared.fault = error
            shared.cv.notify_all()
        note = f"the serial link is lost ({error}); the arm is locked" if error else ""
        if dropped or current:
            log.info("stop: %d move(s) cancelled", len(dropped) + (current is not None))
        resolve(future, outcome(instr, Result.DONE, note, t0))

    def _halt(self, board: SSC32U | None, motion: Motion | None) -> SerialFault | None:
        """STOP every channel first, then take the pose from where the interrupted motion was
        (until the worker's read-back says exactly where). The error if STOP failed."""
        error = None
        if board is not None:
            try:
                board.stop(stop_order(motion, now(), self._channel_of))
            except SerialFault as e:
                error = e
        if motion is not None:
            self.shared.pose.update(motion.at(now()))
            self.shared.distrust_q(motion)
        return error

    @staticmethod
    def _cancel_all(jobs: list[Job], reason: str) -> None:
        # Let the stop's caller answer first (a ROS service reply needs the GIL a few
        # times); the cancelled outcomes are news, not safety, and may come 5 ms later.
        time.sleep(CANCEL_DELAY_S)
        for job in jobs:
            finish(job, Result.CANCELLED, reason)

    def _release(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        shared = self.shared
        with shared.lock:
            state = shared.state
            allowed = next_state(state, Event.RELEASE, shared.guards()) is not None
            if allowed:
                shared.fire(Event.RELEASE)
                shared.locked = False
        if not allowed:
            self._refuse(instr, future, release_refusal(state), t0)
            return
        shared.announce()
        note = "" if state is State.STOPPED else "unlocked; the serial link is still lost"
        resolve(future, outcome(instr, Result.DONE, note, t0))

    def _shutdown(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        shared = self.shared
        current: Job | None = None
        dropped: list[Job] = []
        with shared.lock:
            if shared.shutdown_job is not None:
                reason = "the server is already shutting down"
            else:
                reason = ""
                current, dropped = shared.take_pending()
                park = (Step(dict(self.config.presets["park"]), None),)
                fraction = self.settings.startup_speed_fraction
                shared.shutdown_job = Job(instr, park, future, shared.epoch, t0, fraction)
                shared.fire(Event.SHUTDOWN)
        if reason:
            self._refuse(instr, future, reason, t0)
            return
        shared.announce()
        if current is not None:
            current.cancel.set()
            finish(current, Result.CANCELLED, "cancelled by shutdown")
        for job in dropped:
            finish(job, Result.CANCELLED, "cancelled by shutdown")
