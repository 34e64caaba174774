"""The lane of set-points (issue 24, ros2_control's joint commands): the latest wins, and a
set-point where the arm is heading writes nothing. In the driver, on an emulated board."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import load_config
from al5d.arm.instruction import Outcome, Result
from al5d.arm.states import State
from al5d.model.table import PATH_TOLERANCE_M, below
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Record
from al5d_rig.armrig import Rig, group_moves, group_pulses, logged, pulses
from al5d_rig.rospeer import wait_until
from al5d_rig.sim import Sim

STREAM = "joint_commands"


def moves_since(rig: Rig, before: int, n: int) -> list[Record]:
    """The group moves on the board after the first `before`, once `n` of them are there
    and a moment has passed for any more: a set-point is done when its time is over,
    without asking the board, and its line may reach the board's record a moment later on
    a busy host."""
    rig.emu.wait_for(lambda rs: len(rig.moves()) >= before + n, 5)
    time.sleep(0.2)
    return rig.moves()[before:]


def alive(
    rig: Rig, while_: Future[Outcome], **target: float
) -> tuple[Future[Outcome], list[Future[Outcome]]]:
    """A source alive while the move `while_` runs: its set-point `target` sent again every
    0.1 s, as a source sends its target at its rate (one whose source has gone quiet for
    `server.stream_timeout_s` is not written: the watchdog). The last one, and those it
    replaced."""
    sent = [rig.driver.submit(ins.move(id="alive-0", **target), stream=STREAM)]
    while not while_.done():
        time.sleep(0.1)
        again = ins.move(id=f"alive-{len(sent)}", **target)
        sent.append(rig.driver.submit(again, stream=STREAM))
    return sent[-1], sent[:-1]


def test_a_newer_set_point_replaces_the_one_that_waits(rig: Rig) -> None:
    driver = rig.driver
    before = len(rig.moves())
    running = driver.submit(ins.move(base=60, time_ms=1200))  # the set-points wait behind it
    older = [driver.submit(ins.move(base=b, id=f"p{b}"), stream=STREAM) for b in (10, 20, 30)]
    newest, replaced = alive(rig, running, base=40, elbow=80)
    for future, by in zip(older, ("p20", "p30", "alive-0"), strict=True):
        outcome = future.result(5)
        assert outcome.result is Result.CANCELLED
        assert outcome.reason == f"replaced by set-point {by}"
    for future in replaced:  # replaced while it waited, or where the arm already heads
        said = future.result(5)
        assert "replaced by set-point alive-" in said.reason or said.ok, said
    assert running.result(10).ok and newest.result(10).ok
    moves = moves_since(rig, before, 2)
    assert len(moves) == 2  # the long move and the newest set-point: nothing of the others
    last = moves[-1].commands[0]
    assert group_pulses(last) == pulses(rig.config, {"base": 40, "elbow": 80})


def test_a_set_point_does_not_replace_other_moves(rig: Rig) -> None:
    driver = rig.driver
    before = len(rig.moves())
    running = driver.submit(ins.move(wrist=30, time_ms=800))
    queued = driver.submit(ins.move(wrist=-30, time_ms=200))
    point, _ = alive(rig, queued, wrist=10)
    assert running.result(10).ok and queued.result(10).ok and point.result(10).ok
    # Its line may reach the board's record a moment after the set-point's outcome (a CI
    # run beside two busy loops counted 2).
    assert len(moves_since(rig, before, 3)) == 3
    # Where the wrist comes to rest, not where it is when the outcome comes: the emulated
    # servo runs on the wall clock, 0.56 degrees short of it once in a loaded CI run.
    settled = rig.emu.servo_degrees(rig.emu.settle_time(0.01, ["wrist"]))["wrist"]
    assert abs(settled - 10) < 0.5


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
    # On its way to a set-point: the same one again writes nothing either (and, sent at a
    # stream's rate, keeps the watchdog from holding the arm on its way).
    going = driver.submit(ins.move(base=40, time_ms=2000), stream=STREAM)
    while not going.done():
        again = driver.submit(ins.move(base=40), stream=STREAM).result(5)
        assert again.ok and "nothing written" in again.reason
        time.sleep(0.05)
    assert going.result(10).ok
    # A pulse's worth away is a move.
    assert driver.submit(ins.move(base=40.1), stream=STREAM).result(10).ok
    moves = moves_since(rig, before, 2)
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
    moves = moves_since(rig, before, 2)
    assert len(moves) == 2
    # The joints the stop caught moving, read back (`QP`: 10 us steps), put there first.
    hold = moves[0].commands[0]
    assert isinstance(hold, p.GroupMove) and hold.time_ms is None, moves[0]
    assert all(t.pulse_us % 10 == 0 for t in hold.targets), moves[0]
    assert group_pulses(moves[1].commands[0]) == pulses(rig.config, target)


# -- the streaming mode (issue 25): the running set-point is superseded too ----------------


def test_a_newer_set_point_retargets_the_running_one_as_soon_as_the_wire_allows(
    rig: Rig,
) -> None:
    """The board takes a new group move mid-move and goes from where it is: the newest
    set-point does not wait for the one that runs."""
    driver = rig.driver
    before = len(rig.moves())
    old = driver.submit(ins.move(base=60, time_ms=3000, id="old"), stream=STREAM)
    rig.wait_move_count(before + 1)
    new = driver.submit(ins.move(base=-30, id="new"), stream=STREAM)
    outcome = old.result(5)
    assert outcome.result is Result.CANCELLED and outcome.reason == "superseded by set-point new"
    assert new.result(10).ok
    moves = rig.moves()[before:]
    assert len(moves) == 2
    assert group_pulses(moves[1].commands[0]) == pulses(rig.config, {"base": -30})
    # Mid-move, not after the old one's 3 s: in virtual time, test_arm_core.py.
    # There: a set-point is done when its time is over by the server's clock (no `Q`),
    # which a board thread of a busy test process can trail (1.35 degrees short once).
    wait_until(lambda: abs(rig.emu.servo_degrees()["base"] + 30) < 0.5, 5, "the base at -30")
    assert not any(isinstance(c, p.Stop) for r in rig.emu.records for c in r.commands)


def test_the_watchdog_holds_the_arm_when_the_stream_goes_quiet_mid_move(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    driver = rig.driver
    before = len(rig.emu.records)
    going = driver.submit(ins.move(base=80, time_ms=4000, id="far"), stream=STREAM)
    outcome = going.result(4)  # held well before its 4 s
    assert outcome.result is Result.CANCELLED
    assert "went quiet" in outcome.reason and "server.stream_timeout_s" in outcome.reason
    # Its STOP, a wire time later on the board.
    rig.emu.wait_for(
        lambda rs: any(isinstance(c, p.Stop) for r in rs[before:] for c in r.commands), 5
    )
    # Held where it was, not locked: the state is ready, and the stream goes on.
    driver.wait_for_state(State.READY, 5)
    assert not driver.locked
    base = rig.emu.servo_degrees()["base"]
    assert base < 70
    watchdog = [r for r in logged(caplog) if "watchdog" in r.getMessage()]
    assert len(watchdog) == 1
    assert driver.submit(ins.move(base=base - 5), stream=STREAM).result(10).ok


def test_a_stop_during_a_stream_wins_and_holds_it(rig: Rig) -> None:
    driver = rig.driver
    stop_now = threading.Event()
    futures = []

    def stream() -> None:
        # On until 50 set-points were sent after the stop was taken (counted by what this
        # thread saw before each: on a busy host the stop may come late in the stream).
        k = after = 0
        while after < 50:
            late = stop_now.is_set()
            move = ins.move(base=-60 + 0.2 * (k % 600), id=f"s{k}")
            futures.append((late, driver.submit(move, stream=STREAM)))
            after += late
            k += 1
            time.sleep(0.002)

    sender = threading.Thread(target=stream)
    sender.start()
    time.sleep(0.3)
    # Before the submit, which writes the STOP itself and may return a second later on a
    # busy host (its outcomes settled, the stream's thread taking turns).
    t_stop = time.monotonic()
    stop = driver.submit(ins.stop())
    stop_now.set()
    sender.join(20)
    assert stop.result(5).ok
    late = [f.result(10) for was_late, f in futures if was_late]
    assert len(late) == 50
    assert all(o.result is Result.REFUSED and "emergency stop" in o.reason for o in late)
    # Released, the stream's source still on its way: held until it is where the arm is.
    assert driver.execute(ins.release(), 5).ok
    for k in range(20):
        held = driver.submit(ins.move(base=-60 + 0.2 * (400 + k)), stream=STREAM).result(5)
        assert held.result is Result.REFUSED and "stream of set-points is held" in held.reason

    # Nothing of the stream took effect after the stop's STOP. The emulated board, in this
    # process, may be behind the owner (a CI run beside busy loops: the STOP not yet read
    # when the held set-points above were all answered): waited for.
    def stops(records: list[Record]) -> list[Record]:
        return [
            r
            for r in records
            if r.t_effect >= t_stop and any(isinstance(c, p.Stop) for c in r.commands)
        ]

    first = stops(rig.emu.wait_for(lambda rs: bool(stops(rs)), 20))[0]
    after = [r for r in rig.emu.records if r.t_effect > first.t_effect]
    assert not group_moves(after)


def _depth_under_table_mm(sim: Sim) -> float:
    """How far under the table the board holds the arm now (0: above it)."""
    joints = sim.config.joints
    pulses_now = {name: sim.board.pulse_us(j.channel, sim.t) for name, j in joints.items()}
    pose = {name: joints[name].to_deg(us) for name, us in pulses_now.items()}
    under = below(sim.config.model, pose)
    return 0.0 if under is None else (under.table_m - under.z_m) * 1000.0


def test_a_set_point_naming_fewer_joints_takes_the_others_still_moving_along() -> None:
    """A set-point that supersedes a running one mid-move names only the elbow: the board
    retargets the joints a line names, and the shoulder and wrist went on to the first
    one's target at its pace while the elbow crept to its own: a path nobody judged, 15.9
    mm under the table (found by the model-based test). They now go along with the new
    set-point, one group move judged whole; in virtual time, on the emulated board."""
    sim = Sim(load_config(), baud=115_200).ready()
    first = sim.ask(ins.move(shoulder=26.3, elbow=93.7, wrist=0.8), stream=STREAM)
    sim.run(0.002)
    newer = ins.move(elbow=102, time_ms=1500)
    sim.ask(newer, stream=STREAM)
    deepest = 0.0
    for _ in range(400):  # 2 s: the watchdog holds the arm at 0.5 s
        sim.run(0.005)
        deepest = max(deepest, _depth_under_table_mm(sim))
    assert sim.outcomes[first].reason == f"superseded by set-point {newer.id}"
    assert deepest <= PATH_TOLERANCE_M * 1000.0 + 1e-3, f"{deepest:.1f} mm under the table"
    retarget = [d for _, d in sim.sent if b"#2P1820" in d]
    assert retarget and b"#1P" in retarget[0] and b"#3P" in retarget[0], sim.sent
