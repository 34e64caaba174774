"""The lane of set-points (issue 24, ros2_control's joint commands): the latest wins, and a
set-point where the arm is heading writes nothing. In the driver, on an emulated board."""

from __future__ import annotations

from armrig import Rig, group_pulses, pulses

from al5d.arm import instruction as ins
from al5d.arm.instruction import Result
from al5d.arm.states import State

STREAM = "joint_commands"


def test_a_newer_set_point_replaces_the_one_that_waits(rig: Rig) -> None:
    driver = rig.driver
    before = len(rig.moves())
    running = driver.submit(ins.move(base=60, time_ms=1200))  # the set-points wait behind it
    older = [driver.submit(ins.move(base=b, id=f"p{b}"), stream=STREAM) for b in (10, 20, 30)]
    newest = driver.submit(ins.move(base=40, elbow=80, id="p40"), stream=STREAM)
    for future, by in zip(older, ("p20", "p30", "p40"), strict=True):
        outcome = future.result(5)
        assert outcome.result is Result.CANCELLED
        assert outcome.reason == f"replaced by set-point {by}"
    assert running.result(10).ok and newest.result(10).ok
    moves = rig.moves()[before:]
    assert len(moves) == 2  # the long move and the newest set-point: nothing of the others
    last = moves[-1].commands[0]
    assert group_pulses(last) == pulses(rig.config, {"base": 40, "elbow": 80})


def test_a_set_point_does_not_replace_other_moves(rig: Rig) -> None:
    driver = rig.driver
    before = len(rig.moves())
    running = driver.submit(ins.move(wrist=30, time_ms=800))
    queued = driver.submit(ins.move(wrist=-30, time_ms=200))
    point = driver.submit(ins.move(wrist=10), stream=STREAM)
    assert running.result(10).ok and queued.result(10).ok and point.result(10).ok
    assert len(rig.moves()) - before == 3
    assert abs(rig.emu.servo_degrees()["wrist"] - 10) < 0.5


def test_a_set_point_where_the_arm_is_or_goes_writes_nothing(rig: Rig) -> None:
    driver = rig.driver
    assert driver.execute(ins.move(base=-20, elbow=70), 10).ok
    before = len(rig.moves())
    # At rest there: a hundred of them (a controller at 100 Hz holding the arm) write nothing.
    for _ in range(100):
        outcome = driver.submit(ins.move(base=-20, elbow=70), stream=STREAM).result(5)
        assert outcome.ok and "nothing written" in outcome.reason
    # Closer than half a pulse microsecond (the base: 10 us a degree) is the same pulse.
    same = driver.submit(ins.move(base=-20.04, elbow=70), stream=STREAM).result(5)
    assert "nothing written" in same.reason
    assert len(rig.moves()) == before
    # On its way to a set-point: the same one again writes nothing either.
    going = driver.submit(ins.move(base=40, time_ms=600), stream=STREAM)
    again = driver.submit(ins.move(base=40), stream=STREAM).result(5)
    assert again.ok and "nothing written" in again.reason and not going.done()
    assert going.result(10).ok
    # A pulse's worth away is a move.
    assert driver.submit(ins.move(base=40.1), stream=STREAM).result(10).ok
    moves = rig.moves()[before:]
    assert len(moves) == 2
    assert group_pulses(moves[-1].commands[0]) == pulses(rig.config, {"base": 40.1})


def test_set_points_are_judged_and_refused_like_any_move(rig: Rig) -> None:
    driver = rig.driver
    before = len(rig.moves())
    outcome = driver.submit(ins.move(base=120), stream=STREAM).result(5)
    assert outcome.result is Result.REFUSED and "outside the range" in outcome.reason
    assert driver.submit(ins.stop()).result(5).ok
    locked = driver.submit(ins.move(base=10), stream=STREAM).result(5)
    assert locked.result is Result.REFUSED and driver.state is State.STOPPED
    assert driver.submit(ins.release()).result(5).ok
    assert len(rig.moves()) == before
