"""The stop service's latency under each executor arrangement tried (issue 12).

    python bench/executors.py [TRIALS]

For each arrangement, `al5d serve` on a board in its own process, a move
running and 1000 moves queued, then a stop by service: until its last STOP is
in effect on the board, minus the wire time. Arrangements: the safety services
on their own node and executor thread (the default), on the main executor
(AL5D_SAFETY=shared, as before issue 9), and both with rclpy's Python
SingleThreadedExecutor (AL5D_EXECUTOR=single) or its MultiThreadedExecutor
(AL5D_EXECUTOR=multi) instead of the C++ EventsExecutor.
"""

from __future__ import annotations

import json
import os
import random
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests")]
os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(100, 199)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rosbench  # noqa: E402
from rospeer import Peer  # noqa: E402

from al5d.arm.config import load_config  # noqa: E402

ARRANGEMENTS = {
    "events, safety on its own thread (default)": {},
    "events, safety on the main executor": {"AL5D_SAFETY": "shared"},
    "single-threaded, safety on its own thread": {"AL5D_EXECUTOR": "single"},
    "single-threaded, safety on the main executor": {
        "AL5D_EXECUTOR": "single",
        "AL5D_SAFETY": "shared",
    },
    "multi-threaded (2 threads), safety on the main executor": {
        "AL5D_EXECUTOR": "multi",
        "AL5D_SAFETY": "shared",
    },
    "multi-threaded (2 threads), safety on its own thread": {"AL5D_EXECUTOR": "multi"},
}


def main() -> int:
    trials = int(sys.argv[1]) if len(sys.argv) > 1 else 60
    config = load_config()
    out = {}
    peer = Peer()
    try:
        for name, env in ARRANGEMENTS.items():
            print(f"[{time.strftime('%H:%M:%S')}] {name}", file=sys.stderr, flush=True)
            work = Path(tempfile.mkdtemp(prefix="al5d-exec-"))
            rig = rosbench.Rig(config, 9600, work, peer, env=env)
            try:
                stop = rosbench.emergency_stop(rig, trials=trials)
            finally:
                rig.proc.kill()
                rig.emu.close()
            out[name] = {
                via: {k: stop[f"{via} software"][k] for k in ("n", "p50_ms", "p99_ms", "max_ms")}
                for via in ("service", "topic")
            }
            s = out[name]["service"]
            print(
                f"{name:48s} stop via service minus wire: p50 {s['p50_ms']:.2f} ms, "
                f"p99 {s['p99_ms']:.2f} ms, max {s['max_ms']:.2f} ms (n={s['n']})",
                flush=True,
            )
    finally:
        peer.close()
    (HERE / "out").mkdir(exist_ok=True)
    (HERE / "out" / "executors.json").write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
