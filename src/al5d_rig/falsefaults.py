"""False link faults on a busy host (issue 23's rig): the board and the server apart, loaded.

    python -m al5d_rig.falsefaults [--seconds 60] [--busy 6]

`al5d emulator` and `al5d serve --port` run as separate processes at the
default priority with the default configuration, `busy` busy loops beside them,
and this process moves the arm now and then (so that both the idle and the
moving link checks run). Every "serial fault" the server logs is a false one:
the board never failed. Prints one line of JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from al5d_rig.contention import busy_loops, ended
from al5d_rig.proc import AL5D, Proc, dies_with_parent
from al5d_rig.rospeer import Peer

#: What the server logs when it takes the board for lost.
FAULT = "serial fault"


def run(seconds: float, busy: int) -> dict[str, Any]:
    link = Path(tempfile.mkdtemp(prefix="al5d-falsefaults-")) / "ssc32u"
    emulator = subprocess.Popen(
        [AL5D, "emulator", "--link", str(link)],
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=dies_with_parent,
    )
    assert emulator.stdout is not None
    emulator.stdout.readline()  # the device path: the board is up
    server = Proc("serve", "--port", str(link), "--log-level", "INFO")
    peer = Peer(results=True, name="al5d_falsefaults_peer")
    loops: list[subprocess.Popen[bytes]] = []
    loads = []
    moves = 0
    try:
        server.err.wait_for("STATE: ready", 60)
        peer.wait_for_server()
        loops = busy_loops(busy)
        rng = random.Random(23)
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            peer.send(
                f"ff-{moves}", "move", time_ms=rng.choice([300, 800]), base=rng.uniform(-40, 40)
            )
            moves += 1
            time.sleep(rng.uniform(0.5, 2.0))
            loads.append(os.getloadavg()[0])
        lines = server.err.drain(1.0)
        faults = [line for line in server.err.all if FAULT in line]
        return {
            "seconds": seconds,
            "busy": busy,
            "moves": moves,
            "false_faults": len(faults),
            "faults": faults[:10],
            "load1_median": sorted(loads)[len(loads) // 2] if loads else None,
            "server_alive": server.popen.poll() is None,
            "tail": lines[-5:],
        }
    finally:
        ended(loops)
        peer.close()
        server.kill()
        emulator.kill()
        emulator.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--busy", type=int, default=6)
    args = parser.parse_args()
    print(json.dumps(run(args.seconds, args.busy)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
