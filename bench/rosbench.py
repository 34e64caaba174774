"""Figures that need the server in its own process: ROS latency, command to board, stop, reach.

Three processes: the emulated board (`al5d emulator --record -`, so that the
times it stamps are not held up by this process's GIL), `al5d serve --port
LINK`, and this one, the ROS 2 client, which reads the board's record and
replays it in a servo model of its own for the reach times. Every time is
CLOCK_MONOTONIC, which all processes on the machine share.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import os
import random
import re
import signal
import sys
import time
from pathlib import Path
from typing import Any

import yaml
from stats import figure
from std_srvs.srv import Trigger

from al5d.app.reach import TOLERANCE_DEG
from al5d.arm.config import DEFAULT_CONFIG, ArmConfig
from al5d.model.table import path_below
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Record
from al5d_rig.boardproc import BoardProcess
from al5d_rig.proc import Proc
from al5d_rig.rospeer import Peer, wait_future, wait_until

OUT = Path(__file__).resolve().parent / "out"
STOP_LINES = [f"STOP{ch}".encode() for ch in range(6)]
STOP_BYTES = len(p.CANCEL + p.encode_stop(range(6)))


def bench_config(path: Path, queue_capacity: int) -> Path:
    """The shipped configuration with a queue deep enough for the load figures."""
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["server"]["queue_capacity"] = queue_capacity
    path.write_text(yaml.safe_dump(data))
    return path


def proc_stat(pid: int) -> tuple[float, int]:
    """(CPU seconds used, resident kB) of a process, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = int(fields[11]) + int(fields[12])  # utime + stime
    rss = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1])
    return ticks / os.sysconf("SC_CLK_TCK"), rss


class Rig:
    """The board and the server in processes of their own, and this process as the client."""

    def __init__(
        self,
        config: ArmConfig,
        baud: int,
        workdir: Path,
        peer: Peer,
        env: dict[str, str] | None = None,
    ) -> None:
        self.config = config
        self.baud = baud
        self.peer = peer
        self.link = workdir / f"ssc32u-{baud}"
        self.trace = workdir / f"trace-{baud}.txt"
        self.emu = BoardProcess(self.link, baud, config)
        cfg = bench_config(workdir / "bench.yaml", 100_000)
        self.t_spawn = time.monotonic()
        self.proc = Proc(
            "serve",
            "--port",
            str(self.link),
            "--baud",
            str(baud),
            "--config",
            str(cfg),
            "--trace",
            str(self.trace),
            "--log-level",
            "INFO",
            env=env,
        )
        try:
            self.proc.err.wait_for("STATE: ready", 30)
            self.t_ready = time.monotonic()
            self.n = 0
            peer.wait_for_server()
            self.handshake(peer)
        except BaseException:
            self.proc.kill()
            self.emu.close()
            raise

    def ident(self, tag: str) -> str:
        self.n += 1
        return f"{tag}-{self.baud}-{self.n}"

    def record_after(self, t: float, predicate: Any, timeout: float = 10.0) -> Record:
        """The first record after `t` that matches (looking only at the records after `t`)."""

        def find(records: list[Record]) -> Record | None:
            newer = list(itertools.takewhile(lambda r: r.t_effect > t, reversed(records)))
            return next((r for r in reversed(newer) if predicate(r)), None)

        return find(self.emu.wait_for(lambda rs: find(rs) is not None, timeout))  # type: ignore[return-value]

    def move(self, tag: str, time_ms: int = 0, **joints: float) -> tuple[str, float]:
        ident = self.ident(tag)
        t = time.monotonic()
        self.peer.send(ident, "move", time_ms, **joints)
        return ident, t

    def barrier(self, timeout: float = 30.0, peer: Peer | None = None) -> None:
        """Wait until the server's owner has taken in everything sent so far.

        Messages on the topic reach the owner in order, and it judges each move as it takes
        it: a move out of range is refused then, and the server logs the refusal with its
        id. (An unknown word is refused by the ROS node before the owner: it passed the
        moves still on their way to it.) The server logs each reason once a second, the
        repeats counted: each barrier's angle is its own, so that its reason is news.
        """
        ident = self.ident("barrier")
        (peer or self.peer).send(ident, "move", 0, base=1000.0 + self.n)
        self.proc.err.wait_for(f"[{ident}]", timeout)

    def diagnose(self, what: str) -> str:
        """What the server said and what the board saw last, for a figure that went wrong."""
        lines = [x for x in self.proc.err.drain(0.5) if "refused" not in x][-12:]
        records = [
            f"{r.t_effect:.4f} {r.raw[:40]!r} {r.ignored or ''}" for r in self.emu.records[-8:]
        ]
        text = "\n".join([what, "server:", *lines, "board:", *records])
        print(text, file=sys.stderr, flush=True)
        return text

    def handshake(self, peer: Peer, timeout: float = 30.0) -> None:
        """Until this server has heard `peer`: a subscription count can be met by a reader
        of a server that just ended, and messages sent before the match are lost."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.barrier(1.0, peer)
                return
            except AssertionError:
                if time.monotonic() > deadline:
                    raise

    def settle(self) -> None:
        """Wait for the arm to be idle and the results to have come."""
        ident, _ = self.move("settle", base=0)
        self.peer.result(ident, 60)

    def close(self) -> dict[str, dict[str, int]]:
        """Shut the server down; return its trace: by instruction id, when the message
        reached its callback ("recv") and when the move's bytes were written ("write")."""
        self.proc.popen.send_signal(signal.SIGTERM)
        self.proc.wait(60)
        self.emu.close()
        return read_trace(self.trace)


def read_trace(path: Path) -> dict[str, dict[str, int]]:
    """A trace's lines ([id, what, ns]) by instruction id, then by what."""
    trace: dict[str, dict[str, int]] = {}
    for line in path.read_text().splitlines():
        ident, what, t = json.loads(line)
        trace.setdefault(ident, {})[what] = t
    return trace


def ros_latency(
    rig: Rig, n: int = 2000, warmup: int = 200, word: str = "move"
) -> tuple[list[str], dict[str, float]]:
    """Publish paced moves (queued on the server; for the floor, `word` is one it only
    traces, of the same size); the trace gives each callback's start."""
    sent: dict[str, float] = {}
    ids = []
    for i in range(n + warmup):
        ident = rig.ident("lat")
        t = time.monotonic_ns()
        rig.peer.send(ident, word, 0, base=0.0)
        if i >= warmup:
            sent[ident] = t
            ids.append(ident)
        time.sleep(0.002)
    rig.barrier()
    if word == "move":
        rig.peer.trigger("stop")
        rig.peer.trigger("release")
    return ids, sent


def latency_figure(
    name: str, ids: list[str], sent: dict[str, float], trace: dict[str, dict[str, int]]
) -> dict[str, Any]:
    """Publish to callback start, in ms, of the traced ones of `ids`."""
    return figure(name, [(trace[i]["recv"] - sent[i]) / 1e6 for i in ids if i in trace])


def command_to_board(rig: Rig, n: int = 300) -> dict[str, Any]:
    """Publish one small move at a time, the next when the last has its outcome; until its CR
    is in effect on the emulated board."""
    total, software = [], []
    times: dict[str, tuple[float, float, float]] = {}  # id -> (published, in effect, wire), s
    for i in range(n + 20):
        deg = 1.0 if i % 2 else -1.0
        ident, t_pub = rig.move("c2b", base=deg)
        rec = rig.record_after(t_pub, lambda r: r.raw.startswith(b"#0P"))
        wire = p.wire_time_s(len(rec.raw) + 1, rig.baud)
        rig.peer.result(ident)
        if i >= 20:
            total.append((rec.t_effect - t_pub) * 1000)
            software.append((rec.t_effect - t_pub - wire) * 1000)
            times[ident] = (t_pub, rec.t_effect, wire)
    wire_ms = p.wire_time_s(len(b"#0P1510T3\r"), rig.baud) * 1000
    return {
        "total": figure(f"command to board {rig.baud}", total, wire_ms=wire_ms),
        "software": figure(f"command to board {rig.baud} minus wire", software),
        "times": times,
    }


def breakdown(c2b: dict[str, Any], trace: dict[str, dict[str, int]]) -> dict[str, Any]:
    """Command to board in three parts, from the server's trace: ROS, server, board side."""
    ros, server, board = [], [], []
    for ident, (t_pub, t_effect, wire) in c2b.pop("times").items():
        t = trace.get(ident, {})
        if "recv" in t and "write" in t:
            recv, write = t["recv"] / 1e9, t["write"] / 1e9
            ros.append((recv - t_pub) * 1000)
            server.append((write - recv) * 1000)
            board.append((t_effect - write - wire) * 1000)
    return {
        "ros": figure("publish -> callback", ros),
        "server": figure("callback -> bytes written", server),
        "board": figure("written -> CR in effect, minus wire", board),
    }


def emergency_stop(rig: Rig, trials: int = 200, queued: int = 1000) -> dict[str, Any]:
    """Stop by service and by topic while a move runs and `queued` moves wait; until STOP5 acts.

    A peer of its own that does not take the results: each stop cancels a thousand
    moves, and their results would load this process, whose emulator must answer
    the driver's read-back within its deadline.
    """
    wire = p.wire_time_s(STOP_BYTES, rig.baud) * 1000
    by: dict[str, list[float]] = {"service": [], "topic": []}
    answered: list[float] = []
    missed: list[str] = []
    quiet = Peer(results=False, name="al5d_bench_stopper")
    for client in quiet.services.values():
        assert client.wait_for_service(timeout_sec=10)
    rig.handshake(quiet)
    for trial in range(trials):
        via = "service" if trial % 2 == 0 else "topic"
        t_long = time.monotonic()
        # The base alone: with the shoulder at 40 degrees as well, the fingers would go
        # under the table, and the server refuses such a move whole.
        quiet.send(rig.ident("long"), "move", 5000, base=80 if trial % 4 < 2 else -80)
        for k in range(queued):
            quiet.send(rig.ident("q"), "move", 0, base=(k % 60) - 30)
        try:
            rig.record_after(t_long, lambda r: b"T5000" in r.raw)
        except TimeoutError:
            rig.diagnose(f"trial {trial}: the long move never reached the board in 10 s")
            raise
        rig.barrier(peer=quiet)  # the queued moves are all in the server's queue
        t0 = time.monotonic()
        if via == "service":
            future = quiet.services["stop"].call_async(Trigger.Request())
            # When the answer came, not when we looked (after the STOP bytes on the board).
            future.add_done_callback(
                lambda f, t0=t0: answered.append((time.monotonic() - t0) * 1000)
            )
        else:
            quiet.send(rig.ident("stop"), "stop")
        try:
            rec = rig.record_after(t0, lambda r: r.raw == STOP_LINES[-1])
        except TimeoutError:
            missed.append(rig.diagnose(f"trial {trial} via {via}: no STOP on the board in 10 s"))
            quiet.trigger("release")
            rig.settle()
            continue
        if via == "service":
            wait_future(future)
        by[via].append((rec.t_effect - t0) * 1000)
        assert quiet.trigger("release").success
    quiet.close()
    counts = [
        int(m.group(1))
        for line in rig.proc.err.drain(1)
        if (m := re.search(r"stop: (\d+) move", line))
    ]
    out = {}
    for via, samples in by.items():
        out[via] = figure(f"stop via {via}", samples, wire_ms=wire)
        out[f"{via} software"] = figure(f"stop via {via} minus wire", [s - wire for s in samples])
    out["service answered"] = figure("stop service answered", answered)
    out["queued at stop"] = {"min": min(counts) if counts else 0, "trials": len(counts)}
    out["missed"] = missed
    return out


def _stops(channels: list[int], t0: float, records: list[Record]) -> list[Record]:
    wanted = {f"STOP{ch}".encode() for ch in channels}
    return [r for r in records if r.t_effect > t0 and r.raw in wanted]


def _halted(channels: list[int], t0: float, records: list[Record]) -> bool:
    return len(_stops(channels, t0, records)) >= len(channels)


def _order_move(rig: Rig, moving: list[str], end: int) -> str:
    """A 3 s move of the `moving` joints towards one end of their ranges, on the board: 80 %
    of the way there, or less where the server refuses it whole (the fingers would go
    under the table)."""
    cfg = rig.config
    for frac in (0.8, 0.65, 0.5, 0.35):
        target = {
            j: cfg.joints[j].range_deg[end] * frac + cfg.joints[j].range_deg[1 - end] * (1 - frac)
            for j in moving
        }
        ident, t_pub = rig.move("order", 3000, **target)

        def written(records: list[Record], ident: str = ident, t_pub: float = t_pub) -> bool:
            return ident in rig.peer.results or any(
                r.t_effect > t_pub and b"T3000" in r.raw for r in records
            )

        rig.emu.wait_for(written, 10)
        result = rig.peer.results.get(ident)
        if result is None or result.outcome != "refused":
            return ident
    raise AssertionError(f"every move of {moving} towards end {end} was refused")


def stop_order(rig: Rig, trials: int = 10) -> dict[str, Any]:
    """By number of moving joints: stop request (service) until the last MOVING servo's STOP
    is in effect. The moving joints' STOPs go first, the fastest first; in channel order
    (before issue 9) the last moving one could wait behind every STOP before its channel."""
    cfg = rig.config
    names = list(cfg.joints)
    out: dict[str, Any] = {}
    for k in range(1, len(names) + 1):
        moving = names[-k:]  # the last channels: the worst case for channel order
        channels = [cfg.joints[j].channel for j in moving]
        samples = []
        for trial in range(trials):
            ident = _order_move(rig, moving, trial % 2)
            time.sleep(0.3)
            t0 = time.monotonic()
            wait_future(rig.peer.services["stop"].call_async(Trigger.Request()))
            stops = rig.emu.wait_for(functools.partial(_halted, channels, t0), 10)
            samples.append((max(r.t_effect for r in _stops(channels, t0, stops)) - t0) * 1000)
            rig.peer.trigger("release")
            rig.peer.result(ident)
        ours = len(p.CANCEL) + sum(len(f"STOP{ch}\r") for ch in channels)
        in_channel_order = len(p.CANCEL) + sum(
            len(f"STOP{ch}\r") for ch in sorted(cfg.channels) if ch <= max(channels)
        )
        out[str(k)] = figure(
            f"stop: last of {k} moving servos halted",
            samples,
            wire_ms=p.wire_time_s(ours, rig.baud) * 1000,
            channel_order_wire_ms=p.wire_time_s(in_channel_order, rig.baud) * 1000,
        )
    return out


def goal_cost(rig: Rig, before: int = 3000, n: int = 100) -> dict[str, Any]:
    """Round trip of a Move goal (send -> accepted -> result), and the server's CPU per goal,
    with no goal before and after `before` finished goals (rclpy used to keep them all)."""
    from al5d_interfaces.action import Move

    def rounds(count: int) -> tuple[list[float], float]:
        cpu0, _ = proc_stat(rig.proc.popen.pid)
        samples = []
        for i in range(count):
            t0 = time.monotonic()
            handle = wait_future(
                rig.peer.move.send_goal_async(Move.Goal(joints=["base"], degrees=[float(i % 2)]))
            )
            wait_future(handle.get_result_async())
            samples.append((time.monotonic() - t0) * 1000)
        cpu1, _ = proc_stat(rig.proc.popen.pid)
        return samples, (cpu1 - cpu0) / count * 1000

    first, cpu_first = rounds(n)
    _, rss0 = proc_stat(rig.proc.popen.pid)
    rounds(before)
    last, cpu_last = rounds(n)
    _, rss1 = proc_stat(rig.proc.popen.pid)
    return {
        "first": figure("goal round trip, the first goals", first, cpu_ms=cpu_first),
        "after": figure(
            f"goal round trip after {before} goals", last, cpu_ms=cpu_last, before=before
        ),
        "memory_per_goal_kb": (rss1 - rss0) / (before + n),
    }


def _fjt_client(rig: Rig) -> Any:
    from control_msgs.action import FollowJointTrajectory

    from al5d_rig.rospeer import LockedActionClient

    client = LockedActionClient(
        rig.peer.node, FollowJointTrajectory, rig.peer.names.follow_joint_trajectory
    )
    assert client.wait_for_server(timeout_sec=10)
    return client


def _fjt_goal(rig: Rig, points: list[tuple[float, dict[str, float]]]) -> Any:
    from builtin_interfaces.msg import Duration
    from control_msgs.action import FollowJointTrajectory
    from trajectory_msgs.msg import JointTrajectoryPoint

    goal = FollowJointTrajectory.Goal()
    names = list(points[0][1])
    goal.trajectory.joint_names = names
    for t, degrees in points:
        values = rig.config.model.to_urdf(degrees)
        ns = round(t * 1e9)
        goal.trajectory.points.append(
            JointTrajectoryPoint(
                positions=[values[j] for j in names],
                time_from_start=Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
            )
        )
    return goal


def trajectory_timing(rig: Rig, runs: int = 5, points: int = 10, seed: int = 3) -> dict[str, Any]:
    """FollowJointTrajectory: when the emulated servos reached each point, against its
    time_from_start counted from the first group move's effect (execution start)."""
    from action_msgs.msg import GoalStatus

    cfg, rng = rig.config, random.Random(seed)
    client = _fjt_client(rig)
    arm = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]
    late_ms: list[float] = []
    wire_ms = error = 0.0
    try:
        for _ in range(runs):
            rig.settle()
            pose: dict[str, float] | None = None  # where the last run left it: unknown here
            plan: list[tuple[float, dict[str, float]]] = []
            t = 0.0
            for _ in range(points):
                target = {j: rng.uniform(*cfg.joints[j].range_deg) * 0.3 for j in arm}
                target["elbow"] = rng.uniform(30, 90)
                # Feasible with 30 % to spare: the figure is our timing, not the servos'.
                need = (
                    1.0
                    if pose is None
                    else max(abs(target[j] - pose[j]) / cfg.joints[j].speed_deg_s for j in arm)
                )
                t += max(0.08, need * 1.3)
                plan.append((round(t, 3), target))
                pose = target
            t_send = time.monotonic()
            handle = wait_future(client.send_goal_async(_fjt_goal(rig, plan)))
            assert handle.accepted
            answer = wait_future(handle.get_result_async(), 60)
            assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
            records = [
                r
                for r in rig.emu.wait_for(lambda rs: True, 1)
                if r.t_effect > t_send and r.raw.startswith(b"#")
            ][-points:]
            assert len(records) == points, f"{len(records)} group moves for {points} points"
            model = rig.emu.model()
            start = records[0].t_effect
            wire_ms = p.wire_time_s(len(records[0].raw) + 1, rig.baud) * 1000
            for (at, target), rec in zip(plan, records, strict=True):
                # The board's pulses reach the point when its group move's time has run;
                # the servos follow within the tolerance (the plan is within their speed).
                (cmd,) = rec.commands
                assert isinstance(cmd, p.GroupMove) and cmd.time_ms is not None
                t_point = rec.t_effect + cmd.time_ms / 1000
                late_ms.append(abs(t_point - start - at) * 1000)
                # The servo as this move left it (servo_degrees(t) is the latest move's).
                there = model.trajectory(rec.t_effect, [t_point], target)
                error = max(error, max(abs(there[j][1][0] - d) for j, d in target.items()))
    finally:
        client.destroy()
    return figure(
        "|trajectory point reached - its time_from_start|",
        late_ms,
        wire_ms=wire_ms,
        servo_error_deg=error,
    )


def trajectory_goal_latency(rig: Rig, rounds: int = 20) -> dict[str, Any]:
    """Send -> goal response for a 100-point trajectory: accepted (then cancelled at once),
    and with its last point out of range (rejected)."""
    client = _fjt_client(rig)
    plan = [(0.2 * (i + 1), {"base": 20.0 * ((i % 2) * 2 - 1)}) for i in range(100)]
    good = _fjt_goal(rig, plan)
    bad = _fjt_goal(rig, [*plan[:-1], (plan[-1][0], {"base": 500.0})])
    accept, reject = [], []
    try:
        for _ in range(rounds):
            rig.settle()
            t0 = time.monotonic()
            handle = wait_future(client.send_goal_async(good))
            accept.append((time.monotonic() - t0) * 1000)
            assert handle.accepted
            wait_future(handle.cancel_goal_async())
            wait_future(handle.get_result_async(), 10)
            t0 = time.monotonic()
            handle = wait_future(client.send_goal_async(bad))
            reject.append((time.monotonic() - t0) * 1000)
            assert not handle.accepted
    finally:
        client.destroy()
    return {
        "accepted": figure("100-point trajectory goal accepted", accept),
        "rejected": figure("100-point trajectory goal rejected", reject),
    }


#: `move_to path=line` figures: (start: None for `ready`, else a point at pitch -30), target
#: (metres), pitch and roll (degrees). The first two went 1.08 and 0.99 mm off the line when
#: the plan was judged on unrounded angles.
LINES: list[tuple[tuple[float, float, float] | None, tuple[float, float, float], float, float]] = [
    (None, (0.10, 0.25, 0.05), -30.0, 0.0),
    (None, (0.15, -0.20, 0.15), -30.0, 45.0),
    ((0.25, -0.12, 0.06), (0.25, 0.12, 0.14), -30.0, 0.0),
    (None, (0.30, 0.00, 0.20), 0.0, 0.0),
    (None, (0.15, 0.00, 0.02), -90.0, 0.0),
]


def line_path(rig: Rig) -> dict[str, Any]:
    """`move_to path=line` from the record of the board, over several lines: each one's
    largest distance of the tool from the straight line (the emulated servos every 0.5 ms),
    its group moves and its time; `line` is the worst of them, `joint` the same worst line
    as one joint-space move."""
    from al5d_interfaces.msg import ArmInstruction

    from al5d.model import distance_to_segment, forward

    geometry = rig.config.model.geometry

    def send(instruction: str, **fields: float) -> tuple[list[Record], float]:
        ident = rig.ident(instruction)
        t0 = time.monotonic()
        rig.peer.pub.publish(
            ArmInstruction(
                instruction=instruction,
                joints=list(fields),
                degrees=list(fields.values()),
                id=ident,
            )
        )
        result = rig.peer.result(ident, 30)
        assert result.outcome == "done", result.reason
        moves = [
            r
            for r in rig.emu.wait_for(lambda rs: True, 1)
            if r.t_effect > t0 and r.raw.startswith(b"#")
        ]
        return moves, result.elapsed_ms

    def run(
        start: tuple[float, float, float] | None,
        end: tuple[float, float, float],
        pitch: float,
        roll: float,
        line: bool,
    ) -> dict[str, Any]:
        if start is None:
            send("ready")
        else:
            send("move_to", x=start[0], y=start[1], z=start[2], pitch=math.radians(-30.0))
        model = rig.emu.model()
        time.sleep(max(0.0, model.settle_time(0.01) - time.monotonic()) + 0.05)
        p0 = forward(geometry, rig.emu.model().servo_degrees()).position
        fields = {"x": end[0], "y": end[1], "z": end[2], "pitch": math.radians(pitch)}
        fields["roll"] = math.radians(roll)
        moves, _ = send("move_to", **fields, **({"path": 1.0} if line else {}))
        model = rig.emu.model()
        t_first = moves[0].t_effect
        t_end = model.settle_time(0.05)
        worst = 0.0
        for pose in executed(model, moves, t_end, 0.0005):
            worst = max(worst, distance_to_segment(p0, end, forward(geometry, pose).position))
        return {
            "target_mm": [round(c * 1000) for c in end],
            "segments": len(moves),
            "max_deviation_mm": worst * 1000,
            "time_ms": (t_end - t_first) * 1000,
        }

    lines = [run(*spec, line=True) for spec in LINES]
    k = max(range(len(lines)), key=lambda i: lines[i]["max_deviation_mm"])
    return {"line": lines[k], "joint": run(*LINES[k], line=False), "lines": lines}


def executed(model: Any, moves: list[Record], t_end: float, dt: float = 0.001) -> list[Any]:
    """The servos' angles every `dt` from the first move's effect to `t_end`, each move's
    span from its own snapshot (`servo_degrees(t)` tells the latest move's only)."""
    last = model.servo_degrees()  # the joints no move here touches stay where they are
    poses = []
    for i, rec in enumerate(moves):
        t1 = moves[i + 1].t_effect if i + 1 < len(moves) else t_end
        times = [rec.t_effect + k * dt for k in range(max(1, int((t1 - rec.t_effect) / dt)))]
        span = model.trajectory(rec.t_effect, times)
        for k in range(len(times)):
            last = {**last, **{j: servo[k] for j, (_, servo) in span.items()}}
            poses.append(last)
    return poses


def physical_minimum_s(
    config: ArmConfig, start: dict[str, float], target: dict[str, float]
) -> float:
    return max(abs(target[j] - start[j]) / config.joints[j].speed_deg_s for j in target)


def reach(rig: Rig, n: int = 200, seed: int = 1) -> dict[str, Any]:
    """SA03: request -> every emulated servo within 1 degree, against physics + wire time.

    Random targets that keep the arm above the table (the server refuses the others whole,
    about a third of uniform ones), and the worst case: every joint across its range, the
    shoulder and the elbow as far as the table allows (the wrist's 180 degrees take the
    longest either way)."""
    cfg = rig.config
    rng = random.Random(seed)
    ident, _ = rig.move("start", **cfg.presets["park"])
    rig.peer.result(ident, 30)
    pose = dict(cfg.presets["park"])
    reach_ms, margin_ms, rows = [], [], []

    def above(target: dict[str, float]) -> bool:
        return path_below(cfg.model, [pose, target]) is None

    def one(target: dict[str, float], tag: str) -> tuple[float, float, Record] | None:
        nonlocal pose
        ident, t_pub = rig.move(tag, **target)
        result = rig.peer.result(ident, 30)
        if result.outcome == "refused":  # a pulse's rounding our check here does not make
            return None
        assert result.outcome == "done", result.reason
        rec = rig.record_after(t_pub, lambda r: r.raw.startswith(b"#"))
        t_reach = rig.emu.model().reach_time(rec.t_effect, TOLERANCE_DEG, target)
        assert t_reach is not None
        bound = physical_minimum_s(cfg, pose, target) + p.wire_time_s(len(rec.raw) + 1, rig.baud)
        pose = dict(target)
        return (t_reach - t_pub) * 1000, bound * 1000, rec

    while len(reach_ms) < n:
        target = {j: rng.uniform(*cfg.joints[j].range_deg) for j in cfg.joints}
        got = one(target, "reach") if above(target) else None
        if got is not None:
            reach_ms.append(got[0])
            margin_ms.append(got[0] - got[1])
            rows.append({"reach_ms": got[0], "bound_ms": got[1]})
    low = {j: cfg.joints[j].range_deg[0] for j in cfg.joints}
    high = {j: cfg.joints[j].range_deg[1] for j in cfg.joints}
    assert one(dict(cfg.presets["park"]), "worst-park") is not None  # from there, low is above
    assert one(low, "worst-from") is not None
    for k in range(21):
        frac = 1 - k * 0.05
        folded = {j: low[j] + (high[j] - low[j]) * frac for j in ("shoulder", "elbow")}
        if above({**high, **folded}):
            break
    worst_one = one({**high, **folded}, "worst")
    assert worst_one is not None
    worst, worst_bound, worst_rec = worst_one
    span = worst_bound / 1000 + 0.15
    times = [worst_rec.t_effect - 0.05 + k * span / 400 for k in range(400)]
    return {
        "random": figure("reach time", reach_ms),
        "margin": figure("reach time minus (physical minimum + wire)", margin_ms),
        "worst_ms": worst,
        "worst_bound_ms": worst_bound,
        "worst_trajectory": {
            "t_ms": [(t - worst_rec.t_effect) * 1000 for t in times],
            "joints": rig.emu.model().trajectory(worst_rec.t_effect, times),
        },
        "within_2300": sum(r <= 2300 for r in reach_ms) / len(reach_ms),
    }


def throughput(rig: Rig, n: int = 10000) -> dict[str, Any]:
    """A burst of `n` moves over ROS: the rate the server takes them in, and none lost."""
    ids = []
    t0 = time.monotonic_ns()
    for k in range(n):
        ident = rig.ident("burst")
        ids.append(ident)
        rig.peer.send(ident, "move", 0, base=(k % 60) - 30)
    t_sent = time.monotonic_ns()
    rig.barrier(60)  # the whole burst is in; the trace says when each message arrived
    # Stop cancels what waits: every instruction then has its outcome.
    rig.peer.trigger("stop")
    wait_until(lambda: all(i in rig.peer.results for i in ids), 60, "every outcome")
    rig.peer.trigger("release")
    return {
        "ids": ids,
        "t0_ns": t0,
        "t_sent_ns": t_sent,
        "received": sum(i in rig.peer.results for i in ids),
    }


def footprint(rig: Rig, idle_s: float = 20.0) -> dict[str, Any]:
    """Resident memory, and CPU over `idle_s` of idling (the kernel counts CPU time in 10 ms
    ticks: over 5 s a tick is 0.2 % of the figure, over 20 s 0.05 %)."""
    cpu0, rss = proc_stat(rig.proc.popen.pid)
    time.sleep(idle_s)
    cpu1, _ = proc_stat(rig.proc.popen.pid)
    return {"rss_mb": rss / 1024, "idle_cpu_percent": (cpu1 - cpu0) / idle_s * 100}


def cold_start(runs: int = 3) -> dict[str, Any]:
    """`al5d serve` (embedded emulator) from spawn to STATE: ready."""
    times = []
    for _ in range(runs):
        t0 = time.monotonic()
        proc = Proc("serve", "--log-level", "INFO")
        proc.err.wait_for("STATE: ready", 30)
        times.append((time.monotonic() - t0) * 1000)
        proc.popen.send_signal(signal.SIGINT)
        proc.wait(30)
    return figure("cold start to ready", times)
