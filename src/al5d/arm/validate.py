"""Whether an instruction can run, judged whole before anything is written (D3, VE02).

Pure functions of the instruction and the arm's limits. `check` gives the
steps to run (one for a move or a preset, one per point for a trajectory) or
the reason to refuse the whole instruction; its fast path serves the usual,
valid move, and `explain` names every problem: the joint, the value and the
range, or the point of a trajectory and what is wrong with it.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from al5d.arm import cartesian
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import MAX_ID, Instruction, Kind, Point, quote
from al5d.arm.resample import LINE_MARGIN_S, Budget, Follow, line_bytes, resample
from al5d.arm.translate import Translator
from al5d.model import ArmModel, as_sent, below_table
from al5d.model.table import HEIGHT_JOINTS, path_below
from al5d.ssc32u.protocol import wire_time_s

#: A reason lists this many problems at most, then says how many more there were.
MAX_PROBLEMS = 5
#: The most points a trajectory may have (40 s at 20 ms a point). Its judgement is the
#: owner's, between two looks for a stop: 10,000 took 0.4 s here (read and judged), a
#: stop's wait behind it; 2,000 about 60 ms.
MAX_POINTS = 2_000


@dataclass(frozen=True, slots=True)
class Limits:
    """What validation needs of the arm: joint ranges, presets, the longest move time."""

    ranges: Mapping[str, tuple[float, float]]
    presets: Mapping[str, Mapping[str, float]]
    max_time_ms: int
    #: The robot model, for Cartesian moves.
    model: ArmModel | None = None
    #: The link's baud: a trajectory is judged at its budget (`resample`); 0: not judged.
    baud: int = 0
    channels: Mapping[str, int] = field(default_factory=dict)
    #: Each joint's servo speed (deg/s).
    speeds: Mapping[str, float] = field(default_factory=dict)
    #: A trajectory's path tolerance where its sender gives none (degrees).
    path_tolerance_deg: float = 1.0
    #: Whether every move's path is kept above the table (`server.table_check`).
    table: bool = True
    #: Per joint, (us at 0 deg, us per deg): the pulses the board interpolates between.
    pulses: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    @classmethod
    def of(cls, config: ArmConfig, baud: int = 0) -> Limits:
        """The arm's limits; with `baud`, trajectories are judged at that link's budget."""
        return cls(
            ranges={n: j.range_deg for n, j in config.joints.items()},
            presets=config.presets,
            max_time_ms=config.server.max_move_time_ms,
            model=config.model,
            baud=baud,
            channels={n: j.channel for n, j in config.joints.items()},
            speeds={n: j.speed_deg_s for n, j in config.joints.items()},
            path_tolerance_deg=config.server.trajectory_path_tolerance_deg,
            table=config.server.table_check,
            pulses={n: (j.to_us(0.0), j.us_per_deg) for n, j in config.joints.items()},
        )


@dataclass(frozen=True, slots=True)
class Step:
    """One group move to make: the target (degrees, the joints named) and its time."""

    target: dict[str, float]
    time_ms: int | None
    #: A trajectory's step: the index of its point (a thinned trajectory skips some).
    point: int = field(default=-1, compare=False)


Steps = tuple[Step, ...]


@dataclass(frozen=True, slots=True)
class Ticket:
    """A motion instruction judged whole, ready to be submitted without a second judgement:
    its steps (none for a Cartesian move, which is planned when it starts)."""

    instr: Instruction
    steps: Steps
    #: What its sender asked beyond its points (a trajectory's tolerances), if anything.
    follow: Follow | None = None


def judge(instr: Instruction, limits: Limits, follow: Follow | None = None) -> Ticket | str:
    """The one judgement of a motion instruction, whatever its channel (a message, a goal,
    a trajectory, a Cartesian target, a Python call): its ticket, or why it is refused.
    `follow`: what a trajectory's sender asks beyond its points (its tolerances)."""
    steps = check(instr, limits, follow)
    return steps if isinstance(steps, str) else Ticket(instr, steps, follow)


def check(instr: Instruction, limits: Limits, follow: Follow | None = None) -> Steps | str:
    """The steps of a motion instruction, or the reason to refuse it whole.

    A Cartesian move's steps depend on where the arm is when it starts: what can be
    judged now is judged, and its steps are empty (planned at its start, `planned`).
    """
    if len(instr.id) > MAX_ID:
        return f"the id is {len(instr.id)} characters long; at most {MAX_ID}"
    if instr.kind is Kind.TRAJECTORY:
        points = _trajectory(instr.points, limits, follow)
        if isinstance(points, str):
            return points
        return table_problem(points, follow.start if follow else None, limits, instr) or points
    if instr.kind is Kind.MOVE_TO:
        if limits.model is None:
            return "move_to needs the arm's robot model"
        return cartesian.precheck(instr, limits.ranges, limits.max_time_ms, limits.model) or ()
    time_ms = instr.time_ms
    if time_ms is not None and not 0 <= time_ms <= limits.max_time_ms:
        return explain(instr, limits)
    if instr.kind is Kind.PRESET:
        pose = limits.presets.get(instr.preset)
        if pose is None:
            return explain(instr, limits)
        steps: Steps = (Step(dict(pose), time_ms),)
    else:
        target = _target(instr.joints, limits)
        if target is None:
            return explain(instr, limits)
        steps = (Step(target, time_ms),)
    # Where the arm starts is known when the move starts (`from_start`); a target that
    # names every joint the heights depend on is judged now.
    return table_problem(steps, None, limits) or steps


def table_problem(
    steps: Steps,
    start: Mapping[str, float | None] | None,
    limits: Limits,
    instr: Instruction | None = None,
) -> str:
    """Why the board's path through `steps` from `start` (degrees; None or a joint None:
    not known) would take a body of the arm under the table, or "" (`model.table`).

    The path is the board's: each step's pulses, rounded to whole microseconds as the
    driver encodes them, reached linearly from the step before. What is not known is not
    judged: without a start, the path from the first target on, and only from where
    the targets name every joint the heights depend on. A trajectory's requested path
    (through every point) is judged as well as the board's (through the points kept).
    """
    model = limits.model
    if not limits.table or model is None or not steps:
        return ""
    known = {j: v for j, v in (start or {}).items() if v is not None}
    paths = [steps]
    points = instr.points if instr is not None and instr.kind is Kind.TRAJECTORY else ()
    if len(points) > len(steps):  # thinned: the points dropped count too
        paths.append(tuple(Step(dict(p.joints), None, i) for i, p in enumerate(points)))
    for path in paths:
        problem = _path_problem(path, known, limits, model, bool(points))
        if problem:
            return problem
    return ""


def _path_problem(
    steps: Steps, known: dict[str, float], limits: Limits, model: ArmModel, points: bool
) -> str:
    poses: list[dict[str, float]] = []
    labels: list[str] = []
    pose = dict(known)
    complete = all(j in pose for j in HEIGHT_JOINTS[:4])
    if complete:
        poses.append(as_sent(pose, limits.pulses))
    for i, step in enumerate(steps):
        pose.update(step.target)
        complete = complete or all(j in pose for j in HEIGHT_JOINTS[:4])
        if not complete:
            continue
        if poses:
            labels.append(_end(step, i, len(steps), points))
        poses.append(as_sent(pose, limits.pulses))
    if not poses:
        return ""
    if len(poses) == 1:  # no start: the first target alone
        under = below_table(model, poses[0])
        where = f"{_end(steps[-1], 0, 1, points)}: " if points else ""
        return "" if under is None else where + str(under)
    problem = path_below(model, poses, labels)
    return "" if problem is None else str(problem)


def _end(step: Step, i: int, n: int, points: bool) -> str:
    """What the end of a step is called in a reason."""
    if points:
        return f"point {step.point}"
    return "the target" if n == 1 else f"waypoint {i + 1} of {n}"


def from_start(
    instr: Instruction, steps: Steps, pose: Mapping[str, float | None], limits: Limits
) -> str:
    """When a move starts, where the arm is (`pose`) is known: its whole path is judged
    against the table (`table_problem`), or "" when nothing is wrong. A Cartesian move's
    steps are judged in `planned`."""
    if instr.kind is Kind.MOVE_TO:
        return ""
    return table_problem(steps, pose, limits, instr)


def _target(joints: tuple[tuple[str, float], ...], limits: Limits) -> dict[str, float] | None:
    """One pass for the usual, valid set of joints; a NaN fails the range test like any
    bad value. None when anything is wrong (`_joint_problems` says what)."""
    ranges = limits.ranges
    target: dict[str, float] = {}
    for name, deg in joints:
        r = ranges.get(name)
        if r is None or name in target or not r[0] <= deg <= r[1]:
            return None
        target[name] = deg
    return target or None


def _name_problem(name: str, seen: set[str], limits: Limits) -> str:
    """Why a move cannot name the joint `name` after those `seen`, or ""."""
    ranges = limits.ranges
    if name not in ranges:
        near = difflib.get_close_matches(name.lower(), ranges, n=1, cutoff=0.6)
        hint = f"did you mean {near[0]!r}? " if near else ""
        return f"unknown joint {quote(name)}; {hint}joints are {', '.join(ranges)}"
    return f"{name} is given twice" if name in seen else ""


def _joint_problems(joints: tuple[tuple[str, float], ...], limits: Limits) -> list[str]:
    if not joints:
        return ["a move names no joint"]
    ranges = limits.ranges
    problems: list[str] = []
    seen: set[str] = set()
    for name, deg in joints:
        r = ranges.get(name)
        named = _name_problem(name, seen, limits)
        if named or r is None:  # (no range: an unknown joint, named)
            problems.append(named)
        elif not math.isfinite(deg):
            problems.append(f"{name}: {deg} is not a finite number of degrees")
        elif not r[0] <= deg <= r[1]:
            problems.append(cartesian.outside(name, deg, *r))
        seen.add(name)
    return problems


def _listed(problems: list[str]) -> str:
    shown = problems[:MAX_PROBLEMS]
    more = len(problems) - len(shown)
    return "; ".join(shown) + (f"; and {more} more" if more else "")


def time_problem(i: int, at_ms: float, before_ms: float) -> str:
    """Why point `i` cannot be at `at_ms` after the start, the point before it being at
    `before_ms` (times must increase strictly), or ""."""
    if not math.isfinite(at_ms) or at_ms < 0:
        return f"point {i}: time_from_start {at_ms:g} ms is negative"
    if i > 0 and at_ms <= before_ms:
        before = f"point {i - 1} ({before_ms:g} ms)"
        return f"point {i}: time_from_start {at_ms:g} ms is not after {before}"
    return ""


def _trajectory(
    points: tuple[Point, ...], limits: Limits, follow: Follow | None = None
) -> Steps | str:
    """Every point checked before any is run; the reason names the first bad point.

    Times must increase strictly, judged on their exact values. The first point may
    be at 0: the start state, as MoveIt and joint_trajectory_controller clients send
    it; it goes at the servos' speed (nothing to do when the arm is there). Points
    are sent as whole milliseconds: a step that rounds to 0 ms (points under a
    millisecond apart) also goes at the servos' speed.

    With the link's baud, the points are then judged at its budget (`resample`): a
    trajectory denser than the wire carries is thinned to the points that keep its
    path within tolerance, or refused with the limit it meets."""
    if not points:
        return "a trajectory has no points"
    if len(points) > MAX_POINTS:
        return f"a trajectory of {len(points)} points is more than the {MAX_POINTS} taken"
    names = [name for name, _ in points[0].joints]
    if all([name for name, _ in point.joints] == names for point in points):
        # The joints every point names (a ROS trajectory's joint_names): no point's fault.
        seen: set[str] = set()
        named = []
        for name in names:
            if problem := _name_problem(name, seen, limits):
                named.append(problem)
            seen.add(name)
        if named:
            return f"the joints it names: {_listed(named)}"
    targets: list[dict[str, float]] = []
    before = 0.0
    sent = 0  # the time of the point before, in the whole ms the board is sent
    for i, point in enumerate(points):
        target = _target(point.joints, limits)
        if target is None:
            return f"point {i}: {_listed(_joint_problems(point.joints, limits))}"
        at = point.at_ms
        late = time_problem(i, at, before)
        if late:
            return late
        step = round(at) - sent
        if step > limits.max_time_ms:
            return (
                f"point {i}: {step} ms after {'the start' if i == 0 else f'point {i - 1}'}, "
                f"above the limit of {limits.max_time_ms} ms"
            )
        targets.append(target)
        before, sent = at, sent + step
    knots: tuple[int, ...] = tuple(range(len(points)))
    if limits.baud:
        plan = resample(points, budget(points, limits, follow))
        if isinstance(plan, str):
            return plan
        knots = plan.knots
    steps: list[Step] = []
    sent = 0
    for k in knots:
        step = round(points[k].at_ms) - sent
        steps.append(Step(targets[k], step or None, k))
        sent += step
    return tuple(steps)


def budget(points: tuple[Point, ...], limits: Limits, follow: Follow | None = None) -> Budget:
    """What a trajectory's points must keep to on this arm's link (`limits.baud`)."""
    follow = follow or Follow()
    longest = max(
        line_bytes([limits.channels[j] for j, _ in p.joints if j in limits.channels])
        for p in points
    )
    names = {j for p in points for j, _ in p.joints}
    line_ms = (wire_time_s(longest, limits.baud) + LINE_MARGIN_S) * 1000.0
    return Budget(
        line_ms=line_ms,
        tolerance={j: follow.tolerance.get(j, limits.path_tolerance_deg) for j in names},
        speeds=limits.speeds,
        max_step_ms=float(limits.max_time_ms),
        late_ms=follow.late_ms,
        start=follow.start,
        baud=limits.baud,
        line_bytes=longest,
    )


def explain(instr: Instruction, limits: Limits) -> str:
    """Every reason to refuse the instruction, naming the joint, the value and the range."""
    if instr.kind is Kind.TRAJECTORY:
        result = _trajectory(instr.points, limits)
        return result if isinstance(result, str) else ""
    problems: list[str] = []
    time_ms = instr.time_ms
    if time_ms is not None and time_ms < 0:
        problems.append(f"time {time_ms} ms is negative")
    elif time_ms is not None and time_ms > limits.max_time_ms:
        problems.append(f"time {time_ms} ms is above the limit of {limits.max_time_ms} ms")
    if instr.kind is Kind.PRESET:
        if instr.preset not in limits.presets:
            known = ", ".join(limits.presets)
            return f"unknown preset {quote(instr.preset)}; presets are {known}"
        return _listed(problems)
    return _listed(problems + _joint_problems(instr.joints, limits))


def planned(
    instr: Instruction,
    pose: Mapping[str, float | None],
    limits: Limits,
    translator: Translator,
) -> Steps | str:
    """A Cartesian move's steps from `pose`, checked like any move's; or why not."""
    assert limits.model is not None
    moves = cartesian.plan(instr, pose, limits.model, translator, limits.max_time_ms)
    if isinstance(moves, str):
        return moves
    steps: list[Step] = []
    for i, (target, time_ms) in enumerate(moves):
        problems = _joint_problems(tuple(target.items()), limits)
        if problems:  # the model keeps to the ranges; this is the last guard before the wire
            where = f"point {i}: " if len(moves) > 1 else ""
            return where + _listed(problems)
        steps.append(Step(target, time_ms))
    return table_problem(tuple(steps), pose, limits) or tuple(steps)
