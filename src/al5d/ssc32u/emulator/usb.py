"""The link between the board and the computer: the SSC-32U's FTDI USB chip, or a plain UART.

`LinkModel` is the setting (a frozen value); `FtdiChip` is the chip's buffer towards
the computer, pure arithmetic over byte times, used by the pty link's answer
thread. Only the USB link has the chip.

What the chip does (FTDI AN232B-04): it sends what it holds to the computer
when a packet is full (62 bytes), or when its latency timer runs out. The model
starts the timer when a byte comes into the empty buffer, so a short answer
waits the whole timer: the longest a real chip makes it wait. (A real chip's
timer restarts at every packet it sends, status-only ones included, so a real
wait lies between 0 and the timer; a client that queries right after each
answer gets most of the timer.)
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass

from al5d.ssc32u import facts


class Transport(enum.Enum):
    """What carries the bytes between the computer and the board."""

    #: The SSC-32U's USB port (an FTDI chip): the kernel keeps bytes already written
    #: whatever an output flush says, and short answers wait for the latency timer.
    USB = "usb"
    #: A plain serial line (the board's TTL header on a UART): an output flush drops the
    #: bytes not yet on the wire, and answers come back as the board sends them.
    UART = "uart"


@dataclass(frozen=True, slots=True)
class LinkModel:
    """The link's model: its transport and, on USB, the chip's latency timer.

    `low_latency` says the host has set the port's low-latency mode (Linux
    `ASYNC_LOW_LATENCY`, pyserial's `set_low_latency_mode(True)`), which sets the
    timer to 1 ms. On a pty a client cannot set it (the ioctl is refused), so it is
    a setting of the emulator.
    """

    transport: Transport = Transport.USB
    latency_ms: int = facts.LATENCY_TIMER_MS
    low_latency: bool = False

    def __post_init__(self) -> None:
        if self.latency_ms not in facts.LATENCY_TIMER_RANGE_MS:
            raise ValueError(f"the latency timer is 1..255 ms, not {self.latency_ms}")

    @property
    def flush_drops_unsent(self) -> bool:
        """Does a client's output flush drop the bytes that have not started on the wire?"""
        return self.transport is Transport.UART

    @property
    def hold_s(self) -> float | None:
        """How long the chip holds a short answer (None: no chip on this link)."""
        if self.transport is Transport.UART:
            return None
        ms = facts.LOW_LATENCY_TIMER_MS if self.low_latency else self.latency_ms
        return ms / 1000.0

    def describe(self) -> str:
        if self.transport is Transport.UART:
            return "uart link (an output flush drops unsent bytes; no latency timer)"
        timer = (
            f"low-latency mode ({facts.LOW_LATENCY_TIMER_MS} ms)"
            if self.low_latency
            else f"latency timer {self.latency_ms} ms"
        )
        return f"usb link (an output flush drops nothing written; {timer})"


#: The board's USB port as it is (the default everywhere): an output flush drops nothing
#: written, a short answer waits 16 ms in the chip.
USB = LinkModel()
#: A plain serial line to the board's TTL header: a flush drops unsent bytes, no chip.
UART = LinkModel(Transport.UART)


@dataclass(frozen=True, slots=True)
class Packet:
    """What the chip sends the computer at `t`."""

    t: float
    data: bytes


class FtdiChip:
    """The chip's buffer towards the computer: bytes in at their times, packets out."""

    def __init__(self, hold_s: float, payload: int = facts.USB_PACKET_PAYLOAD) -> None:
        self.hold_s = hold_s
        self.payload = payload
        self._held = bytearray()
        self._timer_at = float("inf")

    @property
    def due(self) -> float:
        """When the held bytes go (inf when none are held)."""
        return self._timer_at if self._held else float("inf")

    def feed(self, arrivals: Sequence[float], data: bytes) -> list[Packet]:
        """Bytes reaching the chip at `arrivals` (in order, after any fed before); the
        packets they make go: full ones, and held ones whose timer ran out first."""
        out: list[Packet] = []
        for t, byte in zip(arrivals, data, strict=True):
            if self._held and t > self._timer_at:
                out.append(self._send(self._timer_at))
            if not self._held:
                self._timer_at = t + self.hold_s
            self._held.append(byte)
            if len(self._held) >= self.payload:
                out.append(self._send(t))
        return out

    def expire(self) -> Packet | None:
        """The held bytes, sent when their timer runs out (None when none are held)."""
        return self._send(self._timer_at) if self._held else None

    def _send(self, t: float) -> Packet:
        packet = Packet(t, bytes(self._held))
        self._held.clear()
        self._timer_at = float("inf")
        return packet


def byte_arrivals(due: float, n: int, baud: int) -> list[float]:
    """When each of the `n` bytes of an answer whose last byte is due at `due` arrives."""
    bt = facts.BITS_PER_BYTE / baud
    return [due - (n - 1 - i) * bt for i in range(n)]
