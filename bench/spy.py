"""py-spy on the server while a figure is measured: a flame graph, and its top frames.

py-spy (a sampling profiler, pinned in the bench extras) reads the process from
outside, without stopping it (`--nonblocking`), so it costs the server little.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

PY_SPY = str(Path(sys.executable).with_name("py-spy"))


@contextmanager
def profiled(pid: int, out: Path, fmt: str = "raw", rate: int = 500) -> Iterator[None]:
    """Sample process `pid` for the duration of the block into `out` (raw or flamegraph)."""
    args = ["record", "-p", str(pid), "-r", str(rate), "-f", fmt, "-o", str(out)]
    proc = subprocess.Popen(
        [PY_SPY, *args, "--nonblocking", "--threads"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        yield
    finally:
        proc.send_signal(signal.SIGINT)  # py-spy writes what it has on SIGINT
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            err = "py-spy did not end"
        if proc.returncode not in (0, -signal.SIGINT) and not out.exists():
            print(f"py-spy: {err.strip()[-300:]}", file=sys.stderr)


def top_frames(raw: Path, within: str, n: int = 3) -> list[tuple[str, float]]:
    """The `n` frames that held the CPU most (self time, as a share of the samples) among
    the stacks that pass through a frame containing `within` (the command path)."""
    own: Counter[str] = Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = stack.split(";")
        if not any(within in f for f in frames):
            continue
        total += int(count)
        own[frames[-1]] += int(count)
    return [(frame, c / total) for frame, c in own.most_common(n)] if total else []
