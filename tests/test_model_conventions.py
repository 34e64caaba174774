"""The arm-degrees <-> URDF table, the gripper map, and validation of the model's inputs."""

from __future__ import annotations

import ast
import math
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from al5d.model import (
    ARM_JOINTS,
    CONVENTIONS,
    ArmModel,
    Geometry,
    GripperMap,
    InvalidInput,
    Range,
    Ranges,
    joint_from_urdf,
    joint_positions,
    joint_to_urdf,
    link_poses,
)
from al5d_rig.model_support import CHAIN, GEOMETRY, MODEL, PRESETS, RANGES

MODEL_DIR = Path(__file__).resolve().parents[1] / "src" / "al5d" / "model"


def tip_of(link: str, degrees: dict[str, float]) -> tuple[float, float, float]:
    """A link's origin in base_link by the generic chain FK (URDF values)."""
    values = MODEL.to_urdf({**degrees, "gripper": 0.0})
    return link_poses(CHAIN, values)[link].translation


def zero() -> dict[str, float]:
    return dict.fromkeys(ARM_JOINTS, 0.0)


def test_the_package_imports_only_the_standard_library_numpy_and_itself() -> None:
    allowed = set(sys.stdlib_module_names) | {"numpy"}
    for path in MODEL_DIR.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                ok = top in allowed or name == "al5d.model" or name.startswith("al5d.model.")
                assert ok, f"{path.name} imports {name}"


@settings(max_examples=500, deadline=None)
@given(st.sampled_from(ARM_JOINTS), st.floats(-180, 180))
def test_degrees_to_urdf_and_back_is_the_identity(joint: str, degrees: float) -> None:
    assert joint_from_urdf(joint, joint_to_urdf(joint, degrees)) == pytest.approx(
        degrees, abs=1e-12
    )


def test_every_arm_joint_has_a_convention_with_a_unit_axis() -> None:
    assert set(CONVENTIONS) == set(ARM_JOINTS)
    for c in CONVENTIONS.values():
        assert math.hypot(*c.axis) == pytest.approx(1.0)
        assert c.sign in (1.0, -1.0)


def test_base_plus_90_turns_the_arm_right_toward_minus_y() -> None:
    pose = {**zero(), "shoulder": 90.0, "base": 90.0}
    for elbow in (joint_positions(GEOMETRY, pose)["elbow"], tip_of("forearm_link", pose)):
        assert elbow[0] == pytest.approx(0.0, abs=1e-12)
        assert elbow[1] == pytest.approx(-GEOMETRY.humerus)
    assert joint_to_urdf("base", 90.0) == pytest.approx(-math.pi / 2)


def test_shoulder_plus_90_puts_the_elbow_in_front_at_shoulder_height() -> None:
    pose = {**zero(), "shoulder": 90.0}
    for points in (joint_positions(GEOMETRY, pose), None):
        elbow = points["elbow"] if points else tip_of("forearm_link", pose)
        assert elbow == pytest.approx((GEOMETRY.humerus, 0.0, GEOMETRY.base_height))


def test_shoulder_minus_30_leans_the_upper_arm_backwards() -> None:
    elbow = tip_of("forearm_link", {**zero(), "shoulder": -30.0})
    assert elbow[0] == pytest.approx(-GEOMETRY.humerus / 2)
    assert elbow[2] > GEOMETRY.base_height


def test_elbow_plus_90_bends_the_forearm_down_when_the_upper_arm_is_horizontal() -> None:
    pose = {**zero(), "shoulder": 90.0, "elbow": 90.0}
    wrist = tip_of("wrist_link", pose)
    assert wrist == pytest.approx(
        (GEOMETRY.humerus, 0.0, GEOMETRY.base_height - GEOMETRY.ulna), abs=1e-12
    )
    assert joint_positions(GEOMETRY, pose)["wrist"] == pytest.approx(wrist, abs=1e-12)


def test_wrist_minus_90_bends_down_like_the_elbow_and_plus_90_up() -> None:
    level = {**zero(), "shoulder": 90.0}
    wrist_z = GEOMETRY.base_height
    down = tip_of("tool0", {**level, "wrist": -90.0})
    up = tip_of("tool0", {**level, "wrist": 90.0})
    assert down[2] == pytest.approx(wrist_z - GEOMETRY.gripper)
    assert up[2] == pytest.approx(wrist_z + GEOMETRY.gripper)
    # Elbow +90 and wrist -90 bend the same way: both turn the gripper to point down.
    for bent in ({**level, "elbow": 90.0}, {**level, "wrist": -90.0}):
        tip, wrist = tip_of("tool0", bent), tip_of("wrist_link", bent)
        direction = tuple((a - b) / GEOMETRY.gripper for a, b in zip(tip, wrist, strict=True))
        assert direction == pytest.approx((0.0, 0.0, -1.0), abs=1e-12)


def test_wrist_rotate_is_counter_clockwise_about_the_gripper_axis() -> None:
    # Arm straight up: the gripper axis is +z; the left finger starts toward +y and
    # a positive rotate turns it toward -x (counter-clockwise seen from above).
    values = MODEL.to_urdf({**zero(), "wrist_rotate": 90.0, "gripper": 0.0})
    poses = link_poses(CHAIN, values)
    finger = poses["finger_left_link"]
    y_axis = finger.apply((0.0, 1.0, 0.0))
    origin = finger.translation
    direction = tuple(a - b for a, b in zip(y_axis, origin, strict=True))
    assert direction == pytest.approx((-1.0, 0.0, 0.0), abs=1e-12)


def test_urdf_limits_are_sorted_when_the_sign_flips() -> None:
    model = ArmModel.from_config({**RANGES, "base": (-80.0, 60.0), "wrist": (-70.0, 20.0)})
    assert model.urdf_limits("base") == pytest.approx((math.radians(-60), math.radians(80)))
    assert model.urdf_limits("wrist") == pytest.approx((math.radians(-20), math.radians(70)))
    assert model.urdf_limits("elbow") == pytest.approx((0.0, math.radians(135)))


def test_the_gripper_map_runs_from_the_open_gap_to_zero_over_its_range() -> None:
    gm = GripperMap.of(0.032, Range(10.0, 100.0))  # a range other than 0..90, on purpose
    assert gm.gap_from_deg(10.0) == pytest.approx(0.032)
    assert gm.gap_from_deg(100.0) == pytest.approx(0.0)
    assert gm.gap_from_deg(55.0) == pytest.approx(0.016)
    assert gm.deg_from_gap(0.008) == pytest.approx(77.5)
    assert gm.gap_limits == (0.0, 0.032)
    assert gm.metres_per_deg == pytest.approx(0.032 / 90.0)


@settings(max_examples=300, deadline=None)
@given(st.floats(0, 90))
def test_gripper_degrees_to_the_gap_in_metres_and_back(degrees: float) -> None:
    # The URDF's `gripper` is the gap itself (what GripperCommand and MoveIt mean).
    urdf = MODEL.to_urdf({"gripper": degrees})
    assert 0.0 <= urdf["gripper"] <= GEOMETRY.gripper_open + 1e-15
    assert MODEL.from_urdf(urdf)["gripper"] == pytest.approx(degrees, abs=1e-9)


def test_a_whole_pose_round_trips_and_the_finger_mimics_are_ignored() -> None:
    pose = {**PRESETS["park"], "gripper": 30.0}
    values = MODEL.to_urdf(pose)
    assert set(values) == set(pose)
    half = values["gripper"] / 2
    back = MODEL.from_urdf({**values, "gripper_left": half, "gripper_right": half})
    assert back == pytest.approx(pose)
    with pytest.raises(InvalidInput, match="unknown joint 'elbo'"):
        MODEL.to_urdf({"elbo": 3.0})


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("humerus", 0.0, "geometry.humerus must be > 0"),
        ("ulna", -0.1, "geometry.ulna must be > 0"),
        ("gripper", math.nan, "geometry.gripper must be finite"),
        ("base_height", math.inf, "geometry.base_height must be finite"),
        ("shoulder_offset", -0.001, "geometry.shoulder_offset must be >= 0"),
        ("gripper_open", "wide", "geometry.gripper_open must be a number"),
        ("table_height", 0.07, "geometry.table_height must be below the shoulder axis"),
        ("table_height", math.nan, "geometry.table_height must be finite"),
    ],
)
def test_bad_geometry_is_refused_naming_the_field(field: str, value: object, message: str) -> None:
    with pytest.raises(InvalidInput, match=message):
        Geometry(**{field: value})  # type: ignore[arg-type]


def test_geometry_overrides_and_unknown_fields() -> None:
    assert ArmModel.from_config(RANGES, {"ulna": 0.183}).geometry.ulna == 0.183
    assert ArmModel.from_config(RANGES, {"table_height": -0.02}).geometry.table_height == -0.02
    assert Geometry().table_height == 0.0
    with pytest.raises(InvalidInput, match=r"unknown field.*ulnar"):
        ArmModel.from_config(RANGES, {"ulnar": 0.183})


def test_bad_ranges_are_refused_naming_the_joint() -> None:
    with pytest.raises(InvalidInput, match=r"missing joint.*gripper"):
        Ranges.from_mapping({k: v for k, v in RANGES.items() if k != "gripper"})
    with pytest.raises(InvalidInput, match="elbow: a range needs lo < hi"):
        Ranges.from_mapping({**RANGES, "elbow": (135.0, 0.0)})
    with pytest.raises(InvalidInput, match="wrist: a range must be finite"):
        Ranges.from_mapping({**RANGES, "wrist": (-90.0, math.nan)})
