"""The SSC-32U low-level driver: one method per board function, serial I/O kept inside.

It knows channels and pulse widths, never joints or degrees. It never waits for
an acknowledgement (the board sends none); only queries read. Every serial
failure, whatever pyserial or the OS calls it, leaves here as a `SerialFault`
subclass (see `al5d.ssc32u.errors`) with the port and what happened.

Threads: a query (write then read) holds a query lock; `stop()` does not take
it, so an emergency stop never waits behind a read. Writes are serialised by a
short write lock so that the bytes of two commands never interleave.

The wire is not a queue. At 9600 baud a group move takes 40 ms on the wire, and
the port takes bytes as fast as they come: a client writing faster than that
would stack seconds of moves in the port, and an emergency stop's bytes would
queue behind them (the port sends in order; on the USB link nothing already
written can be taken back). So a move is written only when at most
`WIRE_HORIZON_S` of earlier bytes are still on their way (the driver's own
account of the wire, `arrival`), and a writer that comes sooner waits its turn
here, outside the write lock. A move longer than `WIRE_PIECE_S` on the wire (a
group move of six channels is 49 ms at 9600 baud) is written in pieces, each when
the horizon allows it: a stop never waits, and finds at most the horizon and one
piece ahead of it. A stop written between two pieces ends the line: its ESC
cancels the half-sent line on the board, and the rest is not written; a line cut
short any other way is cancelled by an ESC before the next bytes. Other writes (a
query) wait for the line's end: the board would take them for part of it.

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
import logging
import os
import select
import termios
import threading
import time
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from types import TracebackType

import serial

from al5d.clock import Deadline, now
from al5d.priority import cpu_waited_s
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import (
    GarbageAnswer,
    Interrupted,
    LinkLost,
    NoAnswer,
    NotAnSSC32U,
    PortUnavailable,
    SerialFault,
)
from al5d.ssc32u.facts import (
    ANSWER_DELAY_MAX_S,
    BITS_PER_BYTE,
    FACTORY_BAUD,
    FIRMWARE_PREFIX,
    LATENCY_TIMER_MS,
    LOW_LATENCY_TIMER_MS,
)
from al5d.ssc32u.stopline import StopGate

log = logging.getLogger("al5d")

#: How long an answer may take beyond its wire time: the board's slowest (5 ms) ten
#: times over, because the host may be busy when the answer comes; one late answer is
#: asked again, so a silent board is found after two of these.
DEFAULT_READ_TIMEOUT_S = 10 * ANSWER_DELAY_MAX_S
#: Reads wake this often while they wait for an answer's deadline.
READ_SLICE_S = 0.01
#: A read that comes back this much later than its slice: the thread was not running.
SCHEDULING_SLACK_S = 0.005
#: At most this much is excused to one ask of a query (`SSC32U._read`): a silent board on a
#: busy host is found that much later, at worst; on an idle one, not later at all. Beside
#: two busy loops and a flood, a board's answer (an emulator at nice -10 in its own
#: process) came 75 ms late twice in a row, both asks' bytes reaching it 2 ms apart: the
#: kernel's work that carries a pty's bytes waited for a core; with 0.1 s excused to our
#: own thread only, that was a lost link and a missed stop, 3 times in 36 floods; with
#: 0.35 s, none in 30, but a silent board on a busy host was found after 0.85 s (and an
#: idle one's fault took more than a second).
EXCUSE_MAX_S = 0.15
DEFAULT_WRITE_TIMEOUT_S = 0.5
#: How much of earlier bytes' wire time a move may find still to go when it is written (the
#: horizon a stop can find ahead of it, with the one piece written last).
WIRE_HORIZON_S = 0.02
#: A paced write longer than this on the wire goes out in pieces of at most it (9 bytes at
#: 9600 baud, 115 at 115200: only the slow bauds' long lines are cut).
WIRE_PIECE_S = 0.01
#: A VER answer's length, for its deadline (`SSC32-V2.50USB\r` is 15 bytes).
VERSION_ANSWER_BYTES = 16
#: What a dead port raises, depending on the call: pyserial's own, the OS's, and termios's
#: (tcflush on a pty whose master is gone raises termios.error, which is not an OSError).
IO_ERRORS = (serial.SerialException, OSError, termios.error)
#: What pyserial raises when another thread closes the port under a read or a write (its
#: file descriptor is gone mid-call): a lost link too, once the port is closed.
CLOSED_UNDER = (TypeError, AttributeError)


Targets = Mapping[int, int] | Sequence[p.ChannelTarget]
#: Told of every write to a port once its bytes are in it: the bytes, when the write
#: returned and when their last byte reaches the board (CLOCK_MONOTONIC, `al5d.clock.now`).
WriteTap = Callable[[bytes, float, float], None]
#: The taps by port, taken by each `SSC32U` opened on that port (a reconnect's too).
_taps: dict[str, WriteTap] = {}
#: The stop gates by port (`gate_port`), and the boards open now, by port.
_gates: dict[str, StopGate] = {}
_open: dict[str, SSC32U] = {}
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
        board = _open.get(port)
        if gate is None:
            _gates.pop(port, None)
        else:
            _gates[port] = gate
        if board is not None:
            board._gated(gate)


class SSC32U:
    """A connection to one SSC-32U (or the emulator) on a serial port.

    `port` is a device path or a pyserial URL. On connect the driver cancels
    any partial line the board may hold and checks the board with VER.
    """

    def __init__(
        self,
        port: str,
        baud: int = FACTORY_BAUD,
        *,
        read_timeout_s: float = DEFAULT_READ_TIMEOUT_S,
        write_timeout_s: float = DEFAULT_WRITE_TIMEOUT_S,
        check: bool = True,
    ) -> None:
        self.port = port
        self.baud = baud
        self._write_lock = threading.Lock()
        # Paced writers (moves, a cancel's STOPs) wait for the wire one at a time, in turn.
        self._pace_lock = threading.Lock()
        self._query_lock = threading.Lock()
        self._stops = 0  # counts emergency stops, to tell a flushed query from a dead board
        # A line whose pieces stopped half way with no ESC known to follow it (write lock).
        self._cut = False
        self._closed = False
        # When the wire will have carried every byte written so far: a query's answer
        # cannot come before its own bytes, and those queue behind the earlier ones.
        self._wire_free_at = 0.0
        self._write_timeout_s = write_timeout_s
        self._tap = _taps.get(port)
        try:
            self._ser = serial.serial_for_url(
                port,
                baudrate=baud,
                timeout=READ_SLICE_S,
                write_timeout=write_timeout_s,
                exclusive=True,
            )
        except (*IO_ERRORS, ValueError) as e:
            raise PortUnavailable(port, f"cannot open: {e}; {PortUnavailable.advice}") from e
        self.low_latency = self._ask_low_latency()
        # How long an answer may take beyond its wire time: the read timeout, and the time
        # a short answer waits in the board's USB chip.
        timer_ms = LOW_LATENCY_TIMER_MS if self.low_latency else LATENCY_TIMER_MS
        self._margin_s = read_timeout_s + timer_ms / 1000.0
        self.firmware = ""
        self._gate: StopGate | None = None
        if check:
            try:
                self._write(p.CANCEL)
                self.firmware = self._check_version()
            except SerialFault:
                self.close()
                raise
        with _gates_lock:
            _open[port] = self
            self._gated(_gates.get(port))

    def _gated(self, gate: StopGate | None) -> None:
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
        if gate is not None and not self._closed:
            gate.opened(fd)

    def _ask_low_latency(self) -> bool:
        """Ask the USB serial chip to pass short answers on at once.

        The board's FTDI chip holds a short answer until its latency timer runs out
        (16 ms by default): every query would wait that long. Linux lets the host set
        low-latency mode (1 ms) on such ports; a port that is no USB serial device (a pty,
        a network URL) says no, and nothing else changes."""
        try:
            self._ser.set_low_latency_mode(True)
        except (AttributeError, ValueError, *IO_ERRORS) as e:
            log.info(
                "%s: low-latency mode not available (%s): a short answer may wait for the "
                "USB chip's latency timer (16 ms by default)",
                self.port,
                e,
            )
            return False
        log.info("%s: low-latency mode set (answers wait 1 ms in the USB chip, not 16)", self.port)
        return True

    # -- life cycle ------------------------------------------------------------

    def close(self) -> None:
        # Said before the port goes: another thread's read or write under way may then fail
        # on a half-closed port with what pyserial raises for it (see `_lost`).
        self._closed = True
        with _gates_lock:
            if _open.get(self.port) is self:
                del _open[self.port]
            if self._gate is not None:
                self._gate.closed()
        with contextlib.suppress(*IO_ERRORS):  # closing a dead port must not raise
            self._ser.close()

    @property
    def is_open(self) -> bool:
        return bool(self._ser.is_open)

    def __enter__(self) -> SSC32U:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- board functions ----------------------------------------------------------

    def move(self, targets: Targets, time_ms: int | None = None) -> bytes:
        """Group move: every channel to its pulse width (us), all arriving together.

        `targets` maps channel -> pulse us, or lists `ChannelTarget`s with a
        per-channel speed. Returns the bytes written.
        """
        if isinstance(targets, Mapping):
            seq = [p.ChannelTarget(ch, pw) for ch, pw in targets.items()]
        else:
            seq = list(targets)
        data = p.encode_group_move(seq, time_ms)
        self._write(data, paced=True)
        return data

    def write_command(
        self,
        data: bytes,
        unless: Callable[[], bool] | None = None,
        horizon_s: float = WIRE_HORIZON_S,
    ) -> float | None:
        """Write bytes already encoded by `al5d.ssc32u.protocol` (a hot path skips re-encoding).

        Returns when their last byte will have reached the board (CLOCK_MONOTONIC): after
        the bytes before them on the wire (a stop, a query) and their own wire time.
        `unless` is asked under the write lock, just before the write; if it says True,
        nothing is written and None is returned. A caller whose command must never follow
        a stop makes the stop decide before it takes this lock: then either the command
        goes out first and the STOP after it, or the command does not go out at all (a long
        one cut short by a stop between its pieces, cancelled by the stop's ESC: None too).
        The write waits until the wire's horizon allows it (`WIRE_HORIZON_S`, or a shorter
        `horizon_s`: a stream's set-point waits until the wire is free, where a newer one
        may still take its place).
        """
        return self._write(data, unless, paced=True, horizon_s=min(horizon_s, WIRE_HORIZON_S))

    def stop(
        self, channels: Iterable[int], paced: bool = False, key: Hashable | None = None
    ) -> bytes:
        """Emergency stop: ESC, which cancels any partial line on the board, then STOP every
        channel, in one write, without waiting for any query in progress or for the wire.
        `paced`: a STOP that is no emergency (a cancelled move's) waits for the wire as a
        move does, so that a client cancelling a hundred moves a second does not queue
        STOPs ahead of the next emergency stop.

        The output is flushed first: on a plain UART that drops what has not gone yet, but
        on the board's USB link it drops nothing already written (Linux's USB serial drivers
        keep it), so the STOPs may queue behind the rest of a move; the ESC is what makes a
        half-sent move harmless either way. Returns the bytes written. A stop known by `key`
        (a message on the instruction topic) that another process wrote already
        (`gate_port`) is not written again.
        """
        data = p.CANCEL + p.encode_stop(channels)
        self._stops += 1
        self._write(data, paced=paced, flush=True, key=key)
        return data

    def written_elsewhere(self, data: bytes) -> None:
        """Another process has written `data` to this port (the stop process's STOP): the
        account of the wire, and the tap, hear of it as of a write here."""
        with self._write_lock:
            t = now()
            self._wire_free_at = max(t, self._wire_free_at) + self.wire_time_s(data)
            self._tell_tap(data, t)

    def settle_stops(self, timeout: float = GATE_WAIT_S) -> bool:
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
        `until` (CLOCK_MONOTONIC), as `stop` would be asked to; nothing without one."""
        gate = self._gate
        if gate is not None:
            gate.plan(channels, until)

    def cancel(self) -> None:
        """ESC: the board drops the partial line it holds."""
        self._write(p.CANCEL)

    def is_done(self) -> bool:
        """Q: True when the board reports every move complete."""
        answer = self._query(p.encode_query_movement(), 1, "Q")
        try:
            return not p.parse_movement(answer)
        except p.ProtocolError as e:
            raise GarbageAnswer(self.port, f"not an SSC-32U answer: {e}", answer) from e

    def read_pulses(self, channels: Sequence[int]) -> dict[int, int]:
        """QP: the pulse width (us, 10 us resolution) each channel puts out now; 0 = none yet."""
        chans = list(channels)
        answer = self._query(p.encode_query_pulse(chans), len(chans), "QP")
        try:
            return p.parse_pulses(answer, chans)
        except p.ProtocolError as e:
            raise GarbageAnswer(self.port, f"not an SSC-32U answer: {e}", answer) from e

    def version(self) -> str:
        """VER: the firmware string."""
        answer = self._query(p.encode_version(), None, "VER")
        try:
            return p.parse_version(answer)
        except p.ProtocolError as e:
            raise GarbageAnswer(self.port, f"not an SSC-32U answer: {e}", answer) from e

    def set_offsets(self, offsets: Mapping[int, int]) -> None:
        """PO: volatile pulse trims, -100..100 us."""
        self._write(p.encode_pulse_offset(offsets), paced=True)

    def set_outputs(self, levels: Mapping[int, bool]) -> None:
        """H/L: use channels as digital outputs."""
        self._write(p.encode_digital_output(levels), paced=True)

    def arrival(self, n_bytes: int) -> float:
        """When a command of `n_bytes` written now would have reached the board."""
        return max(now(), self._wire_free_at) + self.wire_time_s(n_bytes)

    def wire_time_s(self, command: bytes | int) -> float:
        """Seconds the command (or that many bytes) needs on the wire at the current baud."""
        n = command if isinstance(command, int) else len(command)
        return p.wire_time_s(n, self.baud)

    # -- inside ----------------------------------------------------------------------

    def _lost(self, error: Exception, what: str) -> LinkLost:
        """The I/O error as a lost link; a programming error (not one of a port closed under
        the call) goes on as it is."""
        if isinstance(error, CLOSED_UNDER) and not self._closed:
            raise error
        reason = error if isinstance(error, IO_ERRORS) else "the port was closed"
        return LinkLost(self.port, f"{what}: {reason}")

    def _check_version(self) -> str:
        try:
            firmware = self.version()
        except (NoAnswer, GarbageAnswer) as e:
            got = f"; received {e.received!r}" if e.received else "; received nothing"
            raise NotAnSSC32U(
                self.port,
                f"does not answer like an SSC-32U at {self.baud} baud ({e.what}){got}; "
                f"{NotAnSSC32U.advice}",
                e.received,
            ) from e
        if not firmware.upper().startswith(FIRMWARE_PREFIX):
            raise NotAnSSC32U(
                self.port,
                f"answered VER with {firmware!r}, which is not an SSC-32U; {NotAnSSC32U.advice}",
                firmware.encode("ascii"),
            )
        return firmware

    def _write(
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
            # would take it for part of the line. The pace lock is free between lines.
            with self._pace_lock:
                return self._write_now(data, unless, flush, key)
        piece = max(1, int(self.baud / BITS_PER_BYTE * WIRE_PIECE_S))
        with self._pace_lock:
            if flush or len(data) <= piece:
                self._wait_for_horizon(horizon_s)
                return self._write_now(data, unless, flush, key)
            return self._write_pieces(data, piece, unless, horizon_s)

    def _wait_for_horizon(self, horizon_s: float) -> None:
        while (wait := self._wire_free_at - horizon_s - now()) > 0:
            time.sleep(wait)

    def _write_pieces(
        self, data: bytes, piece: int, unless: Callable[[], bool] | None, horizon_s: float
    ) -> float | None:
        """`data` in pieces of `piece` bytes, each when the horizon allows it (`horizon_s`
        for the first, which decides whether the line goes out at all); the first if
        `unless` lets it, the others unless a stop came meanwhile (its ESC cancels the half
        line). The tap hears of what went out as one write."""
        stops = self._stop_count()

        def stopped() -> bool:
            return self._stop_count() != stops

        t_first, sent, end = 0.0, 0, None
        while sent < len(data):
            self._wait_for_horizon(WIRE_HORIZON_S if sent else horizon_s)
            chunk = data[sent : sent + piece]
            end = self._write_now(chunk, stopped if sent else unless, False, tap=False)
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
                raise self._lost(e, what) from e
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

    def _stop_count(self) -> int:
        """The emergency stops written so far, another process's included (`gate_port`)."""
        gate = self._gate
        return self._stops + (gate.stops if gate is not None else 0)

    def _query(self, data: bytes, n_answer: int | None, name: str) -> bytes:
        """Write a query and read its answer; asked once more before a missing answer is a fault.

        The second ask covers a board (or an emulator in a busy process) that was late once,
        or a query a stop's flush dropped on a UART. The board answers in order, so a late
        first answer comes before the second: both are read, and the last is returned. A
        late first answer is never left for the next query to take as its own.
        """
        with self._query_lock:
            stops = self._stop_count()
            try:
                self._ser.reset_input_buffer()
                t_sent = now()
                deadline = self._ask(data, n_answer)
                answer = self._read(b"", n_answer, 1, deadline)
                if _answers(answer, n_answer) == 0:
                    deadline = self._ask(data, n_answer)
                    answer = self._read(answer, n_answer, 2, deadline)
                    if _answers(answer, n_answer) == 1:
                        # The first was lost, or the second is late: a margin more for it.
                        answer = self._read(answer, n_answer, 2, Deadline(self._margin_s))
            except (*IO_ERRORS, *CLOSED_UNDER) as e:
                raise self._lost(e, f"{name} failed") from e
        if _answers(answer, n_answer) == 0:
            if self._stop_count() != stops:
                raise Interrupted(f"{name} was flushed by an emergency stop")
            got = f", got {answer!r}" if answer else ""
            waited = (deadline.at - t_sent) * 1000
            raise NoAnswer(
                self.port, f"no answer to {name}, asked twice, within {waited:.0f} ms{got}", answer
            )
        return _last(answer, n_answer)

    def _ask(self, data: bytes, n_answer: int | None) -> Deadline:
        """Write the query; its answer's deadline: our bytes on the wire (behind any before
        them), the answer's own bytes back, then the margin."""
        self._write(data)
        back = self.wire_time_s(n_answer if n_answer is not None else VERSION_ANSWER_BYTES)
        return Deadline(back + self._margin_s, start=self._wire_free_at)

    def _read(self, answer: bytes, n_answer: int | None, count: int, deadline: Deadline) -> bytes:
        """Read on from `answer` until it holds `count` answers or the deadline has passed.

        The deadline is the board's: it moves on by the time this thread was not running
        (a read that came back a scheduling delay after its slice), by the time our query
        still waited in the port (its bytes had not left), and by the time the host was
        short of cores meanwhile (`al5d.priority.cpu_waited_s`: the kernel's work that
        carries the port's bytes, and a board emulated on this host, wait their turn too),
        up to `EXCUSE_MAX_S` in all. An answer that came meanwhile is read at once; one that
        did not may be late for those reasons, and a board that is really gone is still
        found: a pulled port fails at once, a silent one after at most the excuse more (on
        an idle host, no later than without it)."""
        start = deadline.at
        t_last = now()
        waited = cpu_waited_s()
        ours = 0.0  # excused to this thread (and to bytes still in the port)
        while True:
            if n_answer is None:
                answer += self._ser.read_until(p.CR)
            else:
                answer += self._ser.read(count * n_answer - len(answer))
            if _answers(answer, n_answer) >= count:
                return answer
            t = now()
            late = t - t_last - READ_SLICE_S
            if late > SCHEDULING_SLACK_S or self._unsent():
                ours += max(late, t - t_last)
            t_last = t
            deadline.at = start + min(EXCUSE_MAX_S, ours)
            if t >= deadline.at and waited is not None:  # the host's share, once it counts
                host = (cpu_waited_s() or waited) - waited
                deadline.at = start + min(EXCUSE_MAX_S, ours + host)
            if t >= deadline.at:
                return answer

    def _unsent(self) -> bool:
        """Do bytes we wrote still wait in the port (a pty's other end has not read them)?"""
        try:
            return bool(self._ser.out_waiting)
        except (*IO_ERRORS, *CLOSED_UNDER, NotImplementedError):
            return False  # a port that cannot tell: its bytes are taken to have left


def _answers(data: bytes, n_answer: int | None) -> int:
    """How many whole answers `data` holds: of `n_answer` bytes each, or ended by CR."""
    return data.count(p.CR) if n_answer is None else len(data) // n_answer


def _last(data: bytes, n_answer: int | None) -> bytes:
    """The last whole answer in `data` (which holds one at least)."""
    if n_answer is None:
        end = data.rindex(p.CR) + 1
        return data[data.rfind(p.CR, 0, end - 1) + 1 : end]
    end = len(data) // n_answer * n_answer
    return data[end - n_answer : end]
