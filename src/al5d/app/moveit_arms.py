"""The launch files of a MoveIt 2 config package of several arms: one robot, each arm
served in its namespace by a server of its own (`al5d moveit --arms`).

The rest of the package (package.xml, CMake, the Setup Assistant's file, RViz's, and the
launch files shared with a package of one arm) is `al5d.app.moveit_package`'s.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Final

from al5d.app.moveit_package import (
    DRIVER_CONTROLLERS,
    HEADER,
    RVIZ,
    SETUP_ASSISTANT,
    STATIC_TFS,
)
from al5d.model.moveit import ARM_CONTROLLER, GRIPPER_CONTROLLER


@dataclass(frozen=True)
class ServedArm:
    """An arm of a package of several, as its launch files start and name it."""

    namespace: str
    #: The configuration its server runs with, in the package's share directory.
    config: str
    #: Its joints' prefix, and so its groups' and MoveIt's controllers' (`left_`).
    joint_prefix: str
    joint_state_rate_hz: float


#: The topics and services of an action, after its name.
_ACTION_PARTS: Final = ("send_goal", "cancel_goal", "get_result", "feedback", "status")


def action_remappings(arms: list[ServedArm]) -> list[tuple[str, str]]:
    """move_group's remappings: each MoveIt controller's action (`/left_arm_controller/
    follow_joint_trajectory`, named by the simple controller manager, which takes no
    namespace) onto the server's own (`/left/arm_controller/follow_joint_trajectory`):
    the action's name and each of its topics and services, whichever rcl remaps."""
    pairs = []
    for arm in arms:
        for controller, action in (
            (ARM_CONTROLLER, "follow_joint_trajectory"),
            (GRIPPER_CONTROLLER, "gripper_cmd"),
        ):
            ours = f"/{arm.joint_prefix}{controller}/{action}"
            theirs = f"/{arm.namespace}/{controller}/{action}"
            pairs.append((ours, theirs))
            pairs += [(f"{ours}/_action/{p}", f"{theirs}/_action/{p}") for p in _ACTION_PARTS]
    return pairs


_ARMS_CONSTANTS = """
ROBOT = {robot}
PACKAGE = {package}
#: Each arm: its namespace, the configuration its server runs with (in this package's
#: share directory) and its joint states' topic.
ARMS = {arms}
CONTROLLERS = {controllers}
#: The merged joint states' rate: the servers' joint-state rate.
JOINT_STATES_RATE = {rate}
#: MoveIt's controllers' actions onto the servers' own (`al5d moveit` says why).
REMAPPINGS = {remappings}
"""

_ARMS_DEMO = """
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.conditions import IfCondition
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare
#CONSTANTS#

def _include(package, name, condition=None, **arguments):
    return IncludeLaunchDescription(
        PythonLaunchDescriptionSource(
            PathJoinSubstitution([FindPackageShare(package), "launch", name])
        ),
        launch_arguments=arguments.items(),
        condition=condition,
    )


def generate_launch_description():
    driver = IfCondition(LaunchConfiguration("driver"))
    actions = [
        DeclareLaunchArgument(
            "driver",
            default_value="true",
            choices=["true", "false"],
            description="also start the arms' servers (al5d's bringup.launch.py, one each)",
        ),
        DeclareLaunchArgument("use_rviz", default_value="true", choices=["true", "false"]),
    ]
    for arm in ARMS:
        ns = arm["namespace"]
        actions += [
            DeclareLaunchArgument(f"{ns}_port", default_value="", description="empty: emulated"),
            DeclareLaunchArgument(f"{ns}_baud", default_value="", description="empty: config's"),
            DeclareLaunchArgument(
                f"{ns}_config_file",
                default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), arm["config"]]),
                description="the arm's configuration (its mount is this package's)",
            ),
            _include(
                "al5d",
                "bringup.launch.py",
                driver,
                namespace=ns,
                port=LaunchConfiguration(f"{ns}_port"),
                baud=LaunchConfiguration(f"{ns}_baud"),
                config_file=LaunchConfiguration(f"{ns}_config_file"),
            ),
        ]
    actions += [
        _include(PACKAGE, "joint_states.launch.py"),
        _include(PACKAGE, "move_group.launch.py"),
        _include(PACKAGE, "moveit_rviz.launch.py", IfCondition(LaunchConfiguration("use_rviz"))),
    ]
    return LaunchDescription(actions)
"""

_ARMS_JOINT_STATES = """
from launch import LaunchDescription
from launch.substitutions import PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare
#CONSTANTS#

def generate_launch_description():
    # MoveIt reads one joint_states topic; each server publishes its arm's in its namespace.
    # joint_state_publisher merges them (its source_list) onto /joint_states.
    return LaunchDescription([
        Node(
            package="joint_state_publisher",
            executable="joint_state_publisher",
            name="al5d_joint_states",
            arguments=[
                PathJoinSubstitution([FindPackageShare(PACKAGE), "config", ROBOT + ".urdf"])
            ],
            parameters=[{
                "source_list": [arm["joint_states"] for arm in ARMS],
                "rate": JOINT_STATES_RATE,
            }],
            output="screen",
        )
    ])
"""

_ARMS_MOVE_GROUP = """
from launch import LaunchDescription
from launch_ros.actions import Node
from moveit_configs_utils import MoveItConfigsBuilder
#CONSTANTS#

def generate_launch_description():
    moveit_config = (
        MoveItConfigsBuilder(ROBOT, package_name=PACKAGE)
        .trajectory_execution(file_path=CONTROLLERS)
        .to_moveit_configs()
    )
    # As moveit_configs_utils' move_group launch, with MoveIt's controllers' actions
    # remapped onto the servers' own, each under its arm's namespace.
    return LaunchDescription([
        Node(
            package="moveit_ros_move_group",
            executable="move_group",
            output="screen",
            parameters=[
                moveit_config.to_dict(),
                {
                    "publish_robot_description_semantic": True,
                    "allow_trajectory_execution": True,
                    "publish_planning_scene": True,
                    "publish_geometry_updates": True,
                    "publish_state_updates": True,
                    "publish_transforms_updates": True,
                    "monitor_dynamics": False,
                },
            ],
            remappings=[tuple(pair) for pair in REMAPPINGS],
        )
    ])
"""

#: launch/<name> of a package of several arms: (what it starts, its body).
ARMS_LAUNCH_FILES: Final = {
    "demo.launch.py": (
        "The arms with MoveIt as one robot: a server for each (driver:=false if they run\n"
        "already; <ns>_port:=, <ns>_config_file:=), their joint states merged, move_group\n"
        "and RViz, executing through the servers' own trajectory and gripper actions",
        _ARMS_DEMO,
    ),
    "joint_states.launch.py": (
        "The arms' joint states, each server's, merged onto /joint_states for MoveIt",
        _ARMS_JOINT_STATES,
    ),
    "move_group.launch.py": (
        "MoveIt's move_group, executing through the servers' actions",
        _ARMS_MOVE_GROUP,
    ),
    "moveit_rviz.launch.py": ("RViz with MoveIt's MotionPlanning display", RVIZ),
    "static_virtual_joint_tfs.launch.py": (
        "The static transforms of the SRDF's virtual joints (none by default)",
        STATIC_TFS,
    ),
    "setup_assistant.launch.py": ("MoveIt's Setup Assistant on this package", SETUP_ASSISTANT),
}


def arms_launch_files(*, robot: str, package: str, arms: list[ServedArm]) -> dict[str, str]:
    """launch/<name> -> its text, for a package of several arms."""
    constants = _ARMS_CONSTANTS.format(
        robot=json.dumps(robot),
        package=json.dumps(package),
        arms=json.dumps(
            [
                {
                    "namespace": arm.namespace,
                    "config": arm.config,
                    "joint_states": f"/{arm.namespace}/joint_states",
                }
                for arm in arms
            ]
        ),
        controllers=json.dumps(DRIVER_CONTROLLERS),
        rate=float(max(arm.joint_state_rate_hz for arm in arms)),
        remappings=json.dumps(action_remappings(arms)),
    )
    return {
        f"launch/{name}": HEADER.format(doc=doc, package=package)
        + body.replace("#CONSTANTS#", constants)
        for name, (doc, body) in ARMS_LAUNCH_FILES.items()
    }
