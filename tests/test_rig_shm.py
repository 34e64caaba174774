"""Fast DDS's shared-memory files of a killed process are found and removed; a live
process's are kept (`al5d_rig.shm`)."""

from __future__ import annotations

import contextlib
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


def held(pid: int) -> set[str]:
    """The lock files in /dev/shm that process `pid` holds open (Fast DDS keeps each of its
    segments' and ports' locks open while it lives)."""
    names = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):
            target = Path(os.readlink(f"/proc/{pid}/fd/{fd}"))
            if target.parent == shm.SHM and shm._LOCK.match(target.name):
                names.add(target.name)
    return names


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
    # Each participant's files are those it holds open, not those new since the test
    # began: other tests' processes make and remove theirs meanwhile (an idle CI run saw
    # another process's port lock gone, its port file still there, and took it for one
    # the clean had half removed).
    live, killed = participant(), participant()
    try:
        alive = held(live.pid)
        dead = held(killed.pid) - alive
        segment = {name for name in dead if "_port" not in name}
        assert alive and segment, (alive, dead)
        before = {name: inode(shm.SHM / name) for name in dead}
        assert all((shm.SHM / name[:-3]).exists() for name in segment), segment
        killed.send_signal(signal.SIGKILL)
        killed.wait(30)
        shm.clean()
        # The live one's files stay, each lock with its segment or port.
        for name in alive:
            assert (shm.SHM / name).exists() and (shm.SHM / name[:-3]).exists(), name
        # The killed one's own segment goes, its lock and itself (its name is random: no
        # other process makes it again).
        for name in segment:
            assert inode(shm.SHM / name) is None and inode(shm.SHM / name[:-3]) is None, name
        # Its ports are numbered: another process may take one up since; none is left
        # with the killed one's lock unowned.
        for name in dead - segment:
            lock = shm.SHM / name
            assert inode(lock) != before[name] or shm._owned(lock), name
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
