"""The URDF's kinematic tree as data, built from the model, and forward kinematics over it.

One structure feeds the URDF text, the /tf transforms and the MoveIt data, so
the numbers exist once. Every joint is 0 with the arm straight up; each link's
frame sits on its joint's axis with z along the link.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Final, Literal

from al5d.model.arm import ArmModel
from al5d.model.errors import InvalidInput
from al5d.model.joints import ARM_JOINTS, CONVENTIONS, GRIPPER_FINGERS, JOINTS
from al5d.model.looks import Shape, link_looks
from al5d.model.transforms import Transform, Vec3, quat_from_axis_angle, quat_from_rpy

#: Default `effort` limit (N m, N for the fingers). URDF requires one; nothing here
#: uses it (MoveIt plans kinematically, the servos take no torque command). 1.0 is
#: of the order of the AL5D servos' stall torques (0.4 .. 2.4 N m).
DEFAULT_EFFORT: Final = 1.0

#: Link names, root to tip (before any prefix).
BASE_LINK: Final = "base_link"
TOOL_LINK: Final = "tool0"
LINK_OF_JOINT: Final[Mapping[str, str]] = {
    "base": "turntable_link",
    "shoulder": "upper_arm_link",
    "elbow": "forearm_link",
    "wrist": "wrist_link",
    "wrist_rotate": "hand_link",
    "gripper": "gripper_link",
    GRIPPER_FINGERS[0]: "finger_left_link",
    GRIPPER_FINGERS[1]: "finger_right_link",
}

# Display and collision sizes (metres), of the order of the real AL5D parts. They
# are approximate on purpose: for RViz, a web view and coarse self-collision only.
_BASE_RADIUS = 0.048  # round base housing
_BASE_HOUSING = 0.04  # its height, capped below the shoulder axis
_CLEARANCE = 0.02  # gap kept around the elbow and wrist axes, so bends never overlap
_FINGER = (0.02, 0.008, 0.03)  # finger box: width, thickness (across the gap), length
_WRIST_BLOCK = 0.025  # wrist rotate servo, along the gripper axis


@dataclass(frozen=True)
class Link:
    """A URDF link; `shape` its collision body (one, unturned: the table check and MoveIt use
    it), None for a frame without a body (tool0); `visuals` what it looks like
    (`looks`; none: the collision body)."""

    name: str
    shape: Shape | None
    visuals: tuple[Shape, ...] = ()


@dataclass(frozen=True)
class Limit:
    """URDF `<limit>`: lower < upper (rad or m), velocity (rad/s or m/s), effort."""

    lower: float
    upper: float
    velocity: float
    effort: float


@dataclass(frozen=True)
class Mimic:
    """URDF `<mimic>`: value = multiplier * joint + offset."""

    joint: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class Joint:
    """A URDF joint: the child's origin in the parent frame, then motion along `axis`."""

    name: str
    type: Literal["revolute", "prismatic", "fixed"]
    parent: str
    child: str
    xyz: Vec3
    rpy: Vec3
    axis: Vec3
    limit: Limit | None = None
    mimic: Mimic | None = None

    def transform(self, value: float = 0.0) -> Transform:
        """The child link's frame in the parent's for a joint value (rad or m)."""
        origin = Transform(self.xyz, quat_from_rpy(*self.rpy))
        if self.type == "revolute":
            return origin * Transform(rotation=quat_from_axis_angle(self.axis, value))
        if self.type == "prismatic":
            a = self.axis
            return origin * Transform((a[0] * value, a[1] * value, a[2] * value))
        return origin


@dataclass(frozen=True)
class Chain:
    """The whole tree: links, joints parent before child, and the frame prefix used."""

    links: tuple[Link, ...]
    joints: tuple[Joint, ...]
    prefix: str
    #: Prefixed names of the root (base_link) and the tool frame (tool0).
    root: str
    tool: str
    #: Put before every joint name (`left_` makes `left_base`): several arms in one robot.
    joint_prefix: str = ""

    def key(self, joint: str) -> str:
        """The model's name of a joint of the chain (`left_base` -> `base`), as the values
        of `ArmModel.to_urdf` are keyed."""
        return joint.removeprefix(self.joint_prefix)

    def named(self, values: Mapping[str, float]) -> dict[str, float]:
        """Values keyed by the model's names (`base`), keyed by the chain's (`left_base`)."""
        return {self.joint_prefix + name: value for name, value in values.items()}

    def joint(self, name: str) -> Joint:
        """A joint by name."""
        for j in self.joints:
            if j.name == name:
                return j
        raise InvalidInput(f"no joint {name!r} in the chain")

    def link(self, name: str) -> Link:
        """A link by (prefixed) name."""
        for link in self.links:
            if link.name == name:
                return link
        raise InvalidInput(f"no link {name!r} in the chain")

    @property
    def movable(self) -> tuple[str, ...]:
        """Joints that take a value (not fixed, not mimic): what /joint_states carries."""
        return tuple(j.name for j in self.joints if j.type != "fixed" and j.mimic is None)


def _speeds(speeds_deg_s: Mapping[str, float]) -> dict[str, float]:
    out = {}
    for name in JOINTS:
        if name not in speeds_deg_s:
            raise InvalidInput(f"speeds: missing joint {name}")
        v = speeds_deg_s[name]
        if not (math.isfinite(v) and v > 0):
            raise InvalidInput(f"speeds: {name} must be finite and > 0 deg/s, not {v}")
        out[name] = float(v)
    return out


def build_chain(
    model: ArmModel,
    speeds_deg_s: Mapping[str, float],
    *,
    prefix: str = "",
    joint_prefix: str = "",
    effort: float = DEFAULT_EFFORT,
) -> Chain:
    """The AL5D's tree from its geometry, ranges and servo speeds (deg/s per joint).

    `prefix` (e.g. "left/") is put before every link name, as robot_state_publisher's
    frame_prefix does to frames; `joint_prefix` (e.g. "left_") before every joint name,
    so that two arms' joints never share a name in one URDF.
    """
    speeds = _speeds(speeds_deg_s)
    if not (math.isfinite(effort) and effort > 0):
        raise InvalidInput(f"effort must be finite and > 0, not {effort}")
    g = model.geometry
    gm = model.gripper_map
    n = {j: prefix + link for j, link in LINK_OF_JOINT.items()}
    root, tool = prefix + BASE_LINK, prefix + TOOL_LINK

    housing = min(_BASE_HOUSING, 0.6 * g.base_height)
    pedestal = g.base_height - housing
    upper = max(g.humerus - 2 * _CLEARANCE, 0.005)
    fore = max(g.ulna - 2 * _CLEARANCE, 0.005)
    wrist_len = min(_WRIST_BLOCK, 0.3 * g.gripper)
    finger_len = min(_FINGER[2], 0.3 * g.gripper)
    hand_start = _CLEARANCE + wrist_len
    hand_len = max(g.gripper - finger_len - hand_start, 0.005)
    fw, ft = _FINGER[0], _FINGER[1]

    looks = link_looks(g, finger_len, (fw, ft))
    links = (
        Link(
            root,
            Shape("cylinder", (_BASE_RADIUS, housing, 0.0), (0, 0, housing / 2), "dark"),
            looks["root"],
        ),
        Link(
            n["base"],
            Shape("box", (0.06, 0.07, pedestal), (0, 0, housing + pedestal / 2), "dark"),
            looks["base"],
        ),
        Link(
            n["shoulder"],
            Shape("box", (0.025, 0.06, upper), (0, 0, g.humerus / 2), "metal"),
            looks["shoulder"],
        ),
        Link(
            n["elbow"],
            Shape("box", (0.024, 0.035, fore), (0, 0, g.ulna / 2), "metal"),
            looks["elbow"],
        ),
        Link(
            n["wrist"],
            Shape("box", (0.03, 0.04, wrist_len), (0, 0, _CLEARANCE + wrist_len / 2), "dark"),
            looks["wrist"],
        ),
        Link(
            n["wrist_rotate"],
            Shape("box", (0.03, 0.06, hand_len), (0, 0, hand_start + hand_len / 2), "metal"),
            looks["wrist_rotate"],
        ),
        # The gap itself: a frame without a body, moved by `gripper`; the fingers mimic it.
        Link(n["gripper"], None),
        Link(
            n[GRIPPER_FINGERS[0]],
            Shape("box", (fw, ft, finger_len), (0, ft / 2, finger_len / 2), "dark"),
            looks["left"],
        ),
        Link(
            n[GRIPPER_FINGERS[1]],
            Shape("box", (fw, ft, finger_len), (0, -ft / 2, finger_len / 2), "dark"),
            looks["right"],
        ),
        Link(tool, None),
    )

    parents = {
        "base": root,
        "shoulder": n["base"],
        "elbow": n["shoulder"],
        "wrist": n["elbow"],
        "wrist_rotate": n["wrist"],
    }
    origins: dict[str, Vec3] = {
        "base": (0.0, 0.0, 0.0),
        "shoulder": (g.shoulder_offset, 0.0, g.base_height),
        "elbow": (0.0, 0.0, g.humerus),
        "wrist": (0.0, 0.0, g.ulna),
        "wrist_rotate": (0.0, 0.0, 0.0),
    }
    joints: list[Joint] = []
    for name in ARM_JOINTS:
        lower, upper_lim = model.urdf_limits(name)
        joints.append(
            Joint(
                name=name,
                type="revolute",
                parent=parents[name],
                child=n[name],
                xyz=origins[name],
                rpy=(0.0, 0.0, 0.0),
                axis=CONVENTIONS[name].axis,
                limit=Limit(lower, upper_lim, math.radians(speeds[name]), effort),
            )
        )
    g_lower, g_upper = gm.gap_limits
    gap_speed = speeds["gripper"] * gm.metres_per_deg
    finger_origin = (0.0, 0.0, g.gripper - finger_len)
    half = Limit(g_lower / 2, g_upper / 2, gap_speed / 2, effort)
    joints += [
        Joint(
            "gripper",
            "prismatic",
            n["wrist_rotate"],
            n["gripper"],
            finger_origin,
            (0.0, 0.0, 0.0),
            (0.0, 1.0, 0.0),
            Limit(g_lower, g_upper, gap_speed, effort),
        ),
        *(
            Joint(
                finger,
                "prismatic",
                n["wrist_rotate"],
                n[finger],
                finger_origin,
                (0.0, 0.0, 0.0),
                (0.0, side, 0.0),
                half,
                Mimic("gripper", multiplier=0.5),
            )
            for finger, side in zip(GRIPPER_FINGERS, (1.0, -1.0), strict=True)
        ),
        Joint(
            "tool0_joint",
            "fixed",
            n["wrist_rotate"],
            tool,
            (0.0, 0.0, g.gripper),
            (0.0, 0.0, 0.0),
            (0.0, 0.0, 1.0),
        ),
    ]
    if joint_prefix:
        joints = [_prefixed(joint, joint_prefix) for joint in joints]
    return Chain(links, tuple(joints), prefix, root, tool, joint_prefix)


def _prefixed(joint: Joint, prefix: str) -> Joint:
    mimic = joint.mimic
    if mimic is not None:
        mimic = Mimic(prefix + mimic.joint, mimic.multiplier, mimic.offset)
    return replace(joint, name=prefix + joint.name, mimic=mimic)


def _value(chain: Chain, joint: Joint, values: Mapping[str, float]) -> float:
    if joint.type == "fixed":
        return 0.0
    if joint.mimic is not None:
        m = joint.mimic
        return m.multiplier * _value_of(chain.key(m.joint), values) + m.offset
    return _value_of(chain.key(joint.name), values)


def _value_of(name: str, values: Mapping[str, float]) -> float:
    if name not in values:
        raise InvalidInput(f"no value for joint {name!r}")
    v = float(values[name])
    if not math.isfinite(v):
        raise InvalidInput(f"joint {name!r} must be finite, not {v}")
    return v


def joint_transforms(chain: Chain, values: Mapping[str, float]) -> dict[str, Transform]:
    """For /tf: {joint name: child frame in parent frame} for URDF values (rad, m), keyed
    by the model's joint names (`ArmModel.to_urdf`'s, without the chain's joint prefix).

    Fixed joints are included (they belong on /tf_static); mimic joints follow
    their master, so `values` needs only `Chain.movable`.
    """
    return {j.name: j.transform(_value(chain, j, values)) for j in chain.joints}


def link_poses(chain: Chain, values: Mapping[str, float]) -> dict[str, Transform]:
    """Every link's frame in the root frame (base_link) for URDF values."""
    poses = {chain.root: Transform()}
    for j in chain.joints:  # parents come before children by construction
        poses[j.child] = poses[j.parent] * j.transform(_value(chain, j, values))
    return poses


def tool_pose(chain: Chain, values: Mapping[str, float]) -> Transform:
    """base_link -> tool0 for URDF values."""
    return link_poses(chain, values)[chain.tool]
