"""The emulator's settings as text (`al5d emulator --input A=0 --register 0=8 ...`).

Each function reads one command-line value and raises argparse's error with
what is allowed, so that `al5d emulator` says it before it starts.
"""

from __future__ import annotations

import argparse

from al5d.ssc32u import facts
from al5d.ssc32u.emulator.inputs import Level, input_level
from al5d.ssc32u.emulator.measure import Mechanics


def _pair(text: str, what: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: expected {what}")
    return name.strip(), value.strip()


def _int(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from e


def latency_ms(text: str) -> int:
    ms = _int(text, "a number of milliseconds")
    if ms not in facts.LATENCY_TIMER_RANGE_MS:
        raise argparse.ArgumentTypeError(f"the latency timer is 1..255 ms, not {ms}")
    return ms


def input_setting(text: str) -> tuple[str, Level]:
    """`A=1`, `B=open`, `VA=128`: the pin's setting, checked, as its analog name and level
    (`A=1` is `VA` at 255), which `Board(inputs=...)` takes as it is."""
    name, value = _pair(text, "PIN=LEVEL, e.g. A=0, B=open or VA=128")
    try:
        pin, level = input_level(name, value)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e
    return f"V{pin}", level


def register_setting(text: str) -> tuple[int, int]:
    """`0=8`, `R32=-50`: a register and its value at power-up."""
    name, value = _pair(text, "N=VALUE, e.g. 0=8")
    number = _int(name.upper().removeprefix("R"), "a register number")
    if number not in facts.REGISTERS:
        raise argparse.ArgumentTypeError(f"register {number} is outside 0..255")
    v = _int(value, "a register value")
    if v not in facts.REGISTER_VALUES:
        raise argparse.ArgumentTypeError(f"register value {v} is outside -32768..65535")
    return number, v


def pulse_setting(text: str) -> tuple[int, int]:
    """`0=1500`: a channel's pulse at power-up."""
    name, value = _pair(text, "CH=US, e.g. 0=1500")
    ch, us = _int(name, "a channel"), _int(value, "a pulse width in us")
    if ch not in facts.CHANNELS or not facts.PULSE_MIN_US <= us <= facts.PULSE_MAX_US:
        raise argparse.ArgumentTypeError(f"{text!r}: channels 0..31, pulses 500..2500 us")
    return ch, us


#: A misalignment beyond this is a horn on the wrong spline by several teeth, not an offset.
MISALIGN_MAX_US = 500


def misalign_setting(text: str) -> tuple[str, Mechanics]:
    """`base=40`, `shoulder=-25,reversed`, `elbow=reversed`: a joint that truly stands that
    many us off its calibration, or turns the other way (checked against the config later)."""
    name, value = _pair(text, "JOINT=US[,reversed], e.g. base=40 or elbow=-20,reversed")
    words = [w.strip() for w in value.split(",")]
    reversed_ = "reversed" in words
    rest = [w for w in words if w != "reversed"]
    if len(rest) > 1 or (not rest and not reversed_):
        raise argparse.ArgumentTypeError(f"{text!r}: expected JOINT=US[,reversed]")
    offset = float(_int(rest[0].removesuffix("us"), "an offset in us")) if rest else 0.0
    if abs(offset) > MISALIGN_MAX_US:
        raise argparse.ArgumentTypeError(f"{text!r}: an offset within +-{MISALIGN_MAX_US} us")
    return name, Mechanics(offset, reversed_)
