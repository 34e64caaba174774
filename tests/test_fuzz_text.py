"""Fuzzing the text grammar and sequence files (issue 10): nothing but a clear error, ever.

hypothesis generates lines and files; the invariants: parsing ends in an
instruction or a GrammarError (never another exception), an error names the
word (or the file and line), and what parses prints back to itself.
"""

from __future__ import annotations

import string

from hypothesis import given, settings
from hypothesis import strategies as st

from al5d.arm import instruction as ins
from al5d.arm.instruction import GrammarError
from al5d_rig.fuzzcount import count, examples

WORDS = ["park", "ready", "straight_up", "move", "stop", "release", "shutdown", "wait", "&", "#"]
KEYS = ["base", "shoulder", "elbow", "wrist", "gripper", "wrist_rotate", "time", "finger", ""]
VALUES = st.one_of(
    st.integers(-(10**30), 10**30).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(str),
    st.text(string.printable, max_size=12),
    st.text(max_size=8),
)
WORD = st.one_of(
    st.sampled_from(WORDS),
    st.builds(lambda k, v: f"{k}={v}", st.sampled_from(KEYS), VALUES),
    st.text(max_size=15),
)
LINE = st.lists(WORD, max_size=8).map(" ".join)


@settings(max_examples=examples(3000), deadline=None)
@given(line=LINE)
def test_a_line_is_an_instruction_or_a_grammar_error(line: str) -> None:
    count("text lines")
    try:
        instr = ins.parse_instruction(line)
    except GrammarError as e:
        assert str(e)
        assert len(str(e)) < 400  # a reason quotes a bounded part of what it got
        return
    assert ins.parse_instruction(str(instr)).joints == instr.joints
    assert ins.parse_instruction(str(instr)).kind is instr.kind


@settings(max_examples=examples(1000), deadline=None)
@given(data=st.lists(st.one_of(LINE.map(str.encode), st.binary(max_size=30)), max_size=12))
def test_a_sequence_file_is_steps_or_one_error_naming_its_line(data: list[bytes]) -> None:
    count("sequence files")
    try:
        steps = ins.parse_sequence(b"\n".join(data), "f.seq")
    except GrammarError as e:
        assert str(e).startswith("f.seq:")
        line = int(str(e).split(":")[1])
        assert 1 <= line <= max(1, len(b"\n".join(data).splitlines()))
        return
    for step, _ in steps:
        if isinstance(step, ins.Wait):
            assert 0 <= step.ms <= ins.WAIT_MAX_MS
        elif step.time_ms is not None:
            assert 0 <= step.time_ms <= ins.TIME_FIELD_MAX_MS
