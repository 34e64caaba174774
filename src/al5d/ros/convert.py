"""ROS messages to instructions and outcomes, and back: pure functions, no node."""

from __future__ import annotations

import math
from collections.abc import Sequence

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from trajectory_msgs.msg import JointTrajectory

from al5d.arm.instruction import (
    SAFETY,
    TIME_FIELD_MAX_MS,
    Instruction,
    Kind,
    Outcome,
    Point,
    Result,
    new_id,
    quote,
)


def to_message(instr: Instruction) -> ArmInstruction:
    """The message of an instruction; a time its uint32 field cannot carry is an error here,
    not a number that wraps around on the way (4294967301 ms would arrive as 5 ms)."""
    if instr.time_ms is not None and not 0 <= instr.time_ms <= TIME_FIELD_MAX_MS:
        raise ValueError(
            f"time {instr.time_ms} ms does not fit the message (0..{TIME_FIELD_MAX_MS})"
        )
    msg = ArmInstruction()
    msg.instruction = instr.name
    msg.joints = [j for j, _ in instr.joints]
    msg.degrees = [float(d) for _, d in instr.joints]
    msg.time_ms = instr.time_ms or 0
    msg.id = instr.id
    return msg


def move_from_fields(
    joints: Sequence[str], degrees: Sequence[float], time_ms: int | None, ident: str
) -> Instruction | str:
    """A move from a message's or goal's parallel arrays, or why it is not one."""
    if len(joints) != len(degrees):
        return f"joints and degrees differ in length ({len(joints)} and {len(degrees)})"
    pairs = tuple(zip(joints, degrees, strict=True))
    return Instruction(Kind.MOVE, joints=pairs, time_ms=time_ms, id=ident)


def from_message(msg: ArmInstruction, presets: tuple[str, ...]) -> Instruction | str:
    """The instruction in a message, or why it is not one."""
    word = msg.instruction.strip().lower()
    ident = msg.id or new_id()
    time_ms = msg.time_ms or None
    if word in presets:
        if len(msg.joints) or len(msg.degrees):
            return f"{word} is a preset: it takes no joints (ambiguous); send a move instead"
        return Instruction(Kind.PRESET, preset=word, time_ms=time_ms, id=ident)
    if word == Kind.MOVE.value:
        return move_from_fields(msg.joints, msg.degrees, time_ms, ident)
    for kind in SAFETY:
        if word == kind.value:
            return Instruction(kind, id=ident)
    known = " | ".join((*presets, "move", *(k.value for k in SAFETY)))
    return f"unknown instruction {quote(msg.instruction)}; expected {known}"


def outcome_message(outcome: Outcome) -> InstructionResult:
    msg = InstructionResult()
    msg.id = outcome.id
    msg.instruction = outcome.instruction
    msg.outcome = outcome.result.value
    msg.reason = outcome.reason
    msg.elapsed_ms = float(outcome.elapsed_ms)
    return msg


def outcome_from_message(msg: InstructionResult) -> Outcome:
    return Outcome(msg.id, msg.instruction, Result(msg.outcome), msg.reason, msg.elapsed_ms)


def trajectory_id(msg: JointTrajectory) -> str:
    """The id a trajectory's outcome carries: `header.frame_id` when the sender set it (a
    JointTrajectory has no id field, and its frame is unused), else the header's stamp,
    `<sec>.<nanosec>`, which a sender that stamps its messages knows."""
    if msg.header.frame_id:
        return str(msg.header.frame_id)
    stamp = msg.header.stamp
    return f"{stamp.sec}.{stamp.nanosec:09d}"


def trajectory_from_message(msg: JointTrajectory) -> Instruction | str:
    """The trajectory of a message (radians to degrees, times to ms), or why it is not one.

    The points' joints and times are judged by the driver's validation, whole.
    """
    names = list(msg.joint_names)
    points: list[Point] = []
    for i, point in enumerate(msg.points):
        if len(point.positions) != len(names):
            return f"point {i}: {len(point.positions)} positions for {len(names)} joints"
        t = point.time_from_start
        at_ms = round((t.sec + t.nanosec * 1e-9) * 1000)
        degrees = (math.degrees(r) for r in point.positions)
        points.append(Point(tuple(zip(names, degrees, strict=True)), at_ms))
    return Instruction(Kind.TRAJECTORY, points=tuple(points), id=trajectory_id(msg))
