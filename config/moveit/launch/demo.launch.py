"""The AL5D with MoveIt: the al5d server (driver:=false if it runs already), move_group
and RViz, with the server's own controllers (controllers:=driver, the default) or
ros2_control's (controllers:=ros2_control: the controller manager with the
topic-based hardware, whose joint commands the server takes)

Written by `al5d moveit` for the package al5d_moveit_config.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription
from launch.conditions import IfCondition
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import EqualsSubstitution, LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node, PushRosNamespace
from launch_ros.substitutions import FindPackageShare

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
