"""How short of cores this host was over a stretch of a test: the kernel's CPU pressure.

A test that checks when something happened (a trajectory's point on the board, a step's
lateness the server reports) cannot tell a late server from a host that gave it no core:
on a machine with busy loops beside the suite, a thread waits its turn for seconds. Such a
test allows what the host was short of cores meanwhile (`Shortage.s`) on top of its own
bound, as the driver's link checks excuse a late answer (`al5d.priority.cpu_waited_s`): on
an idle host that is about nothing and the bound is the test's; on a busy one, the check
says only what the host let it say.
"""

from __future__ import annotations

from al5d.priority import cpu_waited_s


class Shortage:
    """From its making: how long at least one runnable task of this host waited for a core,
    in seconds (0 where the kernel does not say: the test's own bound alone)."""

    def __init__(self) -> None:
        self._start = cpu_waited_s()

    @property
    def s(self) -> float:
        now = cpu_waited_s()
        if now is None or self._start is None:
            return 0.0
        return now - self._start
