"""The arm model's inputs in one record: geometry plus joint ranges, and the unit mapping."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields

from al5d.model.errors import InvalidInput
from al5d.model.geometry import Geometry
from al5d.model.joints import (
    GripperMap,
    Ranges,
    degrees_to_urdf,
    urdf_limits,
    urdf_speeds_to_degrees,
    urdf_to_degrees,
)


@dataclass(frozen=True)
class ArmModel:
    """What every kinematic function needs: the arm's lengths and its joints' safe ranges."""

    ranges: Ranges
    geometry: Geometry = field(default_factory=Geometry)
    #: Derived from `geometry.gripper_open` and `ranges.gripper`; not an input.
    gripper_map: GripperMap = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        gm = GripperMap.of(self.geometry.gripper_open, self.ranges.gripper)
        object.__setattr__(self, "gripper_map", gm)

    @classmethod
    def from_config(
        cls,
        ranges: Mapping[str, Sequence[float]],
        geometry: Mapping[str, float] | None = None,
    ) -> ArmModel:
        """From plain config values: {joint: [lo, hi]} and optional geometry overrides (metres)."""
        overrides = dict(geometry or {})
        known = {f.name for f in fields(Geometry)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise InvalidInput(
                f"geometry: unknown field(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(known))}"
            )
        return cls(Ranges.from_mapping(ranges), Geometry(**overrides))

    def to_urdf(self, degrees: Mapping[str, float]) -> dict[str, float]:
        """{joint: arm degrees} -> {URDF joint: radians, or metres for the gripper}."""
        return degrees_to_urdf(degrees, self.gripper_map)

    def from_urdf(self, values: Mapping[str, float]) -> dict[str, float]:
        """{URDF joint: radians or metres} -> {joint: arm degrees}."""
        return urdf_to_degrees(values, self.gripper_map)

    def speeds_from_urdf(self, velocities: Mapping[str, float]) -> dict[str, float]:
        """{URDF joint: velocity limit, rad/s or m/s for the gripper} -> {joint: deg/s}, the
        servos' speeds a URDF of `al5d.model.urdf` was made with; other joints left out."""
        return urdf_speeds_to_degrees(velocities, self.gripper_map)

    def urdf_limits(self, joint: str) -> tuple[float, float]:
        """(lower, upper) of a URDF joint (radians, or metres for the gripper)."""
        return urdf_limits(joint, self.ranges, self.gripper_map)
