"""The fast path (issue 12): an idle arm's move is written by the thread that submits it.

And a stop at any point of that path, before the check, between the check and
the write, or during the write, leaves its STOP last on the wire: a move that
predates the stop never stays in effect after it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, replace

import pytest

from al5d.arm import instruction as ins
from al5d.arm.instruction import Outcome, Result
from al5d.arm.states import State
from al5d.clock import wall_ns
from al5d.model import distance_to_segment
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Record
from al5d_rig.armrig import Rig, executed_tips


def writers(rig: Rig) -> list[str]:
    """Names of the threads that wrote each move, as they are written."""
    names: list[str] = []
    rig.driver.motion_listeners.append(lambda _: names.append(threading.current_thread().name))
    return names


def test_an_idle_arms_move_is_written_by_the_callers_thread(rig: Rig) -> None:
    names = writers(rig)
    assert rig.driver.execute(ins.move(base=20), 10).ok
    assert names == [threading.current_thread().name]
    assert rig.driver.state is State.READY


def test_a_move_behind_another_is_written_by_the_worker(rig: Rig) -> None:
    names = writers(rig)
    first = rig.driver.submit(ins.move(base=40, time_ms=500))
    second = rig.driver.submit(ins.move(base=0))
    assert first.result(10).ok and second.result(10).ok
    assert names == [threading.current_thread().name, "al5d-worker"]
    assert [r.raw[:7] for r in rig.moves()[-2:]] == [b"#0P1900", b"#0P1500"]


def acts_on(rec: Record, channel: int) -> str:
    """ "stop" or "move" if the line acted on `channel` (a STOP, a group move), else ""."""
    for c in rec.commands:
        if isinstance(c, p.Stop) and c.channel == channel:
            return "stop"
        if isinstance(c, p.GroupMove) and any(t.channel == channel for t in c.targets):
            return "move"
    return ""


def quiet(rig: Rig, for_s: float = 0.15) -> None:
    """Until the board has received nothing for `for_s` (a stop's six STOPs take 38.5 ms of
    wire at 9600 baud)."""
    seen = -1
    while len(rig.emu.records) != seen:
        seen = len(rig.emu.records)
        time.sleep(for_s)


def held(rig: Rig, channel: int) -> bool:
    """The channel's pulse does not change any more: nothing moves it."""
    before = rig.emu.pulse_us(channel)
    time.sleep(0.2)
    return rig.emu.pulse_us(channel) == before


@dataclass
class Trial:
    result: Result
    #: What reached the board on the base's channel during the trial, in order.
    base: list[str]
    #: The threads that reached the race point: the fast path runs in the caller's.
    at_point: list[str]


def run_with_a_stop(rig: Rig, point: str, wait: bool) -> Trial:
    """Submit an idle arm's move; a stop comes from another thread at `point` of its fast
    path, and (if `wait`) is done before the path goes on, or has at least ended the
    epoch ("locked": it then waits for the write lock, which the move holds)."""
    threads: list[threading.Thread] = []
    at_point: list[str] = []
    board = rig.driver.core.board
    assert board is not None
    write = board.write_command
    before = len(rig.emu.records)

    def hook(at: str) -> None:
        if at != point or threads:
            return
        at_point.append(threading.current_thread().name)
        epoch = rig.driver.epoch
        thread = threading.Thread(target=rig.driver.execute, args=(ins.stop(), 5))
        threads.append(thread)
        thread.start()
        if wait and point == "locked":
            deadline = time.monotonic() + 5
            while rig.driver.epoch == epoch and time.monotonic() < deadline:
                time.sleep(0.001)
        elif wait:
            thread.join(5)

    def writing(data: bytes, unless: Callable[[], bool] | None = None) -> float | None:
        hook("writing")
        return write(data, unless) if unless is not None else write(data)

    rig.driver.writer.race_hook = hook
    board.write_command = writing  # type: ignore[method-assign]
    try:
        outcome = rig.driver.execute(ins.move(base=80, time_ms=1500), 10)
    finally:
        rig.driver.writer.race_hook = None
        board.write_command = write  # type: ignore[method-assign]
        for th in threads:
            th.join(5)
    rig.emu.wait_for(lambda rs: any(acts_on(r, 0) == "stop" for r in rs[before:]), 2)
    quiet(rig)
    base = [a for r in rig.emu.records[before:] if (a := acts_on(r, 0))]
    return Trial(outcome.result, base, at_point)


@pytest.mark.parametrize(
    ("point", "wait", "expected", "reached"),
    [
        # After the move was judged, before its admission: the move was sent (submitted)
        # before the stop, which cancels it, as it would had it waited in the queue.
        ("judged", True, Result.CANCELLED, False),
        # Between that check and the write: the stop is done first; the move never goes out.
        ("checked", True, Result.CANCELLED, False),
        # The move holds the write lock and the stop waits for it, the epoch ended: the
        # move's last check sees that, and it never goes out.
        ("locked", True, Result.CANCELLED, False),
        # As the write begins (before its lock), the two racing: either may have it first.
        ("writing", False, Result.CANCELLED, None),
    ],
)
def test_a_stop_at_any_point_of_the_fast_path_is_never_overtaken(
    rig: Rig, point: str, wait: bool, expected: Result, reached: bool | None
) -> None:
    for trial in range(10 if reached is None else 3):
        got = run_with_a_stop(rig, point, wait)
        assert got.at_point == [threading.current_thread().name], f"trial {trial}: fast path?"
        assert got.result is expected, f"trial {trial}"
        assert "stop" in got.base, f"trial {trial}: no STOP on the board"
        # Nothing of the move after the stop's STOP: it went out before it, or not at all.
        assert "move" not in got.base[got.base.index("stop") :], f"trial {trial}: {got.base}"
        if reached is not None:
            assert ("move" in got.base) is reached, f"trial {trial}: {got.base}"
        assert held(rig, 0), f"trial {trial}: base still moving after the stop"
        assert rig.driver.state is State.STOPPED
        assert rig.driver.execute(ins.release(), 5).ok
        assert rig.driver.execute(ins.move(base=0), 10).ok  # back for the next trial


def test_a_move_right_after_a_cancel_waits_for_the_pose_to_be_read_back(rig: Rig) -> None:
    """A cancel halts the arm and has the worker read its pose back; a move submitted at
    once must not be written before that read, or the read is a snapshot of the new move
    and the driver's estimate of where the arm is freezes there."""
    for trial in range(3):
        first = ins.move(base=80 if trial % 2 == 0 else -80, time_ms=1500)
        rig.driver.submit(first)
        time.sleep(0.3)
        assert rig.driver.cancel(first.id)
        second = rig.driver.submit(ins.move(base=0, elbow=60 + 10 * trial, time_ms=800))
        time.sleep(0.4)  # about half-way
        estimate, board = rig.driver.positions(), rig.emu.servo_degrees()
        for joint in ("base", "elbow"):
            assert abs(estimate[joint] - board[joint]) < 3, (trial, joint, estimate, board)
        assert second.result(10).ok


def test_a_move_sent_before_a_stop_and_submitted_after_it_is_cancelled(rig: Rig) -> None:
    # An action accepts a goal, then runs it a little later (or a move waits on a topic
    # behind a flood): a stop in between cancels it, as it cancels every move that waits,
    # even once the arm is released again.
    sent = wall_ns()
    assert rig.driver.execute(ins.stop(), 5).ok
    assert rig.driver.execute(ins.release(), 5).ok
    n = len(rig.moves())
    late = rig.driver.submit(replace(ins.move(base=30), sent_ns=sent)).result(5)
    assert late.result is Result.CANCELLED and "cancelled by stop (it was sent before)" in (
        late.reason
    )
    assert len(rig.moves()) == n
    assert rig.driver.submit(replace(ins.move(base=30), sent_ns=wall_ns())).result(10).ok


def test_a_move_sent_while_the_arm_was_locked_and_taken_after_the_release_is_refused(
    rig: Rig,
) -> None:
    assert rig.driver.execute(ins.stop(), 5).ok
    sent = wall_ns()
    assert rig.driver.execute(ins.release(), 5).ok
    n = len(rig.moves())
    late = rig.driver.submit(replace(ins.move(base=30), sent_ns=sent)).result(5)
    assert late.result is Result.REFUSED and "sent while the arm was locked" in late.reason
    assert len(rig.moves()) == n


def test_a_stop_and_a_release_while_a_sent_move_is_judged_still_cancel_it(rig: Rig) -> None:
    """A goal accepted before a stop, submitted as the stop and a release come in before its
    admission: it is cancelled, not run (it was sent before the stop)."""
    n = len(rig.moves())
    sent = wall_ns()

    def hook(at: str) -> None:
        if at == "judged":
            rig.driver.writer.race_hook = None
            assert rig.driver.execute(ins.stop(), 5).ok
            assert rig.driver.execute(ins.release(), 5).ok

    rig.driver.writer.race_hook = hook
    try:
        late = rig.driver.submit(replace(ins.move(base=30), sent_ns=sent)).result(5)
    finally:
        rig.driver.writer.race_hook = None
    assert late.result is Result.CANCELLED, late
    assert len(rig.moves()) == n


def test_a_line_planned_as_another_move_gets_in_first_starts_where_that_one_ends(
    rig: Rig,
) -> None:
    """A straight line is planned on an idle arm; another thread's move is written before
    the line is queued: the line is planned again from where that move ends."""
    assert rig.driver.execute(ins.preset("ready"), 10).ok
    other: list[Future[Outcome]] = []
    fired = threading.Event()

    def hook(at: str) -> None:
        if at == "judged" and not fired.is_set():
            fired.set()  # the other move passes here too
            other.append(rig.driver.submit(ins.move(base=30, time_ms=300)))

    n = len(rig.moves())
    target = (150.0, -200.0, 150.0)
    rig.driver.writer.race_hook = hook
    try:
        line = rig.driver.submit(ins.move_to(*target, pitch=-30, line=True))
    finally:
        rig.driver.writer.race_hook = None
    assert other and other[0].result(10).ok
    assert line.result(20).ok
    moves = rig.moves()[n:]
    assert len(moves) > 2  # the other move, then the line's hops
    start = rig.emu.trajectory(moves[1].t_effect, [moves[1].t_effect])  # where the line began
    assert start["base"][1][0] == pytest.approx(30, abs=0.5)
    tips = executed_tips(rig, moves[1:], rig.emu.settle_time(0.01))
    end = tuple(c / 1000 for c in target)
    worst = max(distance_to_segment(tips[0], end, q) for q in tips)
    assert worst <= 0.001, f"the line went {worst * 1000:.1f} mm off"
