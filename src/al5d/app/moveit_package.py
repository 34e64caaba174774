"""The frame of a MoveIt 2 config package for Jazzy, laid out as the Setup Assistant lays
one out: package.xml, CMakeLists.txt, .setup_assistant, the RViz config and launch/.

The data (URDF, SRDF, limits, controllers) comes from `al5d.model.moveit`; this module
holds what only the package needs. The launch files use `moveit_configs_utils` as the
Setup Assistant's do, and add the one choice the AL5D has: `controllers:=driver`
(the server's own FollowJointTrajectory and GripperCommand actions) or
`controllers:=ros2_control` (ros2_control's controllers, whose topic-based hardware
publishes joint commands that the server takes).
"""

from __future__ import annotations

import json
import re
from typing import Any, Final

import yaml

from al5d.model.moveit import (
    ARM_GROUP,
    ROS2_ARM_CONTROLLER,
    ROS2_GRIPPER_CONTROLLER,
)

DEFAULT_PACKAGE: Final = "al5d_moveit_config"
#: MoveIt's files for each set-up, relative to the package's share directory.
DRIVER_CONTROLLERS: Final = "config/moveit_controllers.yaml"
ROS2_CONTROL_CONTROLLERS: Final = "config/moveit_ros2_control_controllers.yaml"
VERSION: Final = "0.1.0"
#: REP 144: lowercase letters, digits and underscores, starting with a letter.
_PACKAGE_NAME = re.compile(r"[a-z][a-z0-9_]*")


def package_name_problem(name: str) -> str | None:
    """Why `name` is no ROS package name (REP 144), or None."""
    if not _PACKAGE_NAME.fullmatch(name) or "__" in name or name.endswith("_"):
        return (
            f"package name {name[:60]!r}: lowercase letters, digits and single underscores, "
            "starting with a letter (REP 144)"
        )
    return None


def package_xml(package: str, robot: str, *, arms: bool = False) -> str:
    """package.xml, format 3: what `ros2 launch` of each set-up needs at run time (`arms`:
    a package of several arms, whose joint states joint_state_publisher merges)."""
    run = [
        "al5d",
        "moveit_ros_move_group",
        "moveit_kinematics",
        "moveit_planners",
        "moveit_simple_controller_manager",
        "moveit_configs_utils",
        "moveit_ros_visualization",
        "moveit_setup_assistant",
        "robot_state_publisher",
        "rviz2",
        "tf2_ros",
        "xacro",
        "controller_manager",
        "joint_trajectory_controller",
        "gripper_controllers",
        "joint_state_topic_hardware_interface",
    ]
    if arms:  # the ros2_control set-up is one arm's; the arms' joint states are merged
        control = {"xacro", "controller_manager", "joint_trajectory_controller"}
        control |= {"gripper_controllers", "joint_state_topic_hardware_interface"}
        run = [name for name in run if name not in control] + ["joint_state_publisher"]
    depends = "\n".join(f"  <exec_depend>{name}</exec_depend>" for name in run)
    return f"""<?xml version="1.0"?>
<?xml-model href="http://download.ros.org/schema/package_format3.xsd" schematypens="http://www.w3.org/2001/XMLSchema"?>
<package format="3">
  <name>{package}</name>
  <version>{VERSION}</version>
  <description>
    The configuration and launch files for using the {robot} (a Lynxmotion AL5D on an
    SSC-32U, driven by the al5d server) with MoveIt 2, written by `al5d moveit`.
  </description>
  <maintainer email="al5d@example.com">al5d</maintainer>
  <license>MIT</license>

  <buildtool_depend>ament_cmake</buildtool_depend>

{depends}

  <export>
    <build_type>ament_cmake</build_type>
  </export>
</package>
"""


def cmakelists(package: str) -> str:
    """CMakeLists.txt: installs config/, launch/ and .setup_assistant into the share dir."""
    return f"""cmake_minimum_required(VERSION 3.22)
project({package} NONE)

find_package(ament_cmake REQUIRED)

ament_package()

install(
  DIRECTORY launch
  DESTINATION share/${{PROJECT_NAME}}
  PATTERN "setup_assistant.launch" EXCLUDE)
install(DIRECTORY config DESTINATION share/${{PROJECT_NAME}})
install(FILES .setup_assistant DESTINATION share/${{PROJECT_NAME}})
"""


def setup_assistant(package: str, robot: str) -> str:
    """.setup_assistant: where the Setup Assistant (and MoveItConfigsBuilder) find the
    URDF and the SRDF, and the control xacro's interfaces."""
    data: dict[str, Any] = {
        "moveit_setup_assistant_config": {
            "urdf": {"package": package, "relative_path": f"config/{robot}.urdf"},
            "srdf": {"relative_path": f"config/{robot}.srdf"},
            "package_settings": {"author_name": "al5d", "author_email": "al5d@example.com"},
            "control_xacro": {"command": ["position"], "state": ["position"]},
            "modified_urdf": {"xacros": ["control_xacro"]},
        }
    }
    return yaml.safe_dump(data, sort_keys=False)


def rviz_config(fixed_frame: str, group: str = ARM_GROUP) -> str:
    """config/moveit.rviz: a grid and MoveIt's MotionPlanning display for `group`.

    Topic names are relative, so that RViz started in the arm's namespace finds the
    arm's description and planning scene."""
    data: dict[str, Any] = {
        "Panels": [
            {"Class": "rviz_common/Displays", "Name": "Displays"},
            {"Class": "rviz_common/Views", "Name": "Views"},
        ],
        "Visualization Manager": {
            "Displays": [
                {"Class": "rviz_default_plugins/Grid", "Name": "Grid", "Value": True},
                {
                    "Class": "moveit_rviz_plugin/MotionPlanning",
                    "Name": "MotionPlanning",
                    "Robot Description": "robot_description",
                    "Planning Scene Topic": "monitored_planning_scene",
                    "Planned Path": {
                        "Trajectory Topic": "display_planned_path",
                        "Loop Animation": False,
                    },
                    "Planning Request": {"Planning Group": group},
                    "Scene Robot": {"Robot Alpha": 0.5},
                    "Value": True,
                },
            ],
            "Global Options": {"Fixed Frame": fixed_frame},
            "Tools": [
                {"Class": "rviz_default_plugins/Interact"},
                {"Class": "rviz_default_plugins/MoveCamera"},
                {"Class": "rviz_default_plugins/Select"},
            ],
            "Value": True,
            "Views": {
                "Current": {
                    "Class": "rviz_default_plugins/Orbit",
                    "Name": "Current View",
                    "Target Frame": fixed_frame,
                    "Distance": 1.0,
                    "Focal Point": {"X": 0.1, "Y": 0.0, "Z": 0.15},
                    "Pitch": 0.5,
                    "Yaw": 0.8,
                }
            },
        },
    }
    return yaml.safe_dump(data, sort_keys=False)


HEADER = '''"""{doc}

Written by `al5d moveit` for the package {package}.
"""
'''

_CONSTANTS = """
ROBOT = {robot}
PACKAGE = {package}
#: The arm's namespace when the package was written ("" none): the server's names are
#: under it, and so are MoveIt's nodes.
NAMESPACE = {namespace}
#: MoveIt's controller configuration for each set-up (controllers:=...).
CONTROLLERS = {{
    "driver": {driver},
    "ros2_control": {ros2_control},
}}
"""


def _launch(doc: str, body: str, *, robot: str, package: str, namespace: str) -> str:
    # JSON strings are Python strings, in the double quotes the launch files use.
    constants = _CONSTANTS.format(
        robot=json.dumps(robot),
        package=json.dumps(package),
        namespace=json.dumps(namespace),
        driver=json.dumps(DRIVER_CONTROLLERS),
        ros2_control=json.dumps(ROS2_CONTROL_CONTROLLERS),
    )
    return HEADER.format(doc=doc, package=package) + body.replace("#CONSTANTS#", constants)


_DEMO = """
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription
from launch.conditions import IfCondition
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import EqualsSubstitution, LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node, PushRosNamespace
from launch_ros.substitutions import FindPackageShare
#CONSTANTS#

def _include(name, condition=None, **arguments):
    return IncludeLaunchDescription(
        PythonLaunchDescriptionSource(
            PathJoinSubstitution([FindPackageShare(PACKAGE), "launch", name])
        ),
        launch_arguments=arguments.items(),
        condition=condition,
    )


def generate_launch_description():
    controllers = LaunchConfiguration("controllers")
    ros2_control = IfCondition(EqualsSubstitution(controllers, "ros2_control"))
    moveit = [PushRosNamespace(NAMESPACE)] if NAMESPACE else []
    moveit += [
        _include("move_group.launch.py", controllers=controllers),
        _include("moveit_rviz.launch.py", condition=IfCondition(LaunchConfiguration("use_rviz"))),
        # ros2_control: the controller manager with the topic hardware (its URDF, with
        # the ros2_control tag, comes from rsp.launch.py), then its two controllers.
        _include("rsp.launch.py", condition=ros2_control),
        Node(
            package="controller_manager",
            executable="ros2_control_node",
            parameters=[
                PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "ros2_controllers.yaml"])
            ],
            # The server owns robot_description (a URDF without the ros2_control tag).
            remappings=[
                ("robot_description", "ros2_control_description"),
                ("~/robot_description", "ros2_control_description"),
            ],
            output="screen",
            condition=ros2_control,
        ),
        _include("spawn_controllers.launch.py", condition=ros2_control),
    ]
    return LaunchDescription([
        DeclareLaunchArgument(
            "controllers",
            default_value="driver",
            choices=["driver", "ros2_control"],
            description="driver: the server's own trajectory and gripper actions; "
            "ros2_control: ros2_control's controllers, through the topic-based hardware",
        ),
        DeclareLaunchArgument(
            "driver",
            default_value="true",
            choices=["true", "false"],
            description="also start the al5d server (al5d's bringup.launch.py)",
        ),
        DeclareLaunchArgument("port", default_value="", description="empty: the emulator"),
        DeclareLaunchArgument("baud", default_value="", description="empty: the configuration's"),
        DeclareLaunchArgument("config_file", default_value="", description="empty: shipped"),
        DeclareLaunchArgument("use_rviz", default_value="true", choices=["true", "false"]),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(
                PathJoinSubstitution([FindPackageShare("al5d"), "launch", "bringup.launch.py"])
            ),
            launch_arguments={
                "namespace": NAMESPACE,
                "port": LaunchConfiguration("port"),
                "baud": LaunchConfiguration("baud"),
                "config_file": LaunchConfiguration("config_file"),
            }.items(),
            condition=IfCondition(LaunchConfiguration("driver")),
        ),
        GroupAction(moveit),
    ])
"""

_MOVE_GROUP = """
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from moveit_configs_utils import MoveItConfigsBuilder
from moveit_configs_utils.launches import generate_move_group_launch
#CONSTANTS#

def _move_group(context):
    controllers = CONTROLLERS[LaunchConfiguration("controllers").perform(context)]
    moveit_config = (
        MoveItConfigsBuilder(ROBOT, package_name=PACKAGE)
        .trajectory_execution(file_path=controllers)
        .to_moveit_configs()
    )
    return [generate_move_group_launch(moveit_config)]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("controllers", default_value="driver", choices=list(CONTROLLERS)),
        OpaqueFunction(function=_move_group),
    ])
"""

_RSP = """
from launch import LaunchDescription
from launch_ros.actions import Node
from moveit_configs_utils import MoveItConfigsBuilder
#CONSTANTS#

def generate_launch_description():
    moveit_config = MoveItConfigsBuilder(ROBOT, package_name=PACKAGE).to_moveit_configs()
    # The server publishes robot_description and the TF tree from its own state; this
    # publisher only hands the controller manager the URDF with the ros2_control tag,
    # on a topic of its own, and its transforms go nowhere anyone listens.
    return LaunchDescription([
        Node(
            package="robot_state_publisher",
            executable="robot_state_publisher",
            name="ros2_control_description_publisher",
            output="screen",
            parameters=[moveit_config.robot_description],
            remappings=[
                ("robot_description", "ros2_control_description"),
                ("joint_states", "ros2_control_description/joint_states"),
                ("/tf", "ros2_control_description/tf"),
                ("/tf_static", "ros2_control_description/tf_static"),
            ],
        )
    ])
"""

RVIZ = """
from moveit_configs_utils import MoveItConfigsBuilder
from moveit_configs_utils.launches import generate_moveit_rviz_launch
#CONSTANTS#

def generate_launch_description():
    moveit_config = MoveItConfigsBuilder(ROBOT, package_name=PACKAGE).to_moveit_configs()
    return generate_moveit_rviz_launch(moveit_config)
"""

_SPAWN = f"""
from launch import LaunchDescription
from launch_ros.actions import Node
#CONSTANTS#

def generate_launch_description():
    # ros2_control's two controllers (no joint_state_broadcaster: the server publishes
    # joint_states, which the topic hardware reads).
    return LaunchDescription([
        Node(package="controller_manager", executable="spawner", arguments=[name], output="screen")
        for name in ({ROS2_ARM_CONTROLLER!r}, {ROS2_GRIPPER_CONTROLLER!r})
    ])
"""

STATIC_TFS = """
from moveit_configs_utils import MoveItConfigsBuilder
from moveit_configs_utils.launches import generate_static_virtual_joint_tfs_launch
#CONSTANTS#

def generate_launch_description():
    moveit_config = MoveItConfigsBuilder(ROBOT, package_name=PACKAGE).to_moveit_configs()
    return generate_static_virtual_joint_tfs_launch(moveit_config)
"""

SETUP_ASSISTANT = """
from moveit_configs_utils import MoveItConfigsBuilder
from moveit_configs_utils.launches import generate_setup_assistant_launch
#CONSTANTS#

def generate_launch_description():
    moveit_config = MoveItConfigsBuilder(ROBOT, package_name=PACKAGE).to_moveit_configs()
    return generate_setup_assistant_launch(moveit_config)
"""

#: launch/<name>: (what it starts, its body).
LAUNCH_FILES: Final = {
    "demo.launch.py": (
        "The AL5D with MoveIt: the al5d server (driver:=false if it runs already), move_group\n"
        "and RViz, with the server's own controllers (controllers:=driver, the default) or\n"
        "ros2_control's (controllers:=ros2_control: the controller manager with the\n"
        "topic-based hardware, whose joint commands the server takes)",
        _DEMO,
    ),
    "move_group.launch.py": (
        "MoveIt's move_group, executing through the controllers of `controllers:=`",
        _MOVE_GROUP,
    ),
    "rsp.launch.py": (
        "The URDF with its ros2_control tag, for the controller manager",
        _RSP,
    ),
    "moveit_rviz.launch.py": ("RViz with MoveIt's MotionPlanning display", RVIZ),
    "spawn_controllers.launch.py": ("ros2_control's controllers of the arm", _SPAWN),
    "static_virtual_joint_tfs.launch.py": (
        "The static transforms of the SRDF's virtual joints (none by default)",
        STATIC_TFS,
    ),
    "setup_assistant.launch.py": (
        "MoveIt's Setup Assistant on this package",
        SETUP_ASSISTANT,
    ),
}


def launch_files(*, robot: str, package: str, namespace: str) -> dict[str, str]:
    """launch/<name> -> its text."""
    return {
        f"launch/{name}": _launch(doc, body, robot=robot, package=package, namespace=namespace)
        for name, (doc, body) in LAUNCH_FILES.items()
    }
