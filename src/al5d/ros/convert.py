"""ROS messages to instructions and outcomes, and back: pure functions, no node."""

from __future__ import annotations

from collections.abc import Sequence

from al5d_interfaces.msg import ArmInstruction, InstructionResult

from al5d.arm.instruction import (
    SAFETY,
    TIME_FIELD_MAX_MS,
    Instruction,
    Kind,
    Outcome,
    Result,
    new_id,
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
        return Instruction(Kind.PRESET, preset=word, time_ms=time_ms, id=ident)
    if word == Kind.MOVE.value:
        return move_from_fields(msg.joints, msg.degrees, time_ms, ident)
    for kind in SAFETY:
        if word == kind.value:
            return Instruction(kind, id=ident)
    known = " | ".join((*presets, "move", *(k.value for k in SAFETY)))
    return f"unknown instruction {msg.instruction!r}; expected {known}"


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
