"""The ROS domains of a test run: a pair of its own for each pytest process."""

from __future__ import annotations

import fcntl
import os
from typing import IO

#: The lock files of the domains this process holds, open while it lives.
_CLAIMED: list[IO[str]] = []


def alone() -> dict[str, str]:
    """The environment of a process in a ROS domain with no server: this process's next
    one, kept free for this (`claim` takes a pair)."""
    return {"ROS_DOMAIN_ID": str(int(os.environ["ROS_DOMAIN_ID"]) + 1)}


def claim() -> int:
    """A free pair of domains (`n` and `n + 1`: one test uses the next as "another"),
    claimed by a lock file held while this process lives, so that test runs on one host
    never see each other whatever else runs (another checkout's suite, a second run).
    Domains picked from the process id collided: two suites in different worktrees met
    about 1 time in 20. From 166: below it, `contention`'s servers take theirs."""
    for domain in range(166, 231, 2):
        lock = open(f"/tmp/al5d-test-ros-domain-{domain}.lock", "w")  # noqa: SIM115
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        _CLAIMED.append(lock)  # held until this process ends
        return domain
    raise RuntimeError("every ROS domain pair from 166 to 230 is taken by another test run")
