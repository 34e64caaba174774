"""Fast DDS's shared-memory files left by processes that are gone, found and removed.

A process that ends without closing its DDS participants (the rig kills servers and clients
outright, tests SIGKILL them on purpose) leaves its segments and ports in /dev/shm. They
pile up across runs (3,369 segments, 3 GB after a day of runs here), and a stale port
then stands in the way of new processes: "Failed init_port fastrtps_port7005:
open_and_lock_file failed" on a CI run's stdout, and a test's answers that never came
until they were removed.

Fast DDS keeps beside each segment and port a lock file (`_el` or `_sl`) that its owner
holds locked (flock) while it lives: one that can be locked has no owner left, and its
files may go (as Fast DDS's own `fastdds shm clean` finds them; that tool is not in the
wheels). Run it when no process of the run is starting: between a file's creation and
its lock, a live one looks dead.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
from pathlib import Path

SHM = Path("/dev/shm")
#: A segment's or a port's lock file (Fast DDS 2.x names them fastrtps_, 3.x fastdds_).
_LOCK = re.compile(r"^(fastrtps|fastdds)_(port\d{1,5}|[0-9a-f]{16})_(el|sl)$")


def _owned(lock: Path) -> bool:
    """Whether a live process holds `lock` (a file it cannot be opened is taken as held)."""
    try:
        with open(lock, "ab") as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    return False


def clean(shm: Path = SHM) -> int:
    """Remove the segments and ports in `shm` whose owners are gone, with their lock files
    (and a port's mutex); how many were removed."""
    try:
        names = os.listdir(shm)
    except FileNotFoundError:
        return 0
    removed = 0
    for name in names:
        found = _LOCK.match(name)
        if found is None or _owned(shm / name):
            continue
        base = name[:-3]
        files = [name, base]
        if found.group(2).startswith("port"):
            files.append(f"sem.{base}_mutex")
        for each in files:
            with contextlib.suppress(FileNotFoundError):
                (shm / each).unlink()
        removed += 1
    return removed
