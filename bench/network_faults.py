"""Fifty random faults on the link between the laptop and the arm's host (`make soak`): cuts
(0.4 to 3 s), delays (50 to 500 ms) and losses (5 to 30 %), alone or together, under a
client sending moves and straight-line moves, with a stop after every third fault while
the link is up (`al5d_rig.netfaults`). It prints what each side saw and exits 1 if a
promise broke: a request with more than one outcome, a request its sender gave up on that
moved the arm, a stop not obeyed. Needs root (CI runs as root).
"""

from __future__ import annotations

import os
import sys

from al5d_rig import domains, netfaults, netrig

if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())

FAULTS = int(os.environ.get("AL5D_FAULTS", "50"))
SEED = int(os.environ.get("AL5D_SEED", "4444"))


def main() -> int:
    why = netrig.unavailable()
    if why is not None:
        print(f"network_faults: cannot run here: {why}", file=sys.stderr)
        return 1
    with netrig.Hosts(cable=True) as hosts:
        report = netfaults.run(hosts, FAULTS, SEED)
    problems = netfaults.check(report)
    print(netfaults.figures(report))
    for problem in problems:
        print(f"BROKEN: {problem}")
    print(f"{FAULTS} faults (seed {SEED}): {'every promise held' if not problems else 'NOT held'}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
