"""Trajectories at the link's budget over real DDS (issue 25): dense goals at 9600 baud.

A FollowJointTrajectory of 100 points at 20 ms is more than the wire carries at
9600 baud (a group move of the five arm joints is 40 bytes, 41.7 ms): it used to
end ABORTED, point 98 nearly 2 s late. Thinned to what the wire carries, it
succeeds, and the emulated servos (their positions over time, from the board's
record) stay within the path tolerance of the requested path. One that no
thinning can keep on its path is rejected whole, naming the wire.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import pytest
from action_msgs.msg import GoalStatus
from armrig import LINK_CHECK
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from rospeer import LockedActionClient, Peer, wait_future, wait_until
from served import Served, served
from trajectory_msgs.msg import JointTrajectoryPoint

from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p

ARM = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]
START = {"base": 0.0, "shoulder": 30.0, "elbow": 90.0, "wrist": 0.0, "wrist_rotate": 0.0}
#: Each joint's travel out and back (degrees).
TRAVEL = {"base": 25.0, "shoulder": 15.0, "elbow": -20.0, "wrist": 15.0, "wrist_rotate": 20.0}


class Rig:
    def __init__(self, s: Served) -> None:
        self.s = s
        self.fjt = LockedActionClient(
            s.peer.node, FollowJointTrajectory, "/arm_controller/follow_joint_trajectory"
        )
        assert self.fjt.wait_for_server(timeout_sec=10)

    @property
    def peer(self) -> Peer:
        return self.s.peer

    def goal(self, points: list[tuple[float, dict[str, float]]]) -> Any:
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = ARM
        for t, degrees in points:
            values = self.s.config.model.to_urdf(degrees)
            sec = int(t)
            goal.trajectory.points.append(
                JointTrajectoryPoint(
                    positions=[values[j] for j in ARM],
                    time_from_start=Duration(sec=sec, nanosec=round((t - sec) * 1e9)),
                )
            )
        return goal

    def run(self, goal: Any) -> Any:
        handle = wait_future(self.fjt.send_goal_async(goal))
        assert handle.accepted, self.peer.result(bytes(handle.goal_id.uuid).hex()).reason
        return wait_future(handle.get_result_async(), 30)

    def recover(self) -> None:
        if self.s.states[-1] != "ready":
            self.peer.trigger("release")
            wait_until(lambda: self.s.states[-1] == "ready", 10, "ready")


@pytest.fixture(scope="module")
def rig(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with served(config, tmp_path_factory.mktemp("budget"), "al5d_budget_peer") as s:
        r = Rig(s)
        try:
            yield r
        finally:
            r.fjt.destroy()


def wave(n: int, dt: float) -> list[tuple[float, dict[str, float]]]:
    """Out and back from START, from rest to rest, as MoveIt times a path: n points dt apart."""
    span = (n - 1) * dt
    out = []
    for k in range(n):
        f = (1 - math.cos(2 * math.pi * k * dt / span)) / 2
        out.append((k * dt, {j: START[j] + TRAVEL[j] * f for j in ARM}))
    return out


def deviation(
    rig: Rig, points: list[tuple[float, dict[str, float]]], records: list[Any]
) -> dict[str, float]:
    """Per joint, the most the emulated servo was off the requested path (radians), sampled
    every 2 ms from when the first move took effect (the point at 0 is where the arm was)
    to the last point's time, from the board's record of every group move."""
    model = rig.s.config.model
    moves = [r for r in records if any(isinstance(c, p.GroupMove) for c in r.commands)]
    origin = moves[0].t_effect
    times = [t for t, _ in points]
    wanted = [model.to_urdf(d) for _, d in points]
    worst = dict.fromkeys(ARM, 0.0)
    for k, rec in enumerate(moves):
        end = moves[k + 1].t_effect if k + 1 < len(moves) else origin + times[-1]
        samples = [rec.t_effect + i * 0.002 for i in range(int((end - rec.t_effect) / 0.002) + 1)]
        servo = rig.s.emu.trajectory(rec.t_effect, samples, ARM)
        for i, t in enumerate(samples):
            s = min(max(t - origin, 0.0), times[-1])
            m = min(len(times) - 2, int(s / (times[1] - times[0])))
            f = (s - times[m]) / (times[m + 1] - times[m])
            have = model.to_urdf({j: servo[j][1][i] for j in ARM})
            for j in ARM:
                want = wanted[m][j] + (wanted[m + 1][j] - wanted[m][j]) * f
                worst[j] = max(worst[j], abs(have[j] - want))
    return worst


def test_a_dense_trajectory_is_thinned_to_the_wire_and_stays_on_its_path(rig: Rig) -> None:
    rig.recover()
    assert rig.run(rig.goal([(1.0, START)])).status == GoalStatus.STATUS_SUCCEEDED
    points = wave(100, 0.02)
    goal = rig.goal(points)
    goal.goal_time_tolerance = Duration(sec=0, nanosec=100_000_000)
    rig.s.emu.clear_records()
    answer = rig.run(goal)
    # It used to end ABORTED: "point 98 was reached 1898 ms after its time_from_start".
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    assert answer.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    records = rig.s.emu.records
    moves = [c for r in records for c in r.commands if isinstance(c, p.GroupMove)]
    # A line's time apart, and more than one in every three points: the wire's pace.
    assert 20 <= len(moves) <= 45, len(moves)
    # The first and last points exactly (each joint's pulse within 1 us).
    channels = {j: rig.s.config.joints[j].channel for j in ARM}
    for move, (_, degrees) in ((moves[0], points[0]), (moves[-1], points[-1])):
        pulses = {t.channel: t.pulse_us for t in move.targets}
        for j, deg in degrees.items():
            assert abs(pulses[channels[j]] - rig.s.config.joints[j].to_us(deg)) <= 1
    # The servos within the default path tolerance (1 deg) of the requested path.
    tolerance = math.radians(rig.s.config.server.trajectory_path_tolerance_deg)
    off = deviation(rig, points, records)
    assert all(v <= tolerance for v in off.values()), off


def test_a_goal_s_own_path_tolerance_is_kept(rig: Rig) -> None:
    rig.recover()
    assert rig.run(rig.goal([(1.0, START)])).status == GoalStatus.STATUS_SUCCEEDED
    points = wave(200, 0.01)
    goal = rig.goal(points)
    goal.path_tolerance = [JointTolerance(name=j, position=0.03) for j in ARM]
    rig.s.emu.clear_records()
    answer = rig.run(goal)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    off = deviation(rig, points, rig.s.emu.records)
    assert all(v <= 0.03 for v in off.values()), off


def test_a_path_too_tight_for_the_wire_is_rejected_whole_naming_the_wire(rig: Rig) -> None:
    rig.recover()
    # The base zigzags 10 deg every 20 ms: no group move a wire's time apart follows it.
    points = [(k * 0.02, {**START, "base": 10.0 * (k % 2)}) for k in range(50)]
    rig.s.emu.clear_records()
    handle = wait_future(rig.fjt.send_goal_async(rig.goal(points)))
    assert not handle.accepted
    reason = rig.peer.result(bytes(handle.goal_id.uuid).hex()).reason
    assert reason.startswith("the wire: at 9600 baud a group move of 40 bytes takes 41.7 ms"), (
        reason
    )
    assert "puts base 10 deg off the requested path at point 1" in reason, reason
    assert all(LINK_CHECK.fullmatch(r.raw) for r in rig.s.emu.records), "a rejected goal wrote"
    assert rig.s.states[-1] == "ready"
