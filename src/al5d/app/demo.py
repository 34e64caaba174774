"""The DE01 demo: server on the embedded emulator, client in its own process, QoS table."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

from al5d.app.reach import QoSRecorder, format_table
from al5d.app.server import RosSide, ServerOptions, arm
from al5d.arm.config import load_config
from al5d.owner import lane

DEMO_SEQUENCE = Path(__file__).resolve().parent.parent / "data" / "demo.seq"


def run_demo(sequence: Path = DEMO_SEQUENCE, baud: int | None = None) -> int:
    """Run the sequence through `al5d run` (over ROS 2) against this process's server; 0 if
    SA03 held."""

    # A domain of our own unless the user chose one: two demos on one host never meet.
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(100, 199)))
    config = load_config()
    started = time.monotonic()
    print(
        f"al5d demo: server on the embedded emulator, ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}"
    )
    options = ServerOptions(baud=baud)
    ros = RosSide(options)
    try:
        settings = ros.settings()
        if isinstance(settings, str):
            print(f"al5d demo: {settings}", file=sys.stderr)
            return 2
        with arm(options, config, lane.path()) as (owner, emulator):
            assert emulator is not None
            recorder = QoSRecorder(owner, emulator)
            ros.serve(owner)
            client = [sys.executable, "-m", "al5d", "run", "--via", "ros", str(sequence)]
            print(f"al5d demo: client: al5d run --via ros {sequence}", flush=True)
            code = subprocess.call(client)
            owner.finished.wait(30)
    finally:
        ros.close()
    rows = recorder.rows()
    print()
    print("QoS achieved per move (DE02):")
    print(format_table(rows))
    print(
        f"\nal5d demo: client exit {code} (1 is expected: the demo refuses and cancels "
        f"on purpose); {time.monotonic() - started:.1f} s in all"
    )
    if code == 2:
        return 2
    return 0 if all(r.within_bound is not False for r in rows) else 1
