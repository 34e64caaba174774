"""A probe of the host's stalls: what no scheduling priority of ours could have got past.

    python -m al5d_rig.stallprobe      (runs until its standard input closes)

A process at the highest real-time priority (SCHED_FIFO, where the OS allows it; else
nice -20) sleeps 1 ms at a time and notes every wake-up that came `GAP_S` or more late.
A real-time thread runs ahead of every ordinary task of the host, so what delays it is
the host itself: the hypervisor running another guest (the kernel counts it as steal
time), interrupts, the kernel's own work. A stop that was slow in the same interval was
slow for the same reason, and its latency says nothing about the driver.

When its input closes it prints one line of JSON: the gaps as (monotonic start, seconds
late), the steal time over the run, and which scheduling it got.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

#: A wake-up this late is a stall.
GAP_S = 0.003
TICK_S = 0.001


@dataclass(frozen=True)
class Stalls:
    """Stalls seen by a probe, as its JSON line gives them."""

    gaps: tuple[tuple[float, float], ...] = ()
    steal_s: float = 0.0
    scheduling: str = ""

    @classmethod
    def of(cls, line: str) -> Stalls:
        d = json.loads(line)
        return cls(tuple((a, b) for a, b in d["gaps"]), d["steal_s"], d["scheduling"])

    def during(self, start: float, seconds: float) -> float:
        """The longest stall that overlapped [start, start + seconds], in seconds."""
        end = start + seconds
        worst = 0.0
        for t, late in self.gaps:
            # A gap is the time from when the probe should have woken to when it did.
            if t < end and t + late > start:
                worst = max(worst, late)
        return worst


def steal_s() -> float:
    """The host's steal time since boot (the hypervisor's, in /proc/stat), in seconds."""
    with open("/proc/stat") as f:
        fields = f.readline().split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def scheduled_first() -> str:
    try:
        top = os.sched_get_priority_max(os.SCHED_FIFO)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(top))
        return "SCHED_FIFO"
    except (OSError, AttributeError):
        try:
            os.setpriority(os.PRIO_PROCESS, 0, -20)
            return "nice -20"
        except OSError:
            return "default"


def main() -> int:
    scheduling = scheduled_first()
    gaps: list[tuple[float, float]] = []
    ended = threading.Event()
    stolen = steal_s()

    def wait_for_eof() -> None:
        sys.stdin.read()
        ended.set()

    threading.Thread(target=wait_for_eof, daemon=True).start()
    due = time.monotonic() + TICK_S
    while not ended.is_set():
        time.sleep(TICK_S)
        now = time.monotonic()
        if now - due >= GAP_S:
            gaps.append((due, now - due))
        due = now + TICK_S
    out: dict[str, Any] = {
        "gaps": gaps,
        "steal_s": steal_s() - stolen,
        "scheduling": scheduling,
    }
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
