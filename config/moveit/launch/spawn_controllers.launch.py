"""ros2_control's controllers of the arm

Written by `al5d moveit` for the package al5d_moveit_config.
"""

from launch import LaunchDescription
from launch_ros.actions import Node

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


def generate_launch_description():
    # ros2_control's two controllers (no joint_state_broadcaster: the server publishes
    # joint_states, which the topic hardware reads).
    return LaunchDescription([
        Node(package="controller_manager", executable="spawner", arguments=[name], output="screen")
        for name in ('joint_trajectory_controller', 'gripper_action_controller')
    ])
