"""The SSC-32U serial protocol: pure encoding and parsing of commands and answers.

One place for the bytes of the board, used by both sides: the low-level driver
encodes commands and parses answers, the emulator parses commands and encodes
answers. Nothing here does I/O. Used as one namespace
(`from al5d.ssc32u import protocol as p`; `p.GroupMove`, `p.parse_line`). A parser
refuses (`ProtocolError`) bytes the board would never send.
"""

from __future__ import annotations

import operator
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from al5d.ssc32u.facts import (
    ANALOG_PINS,
    BITS_PER_BYTE,
    BLANKS,
    CHANNELS,
    DIGITAL_PINS,
    DONE,
    HIGH,
    LOW,
    MOVING,
    OFFSET_RANGE,
    PULSE_MAX_US,
    PULSE_MIN_US,
    PULSE_OFF,
    QP_RESOLUTION_US,
    REGISTER_VALUES,
    REGISTERS,
    STARTUP_MAX_CHARS,
    STARTUP_QUOTE,
)
from al5d.ssc32u.facts import TIME_MAX_MS as TIME_MAX_MS  # for the callers' checks

# -- the commands as data: one frozen dataclass per command, CR and ESC, the wire time -----
# Shared by both sides: the client's side writes these, the board's side reads them.


CR = b"\r"
ESC = b"\x1b"
#: Sent on its own, ESC ends whatever partial line the board holds without running it.
CANCEL = ESC


class ProtocolError(ValueError):
    """A command that the board would not accept, or an answer that is not the board's."""


@dataclass(frozen=True, slots=True)
class ChannelTarget:
    """One channel of a group move: pulse width in us and an optional speed in us/s."""

    channel: int
    pulse_us: int
    speed_us_s: int | None = None


@dataclass(frozen=True, slots=True)
class GroupMove:
    """`#<ch>P<pw>[S<spd>]...[T<ms>]`: every channel starts and ends together."""

    targets: tuple[ChannelTarget, ...]
    time_ms: int | None = None


@dataclass(frozen=True, slots=True)
class Stop:
    """`STOP<ch>`: the servo stops where its pulse is now."""

    channel: int


@dataclass(frozen=True, slots=True)
class QueryMovement:
    """`Q`: answered `+` while a move runs, `.` when it is complete."""


@dataclass(frozen=True, slots=True)
class QueryPulse:
    """`QP<ch>` (repeated): one byte per channel, pulse width / 10."""

    channels: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class Version:
    """`VER`: answered with the firmware string and CR."""


@dataclass(frozen=True, slots=True)
class PulseOffset:
    """`#<ch>PO<offset>`: a volatile trim of -100..100 us per channel."""

    offsets: tuple[tuple[int, int], ...]


@dataclass(frozen=True, slots=True)
class DigitalOutput:
    """`#<ch>H` / `#<ch>L`: the channel becomes a digital output, high or low."""

    levels: tuple[tuple[int, bool], ...]


@dataclass(frozen=True, slots=True)
class ByteOutput:
    """`#<bank>:<value>`: the 8 channels of a bank (0 = 0..7, ..., 3 = 24..31) as outputs."""

    bank: int
    value: int


@dataclass(frozen=True, slots=True)
class ReadDigital:
    """`A`..`F`, latched `AL`..`FL`: answered ASCII `0` or `1`, no CR."""

    pin: str
    latched: bool = False


@dataclass(frozen=True, slots=True)
class ReadAnalog:
    """`VA`..`VH`: answered one byte, 0 (0 V) to 255 (4.98 V)."""

    pin: str


@dataclass(frozen=True, slots=True)
class ReadRegister:
    """`R<n>`: answered the value in decimal ASCII, then CR."""

    number: int


@dataclass(frozen=True, slots=True)
class WriteRegister:
    """`R<n>=<v>`: stored (EEPROM); most registers act at the next power-up."""

    number: int
    value: int


@dataclass(frozen=True, slots=True)
class DefaultRegisters:
    """`RDFLT`: every register to its default; answered `OK` and CR when done."""


@dataclass(frozen=True, slots=True)
class ShowStartup:
    """`SS`: answered the startup string between double quotes, then CR."""


@dataclass(frozen=True, slots=True)
class AppendStartup:
    """`SSCAT <text>`: the rest of the line, spaces kept, added to the startup string."""

    text: str


@dataclass(frozen=True, slots=True)
class DeleteStartup:
    """`SSDEL<n>`: the last n characters of the startup string deleted."""

    count: int


@dataclass(frozen=True, slots=True)
class Unrecognized:
    """A line the board does not understand; the board ignores it."""

    text: str
    why: str


Command = (
    GroupMove
    | Stop
    | QueryMovement
    | QueryPulse
    | Version
    | PulseOffset
    | DigitalOutput
    | ByteOutput
    | ReadDigital
    | ReadAnalog
    | ReadRegister
    | WriteRegister
    | DefaultRegisters
    | ShowStartup
    | AppendStartup
    | DeleteStartup
)
#: The commands the board answers.
Query = (
    QueryMovement
    | QueryPulse
    | Version
    | ReadDigital
    | ReadAnalog
    | ReadRegister
    | DefaultRegisters
    | ShowStartup
)


def wire_time_s(n_bytes: int, baud: int) -> float:
    """Seconds that `n_bytes` take on an 8N1 line at `baud`."""
    if baud <= 0:
        raise ValueError(f"baud must be positive, got {baud}")
    return n_bytes * BITS_PER_BYTE / baud


# -- the client's side: each command as the bytes the board reads, checked -----------------
# Encodings are minimal (no spaces, no fields the board does not need) because
# every byte costs 10 bit times on the wire.


def _whole(value: object, what: str) -> None:
    """A number the board reads is digits only: `value` must be an integer (numpy's too).
    A float passed on (`1700.0`) went out as `#0P1700.0`, which the board ignores, with
    no error here (an outside try of the driver, with pulses computed from angles)."""
    try:
        if isinstance(value, bool):
            raise TypeError
        operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise ProtocolError(
            f"{what} {value!r} is not a whole number: the board reads digits only (round it first)"
        ) from None


def _check_channel(channel: int) -> None:
    _whole(channel, "channel")
    if channel not in CHANNELS:
        raise ProtocolError(f"channel {channel} is outside 0..31")


def _check_distinct(channels: Sequence[int]) -> None:
    for ch in channels:
        _check_channel(ch)
    if len(set(channels)) != len(channels):
        raise ProtocolError(f"channel given twice in {list(channels)}")


def move_prefix(channel: int) -> str:
    """`#<ch>P`: what comes before a channel's pulse width in a move.

    The one place of the move's format, with `time_suffix`: a caller that encodes
    many moves (the arm's translator) keeps these per channel and adds the pulse.
    """
    return f"#{channel}P"


def time_suffix(time_ms: int | None) -> str:
    """`T<ms>` and the CR that ends a group move; without T when the time is 0 or None."""
    return f"T{time_ms}\r" if time_ms else "\r"


def encode_group_move(targets: Sequence[ChannelTarget], time_ms: int | None = None) -> bytes:
    """`#0P1500S750#1P1600T1000\\r`; S and T only where given (T0 is left out)."""
    if not targets:
        raise ProtocolError("a move needs at least one channel")
    _check_distinct([t.channel for t in targets])
    parts: list[str] = []
    for t in targets:
        _whole(t.pulse_us, f"channel {t.channel}: pulse")
        if t.pulse_us != PULSE_OFF and not PULSE_MIN_US <= t.pulse_us <= PULSE_MAX_US:
            raise ProtocolError(
                f"channel {t.channel}: pulse {t.pulse_us} us is outside "
                f"{PULSE_MIN_US}..{PULSE_MAX_US} (or 0 for off)"
            )
        if t.speed_us_s is None:
            parts.append(f"{move_prefix(t.channel)}{t.pulse_us}")
        else:
            _whole(t.speed_us_s, f"channel {t.channel}: speed")
            if t.speed_us_s <= 0:
                raise ProtocolError(f"channel {t.channel}: speed {t.speed_us_s} must be positive")
            parts.append(f"{move_prefix(t.channel)}{t.pulse_us}S{t.speed_us_s}")
    if time_ms is not None:
        _whole(time_ms, "time")
    if time_ms is not None and not 0 <= time_ms <= TIME_MAX_MS:
        raise ProtocolError(f"time {time_ms} ms is outside 0..{TIME_MAX_MS}")
    parts.append(time_suffix(time_ms))
    return "".join(parts).encode("ascii")


def encode_stop(channels: Iterable[int]) -> bytes:
    """`STOP0\\rSTOP1\\r...`: one command per channel, all in one write."""
    chans = list(channels)
    if not chans:
        raise ProtocolError("stop needs at least one channel")
    _check_distinct(chans)
    return "".join(f"STOP{ch}\r" for ch in chans).encode("ascii")


def encode_query_movement() -> bytes:
    return b"Q\r"


def encode_query_pulse(channels: Iterable[int]) -> bytes:
    """`QP0QP1QP2\\r`: the board answers one byte per channel, in order."""
    chans = list(channels)
    if not chans:
        raise ProtocolError("a pulse query needs at least one channel")
    for ch in chans:
        _check_channel(ch)
    return ("".join(f"QP{ch}" for ch in chans) + "\r").encode("ascii")


def encode_version() -> bytes:
    return b"VER\r"


def encode_pulse_offset(offsets: Mapping[int, int]) -> bytes:
    """`#0PO10#1PO-5\\r`."""
    if not offsets:
        raise ProtocolError("a pulse offset needs at least one channel")
    for ch, off in offsets.items():
        _check_channel(ch)
        _whole(off, f"channel {ch}: offset")
        if off not in OFFSET_RANGE:
            raise ProtocolError(f"channel {ch}: offset {off} us is outside -100..100")
    return ("".join(f"#{ch}PO{off}" for ch, off in offsets.items()) + "\r").encode("ascii")


def encode_digital_output(levels: Mapping[int, bool]) -> bytes:
    """`#0H#1L\\r`."""
    if not levels:
        raise ProtocolError("a digital output needs at least one channel")
    for ch in levels:
        _check_channel(ch)
    return ("".join(f"#{ch}{'H' if hi else 'L'}" for ch, hi in levels.items()) + "\r").encode(
        "ascii"
    )


def encode_byte_output(bank: int, value: int) -> bytes:
    """`#3:123\\r`: bit 0 of the value is the bank's lowest channel."""
    _whole(bank, "bank")
    _whole(value, "byte")
    if bank not in range(4):
        raise ProtocolError(f"bank {bank} is outside 0..3")
    if value not in range(256):
        raise ProtocolError(f"byte {value} is outside 0..255")
    return f"#{bank}:{value}\r".encode("ascii")


def _input_read(read: ReadDigital | ReadAnalog) -> str:
    if isinstance(read, ReadAnalog):
        if read.pin not in ANALOG_PINS or len(read.pin) != 1:
            raise ProtocolError(f"no analog input {read.pin!r}: pins are {ANALOG_PINS}")
        return f"V{read.pin}"
    if read.pin not in DIGITAL_PINS or len(read.pin) != 1:
        raise ProtocolError(f"no digital input {read.pin!r}: pins are {DIGITAL_PINS}")
    return read.pin + ("L" if read.latched else "")


def encode_input_reads(reads: Iterable[ReadDigital | ReadAnalog]) -> bytes:
    """`ABLVA\\r`: one answer byte per read, in order (no separator is needed: no read
    starts with L, so `A` then `BL` cannot be taken for `AL` then `B`)."""
    parts = [_input_read(r) for r in reads]
    if not parts:
        raise ProtocolError("an input read needs at least one pin")
    return ("".join(parts) + "\r").encode("ascii")


def _check_register(number: int) -> None:
    _whole(number, "register")
    if number not in REGISTERS:
        raise ProtocolError(f"register {number} is outside 0..255")


def encode_register_read(number: int) -> bytes:
    _check_register(number)
    return f"R{number}\r".encode("ascii")


def encode_register_write(number: int, value: int) -> bytes:
    _check_register(number)
    _whole(value, "register value")
    if value not in REGISTER_VALUES:
        raise ProtocolError(f"register value {value} is outside -32768..65535")
    return f"R{number}={value}\r".encode("ascii")


def encode_startup_append(text: str) -> bytes:
    """`SSCAT <text>\\r`: the board drops the one blank after SSCAT and keeps the rest."""
    if not text or len(text) > STARTUP_MAX_CHARS:
        raise ProtocolError(f"a startup string part has 1..{STARTUP_MAX_CHARS} characters")
    if any(not 0x20 <= ord(c) <= 0x7E for c in text):
        raise ProtocolError(f"a startup string is printable ASCII: {text!r}")
    return f"SSCAT {text}\r".encode("ascii")


def encode_startup_delete(count: int) -> bytes:
    if count not in range(256):
        raise ProtocolError(f"SSDEL deletes 0..255 characters, not {count}")
    return f"SSDEL{count}\r".encode("ascii")


def encode(command: Command) -> bytes:
    """The bytes of any command, CR included."""
    match command:
        case GroupMove(targets, time_ms):
            return encode_group_move(targets, time_ms)
        case Stop(channel):
            return encode_stop([channel])
        case QueryMovement():
            return encode_query_movement()
        case QueryPulse(channels):
            return encode_query_pulse(channels)
        case Version():
            return encode_version()
        case PulseOffset(offsets):
            return encode_pulse_offset(dict(offsets))
        case DigitalOutput(levels):
            return encode_digital_output(dict(levels))
        case ByteOutput(bank, value):
            return encode_byte_output(bank, value)
        case ReadDigital() | ReadAnalog():
            return encode_input_reads([command])
        case ReadRegister(number):
            return encode_register_read(number)
        case WriteRegister(number, value):
            return encode_register_write(number, value)
        case DefaultRegisters():
            return b"RDFLT\r"
        case ShowStartup():
            return b"SS\r"
        case AppendStartup(text):
            return encode_startup_append(text)
        case DeleteStartup(count):
            return encode_startup_delete(count)
    raise ProtocolError(f"not a command: {command!r}")


# -- the board's answers to queries: encoded by the emulator, parsed by the driver ---------


#: A VER answer's length, for its deadline (`SSC32-V2.50USB\r` is 15 bytes).
VERSION_ANSWER_BYTES = 16


def count_answers(data: bytes, n_answer: int | None) -> int:
    """How many whole answers `data` holds: of `n_answer` bytes each, or lines (None)."""
    return data.count(CR) if n_answer is None else len(data) // n_answer


def last_answer(data: bytes, n_answer: int | None) -> bytes:
    """The last whole answer in `data` (which holds one at least)."""
    if n_answer is None:
        end = data.rindex(CR) + 1
        return data[data.rfind(CR, 0, end - 1) + 1 : end]
    end = len(data) // n_answer * n_answer
    return data[end - n_answer : end]


def parse_movement(answer: bytes) -> bool:
    """True while moving (`+`), False when complete (`.`)."""
    if answer == MOVING:
        return True
    if answer == DONE:
        return False
    raise ProtocolError(f"Q answered {answer!r}, expected b'+' or b'.'")


def encode_pulses(pulses_us: Sequence[int]) -> bytes:
    """The QP answer: one byte per channel, pulse width / 10."""
    return bytes(max(0, min(255, p // QP_RESOLUTION_US)) for p in pulses_us)


def parse_pulses(answer: bytes, channels: Sequence[int]) -> dict[int, int]:
    """Pulse widths in us from a QP answer (resolution 10 us; 0 = no pulse yet)."""
    if len(answer) != len(channels):
        raise ProtocolError(
            f"QP for {len(channels)} channel(s) answered {len(answer)} byte(s): {answer!r}"
        )
    pulses = {ch: b * QP_RESOLUTION_US for ch, b in zip(channels, answer, strict=True)}
    for ch, p in pulses.items():
        if p != PULSE_OFF and not PULSE_MIN_US <= p <= PULSE_MAX_US:
            raise ProtocolError(
                f"QP{ch} answered {p // QP_RESOLUTION_US} ({p} us), "
                f"outside {PULSE_MIN_US}..{PULSE_MAX_US} us"
            )
    return pulses


def parse_version(answer: bytes) -> str:
    """The firmware string of a VER answer (which ends with CR)."""
    if not answer.endswith(CR):
        raise ProtocolError(f"VER answer has no CR: {answer!r}")
    text = answer[:-1]
    if not text or any(b < 0x20 or b > 0x7E for b in text):
        raise ProtocolError(f"VER answer is not printable ASCII: {answer!r}")
    return text.decode("ascii")


def parse_digital(answer: bytes, n: int) -> list[bool]:
    """The levels of a digital read of `n` pins: True for high (`1`)."""
    if len(answer) != n or any(bytes([b]) not in (LOW, HIGH) for b in answer):
        raise ProtocolError(f"a read of {n} digital input(s) answered {answer!r}")
    return [bytes([b]) == HIGH for b in answer]


def _cr_line(answer: bytes, what: str) -> str:
    if not answer.endswith(CR) or any(b < 0x20 or b > 0x7E for b in answer[:-1]):
        raise ProtocolError(f"{what} answer is not printable ASCII then CR: {answer!r}")
    return answer[:-1].decode("ascii")


def parse_register(answer: bytes) -> int:
    """The value of an `R<n>` answer (`1023\\r`, `-50\\r`)."""
    text = _cr_line(answer, "register")
    if not re.fullmatch(r"-?\d+", text):
        raise ProtocolError(f"register answer is not a decimal number: {answer!r}")
    return int(text)


def parse_startup(answer: bytes) -> str:
    """The startup string of an `SS` answer (`"#0P1500;"\\r`)."""
    text = _cr_line(answer, "SS")
    quote = STARTUP_QUOTE.decode("ascii")
    if len(text) < 2 or text[0] != quote or text[-1] != quote:
        raise ProtocolError(f"SS answer is not quoted: {answer!r}")
    return text[1:-1]


# -- the board's side: a received line read into commands, as the board does ---------------
# With the board's rule for how long a group move takes.


# Order matters where one token starts another: STOP and SSDEL before SS, QP before Q,
# VER before VE, RDFLT before R<n>, AL before A.
_TOKEN = re.compile(
    rb"#(?P<ch>\d+)(?:PO(?P<off>[+-]?\d+)|P(?P<pw>\d+)(?:S(?P<spd>\d+))?|(?P<hl>[HL]))"
    rb"|#(?P<bank>\d+):(?P<byte>\d+)"
    rb"|T(?P<t>\d+)"
    rb"|STOP(?P<stop>\d+)"
    rb"|SSDEL(?P<ssdel>\d+)?"
    rb"|(?P<ss>SS)"
    rb"|QP(?P<qp>\d+)"
    rb"|(?P<q>Q)"
    rb"|(?P<ver>VER)"
    rb"|V(?P<analog>[A-H])"
    rb"|(?P<rdflt>RDFLT)"
    rb"|R(?P<reg>\d+)(?:=(?P<val>[+-]?\d+))?"
    rb"|(?P<digital>[A-F])(?P<latched>L)?"
)
_SSCAT = b"SSCAT"


def _startup_append(line: bytes) -> AppendStartup | None:
    """`SSCAT <text>` when the line is one: its text is everything after SSCAT and the one
    blank that follows it, spaces included (UG-39), so it cannot go through the blank-free
    tokens. Line feeds are dropped even there: a CR LF client puts one in every line."""
    line = line.replace(b"\n", b"")
    i = 0
    for letter in _SSCAT:
        while i < len(line) and line[i] in BLANKS:
            i += 1
        if i >= len(line) or line[i] & 0xDF != letter:
            return None
        i += 1
    if i < len(line) and line[i] in b" \t":
        i += 1
    return AppendStartup(line[i:].decode("latin-1"))


def parse_line(line: bytes) -> list[Command] | Unrecognized:
    """The commands of one line (without its CR), as the board reads them.

    Case, spaces, tabs and line feeds do not matter (UG-24). A line that does not
    parse as a whole is returned as `Unrecognized`: the board ignores it, and so
    does the emulator. Pulse widths outside 500..2500 are returned as sent;
    clipping is the board's business, not the grammar's.
    """
    text = line.translate(None, BLANKS).upper()
    shown = line.decode("ascii", "replace")
    if not text:
        return Unrecognized(shown, "empty line")
    if (append := _startup_append(line)) is not None:
        return [append]
    commands: list[Command] = []
    targets: list[ChannelTarget] = []
    offsets: list[tuple[int, int]] = []
    levels: list[tuple[int, bool]] = []
    time_ms: int | None = None
    group_at: int | None = None  # where the group move goes among the commands
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            return Unrecognized(shown, f"cannot read {text[pos : pos + 12]!r} at column {pos}")
        pos = m.end()
        g = m.groupdict()
        if g["ch"] is not None:
            ch = int(g["ch"])
            if ch not in CHANNELS:
                return Unrecognized(shown, f"channel {ch} is outside 0..31")
            if g["off"] is not None:
                offsets.append((ch, int(g["off"])))
            elif g["hl"] is not None:
                levels.append((ch, g["hl"] == b"H"))
            else:
                spd = int(g["spd"]) if g["spd"] is not None else None
                targets.append(ChannelTarget(ch, int(g["pw"]), spd))
                if group_at is None:
                    group_at = len(commands)
        elif g["bank"] is not None:
            bank, value = int(g["bank"]), int(g["byte"])
            if bank not in range(4) or value not in range(256):
                return Unrecognized(shown, f"byte output #{bank}:{value} is outside 0..3:0..255")
            commands.append(ByteOutput(bank, value))
        elif g["t"] is not None:
            time_ms = int(g["t"])
            if group_at is None:
                group_at = len(commands)
        elif g["stop"] is not None:
            commands.append(Stop(int(g["stop"])))
        elif g["qp"] is not None:
            ch = int(g["qp"])
            if commands and isinstance(commands[-1], QueryPulse):
                commands[-1] = QueryPulse((*commands[-1].channels, ch))
            else:
                commands.append(QueryPulse((ch,)))
        elif g["q"] is not None:
            commands.append(QueryMovement())
        elif g["ver"] is not None:
            commands.append(Version())
        elif m.group().startswith(b"SSDEL"):
            if g["ssdel"] is None:  # not SS, D, EL: a command word is read whole
                return Unrecognized(shown, "SSDEL without a count")
            commands.append(DeleteStartup(int(g["ssdel"])))
        elif g["ss"] is not None:
            commands.append(ShowStartup())
        elif g["analog"] is not None:
            commands.append(ReadAnalog(g["analog"].decode("ascii")))
        elif g["rdflt"] is not None:
            commands.append(DefaultRegisters())
        elif g["reg"] is not None:
            number = int(g["reg"])
            if number not in REGISTERS:
                return Unrecognized(shown, f"register {number} is outside 0..255")
            if g["val"] is None:
                commands.append(ReadRegister(number))
            else:
                commands.append(WriteRegister(number, int(g["val"])))
        else:
            commands.append(ReadDigital(g["digital"].decode("ascii"), g["latched"] is not None))
    if time_ms is not None and not targets:
        return Unrecognized(shown, "T without any channel to move")
    if targets and group_at is not None:
        commands.insert(group_at, GroupMove(tuple(targets), time_ms))
    if offsets:
        commands.append(PulseOffset(tuple(offsets)))
    if levels:
        commands.append(DigitalOutput(tuple(levels)))
    return commands


def group_duration_s(
    moves: Mapping[int, tuple[int, int, int | None]], time_ms: int | None
) -> float:
    """The board's duration rule: max(T, max over channels of |delta pw| / S).

    `moves` maps channel -> (from us, to us, speed us/s or None).
    """
    longest = (time_ms or 0) / 1000.0
    for start, end, speed in moves.values():
        if speed:
            longest = max(longest, abs(end - start) / speed)
    return longest
