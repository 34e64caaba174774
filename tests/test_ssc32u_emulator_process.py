"""`al5d emulator` as a process of its own, driven by the low-level driver."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from al5d.ssc32u.driver import SSC32U

AL5D = Path(sys.executable).with_name("al5d")


def test_standalone_emulator(tmp_path: Path) -> None:
    link = tmp_path / "ssc32u"
    proc = subprocess.Popen(
        [str(AL5D), "emulator", "--baud", "115200", "--link", str(link)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().strip()
        assert first == str(link)
        assert os.path.realpath(link).startswith("/dev/pts/")
        with SSC32U(first, 115200) as board:
            assert board.firmware == "SSC32-V2.50USB"
            board.move({0: 1500})
            assert board.read_pulses([0]) == {0: 1500}
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    assert not link.exists()
