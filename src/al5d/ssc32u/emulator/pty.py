"""The emulated board's serial link: a pseudo terminal carrying bytes at the client's baud.

The client (our driver, or any program that speaks to a serial port) opens the
pty's slave like the board's USB port. The link reads the master side as soon
as the client writes and gives each byte a virtual slot on the wire at the
baud the client set (10 bit times a byte); a line goes to the board when its CR
arrives. The board's answers are written back when they are due: on the USB
link (`usb.LinkModel`, the default) they first wait in the FTDI chip for its latency
timer, on a plain UART they come as the board sends them.

A client's output flush (TCOFLUSH) reaches the link through the pty's packet
mode. On the USB link it drops nothing: Linux's USB serial drivers keep bytes
already written. On a UART it drops the bytes whose slot has not begun.

What a pty cannot do: a flush on the slave discards the bytes the link has not
yet read from the master, before the link hears of the flush. Bytes written
and flushed at once (within a few tens of microseconds) are lost on either
model; the link reads as soon as it can, but no reader wins that race every
time (see docs/emulator.md, "What it does not model").
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import queue
import select
import struct
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from al5d.clock import now
from al5d.priority import make_urgent
from al5d.ssc32u import facts
from al5d.ssc32u.emulator.board import Answer, Board, Record
from al5d.ssc32u.emulator.usb import FtdiChip, LinkModel, Packet, byte_arrivals

#: A line longer than this is cut (what the board's buffer holds of it).
MAX_LINE = 1024
#: What termios calls the bauds a client may set.
_BAUDS = {
    getattr(termios, f"B{b}"): b
    for b in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
}


class _Slot(NamedTuple):
    """A byte on the virtual wire: when its first bit leaves the client, when its last arrives."""

    start: float
    arrival: float
    byte: int
    heard: bool  # sent at the board's baud; otherwise the board hears noise


class ChooseAnotherLink(ValueError):
    """The path asked for as the board's symlink is taken: choose another (or free it)."""


def link_problem(link: Path) -> str | None:
    """Why `link` cannot be made the board's symlink, or None. A file, a directory or a link
    to a device that is there (another board's) is never replaced; a link whose device has
    gone (a board that ended without removing it) is."""
    if link.is_symlink():
        if not link.exists():
            return None
        return (
            f"{link} is in use: it points to {os.readlink(link)}, which is there (another "
            "board's?); choose another path, or end that board (or remove the link if none "
            "uses it)"
        )
    if link.exists():
        kind = "a directory" if link.is_dir() else "a file"
        return f"{link} is {kind}, not a board's link: choose another path (it is left as it is)"
    if not link.parent.is_dir():
        return f"{link}: there is no directory {link.parent}"
    return None


class PtyLink:
    """A pty whose master side is the board: opened by `open()`, ended by `close()`.

    `link` (optional) is a symlink kept pointing at the current slave, so that a
    client's path survives a reconnect (a new pty) as a USB device path would; while
    unplugged (the emulator's DISCONNECT) there is none, as there is no such device.
    `model` is what the link between computer and board does (USB or UART).
    """

    def __init__(
        self,
        board: Board,
        link: str | os.PathLike[str] | None = None,
        model: LinkModel | None = None,
    ) -> None:
        self.board = board
        self.link = Path(link) if link is not None else None
        self._linked = False  # the link is this board's (made at its first open)
        self.model = model if model is not None else LinkModel()
        self._master = -1
        self._slave = -1
        self.device = ""
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self._answers: queue.Queue[Answer | None] = queue.Queue()
        self._wake_r, self._wake_w = -1, -1
        self._line_began = 0.0  # when the first byte of the board's partial line arrived
        #: How many of the client's bytes the link has read from the pty (one writer: its
        #: reader thread). A flush finds those it has not read in the pty, whose own flush
        #: may keep them (see `_flush`).
        self.bytes_heard = 0

    @property
    def is_open(self) -> bool:
        return self._running.is_set()

    def send(self, answers: list[Answer]) -> None:
        """Answers the board makes by itself (its startup string after a reset)."""
        for answer in answers:
            self._answers.put(answer)

    def open(self) -> None:
        self._open_pty()
        self._running.set()
        self._threads = [
            threading.Thread(target=_urgently(self._read_loop), name="ssc32u-rx", daemon=True),
            threading.Thread(target=_urgently(self._answer_loop), name="ssc32u-tx", daemon=True),
        ]
        for th in self._threads:
            th.start()

    def close(self) -> None:
        """Close the pty: the client's reads and writes fail, as when a cable is pulled."""
        self._running.clear()
        self._answers.put(None)
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        for th in self._threads:
            if th is not threading.current_thread():
                th.join(timeout=2)
        self._threads = []
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = -1
        self._answers = queue.Queue()

    def remove_link(self) -> None:
        """The link, if it is still this board's (never a path it did not make)."""
        if self._linked and self.link is not None and self.link.is_symlink():
            with contextlib.suppress(OSError):
                if os.readlink(self.link) == self.device:
                    self.link.unlink()

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        # Raw before any client opens it, or the line discipline eats CR.
        tty.setraw(slave)
        attrs = termios.tcgetattr(slave)
        speed = getattr(termios, f"B{self.board.baud}")
        attrs[4] = attrs[5] = speed
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        os.set_blocking(master, False)
        # Packet mode: the master hears of the client's output flushes (TIOCPKT_FLUSHWRITE).
        fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
        self._master, self._slave = master, slave
        self.device = os.ttyname(slave)
        self._wake_r, self._wake_w = os.pipe()
        if self.link is not None:
            # Once, at the first open: later opens (a replug) move this board's own link.
            problem = None if self._linked else link_problem(self.link)
            if problem is not None:
                self.close()
                raise ChooseAnotherLink(problem)
            self._linked = True
            tmp = self.link.with_name(self.link.name + ".tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.device)
            tmp.replace(self.link)

    def client_baud(self) -> int:
        """The baud the client set on its side (0 if it set one termios does not name)."""
        try:
            speed = termios.tcgetattr(self._master)[4]
        except (termios.error, OSError):
            return self.board.baud
        return _BAUDS.get(speed, 0)

    def _read_loop(self) -> None:
        """Put each byte on a virtual wire at the client's baud and act on each line at its CR.

        Bytes are read from the pty as soon as the client writes them and get
        a slot on the wire: byte after byte, 10 bit times each, starting when
        written or when the wire is free. The master runs in packet mode, so a
        client's output flush (TCOFLUSH) is reported here; on a UART it drops the
        bytes whose slot has not begun, on USB nothing.
        """
        wire: deque[_Slot] = deque()
        ends: deque[float] = deque()  # arrival times of the CR/ESC bytes on the wire
        line = bytearray()
        line_free = 0.0  # when the wire has carried the last byte given to it
        master, wake = self._master, self._wake_r
        while self._running.is_set():
            timeout = max(0.0, ends[0] - now()) if ends else 0.5
            try:
                ready, _, _ = select.select([master, wake], [], [], timeout)
            except (OSError, ValueError):
                return
            if wake in ready or not self._running.is_set():
                return
            if master in ready:
                t_seen = now()
                try:
                    packet = os.read(master, 4096)
                except BlockingIOError:
                    packet = b""
                except OSError:
                    return
                if not packet:
                    continue
                if packet[0] != 0:  # a status packet: only a flush of the client's output matters
                    flushed = packet[0] & termios.TIOCPKT_FLUSHWRITE
                    if flushed and self.model.flush_drops_unsent:
                        line_free = self._flush(wire, ends, t_seen, line_free)
                    continue
                self.bytes_heard += len(packet) - 1
                line_free = self._on_wire(packet[1:], t_seen, line_free, wire, ends)
            self._deliver(wire, ends, line)

    def _on_wire(
        self, data: bytes, t_seen: float, line_free: float, wire: deque[_Slot], ends: deque[float]
    ) -> float:
        """Give each byte its slot; return when the wire is free again."""
        baud = self.client_baud()
        heard = baud == self.board.baud
        bt = facts.BITS_PER_BYTE / (baud or self.board.baud)
        t = max(t_seen, line_free)
        for byte in data:
            wire.append(_Slot(t, t + bt, byte, heard))
            t += bt
            if byte in (0x0D, 0x1B):
                ends.append(t)
        return t

    def _deliver(self, wire: deque[_Slot], ends: deque[float], line: bytearray) -> None:
        """Hand the board every byte that has arrived by now; a line at its CR (or ESC).

        A line begun before the board last powered up (a reset) is lost with its memory."""
        t_now = now()
        while wire and wire[0].arrival <= t_now:
            _, arrival, byte, heard = wire.popleft()
            if line and self._line_began < self.board.powered_at <= arrival:
                line.clear()
            if not line:
                self._line_began = arrival
            if byte in (0x0D, 0x1B):
                ends.popleft()
                if not heard:
                    self.board.note(Record(arrival, bytes(line), (), self._noise_reason()))
                elif byte == 0x0D:
                    for answer in self.board.execute(bytes(line), arrival):
                        self._answers.put(answer)
                else:
                    self.board.note(Record(arrival, bytes(line), (), "cancelled by ESC"))
                line.clear()
            elif len(line) < MAX_LINE:
                line.append(byte)

    def _noise_reason(self) -> str:
        return f"noise: client at {self.client_baud()} baud, board at {self.board.baud}"

    @staticmethod
    def _flush(wire: deque[_Slot], ends: deque[float], t_flush: float, line_free: float) -> float:
        """Drop the bytes whose slot had not begun at `t_flush`; return when the wire is free.

        Only bytes this thread has read can be kept or dropped here. Of those still unread
        in the master when the client flushed, the pty's own flush discards the ones it
        had not yet handed to the master's line discipline (on the USB model too, where the
        real link would keep them); the ones it had are read after the flush's report, and
        go on the wire as if written after it.
        """
        while wire and wire[-1].start > t_flush:
            if wire.pop().byte in (0x0D, 0x1B):
                ends.pop()
        return wire[-1].arrival if wire else min(line_free, t_flush)

    def _answer_loop(self) -> None:
        """Write each answer back when it is due: on USB, as the FTDI chip sends it on."""
        answers, master = self._answers, self._master
        hold = self.model.hold_s
        chip = FtdiChip(hold) if hold is not None else None
        while True:
            wait = None if chip is None or chip.due == float("inf") else chip.due - now()
            try:
                item = answers.get(timeout=max(0.0, wait) if wait is not None else None)
            except queue.Empty:  # the chip's latency timer ran out before another answer
                assert chip is not None
                packet = chip.expire()
                if packet is not None and not _write(master, packet):
                    return
                continue
            if item is None:
                return
            due, data = item
            if chip is None:
                if not _write(master, Packet(due, data)):
                    return
                continue
            for packet in chip.feed(byte_arrivals(due, len(data), self.board.baud), data):
                if not _write(master, packet):
                    return


def _urgently(loop: Callable[[], None]) -> Callable[[], None]:
    """`loop` at the urgent priority: the emulated board stands for a processor of its own,
    which hears and answers in its time whatever the host does, also when it runs in the
    same process as a busy client (a test, `al5d serve --emulate`)."""

    def run() -> None:
        make_urgent("the emulated board")
        loop()

    return run


def _write(master: int, packet: Packet) -> bool:
    """Write `packet` to the pty at its time; False once the pty is gone."""
    _sleep_until(packet.t)
    try:
        os.write(master, packet.data)
    except OSError:
        return False
    return True


def _sleep_until(t: float) -> None:
    wait = t - now()
    if wait > 0:
        time.sleep(wait)
