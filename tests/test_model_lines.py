"""Straight-line moves: every hop stays near the line, with fewer hops than a fixed split."""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Mapping

import pytest

from al5d.arm.cartesian import pulse_scale
from al5d.arm.config import load_config
from al5d.arm.translate import Translator
from al5d.model import (
    ARM_JOINTS,
    ArmModel,
    BelowTable,
    Geometry,
    InvalidInput,
    JointOutOfRange,
    PathUnreachable,
    Unreachable,
    as_sent,
    forward,
    plan_line,
    segment_deviation,
    solve,
)
from al5d.model.lines import LinePlan
from al5d.model.transforms import Vec3
from al5d_rig.model_support import GEOMETRY, MODEL, PRESETS, mid_pose

READY = {j: float(PRESETS["ready"][j]) for j in ARM_JOINTS}
TOL = 0.001
DENSE = 2000
#: How the shipped arm's driver encodes degrees as pulses.
PULSES = pulse_scale(Translator(load_config()))

MOVES: list[tuple[dict[str, float], Vec3, float | None, float | None]] = [
    (READY, (0.20, 0.15, 0.05), -30.0, None),
    (READY, (0.15, -0.20, 0.15), -30.0, 45.0),
    (READY, (0.30, 0.00, 0.20), 0.0, None),
    (READY, (0.25, 0.00, 0.05), None, None),
    (mid_pose(), (0.12, 0.22, 0.02), -60.0, -20.0),
]


def hop_deviations(start: Mapping[str, float], plan: LinePlan) -> list[float]:
    stops = [start, *plan.waypoints]
    return [
        segment_deviation(GEOMETRY, a, b, plan.start, plan.end, DENSE)
        for a, b in itertools.pairwise(stops)
    ]


def fewest_uniform_hops(start: Mapping[str, float], plan: LinePlan) -> int:
    """The smallest n for which n equal hops along the line hold the tolerance."""
    d_pitch = plan.pitch_deg[1] - plan.pitch_deg[0]
    d_roll = plan.roll_deg[1] - plan.roll_deg[0]

    def at(t: float) -> dict[str, float]:
        p = [a + t * (b - a) for a, b in zip(plan.start, plan.end, strict=True)]
        pitch = plan.pitch_deg[0] + t * d_pitch
        return solve(MODEL, p[0], p[1], p[2], pitch, plan.roll_deg[0] + t * d_roll)

    for n in range(1, 200):
        stops = [dict(start)] + [at(i / n) for i in range(1, n + 1)]
        devs = (
            segment_deviation(GEOMETRY, a, b, plan.start, plan.end, 400)
            for a, b in itertools.pairwise(stops)
        )
        if max(devs) <= TOL:
            return n
    raise AssertionError("no uniform split holds the tolerance")


@pytest.mark.parametrize(("start", "target", "pitch", "roll"), MOVES)
def test_every_hop_stays_within_the_tolerance_of_the_line(
    start: dict[str, float], target: Vec3, pitch: float | None, roll: float | None
) -> None:
    plan = plan_line(MODEL, start, target, pitch, roll, tolerance_m=TOL)
    devs = hop_deviations(start, plan)
    assert max(devs) <= TOL * (1 + 1e-6)
    assert plan.max_deviation_m == pytest.approx(max(devs), abs=1e-7)
    # Hops are as long as allowed: all but the last use most of the tolerance.
    assert all(d > 0.9 * TOL for d in devs[:-1])


@pytest.mark.parametrize(("start", "target", "pitch", "roll"), MOVES)
def test_waypoints_lie_on_the_line_with_pitch_and_roll_interpolated(
    start: dict[str, float], target: Vec3, pitch: float | None, roll: float | None
) -> None:
    plan = plan_line(MODEL, start, target, pitch, roll)
    assert plan.fractions[-1] == 1.0
    assert all(a < b for a, b in itertools.pairwise(plan.fractions))
    p0, p1 = plan.start, plan.end
    assert p0 == pytest.approx(forward(GEOMETRY, start).position)
    for f, q in zip(plan.fractions, plan.waypoints, strict=True):
        pose = forward(GEOMETRY, q)
        on_line = [a + f * (b - a) for a, b in zip(p0, p1, strict=True)]
        assert math.dist(pose.position, on_line) <= 1e-8
        expected_pitch = plan.pitch_deg[0] + f * (plan.pitch_deg[1] - plan.pitch_deg[0])
        assert pose.pitch_deg == pytest.approx(expected_pitch, abs=1e-6)
        expected_roll = plan.roll_deg[0] + f * (plan.roll_deg[1] - plan.roll_deg[0])
        assert pose.roll_deg == pytest.approx(expected_roll, abs=1e-9)
        assert all(MODEL.ranges.of(j).lo <= q[j] <= MODEL.ranges.of(j).hi for j in ARM_JOINTS)
    assert forward(GEOMETRY, plan.waypoints[-1]).position == pytest.approx(target, abs=1e-8)


@pytest.mark.parametrize(("start", "target", "pitch", "roll"), MOVES)
def test_the_plan_never_needs_more_hops_than_the_best_uniform_split(
    start: dict[str, float], target: Vec3, pitch: float | None, roll: float | None
) -> None:
    plan = plan_line(MODEL, start, target, pitch, roll, tolerance_m=TOL)
    assert len(plan.waypoints) <= fewest_uniform_hops(start, plan)


@pytest.mark.parametrize(
    ("target", "pitch"),
    [((0.15, 0.0, 0.02), -90.0), ((0.10, 0.25, 0.05), -30.0), ((0.05, 0.30, 0.10), -30.0)],
)
def test_where_the_curvature_varies_the_plan_beats_any_uniform_split(
    target: Vec3, pitch: float
) -> None:
    # Uniform hops must all be as short as the worst stretch needs; ours are not.
    plan = plan_line(MODEL, READY, target, pitch, tolerance_m=TOL)
    assert len(plan.waypoints) < fewest_uniform_hops(READY, plan)


def test_the_plan_needs_far_fewer_hops_than_a_fixed_step() -> None:
    # A naive planner's fixed 5 mm step (it holds 1 mm here only by being short).
    plan = plan_line(MODEL, READY, (0.20, 0.15, 0.05), -30.0, tolerance_m=TOL)
    length = math.dist(plan.start, plan.end)
    assert len(plan.waypoints) * 3 < math.ceil(length / 0.005)


def test_one_group_move_alone_would_leave_the_line() -> None:
    # The reason for the planner: joints moving linearly make the tip curve.
    plan = plan_line(MODEL, READY, (0.20, 0.15, 0.05), -30.0)
    end = plan.waypoints[-1]
    assert segment_deviation(GEOMETRY, READY, end, plan.start, plan.end) > 10 * TOL
    assert len(plan.waypoints) > 1


def test_a_short_move_is_a_single_hop() -> None:
    p = forward(GEOMETRY, READY).position
    plan = plan_line(MODEL, READY, (p[0] + 0.005, p[1], p[2]), -30.0)
    assert plan.fractions == (1.0,)


def test_a_tighter_tolerance_needs_more_hops() -> None:
    loose = plan_line(MODEL, READY, (0.20, 0.15, 0.05), -30.0, tolerance_m=0.002)
    tight = plan_line(MODEL, READY, (0.20, 0.15, 0.05), -30.0, tolerance_m=0.0002)
    assert len(tight.waypoints) > len(loose.waypoints)
    assert tight.max_deviation_m <= 0.0002


def test_without_a_pitch_the_start_pitch_is_kept_when_reachable() -> None:
    plan = plan_line(MODEL, READY, (0.28, 0.05, 0.08))
    assert plan.pitch_deg == pytest.approx((-30.0, -30.0))
    assert plan.roll_deg == (0.0, 0.0)


@pytest.mark.parametrize(("start", "target", "pitch", "roll"), MOVES)
def test_with_the_pulse_scale_every_hop_holds_as_the_board_runs_it(
    start: dict[str, float], target: Vec3, pitch: float | None, roll: float | None
) -> None:
    # The board runs whole microseconds and interpolates them linearly: judged on the
    # exact angles, a plan loses up to about 0.25 mm to the rounding.
    plan = plan_line(MODEL, start, target, pitch, roll, tolerance_m=0.0009, pulses=PULSES)
    sent = [as_sent(q, PULSES) for q in (start, *plan.waypoints)]
    assert plan.start == pytest.approx(forward(GEOMETRY, sent[0]).position, abs=1e-12)
    devs = [
        segment_deviation(GEOMETRY, a, b, plan.start, target, DENSE)
        for a, b in itertools.pairwise(sent)
    ]
    assert max(devs) <= 0.0009 * (1 + 1e-6)
    assert plan.max_deviation_m == pytest.approx(max(devs), abs=1e-7)
    # The waypoints stay exact (the driver rounds them, and keeps them in range).
    assert forward(GEOMETRY, plan.waypoints[-1]).position == pytest.approx(target, abs=1e-8)


def test_as_sent_rounds_each_pulse_as_the_driver_encodes_it() -> None:
    config = load_config()
    translator = Translator(config)
    degrees = {"base": 10.04, "shoulder": 33.3333, "elbow": 91.87, "wrist": -7.77}
    sent = as_sent(degrees, PULSES)
    for joint, deg in sent.items():
        us = config.joints[joint].to_us(deg)
        assert us == pytest.approx(round(us), abs=1e-9)  # a whole microsecond
        assert abs(deg - degrees[joint]) <= 0.5 / abs(config.joints[joint].us_per_deg) + 1e-12
        assert translator.encode({joint: deg}, 10) == translator.encode({joint: degrees[joint]}, 10)
    assert as_sent({"gripper": 1.234}, PULSES) == {"gripper": 1.234}  # no scale: as given
    with pytest.raises(InvalidInput, match="pulses needs"):
        plan_line(MODEL, READY, (0.2, 0.0, 0.1), 0.0, pulses={"base": (1500.0, 10.0)})


def test_a_line_through_the_unreachable_is_refused_whole_naming_the_stretch() -> None:
    # From the ready pose out to 420 mm ahead: reach ends part of the way along.
    target = (0.42, 0.0, 0.10)
    with pytest.raises(PathUnreachable) as info:
        plan_line(MODEL, READY, target, -30.0)
    err = info.value
    assert 0.0 < err.fraction < 1.0 and err.until == 1.0
    # The worst point is the target, 10 mm further than the edge of the reach.
    assert re.fullmatch(
        r"the line leaves the arm's reach between \d+ % and 100 % of the path: "
        r"up to 343 mm from the shoulder, the arm reaches 333 mm",
        str(err),
    ), str(err)
    p0 = forward(GEOMETRY, READY).position

    def ok(t: float) -> bool:
        p = [a + t * (b - a) for a, b in zip(p0, target, strict=True)]
        try:
            solve(MODEL, p[0], p[1], p[2], -30.0)
        except Unreachable:
            return False
        return True

    assert ok(err.fraction - 0.002) and not ok(err.fraction + 0.0005)


def test_a_line_that_dips_out_of_range_midway_reports_its_worst_point() -> None:
    # Across the front of the base at low height: both ends reachable, the middle
    # passes too close to the base for the elbow's range. At the edge of the stretch
    # the elbow is a hair out of range; at its worst, 18 deg.
    start = solve(MODEL, 0.06, 0.20, 0.03, -90.0)
    target = (0.06, -0.20, 0.03)
    solve(MODEL, *target, -90.0)
    with pytest.raises(PathUnreachable) as info:
        plan_line(MODEL, start, target, -90.0)
    err = info.value
    assert str(err) == (
        "the line leaves the elbow's range between 25 % and 75 % of the path: "
        "it would need up to 153 deg, its range is 0..135"
    )
    assert isinstance(err.cause, JointOutOfRange) and err.cause.needed_deg < 135.01
    # Against a dense scan of the stretch.
    p0 = forward(GEOMETRY, start).position
    needed = []
    for i in range(2001):
        t = err.fraction + (err.until - err.fraction) * i / 2000
        p = [a + t * (b - a) for a, b in zip(p0, target, strict=True)]
        try:
            solve(MODEL, p[0], p[1], p[2], -90.0, base_hint_deg=start["base"])
        except JointOutOfRange as e:
            needed += [v[1] for v in e.violations if v[0] == "elbow"]
    assert isinstance(err.worst, JointOutOfRange)
    worst = next(v[1] for v in err.worst.violations if v[0] == "elbow")
    assert worst == pytest.approx(max(needed), abs=0.01)


def test_a_line_below_the_table_is_refused_naming_how_deep() -> None:
    with pytest.raises(PathUnreachable) as info:
        plan_line(MODEL, READY, (0.2, 0.0, -0.05), -90.0)
    assert re.fullmatch(
        # A finger first: on the way the gripper is not yet vertical, and its fingers' width
        # (20 mm) reaches lower than its tip; at the end they are level with it.
        r"the line takes the left finger below the table between \d+ % and 100 % of the path: "
        r"down to z=-50 mm, the table is at z=0 mm",
        str(info.value),
    ), str(info.value)
    assert isinstance(info.value.cause, BelowTable)
    # A table of another height (the config's geometry.table_height) moves the limit.
    low = ArmModel(MODEL.ranges, Geometry(table_height=-0.06))
    assert plan_line(low, READY, (0.2, 0.0, -0.05), -90.0).fractions[-1] == 1.0


def test_a_line_over_the_base_axis_keeps_the_base_where_it_is() -> None:
    # Both headings are in range here; IK alone would swing the base 180 deg at the
    # axis, the planner's base hint keeps it and lets the arm lean back instead.
    start = solve(MODEL, 0.0, 0.03, 0.49, 90.0)
    plan = plan_line(MODEL, start, (0.0, -0.03, 0.49), 90.0)
    assert {w["base"] for w in plan.waypoints} == {start["base"]} == {-90.0}
    assert max(hop_deviations(start, plan)) <= TOL * (1 + 1e-6)


def test_a_line_past_the_side_the_base_cannot_face_is_refused_where_the_joints_jump() -> None:
    start = {
        "base": 38.24,
        "shoulder": -13.84,
        "elbow": 39.49,
        "wrist": 75.24,
        "wrist_rotate": -63.0,
    }
    with pytest.raises(PathUnreachable, match=r"fails at 60% .*the joints would jump here"):
        plan_line(MODEL, start, (0.0162, -0.0099, 0.409))


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(InvalidInput):
        plan_line(MODEL, READY, (math.nan, 0.0, 0.1), 0.0)
    with pytest.raises(InvalidInput):
        plan_line(MODEL, READY, (0.2, 0.0, 0.1), 0.0, tolerance_m=0.0)
    with pytest.raises(InvalidInput, match="start needs joint wrist"):
        plan_line(MODEL, {j: 0.0 for j in ARM_JOINTS if j != "wrist"}, (0.2, 0.0, 0.1), 0.0)
