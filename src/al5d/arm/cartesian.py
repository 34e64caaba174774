"""Cartesian moves (`move_to`): a point for the tool tip, planned into group moves by the model.

Two halves. `precheck` judges what does not depend on where the arm is: finite
numbers, the gripper's and the roll's ranges, the time, that the point is above
the table and reachable at all (at the given pitch, or at some pitch); it runs
when the instruction comes. `plan` turns the target into steps from where the
arm is when the move starts (the pitch nearest the current one, the base nearest
the current heading, the straight line from the current tip): one group move, or
for `path=line` the fewest that keep the tip within 1 mm of the line. Either
refuses the whole move, with the model's reason, before a byte is written.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from al5d.arm.config import ServerSettings
from al5d.arm.instruction import Instruction, ToolTarget
from al5d.arm.translate import Translator
from al5d.model import (
    ARM_JOINTS,
    ArmModel,
    BelowTable,
    LinePlan,
    ModelError,
    below_table,
    forward,
    plan_line,
    solve,
    solve_nearest_pitch,
)
from al5d.model.kinematics import TABLE_SLACK_M

#: A group move to make: the target (degrees of the joints named) and its time (ms); None
#: for "as fast as the servos go", which the writer works out from the same speeds.
Move = tuple[dict[str, float], int | None]
Ranges = Mapping[str, tuple[float, float]]

#: The largest pitch or roll taken, either way: one turn.
ONE_TURN_DEG = 360.0
#: Without a pitch, and before the arm's pitch is known, the reachable pitch nearest this.
LEVEL_DEG = 0.0
#: `path=line` promises 1 mm from the line on the arm. The plan judges each hop as the
#: board runs it (pulses rounded to whole microseconds, interpolated linearly between), so
#: what it does not see is small: a hop that takes effect a little before the one before
#: has ended (it is written a wire time early) cuts that corner.
LINE_TOLERANCE_M = 0.0009
#: Without a time, a line goes at the fastest pace that this share of its length can keep
#: (see `hop_times`).
STEADY_SHARE = 0.9
#: A line's longest time when the caller gives none: the server's default limit.
DEFAULT_MAX_TIME_MS = ServerSettings().max_move_time_ms
#: A hop planned this close (ms) to its servos' minimum is sent as "as fast as they go":
#: the same time, and no schedule for the writer to find it a millisecond short of.
AT_FLOOR_MS = 1.0


def _in_range(ranges: Ranges, joint: str, deg: float) -> str:
    lo, hi = ranges[joint]
    return "" if lo <= deg <= hi else outside(joint, deg, lo, hi)


def outside(joint: str, deg: float, lo: float, hi: float) -> str:
    """Why `deg` of `joint` is refused, outside `lo`..`hi`: with the digits that show it
    beyond them (90.0000000001 was said as 90, of the range -90..90)."""
    limits = (f"{lo:g}", f"{hi:g}")
    text = f"{deg:g}"
    for digits in range(7, 18):
        if text not in limits:
            break
        text = f"{deg:.{digits}g}"
    return f"{joint}: {text} deg is outside the range {limits[0]}..{limits[1]}"


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
    for name in ("pitch", "roll"):
        angle = values[name]
        if angle is not None and abs(angle) > ONE_TURN_DEG:
            # Beyond a turn an angle is a mistake, never a pose: the trigonometry would
            # quietly wrap 1e300 degrees round to some angle between -180 and 180.
            return f"{name}: {angle:g} deg is beyond one turn ({ONE_TURN_DEG:g} deg)"
    time_ms = instr.time_ms
    if time_ms is not None and not 0 <= time_ms <= max_time_ms:
        return f"time {time_ms} ms is outside 0..{max_time_ms} ms"
    if t.gripper_deg is not None and (bad := _in_range(ranges, "gripper", t.gripper_deg)):
        return bad
    if t.roll_deg is not None and (bad := _in_range(ranges, "wrist_rotate", t.roll_deg)):
        return f"roll: {bad}"
    table = model.geometry.table_height
    if t.z_m < table - TABLE_SLACK_M:
        return str(BelowTable("tool tip", t.z_m, table))
    try:
        if t.pitch_deg is None:
            solve_nearest_pitch(model, t.x_m, t.y_m, t.z_m, LEVEL_DEG, t.roll_deg or 0.0)
        else:
            sol = solve(model, t.x_m, t.y_m, t.z_m, t.pitch_deg, t.roll_deg or 0.0)
            under = below_table(model, sol)
            if under is not None:
                return str(under)
    except ModelError as e:
        return str(e)
    return ""


def plan(
    instr: Instruction,
    pose: Mapping[str, float | None],
    model: ArmModel,
    translator: Translator,
    max_time_ms: int = DEFAULT_MAX_TIME_MS,
) -> list[Move] | str:
    """The group moves of a `move_to` from `pose` (arm degrees), or why it cannot be made.

    `max_time_ms` (the server's `max_move_time_ms`) bounds a straight line's whole time.
    """
    t = instr.tool
    assert t is not None
    unknown = [j for j, v in pose.items() if v is None]
    if unknown:
        return f"the arm's pose is not known yet ({', '.join(unknown)}): park first"
    start = {j: float(v) for j, v in pose.items() if v is not None}
    try:
        if t.line:
            return _line(instr, t, start, model, translator, max_time_ms)
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
    under = below_table(model, target)
    if under is not None:
        raise under
    if t.gripper_deg is not None:
        target["gripper"] = t.gripper_deg
    return target


def pulse_scale(translator: Translator) -> dict[str, tuple[float, float]]:
    """(us at 0 deg, us per deg) of each arm joint: how the driver will encode a plan."""
    joints = translator.joints
    return {j: (joints[j].to_us(0.0), joints[j].us_per_deg) for j in ARM_JOINTS}


def hop_times(
    floors: Sequence[float], shares: Sequence[float], requested_ms: float | None = None
) -> list[float]:
    """Each hop's time (ms): its share of the line at one pace, never under its floor (the
    time its servos need at top speed), so that no hop is asked the impossible.

    With a requested time, the pace is the one that makes the hops add up to it (hops
    held to their floor leave the others less), or every hop at its floor when even
    that takes longer. Without one, the pace is the fastest that STEADY_SHARE of the
    line's length can keep: the tool keeps one speed there, and where it cannot (near
    the base axis the base must swing far for little travel) only those hops go slower.
    Slowing the whole line to its most demanding hop made a line that passes near the
    axis take over a minute; each hop at its own top speed would make the tool lurch
    between speeds all along (by nearly two times on an ordinary line).
    """
    if requested_ms:
        if sum(floors) >= requested_ms:
            return list(floors)
        lo, hi = 0.0, float(requested_ms) / max(min(shares), 1e-12)
        for _ in range(100):  # the sum grows with the pace's time: bisect for it
            mid = (lo + hi) / 2
            if sum(max(m, s * mid) for m, s in zip(floors, shares, strict=True)) > requested_ms:
                hi = mid
            else:
                lo = mid
        pace = lo
    else:
        # (the line's time at the pace this hop allows, its share), fastest pace first
        need = sorted((m / max(s, 1e-12), s) for m, s in zip(floors, shares, strict=True))
        covered, pace = 0.0, 0.0
        for line_ms, share in need:
            covered += share
            pace = line_ms
            if covered >= STEADY_SHARE - 1e-12:
                break
    return [max(m, s * pace) for m, s in zip(floors, shares, strict=True)]


def _line(
    instr: Instruction,
    t: ToolTarget,
    start: Mapping[str, float],
    model: ArmModel,
    translator: Translator,
    max_time_ms: int,
) -> list[Move] | str:
    """The fewest group moves that keep the tip within 1 mm of the line, timed by
    `hop_times`; a gripper change is spread over them, so it ends with the line."""
    line = plan_line(
        model,
        start,
        (t.x_m, t.y_m, t.z_m),
        t.pitch_deg,
        t.roll_deg,
        tolerance_m=LINE_TOLERANCE_M,
        pulses=pulse_scale(translator),
    )
    targets = [dict(w) for w in line.waypoints]
    if t.gripper_deg is not None:
        g0, g1 = start["gripper"], t.gripper_deg
        for f, target in zip(line.fractions, targets, strict=True):
            target["gripper"] = g0 + f * (g1 - g0)
    shares = [b - a for a, b in zip((0.0, *line.fractions), line.fractions, strict=False)]
    befores: list[Mapping[str, float]] = [start, *targets[:-1]]
    floors = [translator.minimum_ms(b, a) for b, a in zip(befores, targets, strict=True)]
    times = hop_times(floors, shares, instr.time_ms)
    total = sum(times)
    if total > max_time_ms:
        return _too_long(line, shares, befores, targets, floors, total, max_time_ms, translator)
    moves: list[Move] = []
    planned = 0.0  # the line's time so far, at the plan's pace (ms)
    for target, ms, floor in zip(targets, times, floors, strict=True):
        before = round(planned)
        planned += ms
        if ms - floor < AT_FLOOR_MS:
            moves.append((target, None))
        else:
            # Whole ms where the line's schedule falls, not each hop's rounded up: those
            # added up to a few ms over the requested time, and every timed line said INF03.
            moves.append((target, max(math.ceil(floor), round(planned) - before)))
    return moves


def _too_long(
    line: LinePlan,
    shares: Sequence[float],
    befores: Sequence[Mapping[str, float]],
    targets: Sequence[Mapping[str, float]],
    floors: Sequence[float],
    total_ms: float,
    max_time_ms: int,
    translator: Translator,
) -> str:
    """Why a line takes too long: its slowest stretch, and the joint that makes it slow."""
    k = max(range(len(shares)), key=lambda i: floors[i] / max(shares[i], 1e-12))
    before, target = befores[k], targets[k]
    joint = max(target, key=lambda j: translator.minimum_ms(before, {j: target[j]}))
    turn = abs(target[joint] - before[joint])
    length_mm = math.dist(line.start, line.end) * 1000 * shares[k]
    head = f"the line would take {total_ms:.0f} ms, above the limit of {max_time_ms} ms: "
    if joint != "base":
        return head + f"the {joint} would have to turn {turn:.0f} deg in {length_mm:.3g} mm of it"
    f0 = sum(shares[:k])
    a = [p + f0 * (q - p) for p, q in zip(line.start, line.end, strict=True)]
    b = [p + (f0 + shares[k]) * (q - p) for p, q in zip(line.start, line.end, strict=True)]
    axis_mm = _axis_distance((a[0], a[1]), (b[0], b[1])) * 1000
    near = "within 0.1 mm of" if axis_mm < 0.1 else f"{axis_mm:.1f} mm from"
    return head + (
        f"it passes {near} the base axis, where the base would have to turn "
        f"{turn:.0f} deg in {length_mm:.3g} mm"
    )


def _axis_distance(a: tuple[float, float], b: tuple[float, float]) -> float:
    """How close the segment a-b (seen from above) comes to the base axis (x = y = 0)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    d2 = dx * dx + dy * dy
    u = 0.0 if d2 == 0 else min(1.0, max(0.0, -(a[0] * dx + a[1] * dy) / d2))
    return math.hypot(a[0] + u * dx, a[1] + u * dy)
