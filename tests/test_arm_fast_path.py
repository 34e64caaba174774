"""The fast path (issue 12): an idle arm's move is written by the thread that submits it.

And a stop at any point of that path, before the check, between the check and
the write, or during the write, leaves its STOP last on the wire: a move that
predates the stop never stays in effect after it.
"""

from __future__ import annotations

import threading
import time

import pytest
from armrig import Rig

from al5d.arm import instruction as ins
from al5d.arm.instruction import Result
from al5d.arm.states import State
from al5d.ssc32u import protocol as p


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


def last_word_on(rig: Rig, channel: int) -> bytes:
    """The last line the board received that acted on `channel` (a move or a STOP)."""

    def acts(rec_commands: tuple[p.Command, ...]) -> bool:
        for c in rec_commands:
            if isinstance(c, p.Stop) and c.channel == channel:
                return True
            if isinstance(c, p.GroupMove) and any(t.channel == channel for t in c.targets):
                return True
        return False

    return [r.raw for r in rig.emu.records if acts(r.commands)][-1]


def quiet(rig: Rig, for_s: float = 0.15) -> None:
    """Until the board has received nothing for `for_s` (a re-STOP after a raced move takes
    about 60 ms of wire at 9600 baud to arrive whole)."""
    seen = -1
    while len(rig.emu.records) != seen:
        seen = len(rig.emu.records)
        time.sleep(for_s)


def held(rig: Rig, channel: int) -> bool:
    """The channel's pulse does not change any more: nothing moves it."""
    before = rig.emu.pulse_us(channel)
    time.sleep(0.2)
    return rig.emu.pulse_us(channel) == before


def stop_in_another_thread(rig: Rig, wait: bool) -> threading.Thread:
    thread = threading.Thread(target=rig.driver.execute, args=(ins.stop(), 5))
    thread.start()
    if wait:
        thread.join(5)
    return thread


def run_with_a_stop(rig: Rig, point: str, wait: bool) -> Result:
    """Submit an idle arm's move; a stop comes at `point` of its fast path."""
    threads: list[threading.Thread] = []
    board = rig.driver.shared.board
    assert board is not None
    write = board.write_command

    def hook(at: str) -> None:
        if at == point:
            threads.append(stop_in_another_thread(rig, wait))

    def writing(data: bytes) -> float:
        hook("writing")
        return write(data)

    rig.driver.writer.race_hook = hook
    board.write_command = writing  # type: ignore[method-assign]
    try:
        outcome = rig.driver.execute(ins.move(base=80, time_ms=1500), 10)
    finally:
        rig.driver.writer.race_hook = None
        board.write_command = write  # type: ignore[method-assign]
        for th in threads:
            th.join(5)
    return outcome.result


def test_a_stop_before_the_check_refuses_the_move(rig: Rig) -> None:
    assert rig.driver.execute(ins.stop(), 5).ok
    n = len(rig.moves())
    assert rig.driver.execute(ins.move(base=80), 5).result is Result.REFUSED
    assert len(rig.moves()) == n


@pytest.mark.parametrize(
    ("point", "wait"),
    [
        ("checked", True),  # between the check and the write: the stop is done first
        ("writing", False),  # during the write: the two race for the wire
    ],
)
def test_a_stop_during_the_fast_path_has_the_last_word(rig: Rig, point: str, wait: bool) -> None:
    for trial in range(10 if point == "writing" else 3):
        result = run_with_a_stop(rig, point, wait)
        assert result is Result.CANCELLED, f"trial {trial}"
        rig.emu.wait_for(lambda rs: any(r.raw.startswith(b"STOP0") for r in rs[-8:]), 2)
        quiet(rig)
        assert last_word_on(rig, 0) == b"STOP0", f"trial {trial}: the move outlived the stop"
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


def test_a_move_taken_in_before_a_stop_and_submitted_after_it_is_cancelled(rig: Rig) -> None:
    # An action accepts a goal, then runs it a little later: a stop in between cancels it,
    # as it cancels every move that waits, even once the arm is released again.
    taken_at = rig.driver.epoch
    assert rig.driver.execute(ins.stop(), 5).ok
    assert rig.driver.execute(ins.release(), 5).ok
    n = len(rig.moves())
    late = rig.driver.submit(ins.move(base=30), taken_at).result(5)
    assert late.result is Result.CANCELLED and "a stop (or a fault) came after" in late.reason
    assert len(rig.moves()) == n
    assert rig.driver.submit(ins.move(base=30), rig.driver.epoch).result(10).ok
