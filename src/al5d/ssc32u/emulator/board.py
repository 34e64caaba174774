"""The emulated SSC-32U's logic: commands in at their time of effect, answers out, servos moving.

No I/O and no threads of its own: the pty link (`al5d.ssc32u.emulator.pty`)
hands each line over when its CR has arrived and writes the answers back when
they are due. Observers (tests, the demo, the benchmarks) read the records and
the servo model from any thread.
"""

from __future__ import annotations

import enum
import threading
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, TypedDict

if TYPE_CHECKING:
    from typing import Unpack  # Python 3.11; only read by the type checker

from al5d.clock import now
from al5d.ssc32u import facts
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator.inputs import Pin, input_level
from al5d.ssc32u.emulator.measure import ArmDescription, Mechanics, ServoJoint, ServoObserver
from al5d.ssc32u.emulator.records import RESET, SERIAL, STARTUP, Answer, Record, RecordLog
from al5d.ssc32u.emulator.servo import DEFAULT_SPEED_US_S, Pulse, Servo

__all__ = [
    "DEFAULT_ANSWER_DELAY_S",
    "RESET",
    "SERIAL",
    "STARTUP",
    "Answer",
    "ArmDescription",
    "Board",
    "BoardSettings",
    "Fault",
    "InputValue",
    "Mechanics",
    "Pulse",
    "Record",
    "ServoJoint",
]

#: How long the emulated board takes to start answering a query: within the manual's
#: 50 us to 5 ms, near the fast end, as a board that is not busy.
DEFAULT_ANSWER_DELAY_S = 0.0003
GARBAGE = b"\xfe?\x00\xff\r"


class Fault(enum.Enum):
    """Faults the emulator can inject on demand."""

    DISCONNECT = "disconnect"  # the adapter is unplugged: the client's I/O fails
    NO_ANSWER = "no_answer"  # queries are not answered
    GARBAGE = "garbage"  # queries are answered with bytes that are not the board's
    # A brown-out: the board restarts at once (an event: it does not stay injected).
    # Pulses off, positions forgotten, latches cleared, then its power-up settings again.
    RESET = "reset"


InputValue = bool | int | str | None


class BoardSettings(TypedDict, total=False):
    """What a board is set to, besides the arm on its channels: the keywords of `Board`
    and `Emulator` (see `Board` for each; an unset one takes the factory's value)."""

    baud: int
    version: str
    answer_delay_s: float
    initial_pose: Mapping[str, float] | None
    inputs: Mapping[str, InputValue] | None
    registers: Mapping[int, int] | None
    startup: str
    power_up: Mapping[int, int] | None
    announce_reset: bool
    mechanics: Mapping[str, Mechanics] | None


def default_registers(baud: int = facts.FACTORY_BAUD) -> dict[int, int]:
    """Every register as `RDFLT` leaves it: 0, but R4 holding the baud / 10."""
    regs = dict.fromkeys(facts.REGISTERS, 0)
    regs[facts.R_BAUD] = baud // 10
    return regs


class Board(RecordLog, ServoObserver):
    """The board's model: servos, inputs, registers, faults and the answers to queries;
    the record of every line (`RecordLog`) and what observers measure (`ServoObserver`).

    `config` describes the arm on the channels (speeds, and a calibration for the
    views in degrees); `initial_pose` (degrees) is where the physical servos stand
    at power-up, by default the arm's park pose (where it was switched off, PO01).

    Power-up state, as a board's EEPROM gives it: `registers` (number -> value),
    `startup` (the startup string, run at power-up; a missing final `;` is added,
    since only terminated commands run) and `power_up` (channel -> pulse us, kept in
    the initial pulse width registers). `startup` and `power_up` also set their
    enable bits in R0. `inputs` sets the input pins (`A`=0/1, `VA`=0..255, or
    "open"; see `inputs.input_level`); unset pins are open. `announce_reset` makes
    a reset send what `SS` would answer, so that a client's handling of unasked-for
    bytes can be tested (the guide mentions nothing a board sends at power-up).
    `mechanics` (joint name -> `Mechanics`) makes the arm on the board other than its
    configuration says, as calibration finds it: `joint_degrees` reads its true angles.
    """

    def __init__(
        self,
        config: ArmDescription | None = None,
        *,
        powered_at: float | None = None,
        **settings: Unpack[BoardSettings],
    ) -> None:
        # The type checker sees a misspelt setting; a caller without one must hear of it too,
        # not get the factory's value for it.
        unknown = sorted(settings.keys() - BoardSettings.__optional_keys__)
        if unknown:
            known = ", ".join(sorted(BoardSettings.__optional_keys__))
            raise TypeError(f"Board: no setting {', '.join(unknown)} (settings: {known})")
        RecordLog.__init__(self)
        ServoObserver.__init__(self)
        self.config = config
        baud = settings.get("baud", facts.FACTORY_BAUD)
        initial_pose = settings.get("initial_pose")
        startup = settings.get("startup", "")
        for name, mech in (settings.get("mechanics") or {}).items():
            if config is None or name not in config.joints:
                known = ", ".join(config.joints) if config is not None else "none without a config"
                raise ValueError(f"mechanics of {name!r}: no such joint (joints: {known})")
            self.mechanics[name] = mech
        self.baud = baud
        self.version = settings.get("version", facts.FIRMWARE)
        self.answer_delay_s = settings.get("answer_delay_s", DEFAULT_ANSWER_DELAY_S)
        self.announce_reset = settings.get("announce_reset", False)
        self._lock = threading.RLock()  # the board's model
        self._faults: set[Fault] = set()
        self._servos: dict[int, Servo] = {}
        #: Told of each change of a channel's pulses (`observe_pulses`), and what they were told.
        self._pulse_listeners: list[Callable[[int, Pulse], None]] = []
        self._told: dict[int, Pulse] = {}
        self._pins = {pin: Pin() for pin in facts.ANALOG_PINS}
        for name, value in (settings.get("inputs") or {}).items():
            pin, level = input_level(name, value)
            self._pins[pin].level = level
        self._registers = default_registers(baud)
        for number, value in (settings.get("registers") or {}).items():
            self._check_register(number, value)
            self._registers[number] = value
        for ch, pw in (settings.get("power_up") or {}).items():
            if ch not in facts.CHANNELS or not facts.PULSE_MIN_US <= pw <= facts.PULSE_MAX_US:
                raise ValueError(f"power-up pulse {ch}: {pw} us; channels 0..31, 500..2500 us")
            self._registers[facts.R_PULSE_WIDTH + ch] = pw
            self._registers[facts.R_ENABLE] |= facts.ENABLE_PULSE_WIDTH
        self._startup = ""
        if startup:
            end = facts.STARTUP_END
            self._startup = (startup if startup.endswith(end) else startup + end)[
                : facts.STARTUP_MAX_CHARS
            ]
            self._registers[facts.R_ENABLE] |= facts.ENABLE_STARTUP_STRING
        self._tx_free = float("-inf")  # when the board's serial output has sent its last answer
        #: When the board last powered up (a reset is one): a partial line from before is lost.
        self.powered_at = t = now() if powered_at is None else powered_at
        if config is not None:
            pose = initial_pose if initial_pose is not None else config.presets.get("park", {})
            for name, joint in config.joints.items():
                self._servos[joint.channel] = Servo(
                    speed_us_s=joint.speed_us_s,
                    position_us=joint.to_us(pose.get(name, 0.0)),
                    t_position=t,
                )
        with self._lock:
            self._power_up(t)  # what its startup string would answer goes nowhere: no link yet

    @staticmethod
    def _check_register(number: int, value: int) -> None:
        if number not in facts.REGISTERS or value not in facts.REGISTER_VALUES:
            raise ValueError(f"register R{number}={value}: R0..R255, values -32768..65535")

    # -- faults ------------------------------------------------------------

    def has_fault(self, fault: Fault) -> bool:
        return fault in self._faults

    def inject(self, fault: Fault) -> None:
        """Start a fault (on a bare board, DISCONNECT only marks it; the link acts on it).

        RESET is an event, not a state: the board restarts now (see `reset`) and the fault
        is not kept; the answers its startup string makes go nowhere on a bare board."""
        if fault is Fault.RESET:
            self.reset()
            return
        with self._lock:
            self._faults.add(fault)

    def reset(self, t: float | None = None, announce: bool | None = None) -> list[Answer]:
        """A brown-out and restart at `t` (now): every pulse off (`QP` answers 0), every
        position forgotten (the next move runs at full speed), Q's moves over, latches
        cleared and inputs digital again, offsets and outputs gone; then the power-up
        settings (registers, startup string) apply as at power-up. The physical servos
        stay where they were, limp. Returns the answers the restart sends (the startup
        string's queries, and the `SS` answer if `announce`, by default `announce_reset`).
        """
        t = now() if t is None else t
        announce = self.announce_reset if announce is None else announce
        with self._lock:
            for ch, servo in self._servos.items():
                servo.advance(t)
                self._remember(ch, servo)
            self.note(Record(t, b"", (), "board reset: pulses off, positions forgotten", RESET))
            answers = self._power_up(t)
            if announce and (sent := self._answer(self._startup_answer(), t)) is not None:
                answers.append(sent)
            self._tell_pulses()
        return answers

    def _power_up(self, t: float) -> list[Answer]:
        """The board's start: nothing known, nothing on, then the enabled power-up settings."""
        self.powered_at = t
        self._tx_free = float("-inf")  # a restart ends whatever it was sending
        for servo in self._servos.values():
            servo.advance(t)
            servo.on = servo.known = False
            servo.start_us = servo.end_us = 0.0
            servo.t0 = servo.t1 = servo.busy_until = t
            servo.offset_us = 0
            servo.output_high = None
        for pin in self._pins.values():
            pin.power_up(t)
        enable = self._registers[facts.R_ENABLE]
        if enable & facts.ENABLE_GLOBAL_DISABLE:
            return []
        lo, hi = facts.OFFSET_RANGE[0], facts.OFFSET_RANGE[-1]
        for ch in facts.CHANNELS:
            offset = self._registers[facts.R_PULSE_OFFSET + ch]
            if enable & facts.ENABLE_PULSE_OFFSET and offset:
                self._servo(ch, t).offset_us = max(lo, min(hi, offset))
            pw = self._registers[facts.R_PULSE_WIDTH + ch]
            if enable & facts.ENABLE_PULSE_WIDTH and pw:
                servo = self._servo(ch, t)
                servo.on = servo.known = True
                servo.start_us = servo.end_us = max(facts.PULSE_MIN_US, min(facts.PULSE_MAX_US, pw))
                self._remember(ch, servo)
        answers: list[Answer] = []
        if enable & facts.ENABLE_STARTUP_STRING:
            # Only terminated commands run: the text after the last `;` is not a command yet.
            for command in self._startup.split(facts.STARTUP_END)[:-1]:
                answers += self._execute(command.encode("latin-1"), t, STARTUP)
        return answers

    # -- what the servos are sent (the physical twin follows it) ---------------------

    def observe_pulses(self, listener: Callable[[int, Pulse], None]) -> None:
        """Tell `listener` (channel, `Pulse`) what every channel puts out now, then every
        change of it, in order. It runs in the board's thread under its lock, as each line
        takes effect: it must only hand the pulse on (what the board answers is the same
        with a listener and without)."""
        with self._lock:
            self._pulse_listeners.append(listener)
            self._told = {ch: servo.pulse() for ch, servo in self._servos.items()}
            for ch, pulse in self._told.items():
                listener(ch, pulse)

    def _tell_pulses(self) -> None:
        if not self._pulse_listeners:
            return
        for ch, servo in self._servos.items():
            pulse = servo.pulse()
            if self._told.get(ch) != pulse:
                self._told[ch] = pulse
                for listener in self._pulse_listeners:
                    listener(ch, pulse)

    # -- inputs, registers and the startup string (observers and tests) ---------

    def set_input(self, name: str, value: InputValue, t: float | None = None) -> None:
        """Drive an input pin from now (or `t`): `A`..`H` with 0/1/True/False, `VA`..`VH`
        with 0..255, or None / "open"."""
        pin, level = input_level(name, value)
        with self._lock:
            self._pins[pin].set(now() if t is None else t, level)

    def register(self, number: int) -> int:
        with self._lock:
            return self._registers[number]

    @property
    def startup(self) -> str:
        """The stored startup string."""
        with self._lock:
            return self._startup

    def clear(self, fault: Fault | None = None) -> None:
        with self._lock:
            if fault is None:
                self._faults.clear()
            else:
                self._faults.discard(fault)

    def output(self, channel: int) -> bool | None:
        """The level of `channel` as a digital output (`#<ch>H`/`L`, `#<bank>:<byte>`);
        None while it is not one."""
        with self._lock:
            servo = self._servos.get(channel)
            return servo.output_high if servo else None

    def moving(self, t: float | None = None) -> bool:
        with self._lock:
            return self._busy(now() if t is None else t)

    def execute(self, raw: bytes, t: float) -> list[Answer]:
        """Act on one line whose CR arrived at `t`; its answer, with its due time.

        The board runs a line's commands after its CR and sends their answers as one
        burst, in the order of the queries.
        """
        with self._lock:
            return self._execute(raw, t, SERIAL)

    def _execute(self, raw: bytes, t: float, source: str) -> list[Answer]:
        parsed = p.parse_line(raw)
        if isinstance(parsed, p.Unrecognized):
            self.note(Record(t, raw, (), parsed.why, source))
            return []
        notes: list[str] = []
        data = bytearray()
        delay = 0.0
        for cmd in parsed:
            answer = self._apply(cmd, t, notes)
            if answer is not None:
                data += answer
            if isinstance(cmd, p.DefaultRegisters):
                delay = facts.DEFAULTS_TIME_S  # "may take over a second" before its OK
        self.note(Record(t, raw, tuple(parsed), "; ".join(notes) if notes else None, source))
        self._tell_pulses()
        sent = self._answer(bytes(data), t, delay) if data else None
        return [sent] if sent is not None else []

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
                    self._output(ch, high, t)
            case p.ByteOutput(bank, value):
                for bit in range(8):
                    self._output(bank * 8 + bit, bool(value >> bit & 1), t)
            case p.ReadDigital(pin, latched):
                return self._pins[pin].latched(t) if latched else self._pins[pin].digital(t)
            case p.ReadAnalog(pin):
                return bytes([self._pins[pin].read_analog(t)])
            case p.ReadRegister(number):
                return f"{self._registers[number]}".encode("ascii") + p.CR
            case p.WriteRegister(number, value):
                if value in facts.REGISTER_VALUES:
                    self._registers[number] = value
                else:
                    notes.append(f"R{number}={value}: not a 16-bit value, not stored")
            case p.DefaultRegisters():
                self._registers = default_registers()
                return facts.DEFAULTS_DONE
            case p.ShowStartup():
                return self._startup_answer()
            case p.AppendStartup(text):
                whole = self._startup + text
                if len(whole) > facts.STARTUP_MAX_CHARS:
                    notes.append(f"startup string full: {len(whole) - 100} character(s) dropped")
                self._startup = whole[: facts.STARTUP_MAX_CHARS]
            case p.DeleteStartup(count):
                self._startup = self._startup[: max(0, len(self._startup) - count)]
        return None

    def _output(self, channel: int, high: bool, t: float) -> None:
        servo = self._servo(channel, t)
        servo.advance(t)
        servo.on = False
        servo.output_high = high

    def _startup_answer(self) -> bytes:
        quote = facts.STARTUP_QUOTE
        return quote + self._startup.encode("latin-1") + quote + p.CR

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

    def _answer(self, data: bytes, t: float, delay: float = 0.0) -> Answer | None:
        """The answer's due time: after the board's answer delay, behind any answer it is
        still sending, then its own bytes at the board's baud."""
        if Fault.NO_ANSWER in self._faults:
            return None
        if Fault.GARBAGE in self._faults:
            data = GARBAGE
        bt = facts.BITS_PER_BYTE / self.baud
        start = max(t + self.answer_delay_s + delay, self._tx_free)
        self._tx_free = start + len(data) * bt
        return (self._tx_free, data)
