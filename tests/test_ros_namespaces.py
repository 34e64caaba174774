"""Several arms side by side (issue 14): two servers in two namespaces, each driven alone."""

from __future__ import annotations

import re
import signal
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectoryPoint

from al5d import exits
from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.ros.client import Client
from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATCHED
from al5d.ros.robot import QOS_TF_STATIC
from al5d.ssc32u.emulator import Emulator
from al5d_rig.armrig import group_moves
from al5d_rig.proc import Proc, patient_config
from al5d_rig.rospeer import LockedActionClient, Peer, first_goal_answer, wait_future, wait_until
from al5d_rig.trajectories import multi_dof_goal, nan_gripper_goal


@dataclass
class Arm:
    name: str
    emu: Emulator
    proc: Proc
    peer: Peer


@pytest.fixture(scope="module")
def arms(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[list[Arm]]:
    made: list[Arm] = []
    try:
        for name in ("left", "right"):
            folder = tmp_path_factory.mktemp(name)
            link = folder / "ssc32u"
            emu = Emulator(config, link=link).start()
            # The emulators are threads of this busy process: the patient answer timeout.
            if name == "left":  # by the option
                where = ["--namespace", name, "--config", patient_config()]
            else:  # by the configuration's key, `server.namespace`
                data = yaml.safe_load(Path(patient_config()).read_text())
                data["server"]["namespace"] = name
                (folder / "arm.yaml").write_text(yaml.safe_dump(data))
                where = ["--config", str(folder / "arm.yaml")]
            proc = Proc("serve", "--port", str(link), *where, "--log-level", "INFO")
            made.append(Arm(name, emu, proc, Peer(name=f"al5d_{name}_peer", namespace=name)))
        for arm in made:
            arm.proc.err.wait_for("STATE: ready", 30)
            arm.peer.wait_for_server()
        yield made
    finally:
        for arm in made:
            arm.peer.close()
            arm.proc.kill()
            arm.emu.close()


def test_names_follow_ros_conventions() -> None:
    assert Names.of(None).instruction == "/al5d/instruction"
    assert Names.of("").joint_states == "/joint_states"
    assert Names.of("/").follow_joint_trajectory == "/arm_controller/follow_joint_trajectory"
    left = Names.of("left")
    assert left.instruction == "/left/al5d/instruction"
    assert sorted(left.services) == ["/left/al5d/release", "/left/al5d/shutdown", "/left/al5d/stop"]
    assert left.joint_states == "/left/joint_states"
    assert left.robot_description == "/left/robot_description"
    assert left.gripper_command == "/left/gripper_controller/gripper_cmd"
    assert left.frame_prefix == "left/"
    assert Names.of("/lab/left/").frame_prefix == "lab/left/"
    for bad in ("1arm", "left arm", "a//b", "a-b"):
        with pytest.raises(ValueError, match="namespace"):
            Names.of(bad)


def done(arm: Arm, ident: str) -> bool:
    result = arm.peer.result(ident)
    assert result.outcome == "done", (arm.name, result.reason, arm.proc.err.drain(0.5)[-20:])
    return True


def test_each_server_moves_its_own_arm_only(arms: list[Arm]) -> None:
    left, right = arms
    for arm in arms:
        arm.emu.clear_records()
    left.peer.send("l-1", "move", time_ms=300, base=40)
    assert done(left, "l-1")
    assert len(group_moves(left.emu.records)) == 1 and group_moves(right.emu.records) == []
    right.peer.send("r-1", "move", time_ms=300, base=-40)
    assert done(right, "r-1")
    assert len(group_moves(left.emu.records)) == 1 and len(group_moves(right.emu.records)) == 1
    assert abs(left.emu.servo_degrees()["base"] - 40) < 0.5
    assert abs(right.emu.servo_degrees()["base"] + 40) < 0.5
    # A stop for one arm leaves the other free.
    assert left.peer.trigger("stop").success
    right.peer.send("r-2", "move", time_ms=200, base=0)
    assert done(right, "r-2")
    assert left.peer.trigger("release").success


def test_each_arm_has_its_joint_states_controllers_and_prefixed_frames(arms: list[Arm]) -> None:
    for arm in arms:
        wait_until(lambda a=arm: a.peer.joint_states, 5, f"{arm.name} joint states")
        # Its joints carry its namespace's prefix: two arms' names never meet in one robot.
        joints = list(arm.peer.joint_states[-1].name)
        assert joints and all(j.startswith(f"{arm.name}_") for j in joints), joints
        names = arm.peer.names
        assert arm.peer.node.count_publishers(names.robot_description) == 1
        client = arm.peer.node.create_client(
            FollowJointTrajectory.Impl.SendGoalService,
            f"{names.follow_joint_trajectory}/_action/send_goal",
        )
        assert client.wait_for_service(timeout_sec=30)
        arm.peer.destroy(client)
    frames: set[str] = set()
    sub = arms[0].peer.node.create_subscription(
        TFMessage, "/tf", lambda m: frames.update(t.child_frame_id for t in m.transforms), 100
    )
    try:
        wait_until(
            lambda: {f.split("/")[0] for f in frames} == {"left", "right"}, 30, "both arms' frames"
        )
    finally:
        arms[0].peer.destroy(sub)
    assert all(f.startswith(("left/", "right/")) for f in frames)


def test_the_command_line_client_takes_the_namespace(arms: list[Arm], tmp_path: Path) -> None:
    left, right = arms
    for arm in arms:
        arm.emu.clear_records()
    sent = Proc("send", "--namespace", "right", "move", "elbow=70", "time=200")
    assert sent.wait(30) == 0, sent.err.drain()
    assert group_moves(right.emu.records) and group_moves(left.emu.records) == []
    lost = Proc("send", "--namespace", "middle", "--wait", "1", "ready")
    assert lost.wait(30) == exits.NO_SERVER
    said = "\n".join(lost.err.drain())
    assert "/middle/al5d/instruction" in said
    # Issue 46: the servers it can see under other names are named; neither is offered in
    # its place (an outside try: "--namespace left?" for an arm `right` that was down).
    assert re.search(r"found /left and /right$", said, re.MULTILINE), said
    assert "--namespace left?" not in said, said
    typo = Proc("send", "--namespace", "rigth", "--wait", "1", "ready")
    assert typo.wait(30) == exits.NO_SERVER
    said = "\n".join(typo.err.drain())
    assert "found /left and /right: --namespace right?" in said, said


@pytest.mark.parametrize("via", ["ros", "lane"])
def test_with_only_namespaced_servers_a_client_names_them(arms: list[Arm], via: str) -> None:
    """Over ROS 2 the graph shows them, over the lane this machine's lanes do."""
    lost = Proc("send", "--via", via, "--wait", "3", "ready")
    assert lost.wait(30) == exits.NO_SERVER
    said = "\n".join(lost.err.drain())
    assert "found /left and /right: name one with --namespace" in said, said


@pytest.mark.parametrize("what", ["stop", "ready"])
def test_a_client_that_finds_no_server_names_the_others_while_it_still_looks(
    arms: list[Arm], what: str
) -> None:
    """A stop meant for another arm is said so at once, not when it gives up (an outside
    try: `al5d send stop` with only /left and /right running waited 10 s to name them)."""
    lost = Proc("send", "--via", "ros", "--wait", "120", what)
    try:
        said = lost.err.wait_for("found /left and /right: name one with --namespace", 60)
        assert lost.popen.poll() is None, said  # said while it looks on
        assert "still" in said, said
    finally:
        lost.popen.send_signal(signal.SIGINT)
        lost.wait(30)
        lost.kill()


def test_a_check_with_no_server_at_its_name_names_the_ones_here(
    arms: list[Arm], tmp_path: Path
) -> None:
    """`al5d run --check` judges against the shipped configuration where no server is at
    its name, and names the servers here whose configuration may be the one meant."""
    steps = tmp_path / "steps.txt"
    steps.write_text("ready\n")
    checked = Proc("run", "--check", str(steps))
    assert checked.wait(60) == exits.DONE
    said = "\n".join(checked.out.drain())
    assert "shipped configuration (none on this machine's lane; found /left and /right" in said
    named = Proc("run", "--check", "--namespace", "left", str(steps))
    assert named.wait(60) == exits.DONE
    assert "none the server would refuse" in "\n".join(named.out.drain())


def test_another_arm_is_offered_only_for_a_typo() -> None:
    """A namespace that is not found is taken for another only where it is that one
    mistyped; one a letter or digit apart is another arm, which may be down (a review:
    `arm1` offered `arm2`, `lab_left` offered `lab/left`)."""
    from al5d.ros.answers import _which

    assert _which("/rigth", ["/left", "/right"]) == ": --namespace right?"
    assert _which("/RIGHT", ["/left", "/right"]) == ": --namespace right?"
    for asked, found in [
        ("/arm1", ["/arm2"]),
        ("/lab_left", ["/lab/left"]),
        ("/left", ["/left2"]),
        ("/right", ["/left"]),
        ("/middle", ["/left", "/right"]),
    ]:
        assert _which(asked, found) == "", (asked, found)
    assert _which("/", ["/left"]) == ": --namespace left?"  # no arm named: the only one
    assert _which("/", ["/left", "/right"]) == ": name one with --namespace"


def test_a_web_view_with_no_server_at_its_name_names_the_ones_it_sees(arms: list[Arm]) -> None:
    """As `al5d send` does: an outside try's page waited with no word of /left and /right."""
    web = Proc("web", "--port", "0")
    try:
        said = web.err.wait_for("no al5d server heard at /al5d/instruction yet", 60)
        assert "found /left and /right: name one with --namespace" in said, said
    finally:
        web.popen.send_signal(signal.SIGTERM)
        web.wait(60)
        web.kill()


def test_each_arms_control_actions_move_that_arm_only(arms: list[Arm], config: ArmConfig) -> None:
    left, right = arms
    for arm in arms:
        arm.emu.clear_records()
    fjt = LockedActionClient(
        left.peer.node, FollowJointTrajectory, left.peer.names.follow_joint_trajectory
    )
    gripper = LockedActionClient(right.peer.node, GripperCommand, right.peer.names.gripper_command)
    try:
        assert fjt.wait_for_server(timeout_sec=10) and gripper.wait_for_server(timeout_sec=10)
        first_goal_answer(fjt, multi_dof_goal())
        first_goal_answer(gripper, nan_gripper_goal())
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = ["left_elbow"]  # the namespace's joint prefix
        elbow = config.model.to_urdf({"elbow": 60.0})["elbow"]
        goal.trajectory.points = [
            JointTrajectoryPoint(positions=[elbow], time_from_start=Duration(nanosec=300_000_000))
        ]
        handle = wait_future(fjt.send_goal_async(goal))
        assert handle.accepted, left.peer.result(bytes(handle.goal_id.uuid).hex()).reason
        assert wait_future(handle.get_result_async(), 10).status == GoalStatus.STATUS_SUCCEEDED
        assert len(group_moves(left.emu.records)) == 1 and group_moves(right.emu.records) == []
        close = GripperCommand.Goal()
        close.command.position = 0.005
        handle = wait_future(gripper.send_goal_async(close))
        assert wait_future(handle.get_result_async(), 10).status == GoalStatus.STATUS_SUCCEEDED
        assert len(group_moves(left.emu.records)) == 1 and len(group_moves(right.emu.records)) == 1
        assert abs(left.emu.servo_degrees()["elbow"] - 60) < 0.5
        # The other arm's joints, or none's, are no joints of the left arm: rejected.
        for names in (["right_elbow"], ["elbow"]):
            goal.trajectory.joint_names = names
            handle = wait_future(fjt.send_goal_async(goal))
            assert not handle.accepted
        reason = left.peer.result(bytes(handle.goal_id.uuid).hex()).reason
        assert "'elbow' is not a joint of this arm" in reason, reason
        assert len(group_moves(left.emu.records)) == 1
    finally:
        left.peer.destroy(fjt, gripper)


def test_the_sequence_runner_and_the_python_client_take_the_namespace(
    arms: list[Arm], tmp_path: Path
) -> None:
    left, right = arms
    for arm in arms:
        arm.emu.clear_records()
    seq = tmp_path / "left.seq"
    seq.write_text("move wrist=20 time=200\nmove wrist=0 time=200\n")
    ran = Proc("run", "--namespace", "left", str(seq))
    assert ran.wait(30) == 0, ran.err.drain()
    assert len(group_moves(left.emu.records)) == 2 and group_moves(right.emu.records) == []
    client = Client(namespace="right")
    try:
        client.wait_for_server(10)
        move = ins.move(wrist=-20, time_ms=200)
        client.send(move)
        outcome = client.outcome(move.id, 10)
        assert outcome is not None and outcome.ok
    finally:
        client.close()
    assert len(group_moves(left.emu.records)) == 2 and len(group_moves(right.emu.records)) == 1


def test_each_arms_description_and_static_frames_carry_its_prefix(arms: list[Arm]) -> None:
    peer = arms[0].peer  # one listener for both: late joiners of latched topics
    urdfs: dict[str, str] = {}
    static: set[str] = set()
    subs = [
        peer.node.create_subscription(
            String,
            arm.peer.names.robot_description,
            lambda m, name=arm.name: urdfs.__setitem__(name, m.data),
            QOS_LATCHED,
        )
        for arm in arms
    ]
    subs.append(
        peer.node.create_subscription(
            TFMessage,
            "/tf_static",
            lambda m: static.update(
                f for t in m.transforms for f in (t.header.frame_id, t.child_frame_id)
            ),
            QOS_TF_STATIC,
        )
    )
    try:
        wait_until(lambda: len(urdfs) == 2, 30, "both robot descriptions")
        wait_until(
            lambda: {f.split("/")[0] for f in static} >= {"left", "right"}, 30, "static frames"
        )
    finally:
        peer.destroy(*subs)
    for name, urdf in urdfs.items():
        other = "right" if name == "left" else "left"
        assert f'<link name="{name}/base_link"' in urdf and f'"{name}/tool0"' in urdf
        assert f"{other}/" not in urdf
    assert all(f.startswith(("left/", "right/")) for f in static)
