"""MoveIt 2 configuration data (SRDF, joint limits, kinematics, controllers) from the model.

Everything comes from the same chain as the URDF, so names and limits agree by
construction. The functions return text or plain dicts ready for yaml.safe_dump;
nothing is written to disk here.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from typing import Any, Final

from al5d.model.arm import ArmModel
from al5d.model.chain import Chain
from al5d.model.collisions import DEFAULT_SAMPLES, disabled_pairs
from al5d.model.errors import InvalidInput
from al5d.model.joints import ARM_JOINTS
from al5d.model.urdf import num

ARM_GROUP: Final = "arm"
GRIPPER_GROUP: Final = "gripper"
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
    robot = ET.Element("robot", name=robot_name)
    arm = ET.SubElement(robot, "group", name=ARM_GROUP)
    ET.SubElement(arm, "chain", base_link=chain.root, tip_link=chain.tool)
    hand = ET.SubElement(robot, "group", name=GRIPPER_GROUP)
    ET.SubElement(hand, "joint", name="gripper")

    def state(group: str, name: str, values: Mapping[str, float]) -> None:
        element = ET.SubElement(robot, "group_state", name=name, group=group)
        for joint, value in values.items():
            ET.SubElement(element, "joint", name=joint, value=num(value))

    for name, preset in presets.items():
        state(ARM_GROUP, name, _preset_state(model, name, preset, ARM_JOINTS))
    gm = model.gripper_map
    state(GRIPPER_GROUP, "open", {"gripper": gm.gap_from_deg(gm.open_deg)})
    state(GRIPPER_GROUP, "closed", {"gripper": gm.gap_from_deg(gm.closed_deg)})
    for name, preset in presets.items():
        if name not in ("open", "closed"):
            state(GRIPPER_GROUP, name, _preset_state(model, name, preset, ("gripper",)))
    ET.SubElement(
        robot,
        "end_effector",
        name="hand",
        parent_link=chain.tool,
        group=GRIPPER_GROUP,
        parent_group=ARM_GROUP,
    )
    for pair in disabled_pairs(chain, samples=collision_samples):
        ET.SubElement(
            robot, "disable_collisions", link1=pair.link1, link2=pair.link2, reason=pair.reason
        )
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def joint_limits(chain: Chain, *, ramp_s: float | None = DEFAULT_RAMP_S) -> dict[str, Any]:
    """joint_limits.yaml: every movable joint's velocity limit from the URDF (the servo
    speeds); acceleration = velocity / ramp_s, or no acceleration limit if ramp_s is None."""
    if ramp_s is not None and not (math.isfinite(ramp_s) and ramp_s > 0):
        raise InvalidInput(f"ramp_s must be finite and > 0, or None, not {ramp_s}")
    limits: dict[str, Any] = {}
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
    *, position_only_ik: bool = True, timeout_s: float = 0.05, resolution: float = 0.005
) -> dict[str, Any]:
    """kinematics.yaml: KDL for group `arm`.

    Position-only by default: five joints cannot meet an arbitrary 6-D pose, so
    with full poses KDL fails on almost every goal an interactive marker gives.
    """
    return {
        ARM_GROUP: {
            "kinematics_solver": KDL_PLUGIN,
            "kinematics_solver_search_resolution": resolution,
            "kinematics_solver_timeout": timeout_s,
            "position_only_ik": position_only_ik,
        }
    }


def controllers() -> dict[str, Any]:
    """moveit_controllers.yaml for MoveIt's simple controller manager and our two actions."""
    return {
        "moveit_controller_manager": (
            "moveit_simple_controller_manager/MoveItSimpleControllerManager"
        ),
        "moveit_simple_controller_manager": {
            "controller_names": [ARM_CONTROLLER, GRIPPER_CONTROLLER],
            ARM_CONTROLLER: {
                "type": "FollowJointTrajectory",
                "action_ns": "follow_joint_trajectory",
                "default": True,
                "joints": list(ARM_JOINTS),
            },
            GRIPPER_CONTROLLER: {
                "type": "GripperCommand",
                "action_ns": "gripper_cmd",
                "default": True,
                "joints": ["gripper"],
            },
        },
    }


def moveit_config(
    model: ArmModel,
    chain: Chain,
    presets: Mapping[str, Mapping[str, float]],
    *,
    robot_name: str = "al5d",
) -> dict[str, Any]:
    """All four, keyed by the file name a MoveIt config package gives them."""
    return {
        f"{robot_name}.srdf": srdf(model, chain, presets, robot_name=robot_name),
        "joint_limits.yaml": joint_limits(chain),
        "kinematics.yaml": kinematics(),
        "moveit_controllers.yaml": controllers(),
    }
