"""A sequence judged whole before its first instruction is sent (pure): every line read by the
grammar, then every step judged as the server will judge it (`validate`), each from where the
steps before it leave the arm: the joints, their ranges, the times, the presets, the table,
the reach of a `move_to`, and the named poses a `pose` line names.

One judgement for every client that plays a sequence: `al5d run` (and `al5d run --check`,
which sends nothing), `al5d shell` (a line at a time) and the web view's Teach tab. Every
problem is told at once, each with its line; a sequence with any is not played at all.

Where the arm starts is what the caller knows: the web view knows the arm's pose, the
command line does not (a preset or a move naming every joint makes it known from there
on). What cannot be known is not judged: the server judges it again when the step starts.
The arm's state (a stop's lock) is not judged either: the server's outcomes say it.
"""

from __future__ import annotations

import codecs
import errno
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from al5d.arm import validate
from al5d.arm.config import ArmConfig, load_config
from al5d.arm.instruction import (
    MAX_SEQUENCE_ERRORS,
    GrammarError,
    Instruction,
    Kind,
    SequenceErrors,
    SequenceStep,
    UnknownInstruction,
    is_stop,
    sequence_line,
)
from al5d.arm.poses import NamedPoses
from al5d.arm.translate import Translator
from al5d.model import ARM_JOINTS

#: Where the arm is, by joint (degrees; None: not known).
Pose = dict[str, float | None]


@dataclass(frozen=True, slots=True)
class Line:
    """A step of a sequence with the line it was read from (1 is the first)."""

    number: int
    text: str
    step: SequenceStep
    #: Judged from where the lines before it leave every joint: the path's table and the
    #: start's ranges included. False: the arm's start was not known (the server judges
    #: those as the step starts).
    known: bool = True


@dataclass(frozen=True, slots=True)
class Problem:
    """Why a line of a sequence cannot be played: the grammar's reason or the server's."""

    number: int
    text: str
    reason: str
    #: The grammar's (a line no configuration would take), not the server's.
    grammar: bool = False

    def at(self, name: str) -> str:
        """`name:line: reason`, as a compiler says it."""
        return f"{name}:{self.number}: {self.reason}"


@dataclass(frozen=True, slots=True)
class Judgement:
    """A sequence judged: its steps (the good lines) and every problem, in line order."""

    name: str
    lines: tuple[Line, ...]
    problems: tuple[Problem, ...]

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def steps(self) -> list[SequenceStep]:
        return [line.step for line in self.lines]

    def error(self) -> SequenceErrors:
        """The problems as one error, a line each (`file:line: reason`)."""
        shown = self.problems[:MAX_SEQUENCE_ERRORS]
        return SequenceErrors([p.at(self.name) for p in shown], len(self.problems) - len(shown))


class SequenceJudge:
    """Judges sequences for one arm configuration as its server judges their instructions."""

    def __init__(self, config: ArmConfig) -> None:
        self.config = config
        self.presets = tuple(config.presets)
        self.limits = validate.Limits.of(config)
        self.translator = Translator(config)

    def judge(
        self,
        data: bytes,
        name: str = "<sequence>",
        poses: NamedPoses | None = None,
        start: Mapping[str, float] | None = None,
    ) -> Judgement:
        """Every line of a sequence file's bytes read and judged; `start` where the arm is
        (None: not known)."""
        lines: list[Line] = []
        problems: list[Problem] = []
        # The byte order mark some editors start a UTF-8 file with: not a word of its first
        # line (seen: "word 1 '\ufeffmove': unknown instruction").
        data = data.removeprefix(codecs.BOM_UTF8)
        pose: Pose = {j: None for j in self.config.joints}
        pose.update(start or {})
        ended_at = 0  # the line of a shutdown: nothing after it reaches a server
        for number, raw in enumerate(data.splitlines(), start=1):
            text = raw.decode("utf-8", errors="replace").split("#", 1)[0].strip()
            try:
                step = sequence_line(raw, self.presets, poses)
            except GrammarError as e:
                # An unknown first word may be a preset of another configuration's.
                bad = not isinstance(e, UnknownInstruction)
                problems.append(Problem(number, text, str(e), grammar=bad))
                continue
            if step is None:
                continue
            item, _ = step
            if ended_at:
                why = f"the server shuts down at line {ended_at}: nothing after it is run"
                problems.append(Problem(number, text, why))
                continue
            known = True
            if isinstance(item, Instruction):
                moves = item.kind not in (Kind.STOP, Kind.RELEASE)
                known = not moves or all(v is not None for v in pose.values())
                reason = self._step(item, pose)
                if reason:
                    problems.append(Problem(number, text, reason))
                    continue
                if item.kind is Kind.SHUTDOWN:
                    ended_at = number
            lines.append(Line(number, text, step, known))
        return Judgement(name, tuple(lines), tuple(problems))

    def judge_text(
        self,
        text: str,
        name: str = "<sequence>",
        poses: NamedPoses | None = None,
        start: Mapping[str, float] | None = None,
    ) -> Judgement:
        return self.judge(text.encode("utf-8"), name, poses, start)

    def judge_line(self, line: str, poses: NamedPoses | None = None) -> SequenceStep | None:
        """One line (`al5d shell`): its step, None for a blank line or a comment; GrammarError
        with the grammar's or the server's reason. Judged alone: where the arm is is not known.
        A stop is a stop whatever words follow it (a file's line takes none)."""
        words = line.split("#", 1)[0].split()
        if words and is_stop(words[0]):
            return Instruction(Kind.STOP), False
        judged = self.judge_text(line, poses=poses)
        if judged.problems:
            raise GrammarError(judged.problems[0].reason)
        return judged.lines[0].step if judged.lines else None

    def _step(self, instr: Instruction, pose: Pose) -> str:
        """Why the server would refuse `instr` started from `pose`, or "" (then `pose` is
        where it leaves the arm)."""
        kind = instr.kind
        if kind is Kind.STOP:
            pose.update(dict.fromkeys(pose))  # halted wherever it was on its way
            return ""
        if kind is Kind.RELEASE:
            return ""
        if kind is Kind.SHUTDOWN:
            pose.update(self.config.presets["park"])
            return ""
        steps = validate.check(instr, self.limits)
        if isinstance(steps, str):
            return steps
        if kind is Kind.MOVE_TO:
            if any(pose[j] is None for j in ARM_JOINTS):
                # Planned from where the arm is when it starts: the server plans it then.
                pose.update(dict.fromkeys(ARM_JOINTS))
                return ""
            steps = validate.planned(instr, pose, self.limits, self.translator)
            if isinstance(steps, str):
                return steps
        else:
            problem = validate.from_start(instr, steps, pose, self.limits)
            if problem:
                return problem
        for step in steps:
            pose.update(step.target)
        return ""


#: The largest sequence file read (a sequence of 100,000 lines is about 2 MB).
MAX_FILE_BYTES = 16 * 1024 * 1024


def read_sequence(path: str | Path) -> bytes:
    """A sequence file's bytes (`-`: standard input's, to its end); OSError (its `strerror`
    says why) where it cannot be read or is larger than `MAX_FILE_BYTES` (`/dev/zero` was
    read until memory ran out)."""
    if str(path) == "-":
        data = sys.stdin.buffer.read(MAX_FILE_BYTES + 1)
    else:
        with open(path, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    if len(data) > MAX_FILE_BYTES:
        raise OSError(errno.EFBIG, f"larger than {MAX_FILE_BYTES // 2**20} MiB: no sequence file")
    return data


def judge_sequence(
    data: bytes,
    config: ArmConfig,
    name: str = "<sequence>",
    poses: NamedPoses | None = None,
    start: Mapping[str, float] | None = None,
) -> Judgement:
    """A sequence file's bytes judged whole against `config` (`SequenceJudge.judge`)."""
    return SequenceJudge(config).judge(data, name, poses, start)


def judged_steps(
    data: bytes, name: str, poses: NamedPoses | None, config: ArmConfig | None = None
) -> list[SequenceStep]:
    """The steps of a sequence file judged whole against the server's configuration (`config`,
    by default the shipped one, as `al5d serve` reads it), where the arm starts not known;
    SequenceErrors (a GrammarError) with every problem, a line each, if there is any."""
    judged = SequenceJudge(config or load_config()).judge(data, name, poses)
    if not judged.ok:
        raise judged.error()
    return judged.steps
