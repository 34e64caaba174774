"""The link cut mid-move, 20 times (`make soak`): how long after each cut the server halts
what the lost client commanded, against `server.client_lease_s` + 0.5 s.

Two hosts (`al5d_rig.netrig`: network namespaces joined by a veth pair), the server on
one, a Python client on the other sending 6 s moves; 1.5 s into each the link is cut.
The halt's time is that of the server's log line `...: halted`, which the owner says in
the step that writes the halt to the board. Needs root (CI runs as root).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from datetime import datetime

from al5d_rig import domains, netrig
from al5d_rig.proc import AL5D, Lines, patient_config

if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())

CUTS = int(os.environ.get("AL5D_CUTS", "20"))
LEASE_S = 1.0
CMD_S = 60.0

LAPTOP = """
import sys, time
from al5d.ros.client import Client, LostContact
c = Client(wait_s=60)
c.wait_for_server(60)
print("ready", flush=True)
for k, line in enumerate(sys.stdin):
    while c.lost_contact() is not None:
        time.sleep(0.05)
    try:
        print("outcome", c.execute(f"move base={-60 if k % 2 else 60} time=6000", 60), flush=True)
    except LostContact:
        print("lost", flush=True)
"""


def main() -> int:
    why = netrig.unavailable()
    if why is not None:
        print(f"network_cut: cannot run here: {why}", file=sys.stderr)
        return 1
    halts: list[float] = []
    told: list[float] = []
    with netrig.Hosts() as hosts:
        server = hosts.popen(hosts.arm, [AL5D, "serve", "--config", patient_config()])
        laptop = hosts.popen(hosts.laptop, [sys.executable, "-c", LAPTOP])
        assert server.stderr is not None and laptop.stdout is not None
        assert laptop.stdin is not None
        log, out = Lines(server.stderr), Lines(laptop.stdout)
        try:
            log.wait_for("STATE: ready", CMD_S)
            out.wait_for("ready", CMD_S)
            for k in range(CUTS):
                laptop.stdin.write("go\n")
                laptop.stdin.flush()
                log.wait_for("STATE: moving", CMD_S)
                time.sleep(1.5)
                cut = time.time()
                hosts.cut()
                halted = log.wait_for(": halted", CMD_S)
                out.wait_for("lost", CMD_S)
                told.append(time.time() - cut)
                halts.append(_clock(halted, cut) - cut)
                hosts.mend()
                print(f"cut {k + 1}: halt {halts[-1]:.3f} s, client told {told[-1]:.2f} s")
        finally:
            laptop.kill()
            server.kill()
    limit = LEASE_S + 0.5
    held = max(halts) <= limit
    print(
        f"{CUTS} cuts mid-move: halt after the cut p50 {statistics.median(halts):.3f} s, "
        f"max {max(halts):.3f} s (target: every one within lease {LEASE_S:g} s + 0.5 s = "
        f"{limit:g} s: {'held' if held else 'NOT held'}); the client said it lost contact "
        f"within {max(told):.2f} s of each cut"
    )
    return 0 if held else 1


def _clock(line: str, near: float) -> float:
    at = datetime.strptime(line.split()[0], "%H:%M:%S.%f").time()
    return datetime.combine(datetime.fromtimestamp(near).date(), at).timestamp()


if __name__ == "__main__":
    sys.exit(main())
