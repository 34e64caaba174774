"""The lane of set-points (issue 24, ros2_control's joint commands): the latest wins, and a
set-point where the arm is heading writes nothing. In the driver, on an emulated board."""

from __future__ import annotations

from armrig import Rig, group_pulses, pulses
from rospeer import wait_until

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
    going = driver.submit(ins.move(base=40, time_ms=3000), stream=STREAM)
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


def test_a_stop_holds_the_stream_until_a_set_point_where_the_arm_is(rig: Rig) -> None:
    """ros2_control's hardware sends its last target again and again while the arm is off
    it: after a stop and a release that target is not driven to; a set-point where the arm
    stands (a controller that let go of the old target) resumes the stream."""
    driver = rig.driver
    target = {"base": 70.0, "elbow": 100.0}
    moved = len(rig.moves())
    going = driver.submit(ins.move(**target, time_ms=4000, id="old"), stream=STREAM)
    rig.wait_move_count(moved + 1)
    assert driver.execute(ins.stop(), 10).ok
    assert going.result(10).result is Result.CANCELLED
    assert driver.execute(ins.release(), 10).ok
    driver.wait_for_state(State.READY, 10)
    before = len(rig.moves())
    for _ in range(20):  # the hardware at its rate, still on the old target
        again = driver.submit(ins.move(**target), stream=STREAM).result(5)
        assert again.result is Result.REFUSED and "stream of set-points is held" in again.reason
    assert len(rig.moves()) == before

    def hold_here() -> bool:
        """A controller re-activated: it holds where the joint states say the arm is (once
        the pose after the stop is read back)."""
        here = driver.submit(ins.move(**driver.positions()), stream=STREAM).result(10)
        assert here.ok or "stream of set-points is held" in here.reason, here.reason
        return here.ok and "nothing written" in here.reason

    wait_until(hold_here, 10, "the stream resumed")
    assert driver.submit(ins.move(**target), stream=STREAM).result(10).ok
    moves = rig.moves()[before:]
    assert len(moves) == 1
    assert group_pulses(moves[0].commands[0]) == pulses(rig.config, target)
