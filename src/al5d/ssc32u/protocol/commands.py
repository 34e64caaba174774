"""The SSC-32U's commands as data: one frozen dataclass per command, and the line's bytes.

Shared by both sides of the protocol (`encode` writes these, `grammar` reads
them); nothing here does I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

from al5d.ssc32u.facts import BITS_PER_BYTE

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
