"""The standard control actions as MoveIt's simple controller manager uses them (issue 14).

Over real DDS against `al5d serve` in its own process; the emulated board is in
this process behind a pty, so the tests see exactly what reached it.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from action_msgs.msg import GoalStatus, GoalStatusArray
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from control_msgs.msg import JointTolerance
from rclpy.qos import qos_profile_action_status_default
from trajectory_msgs.msg import JointTrajectoryPoint

from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator
from al5d_rig.armrig import LINK_CHECK, board_pulses, group_moves, holds
from al5d_rig.host import Shortage
from al5d_rig.rospeer import LockedActionClient, Peer, first_goal_answer, wait_future, wait_until
from al5d_rig.served import served
from al5d_rig.trajectories import multi_dof_goal

ARM = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]
FJT = FollowJointTrajectory.Result


@dataclass
class Rig:
    emu: Emulator
    peer: Peer
    config: ArmConfig
    fjt: LockedActionClient
    gripper: LockedActionClient
    states: list[str]

    def urdf(self, **degrees: float) -> list[float]:
        """Arm degrees of the five arm joints in the URDF's radians (REP 103), in ARM order."""
        values = self.config.model.to_urdf(degrees)
        return [values[j] for j in ARM]

    def trajectory(
        self, points: list[tuple[float, dict[str, float]]], names: list[str] | None = None
    ) -> FollowJointTrajectory.Goal:
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = names or ARM
        for t, degrees in points:
            sec = int(t)
            goal.trajectory.points.append(
                JointTrajectoryPoint(
                    positions=self.urdf(**degrees),
                    time_from_start=Duration(sec=sec, nanosec=round((t - sec) * 1e9)),
                )
            )
        return goal

    def send(self, client: LockedActionClient, goal: Any, feedback: list[Any] | None = None) -> Any:
        return wait_future(
            client.send_goal_async(
                goal, feedback_callback=feedback.append if feedback is not None else None
            )
        )

    def recover(self) -> None:
        """Back to ready, whatever the last test left."""
        if self.states[-1] != "ready":
            self.peer.trigger("release")
            wait_until(lambda: self.states[-1] == "ready", 10, "ready")


def only_link_checks(rig: Rig) -> bool:
    """Nothing reached the board since its records were cleared but the driver's own checks
    of the link (not a move, nor a STOP, nor an ESC)."""
    return all(LINK_CHECK.fullmatch(r.raw) for r in rig.emu.records)


def pose(**degrees: float) -> dict[str, float]:
    return {j: degrees.get(j, 0.0) for j in ARM}


@pytest.fixture(scope="module")
def rig(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    workdir = tmp_path_factory.mktemp("controllers")
    with served(config, workdir, "al5d_moveit_peer") as s:
        fjt = LockedActionClient(
            s.peer.node, FollowJointTrajectory, "/arm_controller/follow_joint_trajectory"
        )
        gripper = LockedActionClient(s.peer.node, GripperCommand, "/gripper_controller/gripper_cmd")
        try:
            assert fjt.wait_for_server(timeout_sec=10) and gripper.wait_for_server(timeout_sec=10)
            first_goal_answer(fjt, multi_dof_goal())
            yield Rig(s.emu, s.peer, config, fjt, gripper, s.states)
        finally:
            s.peer.destroy(fjt, gripper)


def test_a_trajectory_runs_one_group_move_per_point_in_order_at_its_times(rig: Rig) -> None:
    points = [
        (0.4, pose(base=20, shoulder=10, elbow=60)),
        (0.9, pose(base=-20, shoulder=20, elbow=80, wrist=-10)),
        (1.2, pose(base=0, shoulder=30, elbow=90, wrist_rotate=30)),
    ]
    for attempt in range(3):
        rig.recover()
        if attempt:
            # The goal halted below left joints known only within a step of QP, which the
            # next goal's first line would hold: a preset makes them known again.
            rig.peer.send(f"known-{attempt}", "ready")
            assert rig.peer.result(f"known-{attempt}").outcome == "done"
        rig.emu.clear_records()
        feedback: list[Any] = []
        short = Shortage()
        handle = rig.send(rig.fjt, rig.trajectory(points), feedback)
        assert handle.accepted
        answer = wait_future(handle.get_result_async(), 15)
        if not (
            answer.status == GoalStatus.STATUS_ABORTED and short.excuses(answer.result.error_string)
        ):
            break
        # An idle CI run, four workers on two cores: point 1 written 36 ms late, its base
        # 2.88 deg off the path. The server kept its word; the times are judged on a goal
        # the host ran in time.
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    assert answer.result.error_code == FJT.SUCCESSFUL, answer.result.error_string
    records = [r for r in rig.emu.records if any(isinstance(c, p.GroupMove) for c in r.commands)]
    moves = group_moves(rig.emu.records)
    assert len(moves) == len(points) == len(records)
    # Each point is reached at its time_from_start, counted from the first move's effect:
    # the board's pulses get there when each group move's time has run (a line written
    # late has its time shortened to arrive on time). How close is `make bench`'s figure
    # (trajectory timing); here, generous: a loaded machine wakes late (138 ms once beside
    # two busy loops, and 1.67 s once, when the host was short of cores for seconds).
    start = records[0].t_effect
    late_s = 0.5 + short.s
    for rec, move, (at, _) in zip(records, moves, points, strict=True):
        assert move.time_ms is not None
        assert -0.5 < rec.t_effect + move.time_ms / 1000 - start - at < late_s
    channels = {j: rig.config.joints[j].channel for j in ARM}
    for move, (_, degrees) in zip(moves, points, strict=True):
        pulses = {t.channel: t.pulse_us for t in move.targets}
        for j, deg in degrees.items():
            assert abs(pulses[channels[j]] - rig.config.joints[j].to_us(deg)) <= 1
    # Feedback: desired, actual and error for the named joints, as the arm moved.
    assert feedback, "no feedback while the trajectory ran"
    last = feedback[-1].feedback
    assert list(last.joint_names) == ARM
    fb = (last.desired.positions, last.actual.positions, last.error.positions)
    for d, a, e in zip(*fb, strict=True):
        assert math.isclose(e, d - a, abs_tol=1e-9)
    ends = rig.emu.servo_degrees()
    for j, deg in points[-1][1].items():
        assert abs(ends[j] - deg) < 0.5


def test_a_trajectory_stamped_ahead_starts_at_its_stamp(rig: Rig) -> None:
    """`header.stamp` 1.5 s ahead: the goal is accepted at once and its first line reaches
    the board no earlier than the stamp (ros2_control's controllers start a trajectory at
    its stamp; it started at once, whatever the stamp said). A stamp 60 s ahead (a
    sender's clock likely wrong) is rejected, naming the stamp, with nothing written."""
    rig.recover()
    rig.emu.clear_records()
    goal = rig.trajectory([(0.3, pose(base=15, shoulder=10, elbow=60))])
    ahead_s = 1.5
    asked, wall = time.monotonic(), time.time_ns()
    stamp = wall + round(ahead_s * 1e9)
    goal.trajectory.header.stamp.sec, goal.trajectory.header.stamp.nanosec = divmod(stamp, 10**9)
    handle = rig.send(rig.fjt, goal)
    assert handle.accepted
    answer = wait_future(handle.get_result_async(), 30)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    moves = [r for r in rig.emu.records if any(isinstance(c, p.GroupMove) for c in r.commands)]
    assert moves, rig.emu.records
    # A lower bound, which a busy host only makes later: the line's CR came after the stamp.
    assert moves[0].t_effect >= asked + ahead_s, moves[0].t_effect - asked
    rig.emu.clear_records()
    far = rig.trajectory([(0.3, pose(base=-15, shoulder=10, elbow=60))])
    stamp = time.time_ns() + 60 * 10**9
    far.trajectory.header.stamp.sec, far.trajectory.header.stamp.nanosec = divmod(stamp, 10**9)
    handle = rig.send(rig.fjt, far)
    assert not handle.accepted
    refusal = rig.peer.result(bytes(handle.goal_id.uuid).hex())
    assert refusal.outcome == "refused", refusal
    assert refusal.reason.startswith("its start (header.stamp) is 60.0 s ahead"), refusal.reason
    time.sleep(0.2)
    assert only_link_checks(rig), "a rejected goal wrote to the board"


def test_a_moveit_shaped_trajectory_from_the_start_state_succeeds(rig: Rig) -> None:
    # What MoveIt sends: the first point is the current state (from /joint_states) at
    # time_from_start 0, then points about 0.1 s apart with velocities and accelerations.
    rig.recover()
    wait_until(lambda: rig.peer.joint_states, 5, "joint states")
    state = rig.peer.joint_states[-1]
    start = [state.position[list(state.name).index(j)] for j in ARM]
    end = rig.urdf(**pose(base=25, shoulder=15, elbow=70))
    n = 8
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ARM
    for k in range(n + 1):
        f = k / n
        goal.trajectory.points.append(
            JointTrajectoryPoint(
                positions=[a + (b - a) * f for a, b in zip(start, end, strict=True)],
                velocities=[0.0] * len(ARM),
                accelerations=[0.0] * len(ARM),
                time_from_start=Duration(sec=0, nanosec=k * 100_000_000),
            )
        )
    rig.emu.clear_records()
    pulses_before = board_pulses(rig.emu)
    short = Shortage()
    handle = rig.send(rig.fjt, goal)
    assert handle.accepted
    answer = wait_future(handle.get_result_async(), 15)
    if answer.status == GoalStatus.STATUS_ABORTED and short.excuses(answer.result.error_string):
        return  # a CI run with four workers on two cores: 151 ms late, the host short
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    # The start point too: the arm is already there.
    moves = group_moves(rig.emu.records)
    assert len(moves) - holds(moves, n + 1, pulses_before) == n + 1
    ends = rig.emu.servo_degrees()
    for j, deg in pose(base=25, shoulder=15, elbow=70).items():
        assert abs(ends[j] - deg) < 0.5


def test_joints_not_named_keep_their_place(rig: Rig) -> None:
    rig.recover()
    before = rig.emu.servo_degrees()
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ["elbow"]
    goal.trajectory.points = [
        JointTrajectoryPoint(
            positions=[rig.urdf(**pose(elbow=70))[2]],
            time_from_start=Duration(sec=0, nanosec=300_000_000),
        )
    ]
    handle = rig.send(rig.fjt, goal)
    assert wait_future(handle.get_result_async(), 10).status == GoalStatus.STATUS_SUCCEEDED
    after = rig.emu.servo_degrees()
    assert abs(after["elbow"] - 70) < 0.5
    # Within a step of `QP` (10 us, 1 degree): after a goal halted mid-way (a test before
    # this one, on a busy host), the pose is read back, and the first line puts the joints
    # it caught moving where they were read (docs/server.md); otherwise exactly.
    for j in ("base", "shoulder", "wrist", "wrist_rotate", "gripper"):
        assert abs(after[j] - before[j]) < 1.0


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ("unknown joint", "unknown joint"),
        # Issue 22, defect 3: a finger of our own URDF raised KeyError in the goal callback,
        # and the goal was never answered.
        ("a finger", "gripper_left is a finger of the URDF's gripper"),
        ("decreasing time", "not after point 0"),
        ("out of range", "point 1"),
        ("sizes", "positions for 5 joints"),
        # Taken whole, as positions are: a velocity or acceleration that is no number was
        # ignored (they are not used), and a negative goal_time_tolerance taken as none
        # (but -1 s: no limit, below).
        ("nan velocity", "point 1: velocities hold nan"),
        ("inf acceleration", "point 2: accelerations hold inf"),
        ("negative goal time tolerance", "goal_time_tolerance -0.5 s is negative"),
        ("effort", "point 0: gives effort: the AL5D's servos take positions only"),
    ],
)
def test_a_bad_trajectory_is_rejected_whole_and_writes_nothing(
    rig: Rig, change: str, reason: str
) -> None:
    rig.recover()
    goal = rig.trajectory([(0.3, pose(base=10)), (0.6, pose(base=20)), (0.9, pose(base=30))])
    pts = goal.trajectory.points
    if change == "unknown joint":
        goal.trajectory.joint_names = ["base", "shoulder", "elbow", "wrist", "thumb"]
    elif change == "a finger":
        goal.trajectory.joint_names = ["base", "shoulder", "elbow", "wrist", "gripper_left"]
    elif change == "decreasing time":
        pts[1].time_from_start = Duration(sec=0, nanosec=200_000_000)
    elif change == "out of range":
        pts[1].positions = rig.urdf(**pose(elbow=170))  # its range is 0..135
    elif change == "nan velocity":
        pts[1].velocities = [0.0, math.nan, 0.0, 0.0, 0.0]
    elif change == "inf acceleration":
        pts[2].accelerations = [0.0, 0.0, 0.0, 0.0, math.inf]
    elif change == "negative goal time tolerance":
        goal.goal_time_tolerance = Duration(sec=-1, nanosec=500_000_000)
    elif change == "effort":
        pts[0].effort = [1.0] * 5
    else:
        pts[2].positions = pts[2].positions[:4]
    rig.emu.clear_records()
    handle = rig.send(rig.fjt, goal)
    assert not handle.accepted
    ident = bytes(handle.goal_id.uuid).hex()
    refusal = rig.peer.result(ident)
    assert refusal.outcome == "refused" and reason in refusal.reason, refusal.reason
    # Named as an accepted goal's outcome is: the instruction it would have been.
    assert refusal.instruction == "trajectory", refusal
    time.sleep(0.2)
    assert only_link_checks(rig), "a rejected goal wrote to the board"


def test_a_cancel_halts_the_arm_where_it_is_without_the_lock(rig: Rig) -> None:
    rig.recover()
    # Slow enough that the cancel, however late on a busy host (its way is DDS, the
    # bridge, the owner), halts the base seconds before 55 degrees.
    goal = rig.trajectory([(4.0, pose(base=60, elbow=40)), (8.0, pose(base=-60, elbow=100))])
    handle = rig.send(rig.fjt, goal)
    assert handle.accepted
    time.sleep(1.2)
    t_cancel = time.monotonic()
    wait_future(handle.cancel_goal_async())
    answer = wait_future(handle.get_result_async(), 10)
    assert answer.status == GoalStatus.STATUS_CANCELED
    # The answer may come before the base's STOP has crossed the wire (8 ms at 9600 baud).
    rig.emu.wait_for(lambda rs: any(r.raw == b"STOP0" and r.t_effect > t_cancel for r in rs))
    here = rig.emu.servo_degrees()
    time.sleep(0.3)
    assert abs(rig.emu.servo_degrees()["base"] - here["base"]) < 0.5, "still moving"
    assert 5 < here["base"] < 55, "halted mid-way"
    # The state comes over ROS, after the arm's halt (later beside busy loops).
    wait_until(lambda: rig.states[-1] == "ready", 10, "ready: a cancel must not lock the arm")


def test_an_emergency_stop_aborts_the_goal_and_locks(rig: Rig) -> None:
    rig.recover()
    goal = rig.trajectory([(1.5, pose(base=-60)), (3.0, pose(base=60))])
    handle = rig.send(rig.fjt, goal)
    assert handle.accepted
    time.sleep(0.6)
    assert rig.peer.trigger("stop").success
    answer = wait_future(handle.get_result_async(), 10)
    assert answer.status == GoalStatus.STATUS_ABORTED
    assert "stop" in answer.result.error_string
    wait_until(lambda: rig.states[-1] == "stopped", 5, "stopped")
    # Locked: the next goal is rejected before it is accepted, as an inactive
    # joint_trajectory_controller would, with the reason on /al5d/result.
    later = rig.send(rig.fjt, rig.trajectory([(0.3, pose())]))
    assert not later.accepted
    refusal = rig.peer.result(bytes(later.goal_id.uuid).hex())
    assert "send release first" in refusal.reason
    gripper = GripperCommand.Goal()  # the gripper's controller too
    gripper.command.position = 0.01
    time.sleep(0.3)  # the stop's STOPs and read-back off the wire
    rig.emu.clear_records()
    later = rig.send(rig.gripper, gripper)
    assert not later.accepted
    assert "send release first" in rig.peer.result(bytes(later.goal_id.uuid).hex()).reason
    assert only_link_checks(rig), "a rejected goal wrote to the board"
    rig.recover()


def test_a_new_goal_preempts_the_running_one(rig: Rig) -> None:
    rig.recover()
    first = rig.send(rig.fjt, rig.trajectory([(2.0, pose(base=70)), (4.0, pose(base=-70))]))
    time.sleep(0.4)
    second = rig.send(rig.fjt, rig.trajectory([(0.5, pose(base=-10, elbow=45))]))
    assert first.accepted and second.accepted
    old = wait_future(first.get_result_async(), 10)
    # As the joint_trajectory_controller ends a preempted goal: CANCELED, INVALID_GOAL.
    assert old.status == GoalStatus.STATUS_CANCELED and "preempted" in old.result.error_string
    assert old.result.error_code == FJT.INVALID_GOAL
    new = wait_future(second.get_result_async(), 10)
    assert new.status == GoalStatus.STATUS_SUCCEEDED
    # There: the goal ends by the server's clock, which a board thread of a busy test
    # process can trail (1.86 degrees short once, four workers beside busy loops).
    wait_until(lambda: abs(rig.emu.servo_degrees()["elbow"] - 45) < 0.5, 5, "the elbow at 45")
    # READY comes over ROS, after the arm is there (seen still MOVING beside two busy loops).
    wait_until(lambda: rig.states[-1] == "ready", 10, "ready")


def test_goals_sent_back_to_back_leave_the_newest_running(rig: Rig) -> None:
    """Each goal preempts the ones before it, also one still waiting for its own
    predecessor's halt (the halts are written off the executor's thread): the last one
    runs, every other ends CANCELED naming a later goal."""
    rig.recover()
    first = rig.send(rig.fjt, rig.trajectory([(2.0, pose(base=60)), (4.0, pose(base=-60))]))
    time.sleep(0.3)
    futures = [
        rig.fjt.send_goal_async(rig.trajectory([(0.5, pose(base=b, elbow=50))]))
        for b in (-30, -20, -10)
    ]
    handles = [first, *(wait_future(f, 10) for f in futures)]
    assert all(h.accepted for h in handles)
    results = [wait_future(h.get_result_async(), 20) for h in handles]
    ids = [bytes(h.goal_id.uuid).hex() for h in handles]
    for k, r in enumerate(results[:-1]):
        assert r.status == GoalStatus.STATUS_CANCELED, (k, r.status, r.result.error_string)
        by = re.match(r"preempted by goal (\w+)", r.result.error_string)
        assert by is not None and by.group(1) in ids[k + 1 :], (k, r.result.error_string)
        # One outcome on /al5d/result too, naming the same goal (an outside try: a goal
        # preempted while it waited had none; a running one's named another goal).
        told = rig.peer.result(ids[k], 20)
        assert told.outcome == "cancelled", (k, told)
        # The running one halted; one preempted while it waited (at the bridge, for the halt
        # before it, or at the owner) did not run, whichever side it waited on.
        said = f"preempted by trajectory goal {by.group(1)}"
        waited = {said + " before it ran: the arm did not move for it"}
        assert told.reason in ({said} if k == 0 else {said} | waited), (k, told.reason)
    assert results[-1].status == GoalStatus.STATUS_SUCCEEDED
    wait_until(lambda: abs(rig.emu.servo_degrees()["base"] + 10) < 0.5, 5, "the base at -10")
    wait_until(lambda: rig.states[-1] == "ready", 10, "ready")


def test_a_cancel_of_a_goal_waiting_for_the_one_it_preempts_is_obeyed(rig: Rig) -> None:
    """A goal cancelled as soon as it is accepted, while it still waits for the halt of the
    goal it preempts: the cancel is accepted and obeyed (an outside try: it was refused,
    and the goal ran to SUCCEEDED). Where it came after the goal had started (a busy host),
    the goal is halted instead; either way it ends CANCELED, with one outcome."""
    rig.recover()
    first = rig.send(rig.fjt, rig.trajectory([(2.0, pose(base=60)), (4.0, pose(base=-60))]))
    assert first.accepted
    time.sleep(0.3)
    # The cancel is asked from the goal's answer's own callback: as soon as it is accepted.
    cancels: list[Any] = []
    sent = rig.fjt.send_goal_async(rig.trajectory([(1.5, pose(base=-40, elbow=50))]))
    sent.add_done_callback(lambda f: cancels.append(f.result().cancel_goal_async()))
    second = wait_future(sent, 10)
    assert second.accepted
    wait_until(lambda: cancels, 10, "the cancel asked")
    cancel = wait_future(cancels[0], 10)
    assert [bytes(g.goal_id.uuid) for g in cancel.goals_canceling] == [
        bytes(second.goal_id.uuid)
    ], cancel.return_code
    answer = wait_future(second.get_result_async(), 20)
    assert answer.status == GoalStatus.STATUS_CANCELED, answer.result.error_string
    told = rig.peer.result(bytes(second.goal_id.uuid).hex(), 20)
    assert told.outcome == "cancelled", told
    if told.reason.startswith("cancelled by the client before it ran"):
        time.sleep(0.3)
        assert abs(rig.emu.servo_degrees()["elbow"] - 50) > 5, "the cancelled goal moved"
    wait_until(lambda: rig.states[-1] == "ready", 10, "ready")


def test_a_goal_cancelled_while_it_waits_behind_another_move_says_it_did_not_move(
    rig: Rig,
) -> None:
    """An outside try: a goal queued at the owner behind a move of another channel, then
    cancelled, said "cancelled: the arm halted where it was", which it never moved; and
    another, that its result said it did not run while /al5d/result said only "cancelled by
    the client": both now say the same."""
    rig.recover()
    rig.peer.send("ahead", "move", 1500, elbow=60)
    wait_until(lambda: rig.states[-1] == "moving", 10, "the topic's move running")
    handle = rig.send(rig.fjt, rig.trajectory([(0.5, pose(base=-30, elbow=60))]))
    assert handle.accepted
    time.sleep(0.3)  # handed to the owner, where it waits (cancelled before that, it said so)
    wait_future(handle.cancel_goal_async())
    answer = wait_future(handle.get_result_async(), 20)
    assert answer.status == GoalStatus.STATUS_CANCELED, answer.result.error_string
    assert answer.result.error_string.startswith("cancelled by the client before it ran")
    told = rig.peer.result(bytes(handle.goal_id.uuid).hex(), 20)
    assert (told.outcome, told.reason) == ("cancelled", answer.result.error_string), told
    assert rig.peer.result("ahead", 20).outcome == "done"
    assert abs(rig.emu.servo_degrees()["base"] + 30) > 5, "the cancelled goal moved"
    wait_until(lambda: rig.states[-1] == "ready", 10, "ready")


def test_a_goal_waiting_behind_another_move_keeps_its_path_tolerance(rig: Rig) -> None:
    """A second reading: a goal queued at the owner behind a move of another channel was
    judged against the arm's place when it was accepted while the other move carried the
    arm away, and aborted for a path it had not begun (its result said the violation,
    /al5d/result that it was cancelled). Its path starts where the board starts it."""
    rig.recover()
    elbow = rig.emu.servo_degrees()["elbow"]
    away = 10.0 if elbow > 35 else 60.0  # 25 deg or more: far beyond the tolerance
    rig.peer.send("carrier", "move", 1500, elbow=away)
    wait_until(lambda: rig.states[-1] == "moving", 10, "the topic's move running")
    goal = rig.trajectory([(1.0, pose(base=10, elbow=away))])
    goal.path_tolerance = [JointTolerance(name=j, position=0.05) for j in ARM]
    handle = rig.send(rig.fjt, goal)
    assert handle.accepted
    answer = wait_future(handle.get_result_async(), 20)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    told = rig.peer.result(bytes(handle.goal_id.uuid).hex(), 20)
    assert told.outcome == "done", told
    assert rig.peer.result("carrier", 20).outcome == "done"
    assert abs(rig.emu.servo_degrees()["base"] - 10) < 1


def test_a_result_is_kept_after_its_goal_has_left_the_status_messages(rig: Rig) -> None:
    """The status messages carry only recent goals (each message lists every goal kept, so
    a long list costs every goal), while a result stays for a client that asks late."""
    rig.recover()
    lists: list[dict[bytes, int]] = []
    rig.peer.read(
        GoalStatusArray,
        "/arm_controller/follow_joint_trajectory/_action/status",
        lambda msg: lists.append(
            {bytes(s.goal_info.goal_id.uuid): s.status for s in msg.status_list}
        ),
        qos_profile_action_status_default,
    )
    at = rig.emu.servo_degrees()
    here = pose(**{j: round(at[j]) for j in ARM})  # where the arm is: the next test's start
    first = rig.send(rig.fjt, rig.trajectory([(0.3, here)]))
    assert first.accepted
    uuid = bytes(first.goal_id.uuid)
    ended = GoalStatus.STATUS_SUCCEEDED
    wait_until(lambda: any(s.get(uuid) == ended for s in lists), 15, "the first goal's end")

    def gone() -> bool:
        # A status message goes out when a goal changes state: a new goal's lists the
        # goals still kept.
        later = rig.send(rig.fjt, rig.trajectory([(0.2, here)]))
        assert later.accepted
        mine = bytes(later.goal_id.uuid)
        wait_until(lambda: any(mine in s for s in lists), 15, "the later goal's status")
        return uuid not in next(s for s in reversed(lists) if mine in s)

    deadline = time.monotonic() + 60
    while not gone():
        assert time.monotonic() < deadline, "the first goal still in the status messages"
        time.sleep(1.0)
    late = wait_future(first.get_result_async(), 10)
    assert late.status == GoalStatus.STATUS_SUCCEEDED


def test_tolerances_report_a_point_faster_than_the_servos(rig: Rig) -> None:
    rig.recover()
    fast = [(0.05, pose(base=-80)), (0.1, pose(base=80))]  # ~1.5 s of base travel
    goal = rig.trajectory(fast)
    goal.goal_time_tolerance = Duration(sec=0, nanosec=100_000_000)
    # With a time tolerance, judged when the goal comes: rejected, nothing written.
    rig.emu.clear_records()
    handle = rig.send(rig.fjt, goal)
    assert not handle.accepted
    reason = rig.peer.result(bytes(handle.goal_id.uuid).hex()).reason
    assert reason.startswith("servo speed: point "), reason
    assert "its servo does 333 deg/s" in reason and "time tolerance of 100 ms" in reason
    assert only_link_checks(rig), "a rejected goal wrote to the board"
    # -1 s is no limit, as ros2_controllers' controller takes it: accepted.
    goal.goal_time_tolerance = Duration(sec=-1, nanosec=0)
    limitless = rig.send(rig.fjt, goal)
    assert limitless.accepted
    wait_future(limitless.get_result_async(), 15)
    there = wait_future(
        rig.send(rig.fjt, rig.trajectory([(1.0, pose(base=80))])).get_result_async(), 15
    )
    assert there.status == GoalStatus.STATUS_SUCCEEDED
    # Without one, the lateness is reported when the arm gets there.
    goal = rig.trajectory([(0.5, pose(base=70)), (0.55, pose(base=-70)), (3.0, pose(base=80))])
    short = Shortage()
    answer = wait_future(rig.send(rig.fjt, goal).get_result_async(), 15)
    if answer.status == GoalStatus.STATUS_ABORTED and short.excuses(answer.result.error_string):
        # A CI run with four workers on two cores wrote point 1 5 ms late: its servo,
        # 1.7 deg behind, was off the path's 1 deg tolerance. The server kept its word.
        there = rig.send(rig.fjt, rig.trajectory([(1.0, pose(base=80))])).get_result_async()
        assert wait_future(there, 15).status == GoalStatus.STATUS_SUCCEEDED
    else:
        assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
        assert "after its time_from_start" in answer.result.error_string
    goal = rig.trajectory([(0.05, pose(base=-80))])  # from base=80, where the last ended
    goal.path_tolerance = [JointTolerance(name="base", position=0.05)]
    answer = wait_future(rig.send(rig.fjt, goal).get_result_async(), 15)
    assert answer.status == GoalStatus.STATUS_ABORTED
    assert answer.result.error_code == FJT.PATH_TOLERANCE_VIOLATED
    assert "off its path" in answer.result.error_string
    wait_until(lambda: rig.states[-1] == "ready", 10, "ready")


def test_a_late_point_the_next_catches_up_with_is_reported(rig: Rig) -> None:
    rig.recover()
    # Point 1: 60 deg of base in 0.1 s (the servo needs more); point 2 has time to catch up.
    goal = rig.trajectory([(0.5, pose(base=10)), (0.6, pose(base=70)), (3.0, pose())])
    # The servo's lateness is this test's, not the host's: a point written later than its
    # schedule is judged against the path tolerance, and at the servo's full speed (about
    # 330 degrees a second) 1 degree is 3 ms of it: a CI run with four workers wrote point 1
    # 82 ms late, and the goal ended for it, as it should. 90 degrees: a host 270 ms late.
    goal.path_tolerance = [JointTolerance(name="base", position=math.radians(90))]
    answer = wait_future(rig.send(rig.fjt, goal).get_result_async(), 15)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    text = answer.result.error_string
    assert text.startswith("point 1 was reached "), text
    # The last point had the time to catch up: on time, or a busy host's few ms late (seen:
    # 7 ms beside two busy loops).
    last = re.search(r"the last point was reached (\d+) ms after", text)
    assert last is None or float(last.group(1)) < 50, text
    late_ms = float(text.split()[4])
    assert 40 < late_ms < 300, text  # 60 deg of base take about 180 ms


@pytest.mark.parametrize("first_s", [0.0, 0.0003])  # 0.3 ms goes to the board as 0 ms
def test_a_start_point_away_from_the_arm_is_reached_first_and_the_times_count_from_it(
    rig: Rig, first_s: float
) -> None:
    rig.recover()
    home = wait_future(rig.send(rig.fjt, rig.trajectory([(0.5, pose())])).get_result_async(), 10)
    assert home.status == GoalStatus.STATUS_SUCCEEDED
    # Point 0 at time 0 is 50 deg of base away: reached at the servos' speed, then the
    # others keep their times from there, none of them late.
    goal = rig.trajectory([(first_s, pose(base=50)), (0.5, pose(base=40)), (1.0, pose(base=30))])
    # Its check is when the points are reached, not the path: at 20 degrees a second, the
    # default 1 degree is 50 ms of a host's lateness (seen below: 133 ms); 10 degrees, 500.
    goal.path_tolerance = [JointTolerance(name="base", position=math.radians(10))]
    short = Shortage()
    answer = wait_future(rig.send(rig.fjt, goal).get_result_async(), 15)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string
    # Counted from the goal's start instead, points 1 and 2 would come the ~170 ms the
    # servos take for 50 deg late; a busy host may write a step late (seen: 6 ms, 63 ms
    # with four workers on two cores, 133 ms beside two busy loops): what it was short of
    # cores meanwhile is allowed on top.
    text = answer.result.error_string
    late_ms = [float(w) for w in re.findall(r"reached (\d+) ms after", text)]
    assert all(ms < 120 + 1000 * short.s for ms in late_ms), (text, short.s)


def test_a_slow_enough_trajectory_with_tolerances_succeeds(rig: Rig) -> None:
    rig.recover()
    goal = rig.trajectory([(1.0, pose(base=10, elbow=50))])
    goal.goal_tolerance = [JointTolerance(name=j, position=0.01) for j in ARM]
    goal.path_tolerance = [JointTolerance(name=j, position=0.05) for j in ARM]
    goal.goal_time_tolerance = Duration(sec=0, nanosec=100_000_000)
    answer = wait_future(rig.send(rig.fjt, goal).get_result_async(), 15)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result.error_string


@pytest.mark.parametrize("gap_mm", [30.0, 2.0])
def test_the_gripper_command_opens_and_closes_to_a_gap_in_metres(rig: Rig, gap_mm: float) -> None:
    rig.recover()
    goal = GripperCommand.Goal()
    goal.command.position = gap_mm / 1000
    answer = wait_future(rig.send(rig.gripper, goal).get_result_async(), 10)
    assert answer.status == GoalStatus.STATUS_SUCCEEDED
    result = answer.result
    assert result.reached_goal and not result.stalled
    assert abs(result.position - gap_mm / 1000) < 0.0005
    board = rig.config.model.to_urdf(rig.emu.servo_degrees())["gripper"]
    assert abs(board - gap_mm / 1000) < 0.0005


def gripper_goal(gap_m: float) -> GripperCommand.Goal:
    goal = GripperCommand.Goal()
    goal.command.position = gap_m
    return goal


def test_a_new_gripper_goal_preempts_the_one_before_it(rig: Rig) -> None:
    """As ros2_controllers' gripper controller: the newest gripper goal wins, and the one
    before it ends CANCELED, with its one outcome on /al5d/result naming the newer goal
    (they queued before: the first closed the gripper, then the second opened it). Here the
    first waits behind the arm's trajectory, which a gripper goal does not preempt."""
    rig.recover()
    rig.emu.clear_records()
    arm = rig.send(rig.fjt, rig.trajectory([(1.5, pose(base=30))]))
    first = rig.send(rig.gripper, gripper_goal(0.002))
    time.sleep(0.3)  # handed to the owner, where it waits behind the trajectory
    second = rig.send(rig.gripper, gripper_goal(0.030))
    assert arm.accepted and first.accepted and second.accepted
    old = wait_future(first.get_result_async(), 10)
    assert old.status == GoalStatus.STATUS_CANCELED, old.status
    told = rig.peer.result(bytes(first.goal_id.uuid).hex(), 10)
    assert told.outcome == "cancelled", told
    by = bytes(second.goal_id.uuid).hex()
    # As a goal cancelled while it waited is said, on either side of the owner.
    assert (
        told.reason == f"preempted by gripper goal {by} before it ran: the arm did not move for it"
    )
    new = wait_future(second.get_result_async(), 10)
    assert new.status == GoalStatus.STATUS_SUCCEEDED and new.result.reached_goal, new.status
    assert wait_future(arm.get_result_async(), 10).status == GoalStatus.STATUS_SUCCEEDED
    # The first goal never moved the gripper: no line took it below the second's gap.
    channel = rig.config.joints["gripper"].channel
    to_m = rig.config.model.to_urdf
    gaps = [
        to_m({"gripper": rig.config.joints["gripper"].to_deg(t.pulse_us)})["gripper"]
        for move in group_moves(rig.emu.records)
        for t in move.targets
        if t.channel == channel
    ]
    assert gaps and min(gaps) > 0.025, gaps


def test_a_gripper_gap_beyond_its_opening_is_rejected(rig: Rig) -> None:
    rig.recover()
    goal = GripperCommand.Goal()
    goal.command.position = 0.2
    rig.emu.clear_records()
    handle = rig.send(rig.gripper, goal)
    assert not handle.accepted
    refusal = rig.peer.result(bytes(handle.goal_id.uuid).hex())
    assert "outside" in refusal.reason and refusal.instruction == "move", refusal
    assert only_link_checks(rig), "a rejected goal wrote to the board"
