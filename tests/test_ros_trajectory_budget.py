"""Trajectories at the link's budget over real DDS (issue 25): dense goals at 9600 baud.

A FollowJointTrajectory of 100 points at 20 ms is more than the wire carries at
9600 baud (a group move of the five arm joints is 40 bytes, 41.7 ms): it used to
end ABORTED, point 98 nearly 2 s late. Thinned to what the wire carries, it
succeeds, and the emulated servos (their positions over time, from the board's
record) stay within the path tolerance of the requested path. One that no
thinning can keep on its path is rejected whole, naming the wire.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import Any

import pytest
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance

from al5d.arm.config import ArmConfig
from al5d_rig.armrig import LINK_CHECK, group_moves
from al5d_rig.rospeer import LockedActionClient, Peer, first_goal_answer, wait_future, wait_until
from al5d_rig.served import Served, served
from al5d_rig.trajectories import ARM, START, goal_of, multi_dof_goal, wave

#: Each joint's travel out and back (degrees).
TRAVEL = {"base": 25.0, "shoulder": 15.0, "elbow": -20.0, "wrist": 15.0, "wrist_rotate": 20.0}


class Rig:
    def __init__(self, s: Served) -> None:
        self.s = s
        self.fjt = LockedActionClient(
            s.peer.node, FollowJointTrajectory, "/arm_controller/follow_joint_trajectory"
        )
        assert self.fjt.wait_for_server(timeout_sec=10)
        first_goal_answer(self.fjt, multi_dof_goal())

    @property
    def peer(self) -> Peer:
        return self.s.peer

    def goal(self, points: list[tuple[float, dict[str, float]]]) -> Any:
        return goal_of(self.s.config, points)

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
            r.peer.destroy(r.fjt)


def kept_points(rig: Rig, points: list[tuple[float, dict[str, float]]]) -> list[int]:
    """Which requested point each group move on the board is (each joint's pulse within
    1 us), in the order written, each sought after the one before (a path may come back
    to where it was; near a rest, neighbouring points may share their pulses); -1 for a
    line that is none of them."""
    channels = {j: rig.s.config.joints[j].channel for j in ARM}
    wanted = [
        {channels[j]: rig.s.config.joints[j].to_us(d) for j, d in degrees.items()}
        for _, degrees in points
    ]
    moves = group_moves(rig.s.emu.records)
    kept: list[int] = []
    for n, move in enumerate(moves):
        pulses = {t.channel: t.pulse_us for t in move.targets}
        start = max((k for k in kept if k >= 0), default=-1) + 1
        found = [k for k in range(start, len(wanted)) if matches(pulses, wanted[k])]
        # The last line, the latest point it is (near its end a path may rest).
        kept.append((found[-1] if n == len(moves) - 1 else found[0]) if found else -1)
    return kept


def matches(pulses: dict[int, int], wanted: dict[int, float]) -> bool:
    return all(abs(pulses[c] - w) <= 1 for c, w in wanted.items())


def test_a_dense_trajectory_is_thinned_to_the_wire_and_stays_on_its_path(rig: Rig) -> None:
    rig.recover()
    assert rig.run(rig.goal([(1.0, START)])).status == GoalStatus.STATUS_SUCCEEDED
    points = wave(100, 0.02, TRAVEL)
    goal = rig.goal(points)
    # Generous for a busy host: the defect was 1.9 s late.
    goal.goal_time_tolerance = Duration(sec=0, nanosec=500_000_000)
    # And a path tolerance a busy host keeps (0.1 rad is 145 ms late at the wave's 0.69
    # rad/s): with the default (1 degree) a point written 32 ms late in an idle CI run of
    # four workers on two cores rightly ended the goal ABORTED, which is the machine's, not
    # the thinning's. The path kept: the test below, `test_arm_core.py` and bench/.
    goal.path_tolerance = [JointTolerance(name=j, position=0.1) for j in ARM]
    rig.s.emu.clear_records()
    answer = rig.run(goal)
    # It used to end ABORTED: "point 98 was reached 1898 ms after its time_from_start".
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    assert answer.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    kept = kept_points(rig, points)
    # A line's time apart, and more than one in every three points: the wire's pace.
    assert 20 <= len(kept) <= 45, kept
    # Points of the path, in order, the first and the last exactly: the board's own
    # interpolation between them keeps the path (within tolerance: test_arm_resample.py;
    # the servos' deviation on the emulated board is a figure of bench/trajectory_budget.py,
    # where a late write on a busy host is the machine's, not the path's).
    assert kept[0] == 0 and kept[-1] == len(points) - 1, kept
    assert kept == sorted(set(kept)), kept


def test_a_goal_s_own_path_tolerance_is_kept(rig: Rig) -> None:
    rig.recover()
    assert rig.run(rig.goal([(1.0, START)])).status == GoalStatus.STATUS_SUCCEEDED
    # Denser than the wire (a line is 42 ms) and slow enough that a write the busy machine
    # delays does not break the tolerance at run time: at 0.23 rad/s (the base's fastest)
    # 0.03 rad is 130 ms late. At 0.69 rad/s (the same wave in 2 s) a write 58 ms late on a
    # busy CI machine was rightly a path broken, which is the machine's, not the thinning's.
    points = wave(300, 0.02, TRAVEL)
    goal = rig.goal(points)
    goal.path_tolerance = [JointTolerance(name=j, position=0.03) for j in ARM]
    rig.s.emu.clear_records()
    answer = rig.run(goal)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    kept = kept_points(rig, points)
    assert kept[0] == 0 and kept[-1] == len(points) - 1 and kept == sorted(set(kept)), kept
    # Each joint, between the points kept, within the goal's tolerance of the requested path
    # as the board interpolates (linear in pulse, so in degrees).
    model = rig.s.config.model
    wanted = [model.to_urdf(d) for _, d in points]
    for a, b in itertools.pairwise(kept):
        for k in range(a, b + 1):
            f = (points[k][0] - points[a][0]) / (points[b][0] - points[a][0])
            for j in ARM:
                board = model.to_urdf(
                    {i: points[a][1][i] + (points[b][1][i] - points[a][1][i]) * f for i in ARM}
                )[j]
                assert abs(board - wanted[k][j]) <= 0.03, (j, k, board, wanted[k][j])


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
