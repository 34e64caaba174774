"""The local lane: how clients on this machine talk to the owner of the board, as data.

A Unix socket (the user's own: its folder is the user's alone, nothing is on the
network), one JSON object a line each way. A client says `hello` (and what it wants to
hear: `watch`), then asks (`ask`, `judge`, `cancel`; `drop` lets go of a ticket of
`judge` it will not ask with, unanswered); the owner answers each request once under its
`ref`, and tells watchers what happens (`state`, `told`, `moved`, `posed`, `wire`). A
client that goes without `bye` is a lost client: what it commanded does not go on
(`al5d.arm.core`, `Gone`); nor does it after a `bye` that names why the client leaves
(`left_by`: an error, Ctrl-C's `KeyboardInterrupt`). A client that speaks for others
(the ROS bridge for the ROS clients) names one in an `ask` (`for`: its key) and says
when it has lost one (`gone`, with `why`) or one has closed (`gone` without `why`): each
is a client of its own to the core. A recorder (`recorder` in its `hello`, watching
`wire`) is told first the board's writes the owner kept for it from its start, where it
keeps them; one watching `asked` is told each instruction asked by a client whose hello
did not say `ros` (what came over ROS 2 a recording has from there): the bridge's
recording holds them. A leased client (`lease` in its hello) says `sign` at least four
times a lease and a second; the owner's thread answers each (`signed`), so that the
client hears an owner that turns, and can tell one frozen with its lane open
(`Remote.quiet`); a leased client the owner takes for lost is told why (`lost`) as its
lane is closed.

Everything here is pure, and light to import (the standard library and
`al5d.arm.instruction`): `al5d send stop`'s own path (`quick`) imports nothing else.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Any

from al5d.arm.instruction import (
    Instruction,
    Kind,
    Outcome,
    Point,
    Result,
    ToolTarget,
)
from al5d.owner.where import folder, path

__all__ = ["folder", "path"]

if TYPE_CHECKING:  # heavy (numpy, pydantic): imported where they are made, below
    from al5d.arm.jobs import Motion
    from al5d.arm.resample import Follow

#: The protocol's version, said in `hello` and `welcome`.
VERSION = 1
#: The longest line either side takes: a trajectory of the most points (2,000, about
#: 0.3 MB) fits. A line is parsed whole by the owner as it is read (a megabyte in 50 ms
#: here), before the stops of other lanes in that turn.
MAX_LINE = 2 * 1024 * 1024
#: What a client may ask to hear.
WATCHES = ("state", "outcomes", "motion", "pose", "wire", "asked")


class LaneError(ValueError):
    """A line of the lane that is not what the protocol says: the message says what."""


def dumps(message: Mapping[str, Any]) -> bytes:
    """One line of the lane."""
    return json.dumps(message, separators=(",", ":"), allow_nan=False).encode() + b"\n"


class Lines:
    """Bytes in, whole lines out (a line longer than `MAX_LINE` is an error)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> Iterator[dict[str, Any] | LaneError]:
        """The messages `data` completes, in order; a line that is no JSON object, or too
        long, is a LaneError in its place (the lines after it are read as ever)."""
        self._buf += data
        while True:
            end = self._buf.find(b"\n")
            if end < 0:
                if len(self._buf) > MAX_LINE:
                    self._buf.clear()  # up to the next line's end, lost with the error
                    self._skipping = True
                    yield LaneError(f"a line longer than {MAX_LINE} bytes")
                return
            line = bytes(self._buf[:end])
            del self._buf[: end + 1]
            if self._skipping:  # the end of the line too long
                self._skipping = False
                continue
            try:
                yield loads(line)
            except LaneError as e:
                yield e


def _no_constant(word: str) -> Any:
    # Python's JSON reads NaN and Infinity, which JSON has not: a client's `ref` of NaN,
    # echoed in its answer, failed the owner's writing of it (numbers not finite travel as
    # words on the lane, `_num`).
    raise ValueError(f"{word} is not JSON (a number not finite is the word nan, inf or -inf)")


def loads(line: bytes) -> dict[str, Any]:
    try:
        message = json.loads(line, parse_constant=_no_constant)
    except (ValueError, UnicodeDecodeError) as e:
        raise LaneError(f"not JSON: {e}") from None
    except RecursionError:  # a line of arrays nested tens of thousands deep
        raise LaneError("not JSON that can be read: nested too deep") from None
    if not isinstance(message, dict) or not isinstance(message.get("op"), str):
        raise LaneError('not an object with an "op"')
    return message


# -- instructions and outcomes ----------------------------------------------------------


def instruction_out(instr: Instruction) -> dict[str, Any]:
    out: dict[str, Any] = {"kind": instr.kind.value, "id": instr.id}
    if instr.preset:
        out["preset"] = instr.preset
    if instr.joints:
        out["joints"] = [[n, _num(v)] for n, v in instr.joints]
    if instr.time_ms is not None:
        out["time_ms"] = instr.time_ms
    if instr.points:
        out["points"] = [
            [[[n, _num(v)] for n, v in pt.joints], _num(pt.at_ms)] for pt in instr.points
        ]
    if instr.tool is not None:
        t = instr.tool
        maybe = [t.pitch_deg, t.roll_deg, t.gripper_deg]
        out["tool"] = [
            *(_num(v) for v in (t.x_m, t.y_m, t.z_m)),
            *(None if v is None else _num(v) for v in maybe),
            t.line,
        ]
    if instr.sent_ns is not None:
        out["sent_ns"] = instr.sent_ns
    if instr.wait_ms:
        out["wait_ms"] = instr.wait_ms
    if instr.start_ns is not None:
        out["start_ns"] = instr.start_ns
    return out


#: JSON has no NaN or infinity: they travel as these words (and are judged, as any value).
_NOT_FINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _num(value: float) -> float | str:
    """A number for the lane: itself, or the word of a NaN or an infinity."""
    return value if math.isfinite(value) else str(value)


def _number(value: Any, what: str) -> float:
    if isinstance(value, str) and value in _NOT_FINITE:
        return _NOT_FINITE[value]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise LaneError(f"{what}: {str(value)[:40]!r} is not a number")
    try:
        return float(value)
    except OverflowError:  # a whole number of hundreds of digits
        raise LaneError(f"{what}: {str(value)[:40]}... is no number a double holds") from None


def _maybe(value: Any, what: str) -> float | None:
    return None if value is None else _number(value, what)


def _int(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise LaneError(f"{what}: {value!r} is not a whole number")
    return value


def _joints(value: Any, what: str) -> tuple[tuple[str, float], ...]:
    if not isinstance(value, list):
        raise LaneError(f"{what}: not a list of [name, value] pairs")
    out = []
    for pair in value:
        if not (isinstance(pair, list) and len(pair) == 2 and isinstance(pair[0], str)):
            raise LaneError(f"{what}: {pair!r} is not a [name, value] pair")
        out.append((pair[0], _number(pair[1], f"{what} {pair[0][:40]!r}")))
    return tuple(out)


def instruction_in(data: Any) -> Instruction:
    """An instruction from the lane. Raises LaneError naming what is wrong (its values are
    judged later, as every instruction's are)."""
    if not isinstance(data, dict):
        raise LaneError("instr: not an object")
    try:
        kind = Kind(data.get("kind"))
    except ValueError:
        raise LaneError(f"instr: no kind {str(data.get('kind'))[:40]!r}") from None
    ident = data.get("id", "")
    if not isinstance(ident, str):
        raise LaneError("instr: the id must be text")  # a long one is judged (and refused)
    preset = data.get("preset", "")
    if not isinstance(preset, str):
        raise LaneError("instr: preset is not text")
    time_ms = data.get("time_ms")
    points: tuple[Point, ...] = ()
    listed = data.get("points") or []
    if not isinstance(listed, list):
        raise LaneError("instr: points is not a list of [joints, at_ms]")
    for i, pt in enumerate(listed):
        if not (isinstance(pt, list) and len(pt) == 2):
            raise LaneError(f"instr: point {i} is not [joints, at_ms]")
        points += (Point(_joints(pt[0], f"point {i}"), _number(pt[1], f"point {i} at_ms")),)
    tool = None
    if data.get("tool") is not None:
        t = data["tool"]
        if not (isinstance(t, list) and len(t) == 7):
            raise LaneError("instr: tool is not [x, y, z, pitch, roll, gripper, line]")
        tool = ToolTarget(
            _number(t[0], "x"),
            _number(t[1], "y"),
            _number(t[2], "z"),
            _maybe(t[3], "pitch"),
            _maybe(t[4], "roll"),
            _maybe(t[5], "gripper"),
            bool(t[6]),
        )
    sent, start = data.get("sent_ns"), data.get("start_ns")
    for name, ns in (("sent_ns", sent), ("start_ns", start)):
        if ns is not None and not 0 <= _int(ns, name) < 2**63:
            raise LaneError(f"instr: {name} is a time in ns since 1970 (0 to 2**63 - 1)")
    wait_ms = _int(data.get("wait_ms", 0), "wait_ms")
    if not 0 <= wait_ms < 2**32:
        raise LaneError("instr: wait_ms is how long its sender waits: 0 (for ever) to 2**32 - 1")
    return Instruction(
        kind,
        preset=preset,
        joints=_joints(data.get("joints") or [], "joints"),
        time_ms=None if time_ms is None else _int(time_ms, "time_ms"),
        id=ident,
        points=points,
        tool=tool,
        sent_ns=None if sent is None else _int(sent, "sent_ns"),
        wait_ms=wait_ms,
        start_ns=None if start is None else _int(start, "start_ns"),
    )


def outcome_out(outcome: Outcome) -> dict[str, Any]:
    return {
        "id": outcome.id,
        "instruction": outcome.instruction,
        "result": outcome.result.value,
        "reason": outcome.reason,
        "elapsed_ms": outcome.elapsed_ms,
        "expected_ms": outcome.expected_ms,
    }


def outcome_in(data: Any) -> Outcome:
    if not isinstance(data, dict):
        raise LaneError("outcome: not an object")
    try:
        return Outcome(
            str(data["id"]),
            str(data["instruction"]),
            Result(data["result"]),
            str(data.get("reason", "")),
            _number(data.get("elapsed_ms", 0.0), "elapsed_ms"),
            _number(data.get("expected_ms", 0.0), "expected_ms"),
        )
    except (KeyError, ValueError) as e:
        raise LaneError(f"outcome: {e}") from None


def motion_out(motion: Motion) -> dict[str, Any]:
    out: dict[str, Any] = {
        "start": dict(motion.start),
        "target": dict(motion.target),
        "t0": motion.t0,
        "duration_s": motion.duration_s,
    }
    if motion.before is not None:
        out["before"] = motion_out(motion.before)
    return out


def motion_in(data: Any) -> Motion:
    from al5d.arm.jobs import Motion

    if not isinstance(data, dict):
        raise LaneError("motion: not an object")
    try:
        before = data.get("before")
        return Motion(
            {str(k): float(v) for k, v in data["start"].items()},
            {str(k): float(v) for k, v in data["target"].items()},
            float(data["t0"]),
            float(data["duration_s"]),
            None if before is None else motion_in(before),
        )
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise LaneError(f"motion: {e}") from None


def follow_out(follow: Follow | None) -> dict[str, Any] | None:
    if follow is None:
        return None
    late = None if follow.late_ms is None else _num(follow.late_ms)
    return {"tolerance": {k: _num(v) for k, v in follow.tolerance.items()}, "late_ms": late}


def follow_in(data: Any) -> Follow | None:
    """A trajectory's tolerances from the lane (where the arm is, the owner knows)."""
    from al5d.arm.resample import Follow

    if data is None:
        return None
    if not isinstance(data, dict) or not isinstance(data.get("tolerance", {}), dict):
        raise LaneError("follow: not {tolerance: {joint: degrees}, late_ms}")
    tolerance = {
        str(k)[:40]: _number(v, f"tolerance of {str(k)[:40]}")
        for k, v in data.get("tolerance", {}).items()
    }
    return Follow(tolerance, _maybe(data.get("late_ms"), "late_ms"))
