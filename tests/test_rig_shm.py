"""Fast DDS's shared-memory files of a killed process are found and removed; a live
process's are kept (`al5d_rig.shm`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from al5d_rig import shm
from al5d_rig.proc import said

#: A process with a DDS participant, which says so and then waits.
PARTICIPANT = """
import time
from rclpy.node import Node
from al5d.ros.dds import start_context
context = start_context()
node = Node("al5d_shm_probe", context=context)
print("up", flush=True)
time.sleep(600)
"""


def segments() -> set[str]:
    return {n for n in os.listdir(shm.SHM) if shm._LOCK.match(n)}


def inode(path: Path) -> int | None:
    try:
        return path.stat().st_ino
    except FileNotFoundError:
        return None


def participant() -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-c", PARTICIPANT], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and said(proc.stdout) == "up"
    return proc


def test_a_killed_process_s_files_go_a_live_one_s_stay() -> None:
    before = segments()
    live, killed = participant(), participant()
    try:
        theirs = segments() - before
        assert theirs, "the participants made no shared-memory files"
        killed.send_signal(signal.SIGKILL)
        killed.wait(30)
        files = {name: inode(shm.SHM / name[:-3]) for name in theirs}
        shm.clean()
        left = segments()
        # The live one's segment stays (and every port some live process holds); at
        # least the killed one's own segment is gone.
        assert theirs & left, (theirs, left)
        assert theirs - left, (theirs, left)
        for name in theirs - left:
            # Gone, or made again since by a process of another test (a port's number is
            # the domain's: an idle CI run saw one there again).
            now = inode(shm.SHM / name[:-3])
            assert now is None or now != files[name], name
    finally:
        live.kill()
        live.wait(30)
        killed.kill()


def test_a_lock_held_is_kept_one_free_is_removed(tmp_path: Path) -> None:
    import fcntl

    for name in ("fastrtps_0123456789abcdef", "fastrtps_port7411"):
        (tmp_path / name).write_bytes(b"x")
        (tmp_path / f"{name}_el").write_bytes(b"")
    (tmp_path / "sem.fastrtps_port7411_mutex").write_bytes(b"")
    (tmp_path / "other_el").write_bytes(b"")
    with open(tmp_path / "fastrtps_0123456789abcdef_el", "ab") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # flock locks are per open file: this one holds
        assert shm.clean(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "fastrtps_0123456789abcdef",
        "fastrtps_0123456789abcdef_el",
        "other_el",
    ]
