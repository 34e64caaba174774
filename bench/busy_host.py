"""`make soak`'s contention suite (issue 23): the stop and the link on a busy machine, with
their figures against the targets.

Three servers, each flooded at full speed (5,000 moves a second offered) in its own
ROS domain, two busy loops beside them, stops by service and by topic from a
process that does not flood; a FollowJointTrajectory flood of 100 preempting goals
a second at 9600 baud; a board in its own process on a host at load 6 or more,
counting false link faults. Prints one table; writes bench/out/contention.json.
Durations: CONTENTION_SECONDS (40), GOALS_SECONDS (30), FALSE_FAULT_SECONDS (600).
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from soak import log, p99, render  # noqa: E402

from al5d_rig.contention import SLOW_MS, goals, run  # noqa: E402
from al5d_rig.falsefaults import run as false_faults  # noqa: E402

OUT = HERE / "out"
SECONDS = float(os.environ.get("CONTENTION_SECONDS", "40"))
GOALS_SECONDS = float(os.environ.get("GOALS_SECONDS", "30"))
FALSE_FAULT_SECONDS = float(os.environ.get("FALSE_FAULT_SECONDS", "600"))
#: The targets of issue 23: the stop request to its first STOP in effect, minus wire.
STOP_P99_MS = 50.0


def stops_row(name: str, xs: list[float], missed: int) -> tuple[str, str, str, str]:
    ours = f"{statistics.median(xs):.1f} / {p99(xs):.1f} ms (n={len(xs)}), missed {missed}"
    ok = bool(xs) and p99(xs) <= STOP_P99_MS and missed == 0
    return (
        name,
        ours if xs else f"none, missed {missed}",
        f"p99 <= {STOP_P99_MS:.0f} ms, 0 missed",
        "yes" if ok else "NO",
    )


def table(servers: dict[str, Any], flood: dict[str, Any], faults: dict[str, Any]) -> str:
    rows = [("figure", "ours", "target", "held")]
    for i, s in enumerate(servers["servers"]):
        missed = s["stops_missed"]
        rows.append(
            (
                f"server {i + 1} of 3: instructions answered",
                f"{s['outcomes']} of {s['sent']} (never reached it: {s['lost']}; of those "
                f"received, unanswered {s.get('missing_received', 0)}; twice {s['duplicates']})",
                "all it received, once",
                "yes" if s.get("missing_received", 0) == 0 and s["duplicates"] == 0 else "NO",
            )
        )
        rows.append(stops_row("  ... stop by service p50 / p99", s["stop_service_ms"], missed))
        rows.append(stops_row("  ... stop by topic p50 / p99", s["stop_topic_ms"], 0))
    # What no priority of ours gets past (the hypervisor, the kernel): the slow stops it
    # explains are the host's, not the driver's.
    host = servers["host"]
    during = sum(s["host_stall_ms"] > 0 for s in host["slow_stops"])
    longest = max(host["longest_stalls_ms"], default=0.0)
    rows.append(
        (
            "  the host's stalls (a real-time probe): longest; steal; stops over "
            f"{SLOW_MS:.0f} ms during one",
            f"{longest:.1f} ms; {host['steal_s']:.2f} s; {during} of {len(host['slow_stops'])}",
            "(said, not a target)",
            "-",
        )
    )
    # The flood is only what it says if the client kept up with its rate (it once reached
    # about 20 goals a second of the 100 it was asked for).
    reached = flood["sent"] / flood["send_s"]
    rows.append(
        (
            "goal flood at 9600 baud: goals sent per second",
            f"{reached:.1f}",
            f">= {0.95 * flood['rate']:.0f} (95 % of {flood['rate']:.0f} offered)",
            "yes" if reached >= 0.95 * flood["rate"] else "NO",
        )
    )
    rows.append(
        stops_row(
            "  ... stop by service",
            flood["stop_service_ms"],
            len(flood["stops_missed"]),
        )
    )
    rows.append(stops_row("  ... stop by topic", flood["stop_topic_ms"], 0))
    rows.append(
        (
            "  ... goals answered; stop writes failed",
            f"{flood['answered']} of {flood['sent']} (results {flood['results']} of "
            f"{flood['accepted']} accepted); {len(flood['stop_write_failures'])}",
            "all; 0",
            "yes"
            if flood["answered"] == flood["sent"]
            and flood["results"] == flood["accepted"]
            and not flood["stop_write_failures"]
            else "NO",
        )
    )
    rows.append(
        (
            f"false link faults, board in its own process, {faults['seconds'] / 60:.0f} min "
            f"at load {faults['load1_median']:.1f}",
            str(faults["false_faults"]),
            "0 at load >= 6",
            "yes" if faults["false_faults"] == 0 and faults["load1_median"] >= 6 else "NO",
        )
    )
    return render(rows)


def main() -> int:
    started = time.monotonic()
    log(f"contention: 3 flooded servers, 2 busy loops, {SECONDS:g} s")
    servers = run(servers=3, seconds=SECONDS, rate=5000, busy=2)
    log(f"contention: trajectory goals at 100/s, 9600 baud, {GOALS_SECONDS:g} s")
    flood = goals(seconds=GOALS_SECONDS, rate=100, busy=2)
    log(f"contention: false link faults at load >= 6, {FALSE_FAULT_SECONDS:g} s")
    faults = false_faults(seconds=FALSE_FAULT_SECONDS, busy=6)
    OUT.mkdir(exist_ok=True)
    raw = {"servers": servers, "goals": flood, "false_faults": faults}
    (OUT / "contention.json").write_text(json.dumps(raw, indent=1))
    print(table(servers, flood, faults))
    print(f"\n{time.monotonic() - started:.0f} s; raw figures in {OUT / 'contention.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
