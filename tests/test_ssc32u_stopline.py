"""The stop process's end of the port (`al5d.ssc32u.stopline`) on a pseudo terminal, with
the server's lock held by another process, as on a busy host where the server lost its
core in the middle of a write."""

from __future__ import annotations

import fcntl
import os
import select
import subprocess
import sys
import termios
import time
import tty
from collections.abc import Iterator

import pytest

from al5d.ssc32u import protocol as p
from al5d.ssc32u.stopline import StopEnd, StopGate
from al5d_rig.rospeer import wait_until

#: Holds the lock of the shared block (a record lock: per process) until its stdin closes.
HOLD_LOCK = """
import fcntl, sys
fcntl.lockf(int(sys.argv[1]), fcntl.LOCK_EX, 1)
print("locked", flush=True)
sys.stdin.read()
"""


def read_packets(fd: int, settle_s: float = 0.3) -> tuple[bytes, int]:
    """What the board's side of the pty (in packet mode, as the emulator reads it) receives
    until it is quiet for `settle_s`: the bytes, and the status bits of the packets without
    bytes (a flush of the port's output: TIOCPKT_FLUSHWRITE)."""
    data, status = b"", 0
    while select.select([fd], [], [], settle_s)[0]:
        packet = os.read(fd, 4096)
        if packet[0] == 0:
            data += packet[1:]
        else:
            status |= packet[0]
    return data, status


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, int]]:
    board, port = os.openpty()
    # Held as the server holds its port (pyserial's exclusive lock): a driver of another test
    # reconnecting to its vanished emulator's /dev/pts/N, a number this pty may have reused,
    # cannot open it (seen beside two busy loops: its ESC and VER came between the line and
    # the stop's bytes).
    fcntl.flock(port, fcntl.LOCK_EX | fcntl.LOCK_NB)
    tty.setraw(port)
    fcntl.ioctl(board, termios.TIOCPKT, b"\x01\x00\x00\x00")  # packet mode
    try:
        yield board, port
    finally:
        os.close(board)
        os.close(port)


def test_a_stop_that_cannot_take_the_lock_drops_nothing_the_port_holds(
    pty_pair: tuple[int, int],
) -> None:
    """The server holds the port's lock (its write under way) and the stop writes anyway:
    it must not flush the port first. A flush drops the unsent end of a line whose start
    the board has, and the server's write that then comes before the stop's ESC (a query,
    another line) completes the cut line into a command: `#0P1500#1P179` + `Q` moves
    channel 1 to 179 us (the fuzz suite saw 179 us on channel 1 once beside two busy
    loops). Written behind what the port holds, the stop's ESC cancels nothing whole."""
    board, port = pty_pair
    gate = StopGate()
    shared_fd, sock_fd = gate.peer_fds
    end = StopEnd(os.dup(shared_fd), os.dup(sock_fd), range(6), lambda: None)
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(shared_fd)],
        pass_fds=(shared_fd,),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    try:
        gate.opened(port)
        wait_until(lambda: end._port is not None, 10, "the port handed over")
        line = b"#0P1500#1P1790T300\r"
        os.write(port, line)
        head = os.read(board, 14)[1:]  # the board has taken the line's start...
        assert head == b"#0P1500#1P179"
        assert holder.stdout is not None
        assert holder.stdout.readline() == b"locked\n"  # ...and the server holds the lock
        t0 = time.monotonic()
        _, error, data = end.stop()
        assert error == "" and data.startswith(p.CANCEL)
        assert time.monotonic() - t0 < 2.0  # it did not wait for the lock
        # The kernel drops the port's unsent bytes at a flush only while they wait for its
        # worker (a busy host's case), so that the flush itself is what is checked here.
        rest, status = read_packets(board)
        assert not status & termios.TIOCPKT_FLUSHWRITE, "the port was flushed without the lock"
        assert rest == line[len(head) :] + data
    finally:
        holder.kill()
        holder.wait(10)
        gate.closed()
        gate.close()
