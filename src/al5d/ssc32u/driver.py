"""The SSC-32U low-level driver for tools: one method per board function, on a transport.

It knows channels and pulse widths, never joints or degrees; a query writes and waits
for its answer (asked once more before a missing answer is a fault). It is for one
thread at a time: `al5d doctor`, tests and benchmarks. The arm's server does not use it:
its owner (`al5d.owner`) writes the board from one thread, without waiting. Every
serial failure leaves here as a `SerialFault` subclass (see `al5d.ssc32u.errors`).
"""

from __future__ import annotations

import select
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TypeVar

from al5d.clock import Deadline, now
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import GarbageAnswer, NoAnswer, NotAnSSC32U, SerialFault
from al5d.ssc32u.facts import (
    ANSWER_DELAY_MAX_S,
    FACTORY_BAUD,
    FIRMWARE_PREFIX,
    LATENCY_TIMER_MS,
    LOW_LATENCY_TIMER_MS,
)
from al5d.ssc32u.transport import SerialTransport, Transport

#: How long an answer may take beyond its wire time: the board's slowest (5 ms) ten times
#: over, because the host may be busy when the answer comes.
DEFAULT_READ_TIMEOUT_S = 10 * ANSWER_DELAY_MAX_S

Targets = Mapping[int, int] | Sequence[p.ChannelTarget]
T = TypeVar("T")


class SSC32U:
    """A connection to one SSC-32U (or the emulator): on `port` (a device path or a pyserial
    URL) at `baud`, or on a given `transport`. On connect it cancels any partial line the
    board may hold and checks the board with VER."""

    def __init__(
        self,
        port: str = "",
        baud: int = FACTORY_BAUD,
        *,
        transport: Transport | None = None,
        read_timeout_s: float = DEFAULT_READ_TIMEOUT_S,
        check: bool = True,
    ) -> None:
        self.transport = transport or SerialTransport(port, baud)
        self.port = self.transport.port
        self.baud = self.transport.baud
        low_latency = self.transport.open()
        timer_ms = LOW_LATENCY_TIMER_MS if low_latency else LATENCY_TIMER_MS
        self._margin_s = read_timeout_s + timer_ms / 1000.0
        self.firmware = ""
        if check:
            try:
                self.write(p.CANCEL)
                self.firmware = self._check_version()
            except SerialFault:
                self.close()
                raise

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> SSC32U:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- board functions ----------------------------------------------------------------

    def write(self, data: bytes) -> bytes:
        """Bytes already encoded by `al5d.ssc32u.protocol`, as they are."""
        self.transport.write(data)
        return data

    def move(self, targets: Targets, time_ms: int | None = None) -> bytes:
        """Group move: every channel to its pulse width (us), all arriving together."""
        if isinstance(targets, Mapping):
            seq = [p.ChannelTarget(ch, pw) for ch, pw in targets.items()]
        else:
            seq = list(targets)
        return self.write(p.encode_group_move(seq, time_ms))

    def stop(self, channels: Iterable[int]) -> bytes:
        """ESC (the board drops any partial line), then STOP every channel, in one write."""
        return self.write(p.CANCEL + p.encode_stop(channels))

    def cancel(self) -> None:
        """ESC: the board drops the partial line it holds."""
        self.write(p.CANCEL)

    def set_offsets(self, offsets: Mapping[int, int]) -> None:
        """PO: volatile pulse trims, -100..100 us."""
        self.write(p.encode_pulse_offset(offsets))

    def set_outputs(self, levels: Mapping[int, bool]) -> None:
        """H/L: use channels as digital outputs."""
        self.write(p.encode_digital_output(levels))

    def is_done(self) -> bool:
        """Q: True when the board reports every move complete."""
        answer = self._query(p.encode_query_movement(), 1, "Q")
        return not self._parse(p.parse_movement, answer)

    def read_pulses(self, channels: Sequence[int]) -> dict[int, int]:
        """QP: the pulse width (us, 10 us resolution) each channel puts out now; 0 = none yet."""
        chans = list(channels)
        answer = self._query(p.encode_query_pulse(chans), len(chans), "QP")
        return self._parse(lambda a: p.parse_pulses(a, chans), answer)

    def version(self) -> str:
        """VER: the firmware string."""
        return self._parse(p.parse_version, self._query(p.encode_version(), None, "VER"))

    def wire_time_s(self, command: bytes | int) -> float:
        """Seconds the command (or that many bytes) needs on the wire at the current baud."""
        n = command if isinstance(command, int) else len(command)
        return p.wire_time_s(n, self.baud)

    # -- inside -----------------------------------------------------------------------

    def _parse(self, parse: Callable[[bytes], T], answer: bytes) -> T:
        try:
            return parse(answer)
        except p.ProtocolError as e:
            raise GarbageAnswer(self.port, f"not an SSC-32U answer: {e}", answer) from e

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
        """Write a query and read its answer; asked once more before no answer is a fault (a
        late first answer, read with the second, is never left for the next query)."""
        self.transport.read()  # what came unasked is not an answer to this
        answer = b""
        for asks in (1, 2):
            self.write(data)
            back = self.wire_time_s(len(data) + (n_answer or p.VERSION_ANSWER_BYTES))
            answer = self._read(answer, n_answer, asks, Deadline(back + self._margin_s))
            if p.count_answers(answer, n_answer):
                return p.last_answer(answer, n_answer)
        got = f", got {answer!r}" if answer else ""
        raise NoAnswer(self.port, f"no answer to {name}, asked twice{got}", answer)

    def _read(self, answer: bytes, n_answer: int | None, count: int, deadline: Deadline) -> bytes:
        fd = self.transport.fileno()
        while p.count_answers(answer, n_answer) < count and not deadline.expired:
            if fd is not None:
                select.select([fd], [], [], deadline.left())
            else:  # an emulated board in this process: it says when its answer is due
                due = self.transport.due()
                time.sleep(
                    max(0.0, min(due if due is not None else deadline.at, deadline.at) - now())
                )
            answer += self.transport.read()
        return answer
