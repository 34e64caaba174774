"""The board behind one small interface: bytes in, bytes out, and who wrote them.

`Transport` is what the owner of the board (`al5d.owner`) writes to and reads from,
as python-can's `BusABC` stands in front of each bus: `SerialTransport` is a serial
port (the board's USB port, a plain UART, or the emulator's pseudo terminal), and
`al5d.ssc32u.emulator.virtual.VirtualTransport` an emulated board in the same
process, with no pty and no thread. Neither waits for the board: a write hands its
bytes to the port, a read takes what has come. Every transport records the threads
that wrote to it, so that a test can check that one thread did (`writers`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import termios
import threading
from abc import ABC, abstractmethod

import serial

from al5d.ssc32u.errors import LinkLost, PortUnavailable

log = logging.getLogger("al5d")

#: What a dead port raises, depending on the call: pyserial's own, the OS's, and termios's
#: (tcflush on a pty whose master is gone raises termios.error, which is not an OSError).
IO_ERRORS = (serial.SerialException, OSError, termios.error)
#: A write that the port takes no byte of for this long is a lost link.
WRITE_TIMEOUT_S = 0.5


class Transport(ABC):
    """The link to one board at `port`, at `baud`."""

    def __init__(self, port: str, baud: int) -> None:
        self.port = port
        self.baud = baud
        #: The native ids of the threads that have written to it.
        self.writers: set[int] = set()

    @abstractmethod
    def open(self) -> bool:
        """Open the port; whether short answers come at once (the USB chip's low-latency
        mode). Raises PortUnavailable."""

    def write(self, data: bytes) -> None:
        """All of `data` into the port. Raises LinkLost."""
        self.writers.add(threading.get_native_id())
        self._write(data)

    @abstractmethod
    def _write(self, data: bytes) -> None: ...

    @abstractmethod
    def read(self) -> bytes:
        """What has come from the board (b"": nothing yet). Raises LinkLost."""

    def fileno(self) -> int | None:
        """A descriptor that is readable when bytes have come (None: see `due`)."""
        return None

    def due(self) -> float | None:
        """When bytes will come from the board (CLOCK_MONOTONIC), where the transport knows
        it (an emulated board); None where only `fileno` says."""
        return None

    @abstractmethod
    def close(self) -> None:
        """Close the port (closing a dead one does not raise)."""


class SerialTransport(Transport):
    """A serial port through pyserial: a device path (the board's USB port, a UART) or a
    pyserial URL, opened exclusively, read and written without waiting."""

    def __init__(self, port: str, baud: int) -> None:
        super().__init__(port, baud)
        self._ser: serial.Serial | None = None
        self._fd: int | None = None
        #: The low-latency mode last said (None: not yet): said again only when it changes,
        #: not at every try to reconnect (once a second while a port is in fault).
        self._said: bool | None = None

    def open(self) -> bool:
        try:
            ser = serial.serial_for_url(
                self.port, baudrate=self.baud, timeout=0, write_timeout=0, exclusive=True
            )
        except (*IO_ERRORS, ValueError) as e:
            raise PortUnavailable(self.port, f"cannot open: {e}; {PortUnavailable.advice}") from e
        self._ser = ser
        try:
            self._fd = ser.fileno()
        except (AttributeError, NotImplementedError, *IO_ERRORS):
            self._fd = None  # a pyserial URL with no descriptor (loop://)
        return self._low_latency(ser)

    def _low_latency(self, ser: serial.Serial) -> bool:
        """Ask the USB serial chip to pass short answers on at once.

        The board's FTDI chip holds a short answer until its latency timer runs out
        (16 ms by default): every query would wait that long. Linux lets the host set
        low-latency mode (1 ms) on such ports; a port that is no USB serial device (a pty,
        a network URL) says no, and nothing else changes."""
        try:
            ser.set_low_latency_mode(True)
        except (AttributeError, ValueError, *IO_ERRORS) as e:
            self._say(
                False,
                f"{self.port}: low-latency mode not available ({e}): a short answer may wait "
                "for the USB chip's latency timer (16 ms by default)",
            )
            return False
        self._say(
            True, f"{self.port}: low-latency mode set (answers wait 1 ms in the USB chip, not 16)"
        )
        return True

    def _say(self, low: bool, text: str) -> None:
        if self._said is not low:
            log.info("%s", text)
        self._said = low

    def fileno(self) -> int | None:
        return self._fd

    def _write(self, data: bytes) -> None:
        """pyserial's own `write` raises "Write timeout" when its timeout has passed after an
        `os.write` that took every byte, so a write by a thread that waited for a core on a
        busy host was reported as failed: this writes to the descriptor (pyserial opens it
        non-blocking) and waits only while the port is full."""
        ser, fd = self._ser, self._fd
        if ser is None:
            raise LinkLost(self.port, "write failed: the port is closed")
        try:
            if fd is None:
                ser.write(data)
                return
            view = memoryview(data)
            while view:
                with contextlib.suppress(BlockingIOError):  # the port is full: wait below
                    view = view[os.write(fd, view) :]
                if view and not select.select([], [fd], [], WRITE_TIMEOUT_S)[1]:
                    raise LinkLost(
                        self.port, f"write failed: the port took no byte for {WRITE_TIMEOUT_S} s"
                    )
        except IO_ERRORS as e:
            raise LinkLost(self.port, f"write failed: {e}") from e

    def read(self) -> bytes:
        ser, fd = self._ser, self._fd
        if ser is None:
            raise LinkLost(self.port, "read failed: the port is closed")
        try:
            if fd is None:
                return bytes(ser.read(ser.in_waiting or 0))
            return os.read(fd, 4096)
        except BlockingIOError:
            return b""
        except IO_ERRORS as e:
            raise LinkLost(self.port, f"read failed: {e}") from e

    def close(self) -> None:
        ser, self._ser, self._fd = self._ser, None, None
        if ser is not None:
            with contextlib.suppress(*IO_ERRORS):
                ser.close()
