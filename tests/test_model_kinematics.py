"""Closed-form FK and IK: round trips over the workspace, refusals with their reasons."""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from al5d.model import (
    ARM_JOINTS,
    ArmModel,
    BelowTable,
    Geometry,
    InvalidInput,
    JointOutOfRange,
    OutOfReach,
    Unreachable,
    below_table,
    forward,
    joint_positions,
    solve,
    solve_nearest_pitch,
    tool_position,
)
from al5d.model.kinematics import wrap_deg
from al5d.model.transforms import matrix_from_quat
from al5d_rig.model_support import GEOMETRY, MODEL, PRESETS, mid_pose

G = GEOMETRY
TOL_M = 1e-5  # 0.01 mm


def grid_poses() -> list[dict[str, float]]:
    """Joint sets spanning every range, limits included (about 40 000)."""
    axes = {
        "base": np.linspace(-90, 90, 7),
        "shoulder": np.linspace(-30, 90, 13),
        "elbow": np.linspace(0, 135, 16),
        "wrist": np.linspace(-90, 90, 13),
        "wrist_rotate": np.array([-90.0, 0.0, 37.5, 90.0]),
    }
    return [
        dict(zip(ARM_JOINTS, map(float, combo), strict=True))
        for combo in itertools.product(*axes.values())
    ]


def test_ik_then_fk_round_trips_over_a_dense_grid_of_the_reachable_workspace() -> None:
    # Every FK image of in-range joints is reachable, so IK must solve it, and the
    # solution must put the tip back within 0.01 mm with the same pitch and roll.
    worst_m = worst_deg = 0.0
    poses = grid_poses()
    assert len(poses) > 30000
    for pose in poses:
        target = forward(G, pose)
        sol = solve(MODEL, *target.position, target.pitch_deg, target.roll_deg)
        back = forward(G, sol)
        worst_m = max(worst_m, math.dist(back.position, target.position))
        worst_deg = max(worst_deg, abs(wrap_deg(back.pitch_deg - target.pitch_deg)))
        assert back.roll_deg == pytest.approx(target.roll_deg)
        assert all(MODEL.ranges.of(j).lo <= sol[j] <= MODEL.ranges.of(j).hi for j in ARM_JOINTS)
    assert worst_m <= TOL_M
    assert worst_deg <= 1e-5  # full stretch (elbow 0) is singular: ~1e-6 deg of rounding


@settings(max_examples=3000, deadline=None)
@given(
    x=st.floats(-0.5, 0.5),
    y=st.floats(-0.5, 0.5),
    z=st.floats(-0.3, 0.6),
    pitch=st.floats(-180, 180),
    roll=st.floats(-90, 90),
)
def test_any_target_is_solved_exactly_or_refused_never_nan(
    x: float, y: float, z: float, pitch: float, roll: float
) -> None:
    try:
        sol = solve(MODEL, x, y, z, pitch, roll)
    except Unreachable as err:
        assert str(err)
        return
    assert all(math.isfinite(v) for v in sol.values())
    back = forward(G, sol)
    assert math.dist(back.position, (x, y, z)) <= TOL_M
    assert wrap_deg(back.pitch_deg - pitch) == pytest.approx(0.0, abs=1e-6)


def test_forward_gives_the_known_preset_poses() -> None:
    up = forward(G, PRESETS["straight_up"])
    top = G.base_height + G.humerus + G.ulna + G.gripper
    assert up.position == pytest.approx((0.0, 0.0, top), abs=1e-12)
    assert up.pitch_deg == pytest.approx(90.0)
    assert up.quaternion == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-12)
    ready = forward(G, PRESETS["ready"])
    # Upper arm 60 deg up, forearm and gripper 30 deg down, all straight ahead.
    r = G.humerus * math.cos(math.radians(60)) + (G.ulna + G.gripper) * math.cos(math.radians(30))
    z = G.base_height + G.humerus * math.sin(math.radians(60)) - (G.ulna + G.gripper) / 2
    assert ready.position == pytest.approx((r, 0.0, z), abs=1e-12)
    assert ready.pitch_deg == pytest.approx(-30.0)
    assert forward(G, PRESETS["park"]).pitch_deg == pytest.approx(-70.0)


def test_the_orientation_is_rz_of_the_heading_ry_of_90_minus_pitch_rz_of_the_roll() -> None:
    pose = {"base": -30.0, "shoulder": 90.0, "elbow": 0.0, "wrist": 0.0, "wrist_rotate": 0.0}
    m = forward(G, pose).matrix
    # Heading +30 deg (left), gripper horizontal: tool0 z along the arm, x down.
    z_axis = (m[0][2], m[1][2], m[2][2])
    x_axis = (m[0][0], m[1][0], m[2][0])
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    assert z_axis == pytest.approx((c, s, 0.0), abs=1e-12)
    assert x_axis == pytest.approx((0.0, 0.0, -1.0), abs=1e-12)
    q = forward(G, mid_pose()).quaternion
    assert np.allclose(matrix_from_quat(q), forward(G, mid_pose()).matrix)
    assert q[3] >= 0.0


def test_joint_positions_are_a_chain_of_the_link_lengths() -> None:
    pts = joint_positions(G, mid_pose())
    assert math.dist(pts["shoulder"], pts["elbow"]) == pytest.approx(G.humerus)
    assert math.dist(pts["elbow"], pts["wrist"]) == pytest.approx(G.ulna)
    assert math.dist(pts["wrist"], pts["tool0"]) == pytest.approx(G.gripper)
    assert pts["tool0"] == tool_position(G, mid_pose())


def test_a_far_target_is_out_of_reach_with_both_distances() -> None:
    # Gripper level at shoulder height: the wrist is 412 mm from the shoulder.
    x = 0.412 + G.gripper
    with pytest.raises(OutOfReach) as info:
        solve(MODEL, x, 0.0, G.base_height, 0.0)
    assert str(info.value) == "out of reach: 412 mm from the shoulder, the arm reaches 333 mm"
    assert info.value.distance_m == pytest.approx(0.412)
    assert not info.value.too_close


def test_a_target_just_beyond_reach_gets_the_decimals_that_tell_the_difference() -> None:
    # 333.445 mm against a reach of 333.375 mm: equal to the millimetre and to 0.1 mm.
    x = G.max_reach + 0.00007 + G.gripper
    with pytest.raises(OutOfReach) as info:
        solve(MODEL, x, 0.0, G.base_height, 0.0)
    assert re.fullmatch(
        r"out of reach: 333\.4\d mm from the shoulder, the arm reaches 333\.38 mm", str(info.value)
    )


def test_a_target_too_close_to_the_shoulder_is_out_of_reach_the_other_way() -> None:
    # The wrist 20 mm in front of the shoulder: nearer than |ulna - humerus| = 41 mm.
    with pytest.raises(OutOfReach) as info:
        solve(MODEL, 0.020 + G.gripper, 0.0, G.base_height, 0.0)
    assert str(info.value) == (
        "out of reach: 20 mm from the shoulder, the arm reaches no closer than 41 mm"
    )
    assert info.value.too_close


def test_a_target_that_needs_a_joint_out_of_range_names_it_and_its_range() -> None:
    # FK does not check ranges: pose the arm with the elbow at 151 and ask IK for it.
    target = forward(G, {**mid_pose(), "elbow": 151.0, "shoulder": 60.0})
    with pytest.raises(JointOutOfRange) as info:
        solve(MODEL, *target.position, target.pitch_deg, target.roll_deg)
    assert str(info.value) == "elbow would need 151 deg, its range is 0..135"
    assert info.value.joint == "elbow"
    assert info.value.needed_deg == pytest.approx(151.0)


def test_every_joint_out_of_range_is_named_and_a_near_miss_keeps_its_decimals() -> None:
    target = forward(G, {**mid_pose(), "wrist": 95.0, "wrist_rotate": 135.2})
    with pytest.raises(JointOutOfRange) as info:
        solve(MODEL, *target.position, target.pitch_deg, target.roll_deg)
    assert str(info.value) == (
        "wrist would need 95 deg, its range is -90..90; "
        "wrist_rotate would need 135 deg, its range is -90..90"
    )
    near = forward(G, {**mid_pose(), "elbow": 135.2})
    with pytest.raises(JointOutOfRange, match=r"elbow would need 135\.2 deg"):
        solve(MODEL, *near.position, near.pitch_deg)


def test_a_target_exactly_at_a_limit_is_accepted() -> None:
    pose = {"base": 90.0, "shoulder": -30.0, "elbow": 135.0, "wrist": 90.0, "wrist_rotate": -90.0}
    target = forward(G, pose)
    sol = solve(MODEL, *target.position, target.pitch_deg, target.roll_deg)
    assert sol == pytest.approx(pose, abs=1e-6)


def test_a_target_behind_the_base_axis_leans_back_instead_of_turning_round() -> None:
    # Upper arm leaning back, the rest straight up: the tip is behind the base axis.
    pose = {"base": 20.0, "shoulder": -20.0, "elbow": 0.0, "wrist": 0.0, "wrist_rotate": 0.0}
    target = forward(G, pose)
    assert target.position[0] < 0
    sol = solve(MODEL, *target.position, target.pitch_deg)
    # Elbow 0 is full stretch, where the last bit of the target moves the angles by ~1e-6.
    assert sol == pytest.approx(pose, abs=1e-5)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", range(5))
def test_nan_or_infinity_anywhere_is_refused(bad: float, where: int) -> None:
    x, y, z, pitch, roll = [bad if i == where else v for i, v in enumerate((0.2, 0, 0.1, 0, 0))]
    with pytest.raises(InvalidInput, match="must be finite"):
        solve(MODEL, x, y, z, pitch, roll)
    with pytest.raises(InvalidInput, match="must be finite"):
        solve_nearest_pitch(MODEL, x, y, z, pitch, roll)


def test_forward_refuses_nan_and_a_missing_joint() -> None:
    with pytest.raises(InvalidInput, match="finite"):
        forward(G, {**mid_pose(), "elbow": math.nan})
    pose = mid_pose()
    del pose["wrist"]
    with pytest.raises(InvalidInput, match="wrist"):
        forward(G, pose)


def test_a_shoulder_offset_is_honoured_both_ways() -> None:
    model = ArmModel.from_config(MODEL.ranges.as_dict(), {"shoulder_offset": 0.02})
    up = forward(model.geometry, {**mid_pose(), "shoulder": 0.0, "elbow": 0.0, "wrist": 0.0})
    assert math.hypot(*up.position[:2]) == pytest.approx(0.02)
    target = forward(model.geometry, mid_pose())
    assert solve(model, *target.position, target.pitch_deg, target.roll_deg) == pytest.approx(
        mid_pose()
    )


def test_the_pitch_search_keeps_a_reachable_preferred_pitch() -> None:
    target = forward(G, mid_pose())
    sol, pitch = solve_nearest_pitch(MODEL, *target.position, target.pitch_deg, 15.0)
    assert pitch == pytest.approx(target.pitch_deg)
    assert sol == pytest.approx(mid_pose())


@pytest.mark.parametrize(
    ("point", "preferred"),
    [
        ((0.12, -0.05, 0.35), -90.0),
        ((0.36, 0.0, 0.2), 90.0),
        ((0.25, 0.0, 0.25), -90.0),
        ((0.2, 0.1, -0.05), 0.0),
    ],
)
def test_the_pitch_search_finds_the_nearest_reachable_pitch(
    point: tuple[float, float, float], preferred: float
) -> None:
    with pytest.raises(Unreachable):
        solve(MODEL, *point, preferred)
    sol, pitch = solve_nearest_pitch(MODEL, *point, preferred, 0.0)
    back = forward(G, sol)
    assert math.dist(back.position, point) <= TOL_M
    assert back.pitch_deg == pytest.approx(pitch, abs=1e-9)
    # Brute force at 0.01 deg: nothing reachable is nearer the preferred pitch.
    gap = abs(wrap_deg(pitch - preferred))
    for k in range(int(gap * 100)):
        for candidate in (preferred + k / 100, preferred - k / 100):
            with pytest.raises(Unreachable):
                solve(MODEL, *point, candidate)


def test_the_pitch_search_refuses_a_point_no_pitch_reaches() -> None:
    with pytest.raises(Unreachable, match=r"no pitch reaches .*at pitch 0 deg: out of reach"):
        solve_nearest_pitch(MODEL, 0.6, 0.0, 0.1)


def test_messages_use_the_documented_forms() -> None:
    pattern = re.compile(r"^out of reach: \d+ mm from the shoulder, the arm reaches \d+ mm$")
    with pytest.raises(OutOfReach) as info:
        solve(MODEL, 0.0, -0.45, 0.3, 0.0)
    assert pattern.match(str(info.value))


def test_the_table_is_judged_at_the_tip_and_at_the_wrist() -> None:
    # IK knows no table: a target under it is solved, and below_table names the point.
    assert below_table(MODEL, solve(MODEL, 0.2, 0.0, 0.0, -90.0)) is None  # on the table
    tip = below_table(MODEL, solve(MODEL, 0.2, 0.0, -0.1, -90.0))
    assert isinstance(tip, BelowTable) and tip.point == "tool tip"
    assert str(tip) == "below the table: the tool tip would be at z=-100 mm, the table is at z=0 mm"
    # Pointing 30 deg up with the tip 30 mm over the table, the wrist is 20 mm under it.
    wrist = below_table(MODEL, solve(MODEL, 0.32, 0.0, 0.03, 30.0))
    assert isinstance(wrist, BelowTable) and wrist.point == "wrist"
    # The wrist's axis is 20 mm under it; the wrist servo's body (its box in the URDF,
    # 15 mm either side of the axis, tilted 30 deg) goes 3 mm lower.
    assert wrist.z_m == pytest.approx(
        -0.02 - 0.015 * math.cos(math.radians(30)) + 0.0325 * 0.5 - 0.0125 * 0.5
    )
    raised = ArmModel(MODEL.ranges, Geometry(table_height=0.05))
    assert below_table(raised, solve(raised, 0.2, 0.0, 0.04, -90.0)) is not None
    assert below_table(raised, solve(raised, 0.2, 0.0, 0.06, -90.0)) is None


def test_a_huge_target_is_said_in_a_few_digits() -> None:
    """`move_to x=1e308 y=1e308 z=1e308` was refused with about 1 KB of digits: a number of a
    refusal's reason past 1e7 is said as 1e+308, not digit by digit."""
    with pytest.raises(Unreachable) as refused:
        solve_nearest_pitch(MODEL, 1e305, 1e305, 1e305, 0.0, 0.0)
    said = str(refused.value)
    assert "x=1e+308 y=1e+308 z=1e+308 mm" in said and len(said) < 200, said
    huge = str(JointOutOfRange((("base", 1e300, -90.0, 90.0),)))
    assert huge == "base would need 1e+300 deg, its range is -90..90", huge


def test_a_zero_is_said_without_a_sign() -> None:
    """y=0 typed on the page came back as "y=-0 mm" (a -0.0 of the arm's frame)."""
    with pytest.raises(Unreachable) as refused:
        solve_nearest_pitch(MODEL, 0.5, -0.0, 0.1, 0.0, 0.0)
    assert "x=500 y=0 z=100 mm" in str(refused.value), str(refused.value)
