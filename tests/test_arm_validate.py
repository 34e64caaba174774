"""Validation as pure functions: the whole instruction judged before anything is written."""

from __future__ import annotations

import math

import pytest

from al5d.arm import instruction as ins
from al5d.arm.cartesian import outside
from al5d.arm.config import ArmConfig
from al5d.arm.validate import Limits, Step, check, explain


@pytest.fixture(scope="module")
def limits(config: ArmConfig) -> Limits:
    return Limits.of(config)


def test_a_valid_move_gives_its_target_and_a_preset_its_pose(
    limits: Limits, config: ArmConfig
) -> None:
    assert check(ins.move(base=30, elbow=90.5, time_ms=800), limits) == (
        Step({"base": 30, "elbow": 90.5}, 800),
    )
    assert check(ins.preset("ready"), limits) == (Step(dict(config.presets["ready"]), None),)
    assert check(ins.move(base=-90, shoulder=90), limits) == (
        Step({"base": -90, "shoulder": 90}, None),
    )


def test_every_problem_is_named_at_once(limits: Limits) -> None:
    instr = ins.Instruction(
        ins.Kind.MOVE,
        joints=(("base", 91.0), ("finger", 1.0), ("elbow", math.nan), ("base", 1.0)),
        time_ms=70_000,
    )
    reason = check(instr, limits)
    assert reason == explain(instr, limits)
    assert reason == (
        "time 70000 ms is above the limit of 60000 ms; "
        "base: 91 deg is outside the range -90..90; "
        "unknown joint 'finger'; joints are base, shoulder, elbow, wrist, gripper, wrist_rotate; "
        "elbow: nan is not a finite number of degrees; "
        "base is given twice"
    )


@pytest.mark.parametrize(
    ("instr", "reason"),
    [
        (ins.move(shoulder=-30.001), "shoulder: -30.001 deg is outside the range -30..90"),
        (ins.move(wrist=-math.inf), "wrist: -inf is not a finite number of degrees"),
        (ins.move(base=1, time_ms=-1), "time -1 ms is negative"),
        (ins.Instruction(ins.Kind.MOVE), "a move names no joint"),
        (ins.preset("dance"), "unknown preset 'dance'; presets are park, ready, straight_up"),
        (ins.preset("park", time_ms=60_001), "time 60001 ms is above the limit of 60000 ms"),
    ],
)
def test_refusals(limits: Limits, instr: ins.Instruction, reason: str) -> None:
    assert check(instr, limits) == reason


def test_a_trajectory_is_judged_whole_and_its_first_bad_point_named(limits: Limits) -> None:
    good = [ins.Point((("base", 10.0), ("elbow", 80.0)), 500), ins.Point((("base", -10.0),), 1300)]
    assert check(ins.trajectory(good), limits) == (
        Step({"base": 10.0, "elbow": 80.0}, 500),
        Step({"base": -10.0}, 800),
    )
    bad_range = [*good, ins.Point((("elbow", 170.0),), 1500), ins.Point((("base", 0.0),), 2000)]
    assert check(ins.trajectory(bad_range), limits) == (
        "point 2: elbow: 170 deg is outside the range 0..135"
    )
    same_time = [good[0], ins.Point((("base", 0.0),), 500)]
    assert check(ins.trajectory(same_time), limits) == (
        "point 1: time_from_start 500 ms is not after point 0 (500 ms)"
    )
    both_at_zero = [ins.Point((("base", 0.0),), 0), ins.Point((("base", 5.0),), 0)]
    assert check(ins.trajectory(both_at_zero), limits) == (
        "point 1: time_from_start 0 ms is not after point 0 (0 ms)"
    )
    negative = [ins.Point((("base", 0.0),), -1)]
    assert check(ins.trajectory(negative), limits) == ("point 0: time_from_start -1 ms is negative")
    assert check(ins.trajectory([]), limits) == "a trajectory has no points"
    too_long = [ins.Point((("base", 0.0),), 60_001)]
    assert "above the limit of 60000 ms" in str(check(ins.trajectory(too_long), limits))


def test_a_trajectorys_joint_names_are_judged_as_its_own_not_a_points(limits: Limits) -> None:
    """Every point names the same joints (a ROS trajectory's joint_names): a bad name is the
    trajectory's, not "point 0"'s (an outside try); where points name different joints,
    the point is named."""
    twice = [ins.Point((("base", 1.0), ("base", 2.0)), t) for t in (500, 900)]
    assert check(ins.trajectory(twice), limits) == "the joints it names: base is given twice"
    foo = [ins.Point((("base", 1.0), ("elbw", 80.0)), t) for t in (500, 900)]
    said = check(ins.trajectory(foo), limits)
    assert said == (
        "the joints it names: unknown joint 'elbw'; did you mean 'elbow'? joints are "
        "base, shoulder, elbow, wrist, gripper, wrist_rotate"
    ), said
    mixed = [ins.Point((("base", 1.0),), 500), ins.Point((("elbw", 80.0),), 900)]
    assert str(check(ins.trajectory(mixed), limits)).startswith("point 1: unknown joint 'elbw'")


def test_a_trajectory_may_start_at_0_as_moveit_sends_it(limits: Limits) -> None:
    # MoveIt's first point is the start state at time_from_start 0: it goes at the servos'
    # speed (no time asked), and the next keeps its own time.
    start = [ins.Point((("base", 0.0),), 0), ins.Point((("base", 10.0),), 400)]
    assert check(ins.trajectory(start), limits) == (
        Step({"base": 0.0}, None),
        Step({"base": 10.0}, 400),
    )


def test_points_under_a_millisecond_apart_keep_their_order_and_the_schedule(
    limits: Limits,
) -> None:
    # Judged on the exact times (0.4 ms apart is after); sent in whole ms, the steps add
    # up to the last point's time, a step of 0 ms going at the servos' speed.
    close = [
        ins.Point((("base", 10.0),), 500.0),
        ins.Point((("base", 11.0),), 500.4),
        ins.Point((("base", 12.0),), 700.6),
    ]
    steps = check(ins.trajectory(close), limits)
    assert steps == (
        Step({"base": 10.0}, 500),
        Step({"base": 11.0}, None),
        Step({"base": 12.0}, 201),
    )
    backwards = [close[0], ins.Point((("base", 11.0),), 499.9)]
    assert check(ins.trajectory(backwards), limits) == (
        "point 1: time_from_start 499.9 ms is not after point 0 (500 ms)"
    )


def test_a_reason_never_repeats_a_huge_input(limits: Limits) -> None:
    huge = "x" * 1_000_000
    reason = check(ins.move(**{huge: 1.0}), limits)
    assert isinstance(reason, str) and len(reason) < 300 and "1000000 characters" in reason
    many = ins.Instruction(ins.Kind.MOVE, joints=tuple((f"j{i}", 1.0) for i in range(10_000)))
    reason = check(many, limits)
    assert isinstance(reason, str) and reason.endswith("; and 9995 more")
    assert "at most 256" in str(check(ins.move(base=1, id="i" * 257), limits))


def test_an_angle_just_past_a_limit_is_said_with_the_digits_that_show_it() -> None:
    """`move base=90.0000000001` was refused as "base: 90 deg is outside the range -90..90"."""
    assert outside("base", 90.0000000001, -90, 90) == (
        "base: 90.0000000001 deg is outside the range -90..90"
    )
    assert outside("base", 120.5, -90, 90) == "base: 120.5 deg is outside the range -90..90"
