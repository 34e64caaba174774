"""A sequence judged whole before it is sent (`al5d.arm.sequence`): every problem at once, each
with its line, judged as the server judges each step from where the steps before leave it."""

from __future__ import annotations

from pathlib import Path

import pytest

from al5d.arm import validate
from al5d.arm.config import ArmConfig, load_config
from al5d.arm.instruction import (
    GrammarError,
    Instruction,
    Kind,
    SequenceErrors,
    Wait,
    move,
    parse_sequence,
)
from al5d.arm.poses import NamedPoses
from al5d.arm.sequence import SequenceJudge, judged_steps

POSES = NamedPoses(Path("/arm/poses.yaml")).with_pose("home", {"base": 0, "elbow": 90})
#: After `ready`, this takes the wrist under the table (the upper arm level, the forearm
#: straight down): the server refuses it, naming the table.
UNDER_TABLE = "move shoulder=90 elbow=90"


@pytest.fixture(scope="module")
def config() -> ArmConfig:
    return load_config()


@pytest.fixture(scope="module")
def judge(config: ArmConfig) -> SequenceJudge:
    return SequenceJudge(config)


def test_every_problem_is_told_at_once_with_its_line(judge: SequenceJudge) -> None:
    text = (
        "ready\n"
        "move elbo=20\n"
        "# a comment\n"
        "move base=200\n"
        f"{UNDER_TABLE}\n"
        "pose hom time=500\n"
        "move base=10 &\n"
        "wait 100\n"
    )
    judged = judge.judge_text(text, "pick.seq", POSES)
    assert not judged.ok
    said = [p.at("pick.seq") for p in judged.problems]
    assert [p.number for p in judged.problems] == [2, 4, 5, 6], said
    assert said[0].startswith("pick.seq:2: unknown joint 'elbo'; did you mean 'elbow'?"), said
    assert said[1] == "pick.seq:4: base: 200 deg is outside the range -90..90", said
    assert "pick.seq:5: " in said[2] and "table" in said[2], said
    assert said[3] == (
        "pick.seq:6: word 2 'hom': no saved pose named 'hom'; did you mean 'home'? "
        "(in /arm/poses.yaml: home)"
    )
    # The good lines are read, each with its line and text.
    assert [(line.number, line.text) for line in judged.lines] == [
        (1, "ready"),
        (7, "move base=10 &"),
        (8, "wait 100"),
    ]
    assert judged.lines[2].step == (Wait(100), False)
    with pytest.raises(SequenceErrors) as e:
        judged_steps(text.encode(), "pick.seq", POSES)
    assert e.value.errors == tuple(said)


def test_each_step_is_judged_from_where_the_ones_before_leave_the_arm(
    judge: SequenceJudge, config: ArmConfig
) -> None:
    # Where the arm starts is not known: a move that names only some joints cannot be judged
    # against the table; after a preset it can.
    assert judge.judge_text(UNDER_TABLE).ok
    assert not judge.judge_text(f"ready\n{UNDER_TABLE}\n").ok
    assert not judge.judge_text(UNDER_TABLE, start=config.presets["ready"]).ok
    # A stop halts the arm wherever it was: not known again until a move says.
    assert judge.judge_text(f"ready\nmove base=30 time=3000 &\nstop\nrelease\n{UNDER_TABLE}\n").ok
    # What the server judges itself, as any client's instruction, is the same judgement.
    limits = validate.Limits.of(config)
    bad = move(base=200)
    assert judge.judge_text("move base=200").problems[0].reason == validate.check(bad, limits)


def test_a_move_to_is_judged_for_reach_and_planned_once_the_arm_is_known(
    judge: SequenceJudge,
) -> None:
    far = judge.judge_text("move_to x=900 y=0 z=100\n")
    assert [p.number for p in far.problems] == [1]
    assert "reach" in far.problems[0].reason, far.problems
    assert judge.judge_text("park\nmove_to x=250 y=0 z=120 pitch=-30 path=line\npark\n").ok
    # Below the table: refused wherever the arm is.
    low = judge.judge_text("move_to x=200 y=0 z=-50\n")
    assert "table" in low.problems[0].reason, low.problems


def test_nothing_after_a_shutdown_is_run(judge: SequenceJudge) -> None:
    judged = judge.judge_text("ready\nshutdown\npark\n", "end.seq")
    assert [p.at("end.seq") for p in judged.problems] == [
        "end.seq:3: the server shuts down at line 2: nothing after it is run"
    ]


def test_the_shell_judges_a_line_alone(judge: SequenceJudge) -> None:
    assert judge.judge_line("  # nothing") is None
    step = judge.judge_line("move base=10 time=200 &")
    assert step is not None
    instr, background = step
    assert isinstance(instr, Instruction) and instr.kind is Kind.MOVE and background
    with pytest.raises(GrammarError, match=r"^base: 200 deg is outside the range -90\.\.90$"):
        judge.judge_line("move base=200")
    with pytest.raises(GrammarError, match=r"^word 1 'mvoe': unknown instruction; did you"):
        judge.judge_line("mvoe base=30")


def test_a_stop_with_words_is_a_stop_at_the_shell_and_an_error_in_a_file(
    judge: SequenceJudge,
) -> None:
    # Typed at a prompt, a stop refused for its words left the arm moving; a file is judged
    # whole before it runs, and such a line is likelier two lines run together.
    for line in ("stop now", "STOP base=3 &", "stop move base=3"):
        step = judge.judge_line(line)
        assert step is not None and step[0] == Instruction(Kind.STOP, id=step[0].id)
    judged = judge.judge_text("move base=10\nstop move base=3  # two lines\nstop &\n")
    assert [p.at("f.seq") for p in judged.problems] == [
        "f.seq:2: word 2 'move': in a sequence file, stop takes no words"
    ]
    assert judged.problems[0].grammar
    with pytest.raises(GrammarError, match=r"f\.seq:1: word 2 'now': in a sequence file, stop"):
        parse_sequence(b"stop now\n", "f.seq")


def test_a_preset_the_configuration_adds_is_an_instruction(config: ArmConfig) -> None:
    data = config.model_dump()
    data["presets"]["home"] = dict(config.presets["ready"])
    judged = SequenceJudge(ArmConfig.model_validate(data)).judge_text("home time=500\n")
    assert judged.ok, judged.problems
    instr = judged.lines[0].step[0]
    assert isinstance(instr, Instruction) and instr.preset == "home"


def test_only_what_no_configuration_would_take_is_the_grammars(judge: SequenceJudge) -> None:
    """`al5d run` says a file's grammar before it has found a server: an unknown first word is
    not the grammar's, as the server's configuration may name a preset of that name."""
    judged = judge.judge(b"wave\nmove base=x\nwait\nmove base=200\n")
    assert [(p.number, p.grammar) for p in judged.problems] == [
        (1, False),
        (2, True),
        (3, True),
        (4, False),
    ]


def test_a_file_an_editor_began_with_a_byte_order_mark_is_read(judge: SequenceJudge) -> None:
    judged = judge.judge(b"\xef\xbb\xbfready\nmove base=10\n")
    assert judged.ok, judged.problems
    assert [line.number for line in judged.lines] == [1, 2]
    assert [line.known for line in judged.lines] == [False, True]  # where the arm starts
