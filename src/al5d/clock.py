"""Time for everything in al5d: one monotonic clock and a deadline that counts down.

The bottom of the package: it imports nothing of al5d, and every layer may use it.
"""

from __future__ import annotations

import time

#: Every time in al5d is CLOCK_MONOTONIC, which all processes on the machine share.
now = time.monotonic


class Deadline:
    """A moment `timeout` seconds from its creation (or from `start`), and the time left."""

    __slots__ = ("at",)

    def __init__(self, timeout: float, start: float | None = None) -> None:
        self.at = (now() if start is None else start) + timeout

    def left(self) -> float:
        """Seconds until the deadline, never negative."""
        return max(0.0, self.at - now())

    @property
    def expired(self) -> bool:
        return now() >= self.at


def wall_ns() -> int:
    """CLOCK_REALTIME in ns: the clock DDS stamps a message with when it is sent, which every
    process on the machine shares. Only the order of a message's sending and the driver's
    events is judged on it (`al5d.arm.core`); every duration is `now`'s."""
    return time.time_ns()
