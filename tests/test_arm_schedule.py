"""A trajectory's steps keep the schedule of the first: how each step's time is chosen.

The worker writes a step one wire time before the step ahead of it ends; whatever
its bytes' actual arrival (a late wake-up, bytes still on the wire), the step's
T is chosen so that it ends when the schedule says. Pure arithmetic, no board.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.corestate import Arm, Core, Run
from al5d.arm.jobs import Job, Motion
from al5d.arm.running import plan
from al5d.arm.validate import Step
from al5d.ssc32u import protocol as p

STEPS = (Step({"base": 10.0}, 500), Step({"base": 20.0}, 300))


def planned(
    config: ArmConfig, k: int, t_due: float, arrival: float, **where: float
) -> tuple[bytes, int, tuple[str, ...]]:
    """Step `k`'s line, time and notes, planned with the arm at `where` (every other joint
    at 0) by a core whose wire puts bytes written now on the board at `arrival`."""
    core = Core.start(Arm.of(config, "virtual", 9600))
    pose = {**dict.fromkeys(config.joints, 0.0), **where}
    # The line's length decides its wire time: planned once to know it.
    n_bytes = len(core.arm.translator.encode(STEPS[k].target, STEPS[k].time_ms or 0))
    t = arrival - p.wire_time_s(n_bytes, 9600)
    core = replace(core, book=replace(core.book, pose=pose), link=replace(core.link, free_at=t))
    job = Job(1, ins.trajectory([]), STEPS, 0.0, 0)
    run = plan(core, Run(job, STEPS, k, t_due=t_due), t)
    return run.line, run.line_ms, run.notes


@pytest.mark.parametrize("late_ms", [-4.0, 0.0, 1.0, 4.3, 25.0])
def test_a_later_step_ends_when_the_schedule_says_however_late_it_arrives(
    config: ArmConfig, late_ms: float
) -> None:
    # Step 0 was due to end at t=100.5; step 1 (300 ms) is due at 100.8. Its bytes would
    # arrive `late_ms` after step 0's end.
    line, time_ms, _ = planned(config, 1, 100.5, 100.5 + late_ms / 1000)
    assert abs(time_ms - (300 - late_ms)) <= 1  # whole ms; a digit less is a ms less wire
    assert line.endswith(f"T{time_ms}\r".encode())


def test_the_first_step_and_a_lone_move_take_their_time_as_asked(config: ArmConfig) -> None:
    assert planned(config, 0, 0.0, 55.0)[1] == 500


def test_a_step_never_gets_less_than_the_servos_need(config: ArmConfig) -> None:
    # 10 degrees of base (from where step 0 left it) take about 30 ms; arriving 290 ms late
    # leaves 10 ms: raised.
    minimum = Arm.of(config, "v").translator.minimum_ms({"base": 10.0}, {"base": 20.0})
    _, time_ms, _ = planned(config, 1, 100.5, 100.5 + 0.290, base=10.0)
    assert time_ms >= minimum > 10


def test_a_step_squeezed_by_its_schedule_below_the_servos_says_inf03(config: ArmConfig) -> None:
    _, _, notes = planned(config, 1, 100.5, 100.5 + 0.290, base=10.0)
    assert any("INF03" in m and "ms left of its schedule" in m for m in notes)


def test_until_a_written_step_takes_effect_the_arm_is_where_the_step_before_puts_it() -> None:
    # Step k runs 0 -> 40 deg from t=10 to 11; step k+1 (40 -> 0) is written one wire
    # time early and takes effect at 11.
    k = Motion({"base": 0.0, "elbow": 90.0}, {"base": 40.0}, 10.0, 1.0)
    nxt = Motion({"base": 40.0, "elbow": 90.0}, {"base": 0.0, "elbow": 80.0}, 11.0, 1.0)
    linked = nxt.after(k, 10.96)
    assert linked.at(10.96)["base"] == pytest.approx(38.4)  # not already 40
    assert linked.at(10.96)["elbow"] == 90.0
    assert linked.at(11.5) == {"base": 20.0, "elbow": 85.0}
    assert linked.moving(10.96) == ["base", "elbow"]  # the base, still finishing, first
    # Written after the step before ended, it needs no link (and a chain never grows).
    assert nxt.after(k, 11.2) is nxt
    assert linked.after(linked, 11.1).before is not None
    assert linked.after(linked, 11.1).before.before is None  # type: ignore[union-attr]
