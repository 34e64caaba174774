"""The table for every move: the model's bodies against the chain, paths sampled finely
enough, and moves into the table refused whole on a real driver and emulated board."""

from __future__ import annotations

import itertools
import math
import time

import numpy as np
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from al5d.arm import instruction as ins
from al5d.arm.config import load_config, with_changes
from al5d.arm.instruction import Point, Result
from al5d.arm.states import State
from al5d.arm.validate import Limits, check, from_start
from al5d.model import JOINTS, build_chain, link_poses
from al5d.model.table import (
    HEIGHT_JOINTS,
    PATH_TOLERANCE_M,
    below,
    clear_by_bound,
    heights,
    path_below,
)
from al5d.model.transforms import matrix_from_quat
from al5d.ssc32u import protocol as p
from al5d_rig.armrig import Rig, written

CONFIG = load_config()
MODEL = CONFIG.model
READY = dict(CONFIG.presets["ready"])
#: The issue's pose: the sliders' move from ready that put the tool at z = -100 mm.
INTO_TABLE = {"base": 70.0, "shoulder": 40.0, "elbow": 124.0, "wrist": -9.0}
BODIES = {
    "upper arm": "upper_arm_link",
    "forearm": "forearm_link",
    "hand": "hand_link",
    "left finger": "finger_left_link",
    "right finger": "finger_right_link",
}


def degrees_in_range() -> st.SearchStrategy[dict[str, float]]:
    return st.fixed_dictionaries(
        {j: st.floats(*CONFIG.joints[j].range_deg, allow_nan=False) for j in JOINTS}
    )


def chain_lowest(degrees: dict[str, float]) -> dict[str, float]:
    """Each body's lowest corner by the URDF chain's own forward kinematics."""
    chain = build_chain(MODEL, dict.fromkeys(JOINTS, 1.0))
    poses = link_poses(chain, MODEL.to_urdf(degrees))
    out = {}
    for link in chain.links:
        if link.shape is None:
            continue
        pose = poses[link.name]
        rot, at = np.array(matrix_from_quat(pose.rotation)), np.array(pose.translation)
        half, centre = np.array(link.shape.size) / 2, np.array(link.shape.center)
        corners = itertools.product((-1, 1), repeat=3)
        out[link.name] = min(float((rot @ (centre + np.array(c) * half) + at)[2]) for c in corners)
    out["tool0"] = poses[chain.tool].translation[2]
    return out


@settings(max_examples=200, deadline=None)
@given(degrees_in_range())
def test_the_closed_form_is_the_chains_forward_kinematics(degrees: dict[str, float]) -> None:
    h = heights(MODEL)
    z = dict(zip(h.names, h.lowest_one([degrees[j] for j in HEIGHT_JOINTS]), strict=True))
    ref = chain_lowest(degrees)
    assert math.isclose(z["tool tip"], ref["tool0"], abs_tol=1e-12)
    for name, link in BODIES.items():
        assert math.isclose(z[name], ref[link], abs_tol=1e-12), name
    one = h.lowest_one([degrees[j] for j in HEIGHT_JOINTS])
    many = h.lowest(np.array([[degrees[j] for j in HEIGHT_JOINTS]]))[0]
    assert np.allclose(many, one, atol=1e-12)  # both forms agree


@settings(max_examples=60, deadline=None)
@given(degrees_in_range(), degrees_in_range())
def test_no_dip_deeper_than_the_tolerance_is_missed(
    a: dict[str, float], b: dict[str, float]
) -> None:
    # The path sampled 50 times more finely than the check samples it: a pose under the
    # table by more than the tolerance there is one the check has refused.
    h = heights(MODEL)
    assume(below(MODEL, a) is None)  # from under the table the rule is another (below)
    qa = np.array([a[j] for j in HEIGHT_JOINTS])
    qb = np.array([b[j] for j in HEIGHT_JOINTS])
    dense = h.lowest(qa + np.linspace(0, 1, 20001)[:, None] * (qb - qa)).min(axis=1)
    if dense.min() < MODEL.geometry.table_height - PATH_TOLERANCE_M:
        assert path_below(MODEL, [a, b]) is not None
    if path_below(MODEL, [a, b]) is None:
        assert dense.min() >= MODEL.geometry.table_height - PATH_TOLERANCE_M


#: Both ends above the table, the hand sweeping 26 mm through it on the way (below).
DIPS = (
    {**READY, "shoulder": 70.0, "elbow": 50.0, "wrist": 70.0},
    {**READY, "shoulder": 10.0, "elbow": 125.0, "wrist": -90.0},
)


@settings(max_examples=300, deadline=None)
@given(degrees_in_range(), degrees_in_range(), st.floats(0.0, 1.0))
@example(*DIPS, 1.0)  # random pairs seldom dip between two ends above the table
def test_a_path_cleared_by_the_bound_alone_is_above_the_table_all_the_way(
    a: dict[str, float], b: dict[str, float], near: float
) -> None:
    # The bound skips sampling only where no pose on the way is under the table: checked
    # 20,000 times along the path. `b` drawn near `a` as often as far (short moves are the
    # ones the bound clears).
    b = {j: a[j] + near * (b[j] - a[j]) for j in a}
    h = heights(MODEL)
    qa = np.array([a[j] for j in HEIGHT_JOINTS])
    qb = np.array([b[j] for j in HEIGHT_JOINTS])
    if clear_by_bound(h, [list(qa), list(qb)], [h.speed(a, b)]):
        dense = h.lowest(qa + np.linspace(0, 1, 20001)[:, None] * (qb - qa)).min(axis=1)
        assert dense.min() >= MODEL.geometry.table_height
        assert path_below(MODEL, [a, b]) is None


def test_a_small_move_high_above_the_table_is_cleared_without_sampling() -> None:
    h = heights(MODEL)

    def row(pose: dict[str, float]) -> list[float]:
        return [pose[j] for j in HEIGHT_JOINTS]

    nudged = {**READY, "shoulder": READY["shoulder"] + 5.0}
    assert clear_by_bound(h, [row(READY), row(nudged)], [h.speed(READY, nudged)])
    deep = {**READY, **INTO_TABLE}
    assert not clear_by_bound(h, [row(READY), row(deep)], [h.speed(READY, deep)])


def test_a_path_that_dips_under_between_two_poses_above_is_refused() -> None:
    # Both ends above the table (the hand up, leaning forward; then folded back, pointing
    # down); on the way the hand sweeps 26 mm through the table.
    a, b = DIPS
    assert below(MODEL, a) is None and below(MODEL, b) is None
    under = path_below(MODEL, [a, b])
    assert under is not None and 0.5 < under.fraction < 0.8, under
    assert under.body == "left finger" and round(under.z_m * 1000) == -26
    assert str(under).startswith("below the table: the "), str(under)


def test_a_move_from_under_the_table_is_taken_only_if_it_rises() -> None:
    limits = Limits.of(CONFIG)
    bent = {**READY, **INTO_TABLE}  # the arm bent under the table by hand
    up = ins.move(shoulder=0.0)
    steps = check(up, limits)
    assert not isinstance(steps, str) and from_start(up, steps, bent, limits) == ""
    turn = ins.move(base=0.0)  # stays as deep: sweeps through the table
    steps = check(turn, limits)
    assert not isinstance(steps, str)
    assert "does not rise out of it" in from_start(turn, steps, bent, limits)


def test_the_check_is_a_config_key() -> None:
    off = with_changes(CONFIG, {"server.table_check": False})
    move = ins.move(**INTO_TABLE)
    steps = check(move, Limits.of(off))
    assert not isinstance(steps, str) and from_start(move, steps, READY, Limits.of(off)) == ""


def test_a_joint_move_into_the_table_is_refused_with_nothing_written(rig: Rig) -> None:
    assert rig.driver.execute(ins.preset("ready"), 10).ok
    before = written(rig.emu.records)
    outcome = rig.driver.execute(ins.move(**INTO_TABLE), 5)
    assert outcome.result is Result.REFUSED, outcome
    assert outcome.reason.startswith("below the table: the left finger would go "), outcome.reason
    assert "mm under it" in outcome.reason and "of the way to the target" in outcome.reason
    time.sleep(0.1)
    assert written(rig.emu.records) == before
    assert rig.driver.execute(ins.move(base=10.0), 5).ok  # the server goes on


def test_a_move_after_a_stop_mid_move_starts_on_the_board_where_it_was_judged(rig: Rig) -> None:
    """`QP` reads a pulse to 10 us, rounded down: up to 1 degree a joint, and near the table
    up to 2 mm of depth on a path judged from the pose read back (the model-based test
    found the board's pulses 0.67 mm under the table, 0.5 mm allowed). The first move after
    a stop mid-move puts the joints it caught moving where they were read back first (a
    line with no time), so that the board's path starts where its check started it."""
    driver, emu, joints = rig.driver, rig.emu, rig.config.joints
    assert driver.execute(ins.preset("ready"), 10).ok
    moving = {"base": 40.0, "shoulder": 20.0, "elbow": 100.0}
    before = len(rig.moves())
    going = driver.submit(ins.move(**moving, time_ms=4000))
    rig.wait_move_count(before + 1)
    time.sleep(0.7)
    assert driver.execute(ins.stop(), 10).ok
    assert going.result(10).result is Result.CANCELLED
    driver.wait_for_state(State.STOPPED, 10)
    deadline = time.monotonic() + 10
    while driver.core.readback:  # the pose read back
        assert time.monotonic() < deadline, "the pose not read back in 10 s"
        time.sleep(0.01)
    halted = {name: emu.pulse_us(j.channel) for name, j in joints.items()}
    assert driver.execute(ins.release(), 10).ok
    driver.wait_for_state(State.READY, 10)
    n = len(emu.records)
    assert driver.execute(ins.move(wrist=10.0, time_ms=1000), 10).ok
    timed = [
        r for r in emu.records[n:] for c in r.commands if isinstance(c, p.GroupMove) and c.time_ms
    ]
    assert len(timed) == 1, timed
    # The board's ramp for the move starts where the core judged its path from: the pulses
    # read back (the step of `QP` under the pulse the stop left) for the joints that moved,
    # the pulses its own lines wrote for the others.
    start = {name: emu.pulse_us(j.channel, timed[0].t_effect - 1e-6) for name, j in joints.items()}
    for name, us in halted.items():
        expected = us if name not in moving else math.floor(us / 10) * 10
        assert abs(start[name] - expected) < 0.01, (name, us, start[name])


def test_a_trajectory_with_one_point_in_the_table_is_refused_whole(rig: Rig) -> None:
    assert rig.driver.execute(ins.preset("ready"), 10).ok
    arm = ("shoulder", "elbow", "wrist", "wrist_rotate")
    good = [30.0, 90.0, 0.0, 0.0]
    bad = [60.0, 90.0, 0.0, 0.0]  # the hand 113 mm into the table
    poses = [good, [35.0, 90.0, 0.0, 0.0], bad, good]
    points = tuple(
        Point(tuple(zip(arm, q, strict=True)), 400.0 * (i + 1)) for i, q in enumerate(poses)
    )
    before = written(rig.emu.records)
    outcome = rig.driver.execute(ins.trajectory(points), 5)
    assert outcome.result is Result.REFUSED, outcome
    assert "below the table" in outcome.reason and "point 2" in outcome.reason, outcome.reason
    time.sleep(0.1)
    assert written(rig.emu.records) == before
