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

import re

from al5d.priority import cpu_waited_s

#: The server's word for a trajectory whose point it wrote too late to keep the path.
_LATE = re.compile(r"took effect (\d+) ms late: .*\(the host did not run the owner in time\)")


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

    def excuses(self, reason: str) -> bool:
        """Whether `reason` is the server's word that it ended a trajectory because the host
        ran it too late to keep the path (its point took effect N ms late), and the kernel
        says the host was short of cores at least that long meanwhile: the server kept its
        promise (never a goal done off its path), and the test's own, a goal on time,
        was not the server's to keep."""
        late = _LATE.search(reason)
        return late is not None and self.s >= int(late.group(1)) / 1000
