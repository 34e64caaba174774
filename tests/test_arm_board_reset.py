"""A board that resets, and the USB link's low-latency mode, seen from the driver (issue 11)."""

from __future__ import annotations

import logging
import math
import time

import pytest
from armrig import Rig, logged

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Result
from al5d.arm.states import State
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.emulator import Emulator, Link
from al5d.ssc32u.emulator.board import Fault


def warnings(caplog: pytest.LogCaptureFixture, text: str) -> list[str]:
    return [
        r.getMessage()
        for r in logged(caplog)
        if r.levelno >= logging.WARNING and text in r.getMessage()
    ]


def test_a_reset_while_idle_locks_the_arm_and_forgets_the_pose(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    assert rig.driver.execute(ins.move(base=30), 10).ok
    rig.emu.inject(Fault.RESET)
    rig.driver.wait_for_state(State.FAULT, 3)  # found by the idle check (every 0.5 s)
    rig.driver.wait_for_state(State.STOPPED, 5)  # back, but locked: a person must look
    assert warnings(caplog, "the board has reset")
    assert all(math.isnan(v) for v in rig.driver.positions().values()), "the pose is unknown"
    n = len(rig.moves())
    refused = rig.driver.execute(ins.move(base=0), 5)
    assert refused.result is Result.REFUSED and len(rig.moves()) == n
    assert rig.driver.execute(ins.release(), 5).ok
    caplog.clear()
    assert rig.driver.execute(ins.move(base=10), 10).ok
    # The next move is a first command again, and the driver says so (D1).
    assert warnings(caplog, "D1:")


def test_a_reset_during_a_move_cancels_it_and_nothing_more_is_written(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    long = rig.driver.submit(ins.move(base=80, time_ms=3000))
    queued = rig.driver.submit(ins.move(base=-80, time_ms=3000))
    time.sleep(0.4)
    rig.emu.inject(Fault.RESET)
    outcome = long.result(5)
    assert outcome.result is Result.CANCELLED and "reset" in outcome.reason
    assert queued.result(5).result is Result.CANCELLED
    rig.driver.wait_for_state(State.STOPPED, 5)
    time.sleep(0.3)
    assert not any(m.raw.startswith(b"#0P700") for m in rig.moves()), "the queued move ran"


def test_a_board_with_pulses_at_power_up_gets_the_half_speed_start_up_park(
    config: ArmConfig, caplog: pytest.LogCaptureFixture
) -> None:
    """D1 with a board whose startup string set pulses: it knows where the servos are, so
    the park is timed (half speed), and there is no first-command warning."""
    caplog.set_level(logging.DEBUG, logger="al5d")
    pulses = {j.channel: 1500 for j in config.joints.values()}
    with Emulator(config, power_up=pulses) as emu:
        driver = ArmDriver(config, emu.port)
        driver.start()
        try:
            driver.wait_for_state(State.READY, 15)
            park = [r for r in emu.records if r.raw.startswith(b"#")]
            assert len(park) == 1 and b"T" in park[0].raw, park
            assert not warnings(caplog, "D1:")
        finally:
            driver.close()


def test_the_driver_asks_for_low_latency_and_says_what_it_got(
    config: ArmConfig, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="al5d")
    with Emulator(config) as emu, SSC32U(emu.port) as board:
        # A pseudo terminal is no USB serial device: the ioctl is refused, and said so.
        assert board.low_latency is False
        assert any("low-latency mode not available" in r.getMessage() for r in caplog.records)


def test_a_board_that_reset_while_unplugged_is_found_on_reconnecting(
    linked: tuple[Emulator, ArmDriver], caplog: pytest.LogCaptureFixture
) -> None:
    """Unplugged, power-cycled, plugged back: the driver reconnects, and does not take the
    board for the one it left (its pulses are gone)."""
    caplog.set_level(logging.DEBUG, logger="al5d")
    emu, driver = linked
    assert driver.execute(ins.move(base=30), 10).ok
    emu.inject(Fault.DISCONNECT)
    driver.wait_for_state(State.FAULT, 3)
    emu.reset()
    emu.reconnect()
    driver.wait_for_state(State.STOPPED, 5)  # back, locked
    assert warnings(caplog, "the board has reset")
    assert all(math.isnan(v) for v in driver.positions().values()), "the pose is unknown"


def test_a_reset_during_a_stop_is_found_by_the_read_back(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    """The read-back after a stop sees the pulses gone, when the reset came before it."""
    long = rig.driver.submit(ins.move(base=80, time_ms=3000))
    time.sleep(0.3)
    rig.emu.inject(Fault.RESET)  # the stop comes before the next link check (0.15 s)
    rig.driver.submit(ins.stop())
    assert long.result(5).result is Result.CANCELLED
    rig.driver.wait_for_state(State.STOPPED, 5)
    deadline = time.monotonic() + 3
    while not warnings(caplog, "the board has reset") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert warnings(caplog, "the board has reset")
    rig.driver.wait_for_state(State.STOPPED, 5)
    assert all(math.isnan(v) for v in rig.driver.positions().values()), "the pose is unknown"


def test_the_driver_and_its_stop_on_the_usb_link(config: ArmConfig) -> None:
    """On the board's USB link a flush drops nothing already written, and every answer
    waits 16 ms in the chip: the driver still works, and its stop still holds the arm,
    because it writes ESC first (a move cut short on the wire is cancelled, not run)."""
    with Emulator(config, usb=Link()) as emu:
        driver = ArmDriver(config, emu.port)
        driver.start()
        try:
            driver.wait_for_state(State.READY, 15)
            assert driver.execute(ins.move(base=20), 10).ok
            for delay in (0.0, 0.002, 0.02, 0.3):  # during the move's bytes, and after
                long = driver.submit(ins.move(base=-80, elbow=120, time_ms=3000))
                time.sleep(delay)
                assert driver.execute(ins.stop(), 5).ok
                assert long.result(5).result is Result.CANCELLED
                held = emu.servo_degrees()
                time.sleep(0.3)
                after = emu.servo_degrees()
                assert all(abs(after[j] - held[j]) < 0.5 for j in held), (delay, held, after)
                raws = [r.raw for r in emu.records]
                last_stop = max(i for i, raw in enumerate(raws) if b"STOP" in raw)
                assert not any(raw.startswith(b"#") for raw in raws[last_stop:]), raws[-4:]
                assert driver.execute(ins.release(), 5).ok
        finally:
            driver.close()
