"""The suite of figures that need the server in its own process (`rosbench.py`), each latency
with its floor measured after it in the same run (`floors.py`, which builds on the
suite's rig)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import floors
from rosbench import (
    OUT,
    Rig,
    breakdown,
    cold_start,
    command_to_board,
    emergency_stop,
    footprint,
    goal_cost,
    latency_figure,
    line_path,
    reach,
    ros_latency,
    stop_order,
    throughput,
    trajectory_goal_latency,
    trajectory_timing,
)
from spy import profiled, top_frames

from al5d.arm.config import ArmConfig
from al5d_rig.rospeer import Peer


def run(config: ArmConfig, log: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    workdir = Path(tempfile.mkdtemp(prefix="al5d-bench-"))
    OUT.mkdir(exist_ok=True)
    log("cold start (3 runs of al5d serve)")
    out["cold_start"] = cold_start()
    peer = Peer()
    rigs: list[Rig] = []
    try:
        rig = Rig(config, 9600, workdir, peer)
        rigs.append(rig)
        out["cold_start_port_ms"] = (rig.t_ready - rig.t_spawn) * 1000
        log("footprint: resident memory and idle CPU (20 s)")
        out["footprint"] = footprint(rig)
        log("ROS client -> server latency (2000 paced messages)")
        ids, sent = ros_latency(rig)
        log("command to board at 9600 baud (300 moves)")
        out["c2b_9600"] = command_to_board(rig)
        # The profile has a run of its own: py-spy reads the server 500 times a second, a
        # load that must not be inside the figures above (2 cores: it takes the board's).
        log("the same, 2 x 200 moves more, py-spy on the server (not in the figures)")
        raw = OUT / "command-path-9600.txt"
        with profiled(rig.proc.popen.pid, raw):
            command_to_board(rig, 200)
        with profiled(rig.proc.popen.pid, OUT / "command-path-9600.svg", "flamegraph"):
            command_to_board(rig, 200)
        out["profile_9600"] = {
            "file": str(raw),
            "top": top_frames(raw, "ArmNode._on_instruction") if raw.exists() else [],
        }
        log("emergency stop (200 trials, 1000 moves queued each)")
        peer.listen_results(False)  # 200,000 cancelled results would load this process
        out["stop"] = emergency_stop(rig)
        peer.listen_results(True)
        rig.handshake(peer)
        log("stop order: the last moving servo halted, by number of moving joints")
        out["stop_order"] = stop_order(rig)
        log("reach time, SA03 (200 random targets + the worst case)")
        out["reach"] = reach(rig)
        log("FollowJointTrajectory: 10-point timing (5 runs), 100-point goal latency")
        out["trajectory_timing"] = trajectory_timing(rig)
        out["trajectory_goals"] = trajectory_goal_latency(rig)
        log("move_to path=line against path=joint, from the board's record")
        out["line_path"] = line_path(rig)
        log("Move goals: round trip with none and with 3000 goals before")
        out["goals"] = goal_cost(rig)
        rig.settle()
        trace = rig.close()
        out["ros_latency"] = latency_figure("ROS client -> server", ids, sent, trace)
        out["c2b_9600"]["parts"] = breakdown(out["c2b_9600"], trace)
        out["floor_9600"] = floors.measure(config, 9600, workdir, peer, log)
        rig = Rig(config, 115200, workdir, peer)
        rigs.append(rig)
        log("command to board at 115200 baud (300 moves)")
        out["c2b_115200"] = command_to_board(rig)
        log("throughput over ROS (a burst of 10000 moves)")
        burst = throughput(rig)
        rig.settle()
        trace = rig.close()
        out["c2b_115200"]["parts"] = breakdown(out["c2b_115200"], trace)
        out["floor_115200"] = floors.measure(config, 115200, workdir, peer, log)
        got = [trace[i]["recv"] for i in burst["ids"] if i in trace]
        elapsed = (max(got) - burst["t0_ns"]) / 1e9
        out["throughput_ros"] = {
            "n": len(burst["ids"]),
            "rate_per_s": len(got) / elapsed,
            "lost": len(burst["ids"]) - burst["received"],
            "reached_server": len(got),
            "publish_rate_per_s": len(burst["ids"]) / ((burst["t_sent_ns"] - burst["t0_ns"]) / 1e9),
        }
    finally:
        # A server whose board is gone keeps reconnecting, as it should: a failed run
        # must not leave it behind to load the next one.
        for r in rigs:
            r.proc.kill()
            r.emu.close()
        peer.close()
    return out
