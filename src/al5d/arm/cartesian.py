"""Cartesian moves (`move_to`): a point for the tool tip, planned into group moves by the model.

Two halves. `precheck` judges what does not depend on where the arm is: finite
numbers, the gripper's and the roll's ranges, the time, and that the point is
reachable at all (at the given pitch, or at some pitch); it runs when the
instruction comes. `plan` turns the target into steps from where the arm is
when the move starts (the pitch nearest the current one, the base nearest the
current heading, the straight line from the current tip): one group move, or
for `path=line` the fewest that keep the tip within 1 mm of the line. Either
refuses the whole move, with the model's reason, before a byte is written.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from al5d.arm.instruction import Instruction, ToolTarget
from al5d.arm.translate import Translator
from al5d.model import ArmModel, ModelError, forward, plan_line, solve, solve_nearest_pitch

#: A group move to make: the target (degrees of the joints named) and its time (ms).
Move = tuple[dict[str, float], int | None]
Ranges = Mapping[str, tuple[float, float]]

#: Without a pitch, and before the arm's pitch is known, the reachable pitch nearest this.
LEVEL_DEG = 0.0
#: `path=line` promises 1 mm from the line on the arm; the plan keeps 0.8 mm between the
#: waypoints, leaving 0.2 mm for what the plan does not see: pulses rounded to whole
#: microseconds (0.05 deg, up to 0.3 mm at full reach) and the servos' own speed limits.
LINE_TOLERANCE_M = 0.0008


def _in_range(ranges: Ranges, joint: str, deg: float) -> str:
    lo, hi = ranges[joint]
    return "" if lo <= deg <= hi else f"{joint}: {deg:g} deg is outside the range {lo:g}..{hi:g}"


def precheck(instr: Instruction, ranges: Ranges, max_time_ms: int, model: ArmModel) -> str:
    """What is wrong with a `move_to`, wherever the arm is; empty when nothing is."""
    t = instr.tool
    if t is None:
        return "move_to needs a point: x, y and z"
    values = {"x": t.x_m, "y": t.y_m, "z": t.z_m, "pitch": t.pitch_deg, "roll": t.roll_deg}
    values["gripper"] = t.gripper_deg
    for name, v in values.items():
        if v is not None and not math.isfinite(v):
            return f"{name}: {v} is not a finite number"
    time_ms = instr.time_ms
    if time_ms is not None and not 0 <= time_ms <= max_time_ms:
        return f"time {time_ms} ms is outside 0..{max_time_ms} ms"
    if t.gripper_deg is not None and (bad := _in_range(ranges, "gripper", t.gripper_deg)):
        return bad
    if t.roll_deg is not None and (bad := _in_range(ranges, "wrist_rotate", t.roll_deg)):
        return f"roll: {bad}"
    try:
        if t.pitch_deg is None:
            solve_nearest_pitch(model, t.x_m, t.y_m, t.z_m, LEVEL_DEG, t.roll_deg or 0.0)
        else:
            solve(model, t.x_m, t.y_m, t.z_m, t.pitch_deg, t.roll_deg or 0.0)
    except ModelError as e:
        return str(e)
    return ""


def plan(
    instr: Instruction,
    pose: Mapping[str, float | None],
    model: ArmModel,
    translator: Translator,
) -> list[Move] | str:
    """The group moves of a `move_to` from `pose` (arm degrees), or why it cannot be made."""
    t = instr.tool
    assert t is not None
    unknown = [j for j, v in pose.items() if v is None]
    if unknown:
        return f"the arm's pose is not known yet ({', '.join(unknown)}): park first"
    start = {j: float(v) for j, v in pose.items() if v is not None}
    try:
        if t.line:
            return _line(instr, t, start, model, translator)
        return [(_joint_target(t, start, model), instr.time_ms)]
    except ModelError as e:
        return str(e)


def _joint_target(t: ToolTarget, start: Mapping[str, float], model: ArmModel) -> dict[str, float]:
    roll = t.roll_deg if t.roll_deg is not None else start["wrist_rotate"]
    if t.pitch_deg is None:
        pitch_now = forward(model.geometry, start).pitch_deg
        target, _ = solve_nearest_pitch(
            model, t.x_m, t.y_m, t.z_m, pitch_now, roll, base_hint_deg=start["base"]
        )
    else:
        target = solve(model, t.x_m, t.y_m, t.z_m, t.pitch_deg, roll, base_hint_deg=start["base"])
    if t.gripper_deg is not None:
        target["gripper"] = t.gripper_deg
    return target


def _line(
    instr: Instruction,
    t: ToolTarget,
    start: Mapping[str, float],
    model: ArmModel,
    translator: Translator,
) -> list[Move]:
    """The fewest group moves that keep the tip within 1 mm of the line, at one tool speed.

    With a time, each hop gets its share of it by its share of the line; without one,
    the line's time is that of its most demanding hop (its physical minimum over its
    share), so that the tip keeps one speed from end to end.
    """
    line = plan_line(
        model, start, (t.x_m, t.y_m, t.z_m), t.pitch_deg, t.roll_deg, tolerance_m=LINE_TOLERANCE_M
    )
    targets = [dict(w) for w in line.waypoints]
    if t.gripper_deg is not None:
        targets[-1]["gripper"] = t.gripper_deg
    shares = [b - a for a, b in zip((0.0, *line.fractions), line.fractions, strict=False)]
    total = float(instr.time_ms or 0)
    if not total:
        before: Mapping[str, float | None] = start
        for target, share in zip(targets, shares, strict=True):
            total = max(total, translator.minimum_ms(before, target) / max(share, 1e-9))
            before = target
    times = [max(1, math.ceil(total * share)) for share in shares]
    return [(target, ms) for target, ms in zip(targets, times, strict=True)]
