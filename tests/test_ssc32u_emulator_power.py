"""The emulated board's power-up state and its reset (a brown-out), from raw bytes (issue 11)."""

from __future__ import annotations

import time

import pytest
import serial

from al5d.arm.config import ArmConfig
from al5d.ssc32u import facts
from al5d.ssc32u.emulator import Emulator, Fault, Record
from al5d.ssc32u.emulator.board import RESET, STARTUP, Board


def ask(port: serial.Serial, line: bytes, n: int | None = None) -> bytes:
    port.reset_input_buffer()
    port.write(line)
    return port.read_until(b"\r") if n is None else port.read(n)


def line(emu: Emulator, raw: bytes) -> Record:
    return emu.wait_for(lambda rs: any(r.raw == raw for r in rs))[-1]


ARM = b"QP0QP1QP2QP3QP4QP5\r"


# -- reset ---------------------------------------------------------------------------------


def test_a_reset_takes_every_pulse_and_the_next_move_runs_at_full_speed(
    emulator: Emulator,
) -> None:
    with serial.Serial(emulator.port, timeout=1) as port:
        port.write(b"#0P1500#1P1600#2P1700#3P1800#4P1900#5P2000\r")
        assert ask(port, ARM, 6) == bytes([150, 160, 170, 180, 190, 200])
        port.write(b"#0P2400T3000\r")  # a timed move under way when the board resets
        assert ask(port, b"Q\r", 1) == b"+"
        emulator.inject(Fault.RESET)
        assert not emulator.has_fault(Fault.RESET), "a reset is an event, not a state"
        assert ask(port, ARM, 6) == bytes(6), "QP answers 0 on every channel after a reset"
        assert ask(port, b"Q\r", 1) == b"."  # the move died with the board
        # The board forgot where the servos were: the first-command rule again.
        port.write(b"#0P1000T2000\r")
        first = line(emulator, b"#0P1000T2000")
        assert "first command since power-up" in (first.ignored or "")
        assert ask(port, b"QP0\r", 1) == bytes([100])  # jumped, no 2 s ramp
        port.write(b"#0P2000T2000\r")  # the second one is timed again
        second = line(emulator, b"#0P2000T2000")
        assert second.accepted
        assert emulator.pulse_us(0, second.t_effect + 1.0) == pytest.approx(1500)
    reset = [r for r in emulator.records if r.source == RESET]
    assert len(reset) == 1 and reset[0].raw == b"" and not reset[0].accepted


def test_the_servos_stay_where_they_were_limp(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, timeout=1) as port:
        port.write(b"#0P2400\r")
        line(emulator, b"#0P2400")
        time.sleep(0.1)
        emulator.inject(Fault.RESET)
        where = emulator.servo_us(0)
        time.sleep(0.3)
    assert emulator.pulse_us(0) == 0
    assert emulator.servo_us(0) == pytest.approx(where)  # no pulse: it stops, limp


def test_a_reset_clears_the_latches_and_loses_the_partial_line(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, timeout=1) as port:
        emulator.set_input("A", 0)
        time.sleep(0.03)  # longer than the debounce
        emulator.set_input("A", 1)
        time.sleep(0.03)
        port.write(b"#0P1")  # half a line when the board resets
        time.sleep(0.02)
        emulator.inject(Fault.RESET)
        assert ask(port, b"AL\r", 1) == b"1", "the latch saw the low before the reset"
        port.write(b"500\r")
        rest = line(emulator, b"500")
    assert not rest.commands and emulator.pulse_us(0) == 0


def test_a_reset_can_announce_itself(config: ArmConfig) -> None:
    with (
        Emulator(config, startup="#0P1500", announce_reset=True) as emu,
        serial.Serial(emu.port, timeout=1) as port,
    ):
        port.write(b"#0P2000\r")
        assert ask(port, b"QP0\r", 1) == bytes([200])
        emu.inject(Fault.RESET)
        # Unasked: what SS answers; and the startup string ran again.
        assert port.read_until(b"\r") == b'"#0P1500;"\r'
        assert ask(port, b"QP0\r", 1) == bytes([150])
    assert [r.raw for r in emu.records if r.source == STARTUP] == [b"#0P1500", b"#0P1500"]


def test_a_startup_string_query_is_answered_after_a_reset(config: ArmConfig) -> None:
    with (
        Emulator(config, startup="VER;") as emu,
        serial.Serial(emu.port, timeout=1) as port,
    ):
        assert port.read(1) == b"", "nothing before the link was open"
        emu.inject(Fault.RESET)
        assert port.read_until(b"\r") == b"SSC32-V2.50USB\r"


# -- power-up state -----------------------------------------------------------------------------


def test_power_up_pulses_from_the_registers(config: ArmConfig) -> None:
    with (
        Emulator(config, power_up={0: 1500, 1: 1200}) as emu,
        serial.Serial(emu.port, timeout=1) as port,
    ):
        assert ask(port, ARM, 6) == bytes([150, 120, 0, 0, 0, 0])
        assert ask(port, b"R0\r") == f"{facts.ENABLE_PULSE_WIDTH}\r".encode()
        assert ask(port, b"R64\r") == b"1500\r"
        # The board knows where it put them: a timed move is timed (no first-command rule).
        port.write(b"#0P2000T1000\r")
        rec = line(emu, b"#0P2000T1000")
        assert rec.accepted
        assert emu.pulse_us(0, rec.t_effect + 0.5) == pytest.approx(1750)
        # And a reset brings them back.
        emu.inject(Fault.RESET)
        assert ask(port, ARM, 6) == bytes([150, 120, 0, 0, 0, 0])


def test_registers_decide_what_applies_at_power_up(config: ArmConfig) -> None:
    enable = facts.ENABLE_PULSE_WIDTH | facts.ENABLE_PULSE_OFFSET
    regs = {0: enable, facts.R_PULSE_WIDTH + 2: 1500, facts.R_PULSE_OFFSET + 2: -50}
    with Emulator(config, registers=regs) as emu, serial.Serial(emu.port, timeout=1) as port:
        assert ask(port, b"QP2\r", 1) == bytes([150])  # QP reads the pulse, not the offset
        time.sleep(0.3)
        assert emu.servo_us(2) == pytest.approx(1450)  # the servo sees the offset
        # The global disable bit (UG-37) turns all of it off from the next power-up.
        port.write(f"R0={enable | facts.ENABLE_GLOBAL_DISABLE}\r".encode())  # read back below
        assert ask(port, b"R0\r") == f"{enable | facts.ENABLE_GLOBAL_DISABLE}\r".encode()
        emu.inject(Fault.RESET)
        assert ask(port, b"QP2\r", 1) == bytes([0])


def test_the_startup_string_runs_at_power_up(config: ArmConfig) -> None:
    with (
        Emulator(config, startup="#0P1500#1P1700") as emu,
        serial.Serial(emu.port, timeout=1) as port,
    ):
        # A missing final `;` is added: only terminated commands run (UG-39).
        assert ask(port, b"SS\r") == b'"#0P1500#1P1700;"\r'
        assert ask(port, b"R0\r") == f"{facts.ENABLE_STARTUP_STRING}\r".encode()
        assert ask(port, b"QP0QP1\r", 2) == bytes([150, 170])
        # Over the wire, as a user would program it; the tail without `;` does not run.
        port.write(b"SSDEL255\rSSCAT #0P1000;#1P2000\r")
        line(emu, b"SSCAT #0P1000;#1P2000")
        emu.inject(Fault.RESET)
        assert ask(port, b"QP0QP1\r", 2) == bytes([100, 0])
        # Without the enable bit it does not run at all.
        port.write(b"R0=0\r")
        line(emu, b"R0=0")
        emu.inject(Fault.RESET)
        assert ask(port, b"QP0\r", 1) == bytes([0])
    ran = [r for r in emu.records if r.source == STARTUP]
    assert [r.raw for r in ran] == [b"#0P1500#1P1700", b"#0P1000"]


def test_a_bare_board_resets_too() -> None:
    board = Board(power_up={3: 2000})
    board.execute(b"#3P1000", 10.0)
    assert board.pulse_us(3, 10.0) == 1000
    board.inject(Fault.RESET)
    assert board.pulse_us(3) == 2000
    assert board.reset(20.0, announce=True) == [
        (pytest.approx(20.0 + board.answer_delay_s + 3 * 10 / 9600), b'""\r')
    ]


def test_power_up_settings_are_checked() -> None:
    with pytest.raises(ValueError):
        Board(power_up={0: 3000})
    with pytest.raises(ValueError):
        Board(registers={256: 1})
    with pytest.raises(ValueError):
        Board(registers={0: 70000})
