"""The static transforms of the SRDF's virtual joints (none by default)

Written by `al5d moveit` for the package al5d_moveit_config.
"""

from moveit_configs_utils import MoveItConfigsBuilder
from moveit_configs_utils.launches import generate_static_virtual_joint_tfs_launch

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
    return generate_static_virtual_joint_tfs_launch(moveit_config)
