"""The board's answers to queries: encoded by the emulator, parsed and checked by the driver.

A parser refuses (`ProtocolError`) bytes the board would never send.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from al5d.ssc32u.facts import (
    DONE,
    HIGH,
    LOW,
    MOVING,
    PULSE_MAX_US,
    PULSE_MIN_US,
    PULSE_OFF,
    QP_RESOLUTION_US,
    STARTUP_QUOTE,
)
from al5d.ssc32u.protocol.commands import CR, ProtocolError

#: A VER answer's length, for its deadline (`SSC32-V2.50USB\r` is 15 bytes).
VERSION_ANSWER_BYTES = 16


def count_answers(data: bytes, n_answer: int | None) -> int:
    """How many whole answers `data` holds: of `n_answer` bytes each, or lines (None)."""
    return data.count(CR) if n_answer is None else len(data) // n_answer


def last_answer(data: bytes, n_answer: int | None) -> bytes:
    """The last whole answer in `data` (which holds one at least)."""
    if n_answer is None:
        end = data.rindex(CR) + 1
        return data[data.rfind(CR, 0, end - 1) + 1 : end]
    end = len(data) // n_answer * n_answer
    return data[end - n_answer : end]


def parse_movement(answer: bytes) -> bool:
    """True while moving (`+`), False when complete (`.`)."""
    if answer == MOVING:
        return True
    if answer == DONE:
        return False
    raise ProtocolError(f"Q answered {answer!r}, expected b'+' or b'.'")


def encode_pulses(pulses_us: Sequence[int]) -> bytes:
    """The QP answer: one byte per channel, pulse width / 10."""
    return bytes(max(0, min(255, p // QP_RESOLUTION_US)) for p in pulses_us)


def parse_pulses(answer: bytes, channels: Sequence[int]) -> dict[int, int]:
    """Pulse widths in us from a QP answer (resolution 10 us; 0 = no pulse yet)."""
    if len(answer) != len(channels):
        raise ProtocolError(
            f"QP for {len(channels)} channel(s) answered {len(answer)} byte(s): {answer!r}"
        )
    pulses = {ch: b * QP_RESOLUTION_US for ch, b in zip(channels, answer, strict=True)}
    for ch, p in pulses.items():
        if p != PULSE_OFF and not PULSE_MIN_US <= p <= PULSE_MAX_US:
            raise ProtocolError(
                f"QP{ch} answered {p // QP_RESOLUTION_US} ({p} us), "
                f"outside {PULSE_MIN_US}..{PULSE_MAX_US} us"
            )
    return pulses


def parse_version(answer: bytes) -> str:
    """The firmware string of a VER answer (which ends with CR)."""
    if not answer.endswith(CR):
        raise ProtocolError(f"VER answer has no CR: {answer!r}")
    text = answer[:-1]
    if not text or any(b < 0x20 or b > 0x7E for b in text):
        raise ProtocolError(f"VER answer is not printable ASCII: {answer!r}")
    return text.decode("ascii")


def parse_digital(answer: bytes, n: int) -> list[bool]:
    """The levels of a digital read of `n` pins: True for high (`1`)."""
    if len(answer) != n or any(bytes([b]) not in (LOW, HIGH) for b in answer):
        raise ProtocolError(f"a read of {n} digital input(s) answered {answer!r}")
    return [bytes([b]) == HIGH for b in answer]


def _cr_line(answer: bytes, what: str) -> str:
    if not answer.endswith(CR) or any(b < 0x20 or b > 0x7E for b in answer[:-1]):
        raise ProtocolError(f"{what} answer is not printable ASCII then CR: {answer!r}")
    return answer[:-1].decode("ascii")


def parse_register(answer: bytes) -> int:
    """The value of an `R<n>` answer (`1023\\r`, `-50\\r`)."""
    text = _cr_line(answer, "register")
    if not re.fullmatch(r"-?\d+", text):
        raise ProtocolError(f"register answer is not a decimal number: {answer!r}")
    return int(text)


def parse_startup(answer: bytes) -> str:
    """The startup string of an `SS` answer (`"#0P1500;"\\r`)."""
    text = _cr_line(answer, "SS")
    quote = STARTUP_QUOTE.decode("ascii")
    if len(text) < 2 or text[0] != quote or text[-1] != quote:
        raise ProtocolError(f"SS answer is not quoted: {answer!r}")
    return text[1:-1]
