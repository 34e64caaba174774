"""The server restarted 10 times while a client on the laptop, made before the first
restart, sends moves (`make soak`): a stop asked of each new server in its first second is
obeyed within 1 s, or the client says within its timeout that it had no answer
(`al5d_rig.netfaults.restarts`). Needs root (CI runs as root).
"""

from __future__ import annotations

import os
import statistics
import sys

from al5d_rig import domains, netfaults, netrig

if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())

RESTARTS = int(os.environ.get("AL5D_RESTARTS", "10"))


def main() -> int:
    why = netrig.unavailable()
    if why is not None:
        print(f"network_restart: cannot run here: {why}", file=sys.stderr)
        return 1
    with netrig.Hosts() as hosts:
        done = netfaults.restarts(hosts, RESTARTS, seed=10)
    problems = netfaults.restart_problems(done)
    obeyed = [r.obeyed_s for r in done if r.obeyed_s is not None]
    said = sum(1 for r in done if r.said.startswith("raised"))
    unanswered = sorted(r.unanswered_s for r in done if r.unanswered_s is not None)
    for problem in problems:
        print(f"BROKEN: {problem}")
    print(
        f"{RESTARTS} restarts: {len(obeyed)} stops obeyed, after p50 "
        f"{statistics.median(obeyed) if obeyed else float('nan'):.3f} s, max "
        f"{max(obeyed, default=float('nan')):.3f} s; {said} raised unanswered by the client, "
        f"{len(unanswered)} said unanswered at once "
        f"({', '.join(f'{u:.2f}' for u in unanswered)} s after asked) "
        f"(target: each obeyed within {netfaults.RESTART_STOP_S:g} s or said unanswered: "
        f"{'held' if not problems else 'NOT held'})"
    )
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
