"""A client of FollowJointTrajectory as MoveIt is (plain rclpy, no lease of ours), in a
process of its own: it sends one goal, says `accepted`, then `feedback` at the goal's first
feedback (the server has matched the client's readers), and leaves at a line on its
stdin, its goal running; and docs/ros.md's Fast DDS profile that shortens a lease."""

from __future__ import annotations

import re
import sys
from collections.abc import Sequence
from pathlib import Path

SCRIPT = """
import rclpy
import rclpy.task
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from rclpy.action import ActionClient
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectoryPoint

rclpy.init()
node = Node("{node}")
client = ActionClient(node, FollowJointTrajectory, "{action}")
assert client.wait_for_server(60)
goal = FollowJointTrajectory.Goal()
goal.trajectory.joint_names = {names!r}
goal.trajectory.points = [
    JointTrajectoryPoint(positions=p, time_from_start=Duration(sec=s)) for s, p in {points!r}
]
fed = rclpy.task.Future()
future = client.send_goal_async(goal, feedback_callback=lambda _: fed.set_result(True))
rclpy.spin_until_future_complete(node, future, timeout_sec=60)
assert future.result().accepted
print("accepted", flush=True)
rclpy.spin_until_future_complete(node, fed, timeout_sec=60)
assert fed.done()
print("feedback", flush=True)
input()  # then leaves, its goal running
node.destroy_node()
rclpy.shutdown()
"""

#: The client's node: its reader of the action's status is listed under it.
NODE = "al5d_leaving_action_client"


def argv(action: str, names: Sequence[str], points: Sequence[tuple[int, list[float]]]) -> list[str]:
    """The command of a client whose goal on `action` names the joints `names` (the URDF's,
    radians) and holds `points`, each its second from the start and its positions."""
    script = SCRIPT.format(node=NODE, action=action, names=list(names), points=list(points))
    return [sys.executable, "-c", script]


def short_lease_profile(docs: Path) -> str:
    """The Fast DDS profile for MoveIt's processes that `docs`/ros.md gives, as the page
    gives it: a participant's lease of 2 s (Fast DDS's own: 20 s)."""
    page = (docs / "ros.md").read_text()
    found = re.search(r"with a 2 s lease:\n\n  ```xml\n(.*?)\n  ```", page, re.S)
    assert found, "docs/ros.md gives no profile with a 2 s lease"
    return "\n".join(line.removeprefix("  ") for line in found.group(1).splitlines())
