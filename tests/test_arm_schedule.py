"""A trajectory's steps keep the schedule of the first: how each step's time is chosen.

The worker writes a step one wire time before the step ahead of it ends; whatever
its bytes' actual arrival (a late wake-up, bytes still on the wire), the step's
T is chosen so that it ends when the schedule says. Pure arithmetic, no board.
"""

from __future__ import annotations

from concurrent.futures import Future

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.jobs import Job
from al5d.arm.shared import Shared
from al5d.arm.translate import Translator
from al5d.arm.validate import Step
from al5d.arm.writer import StepWriter


def writer(config: ArmConfig) -> StepWriter:
    shared = Shared(config)
    shared.pose.update(dict.fromkeys(config.joints, 0.0))
    return StepWriter(shared, Translator(config), {n: j.channel for n, j in config.joints.items()})


def job_at_step(k: int, t_due: float, steps: tuple[Step, ...]) -> Job:
    job = Job(ins.trajectory([]), steps, Future(), 0, 0.0)
    job.step, job.t_due = k, t_due
    return job


STEPS = (Step({"base": 10.0}, 500), Step({"base": 20.0}, 300))


@pytest.mark.parametrize("late_ms", [-4.0, 0.0, 1.0, 4.3, 25.0])
def test_a_later_step_ends_when_the_schedule_says_however_late_it_arrives(
    config: ArmConfig, late_ms: float
) -> None:
    w = writer(config)
    # Step 0 was due to end at t=100.5; step 1 (300 ms) is due at 100.8. Its bytes would
    # arrive `late_ms` after step 0's end.
    job = job_at_step(1, 100.5, STEPS)
    data, time_ms = w.plan(job, STEPS[1], lambda n_bytes: 100.5 + late_ms / 1000)
    assert time_ms == round(300 - late_ms)
    assert data.endswith(f"T{time_ms}\r".encode())


def test_the_first_step_and_a_lone_move_take_their_time_as_asked(config: ArmConfig) -> None:
    w = writer(config)
    job = job_at_step(0, 0.0, STEPS)
    assert w.plan(job, STEPS[0], lambda n_bytes: 55.0)[1] == 500
    assert w.plan(job, STEPS[0])[1] == 500


def test_a_step_never_gets_less_than_the_servos_need(config: ArmConfig) -> None:
    w = writer(config)
    w.shared.pose["base"] = 10.0  # where step 0 left it
    # 10 degrees of base take about 30 ms; arriving 290 ms late leaves 10 ms: raised.
    job = job_at_step(1, 100.5, STEPS)
    minimum = w.translator.minimum_ms({"base": 10.0}, {"base": 20.0})
    _, time_ms = w.plan(job, STEPS[1], lambda n_bytes: 100.5 + 0.290)
    assert time_ms >= minimum > 10
