"""The write side of a board's port: one write at a time, a stop's never waiting, moves
paced to the wire, and another process's stops kept in order.

The wire is not a queue. At 9600 baud a group move takes 40 ms on the wire, and
the port takes bytes as fast as they come: a client writing faster than that
would stack seconds of moves in the port, and an emergency stop's bytes would
queue behind them (the port sends in order; on the USB link nothing already
written can be taken back). So a move is written only when at most
`WIRE_HORIZON_S` of earlier bytes are still on their way (the driver's own
account of the wire, `arrival`), and a writer that comes sooner waits its turn
here, outside the write lock. A move longer than `WIRE_PIECE_S` on the wire (a
group move of six channels is 49 ms at 9600 baud), and so are a cancelled move's
STOPs, in pieces, each when the horizon allows it. A stop written between two pieces
ends the line: its ESC cancels the half-sent line on the board, and the rest is not
written; a line cut short any other way is cancelled by an ESC before the next bytes.
Other writes (a query) wait for the line's end (the board would take them for part of
it) and for the wire to be free (they cannot be cut). So a stop never waits, and finds
at most the horizon and one piece, or one query, ahead of it.

The emergency stop may be written by another process (`al5d.ssc32u.stopline`): a port
given a `StopGate` (`gate_port`) hands each board's file descriptor to that process,
every write here holds the gate's lock, and a move waits for, and is withheld by, a
stop that process wrote and the server has not obeyed yet.

A recording (`al5d serve --record`) taps the writes of a port (`tap_writes`): each write,
stop included, hands its bytes and times to the tap, which must only hand them over (a
queue's put) and never wait.
"""

from __future__ import annotations

import contextlib
import os
import select
import termios
import threading
import time
from collections.abc import Callable, Hashable, Sequence

import serial

from al5d.clock import now
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import LinkLost
from al5d.ssc32u.facts import BITS_PER_BYTE
from al5d.ssc32u.stopline import StopGate

DEFAULT_WRITE_TIMEOUT_S = 0.5
#: How much of earlier bytes' wire time a move may find still to go when it is written (the
#: horizon a stop can find ahead of it, with the one piece written last).
WIRE_HORIZON_S = 0.02
#: A paced write longer than this on the wire goes out in pieces of at most it (9 bytes at
#: 9600 baud, 115 at 115200: only the slow bauds' long lines are cut).
WIRE_PIECE_S = 0.01
#: What a dead port raises, depending on the call: pyserial's own, the OS's, and termios's
#: (tcflush on a pty whose master is gone raises termios.error, which is not an OSError).
IO_ERRORS = (serial.SerialException, OSError, termios.error)
#: What pyserial raises when another thread closes the port under a read or a write (its
#: file descriptor is gone mid-call): a lost link too, once the port is closed.
CLOSED_UNDER = (TypeError, AttributeError)

#: Told of every write to a port once its bytes are in it: the bytes, when the write
#: returned and when their last byte reaches the board (CLOCK_MONOTONIC, `al5d.clock.now`).
WriteTap = Callable[[bytes, float, float], None]
#: The taps by port, taken by each board opened on that port (a reconnect's too).
_taps: dict[str, WriteTap] = {}
#: The stop gates by port (`gate_port`), and the boards open now, by port.
_gates: dict[str, StopGate] = {}
_open: dict[str, Wire] = {}
_gates_lock = threading.Lock()
#: How long a move waits for the server to obey a stop another process wrote (the server's
#: thread that obeys it may wait for a core on a busy host); past that it is withheld.
GATE_WAIT_S = 1.0


def tap_writes(port: str, tap: WriteTap | None) -> None:
    """Tell `tap` of every write to the boards opened on `port` from now on (None: no more).
    It runs under the write lock, in the writer's thread (the stop's too): it must not
    wait or raise; what it raises is dropped, never the write's failure."""
    if tap is None:
        _taps.pop(port, None)
    else:
        _taps[port] = tap


def gate_port(port: str, gate: StopGate | None) -> None:
    """Order every write to the boards opened on `port` with the stops `gate`'s other end
    writes (None: no more), the board open now included."""
    with _gates_lock:
        wire = _open.get(port)
        if gate is None:
            _gates.pop(port, None)
        else:
            _gates[port] = gate
        if wire is not None:
            wire.gate(gate)


class Wire:
    """The writes to one open port (`ser`, pyserial's) at `baud`, and the account of its
    wire: when the bytes written so far will have reached the board."""

    def __init__(self, ser: serial.Serial, port: str, baud: int, write_timeout_s: float) -> None:
        self._ser = ser
        self.port = port
        self.baud = baud
        self._write_lock = threading.Lock()
        # Paced writers (moves, a cancel's STOPs) wait for the wire one at a time, in turn.
        self._pace_lock = threading.Lock()
        self._stops = 0  # counts emergency stops, to tell a flushed query from a dead board
        # A line whose pieces stopped half way with no ESC known to follow it (write lock).
        self._cut = False
        self.closed = False
        # When the wire will have carried every byte written so far: a query's answer
        # cannot come before its own bytes, and those queue behind the earlier ones.
        self._wire_free_at = 0.0
        self._write_timeout_s = write_timeout_s
        self._tap = _taps.get(port)
        self._gate: StopGate | None = None

    def register(self) -> None:
        """The board is open and checked: its port's stop gate (`gate_port`) from now on."""
        with _gates_lock:
            _open[self.port] = self
            self.gate(_gates.get(self.port))

    def gate(self, gate: StopGate | None) -> None:
        """Writes from now on ordered with `gate`'s stops; its other end gets our port."""
        try:
            fd = self._ser.fileno()
        except (AttributeError, NotImplementedError, *IO_ERRORS):
            return  # a pyserial URL with no descriptor: the server's own stop only
        if gate is self._gate:
            return
        if self._gate is not None:
            self._gate.closed()
        with self._write_lock:
            self._gate = gate
        if gate is not None and not self.closed:
            gate.opened(fd)

    def close(self) -> None:
        """The port is about to close: said first, so that a write or a read under way that
        fails on it is a lost link (`lost`), and the stop gate lets its copy go."""
        self.closed = True
        with _gates_lock:
            if _open.get(self.port) is self:
                del _open[self.port]
            if self._gate is not None:
                self._gate.closed()

    def lost(self, error: Exception, what: str) -> LinkLost:
        """The I/O error as a lost link; a programming error (not one of a port closed under
        the call) goes on as it is."""
        if isinstance(error, CLOSED_UNDER) and not self.closed:
            raise error
        reason = error if isinstance(error, IO_ERRORS) else "the port was closed"
        return LinkLost(self.port, f"{what}: {reason}")

    @property
    def free_at(self) -> float:
        """When the bytes written so far will have reached the board (CLOCK_MONOTONIC)."""
        return self._wire_free_at

    def arrival(self, n_bytes: int) -> float:
        """When a command of `n_bytes` written now would have reached the board."""
        return max(now(), self._wire_free_at) + self.wire_time_s(n_bytes)

    def wire_time_s(self, command: bytes | int) -> float:
        """Seconds the command (or that many bytes) needs on the wire at the current baud."""
        n = command if isinstance(command, int) else len(command)
        return p.wire_time_s(n, self.baud)

    # -- the stops -------------------------------------------------------------------

    def stop(self, data: bytes, paced: bool, key: Hashable | None) -> None:
        """An emergency stop's bytes (ESC first): counted, then written after a flush."""
        self._stops += 1
        self.write(data, paced=paced, flush=True, key=key)

    def stop_count(self) -> int:
        """The emergency stops written so far, another process's included (`gate_port`)."""
        gate = self._gate
        return self._stops + (gate.stops if gate is not None else 0)

    def written_elsewhere(self, data: bytes) -> None:
        """Another process has written `data` to this port (the stop process's STOP): the
        account of the wire, and the tap, hear of it as of a write here."""
        with self._write_lock:
            t = now()
            self._wire_free_at = max(t, self._wire_free_at) + self.wire_time_s(data)
            self._tell_tap(data, t)

    def settle_stops(self, timeout: float) -> bool:
        """Wait (at most `timeout`) until every stop another process wrote (`gate_port`) has
        been obeyed by the server; True if none is left."""
        gate = self._gate
        return gate is None or not gate.pending() or gate.wait_seen(timeout)

    @property
    def gated(self) -> bool:
        """Another process may write a stop to this port (`gate_port`)."""
        return self._gate is not None

    def plan_stops(self, channels: Sequence[int], until: float) -> None:
        """A stop another process writes (`gate_port`) STOPs the channels in this order until
        `until` (CLOCK_MONOTONIC); nothing without one."""
        gate = self._gate
        if gate is not None:
            gate.plan(channels, until)

    # -- the writes ------------------------------------------------------------------

    def write(
        self,
        data: bytes,
        unless: Callable[[], bool] | None = None,
        *,
        paced: bool = False,
        flush: bool = False,
        horizon_s: float = WIRE_HORIZON_S,
        key: Hashable | None = None,
    ) -> float | None:
        """Write `data` (after `WIRE_HORIZON_S` allows it, if `paced`; after an output flush,
        with `flush`); when its last byte reaches the board, or None if `unless` said so (or
        the stop known by `key` was written by another process)."""
        if not paced:
            if flush:  # a stop: never waits, and its ESC cancels a line it comes into
                return self._write_now(data, unless, flush, key)
            # A query (or an ESC) must not come into a line going out in pieces: the board
            # would take it for part of the line. The pace lock is free between lines. It
            # cannot be cut, so it waits for the wire to be free: a stop finds it alone
            # ahead (a read-back of six channels is 20 ms at 9600 baud), not behind the
            # horizon and a piece.
            with self._pace_lock:
                self._wait_for_horizon(0.0)
                return self._write_now(data, unless, flush, key)
        piece = max(1, int(self.baud / BITS_PER_BYTE * WIRE_PIECE_S))
        with self._pace_lock:
            if len(data) <= piece:
                self._wait_for_horizon(horizon_s)
                return self._write_now(data, unless, flush, key)
            # A cancelled move's STOPs (paced, flushed) go in pieces too: a preempting client
            # has one every goal, and six STOPs whole are 38 ms of wire at 9600 baud.
            return self._write_pieces(data, piece, unless, horizon_s, flush, key)

    def _wait_for_horizon(self, horizon_s: float) -> None:
        while (wait := self._wire_free_at - horizon_s - now()) > 0:
            time.sleep(wait)

    def _write_pieces(
        self,
        data: bytes,
        piece: int,
        unless: Callable[[], bool] | None,
        horizon_s: float,
        flush: bool = False,
        key: Hashable | None = None,
    ) -> float | None:
        """`data` in pieces of `piece` bytes, each when the horizon allows it (`horizon_s`
        for the first, which decides whether the line goes out at all); the first if
        `unless` lets it (after a flush, with `flush`; claimed by `key`), the others unless
        a stop came meanwhile (its ESC cancels the half line). The tap hears of what went
        out as one write."""
        stops = self.stop_count()

        def stopped() -> bool:
            return self.stop_count() != stops

        t_first, sent, end = 0.0, 0, None
        while sent < len(data):
            self._wait_for_horizon(WIRE_HORIZON_S if sent else horizon_s)
            chunk = data[sent : sent + piece]
            if sent:
                end = self._write_now(chunk, stopped, False, tap=False)
            else:
                end = self._write_now(chunk, unless, flush, key, tap=False)
            if end is None:
                break
            t_first = t_first or now()
            sent += len(chunk)
        if 0 < sent < len(data):
            with self._write_lock:
                self._cut = True
        if sent:
            self._tell_tap(data[:sent], t_first)
        return end if sent == len(data) else None

    def _write_now(
        self,
        data: bytes,
        unless: Callable[[], bool] | None,
        flush: bool,
        key: Hashable | None = None,
        tap: bool = True,
    ) -> float | None:
        gate = self._gate
        if gate is not None and unless is not None and gate.pending():
            gate.wait_seen(GATE_WAIT_S)
        with self._write_lock, gate.turn() if gate is not None else contextlib.nullcontext():
            if unless is not None and ((gate is not None and gate.pending()) or unless()):
                return None
            if key is not None and gate is not None and not gate.claim(key):
                return None
            if self._cut and not data.startswith(p.CANCEL):
                data = p.CANCEL + data  # the line cut short before it, cancelled on the board
            try:
                if flush:
                    self._ser.reset_output_buffer()
                self._send(data)
            except (*IO_ERRORS, *CLOSED_UNDER) as e:
                what = "stop could not be written" if flush else "write failed"
                raise self.lost(e, what) from e
            self._cut = False
            # After a flush, as if it dropped nothing (the USB link): later than the truth on
            # a UART, which only makes a query's deadline later, never too early.
            t = now()
            self._wire_free_at = max(t, self._wire_free_at) + self.wire_time_s(data)
            if tap:
                self._tell_tap(data, t)
            return self._wire_free_at

    def _tell_tap(self, data: bytes, written: float) -> None:
        """The recording's tap, if any, of bytes written at `written` (a recording never
        fails a write)."""
        if self._tap is not None:
            with contextlib.suppress(Exception):
                self._tap(data, written, self._wire_free_at)

    def _send(self, data: bytes) -> None:
        """All of `data` into the port; a port that takes no byte for the write timeout is
        a fault (`SerialTimeoutException`), and the time this thread was not running is not.

        pyserial's own `write` raises "Write timeout" when its timeout has passed after an
        `os.write` that took every byte, so a stop written whole, by a thread that waited for
        a core on a busy host, was reported as failed and the link taken for lost (seen under
        three flooded servers beside busy loops). This writes to the port's file descriptor
        (pyserial opens it non-blocking) and waits only while the port is full. A port with no
        file descriptor (a pyserial URL such as loop://) is written by pyserial."""
        try:
            fd = self._ser.fileno()
        except (AttributeError, NotImplementedError, *IO_ERRORS):
            self._ser.write(data)
            return
        view = memoryview(data)
        while view:
            with contextlib.suppress(BlockingIOError):  # the port is full: wait below
                view = view[os.write(fd, view) :]
            if view:
                _, ready, _ = select.select([], [fd], [], self._write_timeout_s)
                if not ready:
                    raise serial.SerialTimeoutException("Write timeout")
