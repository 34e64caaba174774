"""MoveIt's move_group, executing through the controllers of `controllers:=`

Written by `al5d moveit` for the package al5d_moveit_config.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from moveit_configs_utils import MoveItConfigsBuilder
from moveit_configs_utils.launches import generate_move_group_launch

ROBOT = "al5d"
PACKAGE = "al5d_moveit_config"
#: The arm's namespace when the package was written ("" none): the server's names are
#: under it, and so are MoveIt's nodes.
NAMESPACE = ""
#: MoveIt's controller configuration for each set-up (controllers:=...).
CONTROLLERS = {
    "driver": "config/moveit_controllers.yaml",
    "ros2_control": "config/moveit_ros2_control_controllers.yaml",
}


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
