"""The joints' prefix of an arm (issue 46: several arms in one MoveIt robot):
`server.joint_prefix`, the namespace's by default, validated as every setting; the URDF,
the joint states' names, the trajectories' and the joint commands' all carry it."""

from __future__ import annotations

import io
import math

import pytest
import yourdfpy
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from al5d.app.moveit import arm_chain
from al5d.arm.config import ArmConfig, ConfigError, default_joint_prefix, with_changes
from al5d.model import urdf_from_chain, urdf_of_arms
from al5d.model.errors import InvalidInput
from al5d.model.transforms import Mount
from al5d.ros import params
from al5d.ros.convert import joint_command_from_message, trajectory_from_message


def test_the_prefix_is_the_namespaces_unless_one_is_given(config: ArmConfig) -> None:
    assert config.server.joint_name_prefix == ""
    assert default_joint_prefix("left") == default_joint_prefix("/left/") == "left_"
    assert default_joint_prefix("/lab/left") == "lab_left_"
    left = with_changes(config, {"server.namespace": "left"})
    assert left.server.joint_name_prefix == "left_"
    assert left.server.joint_prefix_in("right") == "right_"
    given = with_changes(config, {"server.namespace": "left", "server.joint_prefix": "a1_"})
    assert given.server.joint_name_prefix == given.server.joint_prefix_in("right") == "a1_"
    none = with_changes(config, {"server.namespace": "left", "server.joint_prefix": ""})
    assert none.server.joint_name_prefix == ""


@pytest.mark.parametrize("bad", ["left-", "1left_", "left/", "a b", "_left"])
def test_a_bad_prefix_is_refused_naming_its_key(config: ArmConfig, bad: str) -> None:
    with pytest.raises(ConfigError, match=r"server\.joint_prefix: joint_prefix"):
        with_changes(config, {"server.joint_prefix": bad})
    with pytest.raises(ConfigError, match=r"ROS parameters: server\.joint_prefix"):
        params.resolve({"server.joint_prefix": bad}, params.Flags(), base=config)
    with pytest.raises(ConfigError, match=r"server\.joint_prefix"):
        params.resolve({"server.joint_prefix": 5}, params.Flags(), base=config)


def test_the_parameter_says_the_prefix_in_use(config: ArmConfig) -> None:
    settings = params.resolve({}, params.Flags(namespace="left"), base=config)
    assert settings.values()["server.joint_prefix"] == "left_"
    settings = params.resolve(
        {"server.joint_prefix": ""}, params.Flags(namespace="left"), base=config
    )
    assert settings.values()["server.joint_prefix"] == ""


def test_the_urdf_names_every_joint_with_the_prefix(config: ArmConfig) -> None:
    left = with_changes(config, {"server.namespace": "left"})
    chain = arm_chain(left)
    text = urdf_from_chain(chain, "al5d", Mount("world", (0.0, 0.3, 0.0), (0.0, 0.0, 0.0)))
    robot = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False)
    assert robot.validate()
    names = [j.name for j in robot.robot.joints]
    assert names and all(n.startswith("left_") for n in names), names
    assert "left_mount" in names and "left_base" in names
    mimics = {j.mimic.joint for j in robot.robot.joints if j.mimic is not None}
    assert mimics == {"left_gripper"}
    assert [j for j in robot.actuated_joint_names] == list(chain.movable)
    # The model's values, keyed by the model's names, place the prefixed chain.
    values = config.model.to_urdf(dict(config.presets["ready"]))
    robot.update_cfg(chain.named(values))
    from al5d.model import tool_pose

    ours = tool_pose(chain, values).translation
    theirs = robot.get_transform("left/tool0", "left/base_link")[:3, 3]
    assert math.dist(ours, tuple(theirs)) < 1e-9


def test_two_arms_in_one_urdf_share_no_name(config: ArmConfig) -> None:
    left = arm_chain(with_changes(config, {"server.namespace": "left"}))
    right = arm_chain(with_changes(config, {"server.namespace": "right"}))
    mounts = [Mount("world", (0.0, y, 0.0), (0.0, 0.0, 0.0)) for y in (0.3, -0.3)]
    text = urdf_of_arms(list(zip((left, right), mounts, strict=True)))
    robot = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False)
    assert robot.validate() and robot.base_link == "world"
    joints = [j.name for j in robot.robot.joints]
    assert len(joints) == len(set(joints)) == 2 * (len(left.joints) + 1)
    same = arm_chain(with_changes(config, {"server.namespace": "left"}))
    with pytest.raises(InvalidInput, match="given twice"):
        urdf_of_arms([(left, mounts[0]), (same, mounts[1])])
    with pytest.raises(InvalidInput, match="each needs a mount"):
        urdf_of_arms([(left, mounts[0]), (right, None)])


def _trajectory(names: list[str], positions: list[float]) -> JointTrajectory:
    msg = JointTrajectory(joint_names=names)
    point = JointTrajectoryPoint(positions=positions)
    point.time_from_start.nanosec = 500_000_000
    msg.points = [point]
    return msg


def test_trajectories_and_joint_commands_name_the_arms_joints(config: ArmConfig) -> None:
    model = config.model
    elbow = model.to_urdf({"elbow": 60.0})["elbow"]
    got = trajectory_from_message(_trajectory(["left_elbow"], [elbow]), model, prefix="left_")
    assert not isinstance(got, str)
    assert got.points[0].joints == (("elbow", pytest.approx(60.0)),)
    # A name without the arm's prefix is none of its joints, named in the sender's words.
    refused = trajectory_from_message(_trajectory(["elbow"], [elbow]), model, prefix="left_")
    assert isinstance(refused, str) and "'elbow' is not a joint of this arm" in refused
    assert "left_base" in refused
    far = trajectory_from_message(_trajectory(["left_elbow"], [9.0]), model, prefix="left_")
    assert isinstance(far, str) and far.startswith("point 0: left_elbow: 9 rad is outside")
    finger = trajectory_from_message(
        _trajectory(["left_gripper_left"], [0.0]), model, prefix="left_"
    )
    assert isinstance(finger, str) and "command left_gripper" in finger

    command = JointState(name=["left_base", "left_elbow"], position=[0.1, elbow])
    got = joint_command_from_message(command, model, prefix="left_")
    assert not isinstance(got, str) and dict(got.joints)["elbow"] == pytest.approx(60.0)
    other = JointState(name=["right_base"], position=[0.1])
    refused = joint_command_from_message(other, model, prefix="left_")
    assert isinstance(refused, str) and "'right_base' is not a joint of this arm" in refused
    # Without a prefix, the model's names as ever.
    plain = joint_command_from_message(JointState(name=["base"], position=[0.1]), model)
    assert not isinstance(plain, str)
