"""The al5d server, and optionally its web view.

    ros2 launch al5d bringup.launch.py port:=/dev/ttyUSB0 namespace:=left web:=true

Arguments left empty are not passed, so that the configuration file decides them: no
`port` runs the server on its embedded emulator, no `baud` takes the configuration's.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackagePrefix, FindPackageShare

ARGUMENTS = {
    "config_file": (
        PathJoinSubstitution([FindPackageShare("al5d"), "config", "al5d.yaml"]),
        "the arm's configuration file; empty: the server's own default",
    ),
    "port": ("", "the SSC-32U's serial device, e.g. /dev/ttyUSB0; empty: the embedded emulator"),
    "baud": ("", "the board's baud rate; empty: the configuration's"),
    "namespace": ("", "the arm's ROS namespace, e.g. left; empty: the configuration's"),
    "record": ("", "an MCAP file to record what happens in, the board's bytes too; empty: none"),
    "log_level": ("info", "debug, info, warning or error"),
    "web": ("false", "true: also the web view (al5d web)"),
    "web_port": ("8080", "the web view's HTTP port"),
}


def _actions(context):
    given = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    parameters = {name: given[name] for name in ("config_file", "port", "record") if given[name]}
    if given["baud"]:
        parameters["baud"] = int(given["baud"])
    actions = [
        Node(
            package="al5d",
            executable="server",
            # No name=: it would rename every node of the server's process (al5d,
            # al5d_safety, al5d_robot, ...) to one name.
            namespace=given["namespace"] or None,
            parameters=[parameters],
            arguments=["--log-level", given["log_level"]],
            output="screen",
            emulate_tty=True,
        )
    ]
    if given["web"].lower() in ("true", "1", "yes"):
        # A process rather than a Node: a Node appends --ros-args, and the web view
        # takes its settings on its own command line.
        web = ["--port", given["web_port"]]
        if given["namespace"]:
            web += ["--namespace", given["namespace"]]
        if given["config_file"]:
            web += ["--config", given["config_file"]]
        actions.append(
            ExecuteProcess(
                cmd=[PathJoinSubstitution([FindPackagePrefix("al5d"), "lib", "al5d", "web"]), *web],
                name="al5d_web",
                output="screen",
            )
        )
    return actions


def generate_launch_description():
    return LaunchDescription(
        [
            DeclareLaunchArgument(name, default_value=default, description=description)
            for name, (default, description) in ARGUMENTS.items()
        ]
        + [OpaqueFunction(function=_actions)]
    )
