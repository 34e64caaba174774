"""Threads that must not wait their turn, ahead of the rest with the kernel's scheduler.

On a robot's computer MoveIt, RViz, a browser and a flood of instructions
share the cores with the server; a thread that serves the stop must not wait
its turn behind them, and an emulated board, which stands for a board with a
processor of its own, must not answer late because the host is busy. Linux
gives each thread its own nice value (`setpriority(PRIO_PROCESS, tid)`), and a
thread a thread starts inherits it: so the stop path's threads (the safety
services' executor, the stop watcher's reader) and the DDS participant they use
(whose receive threads Fast DDS starts when its first node is made) are made
from a thread at `URGENT_NICE`, and so is every thread of `al5d emulator` and an
emulated board's link wherever it runs.
What no priority buys is told apart by `cpu_waited_s`: the time runnable tasks
waited for a core, which is what makes a board's answer late on a busy host
(the kernel's work that carries a pty's or a USB port's bytes waits its turn too).
Going below nice 0 needs CAP_SYS_NICE (root) or an RLIMIT_NICE that allows it;
where it is refused, one log line says so and the threads run at the default
priority.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from typing import TypeVar

log = logging.getLogger("al5d")

#: The urgent threads' nice value: a runnable thread at -10 weighs about nine times one at 0
#: with Linux's scheduler, and wakes ahead of it.
URGENT_NICE = -10

_refused = threading.Event()  # said once per process

T = TypeVar("T")


def make_urgent(what: str, quiet: bool = False) -> bool:
    """Give the calling thread (and those it starts) the urgent priority; False where the OS
    refuses it, said once unless `quiet`."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), URGENT_NICE)
    except (OSError, AttributeError) as e:
        if not quiet and not _refused.is_set():
            _refused.set()
            log.warning(
                "%s: the OS refused a higher scheduling priority (nice %d: %s); it runs at "
                "the default priority, and waits its turn on a busy host (grant CAP_SYS_NICE, "
                "or raise RLIMIT_NICE with `ulimit -e`, to have it)",
                what,
                URGENT_NICE,
                e,
            )
        return False
    return True


def built_urgently(what: str, build: Callable[[], T]) -> T:
    """`build()` run in a thread at the urgent priority, so that every thread it starts
    (a DDS participant's among them) inherits it; its result, or its exception."""
    out: list[T] = []
    failed: list[BaseException] = []

    def run() -> None:
        make_urgent(what)
        try:
            out.append(build())
        except BaseException as e:  # handed to the caller's thread as is
            failed.append(e)

    thread = threading.Thread(target=run, name=f"{what}-build")
    thread.start()
    thread.join()
    if failed:
        raise failed[0]
    return out[0]


#: The kernel's CPU pressure (Linux 4.20 on, where PSI is enabled): its first line is
#: `some avg10=.. avg60=.. avg300=.. total=<us>`.
CPU_PRESSURE = "/proc/pressure/cpu"


def cpu_waited_s(path: str = CPU_PRESSURE) -> float | None:
    """How long, since boot, at least one runnable task of this host waited for a core (the
    kernel's CPU pressure, "some"), in seconds; None where the kernel does not say.

    The difference over an interval is the part of it the host was short of cores: a
    board's answer that came late for that long was late because of the host, not the
    board. Reading it costs a few microseconds."""
    try:
        with open(path, "rb") as f:
            first = f.readline()
        return int(first.rsplit(b"total=", 1)[1]) / 1e6
    except (OSError, IndexError, ValueError):
        return None
