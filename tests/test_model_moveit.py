"""MoveIt data (SRDF, joint limits, kinematics, controllers) against the URDF it goes with."""

from __future__ import annotations

import io
import itertools
import math
import random
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
import yourdfpy  # type: ignore[import-untyped]

from al5d.model import (
    ARM_JOINTS,
    InvalidInput,
    build_chain,
    controllers,
    joint_limits,
    kinematics,
    moveit_config,
    srdf,
    urdf,
)
from al5d.model.collisions import disabled_pairs
from al5d_rig.model_support import CHAIN, MODEL, PRESETS, RANGES, SPEEDS

URDF = yourdfpy.URDF.load(io.StringIO(urdf(MODEL, SPEEDS)), load_meshes=False)
SRDF = ET.fromstring(srdf(MODEL, CHAIN, PRESETS))


def test_groups_name_links_and_joints_of_the_urdf() -> None:
    arm = SRDF.find("group[@name='arm']/chain")
    assert arm is not None
    assert (arm.get("base_link"), arm.get("tip_link")) == ("base_link", "tool0")
    chain_joints = []
    link = "tool0"
    while link != URDF.base_link:
        joint = next(j for j in URDF.joint_map.values() if j.child == link)
        chain_joints.append(joint.name)
        link = joint.parent
    movable = [j for j in reversed(chain_joints) if URDF.joint_map[j].type != "fixed"]
    assert movable == list(ARM_JOINTS)
    gripper = [j.get("name") for j in SRDF.findall("group[@name='gripper']/joint")]
    assert gripper == ["gripper"]
    assert URDF.joint_map["gripper"].type == "prismatic"


def test_named_states_are_the_presets_in_urdf_units_within_the_limits() -> None:
    states = {(s.get("group"), s.get("name")): s for s in SRDF.findall("group_state")}
    for name, preset in PRESETS.items():
        values = {j.get("name"): float(j.get("value", "nan")) for j in states[("arm", name)]}
        assert list(values) == list(ARM_JOINTS)
        expected = MODEL.to_urdf({j: preset[j] for j in ARM_JOINTS})
        assert values == pytest.approx(expected, abs=1e-15)
        grip = {j.get("name"): float(j.get("value", "nan")) for j in states[("gripper", name)]}
        assert grip == pytest.approx(
            {"gripper": MODEL.to_urdf({"gripper": preset["gripper"]})["gripper"]}
        )
        for joint, value in {**values, **grip}.items():
            limit = URDF.joint_map[joint].limit
            assert limit.lower - 1e-12 <= value <= limit.upper + 1e-12
    assert float(states[("gripper", "open")][0].get("value", "nan")) == pytest.approx(0.032)
    assert float(states[("gripper", "closed")][0].get("value", "nan")) == 0.0
    # park really differs from ready: the values are not copied from one place.
    assert states[("arm", "park")][1].get("value") != states[("arm", "ready")][1].get("value")


def test_the_end_effector_hangs_on_tool0() -> None:
    eef = SRDF.find("end_effector")
    assert eef is not None
    assert eef.attrib == {
        "name": "hand",
        "parent_link": "tool0",
        "group": "gripper",
        "parent_group": "arm",
    }


def test_disabled_pairs_name_urdf_links_and_cover_every_adjacent_pair() -> None:
    pairs = {
        frozenset((d.get("link1"), d.get("link2"))): d.get("reason")
        for d in SRDF.findall("disable_collisions")
    }
    for pair in pairs:
        assert pair <= set(URDF.link_map)
    bodies = {name for name, link in URDF.link_map.items() if link.collisions}
    for joint in URDF.joint_map.values():
        if {joint.parent, joint.child} <= bodies:
            assert pairs[frozenset((joint.parent, joint.child))] == "Adjacent"
    assert pairs[frozenset(("finger_left_link", "finger_right_link"))] == "User"
    # Pairs that do meet keep their check: the hand can reach down to the base.
    assert frozenset(("base_link", "hand_link")) not in pairs
    assert "Never" in pairs.values()


def _boxes(robot: yourdfpy.URDF, link: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A link's collision shape as an oriented box: centre, axes (columns), half sizes."""
    collision = robot.link_map[link].collisions[0]
    g = collision.geometry
    half = (
        np.asarray(g.box.size) / 2
        if g.box is not None
        else np.array([g.cylinder.radius, g.cylinder.radius, g.cylinder.length / 2])
    )
    pose = robot.get_transform(link, robot.base_link) @ collision.origin
    return pose[:3, 3], pose[:3, :3], half


def _overlap(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> bool:
    """Separating-axis test of two oriented boxes (15 axes)."""
    (ca, ra, ha), (cb, rb, hb) = a, b
    axes = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    axes += [np.cross(ra[:, i], rb[:, j]) for i in range(3) for j in range(3)]
    d = cb - ca
    for axis in axes:
        n = np.linalg.norm(axis)
        if n < 1e-9:
            continue
        axis = axis / n
        reach_a = sum(ha[i] * abs(axis @ ra[:, i]) for i in range(3))
        reach_b = sum(hb[i] * abs(axis @ rb[:, i]) for i in range(3))
        if abs(axis @ d) > reach_a + reach_b:
            return False
    return True


def test_never_pairs_do_not_touch_in_random_poses_but_checked_pairs_can() -> None:
    # Independent of the capsules the analysis uses: yourdfpy's poses, exact box tests.
    never = [(p.link1, p.link2) for p in disabled_pairs(CHAIN) if p.reason == "Never"]
    kept = {
        frozenset(pair)
        for pair in itertools.combinations(
            [name for name, link in URDF.link_map.items() if link.collisions], 2
        )
    } - {frozenset((p.link1, p.link2)) for p in disabled_pairs(CHAIN)}
    rng = random.Random(3)
    met: set[frozenset[str]] = set()
    for _ in range(1000):
        degrees = {j: rng.uniform(lo, hi) for j, (lo, hi) in RANGES.items()}
        URDF.update_cfg(MODEL.to_urdf(degrees))
        boxes = {
            name: _boxes(URDF, name) for name, link in URDF.link_map.items() if link.collisions
        }
        for a, b in never:
            assert not _overlap(boxes[a], boxes[b]), (a, b, degrees)
        if not met:
            met = {pair for pair in kept if _overlap(*(boxes[n] for n in pair))}
    assert met, "no checked pair ever overlapped: the box test would catch nothing"


def test_joint_limits_match_the_urdf() -> None:
    limits = joint_limits(CHAIN)
    assert set(limits["joint_limits"]) == {*ARM_JOINTS, "gripper"}
    for name, entry in limits["joint_limits"].items():
        urdf_limit = URDF.joint_map[name].limit
        assert entry["has_velocity_limits"] is True
        assert entry["max_velocity"] == pytest.approx(urdf_limit.velocity)
        assert entry["has_acceleration_limits"] is True
        assert entry["max_acceleration"] == pytest.approx(urdf_limit.velocity / 0.5)
    assert joint_limits(CHAIN)["joint_limits"]["base"]["max_velocity"] == pytest.approx(
        math.radians(60 / 0.18)  # the HS-485HB: 0.18 s per 60 deg
    )
    free = joint_limits(CHAIN, ramp_s=None)["joint_limits"]["elbow"]
    assert free["has_acceleration_limits"] is False
    assert yaml.safe_load(yaml.safe_dump(limits)) == limits


def test_kinematics_and_controllers_name_the_groups_and_urdf_joints() -> None:
    groups = {g.get("name") for g in SRDF.findall("group")}
    kin = kinematics()
    assert set(kin) <= groups
    assert kin["arm"]["kinematics_solver"] == "kdl_kinematics_plugin/KDLKinematicsPlugin"
    manager = controllers()["moveit_simple_controller_manager"]
    assert manager["controller_names"] == ["arm_controller", "gripper_controller"]
    arm, grip = manager["arm_controller"], manager["gripper_controller"]
    assert (arm["type"], arm["action_ns"]) == ("FollowJointTrajectory", "follow_joint_trajectory")
    assert (grip["type"], grip["action_ns"]) == ("GripperCommand", "gripper_cmd")
    assert arm["joints"] == list(ARM_JOINTS)
    assert grip["joints"] == ["gripper"]
    for joint in arm["joints"] + grip["joints"]:
        assert joint in URDF.joint_map


def test_a_prefix_reaches_the_srdf_links() -> None:
    chain = build_chain(MODEL, SPEEDS, prefix="left/")
    doc = ET.fromstring(srdf(MODEL, chain, PRESETS, collision_samples=500))
    arm = doc.find("group[@name='arm']/chain")
    assert arm is not None and arm.get("tip_link") == "left/tool0"
    assert all(d.get("link1", "").startswith("left/") for d in doc.findall("disable_collisions"))


def test_a_preset_out_of_range_or_incomplete_is_refused() -> None:
    bad = {**PRESETS, "bad": {**PRESETS["ready"], "elbow": 150}}
    with pytest.raises(InvalidInput, match=r"preset 'bad': elbow = 150 is outside 0\.0\.\.135\.0"):
        srdf(MODEL, CHAIN, bad)
    partial = {"half": {"base": 0}}
    with pytest.raises(InvalidInput, match="preset 'half': missing joint"):
        srdf(MODEL, CHAIN, partial)


def test_the_bundle_has_the_four_files() -> None:
    bundle = moveit_config(MODEL, CHAIN, PRESETS)
    assert set(bundle) == {
        "al5d.srdf",
        "joint_limits.yaml",
        "kinematics.yaml",
        "moveit_controllers.yaml",
    }
