"""Shared inputs of the model tests: the shipped arm's ranges, speeds and presets.

Read from the one default configuration, so the model's tests judge the model of
the arm the server drives.
"""

from __future__ import annotations

from typing import Final

from al5d.arm.config import load_config
from al5d.model import ArmModel, Geometry, build_chain

_CONFIG = load_config()
RANGES: Final = {name: tuple(j.range_deg) for name, j in _CONFIG.joints.items()}
#: deg/s of the default servos at 6 V (HS-485HB, HS-805BB, HS-755HB, HS-645MG, HS-422).
SPEEDS: Final = {name: j.speed_deg_s for name, j in _CONFIG.joints.items()}
PRESETS: Final = {name: dict(pose) for name, pose in _CONFIG.presets.items()}

MODEL: Final = ArmModel.from_config(RANGES)
GEOMETRY: Final = Geometry()
CHAIN: Final = build_chain(MODEL, SPEEDS)


def mid_pose() -> dict[str, float]:
    """A pose well inside every range (arm forward, forearm down, hand level-ish)."""
    return {"base": 10.0, "shoulder": 40.0, "elbow": 80.0, "wrist": -10.0, "wrist_rotate": 15.0}
