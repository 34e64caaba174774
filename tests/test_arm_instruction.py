"""The instruction grammar: parse, format, and errors that point at the word."""

from __future__ import annotations

import pytest

from al5d.arm import instruction as ins
from al5d.arm.instruction import GrammarError, Instruction, Kind, Wait


@pytest.mark.parametrize(
    ("text", "kind", "preset", "joints", "time_ms"),
    [
        ("park", Kind.PRESET, "park", (), None),
        ("READY", Kind.PRESET, "ready", (), None),
        ("straight_up time=1500", Kind.PRESET, "straight_up", (), 1500),
        ("move base=30", Kind.MOVE, "", (("base", 30.0),), None),
        (
            "move base=-12.5 Elbow=90 time=800",
            Kind.MOVE,
            "",
            (("base", -12.5), ("elbow", 90.0)),
            800,
        ),
        (
            "move base=1 base=2",
            Kind.MOVE,
            "",
            (("base", 1.0), ("base", 2.0)),
            None,
        ),  # driver refuses
        ("stop", Kind.STOP, "", (), None),
        ("release", Kind.RELEASE, "", (), None),
        ("shutdown", Kind.SHUTDOWN, "", (), None),
    ],
)
def test_parse(
    text: str, kind: Kind, preset: str, joints: tuple[tuple[str, float], ...], time_ms: int | None
) -> None:
    instr = ins.parse_instruction(text)
    assert (instr.kind, instr.preset, instr.joints, instr.time_ms) == (
        kind,
        preset,
        joints,
        time_ms,
    )
    assert instr.id


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty instruction"),
        ("fly", r"word 1 'fly': unknown instruction"),
        ("move", r"word 1 'move': name at least one"),
        ("move base=abc", r"word 2 'base=abc': 'abc' is not a number of degrees"),
        # Python's float() reads these (a fuzz run found 'move 0=NAN' taken as a move).
        ("move 0=NAN", r"word 2 '0=NAN': 'NAN' is not a number of degrees"),
        ("move base=-inf", r"word 2 'base=-inf': '-inf' is not a number of degrees"),
        ("move_to x=1e999 y=0 z=100", r"word 2 'x=1e999': '1e999' is not a number of mm"),
        ("move base30", r"word 2 'base30': expected <name>=<value>"),
        ("move base=10 time=fast", r"word 3 'time=fast': 'fast' is not a whole number of ms"),
        ("move base=10 time=-5", r"word 3 'time=-5': time -5 ms is negative"),
        # Python's float() and int() read these as 10 and 5: a number is typed in ASCII
        # digits, or refused.
        ("move base=1_0", r"word 2 'base=1_0': '1_0' is not a number of degrees"),
        ("move base=\u0665", "word 2 'base=\u0665': '\u0665' is not a number of degrees"),
        ("move_to x=\uff15 y=0 z=100", "'\uff15' is not a number of mm"),
        ("move base=10 time=1_000", r"'1_000' is not a whole number of ms"),
        ("move base=10 time=\uff15", "'\uff15' is not a whole number of ms"),
        # More digits than Python's int() reads (4300): out of range, by its sign.
        ("move base=10 time=" + "9" * 5000, r"\(5000 characters\) ms is above the limit"),
        ("move base=10 time=-" + "9" * 5000, r"time '-9{39}'\.\.\. \(5001 characters\) ms is neg"),
        ("move base=10 time=5 time=6", r"word 4 'time=6': time given twice"),
        ("release now=1", r"word 2 'now=1': release takes no arguments"),
        ("park base=3", r"word 2 'base=3': a preset takes only time=<ms>"),
        # The word that is wrong is the first: named with the nearest instruction.
        ("mvoe base=30", r"word 1 'mvoe': unknown instruction; did you mean 'move'\? expected "),
        ("moveto x=250 y=0 z=120", r"word 1 'moveto': unknown instruction; did you mean 'move_to'"),
        (
            "Strait_up time=9",
            r"word 1 'Strait_up': unknown instruction; did you mean 'straight_up'",
        ),
        # Words of sequence files only: said where they belong.
        ("wait 100", r"word 1 'wait': wait <ms> pauses a sequence file or al5d shell"),
        ("pose home", r"word 1 'pose': pose <name> moves to a pose saved in a poses file"),
    ],
)
def test_grammar_errors_point_at_the_word(text: str, message: str) -> None:
    with pytest.raises(GrammarError, match=message):
        ins.parse_instruction(text)


@pytest.mark.parametrize(
    "text", ["stop now=1", "STOP base=3", "stop please", "stop\tnow", "stop!", "Stop. now"]
)
def test_a_stop_is_read_whatever_follows_it(text: str) -> None:
    # Refused for its words, as any other instruction is, a stop typed in a hurry left the
    # arm moving (`al5d send stop now`, a line of `al5d shell`).
    read = ins.parse_instruction(text)
    assert read == Instruction(Kind.STOP, id=read.id)


def test_a_number_is_read_as_it_is_typed() -> None:
    joints = ins.parse_instruction("move base=+5 elbow=.5 wrist=-2. gripper=1E1").joints
    assert joints == (("base", 5.0), ("elbow", 0.5), ("wrist", -2.0), ("gripper", 10.0))
    assert ins.parse_instruction("move base=1e1 time=+0300").time_ms == 300
    # Leading zeros are not digits that int() counts against its 4300.
    assert ins.parse_instruction("move base=1 time=" + "0" * 5000 + "5").time_ms == 5


@pytest.mark.parametrize(
    "instr",
    [
        ins.preset("park"),
        ins.preset("ready", time_ms=2000),
        ins.move(base=30.5, elbow=90),
        ins.move(time_ms=700, wrist=-45, gripper=80),
        ins.stop(),
        ins.release(),
        ins.shutdown(),
    ],
)
def test_format_then_parse_gives_the_instruction_back(instr: Instruction) -> None:
    back = ins.parse_instruction(ins.format_instruction(instr))
    assert (back.kind, back.preset, back.joints, back.time_ms) == (
        instr.kind,
        instr.preset,
        instr.joints,
        instr.time_ms,
    )


def test_sequence_lines() -> None:
    assert ins.parse_sequence_step("  # a comment") is None
    assert ins.parse_sequence_step("") is None
    assert ins.parse_sequence_step("wait 500") == (Wait(500), False)
    step = ins.parse_sequence_step("move base=10  # and a note")
    assert step is not None
    instr, background = step
    assert isinstance(instr, Instruction) and instr.joints == (("base", 10.0),) and not background
    step = ins.parse_sequence_step("move base=10 time=3000 &")
    assert step is not None and step[1] is True
    with pytest.raises(GrammarError, match="wait takes one number"):
        ins.parse_sequence_step("wait")
    with pytest.raises(GrammarError, match="cannot run in the background"):
        ins.parse_sequence_step("wait 10 &")


def test_ids_are_unique() -> None:
    ids = {ins.stop().id for _ in range(1000)}
    assert len(ids) == 1000


class TestSequenceFiles:
    """Issue 10: a sequence file is checked whole; every error names the file, line, word."""

    def test_a_huge_wait_is_an_error_naming_the_line_not_a_crash(self) -> None:
        data = b"park\nmove base=10\nwait 99999999999999999999999\n"
        with pytest.raises(GrammarError) as caught:
            ins.parse_sequence(data, "demo.seq")
        assert str(caught.value) == (
            "demo.seq:3: word 2 '99999999999999999999999': 99999999999999999999999 ms "
            "is above the limit of 3600000 ms"
        )

    def test_invalid_utf8_is_an_error_naming_the_line(self) -> None:
        with pytest.raises(
            GrammarError, match=r"^x.seq:2: not UTF-8 text \(byte 0xff at column 6\)"
        ):
            ins.parse_sequence(b"park\nmove \xff\n", "x.seq")

    @pytest.mark.parametrize(
        ("line", "error"),
        [
            ("wait", "s.seq:1: word 1 'wait': wait takes one number of ms"),
            ("wait 10 20", "s.seq:1: word 3 '20': wait takes one number of ms"),
            ("wait 10 &", "s.seq:1: word 1 'wait': wait cannot run in the background"),
            ("  &", "s.seq:1: word 1 '&': nothing before it to run in the background"),
        ],
    )
    def test_every_error_names_the_word(self, line: str, error: str) -> None:
        with pytest.raises(GrammarError) as caught:
            ins.parse_sequence(f"{line}\n".encode(), "s.seq")
        assert str(caught.value).startswith(error), caught.value

    def test_a_time_a_message_cannot_carry_is_refused_before_packing(self) -> None:
        with pytest.raises(GrammarError, match="4294967301 ms is above the limit of 4294967295"):
            ins.parse_instruction("move base=30 time=4294967301")

    def test_the_whole_file_is_read_before_anything(self) -> None:
        steps = ins.parse_sequence(b"# demo\npark\nmove base=10 &\nwait 100\n\nstop\n", "d.seq")
        assert [type(s).__name__ for s, _ in steps] == [
            "Instruction",
            "Instruction",
            "Wait",
            "Instruction",
        ]
        assert [bg for _, bg in steps] == [False, True, False, False]


def test_the_move_builder_takes_its_time_as_time_ms_not_as_a_joint() -> None:
    """An outside try's `ins.move(base=40, time=1000)` went to the server, which refused
    a joint named time; the builder says so at once."""
    with pytest.raises(TypeError, match=r"time_ms= \(milliseconds\); `time` is no joint"):
        ins.move(base=40, time=1000)
    assert ins.move(base=40, time_ms=1000).time_ms == 1000
