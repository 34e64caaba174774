"""A board that resets, and the USB link's low-latency mode, seen from the driver (issue 11)."""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Result
from al5d.arm.states import State
from al5d.owner.loop import Owner
from al5d.ssc32u.emulator import Emulator, LinkModel, Record
from al5d.ssc32u.emulator.board import Fault
from al5d.ssc32u.transport import SerialTransport
from al5d_rig.armrig import Rig, logged


def warnings(caplog: pytest.LogCaptureFixture, text: str) -> list[str]:
    return [
        r.getMessage()
        for r in logged(caplog)
        if r.levelno >= logging.WARNING and text in r.getMessage()
    ]


@contextlib.contextmanager
def driving(emu: Emulator, config: ArmConfig) -> Iterator[Owner]:
    driver = Owner.on_port(config, emu.port)
    driver.start()
    try:
        driver.wait_for_state(State.READY, 15)
        yield driver
    finally:
        driver.close()


def reset_found(
    driver: Owner, emu: Emulator, caplog: pytest.LogCaptureFixture, within: float
) -> None:
    """The reset was a safety event: found, the arm locked, the pose forgotten and read back
    (unknown where the board has no pulse, the board's pulse where it has one)."""
    driver.wait_for_state(State.FAULT, within)
    driver.wait_for_state(State.STOPPED, 5)  # back, but locked
    assert warnings(caplog, "the board has reset")
    for name, deg in driver.positions().items():
        joint = driver.config.joints[name]
        pulse = emu.pulse_us(joint.channel)
        if pulse == 0:
            assert math.isnan(deg), (name, deg)
        else:
            assert deg == pytest.approx(joint.to_deg(pulse), abs=1.0), (name, deg, pulse)


#: A board with no pulse after a reset, and one whose registers give every channel 1500 us
#: at power-up (base's park pulse, but not shoulder's 1750 or elbow's 2050).
POWER_UP = {"none": None, "1500 us": dict.fromkeys(range(6), 1500)}


@pytest.mark.parametrize("power_up", POWER_UP.values(), ids=POWER_UP.keys())
def test_a_reset_then_a_move_at_once_is_found_during_that_move(
    config: ArmConfig, caplog: pytest.LogCaptureFixture, power_up: dict[int, int] | None
) -> None:
    """The move after the reset restores base only: the check reads back the joint written
    least recently (shoulder, parked), whose pulse is gone or is the power-up one."""
    caplog.set_level(logging.DEBUG, logger="al5d")
    with Emulator(config, power_up=power_up) as emu, driving(emu, config) as driver:
        assert driver.execute(ins.move(base=30), 10).ok
        emu.inject(Fault.RESET)
        move = driver.execute(ins.move(base=0, time_ms=2000), 10)
        # Found by a check during the move (how soon: test_arm_core.py, in virtual time).
        assert move.result is Result.CANCELLED and "the board has reset" in move.reason
        reset_found(driver, emu, caplog, 5)
        n = len([r for r in emu.records if r.raw.startswith(b"#")])
        refused = driver.execute(ins.move(shoulder=0), 5)
        assert refused.result is Result.REFUSED
        assert len([r for r in emu.records if r.raw.startswith(b"#")]) == n


def test_a_reset_of_a_board_with_power_up_pulses_is_found_while_idle(
    config: ArmConfig, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG, logger="al5d")
    with Emulator(config, power_up=POWER_UP["1500 us"]) as emu, driving(emu, config) as driver:
        assert driver.execute(ins.move(base=30), 10).ok
        time.sleep(0.6)  # an idle check or more with nothing amiss
        assert driver.state is State.READY
        emu.inject(Fault.RESET)
        assert emu.pulse_us(config.joints["shoulder"].channel) == 1500
        reset_found(driver, emu, caplog, 2 * config.server.idle_check_interval_s + 1)
        assert "puts out 1500 us where the driver expects" in warnings(caplog, "reset:")[0]


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
        driver = Owner.on_port(config, emu.port)
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
    """Only the refusal can be tested here: low-latency mode is the TIOCSSERIAL ioctl, which
    only a serial driver with a UART behind it takes (USB serial, 8250); a pty refuses it,
    and the one such port a test machine may have is its console, not a test's to change."""
    caplog.set_level(logging.INFO, logger="al5d")
    with Emulator(config) as emu:
        transport = SerialTransport(emu.port, 9600)
        # A pseudo terminal is no USB serial device: the ioctl is refused, and said so, once
        # (a server in fault tries to open its port again every second).
        for _ in range(3):
            assert transport.open() is False
            transport.close()
        said = [r for r in caplog.records if "low-latency mode not" in r.getMessage()]
        assert len(said) == 1, said


def test_a_board_that_reset_while_unplugged_is_found_on_reconnecting(
    linked: tuple[Emulator, Owner], caplog: pytest.LogCaptureFixture
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


def stop_count(records: list[Record]) -> int:
    return sum(r.raw.startswith(b"STOP") for r in records)


def test_the_driver_and_its_stop_on_the_usb_link(config: ArmConfig) -> None:
    """On the board's USB link a flush drops nothing already written, and every answer
    waits 16 ms in the chip: the driver still works, and its stop still holds the arm,
    because it writes ESC first (a move cut short on the wire is cancelled, not run)."""
    with Emulator(config, usb=LinkModel()) as emu:
        driver = Owner.on_port(config, emu.port)
        driver.start()
        try:
            driver.wait_for_state(State.READY, 15)
            assert driver.execute(ins.move(base=20), 10).ok
            for delay in (0.0, 0.002, 0.02, 0.3):  # during the move's bytes, and after
                stops = stop_count(emu.records)
                long = driver.submit(ins.move(base=-80, elbow=120, time_ms=3000))
                time.sleep(delay)
                assert driver.execute(ins.stop(), 5).ok
                assert long.result(5).result is Result.CANCELLED
                # Held from when its STOPs are in effect (written is not yet there: six
                # STOPs are 45 ms of the wire at 9600 baud, and a busy host is later still).
                want = stops + len(config.joints)
                emu.wait_for(lambda rs, want=want: stop_count(rs) >= want)
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
