"""The client's side of the protocol: each command as the bytes the board reads, checked.

Encodings are minimal (no spaces, no fields the board does not need) because
every byte costs 10 bit times on the wire.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

from al5d.ssc32u.facts import (
    ANALOG_PINS,
    CHANNELS,
    DIGITAL_PINS,
    OFFSET_RANGE,
    PULSE_MAX_US,
    PULSE_MIN_US,
    PULSE_OFF,
    REGISTER_VALUES,
    REGISTERS,
    STARTUP_MAX_CHARS,
    TIME_MAX_MS,
)
from al5d.ssc32u.protocol.commands import (
    AppendStartup,
    ByteOutput,
    ChannelTarget,
    Command,
    DefaultRegisters,
    DeleteStartup,
    DigitalOutput,
    GroupMove,
    ProtocolError,
    PulseOffset,
    QueryMovement,
    QueryPulse,
    ReadAnalog,
    ReadDigital,
    ReadRegister,
    ShowStartup,
    Stop,
    Version,
    WriteRegister,
)


def _check_channel(channel: int) -> None:
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
        if t.pulse_us != PULSE_OFF and not PULSE_MIN_US <= t.pulse_us <= PULSE_MAX_US:
            raise ProtocolError(
                f"channel {t.channel}: pulse {t.pulse_us} us is outside "
                f"{PULSE_MIN_US}..{PULSE_MAX_US} (or 0 for off)"
            )
        if t.speed_us_s is None:
            parts.append(f"{move_prefix(t.channel)}{t.pulse_us}")
        else:
            if t.speed_us_s <= 0:
                raise ProtocolError(f"channel {t.channel}: speed {t.speed_us_s} must be positive")
            parts.append(f"{move_prefix(t.channel)}{t.pulse_us}S{t.speed_us_s}")
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
    if number not in REGISTERS:
        raise ProtocolError(f"register {number} is outside 0..255")


def encode_register_read(number: int) -> bytes:
    _check_register(number)
    return f"R{number}\r".encode("ascii")


def encode_register_write(number: int, value: int) -> bytes:
    _check_register(number)
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
