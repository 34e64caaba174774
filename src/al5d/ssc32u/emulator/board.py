"""The emulated SSC-32U's logic: commands in at their time of effect, answers out, servos moving.

No I/O and no threads of its own: the pty link (`al5d.ssc32u.emulator.pty`)
hands each line over when its CR has arrived and writes the answers back when
they are due. Observers (tests, the demo, the benchmarks) read the records and
the servo model from any thread.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import threading
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol

from al5d.clock import Deadline, now
from al5d.ssc32u import facts
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator.servo import DEFAULT_SPEED_US_S, Servo

#: How long the emulated board takes to start answering a query: within the manual's
#: 50 us to 5 ms, near the fast end, as a board that is not busy.
DEFAULT_ANSWER_DELAY_S = 0.0003
GARBAGE = b"\xfe?\x00\xff\r"
HISTORY = 100_000  # commands remembered per channel for reach_time


class Fault(enum.Enum):
    """Faults the emulator can inject on demand."""

    DISCONNECT = "disconnect"  # the adapter is unplugged: the client's I/O fails
    NO_ANSWER = "no_answer"  # queries are not answered
    GARBAGE = "garbage"  # queries are answered with bytes that are not the board's


class ServoJoint(Protocol):
    """A servo on a channel with a linear calibration: what the board model needs of a joint.

    The arm's joint configuration has this shape; the board does not import it.
    """

    @property
    def channel(self) -> int: ...
    @property
    def speed_us_s(self) -> float: ...
    @property
    def us_per_deg(self) -> float: ...
    def to_us(self, deg: float) -> float: ...
    def to_deg(self, us: float) -> float: ...


class ArmDescription(Protocol):
    """Joints by name and named poses: what the emulator takes of an arm's configuration."""

    @property
    def joints(self) -> Mapping[str, ServoJoint]: ...
    @property
    def presets(self) -> Mapping[str, Mapping[str, float]]: ...


@dataclass(frozen=True, slots=True)
class Record:
    """One line as the board received it, with its time of effect (the CR's arrival)."""

    t_effect: float
    raw: bytes
    commands: tuple[p.Command, ...]
    ignored: str | None = None  # why the board did nothing with it

    @property
    def accepted(self) -> bool:
        return self.ignored is None

    def to_json(self) -> str:
        """One line for a record stream (`al5d emulator --record`): time, bytes, why ignored."""
        return json.dumps(
            {
                "t": round(self.t_effect, 6),
                "raw": self.raw.decode("latin-1"),
                "ignored": self.ignored,
            }
        )

    @classmethod
    def from_json(cls, line: str) -> Record:
        """A record read back from a stream; its commands parsed again from its bytes."""
        data = json.loads(line)
        raw = data["raw"].encode("latin-1")
        parsed = p.parse_line(raw)
        commands = () if isinstance(parsed, p.Unrecognized) else tuple(parsed)
        return cls(data["t"], raw, commands, data["ignored"])


Answer = tuple[float, bytes]  # (when its last byte is due at the client, the bytes)


class Board:
    """The board's model: servos, faults, the record of every line, and the answers to queries.

    `config` describes the arm on the channels (speeds, and a calibration for the
    views in degrees); `initial_pose` (degrees) is where the physical servos stand
    at power-up, by default the arm's park pose (where it was switched off, PO01).
    """

    def __init__(
        self,
        config: ArmDescription | None = None,
        *,
        baud: int = facts.FACTORY_BAUD,
        version: str = facts.FIRMWARE,
        answer_delay_s: float = DEFAULT_ANSWER_DELAY_S,
        initial_pose: Mapping[str, float] | None = None,
    ) -> None:
        self.config = config
        self.baud = baud
        self.version = version
        self.answer_delay_s = answer_delay_s
        self._lock = threading.RLock()  # the board's model
        # The records have a lock of their own: an observer that waits for a record
        # never holds up the board (its answers have to come within milliseconds).
        self._changed = threading.Condition(threading.Lock())
        self._records: list[Record] = []
        #: Called with each new record, in the board's thread: keep it short.
        self.record_listeners: list[Callable[[Record], None]] = []
        self._faults: set[Fault] = set()
        self._servos: dict[int, Servo] = {}
        # Per channel: the servo as each command left it, to answer "when did that move arrive".
        self._history: dict[int, deque[Servo]] = {}
        t = now()
        if config is not None:
            pose = initial_pose if initial_pose is not None else config.presets.get("park", {})
            for name, joint in config.joints.items():
                self._servos[joint.channel] = Servo(
                    speed_us_s=joint.speed_us_s,
                    position_us=joint.to_us(pose.get(name, 0.0)),
                    t_position=t,
                )

    # -- faults ------------------------------------------------------------

    def has_fault(self, fault: Fault) -> bool:
        return fault in self._faults

    def inject(self, fault: Fault) -> None:
        """Start a fault (on a bare board, DISCONNECT only marks it; the link acts on it)."""
        with self._lock:
            self._faults.add(fault)

    def clear(self, fault: Fault | None = None) -> None:
        with self._lock:
            if fault is None:
                self._faults.clear()
            else:
                self._faults.discard(fault)

    # -- observation (tests, benchmarks, the demo) ----------------------------

    @property
    def records(self) -> list[Record]:
        with self._changed:
            return list(self._records)

    def clear_records(self) -> None:
        with self._changed:
            self._records.clear()

    def wait_for(
        self, predicate: Callable[[list[Record]], bool], timeout: float = 5.0
    ) -> list[Record]:
        """Wait until `predicate(records)` holds; return the records (raises TimeoutError).

        The predicate sees a copy, outside every lock of the board.
        """
        deadline = Deadline(timeout)
        while True:
            with self._changed:
                seen = len(self._records)
                records = list(self._records)
            if predicate(records):
                return records
            with self._changed:
                while len(self._records) == seen:
                    if deadline.expired:
                        raise TimeoutError(f"emulator: condition not met in {timeout} s")
                    self._changed.wait(deadline.left())

    def pulse_us(self, channel: int, t: float | None = None) -> float:
        """The pulse the board puts out on `channel` (0 when off)."""
        with self._lock:
            servo = self._servos.get(channel)
            return servo.pulse_at(now() if t is None else t) if servo else 0.0

    def servo_us(self, channel: int, t: float | None = None) -> float:
        """Where the physical servo on `channel` is, as a pulse width."""
        with self._lock:
            servo = self._servos.get(channel)
            if servo is None:
                return 0.0
            return servo.position_at(max(now() if t is None else t, servo.t_position))

    def servo_degrees(self, t: float | None = None) -> dict[str, float]:
        """Every configured joint's physical angle, through the calibration."""
        if self.config is None:
            return {}
        return {
            name: j.to_deg(self.servo_us(j.channel, t)) for name, j in self.config.joints.items()
        }

    def _joints(self, joints: Iterable[str] | None, what: str) -> list[tuple[str, ServoJoint]]:
        if self.config is None:
            raise ValueError(f"{what} needs the arm configuration")
        names = list(joints) if joints is not None else list(self.config.joints)
        return [(name, self.config.joints[name]) for name in names]

    def settle_time(self, tol_deg: float = 1.0, joints: Iterable[str] | None = None) -> float:
        """When every joint came (or will come) within `tol_deg` of its final target, to stay."""
        chosen = self._joints(joints, "settle_time")
        with self._lock:
            return max(
                self._servos[j.channel].settle_time(tol_deg * abs(j.us_per_deg)) for _, j in chosen
            )

    def reach_time(
        self, t_effect: float, tol_deg: float = 1.0, joints: Iterable[str] | None = None
    ) -> float | None:
        """When the move that took effect at `t_effect` had every joint within `tol_deg`.

        None if a later command (a move or a STOP) changed one of those joints first:
        that move never arrived. Works after the fact, from the servos' history.
        """
        chosen = self._joints(joints, "reach_time")
        latest = t_effect
        with self._lock:
            for _, joint in chosen:
                snap, later = self._snapshot(joint.channel, t_effect)
                if snap is None:
                    continue  # this joint was not part of that move
                settle = snap.settle_time(tol_deg * abs(joint.us_per_deg))
                if later is not None and later < settle:
                    return None
                latest = max(latest, settle)
        return latest

    def trajectory(
        self, t_effect: float, times: Iterable[float], joints: Iterable[str] | None = None
    ) -> dict[str, tuple[list[float], list[float]]]:
        """Per joint, the commanded pulse and the servo position (both in degrees) at `times`,
        as the move that took effect at `t_effect` left them (for plots)."""
        chosen = self._joints(joints, "trajectory")
        ts = list(times)
        out: dict[str, tuple[list[float], list[float]]] = {}
        with self._lock:
            for name, joint in chosen:
                snap, _ = self._snapshot(joint.channel, t_effect)
                if snap is None:
                    continue
                out[name] = (
                    [joint.to_deg(snap.pulse_at(t)) for t in ts],
                    [joint.to_deg(snap.position_at(t)) for t in ts],
                )
        return out

    def moving(self, t: float | None = None) -> bool:
        with self._lock:
            return self._busy(now() if t is None else t)

    # -- the board -------------------------------------------------------------

    def note(self, rec: Record) -> None:
        """Add a record (the link notes lines it cancelled or could not hear)."""
        with self._changed:
            self._records.append(rec)
            self._changed.notify_all()
        for listener in self.record_listeners:
            listener(rec)

    def execute(self, raw: bytes, t: float) -> list[Answer]:
        """Act on one line whose CR arrived at `t`; the answers it causes, with their due time."""
        parsed = p.parse_line(raw)
        if isinstance(parsed, p.Unrecognized):
            self.note(Record(t, raw, (), parsed.why))
            return []
        notes: list[str] = []
        answers: list[Answer] = []
        with self._lock:
            for cmd in parsed:
                data = self._apply(cmd, t, notes)
                if data is not None and (answer := self._answer(data, t)) is not None:
                    answers.append(answer)
        self.note(Record(t, raw, tuple(parsed), "; ".join(notes) if notes else None))
        return answers

    def _busy(self, t: float) -> bool:
        return any(s.busy_until > t for s in self._servos.values())

    def _servo(self, channel: int, t: float) -> Servo:
        servo = self._servos.get(channel)
        if servo is None:
            servo = Servo(
                speed_us_s=DEFAULT_SPEED_US_S, position_us=facts.PULSE_CENTRE_US, t_position=t
            )
            self._servos[channel] = servo
        return servo

    def _apply(self, cmd: p.Command, t: float, notes: list[str]) -> bytes | None:
        """Carry out one command; the bytes of its answer, if it is a query."""
        match cmd:
            case p.GroupMove():
                self._group_move(cmd, t, notes)
            case p.Stop(channel):
                servo = self._servo(channel, t)
                servo.hold(t)
                self._remember(channel, servo)
            case p.QueryMovement():
                return facts.MOVING if self._busy(t) else facts.DONE
            case p.QueryPulse(channels):
                return p.encode_pulses([round(self._servo(ch, t).pulse_at(t)) for ch in channels])
            case p.Version():
                return self.version.encode("ascii") + p.CR
            case p.PulseOffset(offsets):
                for ch, off in offsets:
                    servo = self._servo(ch, t)
                    servo.advance(t)
                    lo, hi = facts.OFFSET_RANGE[0], facts.OFFSET_RANGE[-1]
                    servo.offset_us = max(lo, min(hi, off))
            case p.DigitalOutput(levels):
                for ch, high in levels:
                    servo = self._servo(ch, t)
                    servo.advance(t)
                    servo.on = False
                    servo.output_high = high
        return None

    def _group_move(self, cmd: p.GroupMove, t: float, notes: list[str]) -> None:
        spans: dict[int, tuple[int, int, int | None]] = {}
        targets: dict[int, int] = {}
        for tgt in cmd.targets:
            pw = tgt.pulse_us
            if pw != facts.PULSE_OFF and not facts.PULSE_MIN_US <= pw <= facts.PULSE_MAX_US:
                clipped = min(facts.PULSE_MAX_US, max(facts.PULSE_MIN_US, pw))
                notes.append(f"channel {tgt.channel}: P{pw} clipped to {clipped}")
                pw = clipped
            targets[tgt.channel] = pw
            servo = self._servo(tgt.channel, t)
            if servo.known and servo.on and pw != facts.PULSE_OFF:
                spans[tgt.channel] = (int(servo.pulse_at(t)), pw, tgt.speed_us_s)
        duration = p.group_duration_s(spans, cmd.time_ms)
        first = [ch for ch, pw in targets.items() if pw and not self._servo(ch, t).known]
        if first:
            notes.append(
                "first command since power-up for channel(s) "
                + ",".join(map(str, first))
                + ": speed and time ignored"
            )
        for ch, pw in targets.items():
            servo = self._servo(ch, t)
            servo.advance(t)
            if pw == facts.PULSE_OFF:
                servo.on = False
                servo.t1 = servo.busy_until = t
                continue
            servo.output_high = None
            if ch in spans:
                servo.start_us = servo.pulse_at(t)
                servo.t1 = servo.busy_until = t + duration
            else:
                servo.start_us = pw
                servo.t1 = servo.busy_until = t
            servo.on = servo.known = True
            servo.end_us = pw
            servo.t0 = t
            self._remember(ch, servo)

    def _snapshot(self, channel: int, t_effect: float) -> tuple[Servo | None, float | None]:
        """The servo as the command at `t_effect` left it, and when the next command came."""
        history = list(self._history.get(channel, ()))
        i = next((k for k, snap in enumerate(history) if snap.t0 == t_effect), None)
        if i is None:
            return None, None
        return history[i], (history[i + 1].t0 if i + 1 < len(history) else None)

    def _remember(self, channel: int, servo: Servo) -> None:
        history = self._history.setdefault(channel, deque(maxlen=HISTORY))
        history.append(dataclasses.replace(servo))

    def _answer(self, data: bytes, t: float) -> Answer | None:
        if Fault.NO_ANSWER in self._faults:
            return None
        if Fault.GARBAGE in self._faults:
            data = GARBAGE
        bt = facts.BITS_PER_BYTE / self.baud
        return (t + self.answer_delay_s + len(data) * bt, data)
