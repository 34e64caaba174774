"""Instructions and their outcomes as data, and the text grammar that reads and writes them.

    park | ready | straight_up            [time=<ms>]
    move <joint>=<degrees> [...]         [time=<ms>]
    move_to x=<mm> y=<mm> z=<mm> [pitch=<deg>] [roll=<deg>] [gripper=<deg>]
            [time=<ms>] [path=joint|line]
    stop | release | shutdown
    wait <ms>                            (sequence files only: a pause on the client)
    pose <name>                          [time=<ms>]
                                         (sequence files only: a saved pose, `arm.poses`)
    <instruction> &                      (sequence files only: do not wait for its outcome)
    # comment

Every instruction carries an id, so that its one outcome (done, refused or
cancelled) can be matched to it wherever it is reported. A trajectory (points
to reach at given times, from ROS) is one instruction with one outcome.
"""

from __future__ import annotations

import difflib
import enum
import itertools
import math
import os
import re
from dataclasses import dataclass, field
from typing import Protocol


class SavedPose(Protocol):
    """A saved pose: its joints' angles (degrees), in the arm's joint order."""

    @property
    def joints(self) -> tuple[tuple[str, float], ...]: ...


class SavedPoses(Protocol):
    """The saved poses a `pose NAME` step may name: `al5d.arm.poses.NamedPoses` (which this
    module does not import: the poses file's module reads the configuration, which imports
    this one)."""

    def find(self, name: str) -> SavedPose | None: ...

    def unknown(self, name: str) -> str:
        """Why `name` is no pose here, and what there is."""
        ...


#: The presets every arm has (PO01 park, PO02 ready, PO03 straight up).
PRESET_NAMES = ("park", "ready", "straight_up")


class Kind(enum.Enum):
    PRESET = "preset"
    MOVE = "move"
    MOVE_TO = "move_to"
    TRAJECTORY = "trajectory"
    STOP = "stop"
    RELEASE = "release"
    SHUTDOWN = "shutdown"


SAFETY = (Kind.STOP, Kind.RELEASE, Kind.SHUTDOWN)

_ids = itertools.count(1)
_prefix = f"{os.getpid():x}"


def new_id() -> str:
    """A short id, unique within this process (cheap: a counter, not a uuid)."""
    return f"{_prefix}-{next(_ids)}"


#: A set-point whose id ends with this is new since the last stop, by its source's word (the
#: web view's jog: a hand on a slider, which the page lets go at a stop): it resumes a
#: stream held since a stop (`al5d.arm.core`), where a source that sends its last target
#: again and again (ros2_control's hardware) must first send where the arm stands.
FRESH_MARK = "~fresh"


#: The longest id an instruction may carry, and the most of a word a reason quotes:
#: a megabyte of id or word must not become a megabyte in every log line and result.
MAX_ID = 256
MAX_QUOTE = 40


def quote(text: str, limit: int = MAX_QUOTE) -> str:
    """`repr(text)`, cut to about `limit` characters: what a reason may repeat of an input."""
    if len(text) <= limit:
        return repr(text)
    return repr(text[:limit]) + f"... ({len(text)} characters)"


@dataclass(frozen=True, slots=True)
class Point:
    """A trajectory's point: joint angles (degrees) to reach `at_ms` after the start.

    The time is kept as ROS gives it (to the nanosecond), so that the order of two
    points under a millisecond apart is judged on their real times."""

    joints: tuple[tuple[str, float], ...]
    at_ms: float


@dataclass(frozen=True, slots=True)
class ToolTarget:
    """Where `move_to` puts the tool tip (tool0): a point in base_link, in metres.

    The gripper's pitch (its axis to the horizontal, + up) and roll (the wrist
    rotate) in degrees; without a pitch the reachable one nearest the current is
    taken, without a roll the wrist rotate stays. `gripper` in its servo degrees.
    `line` keeps the tip within 1 mm of the straight line to the point.
    """

    x_m: float
    y_m: float
    z_m: float
    pitch_deg: float | None = None
    roll_deg: float | None = None
    gripper_deg: float | None = None
    line: bool = False


@dataclass(frozen=True, slots=True)
class Instruction:
    """One instruction for the arm.

    `joints` keeps the order and any duplicates as given, so that validation
    can refuse a duplicate instead of silently taking one of them.
    `time_ms` None (or 0) means as fast as the servos allow.
    """

    kind: Kind
    preset: str = ""
    joints: tuple[tuple[str, float], ...] = ()
    time_ms: int | None = None
    id: str = field(default_factory=new_id)
    points: tuple[Point, ...] = ()
    tool: ToolTarget | None = None
    #: When it was sent (CLOCK_REALTIME ns, `al5d.clock.wall_ns`), where its channel says
    #: (a DDS message's source timestamp); None: when the driver takes it. The order of
    #: a stop, a release and a move from different channels is judged on it (`arm.core`).
    sent_ns: int | None = field(default=None, compare=False)
    #: How long its sender waits for its outcome, from when it was sent (ms; 0: for ever).
    #: Then the sender has given up on it: it is cancelled if it waits, halted if it runs.
    wait_ms: int = field(default=0, compare=False)
    #: Not written before this (CLOCK_REALTIME ns, this machine's clock): a trajectory's
    #: `header.stamp`, where ros2_control's controllers start one too. None, or a time
    #: already past: when its turn comes.
    start_ns: int | None = field(default=None, compare=False)

    @property
    def name(self) -> str:
        """The instruction word: the preset's name, or move/stop/release/shutdown."""
        return self.preset if self.kind is Kind.PRESET else self.kind.value

    def __str__(self) -> str:
        return format_instruction(self)


#: How far ahead of this machine's clock a start (`Instruction.start_ns`) may be: further is
#: more likely a sender's clock that is wrong than a wait meant (the queue waits behind it).
START_AHEAD_S = 10.0


def start_too_far(start_ns: int | None, wall_ns: int) -> str:
    """Why a start `start_ns` is refused when this machine's clock says `wall_ns` (more than
    `START_AHEAD_S` ahead), or ""."""
    ahead_s = ((start_ns or 0) - wall_ns) / 1e9
    if ahead_s <= START_AHEAD_S:
        return ""
    return (
        f"its start (header.stamp) is {ahead_s:.1f} s ahead of this machine's clock, more than "
        f"{START_AHEAD_S:g} s: is its sender's clock right? (a zero stamp starts it when its "
        "turn comes)"
    )


def beyond_its_word(instr: Instruction) -> str:
    """Why `instr` carries what its word does not take (ambiguous: which did its sender
    mean?), or "". A preset takes a time only; a release or a shutdown nothing; a start
    only a trajectory; a stop is obeyed whatever it carries."""
    if instr.kind is Kind.PRESET and (instr.joints or instr.points or instr.tool):
        return f"{instr.preset} is a preset: it takes no joints (ambiguous); send a move instead"
    if instr.kind in (Kind.RELEASE, Kind.SHUTDOWN) and (
        instr.joints or instr.time_ms or instr.points or instr.tool or instr.preset
    ):
        return f"{instr.kind.value} takes no joints or time (ambiguous); send it alone"
    if instr.start_ns is not None and instr.kind not in (Kind.TRAJECTORY, Kind.STOP):
        return f"{instr.name} takes no start (start_ns): only a trajectory does"
    return ""


def preset(name: str, time_ms: int | None = None, id: str | None = None) -> Instruction:
    return Instruction(Kind.PRESET, preset=name, time_ms=time_ms, id=id or new_id())


def move(time_ms: int | None = None, id: str | None = None, **joints: float) -> Instruction:
    """Joints to their angles (degrees), optionally in `time_ms`; TypeError for `time=`,
    which the text grammar says but this takes as `time_ms` (an outside try's `time=1000`
    went to the server as a joint named time)."""
    if "time" in joints:
        raise TypeError("move() takes its time as time_ms= (milliseconds); `time` is no joint")
    return Instruction(Kind.MOVE, joints=tuple(joints.items()), time_ms=time_ms, id=id or new_id())


def move_to(
    x_mm: float,
    y_mm: float,
    z_mm: float,
    *,
    pitch: float | None = None,
    roll: float | None = None,
    gripper: float | None = None,
    line: bool = False,
    time_ms: int | None = None,
    id: str | None = None,
) -> Instruction:
    """The tool tip to a point (millimetres, as the text grammar), optionally pitch and roll."""
    tool = ToolTarget(x_mm / 1000, y_mm / 1000, z_mm / 1000, pitch, roll, gripper, line)
    return Instruction(Kind.MOVE_TO, tool=tool, time_ms=time_ms, id=id or new_id())


def trajectory(points: list[Point] | tuple[Point, ...], id: str | None = None) -> Instruction:
    return Instruction(Kind.TRAJECTORY, points=tuple(points), id=id or new_id())


def stop(id: str | None = None) -> Instruction:
    return Instruction(Kind.STOP, id=id or new_id())


def release(id: str | None = None) -> Instruction:
    return Instruction(Kind.RELEASE, id=id or new_id())


def shutdown(id: str | None = None) -> Instruction:
    return Instruction(Kind.SHUTDOWN, id=id or new_id())


class Result(enum.Enum):
    DONE = "done"
    REFUSED = "refused"
    CANCELLED = "cancelled"


#: After the reason of a motion cancelled while it waited (never written), whichever side
#: of the board's owner it waited on.
NOT_RUN = " before it ran: the arm did not move for it"


@dataclass(frozen=True, slots=True)
class Outcome:
    """What became of an instruction: exactly one per instruction."""

    id: str
    instruction: str
    result: Result
    reason: str = ""
    elapsed_ms: float = 0.0
    expected_ms: float = 0.0

    @property
    def ok(self) -> bool:
        return self.result is Result.DONE

    def __str__(self) -> str:
        text = f"{self.instruction} [{self.id}]: {self.result.value}"
        if self.reason:
            text += f": {self.reason}"
        if self.result is Result.DONE and self.elapsed_ms:
            text += f" ({self.elapsed_ms:.0f} ms)"
        return text


@dataclass(frozen=True, slots=True)
class Wait:
    """`wait <ms>` in a sequence file: the client pauses; the server never sees it."""

    ms: int


class GrammarError(ValueError):
    """Text that is not an instruction; the message points at the offending word."""


class UnknownInstruction(GrammarError):
    """A first word that is no instruction of these presets (a configuration may add more)."""


def _fmt_number(x: float) -> str:
    """The shortest text that reads back as the same number (`1e+06` would lose digits)."""
    if math.isfinite(x) and x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return repr(float(x))


def format_instruction(instr: Instruction) -> str:
    """The text form, which `parse_instruction` reads back."""
    if instr.kind is Kind.TRAJECTORY:
        return f"trajectory of {len(instr.points)} point(s)"
    words = [instr.name]
    if instr.tool is not None:
        t = instr.tool
        words += [
            f"{k}={_fmt_number(v * 1000)}" for k, v in (("x", t.x_m), ("y", t.y_m), ("z", t.z_m))
        ]
        words += [
            f"{k}={_fmt_number(v)}"
            for k, v in (("pitch", t.pitch_deg), ("roll", t.roll_deg), ("gripper", t.gripper_deg))
            if v is not None
        ]
        if t.line:
            words.append("path=line")
    words += [f"{j}={_fmt_number(d)}" for j, d in instr.joints]
    if instr.time_ms:
        words.append(f"time={instr.time_ms}")
    return " ".join(words)


def _where(words: list[str], i: int) -> str:
    return f"word {i + 1} {quote(words[i])}"


#: The largest time an instruction message can carry (its `time_ms` is a uint32): a larger
#: one would wrap around on the way, so the text is refused before it is packed.
TIME_FIELD_MAX_MS = 2**32 - 1
#: The longest `wait` of a sequence file: an hour.
WAIT_MAX_MS = 3_600_000


#: A number as it is typed: ASCII digits, a sign, a point, an exponent. Python's own
#: `float` and `int` also read `1_0` (as 10) and digits of every script (Arabic-Indic,
#: full-width): in a file of moves, a word that reads as another number than it shows is
#: refused, not guessed at.
DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
WHOLE = re.compile(r"[+-]?[0-9]+")


def _parse_ms(words: list[str], i: int, text: str, limit: int = TIME_FIELD_MAX_MS) -> int:
    if not WHOLE.fullmatch(text):
        raise GrammarError(f"{_where(words, i)}: {quote(text)} is not a whole number of ms")
    # Python's int() reads at most 4300 digits; the sign of more (leading zeros aside)
    # says which way they are out of range (and a number that long is quoted in part).
    negative, digits = text[0] == "-", text.lstrip("+-").lstrip("0") or "0"
    if len(digits) > 4000:
        ms = -1 if negative else limit + 1
    else:
        ms = -int(digits) if negative else int(digits)
    shown = str(ms) if len(text) <= 40 else quote(text)
    if ms < 0:
        raise GrammarError(f"{_where(words, i)}: time {shown} ms is negative")
    if ms > limit:
        raise GrammarError(f"{_where(words, i)}: {shown} ms is above the limit of {limit} ms")
    return ms


#: The words of `move_to`: the point in mm, then what it may add.
TOOL_WORDS = ("x", "y", "z", "pitch", "roll", "gripper", "path")
#: A `move_to` point with every coordinate this close to 0 mm (not all 0) is metres mistaken
#: for millimetres: it lies inside the base, where no arm reaches, and the AL5D's reach in
#: metres is well below 1.
METRES_HINT_MM = 1.0


def _number(words: list[str], i: int, value: str, unit: str) -> float:
    number = float(value) if DECIMAL.fullmatch(value) else math.nan
    if not math.isfinite(number):  # 1e999 reads as inf; no arm goes there
        raise GrammarError(f"{_where(words, i)}: {quote(value)} is not a number of {unit}")
    return number


def _tool(words: list[str], values: dict[str, tuple[int, str]]) -> ToolTarget:
    """The `move_to` target of the words read (key -> (word index, value))."""
    missing = [k for k in ("x", "y", "z") if k not in values]
    if missing:
        raise GrammarError(f"word 1 'move_to': name {', '.join(f'{k}=<mm>' for k in missing)}")
    given = {k: _number(words, *values[k], "mm") for k in ("x", "y", "z")}
    if any(given.values()) and all(abs(v) < METRES_HINT_MM for v in given.values()):
        # Such a point lies inside the arm's base: no arm reaches it, and it is what
        # metres typed for millimetres look like (x=0.25 y=0 z=0.12).
        typed = " ".join(f"{k}={_fmt_number(v)}" for k, v in given.items())
        meant = " ".join(f"{k}={_fmt_number(round(v * 1000, 6))}" for k, v in given.items())
        raise GrammarError(
            f"{_where(words, values['x'][0])}: {typed} look like metres; move_to takes "
            f"millimetres: {meant}"
        )
    mm = {k: v / 1000 for k, v in given.items()}
    deg = {
        k: _number(words, *values[k], "degrees")
        for k in ("pitch", "roll", "gripper")
        if k in values
    }
    line = False
    if "path" in values:
        i, path = values["path"]
        if path.lower() not in ("joint", "line"):
            raise GrammarError(f"{_where(words, i)}: path is joint or line")
        line = path.lower() == "line"
    return ToolTarget(
        mm["x"], mm["y"], mm["z"], deg.get("pitch"), deg.get("roll"), deg.get("gripper"), line
    )


#: What may end the word `stop` typed in a hurry (`stop!`, `Stop.`).
STOP_MARKS = "!.,;:"


def is_stop(word: str) -> bool:
    """Whether `word`, the first of a typed instruction, is a stop: `stop` in any case, with
    any of `STOP_MARKS` after it (`al5d.owner.quick` reads it the same way)."""
    return word.lower().rstrip(STOP_MARKS) == Kind.STOP.value


def parse_instruction(text: str, presets: tuple[str, ...] = PRESET_NAMES) -> Instruction:
    """Read one instruction. Range checks are the driver's: this only reads the words.

    A stop is read whatever follows it (`stop now`, `stop base=3`, `stop!`): nothing typed
    with it makes it less of a stop, and one refused for its words left the arm moving."""
    words = text.split()
    if not words:
        raise GrammarError("empty instruction: expected a word such as move, ready or stop")
    if is_stop(words[0]):
        return Instruction(Kind.STOP)
    head = words[0].lower()
    known = (*presets, "move", "move_to", *(kind.value for kind in SAFETY))
    if head not in known:
        raise UnknownInstruction(f"word 1 {quote(words[0])}: {_unknown(head, known)}")
    time_ms: int | None = None
    joints: list[tuple[str, float]] = []
    tool_words: dict[str, tuple[int, str]] = {}
    for i, word in enumerate(words[1:], start=1):
        if head not in (*presets, "move", "move_to"):
            raise GrammarError(f"{_where(words, i)}: {head} takes no arguments")
        key, eq, value = word.partition("=")
        if not eq or not key or not value:
            raise GrammarError(f"{_where(words, i)}: expected <name>=<value>")
        key = key.lower()
        if key == "time":
            if time_ms is not None:
                raise GrammarError(f"{_where(words, i)}: time given twice")
            time_ms = _parse_ms(words, i, value)
        elif head == "move":
            joints.append((key, _number(words, i, value, "degrees")))
        elif head == "move_to":
            if key not in TOOL_WORDS:
                raise GrammarError(f"{_where(words, i)}: move_to takes {', '.join(TOOL_WORDS)}")
            if key in tool_words:
                raise GrammarError(f"{_where(words, i)}: {key} given twice")
            tool_words[key] = (i, value)
        else:
            raise GrammarError(f"{_where(words, i)}: a preset takes only time=<ms>")
    if head in presets:
        return Instruction(Kind.PRESET, preset=head, time_ms=time_ms)
    if head == "move":
        if not joints:
            raise GrammarError("word 1 'move': name at least one <joint>=<degrees>")
        return Instruction(Kind.MOVE, joints=tuple(joints), time_ms=time_ms)
    if head == "move_to":
        return Instruction(Kind.MOVE_TO, tool=_tool(words, tool_words), time_ms=time_ms)
    return Instruction(next(kind for kind in SAFETY if head == kind.value))


#: The words of a sequence file (and `al5d shell`) that are no instruction of the server's:
#: what each is, for the message that meets one anywhere else.
SEQUENCE_ONLY = {
    "wait": "wait <ms> pauses a sequence file or al5d shell between instructions; the "
    "server has no pause to send it",
    "pose": "pose <name> moves to a pose saved in a poses file, which sequence files, "
    "al5d shell and the web view read; the server knows no pose names",
}


#: The words `al5d shell` reads itself (`al5d.app.shell`): to end it, and for its grammar.
SHELL_QUIT = ("exit", "quit")
SHELL_HELP = ("help", "?")


def _unknown(head: str, known: tuple[str, ...]) -> str:
    """Why `head` is no instruction: a word of sequence files only, or the nearest there is."""
    if head in SEQUENCE_ONLY:
        return SEQUENCE_ONLY[head]
    near = difflib.get_close_matches(head, (*known, *SEQUENCE_ONLY), n=1, cutoff=0.6)
    hint = f"did you mean {near[0]!r}? " if near else ""
    return f"unknown instruction; {hint}expected {' | '.join(known)}"


def _pose_move(words: list[str], poses: SavedPoses | None) -> Instruction:
    """`pose <name> [time=<ms>]`: a move of the saved pose's joints."""
    if len(words) < 2 or "=" in words[1]:
        at = _where(words, min(1, len(words) - 1))
        raise GrammarError(f"{at}: name a saved pose: pose <name> [time=<ms>]")
    time_ms: int | None = None
    for i, word in enumerate(words[2:], start=2):
        key, _, value = word.partition("=")
        if key.lower() != "time" or not value:
            raise GrammarError(f"{_where(words, i)}: a pose takes only time=<ms>")
        if time_ms is not None:
            raise GrammarError(f"{_where(words, i)}: time given twice")
        time_ms = _parse_ms(words, i, value)
    pose = None if poses is None else poses.find(words[1])
    if pose is None:
        why = "no poses were read" if poses is None else poses.unknown(words[1])
        raise GrammarError(f"{_where(words, 1)}: {why}")
    return Instruction(Kind.MOVE, joints=pose.joints, time_ms=time_ms)


def parse_sequence_step(
    line: str, presets: tuple[str, ...] = PRESET_NAMES, poses: SavedPoses | None = None
) -> tuple[Instruction | Wait, bool] | None:
    """One line of a sequence file: (instruction or wait, whether it runs in the background).

    None for a blank line or a comment. A line ending in `&` does not wait for
    its outcome before the next line (as in a shell). `pose <name>` is a move to one of
    `poses`.
    """
    text = line.split("#", 1)[0].strip()
    if not text:
        return None
    background = text.endswith("&")
    if background:
        text = text[:-1].rstrip()
        if not text:
            raise GrammarError("word 1 '&': nothing before it to run in the background")
    words = text.split()
    if words and words[0].lower() == "wait":
        if len(words) != 2:
            at = _where(words, 2) if len(words) > 2 else _where(words, 0)
            raise GrammarError(f"{at}: wait takes one number of ms: wait <ms>")
        if background:
            raise GrammarError(f"{_where(words, 0)}: wait cannot run in the background (&)")
        return Wait(_parse_ms(words, 1, words[1], WAIT_MAX_MS)), False
    if words and words[0].lower() == "pose":
        return _pose_move(words, poses), background
    return parse_instruction(text, presets), background


SequenceStep = tuple[Instruction | Wait, bool]


#: The most errors of a sequence file that are told one by one (then how many more).
MAX_SEQUENCE_ERRORS = 100


class SequenceErrors(GrammarError):
    """A sequence file with bad lines: every one of them (`errors`, in order), each naming
    the file, the line and the word; its text is one line each."""

    def __init__(self, errors: list[str], more: int = 0) -> None:
        self.errors = tuple(errors)
        self.more = more
        text = "\n".join(errors)
        if more:
            text += f"\n... and {more} more bad lines"
        super().__init__(text)


def parse_sequence(
    data: bytes,
    name: str = "<sequence>",
    presets: tuple[str, ...] = PRESET_NAMES,
    poses: SavedPoses | None = None,
) -> list[SequenceStep]:
    """Every step of a sequence file, checked whole before anything is sent; a `pose` line
    names one of `poses`.

    Every bad line is an error, all of them in one `SequenceErrors`, each naming the file,
    the line and the word: `demo.seq:3: word 2 'base=x': 'x' is not a number of degrees`.
    """
    steps: list[SequenceStep] = []
    errors: list[str] = []
    more = 0
    for number, raw in enumerate(data.splitlines(), start=1):
        try:
            step = sequence_line(raw, presets, poses)
        except GrammarError as e:
            if len(errors) < MAX_SEQUENCE_ERRORS:
                errors.append(f"{name}:{number}: {e}")
            else:
                more += 1
            continue
        if step is not None:
            steps.append(step)
    if errors:
        raise SequenceErrors(errors, more)
    return steps


def sequence_line(
    raw: bytes, presets: tuple[str, ...] = PRESET_NAMES, poses: SavedPoses | None = None
) -> SequenceStep | None:
    """One line of a sequence file as its bytes (`parse_sequence_step`); text that is not
    UTF-8 is a GrammarError naming the byte, and so is a stop with words after it: a file is
    judged whole before it runs, and such a line (`stop move base=3`) is more likely two
    lines run together than a stop (typed at a prompt, a stop is a stop whatever follows)."""
    try:
        line = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        byte = raw[e.start : e.start + 1].hex()
        raise GrammarError(f"not UTF-8 text (byte 0x{byte} at column {e.start + 1})") from None
    step = parse_sequence_step(line, presets, poses)
    words = line.split("#", 1)[0].strip().removesuffix("&").split()
    if step is not None and len(words) > 1 and is_stop(words[0]):
        raise GrammarError(f"{_where(words, 1)}: in a sequence file, stop takes no words")
    return step
