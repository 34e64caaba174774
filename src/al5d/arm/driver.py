"""The arm driver's caller side: instructions in, one outcome each; the stop that never waits.

A plain Python API, usable without ROS:

    driver = ArmDriver(config, port)      # port of the board (or of the emulator)
    driver.start()                        # connects and parks (STATE: initializing -> ready)
    outcome = driver.execute(move(base=30, elbow=90))
    driver.submit(stop())                 # a Future[Outcome], resolved at once

Everything here runs in the caller's thread: the judgement, the stop's bytes,
an idle arm's first step, a cancel's halt. Every decision about the arm's
state is the protocol's (`al5d.arm.core`, where the rules are written down);
the board I/O that may take long is the worker's (`al5d.arm.worker`). An
emergency stop writes its STOP itself, without waiting for the worker, the
queue or a serial read.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Hashable
from concurrent.futures import Future

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.core import Core
from al5d.arm.effects import Halt, Verdict, tell
from al5d.arm.instruction import MAX_ID, MAX_QUOTE, Instruction, Kind, Outcome, Result
from al5d.arm.jobs import Job, Mode, Sent, Written, finish, outcome, resolve
from al5d.arm.resample import Follow
from al5d.arm.states import Event, State
from al5d.arm.translate import Translator
from al5d.arm.validate import Limits, Step, Ticket, judge
from al5d.arm.worker import Worker
from al5d.arm.writer import StepWriter
from al5d.clock import now, wall_ns
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
        self.limits = Limits.of(config, self.baud)
        self.channels = config.channels
        self.outcome_listeners: list[Callable[[Outcome], None]] = []
        self.state_listeners: list[Callable[[State], None]] = []
        self.motion_listeners: list[Callable[[Sent], None]] = []
        #: Told every instruction as it is submitted, before it is judged (the demo's table).
        self.submit_listeners: list[Callable[[Instruction], None]] = []
        self.core = Core(config, self.state_listeners)
        self._refusals = RefusalLog()
        self.writer = StepWriter(self.core, self.translator, self.limits, self.motion_listeners)
        self._worker = Worker(
            config,
            self.core,
            port,
            self.baud,
            self.writer,
            self._refuse_job,
            self._write_halt,
        )
        self._thread = threading.Thread(target=self._worker.run, name="al5d-worker", daemon=True)
        self.finished = self.core.finished

    # -- public API ---------------------------------------------------------------

    def start(self) -> None:
        """Start the worker: it connects, parks (D1, VE03), then the arm is ready."""
        log.info("STATE: %s", self.core.state.value)
        log.debug("EVENT: %s", Event.START.value)
        self._thread.start()

    @property
    def state(self) -> State:
        return self.core.state

    @property
    def locked(self) -> bool:
        return self.core.locked

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles now (degrees; NaN where unknown since power-up)."""
        return self.core.positions(t)

    def progress(self, instr_id: str) -> float | None:
        """0..1 of the instruction `instr_id` if it is the one running (by its steps)."""
        return self.core.progress(instr_id)

    def judge(self, instr: Instruction, follow: Follow | None = None) -> Ticket | str:
        """The one judgement of a motion instruction (D3): its ticket, to submit as it is,
        or the reason to refuse it whole. `follow`: a trajectory's tolerances, where its
        sender gives them (a FollowJointTrajectory goal)."""
        return judge(instr, self.limits, follow)

    @property
    def epoch(self) -> int:
        """Counts the events that drop every pending move (a stop, a fault, the shutdown)."""
        return self.core.epoch

    def submit(
        self,
        what: Instruction | Ticket,
        *,
        key: Hashable | None = None,
        listeners: bool = True,
        stream: str = "",
        written: bytes | None = None,
    ) -> Future[Outcome]:
        """Hand over an instruction (or a ticket of `judge`); its Future resolves to its one
        outcome.

        `key` identifies a stop message that two readers may both see (`core`, rule 3):
        the second gets the first's future, and no listener hears of it again. With
        `listeners=False` no listener hears of it at all. A move given a `stream` is a
        set-point of it: the latest wins (`core`, the lane of set-points). A stop `written`
        has its STOP on the wire already (these bytes: the stop process wrote them; none
        when the server had): it is obeyed without writing it again."""
        t0 = now()
        instr = what.instr if isinstance(what, Ticket) else what
        # When it was sent: where its channel does not say, now, as the driver takes it.
        sent = instr.sent_ns if instr.sent_ns is not None else wall_ns()
        future: Future[Outcome] = Future()
        kind = instr.kind
        if kind is Kind.STOP:  # before any listener: a stop waits for nothing
            first = self._stop(instr, future, t0, sent, key, written)
            if first is not future:
                return first  # the same stop, obeyed already
        else:
            # A stop the stop process wrote, not yet obeyed here, comes first: a release or a
            # move sent after it is judged as after it (locked), not before.
            board = self.core.board
            if board is not None:
                board.settle_stops()
        if self.submit_listeners and listeners:
            tell(self.submit_listeners, instr, "submit")
        if self.outcome_listeners and listeners:
            future.add_done_callback(self._tell_outcome)
        if kind is Kind.RELEASE:
            self._release(instr, future, t0, sent)
        elif kind is Kind.SHUTDOWN:
            self._shutdown(instr, future, t0, sent)
        elif kind is not Kind.STOP:
            self._enqueue(what, future, t0, sent, stream)
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
        got = self.core.cancel(instr_id)
        if got is None:
            return False
        if isinstance(got, Halt):
            self._write_halt(got)
            job = got.ended.jobs[0]
        else:
            job = got
        self.core.announce()
        finish(job, Result.CANCELLED, reason)
        return True

    @property
    def parked_at_end(self) -> bool | None:
        """After a shutdown: whether the arm reached park (None while no shutdown has ended)."""
        job = self.core.shutdown_job
        if job is None or not job.future.done():
            return None
        return job.future.result().ok

    def wait_for_state(self, state: State, timeout: float = 10.0) -> None:
        """Wait until `state` has been entered and announced (logged, listeners told)."""
        self.core.wait_announced(state, timeout)

    def close(self, timeout: float = 30.0) -> None:
        """Shut down (park first) unless that has happened, and wait for the worker."""
        if self._thread.is_alive() and self.core.shutdown_job is None:
            self.submit(ins.shutdown())
        if self._thread.is_alive():
            self._thread.join(timeout)
        board = self.core.board
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

    def _refuse_job(self, job: Job, reason: str) -> None:
        """A job refused when it was to start (a Cartesian move that cannot be planned from
        where the arm is then): logged and counted like every refusal."""
        self._refuse(job.instr, job.future, reason, job.t_submit)

    def _enqueue(
        self,
        what: Instruction | Ticket,
        future: Future[Outcome],
        t0: float,
        sent: int,
        stream: str = "",
    ) -> None:
        ticket = what if isinstance(what, Ticket) else judge(what, self.limits)
        instr = what.instr if isinstance(what, Ticket) else what
        if isinstance(ticket, str):
            self._refuse(instr, future, ticket, t0)
            return
        if self.writer.race_hook is not None:
            self.writer.race_hook("judged")
        job = Job(instr, ticket.steps, future, 0, t0, sent_ns=sent, stream=stream)
        admission = self.core.admit(job)
        if admission.replaced is not None:
            finish(admission.replaced, Result.CANCELLED, f"replaced by set-point {instr.id}")
        if admission.superseded is not None:
            finish(admission.superseded, Result.CANCELLED, f"superseded by set-point {instr.id}")
        if admission.verdict is Verdict.UNCHANGED:
            self.core.announce()
            resolve(
                future,
                outcome(
                    instr, Result.DONE, "at this set-point, or on its way: nothing written", t0
                ),
            )
        elif admission.verdict in (Verdict.QUEUED, Verdict.SUPERSEDES):
            self.core.announce()
        elif admission.verdict is Verdict.REFUSED:
            self._refuse(instr, future, admission.reason, t0)
        elif admission.verdict is Verdict.CANCELLED:
            resolve(future, outcome(instr, Result.CANCELLED, admission.reason, t0))
        else:
            assert admission.board is not None
            self._write_first(job, admission.board)

    def _write_first(self, job: Job, board: SSC32U) -> None:
        """The fast path: an idle arm's move, written from the caller's thread without the
        hand-over to the worker (a thread wake and the GIL, most of the server's share of
        the latency); the worker then sees it through."""
        core = self.core
        reason = ""
        written: Written | None = None
        error: SerialFault | None = None
        try:
            reason = self.writer.prepare(job)
            if not reason:
                written = self.writer.write(job, job.steps[0], board)
        except SerialFault as e:
            error = e
        except Exception as e:  # a bug: the core must still hear that the write is over
            core.first_written(job, None)
            core.announce()
            finish(job, Result.CANCELLED, f"the driver failed: {e!r}")
            raise
        if reason:
            core.first_written(job, None)
            core.announce()
            self._refuse_job(job, reason)
            return
        motion, ended = core.first_written(job, written, error)
        core.announce()
        if error is not None:
            log.error("serial fault: %s", error)
        elif motion is not None and written is not None:
            self.writer.told(job, written, motion)
        ended.settle()

    def _write_halt(self, halt: Halt, key: Hashable | None = None) -> SerialFault | None:
        """Write a STOP the core decided (a stop's or a cancel's, or a stop message's known by
        `key`: written once, whichever process is first); the error if it failed."""
        if halt.board is None:
            self.core.halt_written(None)
            return LinkLost(self.port, "no board connected")
        error: SerialFault | None = None
        try:
            halt.board.stop(halt.channels, paced=not halt.urgent, key=key)
        except SerialFault as e:
            error = e
        except BaseException as e:  # a bug: the core must still hear that the write is over
            bug = LinkLost(self.port, f"stop could not be written: {e!r}")
            self.core.halt_written(bug).settle()
            self.core.announce()
            raise
        lost = self.core.halt_written(error)
        if lost.jobs or lost.board is not None:
            log.error("serial fault: %s", error)
            self.core.announce()
            lost.settle()
        return error

    def _stop(
        self,
        instr: Instruction,
        future: Future[Outcome],
        t0: float,
        sent: int,
        key: Hashable | None,
        written: bytes | None = None,
    ) -> Future[Outcome]:
        """VE01/D4: halt at once, drop the queue, lock. Never waits for the worker."""
        halt = self.core.stop(future, sent, key)
        board = self.core.board
        if written and board is not None:  # told even when the other reader obeyed it first
            board.written_elsewhere(written)
        if isinstance(halt, Future):
            return halt
        if written is not None:
            error = None
            self.core.halt_written(None)
        else:
            error = self._write_halt(halt, key)
        self.core.announce()
        jobs = halt.ended.jobs
        if jobs:
            # The running move (first) at once; a thousand more outcomes to hand out (and
            # publish) must not hold up the caller, which may be the ROS executor that has
            # to answer the stop service.
            finish(jobs[0], Result.CANCELLED, halt.ended.reason)
            if len(jobs) > 1:
                threading.Thread(
                    target=self._cancel_all,
                    args=(jobs[1:], halt.ended.reason),
                    name="al5d-cancel",
                    daemon=True,
                ).start()
            log.info("stop: %d move(s) cancelled", len(jobs))
        note = f"the serial link is lost ({error}); the arm is locked" if error else ""
        resolve(future, outcome(instr, Result.DONE, note, t0))
        return future

    @staticmethod
    def _cancel_all(jobs: tuple[Job, ...], reason: str) -> None:
        # Let the stop's caller answer first (a ROS service reply needs the GIL a few
        # times); the cancelled outcomes are news, not safety, and may come 5 ms later.
        time.sleep(CANCEL_DELAY_S)
        for job in jobs:
            finish(job, Result.CANCELLED, reason)

    def _release(self, instr: Instruction, future: Future[Outcome], t0: float, sent: int) -> None:
        reason = self.core.release(sent)
        if reason:
            self._refuse(instr, future, reason, t0)
            return
        self.core.announce()
        note = "unlocked; the serial link is still lost" if self.core.state is State.FAULT else ""
        resolve(future, outcome(instr, Result.DONE, note, t0))

    def _shutdown(self, instr: Instruction, future: Future[Outcome], t0: float, sent: int) -> None:
        park = (Step(dict(self.config.presets["park"]), None),)
        fraction = self.settings.startup_speed_fraction
        job = Job(instr, park, future, 0, t0, fraction, Mode.SHUTDOWN, sent)
        ended = self.core.shutdown(job)
        if ended is None:
            self._refuse(instr, future, "the server is already shutting down", t0)
            return
        self.core.announce()
        ended.settle()
