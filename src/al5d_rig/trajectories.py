"""Dense trajectories as MoveIt times them, and their FollowJointTrajectory goals: shared by
`test_ros_trajectory_budget.py` and `bench/trajectory_budget.py`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from trajectory_msgs.msg import JointTrajectoryPoint, MultiDOFJointTrajectoryPoint

from al5d.arm.config import ArmConfig

ARM = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]
START = {"base": 0.0, "shoulder": 30.0, "elbow": 90.0, "wrist": 0.0, "wrist_rotate": 0.0}
Points = list[tuple[float, dict[str, float]]]


def wave(n: int, dt: float, travel: Mapping[str, float]) -> Points:
    """Out by `travel` and back from START, from rest to rest, as MoveIt times a path: n
    points dt apart."""
    span = (n - 1) * dt
    out = []
    for k in range(n):
        f = (1 - math.cos(2 * math.pi * k * dt / span)) / 2
        out.append((k * dt, {j: START[j] + travel[j] * f for j in ARM}))
    return out


def goal_of(config: ArmConfig, points: Points) -> Any:
    """The goal of `points` (seconds, degrees), in radians and URDF joint names."""
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ARM
    for t, degrees in points:
        values = config.model.to_urdf(degrees)
        sec = int(t)
        goal.trajectory.points.append(
            JointTrajectoryPoint(
                positions=[values[j] for j in ARM],
                time_from_start=Duration(sec=sec, nanosec=round((t - sec) * 1e9)),
            )
        )
    return goal


def multi_dof_goal() -> Any:
    """A goal the server rejects at once, moving nothing: a multi-DOF point (the AL5D has
    none), to probe the action server (`rospeer.first_goal_answer`)."""
    goal = FollowJointTrajectory.Goal()
    goal.multi_dof_trajectory.points.append(MultiDOFJointTrajectoryPoint())
    return goal


def nan_gripper_goal() -> Any:
    """A gripper goal the server rejects at once, moving nothing: a gap that is not a number
    (`rospeer.first_goal_answer`)."""
    goal = GripperCommand.Goal()
    goal.command.position = math.nan
    return goal
