"""Floors measured beside our figures, in the same run: a latency's target is our figure over
its floor, which no driver in Python could beat on this machine at this moment, so that a
busy or a slow machine moves both and the ratio stays.

The floor of command to board, of the stop and of a message's way to its callback is
`floor_node.py`: a bare rclpy node that writes the same bytes to the same kind of board
(`al5d emulator` in its own process, on a pty, at the same baud) as soon as a message or a
request comes. The floor of the serial write is pyserial's own write of the same bytes
(`micro.serial_write`).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from rosbench import (
    STOP_BYTES,
    STOP_LINES,
    Rig,
    command_to_board,
    latency_figure,
    read_trace,
    ros_latency,
)
from stats import figure
from std_srvs.srv import Trigger

from al5d.arm.config import ArmConfig
from al5d.ros.qos import QOS_SERVICES
from al5d.ssc32u import protocol as p
from al5d_rig.boardproc import BoardProcess
from al5d_rig.rospeer import Peer, wait_future

HERE = Path(__file__).resolve().parent
#: Our figure over its floor, at most: the median within 20 %, the tail within 50 %.
P50_RATIO = 1.2
P99_RATIO = 1.5


class FloorRig(Rig):
    """`floor_node.py` on a board of its own, and `peer` as its client: `Rig`'s interface
    (`move`, `record_after`, the result of each move), so that the same measurement runs
    on both."""

    def __init__(self, config: ArmConfig, baud: int, workdir: Path, peer: Peer) -> None:
        self.config = config
        self.baud = baud
        self.peer = peer
        self.n = 0
        self.link = workdir / f"floor-{baud}"
        self.trace = workdir / f"floor-trace-{baud}.txt"
        self.emu = BoardProcess(self.link, baud, config)
        self.node = subprocess.Popen(
            [
                sys.executable,
                str(HERE / "floor_node.py"),
                "--port",
                str(self.link),
                "--baud",
                str(baud),
                "--trace",
                str(self.trace),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert self.node.stdout is not None
            assert self.node.stdout.readline().strip() == "ready", "floor_node.py did not start"
            self.stop = peer.node.create_client(
                Trigger, "/al5d_floor/stop", qos_profile=QOS_SERVICES
            )
            assert self.stop.wait_for_service(timeout_sec=30), "the floor's stop service"
            self.answered()
        except BaseException:
            self.close()
            raise

    def answered(self, timeout: float = 30.0) -> None:
        """Until a move of ours has its result: matched both ways (a message sent before
        the match is lost), and the stop service has answered once (its first answer can
        be dropped, `rospeer.Peer.first_answer`)."""
        deadline = time.monotonic() + timeout
        while True:
            ident, _ = self.move("probe", base=0)
            try:
                self.peer.result(ident, 1.0)
                break
            except AssertionError:
                if time.monotonic() > deadline:
                    raise
        while True:
            try:
                wait_future(self.stop.call_async(Trigger.Request()), 2.0)
                return
            except AssertionError:
                if time.monotonic() > deadline:
                    raise

    def barrier(self, timeout: float = 30.0, peer: Peer | None = None) -> None:
        """Until the floor has taken in everything sent so far (it answers each in order)."""
        ident = self.ident("barrier")
        (peer or self.peer).send(ident, "barrier")
        (peer or self.peer).result(ident, timeout)

    def close(self) -> dict[str, dict[str, int]]:
        """Ends the floor node; its trace (empty if it could not write one)."""
        self.node.terminate()
        try:
            self.node.wait(10)
        except subprocess.TimeoutExpired:
            self.node.kill()
        self.emu.close()
        return read_trace(self.trace) if self.trace.exists() else {}


def stop_floor(rig: FloorRig, trials: int = 100) -> dict[str, Any]:
    """The stop by the floor's service and on the topic, in turn, until STOP5 is in effect."""
    wire = p.wire_time_s(STOP_BYTES, rig.baud) * 1000
    by: dict[str, list[float]] = {"service": [], "topic": []}
    for trial in range(trials):
        via = "service" if trial % 2 == 0 else "topic"
        t0 = time.monotonic()
        if via == "service":
            future = rig.stop.call_async(Trigger.Request())
        else:
            rig.peer.send(rig.ident("stop"), "stop")
        rec = rig.record_after(t0, lambda r: r.raw == STOP_LINES[-1])
        by[via].append((rec.t_effect - t0) * 1000)
        if via == "service":
            wait_future(future)
        time.sleep(wire / 1000)  # the wire is free again, as before each of our stops
    return {via: figure(f"floor: stop via {via}", s, wire_ms=wire) for via, s in by.items()}


def measure(config: ArmConfig, baud: int, workdir: Path, peer: Peer, log: Any) -> dict[str, Any]:
    """The floors at `baud`: command to board (as `rosbench.command_to_board`), and at 9600
    the stop."""
    rig = FloorRig(config, baud, workdir, peer)
    out: dict[str, Any] = {}
    try:
        if baud == 9600:
            log("floor: ROS client -> node (2000 paced messages, floor_node.py)")
            ids, sent = ros_latency(rig, word="latency")
        log(f"floor: command to board at {baud} baud (300 moves, floor_node.py)")
        out["c2b"] = command_to_board(rig)
        out["c2b"].pop("times")
        if baud == 9600:
            log("floor: the stop by service and on the topic (100 trials)")
            out["stop"] = stop_floor(rig)
    finally:
        trace = rig.close()
    if baud == 9600:
        out["ros_latency"] = latency_figure("ROS client -> bare node", ids, sent, trace)
    return out


def ratio_row(
    name: str, ours: dict[str, Any], floor: dict[str, Any]
) -> tuple[str, str, str, str, bool]:
    """A row of the table: our p50 and p99 over the floor's, held within the ratios."""
    r50 = ours["p50_ms"] / floor["p50_ms"]
    r99 = ours["p99_ms"] / floor["p99_ms"]
    text = (
        f"p50 {ours['p50_ms']:.2f} / floor {floor['p50_ms']:.2f} ms = {r50:.2f}x, "
        f"p99 {ours['p99_ms']:.2f} / floor {floor['p99_ms']:.2f} ms = {r99:.2f}x"
    )
    target = f"p50 <= {P50_RATIO}x, p99 <= {P99_RATIO}x the floor"
    return (name, text, "-", target, r50 <= P50_RATIO and r99 <= P99_RATIO)
