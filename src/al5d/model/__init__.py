"""The AL5D as a robot model: geometry, joint conventions, kinematics, URDF, lines, MoveIt.

- `geometry`: the arm's lengths; `arm`: `ArmModel`, the lengths and the joints' ranges.
- `joints`: the one table arm degrees <-> URDF values (`CONVENTIONS`, `GripperMap`).
- `transforms`: rigid transforms as tuples (quaternions, matrices, RPY).
- `chain`: the links and joints, and their poses; `urdf`: the URDF made from it.
- `looks`: what the links look like (servos, brackets, tubes, the base, the gripper), from
  the geometry: the URDF's visuals.
- `kinematics`: closed-form forward and inverse kinematics.
- `lines`: a straight line of the tool cut into the fewest group moves.
- `table`: whether the arm's bodies stay above the table, at a pose and along a move.
- `collisions`: the link pairs that can never touch (the SRDF's disabled collisions).
- `moveit`: the SRDF, joint limits, kinematics and controllers files of MoveIt.
- `errors`: what the model raises when it refuses an input or a target.

Pure: standard library and numpy only, nothing else of al5d. Angles in the
arm's own degrees (dict joint -> degrees) unless a name says URDF; lengths in
metres. The one table from arm degrees to URDF values is `joints.CONVENTIONS`
(with `joints.GripperMap` for the gripper).
"""

from al5d.model.arm import ArmModel
from al5d.model.chain import Chain, build_chain, joint_transforms, link_poses, tool_pose
from al5d.model.errors import (
    BelowTable,
    InvalidInput,
    JointOutOfRange,
    ModelError,
    OutOfReach,
    PathUnreachable,
    Unreachable,
)
from al5d.model.geometry import Geometry
from al5d.model.joints import (
    ARM_JOINTS,
    CONVENTIONS,
    JOINTS,
    GripperMap,
    Range,
    Ranges,
    joint_from_urdf,
    joint_to_urdf,
)
from al5d.model.kinematics import (
    ToolPose,
    below_table,
    forward,
    joint_positions,
    solve,
    solve_nearest_pitch,
    tool_position,
    tool_quaternion,
)
from al5d.model.lines import (
    LinePlan,
    PulseScale,
    as_sent,
    distance_to_segment,
    plan_line,
    segment_deviation,
)
from al5d.model.moveit import controllers, joint_limits, kinematics, moveit_config, srdf
from al5d.model.urdf import urdf, urdf_from_chain, urdf_of_arms

__all__ = [
    "ARM_JOINTS",
    "CONVENTIONS",
    "JOINTS",
    "ArmModel",
    "BelowTable",
    "Chain",
    "Geometry",
    "GripperMap",
    "InvalidInput",
    "JointOutOfRange",
    "LinePlan",
    "ModelError",
    "OutOfReach",
    "PathUnreachable",
    "PulseScale",
    "Range",
    "Ranges",
    "ToolPose",
    "Unreachable",
    "as_sent",
    "below_table",
    "build_chain",
    "controllers",
    "distance_to_segment",
    "forward",
    "joint_from_urdf",
    "joint_limits",
    "joint_positions",
    "joint_to_urdf",
    "joint_transforms",
    "kinematics",
    "link_poses",
    "moveit_config",
    "plan_line",
    "segment_deviation",
    "solve",
    "solve_nearest_pitch",
    "srdf",
    "tool_pose",
    "tool_position",
    "tool_quaternion",
    "urdf",
    "urdf_from_chain",
    "urdf_of_arms",
]
