"""A board on a busy host (issue 23): the emulated board is not starved, and a board that is
gone is still found.

The board here is `al5d emulator` in a process of its own; a host that never runs it
again is the real thing (SIGSTOP).
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
from boardproc import BoardProcess
from test_ros_runtime import thread_nices

from al5d.priority import URGENT_NICE
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import LinkLost, NoAnswer


@pytest.fixture
def board_process(tmp_path: Path) -> Iterator[BoardProcess]:
    board = BoardProcess(tmp_path / "ssc32u")
    try:
        yield board
    finally:
        board.close()


def test_the_emulated_board_runs_ahead_of_the_hosts_load(board_process: BoardProcess) -> None:
    # A board answers in its own time, whatever the computer does: the emulator's threads
    # (its main thread, and the link's reader and writer, which it starts) at the urgent
    # priority. (A native thread a library starts at import time keeps the default.)
    if os.geteuid() != 0:
        pytest.skip("only root (or CAP_SYS_NICE) may raise a priority here")
    nices = thread_nices(board_process.popen.pid)
    assert nices.count(URGENT_NICE) >= 3, nices


def test_a_board_that_never_comes_back_is_lost(board_process: BoardProcess) -> None:
    # What is excused is bounded: a board that stays away is a fault (in `make soak`, within
    # the figures of README Reliability).
    with SSC32U(board_process.port) as ssc:
        os.kill(board_process.popen.pid, signal.SIGSTOP)
        try:
            with pytest.raises((NoAnswer, LinkLost)):
                ssc.read_pulses([0])
        finally:
            os.kill(board_process.popen.pid, signal.SIGCONT)
