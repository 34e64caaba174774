"""The emulated SSC-32U, spoken to with raw bytes over a real pseudo terminal."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import serial

from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Fault, Mechanics, Record
from al5d.ssc32u.emulator.board import Board


@pytest.fixture
def wire(emulator: Emulator) -> Iterator[serial.Serial]:
    """A plain pyserial port on the emulator: the test speaks bytes, not our driver."""
    with serial.Serial(emulator.port, 9600, timeout=0.5) as port:
        yield port


def last(emulator: Emulator, raw: bytes, timeout: float = 2.0) -> Record:
    recs = emulator.wait_for(lambda rs: any(r.raw == raw for r in rs), timeout)
    return [r for r in recs if r.raw == raw][-1]


def test_version_answer(wire: serial.Serial) -> None:
    wire.write(b"VER\r")
    assert wire.read_until(b"\r") == b"SSC32-V2.50USB\r"


def test_q_and_qp_answers_are_the_documented_bytes(wire: serial.Serial) -> None:
    wire.write(b"QP0QP1\r")
    assert wire.read(2) == b"\x00\x00"  # no pulse on either channel since power-up
    wire.write(b"#0P1500#1P2000\r")
    wire.write(b"Q\r")
    assert wire.read(1) == b"."
    wire.write(b"QP0QP1\r")
    assert wire.read(2) == bytes([150, 200])
    wire.write(b"#0P1000T1000\r")
    wire.write(b"Q\r")
    assert wire.read(1) == b"+"
    wire.write(b"QP0\r")
    mid = wire.read(1)[0] * 10
    assert 1000 < mid < 1500


def test_answers_after_a_small_delay(emulator: Emulator, wire: serial.Serial) -> None:
    t0 = time.monotonic()
    wire.write(b"Q\r")
    assert wire.read(1) == b"."
    elapsed = time.monotonic() - t0
    # Two bytes out, one back: at least 3 byte times plus the answer delay.
    assert elapsed >= p.wire_time_s(3, 9600) + emulator.answer_delay_s


def test_case_spaces_and_several_commands_in_one_line(
    emulator: Emulator, wire: serial.Serial
) -> None:
    wire.write(b"#0 p1500 #1P1600 t0 q\r")
    assert wire.read(1) == b"."
    rec = last(emulator, b"#0 p1500 #1P1600 t0 q")
    assert rec.commands[0] == p.GroupMove((p.ChannelTarget(0, 1500), p.ChannelTarget(1, 1600)), 0)
    assert emulator.pulse_us(0) == 1500 and emulator.pulse_us(1) == 1600


def test_esc_cancels_the_line(emulator: Emulator, wire: serial.Serial) -> None:
    wire.write(b"#0P1500T100\x1b")
    rec = last(emulator, b"#0P1500T100")
    assert rec.ignored == "cancelled by ESC"
    assert emulator.pulse_us(0) == 0


def test_unknown_input_is_ignored_and_recorded(emulator: Emulator, wire: serial.Serial) -> None:
    wire.write(b"HELLO\r#0P1500\r")
    rec = last(emulator, b"HELLO")
    assert not rec.accepted and "cannot read" in (rec.ignored or "")
    last(emulator, b"#0P1500")
    assert emulator.pulse_us(0) == 1500


def test_out_of_range_pulse_is_clipped_as_the_board_does(
    emulator: Emulator, wire: serial.Serial
) -> None:
    wire.write(b"#0P3000\r")
    rec = last(emulator, b"#0P3000")
    assert "clipped to 2500" in (rec.ignored or "")
    assert emulator.pulse_us(0) == 2500


def test_first_command_after_power_up_ignores_speed_and_time(
    emulator: Emulator, wire: serial.Serial
) -> None:
    wire.write(b"#0P2000T2000\r")
    rec = last(emulator, b"#0P2000T2000")
    assert "first command since power-up" in (rec.ignored or "")
    assert emulator.pulse_us(0, rec.t_effect) == 2000  # jumped: no ramp
    wire.write(b"Q\r")
    assert wire.read(1) == b"."
    # The second command is timed.
    wire.write(b"#0P1000T1000\r")
    rec2 = last(emulator, b"#0P1000T1000")
    assert rec2.accepted
    assert emulator.pulse_us(0, rec2.t_effect + 0.5) == pytest.approx(1500)


def test_group_move_duration_rule_worked_example(emulator: Emulator, wire: serial.Serial) -> None:
    # UG: S500 from 2000 to 750 with T2000 takes 2.5 s, because 1250 us at 500 us/s.
    wire.write(b"#0P2000\r")
    wire.write(b"#0P750S500T2000\r")
    rec = last(emulator, b"#0P750S500T2000")
    t = rec.t_effect
    assert emulator.pulse_us(0, t + 1.0) == pytest.approx(1500)  # 500 us/s, not 625
    assert emulator.pulse_us(0, t + 2.0) == pytest.approx(1000)
    assert emulator.pulse_us(0, t + 2.5) == pytest.approx(750)
    # And Q says so on the wire: still moving after 2.0 s, done after 2.5 s.
    time.sleep(max(0.0, t + 2.2 - time.monotonic()))
    wire.write(b"Q\r")
    assert wire.read(1) == b"+"
    time.sleep(max(0.0, t + 2.55 - time.monotonic()))
    wire.write(b"Q\r")
    assert wire.read(1) == b"."


def test_stop_holds_the_pulse_and_q_says_moving_until_the_move_time_is_over(
    config: ArmConfig,
) -> None:
    board = Board(config, baud=9600)  # the board's logic alone, in virtual time
    t = board.powered_at + 1
    board.execute(b"#0P1000", t)
    board.execute(b"#0P2000T1000", t + 0.01)
    t_stop = t + 0.31
    board.execute(b"STOP0", t_stop)
    held = board.pulse_us(0, t_stop)
    assert held == pytest.approx(1300)  # 0.3 s into 1 s from 1000 to 2000 us
    assert board.pulse_us(0, t_stop + 0.5) == held
    # The board holds whole microseconds (QP says 130).
    assert board.execute(b"QP0", t_stop + 0.1)[0][1] == bytes([round(held) // 10])
    # The manual's caveat: STOP does not end the move's time.
    assert board.execute(b"Q", t_stop + 0.2)[0][1] == b"+"
    assert board.execute(b"Q", t + 0.01 + 1.05)[0][1] == b"."


def test_pulse_offset_and_digital_outputs(emulator: Emulator, wire: serial.Serial) -> None:
    wire.write(b"#0P1500\r#0PO50\r#9H\r")
    last(emulator, b"#9H")
    time.sleep(0.2)
    assert emulator.servo_us(0) == pytest.approx(1550)  # the servo sees pulse + offset
    wire.write(b"QP0\r")
    assert wire.read(1) == bytes([150])


@pytest.mark.parametrize("baud", [9600, 115200])
def test_a_command_takes_effect_when_its_cr_has_arrived(config: ArmConfig, baud: int) -> None:
    command = b"#0P1500#1P1600#2P1700#3P1800#4P1900#5P2000T1234\r"
    with Emulator(config, baud=baud) as emu, serial.Serial(emu.port, baud) as port:
        for _ in range(5):
            t_write = time.monotonic()
            port.write(command)
            rec = emu.wait_for(lambda rs: len(rs) > 0)[-1]
            emu.clear_records()
            wire = p.wire_time_s(len(command), baud)
            assert rec.t_effect - t_write >= wire
            # Only against a hang: beside two busy loops this test process's board thread
            # once read the CR 59 ms after the wire had carried it.
            assert rec.t_effect - t_write < wire + 1.0
            time.sleep(0.01)


def test_client_at_another_baud_is_noise(config: ArmConfig) -> None:
    with Emulator(config, baud=9600) as emu, serial.Serial(emu.port, 115200, timeout=0.2) as port:
        port.write(b"VER\r")
        assert port.read(20) == b""
        rec = emu.wait_for(lambda rs: len(rs) > 0)[-1]
        assert "noise" in (rec.ignored or "")


# Output flushes (USB and UART) and line feeds: test_ssc32u_emulator_link.py.


class TestServoModel:
    """The servo model alone (`Board`, in virtual time): a pty would add only its clock."""

    def test_a_jump_is_followed_at_the_servo_speed(self, config: ArmConfig) -> None:
        base = config.joints["base"]
        board = Board(config, initial_pose={"base": -90})
        t = board.powered_at + 1
        board.execute(b"#0P2400", t)  # first command: the pulse jumps to +90 deg
        start = base.to_us(-90)
        v = base.speed_us_s
        assert board.pulse_us(0, t) == 2400
        assert board.servo_us(0, t + 0.1) == pytest.approx(start + v * 0.1)
        reach = t + (2400 - start) / v
        assert board.servo_us(0, reach + 0.01) == pytest.approx(2400)
        # Within 1 degree: 10 us earlier than the full travel.
        assert board.settle_time(1.0, ["base"]) == pytest.approx(reach - 10 / v, abs=1e-4)

    def test_a_slow_ramp_is_tracked_and_a_fast_one_lags(self, config: ArmConfig) -> None:
        board = Board(config, initial_pose={"base": 0})
        t = board.powered_at + 1
        board.execute(b"#0P1500", t)
        t += 0.01
        board.execute(b"#0P2400T2000", t)  # 450 us/s: slower than the servo (3330 us/s)
        for dt in (0.5, 1.0, 1.9):
            assert board.servo_us(0, t + dt) == pytest.approx(board.pulse_us(0, t + dt))
        end = t + 2.0
        board.execute(b"#0P600T100", end)  # 18000 us/s: the servo cannot keep up
        assert board.servo_us(0, end + 0.1) > board.pulse_us(0, end + 0.1) + 100
        assert board.settle_time(1.0, ["base"]) > end + 0.1


def test_the_board_model_needs_no_pty(config: ArmConfig) -> None:
    # The board's logic alone: lines in at their time of effect, answers out with their due time.
    board = Board(config, baud=9600)
    assert board.execute(b"#0P1500#1P2000", 10.0) == []
    ((due, data),) = board.execute(b"QP0QP1", 10.5)
    assert data == bytes([150, 200])
    assert due == pytest.approx(10.5 + board.answer_delay_s + p.wire_time_s(2, 9600))
    assert board.execute(b"#0P1000T1000", 11.0) == []
    assert board.execute(b"Q", 11.5)[0][1] == b"+"
    assert board.pulse_us(0, 11.5) == pytest.approx(1250)
    assert [r.raw for r in board.records] == [b"#0P1500#1P2000", b"QP0QP1", b"#0P1000T1000", b"Q"]
    board.inject(Fault.NO_ANSWER)
    assert board.execute(b"VER", 12.0) == []


def test_a_misaligned_joint_stands_elsewhere_than_its_calibration_says(config: ArmConfig) -> None:
    """`mechanics`: the pulse the config gives for an angle puts the emulated joint elsewhere
    (a horn seated off, a servo turning the other way), read as the joint's true angle."""
    board = Board(
        config,
        mechanics={"base": Mechanics(offset_us=40), "elbow": Mechanics(-20, reversed=True)},
    )
    base, elbow, wrist = (config.joints[n] for n in ("base", "elbow", "wrist"))
    t = board.powered_at + 1
    line = f"#0P{base.to_us(30):.0f}#2P{elbow.to_us(90):.0f}#3P{wrist.to_us(45):.0f}"
    board.execute(line.encode(), t)
    believed, true = board.servo_degrees(t + 5), board.joint_degrees(t + 5)
    assert believed["base"] == pytest.approx(30)
    assert true["base"] == pytest.approx(30 - 40 / base.us_per_deg)  # 4.4 deg short of 30
    assert believed["elbow"] == pytest.approx(90)
    # Reversed about the centre pulse: 1700 us reads as 1300 (+20 us of its offset).
    assert true["elbow"] == pytest.approx(elbow.to_deg(3000 - (elbow.to_us(90) + 20)))
    assert true["wrist"] == pytest.approx(believed["wrist"]) == pytest.approx(45)
    # The pulse that puts the joint where the config believes, found by hand, is the offset's.
    board.execute(f"#0P{base.to_us(30) + 40:.0f}".encode(), t + 6)
    assert board.joint_degrees(t + 11)["base"] == pytest.approx(30)


def test_a_setting_the_board_has_not_is_refused(config: ArmConfig) -> None:
    # The settings are keywords of a TypedDict: nothing but this check catches a misspelt
    # one at run time (it would take the factory's value).
    with pytest.raises(TypeError, match="no setting answer_delay "):
        Board(config, answer_delay=0.01)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="no setting bauds "):
        Emulator(config, bauds=9600)  # type: ignore[call-arg]


def test_mechanics_name_a_configured_joint(config: ArmConfig) -> None:
    with pytest.raises(ValueError, match="'knee': no such joint"):
        Board(config, mechanics={"knee": Mechanics(10)})
