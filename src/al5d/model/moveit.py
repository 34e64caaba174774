"""MoveIt 2 configuration data (SRDF, joint limits, kinematics, controllers) from the model.

Everything comes from the same chain as the URDF, so names and limits agree by
construction. The functions return text or plain dicts ready for yaml.safe_dump;
nothing is written to disk here.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from al5d.model.arm import ArmModel
from al5d.model.chain import Chain
from al5d.model.collisions import DEFAULT_SAMPLES, disabled_pairs
from al5d.model.errors import InvalidInput
from al5d.model.joints import ARM_JOINTS
from al5d.model.urdf import num

ARM_GROUP: Final = "arm"
GRIPPER_GROUP: Final = "gripper"
#: The group of every arm, in a robot of several.
ARMS_GROUP: Final = "arms"
ARM_CONTROLLER: Final = "arm_controller"
GRIPPER_CONTROLLER: Final = "gripper_controller"
KDL_PLUGIN: Final = "kdl_kinematics_plugin/KDLKinematicsPlugin"
#: Seconds a joint takes to reach its top speed in the joint_limits.yaml default: the
#: servos get there in tens of milliseconds, so 0.5 s keeps MoveIt's timing well
#: inside what they can do, and gives its time parameterisation a defined limit.
DEFAULT_RAMP_S: Final = 0.5
#: MoveIt's setup assistant starts at 10 % of the limits; a new arm should too.
DEFAULT_SCALING: Final = 0.1


def _preset_state(
    model: ArmModel, name: str, preset: Mapping[str, float], joints: tuple[str, ...]
) -> dict[str, float]:
    missing = [j for j in joints if j not in preset]
    if missing:
        raise InvalidInput(f"preset {name!r}: missing joint(s) {', '.join(missing)}")
    for j in joints:
        v = preset[j]
        if not (math.isfinite(v) and v in model.ranges.of(j)):
            r = model.ranges.of(j)
            raise InvalidInput(f"preset {name!r}: {j} = {v} is outside {r.lo}..{r.hi}")
    return model.to_urdf({j: preset[j] for j in joints})


@dataclass(frozen=True)
class MoveItArm:
    """One arm of a MoveIt robot: its model, its chain (its frames' and joints' prefixes),
    its presets, and the prefix of its groups and controllers ("" in a robot of one arm:
    groups `arm` and `gripper`; `left_` gives `left_arm`, `left_gripper`)."""

    model: ArmModel
    chain: Chain
    presets: Mapping[str, Mapping[str, float]]
    group_prefix: str = ""

    @property
    def arm_group(self) -> str:
        return self.group_prefix + ARM_GROUP

    @property
    def gripper_group(self) -> str:
        return self.group_prefix + GRIPPER_GROUP

    @property
    def gripper_joint(self) -> str:
        return self.chain.joint_prefix + "gripper"

    @property
    def arm_joints(self) -> list[str]:
        """The arm's joints as the URDF names them, the gripper left out."""
        return [self.chain.joint_prefix + j for j in ARM_JOINTS]


def srdf(
    model: ArmModel,
    chain: Chain,
    presets: Mapping[str, Mapping[str, float]],
    *,
    robot_name: str = "al5d",
    collision_samples: int = DEFAULT_SAMPLES,
) -> str:
    """The SRDF: groups `arm` (chain base_link -> tool0) and `gripper`, the presets as
    named states (arm joints in group `arm`, the gripper in `gripper`, which also gets
    `open` and `closed`), the end effector, and the disabled collision pairs."""
    arm = MoveItArm(model, chain, presets)
    return srdf_of_arms([arm], robot_name=robot_name, collision_samples=collision_samples)


def srdf_of_arms(
    arms: Sequence[MoveItArm],
    *,
    robot_name: str = "al5d",
    collision_samples: int = DEFAULT_SAMPLES,
) -> str:
    """The SRDF of one robot of `arms`: each arm's groups, named states and end effector as
    `srdf` gives one arm's (behind its group prefix); with several arms, group `arms` of
    every arm's group, and a named state of it for each preset they all have. Collisions
    are disabled within each arm only: one arm's links against another's are checked."""
    robot = ET.Element("robot", name=robot_name)

    def state(group: str, name: str, values: Mapping[str, float]) -> None:
        element = ET.SubElement(robot, "group_state", name=name, group=group)
        for joint, value in values.items():
            ET.SubElement(element, "joint", name=joint, value=num(value))

    for arm in arms:
        group = ET.SubElement(robot, "group", name=arm.arm_group)
        ET.SubElement(group, "chain", base_link=arm.chain.root, tip_link=arm.chain.tool)
        hand = ET.SubElement(robot, "group", name=arm.gripper_group)
        ET.SubElement(hand, "joint", name=arm.gripper_joint)
        named = arm.chain.named
        for name, preset in arm.presets.items():
            state(arm.arm_group, name, named(_preset_state(arm.model, name, preset, ARM_JOINTS)))
        gm = arm.model.gripper_map
        state(arm.gripper_group, "open", {arm.gripper_joint: gm.gap_from_deg(gm.open_deg)})
        state(arm.gripper_group, "closed", {arm.gripper_joint: gm.gap_from_deg(gm.closed_deg)})
        for name, preset in arm.presets.items():
            if name not in ("open", "closed"):
                gripper = _preset_state(arm.model, name, preset, ("gripper",))
                state(arm.gripper_group, name, named(gripper))
        ET.SubElement(
            robot,
            "end_effector",
            name=arm.group_prefix + "hand",
            parent_link=arm.chain.tool,
            group=arm.gripper_group,
            parent_group=arm.arm_group,
        )
    if len(arms) > 1:
        every = ET.SubElement(robot, "group", name=ARMS_GROUP)
        for arm in arms:
            ET.SubElement(every, "group", name=arm.arm_group)
        shared = [p for p in arms[0].presets if all(p in arm.presets for arm in arms)]
        for name in shared:
            values: dict[str, float] = {}
            for arm in arms:
                preset = _preset_state(arm.model, name, arm.presets[name], ARM_JOINTS)
                values |= arm.chain.named(preset)
            state(ARMS_GROUP, name, values)
    for arm in arms:
        for pair in disabled_pairs(arm.chain, samples=collision_samples):
            ET.SubElement(
                robot, "disable_collisions", link1=pair.link1, link2=pair.link2, reason=pair.reason
            )
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def joint_limits(chain: Chain, *, ramp_s: float | None = DEFAULT_RAMP_S) -> dict[str, Any]:
    """joint_limits.yaml: every movable joint's velocity limit from the URDF (the servo
    speeds); acceleration = velocity / ramp_s, or no acceleration limit if ramp_s is None."""
    return joint_limits_of([chain], ramp_s=ramp_s)


def joint_limits_of(
    chains: Sequence[Chain], *, ramp_s: float | None = DEFAULT_RAMP_S
) -> dict[str, Any]:
    """`joint_limits` of every arm's chain in one file."""
    if ramp_s is not None and not (math.isfinite(ramp_s) and ramp_s > 0):
        raise InvalidInput(f"ramp_s must be finite and > 0, or None, not {ramp_s}")
    limits: dict[str, Any] = {}
    for chain in chains:
        for name in chain.movable:
            lim = chain.joint(name).limit
            assert lim is not None  # every movable joint of the chain has one
            limits[name] = {
                "has_velocity_limits": True,
                "max_velocity": lim.velocity,
                "has_acceleration_limits": ramp_s is not None,
                "max_acceleration": 0.0 if ramp_s is None else lim.velocity / ramp_s,
            }
    return {
        "default_velocity_scaling_factor": DEFAULT_SCALING,
        "default_acceleration_scaling_factor": DEFAULT_SCALING,
        "joint_limits": limits,
    }


def kinematics(
    *,
    position_only_ik: bool = True,
    timeout_s: float = 0.05,
    resolution: float = 0.005,
    groups: Sequence[str] = (ARM_GROUP,),
) -> dict[str, Any]:
    """kinematics.yaml: KDL for group `arm` (or each arm's group of `groups`).

    Position-only by default: five joints cannot meet an arbitrary 6-D pose, so
    with full poses KDL fails on almost every goal an interactive marker gives.
    """
    return {
        group: {
            "kinematics_solver": KDL_PLUGIN,
            "kinematics_solver_search_resolution": resolution,
            "kinematics_solver_timeout": timeout_s,
            "position_only_ik": position_only_ik,
        }
        for group in groups
    }


def controllers(arms: Sequence[MoveItArm] | None = None) -> dict[str, Any]:
    """moveit_controllers.yaml for MoveIt's simple controller manager and our two actions;
    with `arms`, each arm's two, named behind its group prefix (`left_arm_controller`) and
    commanding its joints (without: one arm, the model's joint names)."""
    names: list[str] = []
    manager: dict[str, Any] = {"controller_names": names}
    for prefix, arm_joints, gripper in (
        [(a.group_prefix, a.arm_joints, a.gripper_joint) for a in arms]
        if arms
        else [("", list(ARM_JOINTS), "gripper")]
    ):
        names += [prefix + ARM_CONTROLLER, prefix + GRIPPER_CONTROLLER]
        manager[prefix + ARM_CONTROLLER] = {
            "type": "FollowJointTrajectory",
            "action_ns": "follow_joint_trajectory",
            "default": True,
            "joints": arm_joints,
        }
        manager[prefix + GRIPPER_CONTROLLER] = {
            "type": "GripperCommand",
            "action_ns": "gripper_cmd",
            "default": True,
            "joints": [gripper],
        }
    return {
        "moveit_controller_manager": (
            "moveit_simple_controller_manager/MoveItSimpleControllerManager"
        ),
        "moveit_simple_controller_manager": manager,
    }


def moveit_config(
    model: ArmModel,
    chain: Chain,
    presets: Mapping[str, Mapping[str, float]],
    *,
    robot_name: str = "al5d",
) -> dict[str, Any]:
    """All four, keyed by the file name a MoveIt config package gives them."""
    return moveit_config_of([MoveItArm(model, chain, presets)], robot_name=robot_name)


def moveit_config_of(arms: Sequence[MoveItArm], *, robot_name: str = "al5d") -> dict[str, Any]:
    """`moveit_config` of a robot of several arms (or one)."""
    return {
        f"{robot_name}.srdf": srdf_of_arms(arms, robot_name=robot_name),
        "joint_limits.yaml": joint_limits_of([arm.chain for arm in arms]),
        "kinematics.yaml": kinematics(groups=[arm.arm_group for arm in arms]),
        "moveit_controllers.yaml": controllers(arms),
    }


# --- ros2_control: the topic-based hardware between the controllers and the server ---

#: ros2_control's controllers take names of their own: the server keeps serving its
#: `arm_controller` and `gripper_controller` actions in both set-ups, and two action
#: servers under one name would each take some of MoveIt's goals.
ROS2_ARM_CONTROLLER: Final = "joint_trajectory_controller"
ROS2_GRIPPER_CONTROLLER: Final = "gripper_action_controller"
#: ros-controls' topic_based_hardware_interfaces: publishes the controllers' commands as
#: sensor_msgs/JointState and reads the state from another JointState topic.
TOPIC_HARDWARE: Final = "joint_state_topic_hardware_interface/JointStateTopicSystem"
JOINT_COMMANDS_TOPIC: Final = "joint_commands"
JOINT_STATES_TOPIC: Final = "joint_states"
#: Cartesian limits for MoveIt's Pilz planner, well inside what a desk arm's servos do;
#: a request's scaling factors scale them further.
PILZ_LIMITS: Final = {
    "max_trans_vel": 0.2,
    "max_trans_acc": 0.5,
    "max_trans_dec": -0.5,
    "max_rot_vel": 1.0,
}


def topic(namespace: str, name: str) -> str:
    """The absolute name of the server's topic `name` in `namespace` ("" none)."""
    ns = namespace.strip("/")
    return f"/{ns}/{name}" if ns else f"/{name}"


def initial_positions(
    model: ArmModel, chain: Chain, presets: Mapping[str, Mapping[str, float]]
) -> dict[str, Any]:
    """initial_positions.yaml: ros2_control's state until the first joint state arrives.

    The `park` preset where there is one, since the server parks the arm when it starts;
    otherwise the middle of each joint's range."""
    keys = [chain.key(j) for j in chain.movable]
    if "park" in presets:
        values = _preset_state(model, "park", presets["park"], (*ARM_JOINTS, "gripper"))
    else:
        middle = {j: (model.ranges.of(j).lo + model.ranges.of(j).hi) / 2 for j in keys}
        values = model.to_urdf(middle)
    # + 0.0: no negative zero in the file
    return {"initial_positions": chain.named({j: float(values[j]) + 0.0 for j in keys})}


def command_threshold(model: ArmModel, us_per_deg: Mapping[str, float]) -> float:
    """The topic hardware's `trigger_joint_command_threshold`: half a microsecond of pulse
    of the finest joint, in URDF units (radians, the gripper's metres).

    The hardware sends a command only when it differs from the state by more than this
    (summed over the joints): a command that moves one joint by a single microsecond of
    pulse must go. The board places a servo in whole microseconds, so at rest the state
    may sit a fraction of one off the command and the hardware sends the command again at
    every update; the server writes nothing for it (where the arm is already)."""
    return min(
        model.gripper_map.metres_per_deg * 0.5 / abs(scale)
        if joint == "gripper"
        else math.radians(0.5 / abs(scale))
        for joint, scale in us_per_deg.items()
    )


def ros2_controllers(chain: Chain, *, update_rate_hz: int, namespace: str = "") -> dict[str, Any]:
    """ros2_controllers.yaml: the controller manager, a joint trajectory controller for the
    arm's joints and a gripper action controller for the gap.

    No joint_state_broadcaster: the server publishes /joint_states itself, and the
    topic hardware reads its state from there; a broadcaster would put a second,
    echoed copy on the topic the hardware reads. The parameter sections name each node
    with its namespace, so that they apply to the nodes of an arm in one."""
    prefix = f"/{namespace.strip('/')}/" if namespace.strip("/") else ""
    gripper = chain.joint_prefix + "gripper"
    arm = [j for j in chain.movable if j != gripper]
    return {
        f"{prefix}controller_manager": {
            "ros__parameters": {
                "update_rate": update_rate_hz,
                ROS2_ARM_CONTROLLER: {
                    "type": "joint_trajectory_controller/JointTrajectoryController"
                },
                ROS2_GRIPPER_CONTROLLER: {"type": "position_controllers/GripperActionController"},
            }
        },
        f"{prefix}{ROS2_ARM_CONTROLLER}": {
            "ros__parameters": {
                "joints": arm,
                "command_interfaces": ["position"],
                "state_interfaces": ["position"],
            }
        },
        f"{prefix}{ROS2_GRIPPER_CONTROLLER}": {"ros__parameters": {"joint": gripper}},
    }


def ros2_control_controllers(arm: MoveItArm | None = None) -> dict[str, Any]:
    """MoveIt's controllers when ros2_control drives the arm: its two controllers' actions,
    through the same simple controller manager."""
    config = controllers([arm] if arm else None)
    manager = config["moveit_simple_controller_manager"]
    manager["controller_names"] = [ROS2_ARM_CONTROLLER, ROS2_GRIPPER_CONTROLLER]
    manager[ROS2_ARM_CONTROLLER] = manager.pop(ARM_CONTROLLER)
    manager[ROS2_GRIPPER_CONTROLLER] = manager.pop(GRIPPER_CONTROLLER)
    return config


def pilz_cartesian_limits() -> dict[str, Any]:
    """pilz_cartesian_limits.yaml (floats throughout, as MoveIt reads doubles)."""
    return {"cartesian_limits": {k: float(v) for k, v in PILZ_LIMITS.items()}}


def ros2_control_xacro(chain: Chain, *, robot_name: str = "al5d") -> str:
    """`<robot>.ros2_control.xacro`: a macro for the `<ros2_control>` tag with the topic
    hardware, every joint that /joint_states carries commanded by position.

    The hardware's topics and threshold are the macro's parameters, so that the including
    xacro (and a user's xacro arguments) choose them."""
    xacro_ns = "http://www.ros.org/wiki/xacro"
    ET.register_namespace("xacro", xacro_ns)
    robot = ET.Element("robot")
    macro = ET.SubElement(
        robot,
        f"{{{xacro_ns}}}macro",
        name=f"{robot_name}_ros2_control",
        params="name initial_positions_file joint_commands_topic joint_states_topic "
        "trigger_joint_command_threshold",
    )
    ET.SubElement(
        macro,
        f"{{{xacro_ns}}}property",
        name="initial_positions",
        value="${xacro.load_yaml(initial_positions_file)['initial_positions']}",
    )
    control = ET.SubElement(macro, "ros2_control", name="${name}", type="system")
    hardware = ET.SubElement(control, "hardware")
    ET.SubElement(hardware, "plugin").text = TOPIC_HARDWARE
    for param in ("joint_commands_topic", "joint_states_topic", "trigger_joint_command_threshold"):
        ET.SubElement(hardware, "param", name=param).text = f"${{{param}}}"
    for name in chain.movable:
        joint = ET.SubElement(control, "joint", name=name)
        ET.SubElement(joint, "command_interface", name="position")
        state = ET.SubElement(joint, "state_interface", name="position")
        ET.SubElement(
            state, "param", name="initial_value"
        ).text = f"${{initial_positions['{name}']}}"
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def robot_xacro(
    *,
    robot_name: str,
    namespace: str,
    threshold: float,
) -> str:
    """`<robot>.urdf.xacro`: the URDF with the ros2_control tag, as the Setup Assistant's
    modified URDF is made: the plain URDF and the control macro included beside it, its
    topics those of the server in `namespace`, each overridable as a xacro argument."""
    xacro_ns = "http://www.ros.org/wiki/xacro"
    ET.register_namespace("xacro", xacro_ns)
    robot = ET.Element("robot", name=robot_name)
    args = {
        "initial_positions_file": "initial_positions.yaml",
        "joint_commands_topic": topic(namespace, JOINT_COMMANDS_TOPIC),
        "joint_states_topic": topic(namespace, JOINT_STATES_TOPIC),
        "trigger_joint_command_threshold": num(threshold),
    }
    for name, default in args.items():
        ET.SubElement(robot, f"{{{xacro_ns}}}arg", name=name, default=default)
    ET.SubElement(robot, f"{{{xacro_ns}}}include", filename=f"{robot_name}.urdf")
    ET.SubElement(robot, f"{{{xacro_ns}}}include", filename=f"{robot_name}.ros2_control.xacro")
    ET.SubElement(
        robot,
        f"{{{xacro_ns}}}{robot_name}_ros2_control",
        {"name": "TopicBasedSystem", **{name: f"$(arg {name})" for name in args}},
    )
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
