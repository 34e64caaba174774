"""Cartesian moves at the driver (issue 13): the tip to a point, refusals whole, straight lines.

Judged on the emulated board: where its servos put the tip (forward kinematics
of the emulated servo angles, replayed from its record), and what reached it.
"""

from __future__ import annotations

import itertools
import math
import re
import time
from typing import Any

import pytest
import yaml

from al5d.app.demo import DEMO_SEQUENCE, REFUSED_SEQUENCE
from al5d.app.reach import QoSRecorder, format_table, label
from al5d.arm import cartesian
from al5d.arm import instruction as ins
from al5d.arm.config import DEFAULT_CONFIG, ArmConfig, ConfigError, load_config, parse_config
from al5d.arm.instruction import GrammarError, Instruction, Kind, Result
from al5d.arm.sequence import judged_steps
from al5d.arm.translate import Translator
from al5d.arm.validate import Limits, check
from al5d.model import distance_to_segment, forward, solve
from al5d.model.transforms import Vec3
from al5d.ssc32u import protocol as p
from al5d_rig.armrig import Rig, executed_tips, group_pulses, settled_tip, tip, written

CONFIG = load_config()
TRANSLATOR = Translator(CONFIG)


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
        (
            ins.move_to(200, 0, -100, pitch=-90),
            "below the table: the tool tip would be at z=-100 mm, the table is at z=0 mm",
        ),
        (ins.move_to(200, 0, -100), "below the table: the tool tip would be at z=-100 mm"),
        (ins.move_to(320, 0, 30, pitch=30), "below the table: the wrist would be at z=-23 mm"),
        # Issue 22, defect 4: these wrapped round to pitches of 7.4, -25.5 and 15.1 deg.
        (ins.move_to(250, 0, 120, pitch=1e300), "pitch: 1e+300 deg is beyond one turn (360 deg)"),
        (ins.move_to(250, 0, 120, pitch=-1e300), "pitch: -1e+300 deg is beyond one turn"),
        (ins.move_to(250, 0, 120, pitch=1e18), "pitch: 1e+18 deg is beyond one turn"),
        (ins.move_to(250, 0, 120, pitch=361), "pitch: 361 deg is beyond one turn"),
        (ins.move_to(250, 0, 120, roll=-1e9), "roll: -1e+09 deg is beyond one turn"),
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


#: (start: None for ready, else a point at pitch -30), target, pitch, roll. The first two
#: went 1.08 and 0.99 mm off with the plan judged on unrounded angles.
LINES: list[tuple[Vec3 | None, Vec3, float, float | None]] = [
    (None, (100, 250, 50), -30.0, None),
    (None, (150, -200, 150), -30.0, 45.0),
    ((250, -120, 60), (250, 120, 140), -30.0, None),
    (None, (300, 0, 200), 0.0, None),
]


def board_path(start: dict[str, float], moves: list[Any], steps: int = 50) -> list[Vec3]:
    """The tip along the path the board makes of `moves` from `start`: each group move's
    pulses linear in time from the one before (the board's own interpolation), whenever
    each took effect."""
    pose = dict(start)
    tips = []
    for rec in moves:
        cmd = rec.commands[0]
        assert isinstance(cmd, p.GroupMove)
        target = {j: d for j, d in TRANSLATOR.degrees(group_pulses(cmd)).items() if d is not None}
        for k in range(1, steps + 1):
            f = k / steps
            tips.append(
                forward(
                    CONFIG.model.geometry,
                    {**pose, **{j: pose[j] + (d - pose[j]) * f for j, d in target.items()}},
                ).position
            )
        pose.update(target)
    return tips


def test_straight_lines_keep_the_emulated_tip_within_a_millimetre(rig: Rig) -> None:
    """The board's path of a line's group moves is within a millimetre of the segment, and
    so is where the emulated servos end. Where the servos are on the way depends also on
    when each hop took effect, which a busy host delays (a late hop is given less time,
    and the servos lag it): bounded here at 4 mm (2.7 mm seen with six test processes on
    two cores); the figure itself is the bench's."""
    report = []
    for start, target, pitch, roll in LINES:
        first = ins.preset("ready") if start is None else ins.move_to(*start, pitch=-30)
        assert rig.driver.execute(first, 10).ok
        p0 = settled_tip(rig)
        at = rig.emu.servo_degrees()
        n = len(rig.moves())
        outcome = rig.driver.execute(ins.move_to(*target, pitch=pitch, roll=roll, line=True), 20)
        assert outcome.ok, outcome.reason
        moves = rig.moves()[n:]
        assert len(moves) > 1  # one group move would curve: the line is cut
        end = (target[0] / 1000, target[1] / 1000, target[2] / 1000)
        planned = max(distance_to_segment(p0, end, q) for q in board_path(at, moves))
        tips = executed_tips(rig, moves, rig.emu.settle_time(0.01))
        worst = max(distance_to_segment(p0, end, q) for q in tips)
        report.append(
            f"{target}: board {planned * 1000:.3f} mm, servos {worst * 1000:.3f} mm "
            f"in {len(moves)} group moves"
        )
        assert distance(tips[-1], end) < 0.001
        assert planned <= 0.001, report
        assert worst <= 0.004, report


def test_a_timed_line_too_fast_for_the_servos_says_so_once_not_per_hop(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    assert rig.driver.execute(ins.preset("ready"), 10).ok
    n = len(rig.moves())
    outcome = rig.driver.execute(ins.move_to(100, 250, 50, pitch=-30, line=True, time_ms=200), 20)
    assert outcome.ok, outcome.reason
    assert len(rig.moves()) - n > 1
    inf03 = [r.getMessage() for r in caplog.get_records("call") if "INF03" in r.getMessage()]
    # One for the line, with the time it is expected to take (it was one per group move).
    assert len(inf03) == 1, inf03
    assert "requested 200 ms; expected" in inf03[0]


def test_a_timed_line_the_servos_can_keep_adds_up_to_its_time() -> None:
    """Each hop's whole milliseconds fall where the line's schedule does: rounded up hop by
    hop, a line of 2000 ms was sent as 2001 to 2004, and INF03 said of it (an outside try:
    at 1000, 1500, 2000, 3000 and 5000 ms, and on the demo's line)."""
    start = solve(CONFIG.model, 0.25, 0.0, 0.12, -30.0)
    for time_ms in (1000, 1500, 2000, 3000, 5000):
        moves = plan_from(start, ins.move_to(250, 50, 120, pitch=-30, line=True, time_ms=time_ms))
        assert isinstance(moves, list) and len(moves) > 1, moves
        assert all(ms is not None for _, ms in moves), moves
        assert sum(ms for _, ms in moves) == time_ms


def test_a_gripper_change_on_a_line_is_spread_over_its_group_moves(rig: Rig) -> None:
    assert rig.driver.execute(ins.preset("ready"), 10).ok  # gripper 0
    n = len(rig.moves())
    line = ins.move_to(100, 250, 50, pitch=-30, gripper=60, line=True)
    assert rig.driver.execute(line, 20).ok
    gripper = rig.config.joints["gripper"]
    steps = []
    for rec in rig.moves()[n:]:
        (cmd,) = rec.commands
        assert isinstance(cmd, p.GroupMove)
        us = group_pulses(cmd).get(gripper.channel)
        assert us is not None  # every group move moves the gripper a little
        steps.append(gripper.to_deg(us))
    assert len(steps) > 2 and all(a < b for a, b in itertools.pairwise(steps))
    assert steps[0] < 20 and steps[-1] == pytest.approx(60, abs=0.1)


def plan_from(start: dict[str, float], instr: Instruction, max_time_ms: int | None = None) -> Any:
    pose = {**start, "gripper": 0.0}
    if max_time_ms is None:
        return cartesian.plan(instr, pose, CONFIG.model, TRANSLATOR)
    return cartesian.plan(instr, pose, CONFIG.model, TRANSLATOR, max_time_ms)


def planned_ms(start: dict[str, float], moves: list[cartesian.Move]) -> float:
    """The line's time as the writer will send it (None: the servos' own minimum)."""
    total, before = 0.0, {**start, "gripper": 0.0}
    for target, ms in moves:
        total += ms if ms is not None else TRANSLATOR.minimum_ms(before, target)
        before = {**before, **target}
    return total


#: Near the base axis (x = 0.0001 mm), the base must turn 180 deg within a millimetre.
NEAR_AXIS = solve(CONFIG.model, 1e-7, 0.1, 0.46, 110.0)


def test_a_line_near_the_base_axis_takes_a_second_not_over_a_minute() -> None:
    moves = plan_from(NEAR_AXIS, ins.move_to(0.0001, -100, 460, pitch=110, line=True))
    assert isinstance(moves, list), moves
    # Every hop slowed to the one at the axis made it 78 s; that hop alone goes slowly.
    assert planned_ms(NEAR_AXIS, moves) < 2000
    assert any(ms is None for _, ms in moves)


def test_a_line_longer_than_the_limit_is_refused_saying_why() -> None:
    reason = plan_from(NEAR_AXIS, ins.move_to(0.0001, -100, 460, pitch=110, line=True), 500)
    assert isinstance(reason, str)
    assert re.fullmatch(
        r"the line would take \d+ ms, above the limit of 500 ms: it passes within 0\.1 mm of "
        r"the base axis, where the base would have to turn 180 deg in [\d.]+ mm",
        reason,
    ), reason


def test_hop_times_hold_each_floor_and_the_requested_total() -> None:
    floors, shares = [30.0, 10.0, 10.0, 500.0, 10.0], [0.3, 0.2, 0.2, 0.01, 0.29]
    # Without a time: one pace over most of the line, the slow hop at its own floor.
    auto = cartesian.hop_times(floors, shares)
    assert all(t >= m for t, m in zip(auto, floors, strict=True))
    assert auto[3] == 500.0 and sum(auto) < 700
    paces = [t / s for t, s in zip(auto, shares, strict=True)]
    steady = [s for pace, s in zip(paces, shares, strict=True) if pace == pytest.approx(100.0)]
    assert sum(steady) >= cartesian.STEADY_SHARE
    # With a time the hops add up to it, the floors held.
    timed = cartesian.hop_times(floors, shares, 2000)
    assert sum(timed) == pytest.approx(2000) and all(
        t >= m for t, m in zip(timed, floors, strict=True)
    )
    # Too short for the servos: every hop at its floor (the writer says so once).
    assert cartesian.hop_times(floors, shares, 100) == floors


def test_the_table_height_is_a_config_key_validated_like_the_rest() -> None:
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["geometry"]["table_height_mm"] = 30
    config = parse_config(data)
    limits = Limits.of(config)
    assert check(ins.move_to(200, 0, 20, pitch=-90), limits) == (
        "below the table: the tool tip would be at z=20 mm, the table is at z=30 mm"
    )
    assert check(ins.move_to(200, 0, 40, pitch=-90), limits) == ()
    data["geometry"]["table_height_mm"] = 70
    with pytest.raises(ConfigError, match=r"table_height_mm 70 must be below the shoulder axis"):
        parse_config(data)


def test_the_qos_table_shows_cartesian_moves_and_refusals_with_their_reason(rig: Rig) -> None:
    recorder = QoSRecorder(rig.driver, rig.emu)
    assert rig.driver.execute(ins.move_to(250, -120, 60, pitch=-30), 10).ok
    line = ins.move_to(250, 120, 140, pitch=-30, line=True)
    far = ins.move_to(500, 0, 100, pitch=0)
    assert rig.driver.execute(line, 20).ok
    refused = rig.driver.execute(far, 5)
    assert refused.result is Result.REFUSED
    rows = recorder.rows()
    assert [r.instruction for r in rows][-2:] == [str(line), str(far)]
    assert rows[-2].reach_ms is not None and rows[-1].reason == refused.reason
    table = format_table(rows)
    assert "move_to x=250 y=120 z=140 pitch=-30 path=line " in table  # whole
    assert f"refused: {refused.reason}" in table


def test_the_qos_table_measures_the_first_move_after_a_stop(rig: Rig) -> None:
    """Its line holds the joints the stop left, read back, before it moves them (`make
    demo`'s row of that move said 'n/a': its two lines were looked for as one record)."""
    recorder = QoSRecorder(rig.driver, rig.emu)
    running = rig.driver.submit(ins.move(base=60, time_ms=2000))
    rig.wait_move_count(len(rig.moves()) + 1)
    time.sleep(0.3)
    assert rig.driver.execute(ins.stop(), 5).ok
    assert running.result(5).result is Result.CANCELLED
    assert rig.driver.execute(ins.release(), 5).ok
    after = ins.move(base=0, elbow=100)
    assert rig.driver.execute(after, 10).ok
    row = [r for r in recorder.rows() if r.id == after.id][-1]
    assert row.reach_ms is not None, row
    assert "n/a" not in format_table([row])


def test_a_long_label_keeps_its_name_and_its_path() -> None:
    text = "move_to x=250.5 y=-120.25 z=140.125 pitch=-30.5 roll=45 gripper=60 path=line time=900"
    short = label(text, 60)
    assert len(short) <= 60
    assert short.startswith("move_to x=250.5") and short.endswith("... path=line time=900")


def test_the_demo_runs_a_line_and_refuses_unreachable_targets_saying_why(
    config: ArmConfig,
) -> None:
    """`al5d run` judges a file whole: the demo's sequence must pass that judgement (with an
    unreachable target in it, the demo sent nothing at all), and its refused file
    must not, for the reasons it shows."""
    steps = judged_steps(DEMO_SEQUENCE.read_bytes(), "demo.seq", None, config)
    points = [i for i, _ in steps if isinstance(i, Instruction) and i.kind is Kind.MOVE_TO]
    assert any(i.tool is not None and i.tool.line for i in points)
    with pytest.raises(GrammarError) as refused:
        judged_steps(REFUSED_SEQUENCE.read_bytes(), "refused.seq", None, config)
    said = str(refused.value)
    assert "refused.seq:4: out of reach: " in said and "refused.seq:5: below the table: " in said
    assert "refused.seq:3" not in said


def test_a_stop_halts_a_straight_line_and_nothing_more_of_it_is_written(rig: Rig) -> None:
    assert rig.driver.execute(ins.move_to(250, -120, 60, pitch=-30), 10).ok
    line = rig.driver.submit(ins.move_to(250, 120, 140, pitch=-30, line=True, time_ms=3000))
    rig.wait_move_count(len(rig.moves()) + 2)
    assert rig.driver.execute(ins.stop(), 5).ok
    assert line.result(5).result is Result.CANCELLED
    n = len(rig.moves())
    time.sleep(0.5)
    assert len(rig.moves()) == n
