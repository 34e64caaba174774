"""The board's input pins A..H: what a digital, latched or analog read answers, and when.

Pure arithmetic over each pin's history of levels, like the servo model: every
method takes the time, so a debounce of 15 ms is exact rather than polled.

A pin's level is on the analog scale (0 = 0 V, 255 = 4.98 V) or `None` for an
open pin. Digital reads see an open pin high: its weak pull-up (UG-33). The
pull-up is off once the pin is read as analog (UG-34), so an open pin then
floats; the emulator answers 0 for it (our choice: a real one answers noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import pairwise

from al5d.ssc32u import facts

Level = int | None
#: Before any change: the level a pin had at power-up stands for all time before it.
FOREVER = float("-inf")


def input_level(name: str, value: bool | int | str | None) -> tuple[str, Level]:
    """The pin and level of a setting: `A`..`H` with 0 or 1 (a digital level: 0 V or 5 V),
    `VA`..`VH` with 0..255 (an analog level), either with None or "open".

    Raises ValueError, saying what is allowed.
    """
    key = name.strip().upper()
    analog = len(key) == 2 and key[0] == "V"
    pin = key[1:] if analog else key
    allowed = f"A..H (0, 1 or open) or VA..VH (0..{facts.ANALOG_MAX} or open), not {name}={value!r}"
    if len(pin) != 1 or pin not in facts.ANALOG_PINS:
        raise ValueError(f"no such input: {allowed}")
    if value is None or (isinstance(value, str) and value.strip().lower() == "open"):
        return pin, None
    try:
        number = int(value)
    except ValueError as e:
        raise ValueError(f"not a level: {allowed}") from e
    if analog:
        if number not in range(facts.ANALOG_MAX + 1):
            raise ValueError(f"not an analog level: {allowed}")
        return pin, number
    if number not in (0, 1):
        raise ValueError(f"not a digital level: {allowed}")
    return pin, facts.ANALOG_MAX if number else 0


def _high(level: Level) -> bool:
    return level is None or level >= facts.DIGITAL_THRESHOLD


@dataclass
class Pin:
    """One input pin: its levels over time, its latch and whether it is analog yet."""

    level: Level = None  # at power-up, and ever before
    changes: list[tuple[float, Level]] = field(default_factory=list)
    latch_from: float = FOREVER  # when a latched read (or power-up) last reset the latch
    analog: bool = False  # read as analog since power-up (its pull-up is off)

    def set(self, t: float, level: Level) -> None:
        self.changes.append((t, level))

    def level_at(self, t: float) -> Level:
        level = self.level
        for tc, lv in self.changes:
            if tc > t:
                break
            level = lv
        return level

    def debounced(self, t: float) -> list[tuple[float, bool]]:
        """The digital value a read sees, as (from when, value) up to `t`: a new logic level
        counts once it has held for the debounce time (UG-33)."""
        out = [(FOREVER, _high(self.level))]
        spans = [*self.changes, (t, None)]
        for (tc, lv), (tn, _) in pairwise(spans):
            if tc > t:
                break
            if _high(lv) != out[-1][1] and min(tn, t) - tc >= facts.DEBOUNCE_S:
                out.append((tc + facts.DEBOUNCE_S, _high(lv)))
        return out

    def digital(self, t: float) -> bytes:
        return facts.HIGH if self.debounced(t)[-1][1] else facts.LOW

    def latched(self, t: float) -> bytes:
        """Low if the pin is low now or went low since the last latched read; the read resets
        the latch."""
        values = self.debounced(t)
        since = self.latch_from
        self.latch_from = t
        at_start = next(v for tv, v in reversed(values) if tv <= since)
        went_low = not at_start or any(not v for tv, v in values if tv > since)
        return facts.LOW if went_low else facts.HIGH

    def read_analog(self, t: float) -> int:
        if not self.analog:
            self.analog = True  # the read that turns the pin analog is not valid (UG-34)
            return facts.ANALOG_FIRST_READ
        level = self.level_at(t)
        return 0 if level is None else level

    def power_up(self, t: float) -> None:
        """A restart: the latch and the analog mode are gone; the level is what it is."""
        self.level = self.level_at(t)
        self.changes = [(tc, lv) for tc, lv in self.changes if tc > t]
        self.latch_from = t
        self.analog = False
