"""The URDF with its ros2_control tag, for the controller manager

Written by `al5d moveit` for the package al5d_moveit_config.
"""

from launch import LaunchDescription
from launch_ros.actions import Node
from moveit_configs_utils import MoveItConfigsBuilder

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
