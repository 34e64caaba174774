"""A MoveIt-like client that sends FollowJointTrajectory goals at a steady rate, each
preempting the last: run as its own process (issue 23's goal flood).

    python -m al5d_rig.goal_flood_client RATE SECONDS

Prints one line of JSON when ready, waits for a line on stdin, floods, then waits
for every goal's answer and prints how many were sent, answered (accepted or
rejected), and ended with a result, and how long the sending took (`send_s`: the
rate it reached is `sent / send_s`).
"""

from __future__ import annotations

import json
import random
import sys
import threading
import time
from typing import Any

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectoryPoint

from al5d.arm.config import load_config
from al5d.model import ArmModel
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import Names
from al5d_rig.rospeer import LockedActionClient

ARM = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]


def goal(rng: random.Random, model: ArmModel) -> FollowJointTrajectory.Goal:
    """Three points over 0.6 s, well inside the workspace, in the URDF's radians."""
    g = FollowJointTrajectory.Goal()
    g.trajectory.joint_names = ARM
    for k in (1, 2, 3):
        degrees = {
            "base": rng.uniform(-20, 20),
            "shoulder": rng.uniform(10, 30),
            "elbow": rng.uniform(60, 90),
            "wrist": rng.uniform(-10, 10),
            "wrist_rotate": rng.uniform(-30, 30),
        }
        urdf = model.to_urdf(degrees)
        positions = [urdf[j] for j in ARM]
        g.trajectory.points.append(
            JointTrajectoryPoint(
                positions=positions, time_from_start=Duration(sec=0, nanosec=200_000_000 * k)
            )
        )
    return g


def main() -> int:
    rate, seconds = float(sys.argv[1]), float(sys.argv[2])
    context = start_context()
    node = Node("al5d_goal_flood", context=context)
    # rclpy's ActionClient, sending from this thread while its executor spins in another, can
    # take a goal's answer for a stranger's; the tests' locked client cannot.
    client = LockedActionClient(node, FollowJointTrajectory, Names().follow_joint_trajectory)
    spinner = Spinner(node, context, kind="single")
    lock = threading.Lock()
    counts = {"sent": 0, "answered": 0, "accepted": 0, "results": 0}
    statuses: dict[int, int] = {}

    def on_result(future: Any) -> None:
        with lock:
            counts["results"] += 1
            status = future.result().status
            statuses[status] = statuses.get(status, 0) + 1

    def on_answer(future: Any) -> None:
        handle = future.result()
        with lock:
            counts["answered"] += 1
            counts["accepted"] += bool(handle.accepted)
        if handle.accepted:
            handle.get_result_async().add_done_callback(on_result)

    if not client.wait_for_server(timeout_sec=30):
        print(json.dumps({"error": "no trajectory action server"}), flush=True)
        return 1
    print(json.dumps({"ready": True}), flush=True)
    sys.stdin.readline()  # go
    rng = random.Random(23)
    # Loaded once: a config's load takes about 17 ms, which held the flood to about 20
    # goals a second when each goal loaded it.
    model = load_config().model
    n = int(rate * seconds)
    t0 = time.monotonic()
    for i in range(n):
        if (wait := t0 + i / rate - time.monotonic()) > 0:
            time.sleep(wait)
        client.send_goal_async(goal(rng, model)).add_done_callback(on_answer)
        with lock:
            counts["sent"] += 1
    sent_s = time.monotonic() - t0
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with lock:
            if counts["answered"] == n and counts["results"] == counts["accepted"]:
                break
        time.sleep(0.1)
    with lock:
        print(json.dumps({**counts, "statuses": statuses, "send_s": sent_s}), flush=True)
    spinner.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
