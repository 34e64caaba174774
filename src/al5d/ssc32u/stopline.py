"""The emergency stop written by another process: the port handed over, and both processes'
writes kept in order.

Why a second process: on a busy host a thread of the server that serves the stop waits
for the interpreter lock (the GIL), which a thread taking a flood of instructions holds
and loses its core with; at a higher scheduling priority the stop's thread still waits
its turn behind that thread's. Measured: three flooded servers beside two busy loops, a
stop service call to the STOP at the board p99 65-210 ms with the stop path in the
server, against a 14 ms p99 round trip of a bare rclpy service in a process of its own.
So the stop is written by a small process of its own (`al5d.ros.stopproc`), at the
urgent priority, holding a duplicate of the port's file descriptor.

Two ends share a small block of memory and a lock (a POSIX record lock on that block,
which is per process):

- `StopGate`, the server's end, kept by the port's `SSC32U`
  (`al5d.ssc32u.wire.gate_port`): every write the server makes holds the lock; a
  move's write is withheld while the other end has written a stop the server has not
  obeyed yet (`pending`), and waits for that briefly (`wait_seen`), so that its job
  ends as the stop ends it. The server obeys the stop and then `acknowledge`s it.
  The port's file descriptor is handed to the other end whenever a board is opened on
  it, and taken back before it is closed (`opened`, `closed`).
- `StopEnd`, the other process's end: `stop` counts the stop in the shared block
  first (from then on no move of the server's goes out), then writes ESC and STOP for
  every channel. It waits for the lock `HOLD_S` at most: the server holds it only
  across one write, but on a busy host it may lose its core holding it. Past that the
  STOP goes out all the same, behind what the port holds (not flushed: a flush would
  drop the unsent end of a line whose start the board has, and the server's write under
  way, a query or a line, would then complete it into a command: a line cut at `#1P179`
  followed by `Q` moves channel 1 to 179 us), and once the lock comes, a STOP goes out
  again if the server wrote meanwhile, so that whatever it wrote then is halted too.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import mmap
import os
import socket
import struct
import termios
import threading
import time
from collections.abc import Callable, Hashable, Iterator, Sequence

from al5d.clock import now
from al5d.ssc32u import protocol as p

log = logging.getLogger("al5d")

#: The shared block: the stops the other end wrote, the writes the server made, and the
#: order to STOP the channels in until a time (the moving joints first: `plan`), behind a
#: version that is odd while the server changes it.
_STOPS, _WRITES, _VERSION = 0, 8, 16
_PLAN = struct.Struct("=dB32s")
_PLAN_AT = 24
#: The last stops written that are known by a key (a stop message both processes see on
#: the instruction topic), so that one of them is written once: changed under the lock.
_KEYS = struct.Struct("=8QQ")
_KEYS_AT = 72
_SIZE = _KEYS_AT + _KEYS.size
#: How long the stop waits for the server's write under way before it writes anyway.
HOLD_S = 0.005
#: How long it then waits for the lock, to halt what the server wrote meanwhile.
BACKSTOP_S = 2.0
#: What the stop process says when it wrote a stop's STOPs a second time (`StopEnd.stop`).
BACKSTOP_SAID = "STOP written again: the server wrote while the stop waited for its lock"
_POLL_S = 0.0002
#: A message on the port socket: a file descriptor comes with it, or the port is closed.
_OPEN, _CLOSE = b"open", b"close"


class _Shared:
    """The block both ends map, and its lock (held by one process at a time)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._mem = mmap.mmap(fd, _SIZE)

    def read(self, offset: int) -> int:
        value: int = struct.unpack_from("=Q", self._mem, offset)[0]
        return value

    def add(self, offset: int) -> int:
        """One more at `offset` (each counter has one writer); the new count."""
        value = self.read(offset) + 1
        struct.pack_into("=Q", self._mem, offset, value)
        return value

    def plan(self, channels: Sequence[int], until: float) -> None:
        """The order to STOP the channels in until `until` (one writer: the server)."""
        self.add(_VERSION)
        _PLAN.pack_into(self._mem, _PLAN_AT, until, len(channels), bytes(channels))
        self.add(_VERSION)

    def planned(self) -> tuple[float, tuple[int, ...]] | None:
        """The order last planned and until when; None if it was being changed (twice)."""
        for _ in range(2):
            version = self.read(_VERSION)
            until, n, channels = _PLAN.unpack_from(self._mem, _PLAN_AT)
            if version % 2 == 0 and self.read(_VERSION) == version:
                return until, tuple(channels[:n])
        return None

    def claim(self, key: Hashable) -> bool:
        """With the lock held: True if no stop known by `key` has been written (it is now
        taken as written), False if one has."""
        ident = int.from_bytes(hashlib.blake2b(repr(key).encode(), digest_size=8).digest())
        *keys, last = _KEYS.unpack_from(self._mem, _KEYS_AT)
        if ident in keys:
            return False
        keys[last % len(keys)] = ident
        _KEYS.pack_into(self._mem, _KEYS_AT, *keys, last + 1)
        return True

    def lock(self, wait: bool) -> bool:
        try:
            fcntl.lockf(self.fd, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB, 1)
        except (BlockingIOError, PermissionError):
            return False
        return True

    def unlock(self) -> None:
        fcntl.lockf(self.fd, fcntl.LOCK_UN, 1)

    def close(self) -> None:
        with contextlib.suppress(ValueError, BufferError):
            self._mem.close()
        with contextlib.suppress(OSError):
            os.close(self.fd)


class StopGate:
    """The server's end: made before the other process, which is given `peer_fds`."""

    def __init__(self) -> None:
        fd = os.memfd_create("al5d-stop-gate")
        os.ftruncate(fd, _SIZE)
        self._shared = _Shared(fd)
        self._sock, self._peer = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._seen = 0
        self._cv = threading.Condition()

    @property
    def peer_fds(self) -> tuple[int, int]:
        """The shared block and the port socket, for the other process (inherited)."""
        return self._shared.fd, self._peer.fileno()

    def peer_started(self) -> None:
        """The other process has its copies: ours of its socket end goes."""
        self._peer.close()

    # -- the port -------------------------------------------------------------------

    def opened(self, fd: int) -> None:
        """A board is open on `fd`: the other end gets a duplicate of it."""
        with contextlib.suppress(OSError):
            socket.send_fds(self._sock, [_OPEN], [fd])

    def closed(self) -> None:
        """The board's port is about to close: the other end lets its duplicate go (a
        duplicate would keep the port's exclusive lock from the next open)."""
        with contextlib.suppress(OSError):
            self._sock.send(_CLOSE)

    # -- the stops ------------------------------------------------------------------

    @property
    def stops(self) -> int:
        """The stops the other end has written so far."""
        return self._shared.read(_STOPS)

    def pending(self) -> bool:
        """The other end has written a stop the server has not obeyed yet."""
        return self.stops != self._seen

    def acknowledge(self, count: int) -> None:
        """The server has obeyed the stops up to `count` (their jobs are ended)."""
        with self._cv:
            self._seen = max(self._seen, count)
            self._cv.notify_all()

    def wait_seen(self, timeout: float) -> bool:
        """Wait (at most `timeout`) until no stop is pending; True if none is."""
        with self._cv:
            return self._cv.wait_for(lambda: not self.pending(), timeout)

    def plan(self, channels: Sequence[int], until: float) -> None:
        """STOP the channels in this order until `until` (CLOCK_MONOTONIC): the joints of the
        motion under way first (`al5d.arm.jobs.stop_order`); after it, in channel order."""
        self._shared.plan(channels, until)

    @contextlib.contextmanager
    def turn(self) -> Iterator[None]:
        """One write of the server's: the lock held across it, and counted."""
        self._shared.lock(wait=True)
        try:
            yield
            self._shared.add(_WRITES)
        finally:
            self._shared.unlock()

    def claim(self, key: Hashable) -> bool:
        """In a `turn`: False if the other end has written the stop known by `key` already
        (then it is not written again); True, and it is the server's to write, if not."""
        return self._shared.claim(key)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.close()
        with contextlib.suppress(OSError):
            self._peer.close()
        self._shared.close()


class StopEnd:
    """The other process's end: the shared block's and the port socket's descriptors (as
    `StopGate.peer_fds` gave them), and the channels to STOP. `ended` is called when the
    server's end of the socket goes (the server has ended)."""

    def __init__(
        self, shared_fd: int, sock_fd: int, channels: Sequence[int], ended: Callable[[], None]
    ) -> None:
        self._shared = _Shared(shared_fd)
        self._sock = socket.socket(fileno=sock_fd)
        self._channels = tuple(sorted(channels))
        self._ended = ended
        self._port: int | None = None
        # The port's descriptor changes only under this lock; two stops write one at a time.
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._follow, name="al5d-stop-port", daemon=True)
        self._thread.start()

    def _follow(self) -> None:
        """The server's port, as it is opened and closed."""
        while True:
            try:
                msg, fds, _, _ = socket.recv_fds(self._sock, 16, 1)
            except OSError:
                msg, fds = b"", []
            if not msg:
                self._set(None)
                self._ended()
                return
            self._set(fds[0] if msg == _OPEN and fds else None)

    def _set(self, fd: int | None) -> None:
        with self._lock:
            if self._port is not None:
                with contextlib.suppress(OSError):
                    os.close(self._port)
            self._port = fd

    def stop(self, key: Hashable | None = None) -> tuple[int, str, bytes]:
        """Count a stop, then write it: its number (for the server to acknowledge), why it
        could not be written ("" when it was), and the bytes written. A stop known by `key`
        that the server has written already is not written again (no bytes, no error)."""
        with self._lock:
            count = self._shared.add(_STOPS)
            writes = self._shared.read(_WRITES)
            held = self._hold(HOLD_S)
            try:
                if held and key is not None and not self._shared.claim(key):
                    error, data = "", b""
                else:
                    error, data = self._write(flush=held)
            finally:
                if held:
                    self._shared.unlock()
        if not held and not error:
            # The server lost its core holding the lock: whatever it wrote once it had it
            # back went out after our STOP, which must then follow it again.
            threading.Thread(target=self._backstop, args=(writes,), daemon=True).start()
        return count, error, data

    def _hold(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not self._shared.lock(wait=False):
            if time.monotonic() >= deadline:
                return False
            time.sleep(_POLL_S)
        return True

    def _backstop(self, writes: int) -> None:
        # Polled, taking our own lock only a moment at a time: a stop that comes meanwhile
        # must not wait for this one's backstop.
        deadline = time.monotonic() + BACKSTOP_S
        while time.monotonic() < deadline:
            with self._lock:
                if self._shared.lock(wait=False):
                    error: str | None = None  # None: not written again
                    try:
                        if self._shared.read(_WRITES) != writes:
                            error, _ = self._write(flush=True)
                    finally:
                        self._shared.unlock()
                    if error is not None:  # said once the server may write again
                        log.warning("%s%s", BACKSTOP_SAID, f": {error}" if error else "")
                    return
            time.sleep(_POLL_S)

    def _write(self, flush: bool) -> tuple[str, bytes]:
        """Why the STOP could not be written (or ""), and its bytes; with `flush` (only with
        the lock held: no write of the server's is under way) what waits in the port is
        dropped first."""
        fd = self._port
        if fd is None:
            return "no board is open", b""
        try:
            # As the server's own stop: what waits in the port is dropped where the link
            # allows (a UART); the ESC makes a half-written line harmless either way, as
            # long as no write comes between the flush and it, which the lock ensures.
            if flush:
                with contextlib.suppress(termios.error, OSError):
                    termios.tcflush(fd, termios.TCOFLUSH)
            data = p.CANCEL + p.encode_stop(self._order())
            view = memoryview(data)
            deadline = time.monotonic() + BACKSTOP_S
            while view:
                with contextlib.suppress(BlockingIOError):
                    view = view[os.write(fd, view) :]
                if view and time.monotonic() > deadline:
                    return "the port took no byte for 2 s", b""
                if view:
                    time.sleep(_POLL_S)
        except OSError as e:
            return f"stop could not be written: {e}", b""
        return "", data

    def _order(self) -> tuple[int, ...]:
        planned = self._shared.planned()
        if planned is None or now() >= planned[0]:
            return self._channels
        first = planned[1]
        return first + tuple(ch for ch in self._channels if ch not in first)
