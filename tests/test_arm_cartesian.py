"""Cartesian moves at the driver (issue 13): the tip to a point, refusals whole, straight lines.

Judged on the emulated board: where its servos put the tip (forward kinematics
of the emulated servo angles), and what reached it.
"""

from __future__ import annotations

import math
import threading
import time

import pytest
from armrig import Rig, written

from al5d.arm import instruction as ins
from al5d.arm.instruction import Result
from al5d.model import distance_to_segment, forward


def tip(rig: Rig) -> tuple[float, float, float]:
    return forward(rig.config.model.geometry, rig.emu.servo_degrees()).position


def distance(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.dist(a, b)


def test_the_tip_goes_to_the_point_at_the_pitch_asked(rig: Rig) -> None:
    assert rig.driver.execute(ins.move_to(280, 60, 100, pitch=-30), 10).ok
    assert distance(tip(rig), (0.28, 0.06, 0.1)) < 0.0015  # the emulated servos themselves
    pose = forward(rig.config.model.geometry, rig.emu.servo_degrees())
    assert pose.pitch_deg == pytest.approx(-30, abs=0.5)
    assert len(rig.moves()) >= 2  # the park, then one group move


def test_without_a_pitch_the_current_one_is_kept_where_it_can_be(rig: Rig) -> None:
    assert rig.driver.execute(ins.move_to(300, 0, 120, pitch=-20), 10).ok
    assert rig.driver.execute(ins.move_to(280, -60, 90), 10).ok
    pose = forward(rig.config.model.geometry, rig.emu.servo_degrees())
    assert pose.pitch_deg == pytest.approx(-20, abs=0.5)
    assert distance(pose.position, (0.28, -0.06, 0.09)) < 0.0015


@pytest.mark.parametrize(
    ("instr", "reason"),
    [
        (ins.move_to(500, 0, 100, pitch=0), "out of reach: "),
        (ins.move_to(500, 0, 100), "no pitch reaches x=500 y=0 z=100 mm"),
        (ins.move_to(150, 0, 20, pitch=-90, roll=120), "roll: wrist_rotate: 120 deg is outside"),
        (ins.move_to(math.nan, 0, 100), "x: nan is not a finite number"),
        (ins.move_to(200, 0, 100, gripper=95), "gripper: 95 deg is outside the range 0..90"),
        (ins.move_to(30, 0, 100, pitch=90), "elbow would need 159 deg, its range is 0..135"),
    ],
)
def test_unreachable_and_out_of_range_targets_are_refused_with_nothing_written(
    rig: Rig, instr: ins.Instruction, reason: str
) -> None:
    before = written(rig.emu.records)
    outcome = rig.driver.execute(instr, 5)
    assert outcome.result is Result.REFUSED and reason in outcome.reason, outcome.reason
    time.sleep(0.05)
    assert written(rig.emu.records) == before


def test_the_reason_says_how_far(rig: Rig) -> None:
    outcome = rig.driver.execute(ins.move_to(450, 0, 67.31, pitch=0), 5)
    # The wrist point is 350 mm from the shoulder (450 - 100 of gripper); the arm reaches
    # 146.05 + 187.325 = 333.375 mm.
    assert outcome.reason == "out of reach: 350 mm from the shoulder, the arm reaches 333 mm"


def test_a_straight_line_keeps_the_emulated_tip_within_a_millimetre(rig: Rig) -> None:
    assert rig.driver.execute(ins.move_to(250, -120, 60, pitch=-30), 10).ok
    start = tip(rig)
    end = (0.25, 0.12, 0.14)
    samples: list[tuple[float, float, float]] = []
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            samples.append(tip(rig))
            time.sleep(0.002)

    n = len(rig.moves())
    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        outcome = rig.driver.execute(ins.move_to(250, 120, 140, pitch=-30, line=True), 20)
    finally:
        done.set()
        watcher.join()
    assert outcome.ok, outcome.reason
    segments = len(rig.moves()) - n
    assert segments > 1  # one group move would curve: the line is cut
    worst = max(distance_to_segment(start, end, p) for p in samples)
    assert worst <= 0.0011, f"{worst * 1000:.2f} mm off the line over {segments} group moves"
    assert distance(tip(rig), end) < 0.0015
    assert len(samples) > 50


def test_a_stop_halts_a_straight_line_and_nothing_more_of_it_is_written(rig: Rig) -> None:
    assert rig.driver.execute(ins.move_to(250, -120, 60, pitch=-30), 10).ok
    line = rig.driver.submit(ins.move_to(250, 120, 140, pitch=-30, line=True, time_ms=3000))
    rig.wait_move_count(len(rig.moves()) + 2)
    assert rig.driver.execute(ins.stop(), 5).ok
    assert line.result(5).result is Result.CANCELLED
    n = len(rig.moves())
    time.sleep(0.5)
    assert len(rig.moves()) == n
