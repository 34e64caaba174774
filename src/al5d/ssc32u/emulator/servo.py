"""One emulated servo channel: the board's pulse ramp and the physical servo that follows it.

Pure arithmetic in closed form, no I/O and no clock of its own: every method
takes the time, so the time a servo reached its target is known exactly
rather than polled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: A servo the emulator is not told about: 60 deg / 0.19 s at about 10 us/deg.
DEFAULT_SPEED_US_S = 60 / 0.19 * 10


def follow(x: float, c: float, r: float, v: float, d: float) -> float:
    """Where a servo at `x` is after `d` s, chasing a pulse at `c` moving at `r` us/s, at most `v`.

    The servo moves toward its pulse at its top speed `v`; once it has caught
    up it tracks the pulse if the pulse moves no faster than `v`.
    """
    while d > 0:
        g = c - x
        if abs(g) < 1e-9:
            if abs(r) <= v:
                return c + r * d
            return x + math.copysign(v, r) * d
        s = 1.0 if g > 0 else -1.0
        closing = v - s * r
        if closing <= 0:
            return x + s * v * d
        t_meet = abs(g) / closing
        if d <= t_meet:
            return x + s * v * d
        c += r * t_meet
        x = c
        d -= t_meet
    return x


@dataclass(frozen=True, slots=True)
class Pulse:
    """What a channel puts out from `t0` on, as a servo on it sees it: nothing (`on`
    False: the servo is limp), or a pulse from `start_us` at `t0` to `end_us` at `t1` in a
    straight line, then staying, plus the channel's offset. The board tells observers
    (`Board.observe_pulses`) each new one; times are the board's clock (`al5d.clock`)."""

    on: bool
    start_us: float
    end_us: float
    t0: float
    t1: float
    offset_us: int = 0

    def at(self, t: float) -> float:
        """The pulse width (us, the offset included) at `t`; 0 when off."""
        if not self.on:
            return 0.0
        if t >= self.t1 or self.t1 <= self.t0:
            us = self.end_us
        elif t <= self.t0:
            us = self.start_us
        else:
            us = self.start_us + (self.end_us - self.start_us) * (t - self.t0) / (self.t1 - self.t0)
        return us + self.offset_us


@dataclass
class Servo:
    """One channel: its commanded pulse ramp and the physical servo following it."""

    speed_us_s: float
    position_us: float  # physical, at time `t_position`
    t_position: float
    known: bool = False  # has the board had a pulse command for it since power-up?
    on: bool = False  # is the channel putting out pulses?
    start_us: float = 0.0
    end_us: float = 0.0
    t0: float = 0.0
    t1: float = 0.0
    busy_until: float = 0.0  # Q answers '+' until then, even after a STOP
    offset_us: int = 0
    output_high: bool | None = None

    def pulse_at(self, t: float) -> float:
        if not self.on:
            return 0.0
        if t >= self.t1 or self.t1 <= self.t0:
            return self.end_us
        if t <= self.t0:
            return self.start_us
        return self.start_us + (self.end_us - self.start_us) * (t - self.t0) / (self.t1 - self.t0)

    def pulse(self) -> Pulse:
        """What the channel puts out, as one record (`Pulse`)."""
        on = self.on and self.output_high is None
        return Pulse(on, self.start_us, self.end_us, self.t0, self.t1, self.offset_us)

    def position_at(self, t: float) -> float:
        """The physical position at `t` >= the last update (pure)."""
        x, tx = self.position_us, self.t_position
        if not self.on or t <= tx:
            return x
        v, off = self.speed_us_s, self.offset_us
        if tx < self.t1:
            b = min(t, self.t1)
            slope = (self.end_us - self.start_us) / (self.t1 - self.t0)
            x = follow(x, self.pulse_at(tx) + off, slope, v, b - tx)
            tx = b
        if t > tx:
            x = follow(x, self.end_us + off, 0.0, v, t - tx)
        return x

    def advance(self, t: float) -> None:
        if t > self.t_position:
            self.position_us = self.position_at(t)
            self.t_position = t

    def hold(self, t: float) -> None:
        """STOP: the pulse stays where it is at `t`; Q's count-down (busy_until) is kept."""
        self.advance(t)
        held = self.pulse_at(t)
        self.start_us = self.end_us = held
        self.t0 = self.t1 = t

    def settle_time(self, tol_us: float) -> float:
        """When the servo came (or will come) within `tol_us` of its final target, to stay."""
        target = self.end_us + self.offset_us
        if not self.on:
            return self.t_position
        t_lo = self.t_position
        # After the ramp the servo closes the rest at top speed: an upper bound.
        gap = abs(self.position_at(max(self.t1, t_lo)) - target)
        t_hi = max(self.t1, t_lo) + gap / self.speed_us_s
        step = 0.001
        t = t_hi
        while t - step > t_lo and abs(self.position_at(t - step) - target) <= tol_us:
            t -= step
        lo, hi = max(t_lo, t - step), t  # outside (or the start) at lo, inside at hi
        if abs(self.position_at(lo) - target) <= tol_us:
            return lo
        for _ in range(30):
            mid = (lo + hi) / 2
            if abs(self.position_at(mid) - target) <= tol_us:
                hi = mid
            else:
                lo = mid
        return hi
