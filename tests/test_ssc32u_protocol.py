"""Encoding and parsing of the SSC-32U protocol against the bytes of the manual."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

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


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: p.encode_group_move([CT(0, 1600.7)]), r"pulse 1600\.7 is not a whole number"),
        (lambda: p.encode_group_move([CT(0, 1700.0)]), r"pulse 1700\.0 is not a whole"),
        (lambda: p.encode_group_move([CT(0, True)]), "pulse True is not a whole"),
        (lambda: p.encode_group_move([CT(0, 1500)], 100.0), r"time 100\.0 is not a whole"),
        (lambda: p.encode_group_move([CT(0, 1500, 7.5)]), r"speed 7\.5 is not a whole"),
        (lambda: p.encode_group_move([CT(0.0, 1500)]), r"channel 0\.0 is not a whole"),
        (lambda: p.encode_pulse_offset({0: 10.0}), r"offset 10\.0 is not a whole"),
        (lambda: p.encode_register_write(0, 8.0), r"register value 8\.0 is not a whole"),
    ],
)
def test_a_number_that_is_not_a_whole_one_is_refused_not_written_with_its_point(
    call: object, message: str
) -> None:
    """The board reads digits only: `#0P1700.0T100` is a line it ignores, which the
    encoder wrote without a word (an outside try of the driver, pulses from angles)."""
    with pytest.raises(p.ProtocolError, match=message):
        call()


def test_numpy_integers_are_whole_numbers() -> None:
    assert p.encode_group_move([CT(np.int64(0), np.int32(1500))], np.int64(100)) == b"#0P1500T100\r"


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


# -- line feeds, the new commands and their answers (issue 11) ---------------------------


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        (b"\nVER", [p.Version()]),
        (b"VER\n", [p.Version()]),
        (b"#9P1800\n", [p.GroupMove((CT(9, 1800),))]),
        (b"\n#0P1500\n#1P1600\nT500\n", [p.GroupMove((CT(0, 1500), CT(1, 1600)), 500)]),
        (b"Q\nP\n3", [p.QueryPulse((3,))]),
    ],
)
def test_line_feeds_are_ignored_like_spaces_and_tabs(
    line: bytes, expected: list[p.Command]
) -> None:
    assert p.parse_line(line) == expected


def test_the_manuals_input_register_and_startup_commands_parse() -> None:
    digital = [p.ReadDigital(pin, latched) for latched in (False, True) for pin in "ABCDEF"]
    assert p.parse_line(b"A B C D E F AL BL CL DL EL FL") == digital
    # UG-33's example: grouped reads need no spaces.
    assert p.parse_line(b"ABEDL") == [
        p.ReadDigital("A"),
        p.ReadDigital("B"),
        p.ReadDigital("E"),
        p.ReadDigital("D", latched=True),
    ]
    assert p.parse_line(b"VA VB VC VD VE VF VG VH") == [p.ReadAnalog(x) for x in "ABCDEFGH"]
    assert p.parse_line(b"ver") == [p.Version()]  # VER is not VE then R
    assert p.parse_line(b"R0=1023") == [p.WriteRegister(0, 1023)]
    assert p.parse_line(b"R32 = -50") == [p.WriteRegister(32, -50)]
    assert p.parse_line(b"R 32") == [p.ReadRegister(32)]
    assert p.parse_line(b"RDFLT") == [p.DefaultRegisters()]
    assert p.parse_line(b"SS") == [p.ShowStartup()]
    assert p.parse_line(b"SSDEL 5") == [p.DeleteStartup(5)]
    assert p.parse_line(b"STOP 5") == [p.Stop(5)]
    assert p.parse_line(b"#3:123") == [p.ByteOutput(3, 123)]
    # SSCAT keeps every space but the one after it (UG-39), and the case.
    assert p.parse_line(b"SSCAT #0P1000#1P2000T3000;") == [p.AppendStartup("#0P1000#1P2000T3000;")]
    assert p.parse_line(b"sscat PL0 SQ5 SM50;") == [p.AppendStartup("PL0 SQ5 SM50;")]
    assert p.parse_line(b"SSCAT  two") == [p.AppendStartup(" two")]
    assert p.parse_line(b"\nSSCAT x;\n") == [p.AppendStartup("x;")]


@pytest.mark.parametrize(
    "line", [b"G", b"GL", b"VI", b"R256", b"R1=", b"#4:1", b"#0:256", b"AX", b"SSDEL"]
)
def test_malformed_input_and_register_lines_are_rejected_whole(line: bytes) -> None:
    assert isinstance(p.parse_line(line), p.Unrecognized)


def test_the_new_commands_bytes() -> None:
    reads = [p.ReadDigital("A"), p.ReadDigital("B", latched=True), p.ReadAnalog("H")]
    assert p.encode_input_reads(reads) == b"ABLVH\r"
    assert p.encode_register_read(32) == b"R32\r"
    assert p.encode_register_write(32, -50) == b"R32=-50\r"
    assert p.encode(p.DefaultRegisters()) == b"RDFLT\r"
    assert p.encode(p.ShowStartup()) == b"SS\r"
    assert p.encode_startup_append("#0P1000;") == b"SSCAT #0P1000;\r"
    assert p.encode_startup_delete(255) == b"SSDEL255\r"
    assert p.encode_byte_output(3, 123) == b"#3:123\r"
    for call in (
        lambda: p.encode_input_reads([p.ReadDigital("G")]),  # G and H are analog only
        lambda: p.encode_input_reads([p.ReadAnalog("I")]),
        lambda: p.encode_input_reads([]),
        lambda: p.encode_register_read(256),
        lambda: p.encode_register_write(0, 65536),
        lambda: p.encode_startup_append("x" * 101),
        lambda: p.encode_startup_append("a\rb"),
        lambda: p.encode_byte_output(4, 0),
    ):
        with pytest.raises(p.ProtocolError):
            call()


def test_the_new_answers() -> None:
    # UG-33, UG-37, UG-39: ASCII 0/1 per pin; registers in decimal then CR; SS quoted then CR.
    assert p.parse_digital(b"0110", 4) == [False, True, True, False]
    with pytest.raises(p.ProtocolError):
        p.parse_digital(b"01", 3)
    with pytest.raises(p.ProtocolError):
        p.parse_digital(b"\x01", 1)
    assert p.parse_register(b"1023\r") == 1023
    assert p.parse_register(b"-50\r") == -50
    for bad in (b"1023", b"OK\r", b"\r"):
        with pytest.raises(p.ProtocolError):
            p.parse_register(bad)
    answer = b'"#0P1000#1P2000T3000;PL0 SQ5 SM50;"\r'
    assert p.parse_startup(answer) == "#0P1000#1P2000T3000;PL0 SQ5 SM50;"
    assert p.parse_startup(b'""\r') == ""
    with pytest.raises(p.ProtocolError):
        p.parse_startup(b"#0P1000;\r")


# -- properties ---------------------------------------------------------------------------

_channels = st.integers(0, 31)
_pins = st.sampled_from("ABCDEF")
_commands: st.SearchStrategy[p.Command] = st.one_of(
    st.builds(
        lambda chans, pws, t: p.GroupMove(
            tuple(CT(ch, pw) for ch, pw in zip(chans, pws, strict=False)), t
        ),
        st.lists(_channels, min_size=1, max_size=6, unique=True),
        st.lists(st.integers(500, 2500), min_size=6, max_size=6),
        st.one_of(st.none(), st.integers(1, 65535)),
    ),
    st.builds(p.Stop, _channels),
    st.just(p.QueryMovement()),
    st.builds(lambda cs: p.QueryPulse(tuple(cs)), st.lists(_channels, min_size=1, max_size=6)),
    st.just(p.Version()),
    st.builds(lambda ch, off: p.PulseOffset(((ch, off),)), _channels, st.integers(-100, 100)),
    st.builds(lambda ch, hi: p.DigitalOutput(((ch, hi),)), _channels, st.booleans()),
    st.builds(p.ByteOutput, st.integers(0, 3), st.integers(0, 255)),
    st.builds(p.ReadDigital, _pins, st.booleans()),
    st.builds(p.ReadAnalog, st.sampled_from("ABCDEFGH")),
    st.builds(p.ReadRegister, st.integers(0, 255)),
    st.builds(p.WriteRegister, st.integers(0, 255), st.integers(-32768, 65535)),
    st.just(p.DefaultRegisters()),
    st.just(p.ShowStartup()),
    st.builds(p.DeleteStartup, st.integers(0, 255)),
)


@given(_commands, st.data())
def test_blanks_and_line_feeds_anywhere_change_nothing(
    command: p.Command, data: st.DataObject
) -> None:
    """UG-24: spaces, tabs and line feeds are ignored, wherever they are in a command."""
    line = p.encode(command)[:-1]
    cuts = sorted(data.draw(st.lists(st.integers(0, len(line)), max_size=8)))
    blanks = data.draw(
        st.lists(st.sampled_from([b" ", b"\t", b"\n"]), min_size=len(cuts), max_size=len(cuts))
    )
    spaced = bytearray()
    start = 0
    for cut, blank in zip(cuts, blanks, strict=True):
        spaced += line[start:cut] + blank
        start = cut
    spaced += line[start:]
    case = data.draw(st.sampled_from([bytes.lower, bytes.upper, bytes]))
    assert p.parse_line(case(bytes(spaced))) == [command]


@given(
    st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), min_size=1, max_size=100),
    st.data(),
)
def test_startup_text_keeps_its_spaces_and_loses_its_line_feeds(
    text: str, data: st.DataObject
) -> None:
    line = p.encode_startup_append(text)[:-1]
    at = sorted(data.draw(st.lists(st.integers(0, len(line)), max_size=4)))
    with_lf = bytearray(line)
    for i in reversed(at):
        with_lf[i:i] = b"\n"
    assert p.parse_line(bytes(with_lf)) == [p.AppendStartup(text)]
