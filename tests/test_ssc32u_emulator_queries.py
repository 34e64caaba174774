"""Every documented query of the emulated board, answered with the manual's bytes (issue 11).

Raw bytes over the pty for the answers; the board model with chosen times for the
debounce and the latches, whose rules are about milliseconds.
"""

from __future__ import annotations

import time

import pytest
import serial

from al5d.arm.config import ArmConfig
from al5d.ssc32u import facts
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator
from al5d.ssc32u.emulator.board import Board


def ask(port: serial.Serial, line: bytes, n: int | None = None) -> bytes:
    """Write a query line; read `n` bytes, or up to the CR."""
    port.reset_input_buffer()
    port.write(line)
    return port.read_until(b"\r") if n is None else port.read(n)


def test_digital_inputs_answer_ascii_one_byte_per_pin_in_order(config: ArmConfig) -> None:
    inputs = {"A": 0, "B": 1, "C": "open", "D": None, "VE": 40, "VF": 200}
    with Emulator(config, inputs=inputs) as emu, serial.Serial(emu.port, timeout=1) as port:
        # Open pins read high: the inputs' weak pull-up (UG-33). E is at 0.8 V, F at 3.9 V.
        assert ask(port, b"A B C D E F\r", 6) == b"011101"
        assert ask(port, b"FEDCBA\r", 6) == b"101110"
        assert ask(port, b"ABEDL\r", 4) == b"0101"  # UG-33's example
        assert port.read(1) == b"", "a digital read has no CR"


def test_analog_inputs_answer_one_byte_and_the_first_read_is_not_valid(
    config: ArmConfig,
) -> None:
    inputs = {"VA": 102, "VB": 179, "C": 1}
    with Emulator(config, inputs=inputs) as emu, serial.Serial(emu.port, timeout=1) as port:
        # UG-34: the read that makes a pin analog "will not return valid data".
        first = ask(port, b"VA VB VC VH\r", 4)
        assert first == bytes([facts.ANALOG_FIRST_READ] * 4)
        # Then 2 V and 3.5 V are the manual's 102 and 179; 5 V is 255; an open pin, its
        # pull-up off, floats (the emulator says 0).
        assert ask(port, b"VA VB VC VH\r", 4) == bytes([102, 179, 255, 0])
        emu.set_input("VA", 7)
        assert ask(port, b"VA\r", 1) == bytes([7])


def test_several_kinds_of_query_in_one_line_answer_in_order(emulator: Emulator) -> None:
    emulator.set_input("VB", 33)
    with serial.Serial(emulator.port, timeout=1) as port:
        ask(port, b"VB\r", 1)
        port.write(b"#0P1500\r")
        expected = b"1" + bytes([150, 33]) + b"960\r" + b"." + b"SSC32-V2.50USB\r"
        answer = ask(port, b"A QP0 VB R4 Q VER\r", len(expected))
        assert port.read(1) == b""
    assert answer == expected


def test_registers_read_back_as_written_in_decimal_with_cr(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, timeout=1) as port:
        # UG-37's examples.
        port.write(b"R0=1023\r")
        assert ask(port, b"R0\r") == b"1023\r"
        port.write(b"R32 = -50\r")
        assert ask(port, b"R32\r") == b"-50\r"
        assert ask(port, b"R255\r") == b"0\r"
        # UG-34: R4 holds the baud / 10.
        assert ask(port, b"R4\r") == b"960\r"
        port.write(b"R7=70000\r")  # not 16 bits: not stored
        assert ask(port, b"R7\r") == b"0\r"


def test_rdflt_sets_the_defaults_and_answers_ok_after_a_second(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, timeout=3) as port:
        port.write(b"R0=1023\rR4=3840\r")
        t0 = time.monotonic()
        assert ask(port, b"RDFLT\r") == b"OK\r"
        assert time.monotonic() - t0 >= facts.DEFAULTS_TIME_S
        assert ask(port, b"R0\r") == b"0\r"
        assert ask(port, b"R4\r") == b"960\r"


def test_the_startup_string_commands(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, timeout=1) as port:
        assert ask(port, b"SS\r") == b'""\r'
        # UG-39's examples: SSCAT keeps the spaces but the first; SS quotes, then CR.
        port.write(b"SSCAT #0P1000#1P2000T3000;\r")
        port.write(b"SSCAT PL0 SQ5 SM50;\r")
        assert ask(port, b"SS\r") == b'"#0P1000#1P2000T3000;PL0 SQ5 SM50;"\r'
        port.write(b"SSDEL 5\r")
        assert ask(port, b"SS\r") == b'"#0P1000#1P2000T3000;PL0 SQ5 "\r'
        port.write(b"SSCAT " + b"x" * 90 + b"\r")  # at most 100 characters: the rest is lost
        whole = p.parse_startup(ask(port, b"SS\r"))
        assert len(whole) == facts.STARTUP_MAX_CHARS and whole.startswith("#0P1000#1P2000")
        port.write(b"SSDEL255\r")
        assert ask(port, b"SS\r") == b'""\r'
    # SS and SSCAT change no servo: the string runs at power-up only.
    assert emulator.pulse_us(0) == 0


def test_byte_output_sets_a_bank_of_outputs(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, timeout=1) as port:
        port.write(b"#3:123\r#0H\r")  # UG-32: 123 = 01111011, pins 26 and 31 low
        emulator.wait_for(lambda rs: any(r.raw == b"#0H" for r in rs))
    assert [emulator.output(ch) for ch in range(24, 32)] == [
        True,
        True,
        False,
        True,
        True,
        True,
        True,
        False,
    ]
    assert emulator.output(0) is True and emulator.output(8) is None


# -- debounce and latches, at chosen times ----------------------------------------------------


def answer(board: Board, line: bytes, t: float) -> bytes:
    answers = board.execute(line, t)
    return b"".join(data for _, data in answers)


def test_a_digital_read_changes_only_after_15_ms_at_the_new_level() -> None:
    board = Board(inputs={"A": 1})
    board.set_input("A", 0, t=100.0)
    assert answer(board, b"A", 100.010) == b"1"  # not yet 15 ms low
    assert answer(board, b"A", 100.016) == b"0"
    board.set_input("A", 1, t=101.0)
    board.set_input("A", 0, t=101.010)  # a 10 ms blip high: never seen
    assert answer(board, b"A", 101.030) == b"0"


def test_a_latched_read_says_low_if_the_pin_went_low_since_the_last_one() -> None:
    board = Board()  # open: high through the pull-up
    assert answer(board, b"AL", 50.0) == b"1"
    board.set_input("A", 0, t=50.1)
    board.set_input("A", 1, t=50.2)  # 100 ms low, then high again
    assert answer(board, b"A", 50.3) == b"1"
    assert answer(board, b"AL", 50.3) == b"0"  # it went low since the last AL
    assert answer(board, b"AL", 50.4) == b"1"  # that read reset the latch
    board.set_input("A", 0, t=50.5)
    board.set_input("A", 1, t=50.505)  # 5 ms low: debounced away, not latched
    assert answer(board, b"AL", 50.6) == b"1"
    board.set_input("A", 0, t=50.7)
    assert answer(board, b"AL BL AL", 50.8) == b"010"  # low now; B open; A still low


def test_input_settings_are_checked() -> None:
    for name, value in (("I", 1), ("A", 2), ("VA", 256), ("A", "x"), ("VX", 1)):
        with pytest.raises(ValueError):
            Board(inputs={name: value})
