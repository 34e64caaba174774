"""The high-level driver: joints in degrees, limits, presets, the move queue and the safety states.

A plain Python API, usable without ROS:

    driver = ArmDriver(config, port)      # port of the board (or of the emulator)
    driver.start()                        # connects and parks (STATE: initializing -> ready)
    outcome = driver.execute(move(base=30, elbow=90))
    driver.submit(stop())                 # a Future[Outcome], resolved at once

Threads. One worker runs the moves in order, waits for each to complete (its
time, then `Q`), and does the board I/O that may take long. Everything else
(validation, queueing, stop, release) runs in the caller's thread. One lock
guards the state, the queue and the epoch; it is never held during I/O.
An emergency stop bumps the epoch, writes STOP itself (it never waits for the
worker), and cancels what was queued; a job whose epoch is old is never sent.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass, field
from enum import Enum

from al5d import instruction as ins
from al5d.config import ArmConfig, Joint
from al5d.instruction import Instruction, Kind, Outcome, Result
from al5d.lowlevel import SSC32U, Interrupted, SerialFault

log = logging.getLogger("al5d")
now = time.monotonic

#: How often `Q` is asked once a move's time is over.
POLL_INTERVAL_S = 0.002
#: How long the outcomes of moves cancelled by a stop wait, so the stop is answered first.
CANCEL_DELAY_S = 0.005
#: While a move runs, the link is checked this often (a Q is 3 bytes: 1 % of 9600 baud).
HEALTH_INTERVAL_S = 0.25
#: A move whose `Q` still says moving this long after its time is taken as a fault.
COMPLETION_GRACE_S = 2.0


class State(Enum):
    INITIALIZING = "initializing"
    READY = "ready"
    MOVING = "moving"
    STOPPED = "stopped"
    SHUTTING_DOWN = "shutting_down"
    FAULT = "fault"


class Event(Enum):
    START = "start"
    MOVE = "move"
    MOVE_DONE = "move_done"
    STOP = "stop"
    RELEASE = "release"
    SHUTDOWN = "shutdown"
    REFUSED = "refused"
    SERIAL_FAULT = "serial_fault"
    RECONNECTED = "reconnected"


S, E = State, Event
_ALIVE = (S.INITIALIZING, S.READY, S.MOVING, S.STOPPED, S.FAULT)
#: The protocol state machine (D6), plus the fault state. Nothing else may happen.
TRANSITIONS: frozenset[tuple[State, Event, State]] = frozenset(
    {
        (S.INITIALIZING, E.MOVE_DONE, S.READY),  # the start-up park is done
        (S.READY, E.MOVE, S.MOVING),
        (S.MOVING, E.MOVE, S.MOVING),
        (S.MOVING, E.MOVE_DONE, S.MOVING),  # more moves wait
        (S.MOVING, E.MOVE_DONE, S.READY),  # the move list is empty
        (S.READY, E.STOP, S.STOPPED),
        (S.MOVING, E.STOP, S.STOPPED),
        (S.INITIALIZING, E.STOP, S.STOPPED),  # a stop always works, even while parking at start
        (S.STOPPED, E.STOP, S.STOPPED),
        (S.STOPPED, E.RELEASE, S.READY),
        (S.FAULT, E.STOP, S.FAULT),  # locks; the arm stays locked after reconnecting
        (S.FAULT, E.RELEASE, S.FAULT),
        (S.SHUTTING_DOWN, E.STOP, S.SHUTTING_DOWN),
        (S.FAULT, E.RECONNECTED, S.READY),
        (S.FAULT, E.RECONNECTED, S.STOPPED),
        (S.SHUTTING_DOWN, E.SERIAL_FAULT, S.SHUTTING_DOWN),
        *((s, E.SHUTDOWN, S.SHUTTING_DOWN) for s in _ALIVE),
        *((s, E.SERIAL_FAULT, S.FAULT) for s in _ALIVE),
    }
)


class Mode(Enum):
    """Why the worker runs a move, and the states in which it may still be sent."""

    STARTUP = (S.INITIALIZING,)
    QUEUE = (S.READY, S.MOVING)
    SHUTDOWN = (S.SHUTTING_DOWN,)

    @property
    def states(self) -> tuple[State, ...]:
        return self.value  # type: ignore[no-any-return]


class TransitionError(RuntimeError):
    """A transition the state machine does not have: a bug, never a user error."""


@dataclass(slots=True)
class _Job:
    """A motion instruction on its way: validated target, its future, the epoch it belongs to."""

    instr: Instruction
    target: dict[str, float]
    future: Future[Outcome]
    epoch: int
    t_submit: float
    speed_fraction: float = 1.0
    cancel: threading.Event = field(default_factory=threading.Event)
    expected_ms: float = 0.0


@dataclass(frozen=True, slots=True)
class Motion:
    """The move the board is running: from where, to where, when, for how long."""

    start: Mapping[str, float]
    target: Mapping[str, float]
    t0: float
    duration_s: float

    def at(self, t: float) -> dict[str, float]:
        f = 1.0 if self.duration_s <= 0 else min(1.0, max(0.0, (t - self.t0) / self.duration_s))
        return {j: s + (self.target.get(j, s) - s) * f for j, s in self.start.items()}

    def progress(self, t: float) -> float:
        return 1.0 if self.duration_s <= 0 else min(1.0, max(0.0, (t - self.t0) / self.duration_s))


@dataclass(frozen=True, slots=True)
class Sent:
    """A move as it left for the board: for listeners that measure (the demo's QoS table)."""

    instr: Instruction
    data: bytes
    t_submit: float  # when the instruction reached the driver
    t_write: float  # when its bytes were written
    motion: Motion


def _outcome(job_or_instr: _Job | Instruction, result: Result, reason: str, t0: float) -> Outcome:
    instr = job_or_instr.instr if isinstance(job_or_instr, _Job) else job_or_instr
    expected = job_or_instr.expected_ms if isinstance(job_or_instr, _Job) else 0.0
    return Outcome(
        id=instr.id,
        instruction=instr.name,
        result=result,
        reason=reason,
        elapsed_ms=(now() - t0) * 1000.0,
        expected_ms=expected,
    )


def _resolve(future: Future[Outcome], outcome: Outcome) -> bool:
    """Set the one outcome; False if another thread was first (stop racing completion)."""
    try:
        future.set_result(outcome)
    except InvalidStateError:
        return False
    return True


class Translator:
    """Degrees to pulse widths and move times, through the calibration of each joint.

    Per joint the numbers are looked up once, here: translation is on every
    move's path (the benchmark holds it to 10 us for a 6-joint move).
    """

    def __init__(self, config: ArmConfig) -> None:
        self.joints: dict[str, Joint] = dict(config.joints)
        #: name -> (lowest, highest) degrees: the fast path of validation
        self.ranges = {n: j.range_deg for n, j in self.joints.items()}
        #: name -> ("#<ch>P", pulse at 0 degrees, us per degree)
        self._pulse = {
            n: (f"#{j.channel}P", j.to_us(0.0), j.us_per_deg) for n, j in self.joints.items()
        }
        self._s_per_deg = {n: 1.0 / j.speed_deg_s for n, j in self.joints.items()}

    def minimum_ms(
        self, start: Mapping[str, float | None], target: Mapping[str, float], fraction: float = 1.0
    ) -> float:
        """The physical minimum: the largest |delta| / speed over the joints that move."""
        longest = 0.0
        per_deg = self._s_per_deg
        for name, deg in target.items():
            s = start.get(name)
            if s is not None:
                t = abs(deg - s) * per_deg[name]
                if t > longest:
                    longest = t
        return longest * 1000.0 / fraction

    def encode(self, target: Mapping[str, float], time_ms: int) -> bytes:
        """The group move for `target` (degrees) arriving together in `time_ms`."""
        pulse = self._pulse
        parts = []
        for name, deg in target.items():
            prefix, u0, k = pulse[name]
            parts.append(f"{prefix}{int(u0 + deg * k + 0.5)}")  # pulses are positive: half up
        if time_ms:
            parts.append(f"T{time_ms}\r")
        else:
            parts.append("\r")
        return "".join(parts).encode("ascii")

    def degrees(self, pulses: Mapping[int, int]) -> dict[str, float | None]:
        """Angles from pulse widths read back; None where the channel has no pulse yet."""
        out: dict[str, float | None] = {}
        for name, joint in self.joints.items():
            pw = pulses.get(joint.channel, 0)
            out[name] = joint.to_deg(pw) if pw else None
        return out


class ArmDriver:
    """The arm: instructions in, group moves and stops out, one outcome per instruction."""

    def __init__(
        self,
        config: ArmConfig,
        port: str,
        baud: int | None = None,
    ) -> None:
        self.config = config
        self.port = port
        self.baud = baud or config.server.baud
        self.settings = config.server
        self.translator = Translator(config)
        self.channels = config.channels
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._announce_lock = threading.Lock()
        self._pending_notes: list[tuple[Event, State, State]] = []
        self._state = State.INITIALIZING
        self._announced = State.INITIALIZING  # the state last logged and told to the listeners
        self._locked = False  # stop was pressed and release has not come yet
        self._epoch = 0
        self._queue: deque[_Job] = deque()
        self._current: _Job | None = None
        self._board: SSC32U | None = None
        self._fault: SerialFault | None = None
        self._readback = False
        self._shutdown_job: _Job | None = None
        self._parked = False  # the start-up park has been done
        self._pose: dict[str, float | None] = dict.fromkeys(config.joints)
        self._motion: Motion | None = None
        # After a STOP inside a timed move the board answers Q with '+' until that move's
        # time is over (UG-38); until then a move's completion is judged by time alone.
        self._q_unreliable_until = 0.0
        self._worker = threading.Thread(target=self._run, name="al5d-worker", daemon=True)
        self.finished = threading.Event()
        self.outcome_listeners: list[Callable[[Outcome], None]] = []
        self.state_listeners: list[Callable[[State], None]] = []
        self.motion_listeners: list[Callable[[Sent], None]] = []

    # -- public API ---------------------------------------------------------------

    def start(self) -> None:
        """Start the worker: it connects, parks (D1, VE03), then the arm is ready."""
        log.info("STATE: %s", self._state.value)
        log.debug("EVENT: %s", Event.START.value)
        self._worker.start()

    @property
    def state(self) -> State:
        return self._state

    @property
    def locked(self) -> bool:
        return self._locked

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles now (degrees; NaN where unknown since power-up)."""
        motion = self._motion
        pose = self._pose
        if motion is not None:
            est = motion.at(now() if t is None else t)
            return {j: est.get(j, v if v is not None else math.nan) for j, v in pose.items()}
        return {j: (v if v is not None else math.nan) for j, v in pose.items()}

    def progress(self, instr_id: str) -> float | None:
        """0..1 of the expected time of the move `instr_id` if it is the one running."""
        job, motion = self._current, self._motion
        if job is None or motion is None or job.instr.id != instr_id:
            return None
        return motion.progress(now())

    def submit(self, instr: Instruction) -> Future[Outcome]:
        """Hand over an instruction; its Future resolves to its one outcome."""
        t0 = now()
        future: Future[Outcome] = Future()
        if self.outcome_listeners:
            future.add_done_callback(self._tell_outcome)
        kind = instr.kind
        if kind is Kind.STOP:
            self._stop(instr, future, t0)
        elif kind is Kind.RELEASE:
            self._release(instr, future, t0)
        elif kind is Kind.SHUTDOWN:
            self._shutdown(instr, future, t0)
        else:
            self._enqueue(instr, future, t0)
        return future

    def cancel(self, instr_id: str, reason: str = "cancelled by the client") -> bool:
        """Cancel one move: drop it if it waits; halt the arm (without the lock) if it runs.

        False when the move has already ended (or was never here).
        """
        with self._lock:
            job = next((j for j in self._queue if j.instr.id == instr_id), None)
            if job is not None:
                self._queue.remove(job)
                self._cv.notify_all()
            else:
                job = (
                    self._current if self._current and self._current.instr.id == instr_id else None
                )
                if job is None or job is self._shutdown_job:
                    return False
                job.cancel.set()
                board = self._board
                motion, self._motion = self._motion, None
        if job.cancel.is_set():  # it was running: halt where it is
            error = self._halt(board, motion)
            with self._cv:
                if error is None:
                    self._readback = True
                else:
                    self._fault = self._fault or error
                self._cv.notify_all()
        _resolve(job.future, _outcome(job, Result.CANCELLED, reason, job.t_submit))
        return True

    def execute(self, instr: Instruction, timeout: float | None = None) -> Outcome:
        """Submit and wait for the outcome."""
        return self.submit(instr).result(timeout)

    def wait_for_state(self, state: State, timeout: float = 10.0) -> None:
        """Wait until `state` has been entered and announced (logged, listeners told)."""
        deadline = now() + timeout
        with self._cv:
            while self._announced is not state:
                left = deadline - now()
                if left <= 0:
                    raise TimeoutError(
                        f"state {state.value} not reached in {timeout} s (now {self._state.value})"
                    )
                self._cv.wait(left)

    def close(self, timeout: float = 30.0) -> None:
        """Shut down (park first) unless that has happened, and wait for the worker."""
        if self._worker.is_alive() and self._shutdown_job is None:
            self.submit(ins.shutdown())
        if self._worker.is_alive():
            self._worker.join(timeout)
        board = self._board
        if board is not None:
            board.close()
        self.finished.set()

    # -- validation ---------------------------------------------------------------

    def validate(self, instr: Instruction) -> dict[str, float] | str:
        """The target pose of a motion instruction, or the reason to refuse it whole (D3)."""
        time_ms = instr.time_ms
        if time_ms is not None and not 0 <= time_ms <= self.settings.max_move_time_ms:
            return self._explain(instr)
        if instr.kind is Kind.PRESET:
            pose = self.config.presets.get(instr.preset)
            return dict(pose) if pose is not None else self._explain(instr)
        # One pass for the usual, valid move; a NaN fails the range test like any bad value.
        ranges = self.translator.ranges
        target: dict[str, float] = {}
        for name, deg in instr.joints:
            r = ranges.get(name)
            if r is None or name in target or not r[0] <= deg <= r[1]:
                return self._explain(instr)
            target[name] = deg
        return target if target else self._explain(instr)

    def _explain(self, instr: Instruction) -> str:
        """Every reason to refuse the instruction, naming the joint, the value and the range."""
        problems: list[str] = []
        time_ms = instr.time_ms
        limit = self.settings.max_move_time_ms
        if time_ms is not None and time_ms < 0:
            problems.append(f"time {time_ms} ms is negative")
        elif time_ms is not None and time_ms > limit:
            problems.append(f"time {time_ms} ms is above the limit of {limit} ms")
        if instr.kind is Kind.PRESET:
            if instr.preset not in self.config.presets:
                known = ", ".join(self.config.presets)
                return f"unknown preset {instr.preset!r}; presets are {known}"
            return "; ".join(problems)
        if not instr.joints:
            problems.append("a move names no joint")
        joints = self.translator.joints
        seen: set[str] = set()
        for name, deg in instr.joints:
            joint = joints.get(name)
            if joint is None:
                problems.append(f"unknown joint {name!r}; joints are {', '.join(joints)}")
            elif name in seen:
                problems.append(f"{name} is given twice")
            elif not math.isfinite(deg):
                problems.append(f"{name}: {deg} is not a finite number of degrees")
            elif not joint.range_deg[0] <= deg <= joint.range_deg[1]:
                lo, hi = joint.range_deg
                problems.append(f"{name}: {deg:g} deg is outside the range {lo:g}..{hi:g}")
            seen.add(name)
        return "; ".join(problems)

    # -- the caller's side ----------------------------------------------------------

    def _refuse(self, instr: Instruction, future: Future[Outcome], reason: str, t0: float) -> None:
        log.debug("EVENT: %s", Event.REFUSED.value)
        log.warning("refused %s [%s]: %s", instr.name, instr.id, reason)
        _resolve(future, _outcome(instr, Result.REFUSED, reason, t0))

    def _enqueue(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        target = self.validate(instr)
        if isinstance(target, str):
            self._refuse(instr, future, target, t0)
            return
        with self._lock:
            state = self._state
            if state in (S.READY, S.MOVING, S.INITIALIZING):
                if len(self._queue) >= self.settings.queue_capacity:
                    reason = f"the queue is full ({self.settings.queue_capacity} moves wait)"
                else:
                    self._queue.append(_Job(instr, target, future, self._epoch, t0))
                    self._cv.notify_all()
                    return
            elif state is S.STOPPED:
                reason = "the arm is stopped (emergency stop): send release first"
            elif state is S.FAULT:
                reason = f"the serial link is lost ({self._fault}); reconnecting"
            else:
                reason = "the server is shutting down"
        self._refuse(instr, future, reason, t0)

    def _stop(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        """VE01/D4: halt at once, drop the queue, lock. Never waits for the worker."""
        with self._lock:
            self._epoch += 1
            self._locked = True
            board = self._board
            current = self._current
            dropped = list(self._queue)
            self._queue.clear()
            motion, self._motion = self._motion, None
            new = (
                S.STOPPED
                if self._state in (S.READY, S.MOVING, S.INITIALIZING, S.STOPPED)
                else self._state
            )
            self._transition(Event.STOP, new)
        error = self._halt(board, motion)
        if board is None:
            error = SerialFault("no board connected")
        self._announce()
        reason = "cancelled by stop"
        if current is not None:
            current.cancel.set()
            if current is not self._shutdown_job:  # shutdown still ends, with its own outcome
                _resolve(
                    current.future, _outcome(current, Result.CANCELLED, reason, current.t_submit)
                )
        if dropped:
            # A thousand outcomes to hand out (and publish) must not hold up the caller,
            # which may be the ROS executor that has to answer the stop service.
            threading.Thread(
                target=self._cancel_all, args=(dropped, reason), name="al5d-cancel", daemon=True
            ).start()
        with self._cv:
            if error is None:
                self._readback = True
            elif self._fault is None and self._state is not S.FAULT:
                self._fault = error
            self._cv.notify_all()
        note = f"the serial link is lost ({error}); the arm is locked" if error else ""
        if dropped or current:
            log.info("stop: %d move(s) cancelled", len(dropped) + (current is not None))
        _resolve(future, _outcome(instr, Result.DONE, note, t0))

    def _halt(self, board: SSC32U | None, motion: Motion | None) -> SerialFault | None:
        """STOP every channel first, then take the pose from where the interrupted motion was
        (until the worker's read-back says exactly where). The error if STOP failed."""
        error = None
        if board is not None:
            try:
                board.stop(self.channels)
            except SerialFault as e:
                error = e
        if motion is not None:
            self._pose.update(motion.at(now()))
            self._distrust_q(motion)
        return error

    @staticmethod
    def _cancel_all(jobs: list[_Job], reason: str) -> None:
        # Let the stop's caller answer first (a ROS service reply needs the GIL a few
        # times); the cancelled outcomes are news, not safety, and may come 5 ms later.
        time.sleep(CANCEL_DELAY_S)
        for job in jobs:
            _resolve(job.future, _outcome(job, Result.CANCELLED, reason, job.t_submit))

    def _release(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        with self._lock:
            state = self._state
            if state is S.STOPPED:
                self._locked = False
                self._transition(Event.RELEASE, S.READY)
                reason = ""
            elif state is S.FAULT and self._locked:
                self._locked = False
                self._transition(Event.RELEASE, S.FAULT)
                reason = "unlocked; the serial link is still lost"
            else:
                reason = f"the arm is not stopped (state {state.value}): nothing to release"
        if state is S.STOPPED or (state is S.FAULT and reason.startswith("unlocked")):
            self._announce()
            _resolve(future, _outcome(instr, Result.DONE, reason, t0))
        else:
            self._refuse(instr, future, reason, t0)

    def _shutdown(self, instr: Instruction, future: Future[Outcome], t0: float) -> None:
        with self._lock:
            if self._shutdown_job is not None:
                reason = "the server is already shutting down"
            else:
                reason = ""
                self._epoch += 1
                current = self._current
                dropped = list(self._queue)
                self._queue.clear()
                park = dict(self.config.presets["park"])
                self._shutdown_job = _Job(
                    instr, park, future, self._epoch, t0, self.settings.startup_speed_fraction
                )
                self._transition(Event.SHUTDOWN, S.SHUTTING_DOWN)
                self._cv.notify_all()
        if reason:
            self._refuse(instr, future, reason, t0)
            return
        self._announce()
        if current is not None:
            current.cancel.set()
            _resolve(
                current.future,
                _outcome(current, Result.CANCELLED, "cancelled by shutdown", current.t_submit),
            )
        for job in dropped:
            _resolve(
                job.future, _outcome(job, Result.CANCELLED, "cancelled by shutdown", job.t_submit)
            )

    # -- state machine ------------------------------------------------------------------

    def _transition(self, event: Event, new: State) -> None:
        """Change state (the lock is held); the log lines follow in `_announce`, in order."""
        old = self._state
        if (old, event, new) not in TRANSITIONS:
            raise TransitionError(f"no transition {old.value} --{event.value}--> {new.value}")
        self._state = new
        self._pending_notes.append((event, old, new))
        self._cv.notify_all()

    def _announce(self) -> None:
        """Log the transitions made so far (INF01, INF02) and tell the listeners, in order."""
        with self._announce_lock:
            with self._lock:
                notes, self._pending_notes = self._pending_notes, []
            for event, old, new in notes:
                log.debug("EVENT: %s", event.value)
                if new is not old:
                    log.info("STATE: %s", new.value)
                    for listener in self.state_listeners:
                        listener(new)
                with self._cv:
                    self._announced = new
                    self._cv.notify_all()

    def _tell_outcome(self, future: Future[Outcome]) -> None:
        outcome = future.result()
        for listener in self.outcome_listeners:
            try:
                listener(outcome)
            except Exception:  # a listener must not break the driver
                log.exception("outcome listener failed")

    # -- the worker ------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            if self._connect():
                self._startup_park()
            while True:
                with self._cv:
                    while True:
                        if self._shutdown_job is not None:
                            task: object = self._shutdown_job
                            break
                        if self._fault is not None or self._state is S.FAULT:
                            task = "fault"
                            break
                        if self._readback:
                            self._readback = False
                            task = "readback"
                            break
                        if self._queue:
                            task = self._queue.popleft()
                            break
                        self._cv.wait()
                if isinstance(task, _Job) and task is self._shutdown_job:
                    self._park_and_end(task)
                    return
                if task == "fault":
                    if self._state is not S.FAULT and self._fault is not None:
                        self._enter_fault(self._fault)  # a stop found the link dead
                    self._recover()
                elif task == "readback":
                    self._guarded(self._read_back)
                elif isinstance(task, _Job):
                    self._guarded(functools.partial(self._run_job, task))
        except Exception:
            log.exception("the worker failed; the server ends")
            raise
        finally:
            self.finished.set()
            with self._cv:
                self._cv.notify_all()

    def _guarded(self, work: Callable[[], object]) -> None:
        """Run board work; a serial failure becomes the fault state, never a dead worker."""
        try:
            work()
        except SerialFault as e:
            self._enter_fault(e)

    def _connect(self) -> bool:
        try:
            board = SSC32U(self.port, self.baud)
        except SerialFault as e:
            self._enter_fault(e)
            return False
        log.info("connected to %s on %s at %d baud", board.firmware, self.port, self.baud)
        with self._lock:
            self._board = board
        return True

    def _read_back(self, board: SSC32U | None = None) -> None:
        """Learn where the servos are from the board (after a stop, at start, after a reconnect)."""
        board = board or self._board
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
        with self._lock:
            self._pose.update(pose)
            self._motion = None
        log.debug(
            "read back: %s", {j: (None if v is None else round(v, 1)) for j, v in pose.items()}
        )

    def _startup_park(self) -> None:
        self._guarded(self._read_back)
        if self._board is None:
            return
        unknown = [j for j, v in self._pose.items() if v is None]
        if unknown:
            log.warning(
                "D1: first command since the board powered up (no pulse on %s): the board "
                "ignores speed and time for it, so this park goes at full servo speed",
                ", ".join(unknown),
            )
        park = ins.preset("park", id="startup")
        job = _Job(
            park,
            dict(self.config.presets["park"]),
            Future(),
            self._epoch,
            now(),
            self.settings.startup_speed_fraction,
        )
        self._guarded(lambda: self._run_job(job, Mode.STARTUP))

    def _plan(self, job: _Job) -> tuple[bytes, int, float]:
        """Bytes, the time to send (ms) and the physical minimum (ms), from where the arm is."""
        minimum = self.translator.minimum_ms(self._pose, job.target, job.speed_fraction)
        min_ms = math.ceil(minimum - 1e-9)
        requested = job.instr.time_ms or 0
        time_ms = max(requested, min_ms)
        if requested and requested < min_ms:
            log.warning(
                "INF03: %s [%s] cannot be done in the requested %d ms; expected %d ms",
                job.instr.name,
                job.instr.id,
                requested,
                time_ms,
            )
        return self.translator.encode(job.target, time_ms), time_ms, minimum

    def _run_job(self, job: _Job, mode: Mode = Mode.QUEUE) -> bool:
        """Send one move and wait for it; True when it completed (its outcome is then set)."""
        with self._lock:
            board = self._board
            stale = job.epoch != self._epoch or board is None or self._state not in mode.states
            if not stale:
                self._current = job
                if mode is Mode.QUEUE:
                    self._transition(Event.MOVE, S.MOVING)
        if stale or board is None:
            if mode is not Mode.SHUTDOWN:
                reason = "cancelled by stop"
                _resolve(job.future, _outcome(job, Result.CANCELLED, reason, job.t_submit))
            return False
        self._announce()
        try:
            return self._drive(job, board, mode)
        except SerialFault as e:
            job.cancel.set()
            if mode is not Mode.SHUTDOWN:  # the shutdown reports its own outcome
                reason = f"the serial link is lost: {e}"
                _resolve(job.future, _outcome(job, Result.CANCELLED, reason, job.t_submit))
            raise
        finally:
            with self._lock:
                if self._current is job:
                    self._current = None
                    self._cv.notify_all()

    def _drive(self, job: _Job, board: SSC32U, mode: Mode) -> bool:
        data, time_ms, _ = self._plan(job)
        job.expected_ms = float(time_ms)
        start = {j: v for j, v in self._pose.items() if v is not None}
        t_write = now()
        board.write_command(data)
        # The move starts when its CR reaches the board, one wire time after the write.
        t_sent = t_write + board.wire_time_s(data)
        motion = Motion(start, job.target, t_sent, time_ms / 1000.0)
        with self._lock:
            raced = job.epoch != self._epoch or job.cancel.is_set()
            if not raced:
                self._motion = motion
        if raced:
            # A stop came between our check and our write: its STOP may be older than our move.
            board.stop(self.channels)
            return False
        if self.motion_listeners:
            sent = Sent(job.instr, data, job.t_submit, t_write, motion)
            for listener in self.motion_listeners:
                listener(sent)
        if not self._wait_done(job, board, t_sent + time_ms / 1000.0):
            return False  # cancelled: whoever cancelled has set the outcome
        with self._lock:
            if job.epoch != self._epoch:
                return False
            self._pose.update(job.target)
            self._motion = None
            self._current = None
            if mode is Mode.STARTUP:
                self._parked = True
                self._transition(Event.MOVE_DONE, S.READY)
            elif mode is Mode.QUEUE:
                self._transition(Event.MOVE_DONE, S.MOVING if self._queue else S.READY)
        self._announce()
        _resolve(job.future, _outcome(job, Result.DONE, "", job.t_submit))
        return True

    def _distrust_q(self, stopped: Motion) -> None:
        self._q_unreliable_until = max(self._q_unreliable_until, stopped.t0 + stopped.duration_s)

    def _wait_done(self, job: _Job, board: SSC32U, t_end: float) -> bool:
        """Wait out the move's time, then until `Q` says done. False if cancelled.

        During a long move a `Q` every HEALTH_INTERVAL_S finds a dead link early.
        """
        while (left := t_end - now()) > 0:
            if job.cancel.wait(min(left, HEALTH_INTERVAL_S)):
                return False
            if t_end - now() > HEALTH_INTERVAL_S / 2:
                try:
                    board.is_done()
                except Interrupted:
                    return False
        if now() < self._q_unreliable_until:
            return True  # Q still counts down a stopped move: its '+' says nothing of this one
        deadline = t_end + COMPLETION_GRACE_S
        while True:
            try:
                if board.is_done():
                    return True
            except Interrupted:
                return False
            if job.cancel.wait(POLL_INTERVAL_S):
                return False
            if now() > deadline:
                raise SerialFault(
                    f"{self.port}: Q still says moving {COMPLETION_GRACE_S} s after the move's time"
                )

    def _enter_fault(self, error: SerialFault) -> None:
        log.error("serial fault: %s", error)
        with self._lock:
            self._fault = error
            board, self._board = self._board, None
            self._epoch += 1
            current = self._current
            dropped = list(self._queue)
            self._queue.clear()
            self._motion = None
            if self._state is not S.FAULT:
                new = S.SHUTTING_DOWN if self._state is S.SHUTTING_DOWN else S.FAULT
                self._transition(Event.SERIAL_FAULT, new)
        self._announce()
        if board is not None:
            board.close()
        reason = f"the serial link is lost: {error}"
        for job in ([current] if current is not None else []) + dropped:
            if job is not self._shutdown_job:
                job.cancel.set()
                _resolve(job.future, _outcome(job, Result.CANCELLED, reason, job.t_submit))

    def _recover(self) -> None:
        """Reconnect every few tenths of a second; re-learn the positions; no stale move replays."""
        interval = self.settings.reconnect_interval_s
        while True:
            with self._cv:
                if self._shutdown_job is not None:
                    return
                self._cv.wait(interval)
                if self._shutdown_job is not None:
                    return
            try:
                board = SSC32U(self.port, self.baud)
            except SerialFault as e:
                log.debug("reconnect failed: %s", e)
                continue
            try:
                # The board may still be running what it had before the link dropped:
                # learn the pose once that is over, not halfway.
                deadline = now() + self.settings.max_move_time_ms / 1000.0
                while not board.is_done() and now() < deadline:
                    time.sleep(POLL_INTERVAL_S * 5)
                self._read_back(board)
            except (SerialFault, Interrupted) as e:
                log.debug("reconnect failed: %s", e)
                board.close()  # it holds the port exclusively: the next try must open it
                continue
            with self._lock:
                self._board = board
                self._fault = None
                self._transition(Event.RECONNECTED, S.STOPPED if self._locked else S.READY)
            self._announce()
            log.info("reconnected to %s on %s", board.firmware, self.port)
            if not self._parked and not self._locked:
                self.submit(ins.preset("park", time_ms=None, id="startup"))
            return

    def _park_and_end(self, job: _Job) -> None:
        """D2: park, wait until parked, then end (the worker returns after this)."""
        if self._board is not None:
            self._guarded(self._read_back)  # the arm may have stopped anywhere
        done = False
        if self._board is not None:
            try:
                done = self._run_job(job, Mode.SHUTDOWN)
            except SerialFault as e:
                self._enter_fault(e)
        if not done:
            if self._board is None:
                reason = f"the serial link is lost ({self._fault}): the arm could not be parked"
            else:
                reason = "stopped before the arm reached park"
            _resolve(job.future, _outcome(job, Result.DONE, reason, job.t_submit))
        log.info("shutdown: %s", "parked" if done else job.future.result().reason)
