"""The SSC-32U low-level driver: one method per board function, serial I/O kept inside.

It knows channels and pulse widths, never joints or degrees. It never waits for
an acknowledgement (the board sends none); only queries read. Every serial
failure, whatever pyserial or the OS calls it, leaves here as a `SerialFault`
subclass (see `al5d.ssc32u.errors`) with the port and what happened.

Threads: a query (write then read) holds a query lock; `stop()` does not take
it, so an emergency stop never waits behind a read. The writes, moves paced to the
wire and stops that never wait, are `al5d.ssc32u.wire`'s.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from types import TracebackType

import serial

from al5d.clock import Deadline, now
from al5d.priority import cpu_waited_s
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import (
    GarbageAnswer,
    Interrupted,
    NoAnswer,
    NotAnSSC32U,
    PortUnavailable,
    SerialFault,
)
from al5d.ssc32u.facts import (
    ANSWER_DELAY_MAX_S,
    FACTORY_BAUD,
    FIRMWARE_PREFIX,
    LATENCY_TIMER_MS,
    LOW_LATENCY_TIMER_MS,
)
from al5d.ssc32u.wire import (
    CLOSED_UNDER,
    DEFAULT_WRITE_TIMEOUT_S,
    GATE_WAIT_S,
    IO_ERRORS,
    WIRE_HORIZON_S,
    Wire,
)

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
#: A VER answer's length, for its deadline (`SSC32-V2.50USB\r` is 15 bytes).
VERSION_ANSWER_BYTES = 16


Targets = Mapping[int, int] | Sequence[p.ChannelTarget]


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
        self._query_lock = threading.Lock()
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
        self._wire = Wire(self._ser, port, baud, write_timeout_s)
        if check:
            try:
                self._wire.write(p.CANCEL)
                self.firmware = self._check_version()
            except SerialFault:
                self.close()
                raise
        self._wire.register()

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
        # on a half-closed port with what pyserial raises for it (see `Wire.lost`).
        self._wire.close()
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
        self._wire.write(data, paced=True)
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
        return self._wire.write(data, unless, paced=True, horizon_s=min(horizon_s, WIRE_HORIZON_S))

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
        self._wire.stop(data, paced, key)
        return data

    def written_elsewhere(self, data: bytes) -> None:
        """Another process has written `data` to this port (the stop process's STOP): the
        account of the wire, and the tap, hear of it as of a write here."""
        self._wire.written_elsewhere(data)

    def settle_stops(self, timeout: float = GATE_WAIT_S) -> bool:
        """Wait (at most `timeout`) until every stop another process wrote (`gate_port`) has
        been obeyed by the server; True if none is left."""
        return self._wire.settle_stops(timeout)

    @property
    def gated(self) -> bool:
        """Another process may write a stop to this port (`gate_port`)."""
        return self._wire.gated

    def plan_stops(self, channels: Sequence[int], until: float) -> None:
        """A stop another process writes (`gate_port`) STOPs the channels in this order until
        `until` (CLOCK_MONOTONIC), as `stop` would be asked to; nothing without one."""
        self._wire.plan_stops(channels, until)

    def cancel(self) -> None:
        """ESC: the board drops the partial line it holds."""
        self._wire.write(p.CANCEL)

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
        self._wire.write(p.encode_pulse_offset(offsets), paced=True)

    def set_outputs(self, levels: Mapping[int, bool]) -> None:
        """H/L: use channels as digital outputs."""
        self._wire.write(p.encode_digital_output(levels), paced=True)

    def arrival(self, n_bytes: int) -> float:
        """When a command of `n_bytes` written now would have reached the board."""
        return self._wire.arrival(n_bytes)

    def wire_time_s(self, command: bytes | int) -> float:
        """Seconds the command (or that many bytes) needs on the wire at the current baud."""
        return self._wire.wire_time_s(command)

    # -- inside ----------------------------------------------------------------------

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

    def _query(self, data: bytes, n_answer: int | None, name: str) -> bytes:
        """Write a query and read its answer; asked once more before a missing answer is a fault.

        The second ask covers a board (or an emulator in a busy process) that was late once,
        or a query a stop's flush dropped on a UART. The board answers in order, so a late
        first answer comes before the second: both are read, and the last is returned. A
        late first answer is never left for the next query to take as its own.
        """
        with self._query_lock:
            stops = self._wire.stop_count()
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
                raise self._wire.lost(e, f"{name} failed") from e
        if _answers(answer, n_answer) == 0:
            if self._wire.stop_count() != stops:
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
        self._wire.write(data)
        back = self.wire_time_s(n_answer if n_answer is not None else VERSION_ANSWER_BYTES)
        return Deadline(back + self._margin_s, start=self._wire.free_at)

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
