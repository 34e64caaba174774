"""Joint names, ranges, and the one table that maps the arm's degrees to URDF values.

The arm's own degrees (used by the driver, the config and the presets):

    base          -90 left .. 0 middle .. +90 right, seen from above
    shoulder      -30 backwards .. 0 vertical .. +90 horizontal, forward
    elbow         0 straight .. 90 right angle, bent down .. 135 inwards
    wrist         -90 down .. 0 straight .. +90 up ("down" bends like the elbow)
    wrist_rotate  -90 .. 0 .. +90 about the gripper's own axis
    gripper       servo degrees, open end of its range .. closed end

The URDF (REP 103: x forward, y left, z up, counter-clockwise positive, radians)
has every joint at 0 with the arm straight up, so every offset is 0 and only
signs differ: `URDF = sign * radians(degrees - offset_deg)`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

from al5d.model.errors import InvalidInput

#: The five revolute joints, base to tip: the planning group `arm`.
ARM_JOINTS: Final = ("base", "shoulder", "elbow", "wrist", "wrist_rotate")
#: Every joint the arm has, in the driver's order.
JOINTS: Final = ("base", "shoulder", "elbow", "wrist", "gripper", "wrist_rotate")
#: The URDF's finger joints: each moves its finger by half the gap, mimicking `gripper`,
#: whose value is the gap itself (what GripperCommand and MoveIt's gripper handle mean).
GRIPPER_FINGERS: Final = ("gripper_left", "gripper_right")


@dataclass(frozen=True)
class Convention:
    """How one revolute joint's arm degrees map to its URDF angle about `axis`."""

    joint: str
    #: The joint's axis in its own link frame (URDF `<axis xyz>`).
    axis: tuple[float, float, float]
    #: +1 when a positive arm angle turns counter-clockwise about `axis`.
    sign: float
    #: The arm's degrees at which the URDF angle is 0.
    offset_deg: float
    #: What the positive direction means physically (documentation and tests).
    meaning: str


#: The one place where arm degrees meet URDF radians. Pitch joints turn about +y
#: (with the arm in the x-z plane, +y tilts z toward +x: forward and down).
CONVENTIONS: Final[Mapping[str, Convention]] = {
    c.joint: c
    for c in (
        Convention("base", (0.0, 0.0, 1.0), -1.0, 0.0, "+deg turns right, toward -y"),
        Convention("shoulder", (0.0, 1.0, 0.0), 1.0, 0.0, "+deg tilts the upper arm forward"),
        Convention("elbow", (0.0, 1.0, 0.0), 1.0, 0.0, "+deg bends the forearm down"),
        Convention("wrist", (0.0, 1.0, 0.0), -1.0, 0.0, "+deg bends the hand up"),
        Convention(
            "wrist_rotate",
            (0.0, 0.0, 1.0),
            1.0,
            0.0,
            "+deg counter-clockwise about the gripper's outward axis (tool0 z)",
        ),
    )
}


def joint_to_urdf(joint: str, degrees: float) -> float:
    """Arm degrees of a revolute joint -> its URDF angle in radians."""
    c = CONVENTIONS[joint]
    return c.sign * math.radians(degrees - c.offset_deg)


def joint_from_urdf(joint: str, radians: float) -> float:
    """URDF angle in radians of a revolute joint -> arm degrees."""
    c = CONVENTIONS[joint]
    return math.degrees(radians) * c.sign + c.offset_deg


@dataclass(frozen=True)
class Range:
    """A joint's safe range in the arm's degrees, lo < hi."""

    lo: float
    hi: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)):
            raise InvalidInput(f"a range must be finite, not {self.lo}..{self.hi}")
        if not self.lo < self.hi:
            raise InvalidInput(f"a range needs lo < hi, not {self.lo}..{self.hi}")

    def __contains__(self, degrees: object) -> bool:
        return isinstance(degrees, int | float) and self.lo <= degrees <= self.hi


@dataclass(frozen=True)
class Ranges:
    """The safe range of every joint (the config's `range_deg`)."""

    base: Range
    shoulder: Range
    elbow: Range
    wrist: Range
    wrist_rotate: Range
    #: The first end is fully open, the second fully closed.
    gripper: Range

    @classmethod
    def from_mapping(cls, ranges: Mapping[str, Sequence[float]]) -> Ranges:
        """From {joint: (lo, hi)} as the config holds them; every joint must be there."""
        missing = [name for name in JOINTS if name not in ranges]
        if missing:
            raise InvalidInput(f"ranges: missing joint(s) {', '.join(missing)}")
        unknown = sorted(set(ranges) - set(JOINTS))
        if unknown:
            raise InvalidInput(f"ranges: unknown joint(s) {', '.join(unknown)}")
        built: dict[str, Range] = {}
        for name in JOINTS:
            pair = tuple(ranges[name])
            if len(pair) != 2:
                raise InvalidInput(f"ranges: {name} needs [lo, hi], not {list(pair)}")
            try:
                built[name] = Range(float(pair[0]), float(pair[1]))
            except InvalidInput as err:
                raise InvalidInput(f"ranges: {name}: {err}") from None
        return cls(**built)

    def of(self, joint: str) -> Range:
        """The range of a joint by name."""
        if joint not in JOINTS:
            raise InvalidInput(f"unknown joint {joint!r}")
        result: Range = getattr(self, joint)
        return result

    def as_dict(self) -> dict[str, tuple[float, float]]:
        """{joint: (lo, hi)}, in the driver's joint order."""
        return {name: (self.of(name).lo, self.of(name).hi) for name in JOINTS}


@dataclass(frozen=True)
class GripperMap:
    """Gripper servo degrees <-> the gap between the fingers (metres), linear.

    The gap goes from `gap_open_m` at `open_deg` to 0 at `closed_deg`. The URDF
    joint `gripper` is the gap (what a ROS GripperCommand's `position` means, and
    what MoveIt's gripper handle sends: the joint's value); each finger joint
    mimics it with half.
    """

    open_deg: float
    closed_deg: float
    gap_open_m: float

    def __post_init__(self) -> None:
        values = (self.open_deg, self.closed_deg, self.gap_open_m)
        if not all(math.isfinite(v) for v in values):
            raise InvalidInput(f"gripper map must be finite, not {values}")
        if self.open_deg == self.closed_deg or self.gap_open_m <= 0:
            raise InvalidInput(f"gripper map needs distinct ends and a gap > 0, not {values}")

    @classmethod
    def of(cls, gap_open_m: float, gripper_range: Range) -> GripperMap:
        """From the geometry's open gap and the gripper's range (lo = open, hi = closed)."""
        return cls(gripper_range.lo, gripper_range.hi, gap_open_m)

    def gap_from_deg(self, degrees: float) -> float:
        """Servo degrees -> gap between the fingers, metres."""
        return self.gap_open_m * (self.closed_deg - degrees) / (self.closed_deg - self.open_deg)

    def deg_from_gap(self, gap_m: float) -> float:
        """Gap between the fingers in metres -> servo degrees."""
        return self.closed_deg - gap_m / self.gap_open_m * (self.closed_deg - self.open_deg)

    @property
    def gap_limits(self) -> tuple[float, float]:
        """(lower, upper) of the URDF `gripper` joint: closed .. open, metres."""
        return 0.0, self.gap_open_m

    @property
    def metres_per_deg(self) -> float:
        """Gap per servo degree (for velocity limits), metres."""
        return self.gap_open_m / abs(self.closed_deg - self.open_deg)


def urdf_limits(joint: str, ranges: Ranges, gripper: GripperMap) -> tuple[float, float]:
    """(lower, upper) of a joint in URDF units, sign flips sorted out so lower < upper."""
    if joint == "gripper":
        return gripper.gap_limits
    r = ranges.of(joint)
    a, b = joint_to_urdf(joint, r.lo), joint_to_urdf(joint, r.hi)
    return (a, b) if a < b else (b, a)


def degrees_to_urdf(degrees: Mapping[str, float], gripper: GripperMap) -> dict[str, float]:
    """{joint: arm degrees} -> {URDF joint: radians or metres}, for the joints given.

    The finger joints (mimics) are left out: robot_state_publisher and MoveIt derive them.
    """
    out: dict[str, float] = {}
    for joint, value in degrees.items():
        if joint == "gripper":
            out[joint] = gripper.gap_from_deg(value)
        elif joint in CONVENTIONS:
            out[joint] = joint_to_urdf(joint, value)
        else:
            raise InvalidInput(f"unknown joint {joint!r}")
    return out


def urdf_speeds_to_degrees(
    velocities: Mapping[str, float], gripper: GripperMap
) -> dict[str, float]:
    """{URDF joint: velocity limit, rad/s or m/s for the gripper} -> {joint: deg/s}; the
    finger mimics and joints not the arm's are left out."""
    out: dict[str, float] = {}
    for joint, v in velocities.items():
        if joint == "gripper":
            out[joint] = v / gripper.metres_per_deg
        elif joint in CONVENTIONS:
            out[joint] = math.degrees(v)
    return out


def urdf_to_degrees(values: Mapping[str, float], gripper: GripperMap) -> dict[str, float]:
    """{URDF joint: radians or metres} -> {joint: arm degrees}; the finger mimics are ignored."""
    out: dict[str, float] = {}
    for joint, value in values.items():
        if joint == "gripper":
            out[joint] = gripper.deg_from_gap(value)
        elif joint in CONVENTIONS:
            out[joint] = joint_from_urdf(joint, value)
        elif joint not in GRIPPER_FINGERS:
            raise InvalidInput(f"unknown joint {joint!r}")
    return out
