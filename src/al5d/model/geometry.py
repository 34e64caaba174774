"""The arm's dimensions in metres: one frozen, validated record."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from al5d.model.errors import InvalidInput


@dataclass(frozen=True)
class Geometry:
    """Lengths of the AL5D in metres; defaults are Lynxmotion's published constants.

    Every field can be overridden (arms differ: see the kinematics reference).
    """

    #: Table to the shoulder axis, along the base axis.
    base_height: float = 0.06731
    #: Base axis to the shoulder axis, horizontally along the arm (0 on the AL5D).
    shoulder_offset: float = 0.0
    #: Shoulder axis to elbow axis (5.75 in).
    humerus: float = 0.14605
    #: Elbow axis to wrist pitch axis (7.375 in).
    ulna: float = 0.187325
    #: Wrist pitch axis to the tool tip (tool0), the wrist rotate included.
    gripper: float = 0.100
    #: Gap between the fingers when fully open.
    gripper_open: float = 0.032
    #: Height of the table's top in base_link (0: the base stands on it; below 0 when
    #: the arm stands on a plate). Cartesian moves keep the arm above it.
    table_height: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InvalidInput(f"geometry.{f.name} must be a number, not {value!r}")
            if not math.isfinite(value):
                raise InvalidInput(f"geometry.{f.name} must be finite, not {value}")
            # The offset may be zero (the AL5D has none), the table anywhere below the
            # shoulder; every length must be positive.
            if f.name == "table_height":
                if value >= self.base_height:
                    raise InvalidInput(
                        f"geometry.table_height must be below the shoulder axis "
                        f"(base_height {self.base_height:g}), not {value}"
                    )
            elif f.name == "shoulder_offset":
                if value < 0:
                    raise InvalidInput(f"geometry.{f.name} must be >= 0, not {value}")
            elif value <= 0:
                raise InvalidInput(f"geometry.{f.name} must be > 0, not {value}")

    @property
    def max_reach(self) -> float:
        """Largest distance from the shoulder axis to the wrist pitch axis."""
        return self.humerus + self.ulna
