"""The core's bookkeeping of writes from callers' threads survives what goes wrong in them.

Found by the model-based test (`test_arm_model.py`, at `make soak`'s scale): a board
pulled, then two stops at once; the first stop's failed write let go of the board and
closed it while the second was writing, pyserial raised a TypeError on the half-closed
port, and the core never heard that the second write was over: the worker waited for it
for ever, and every later move waited in `moving`.
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.driver import ArmDriver
from al5d.arm.states import State
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.emulator import Emulator, Fault
from al5d.ssc32u.errors import LinkLost


def test_a_port_closed_under_a_write_is_a_lost_link(config: ArmConfig) -> None:
    with Emulator(config) as emu, SSC32U(emu.port) as board:
        # Another thread is closing it: its descriptor is gone, `is_open` not yet false (as
        # pyserial's `close` leaves it between its two steps).
        board._wire.closed = True
        fd, board._ser.fd = board._ser.fd, None
        try:
            with pytest.raises(LinkLost, match="the port was closed"):
                board.stop(range(6))
            with pytest.raises(LinkLost, match="the port was closed"):
                board.move({0: 1500})
        finally:
            board._ser.fd = fd


def test_a_failing_stop_write_still_frees_the_arm_for_the_next_move(rig: object) -> None:
    from al5d_rig.armrig import Rig

    assert isinstance(rig, Rig)
    board = rig.driver.core.board
    assert board is not None
    stop = board.stop

    def broken(channels: object, paced: bool = False, key: object = None) -> bytes:
        raise RuntimeError("a bug in the write")

    board.stop = broken  # type: ignore[assignment,method-assign]
    with pytest.raises(RuntimeError):
        rig.driver.submit(ins.stop())
    board.stop = stop  # type: ignore[method-assign]
    # A fault (the board let go of and closed), then back: locked, as a stop came.
    rig.driver.wait_for_state(State.STOPPED, 10)
    if rig.driver.locked:
        assert rig.driver.execute(ins.release(), 5).ok
    assert rig.driver.execute(ins.move(base=5), 10).ok


def test_stops_racing_on_a_pulled_board_never_wedge_the_arm(config: ArmConfig) -> None:
    server = config.server.model_copy(
        update={"answer_timeout_s": 0.5, "reconnect_interval_s": 0.05}
    )
    fast = config.model_copy(update={"server": server})
    link = Path(tempfile.mkdtemp(prefix="al5d-core-")) / "ssc32u"
    with Emulator(fast, baud=115200, link=link, initial_pose=fast.presets["park"]) as emu:
        driver = ArmDriver(fast, str(link), 115200)
        driver.start()
        try:
            driver.wait_for_state(State.READY, 20)
            for trial in range(40):
                emu.inject(Fault.DISCONNECT)
                time.sleep(0.01 * (trial % 5))
                go = threading.Barrier(2)

                def stop(go: threading.Barrier = go) -> None:
                    go.wait(5)
                    driver.submit(ins.stop())

                threads = [threading.Thread(target=stop) for _ in range(2)]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(10)
                emu.reconnect()
                deadline = time.monotonic() + 10
                while driver.state not in (State.READY, State.STOPPED):
                    assert time.monotonic() < deadline, f"trial {trial}: {driver.state}"
                    time.sleep(0.01)
                if driver.locked:
                    assert driver.execute(ins.release(), 5).ok
                assert driver.execute(ins.move(base=2 if trial % 2 else -2), 10).ok, trial
        finally:
            driver.close(10)
