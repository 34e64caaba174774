"""Validation as pure functions: the whole instruction judged before anything is written."""

from __future__ import annotations

import math

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.validate import Limits, check, explain


@pytest.fixture(scope="module")
def limits(config: ArmConfig) -> Limits:
    return Limits.of(config)


def test_a_valid_move_gives_its_target_and_a_preset_its_pose(
    limits: Limits, config: ArmConfig
) -> None:
    assert check(ins.move(base=30, elbow=90.5, time_ms=800), limits) == {"base": 30, "elbow": 90.5}
    assert check(ins.preset("ready"), limits) == config.presets["ready"]
    assert check(ins.move(base=-90, shoulder=90), limits) == {"base": -90, "shoulder": 90}


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
