"""`al5d send stop` typed in a new terminal: from the command's start to the STOP in effect.

A user who stops the arm from a new shell pays the interpreter's start and whatever the
command does before it asks; over ROS 2 that was discovery (0.7 to 3.5 s measured). On
this machine the command goes by the server's local lane (`al5d.owner.quick`). Each
trial: a 4 s move under way on an emulated board (this process; `al5d serve --port` in a
process of its own), then `al5d send stop` started, timed from the moment it is spawned
to the first STOP in effect on the board. The floor, measured in the same run: a bare
interpreter of the same venv started and ended (`python -c pass`: its `site`, the ROS
wheels' `.pth`, nothing of al5d). Idle, then beside two busy loops.

Target (issue 43): p99 within 250 ms, idle and busy.

    .venv/bin/python bench/quickstop.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from al5d_rig import domains

if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from stats import figure

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig, load_config
from al5d.owner import where
from al5d.owner.client import Remote
from al5d.ssc32u.emulator import Emulator
from al5d_rig.proc import AL5D, Proc, patient_config

TARGET_P99_MS = 250.0
HERE = Path(__file__).resolve().parent


@contextmanager
def busy(loops: int) -> Iterator[None]:
    """`loops` busy loops beside whatever runs."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(loops)]
    try:
        time.sleep(0.5)
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


def floor(n: int) -> list[float]:
    """A bare interpreter of this venv, spawned and ended, in ms."""
    out = []
    for _ in range(n):
        t0 = time.monotonic()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        out.append((time.monotonic() - t0) * 1000)
    return out


def stops(emu: Emulator, arm: Remote, n: int) -> list[float]:
    """`al5d send stop` from its spawn to the first STOP in effect, in ms, `n` times."""
    out = []
    for i in range(n):
        move = arm.submit(ins.move(base=80 if i % 2 else -80, time_ms=4000))
        time.sleep(0.3)
        seen = len(emu.records)
        t0 = time.monotonic()
        done = subprocess.run([AL5D, "send", "stop"], capture_output=True, text=True)
        assert done.returncode == 0 and "(by the local lane)" in done.stdout, done
        records = emu.wait_for(
            lambda rs, seen=seen: any(r.raw.startswith(b"STOP") for r in rs[seen:]), 10
        )
        first = next(r for r in records[seen:] if r.raw.startswith(b"STOP"))
        out.append((first.t_effect - t0) * 1000)
        move.result(10)
        assert arm.execute(ins.release(), 10).ok
    return out


def run(config: ArmConfig, log: Any, n: int = 40) -> dict[str, Any]:
    workdir = Path(tempfile.mkdtemp(prefix="al5d-quickstop-"))
    link = workdir / "ssc32u"
    out: dict[str, Any] = {}
    with Emulator(config, link=link) as emu:
        server = Proc("serve", "--port", str(link), "--config", patient_config())
        try:
            # The lane is said before or after the state, as the owner's thread and the
            # server's start go: either order.
            server.err.wait_for_each(("STATE: ready", "local lane"), 60)
            with Remote.connect(where.path()) as arm:
                for label, loops in (("idle", 0), ("beside two busy loops", 2)):
                    log(f"al5d send stop: {n} trials, {label}")
                    with busy(loops):
                        ours = stops(emu, arm, n)
                        bare = floor(n)
                    out[label] = {
                        "stop": figure(f"al5d send stop, {label}", ours),
                        "floor": figure(f"a bare interpreter, {label}", bare),
                    }
        finally:
            server.popen.send_signal(2)
            server.wait(60)
    return out


def row(label: str, result: dict[str, Any]) -> tuple[str, str, str, str, bool]:
    stop, bare = result["stop"], result["floor"]
    ours = (
        f"p50 {stop['p50_ms']:.0f} / p99 {stop['p99_ms']:.0f} ms (n={stop['n']}); floor: a "
        f"bare interpreter p50 {bare['p50_ms']:.0f} / p99 {bare['p99_ms']:.0f} ms"
    )
    held = stop["p99_ms"] <= TARGET_P99_MS
    return (
        f"`al5d send stop` in a new process -> STOP in effect, {label}",
        ours,
        "-",
        f"p99 <= {TARGET_P99_MS:.0f} ms",
        held,
    )


if __name__ == "__main__":
    results = run(load_config(), lambda text: print(text, file=sys.stderr, flush=True))
    for label, result in results.items():
        print(" | ".join(str(x) for x in row(label, result)))
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / "quickstop.json").write_text(json.dumps(results, indent=1))
