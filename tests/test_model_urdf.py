"""The generated URDF, read back by an independent parser (yourdfpy), against our FK."""

from __future__ import annotations

import io
import math
import random
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yourdfpy  # type: ignore[import-untyped]

from al5d.model import (
    ARM_JOINTS,
    ArmModel,
    InvalidInput,
    build_chain,
    forward,
    joint_positions,
    joint_transforms,
    link_poses,
    urdf,
    urdf_from_chain,
)
from al5d.model.transforms import matrix_from_quat
from al5d_rig.model_support import CHAIN, GEOMETRY, MODEL, RANGES, SPEEDS

TEXT = urdf(MODEL, SPEEDS)


def load(text: str) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=True, load_meshes=False)


@pytest.fixture(scope="module")
def robot() -> yourdfpy.URDF:
    return load(TEXT)


def random_degrees(rng: random.Random) -> dict[str, float]:
    return {j: rng.uniform(lo, hi) for j, (lo, hi) in RANGES.items()}


def test_the_urdf_is_valid_and_has_exactly_the_joints_named(robot: yourdfpy.URDF) -> None:
    assert robot.validate()
    assert robot.robot.name == "al5d"
    types = {name: j.type for name, j in robot.joint_map.items()}
    assert types == {
        "base": "revolute",
        "shoulder": "revolute",
        "elbow": "revolute",
        "wrist": "revolute",
        "wrist_rotate": "revolute",
        "gripper": "prismatic",
        "gripper_left": "prismatic",
        "gripper_right": "prismatic",
        "tool0_joint": "fixed",
    }
    assert robot.base_link == "base_link"
    assert "tool0" in robot.link_map
    for finger in ("gripper_left", "gripper_right"):
        mimic = robot.joint_map[finger].mimic
        assert (mimic.joint, mimic.multiplier, mimic.offset) == ("gripper", 0.5, 0.0)


def test_limits_are_the_arm_ranges_converted_to_urdf_units(robot: yourdfpy.URDF) -> None:
    expected = {
        "base": (-math.pi / 2, math.pi / 2),
        "shoulder": (math.radians(-30), math.pi / 2),
        "elbow": (0.0, math.radians(135)),
        "wrist": (-math.pi / 2, math.pi / 2),
        "wrist_rotate": (-math.pi / 2, math.pi / 2),
        "gripper": (0.0, GEOMETRY.gripper_open),
        "gripper_left": (0.0, GEOMETRY.gripper_open / 2),
        "gripper_right": (0.0, GEOMETRY.gripper_open / 2),
    }
    for name, (lower, upper) in expected.items():
        limit = robot.joint_map[name].limit
        assert (limit.lower, limit.upper) == pytest.approx((lower, upper), abs=1e-15), name
        assert limit.lower < limit.upper
    for name in ARM_JOINTS:
        assert robot.joint_map[name].limit.velocity == pytest.approx(math.radians(SPEEDS[name]))
    # 375 deg/s over a 90 deg range is 4.17 ranges a second of the 32 mm gap.
    assert robot.joint_map["gripper"].limit.velocity == pytest.approx(375 / 90 * 0.032)


def test_an_asymmetric_range_with_a_sign_flip_keeps_lower_below_upper() -> None:
    model = ArmModel.from_config({**RANGES, "base": (-80.0, 60.0), "wrist": (-70.0, 20.0)})
    robot = load(urdf(model, SPEEDS))
    base, wrist = robot.joint_map["base"].limit, robot.joint_map["wrist"].limit
    assert (base.lower, base.upper) == pytest.approx((math.radians(-60), math.radians(80)))
    assert (wrist.lower, wrist.upper) == pytest.approx((math.radians(-20), math.radians(70)))


def test_our_closed_form_fk_agrees_with_yourdfpy_on_random_joint_sets(
    robot: yourdfpy.URDF,
) -> None:
    rng = random.Random(7)
    worst = 0.0
    for _ in range(300):
        degrees = random_degrees(rng)
        robot.update_cfg(MODEL.to_urdf(degrees))
        theirs = robot.get_transform("tool0", "base_link")
        ours = forward(GEOMETRY, degrees)
        worst = max(worst, float(np.linalg.norm(theirs[:3, 3] - ours.position)))
        assert np.allclose(theirs[:3, :3], ours.matrix, atol=1e-9)
        points = joint_positions(GEOMETRY, degrees)
        for joint, link in (("elbow", "forearm_link"), ("wrist", "wrist_link")):
            where = robot.get_transform(link, "base_link")[:3, 3]
            assert np.allclose(where, points[joint], atol=1e-9)
    assert worst <= 1e-6


def test_the_generic_chain_fk_agrees_with_yourdfpy_for_every_link(robot: yourdfpy.URDF) -> None:
    rng = random.Random(11)
    for _ in range(100):
        values = MODEL.to_urdf(random_degrees(rng))
        robot.update_cfg(values)
        poses = link_poses(CHAIN, values)
        for link, pose in poses.items():
            theirs = robot.get_transform(link, "base_link")
            assert np.allclose(theirs[:3, 3], pose.translation, atol=1e-9), link
            assert np.allclose(theirs[:3, :3], matrix_from_quat(pose.rotation), atol=1e-9), link
        # /tf's per-joint transforms compose to the same poses.
        steps = joint_transforms(CHAIN, values)
        for joint in CHAIN.joints:
            composed = poses[joint.parent] * steps[joint.name]
            assert np.allclose(composed.translation, poses[joint.child].translation, atol=1e-12)


def test_the_fingers_open_to_the_configured_gap(robot: yourdfpy.URDF) -> None:
    for degrees, gap in ((0.0, GEOMETRY.gripper_open), (45.0, GEOMETRY.gripper_open / 2)):
        robot.update_cfg(MODEL.to_urdf({**dict.fromkeys(ARM_JOINTS, 0.0), "gripper": degrees}))
        left = robot.get_transform("finger_left_link", "base_link")[:3, 3]
        right = robot.get_transform("finger_right_link", "base_link")[:3, 3]
        assert float(np.linalg.norm(left - right)) == pytest.approx(gap)


def test_a_prefix_goes_on_link_names_only() -> None:
    text = urdf(MODEL, SPEEDS, robot_name="lefty", prefix="left/")
    robot = load(text)
    assert robot.robot.name == "lefty"
    assert set(robot.link_map) == {"left/" + name for name in load(TEXT).link_map}
    assert set(robot.joint_map) == set(load(TEXT).joint_map)
    robot.update_cfg({"shoulder": math.pi / 2})
    assert robot.get_transform("left/tool0", "left/base_link")[0, 3] == pytest.approx(
        GEOMETRY.max_reach + GEOMETRY.gripper
    )


def test_geometry_overrides_reach_the_urdf() -> None:
    model = ArmModel.from_config(RANGES, {"ulna": 0.183, "base_height": 0.07})
    robot = load(urdf(model, SPEEDS))
    robot.update_cfg({})
    top = robot.get_transform("tool0", "base_link")[2, 3]
    assert top == pytest.approx(0.07 + GEOMETRY.humerus + 0.183 + GEOMETRY.gripper)


def test_every_body_has_visual_and_collision_geometry(robot: yourdfpy.URDF) -> None:
    for name, link in robot.link_map.items():
        if name in ("tool0", "gripper_link"):  # frames without a body: the tip, the gap
            continue
        # Looks of several parts (`model.looks`); one body for collisions and the table.
        assert len(link.visuals) >= 1 and len(link.collisions) == 1, name
        for part in (*link.visuals, link.collisions[0]):
            geometry = part.geometry
            assert (geometry.box is not None) or (geometry.cylinder is not None)


def test_the_xml_is_plain_and_numbers_are_exact() -> None:
    root = ET.fromstring(TEXT)
    limit = root.find("joint[@name='elbow']/limit")
    assert limit is not None
    assert float(limit.get("upper", "nan")) == math.radians(135)
    assert urdf_from_chain(CHAIN) == TEXT


def test_missing_or_bad_speeds_are_refused() -> None:
    with pytest.raises(InvalidInput, match="missing joint gripper"):
        build_chain(MODEL, {k: v for k, v in SPEEDS.items() if k != "gripper"})
    with pytest.raises(InvalidInput, match="elbow must be finite and > 0"):
        build_chain(MODEL, {**SPEEDS, "elbow": 0.0})
