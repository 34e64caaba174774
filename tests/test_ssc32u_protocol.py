"""Encoding and parsing of the SSC-32U protocol against the bytes of the manual."""

from __future__ import annotations

import pytest

from al5d.ssc32u import protocol as p
from al5d.ssc32u.protocol import ChannelTarget as CT


@pytest.mark.parametrize(
    ("targets", "time_ms", "expected"),
    [
        # The manual's examples (UG-24..26).
        ([CT(5, 1500, 750)], None, b"#5P1500S750\r"),
        ([CT(3, 1600)], 1000, b"#3P1600T1000\r"),
        ([CT(5, 1600), CT(10, 750)], 2500, b"#5P1600#10P750T2500\r"),
        # Per-channel speed and a group time together.
        ([CT(0, 2000, 500), CT(1, 750)], 2000, b"#0P2000S500#1P750T2000\r"),
        # T0 means no time: left out.
        ([CT(0, 1500)], 0, b"#0P1500\r"),
        # Pulses off.
        ([CT(4, 0)], None, b"#4P0\r"),
    ],
)
def test_group_move_bytes(targets: list[CT], time_ms: int | None, expected: bytes) -> None:
    assert p.encode_group_move(targets, time_ms) == expected


def test_six_channel_move_is_minimal() -> None:
    data = p.encode_group_move([CT(ch, 1500 + ch * 100) for ch in range(6)], 1234)
    assert data == b"#0P1500#1P1600#2P1700#3P1800#4P1900#5P2000T1234\r"
    assert b" " not in data and len(data) == 6 * 7 + 5 + 1


def test_other_commands_bytes() -> None:
    assert p.encode_stop([0, 1, 5]) == b"STOP0\rSTOP1\rSTOP5\r"
    assert p.encode_query_movement() == b"Q\r"
    assert p.encode_query_pulse([0]) == b"QP0\r"
    assert p.encode_query_pulse([0, 1, 2]) == b"QP0QP1QP2\r"
    assert p.encode_version() == b"VER\r"
    assert p.encode_pulse_offset({0: 10, 1: -5}) == b"#0PO10#1PO-5\r"
    assert p.encode_digital_output({3: True, 4: False}) == b"#3H#4L\r"
    assert p.CANCEL == b"\x1b"


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: p.encode_group_move([CT(0, 499)]), "pulse 499 us is outside 500..2500"),
        (lambda: p.encode_group_move([CT(0, 2501)]), "pulse 2501 us"),
        (lambda: p.encode_group_move([CT(32, 1500)]), "channel 32 is outside 0..31"),
        (lambda: p.encode_group_move([CT(1, 1500), CT(1, 1600)]), "channel given twice"),
        (lambda: p.encode_group_move([CT(1, 1500)], 65536), "time 65536 ms"),
        (lambda: p.encode_group_move([CT(1, 1500, 0)]), "speed 0 must be positive"),
        (lambda: p.encode_group_move([]), "at least one channel"),
        (lambda: p.encode_pulse_offset({0: 101}), "offset 101"),
        (lambda: p.encode_stop([]), "at least one channel"),
    ],
)
def test_encoding_refuses_what_the_board_would_not_take(call: object, message: str) -> None:
    with pytest.raises(p.ProtocolError, match=message):
        call()  # type: ignore[operator]


def test_parse_ignores_case_and_blanks_and_reads_several_commands() -> None:
    assert p.parse_line(b"#0 p1500 s750\t#1P1600 t500") == [
        p.GroupMove((CT(0, 1500, 750), CT(1, 1600)), 500)
    ]
    assert p.parse_line(b"ver") == [p.Version()]
    assert p.parse_line(b"QP0QP1QP2") == [p.QueryPulse((0, 1, 2))]
    assert p.parse_line(b"Stop 3") == [p.Stop(3)]
    assert p.parse_line(b"#0P1500T100Q") == [p.GroupMove((CT(0, 1500),), 100), p.QueryMovement()]
    assert p.parse_line(b"#2PO-20#3H") == [
        p.PulseOffset(((2, -20),)),
        p.DigitalOutput(((3, True),)),
    ]


@pytest.mark.parametrize("line", [b"XYZ", b"#0P", b"T100", b"#40P1500", b"", b"#0P1500Z"])
def test_parse_rejects_malformed_lines_whole(line: bytes) -> None:
    assert isinstance(p.parse_line(line), p.Unrecognized)


@pytest.mark.parametrize(
    "command",
    [
        p.GroupMove((CT(0, 1500, 750), CT(31, 2500)), 65535),
        p.Stop(7),
        p.QueryMovement(),
        p.QueryPulse((0, 1, 2, 3, 4, 5)),
        p.Version(),
        p.PulseOffset(((0, -100), (1, 100))),
        p.DigitalOutput(((2, False),)),
    ],
)
def test_encode_then_parse_gives_the_command_back(command: p.Command) -> None:
    data = p.encode(command)
    assert data.endswith(b"\r") and data.count(b"\r") == 1
    assert p.parse_line(data[:-1]) == [command]


def test_answers() -> None:
    assert p.parse_movement(b"+") is True
    assert p.parse_movement(b".") is False
    with pytest.raises(p.ProtocolError):
        p.parse_movement(b"\xfe")
    assert p.encode_pulses([1500, 750, 0]) == bytes([150, 75, 0])
    assert p.parse_pulses(bytes([150, 75]), [0, 1]) == {0: 1500, 1: 750}
    with pytest.raises(p.ProtocolError, match="answered 1 byte"):
        p.parse_pulses(bytes([150]), [0, 1])
    with pytest.raises(p.ProtocolError, match=r"outside 500\.\.2500"):
        p.parse_pulses(bytes([255]), [0])
    assert p.parse_version(b"SSC32-V2.50USB\r") == "SSC32-V2.50USB"
    with pytest.raises(p.ProtocolError):
        p.parse_version(b"SSC32")


def test_wire_time() -> None:
    # 10 bit times a byte: 1.0417 ms at 9600, 86.8 us at 115200.
    assert p.wire_time_s(1, 9600) == pytest.approx(1 / 960)
    assert p.wire_time_s(48, 9600) == pytest.approx(0.05)
    assert p.wire_time_s(48, 115200) == pytest.approx(48 * 10 / 115200)
    with pytest.raises(ValueError):
        p.wire_time_s(1, 0)


def test_duration_rule_worked_example() -> None:
    # UG: S500 from 2000 to 750 with T2000 takes 1250/500 = 2.5 s, not 2 s.
    assert p.group_duration_s({0: (2000, 750, 500)}, 2000) == pytest.approx(2.5)
    assert p.group_duration_s({0: (2000, 1500, 500)}, 2000) == pytest.approx(2.0)
    assert p.group_duration_s({0: (2000, 750, None)}, None) == 0.0
