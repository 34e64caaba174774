"""An emulated board in the same process, on a virtual wire: no pty, no thread, no sleep.

`VirtualWire` puts each byte written at a time on the wire at the board's baud (10
bit times a byte), hands the board (`board.Board`) each line when its CR arrives, and
passes its answers back through the USB chip's buffer (`usb.FtdiChip`) or as a plain
UART would: what the pty link does with threads, done here by arithmetic on times the
caller gives. So a test can run the owner's core against it in virtual time (as fast
as the CPU goes), and `VirtualTransport` serves it to the owner in real time.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from al5d.clock import now
from al5d.ssc32u import facts
from al5d.ssc32u.emulator.board import Board, Fault, Record
from al5d.ssc32u.emulator.pty import MAX_LINE
from al5d.ssc32u.emulator.usb import USB, FtdiChip, LinkModel, Packet, byte_arrivals
from al5d.ssc32u.errors import LinkLost, PortUnavailable
from al5d.ssc32u.transport import Transport


class VirtualWire:
    """The wire between a client and `board`, and the link's model (`usb`)."""

    def __init__(self, board: Board, usb: LinkModel = USB) -> None:
        self.board = board
        self.usb = usb
        self._slots: deque[tuple[float, int]] = deque()  # (arrival, byte)
        self._free = 0.0  # when the wire has carried the last byte given to it
        self._line = bytearray()
        hold = usb.hold_s
        self._chip = FtdiChip(hold) if hold is not None else None
        self._answers: deque[Packet] = deque()  # out of the chip (or the UART), in order
        self._pending: list[tuple[float, bytes]] = []  # the board's answers, not yet in the chip

    def write(self, data: bytes, t: float) -> None:
        """`data` written by the client at `t`."""
        bt = facts.BITS_PER_BYTE / self.board.baud
        start = max(t, self._free)
        for byte in data:
            start += bt
            self._slots.append((start, byte))
        self._free = start

    def advance(self, t: float) -> None:
        """Everything that has happened on the wire and the board by `t`."""
        slots = self._slots
        while slots and slots[0][0] <= t:
            arrival, byte = slots.popleft()
            if byte in (0x0D, 0x1B):
                line = bytes(self._line)
                self._line.clear()
                if byte == 0x0D:
                    self._pending.extend(self.board.execute(line, arrival))
                else:
                    self.board.note(Record(arrival, line, (), "cancelled by ESC"))
            elif len(self._line) < MAX_LINE:
                self._line.append(byte)
        self._pending.sort()
        while self._pending and self._pending[0][0] <= t:
            due, data = self._pending.pop(0)
            self._out(due, data)
        chip = self._chip
        if chip is not None and chip.due <= t:
            packet = chip.expire()
            if packet is not None:
                self._answers.append(packet)

    def _out(self, due: float, data: bytes) -> None:
        if self._chip is None:
            self._answers.append(Packet(due, data))
            return
        arrivals = byte_arrivals(due, len(data), self.board.baud)
        self._answers.extend(self._chip.feed(arrivals, data))

    def read(self, t: float) -> bytes:
        """What has reached the client by `t`."""
        self.advance(t)
        out = bytearray()
        while self._answers and self._answers[0].t <= t:
            out += self._answers.popleft().data
        return bytes(out)

    def due(self) -> float | None:
        """When something next happens on the wire or the board (a line's CR or ESC arriving,
        an answer due, the chip's timer running out); None if nothing will."""
        times = [self._answers[0].t] if self._answers else []
        times += [due for due, _ in self._pending[:1]]
        if self._chip is not None and self._chip.due != float("inf"):
            times.append(self._chip.due)
        ends = next((a for a, b in self._slots if b in (0x0D, 0x1B)), None)
        if ends is not None:
            times.append(ends)
        return min(times) if times else None


class VirtualTransport(Transport):
    """The board as a `Transport` in this process: a write lands on the virtual wire at the
    time `clock` says, a read takes what the board has answered by then. The board's
    faults act as on the pty: DISCONNECT fails the link until `reconnect`."""

    def __init__(
        self,
        board: Board,
        usb: LinkModel = USB,
        port: str = "virtual",
        clock: Callable[[], float] = now,
    ) -> None:
        super().__init__(port, board.baud)
        self.board = board
        self.clock = clock
        self.wire = VirtualWire(board, usb)
        self._open = False

    def open(self) -> bool:
        if self.board.has_fault(Fault.DISCONNECT):
            raise PortUnavailable(self.port, f"cannot open: unplugged; {PortUnavailable.advice}")
        self._open = True
        return self.wire.usb.low_latency

    def _check(self, what: str) -> None:
        if not self._open:
            raise LinkLost(self.port, f"{what} failed: the port is closed")
        if self.board.has_fault(Fault.DISCONNECT):
            raise LinkLost(self.port, f"{what} failed: unplugged")

    def _write(self, data: bytes) -> None:
        self._check("write")
        self.wire.write(data, self.clock())

    def read(self) -> bytes:
        self._check("read")
        return self.wire.read(self.clock())

    def due(self) -> float | None:
        return self.wire.due() if self._open else None

    def close(self) -> None:
        self._open = False
