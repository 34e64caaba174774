"""Straight-line tool moves cut into the fewest group moves that stay near the line.

In a group move the SSC-32U moves every pulse linearly in time, so the joints'
degrees move linearly and the tip travels a curve. A move is planned here as
waypoints on the line (pitch and roll interpolated linearly); each hop from one
waypoint to the next is one group move, made as long as possible while its curve
stays within the tolerance of the line from start to target.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Final

from al5d.model.arm import ArmModel
from al5d.model.errors import InvalidInput, PathUnreachable, Unreachable, excess
from al5d.model.geometry import Geometry
from al5d.model.joints import ARM_JOINTS
from al5d.model.kinematics import (
    below_table,
    forward,
    solve,
    solve_nearest_pitch,
    tip_at,
    wrap_deg,
)
from al5d.model.transforms import Vec3

Joints = tuple[float, float, float, float, float]
#: Per arm joint, the pulse width at 0 deg and the (signed) microseconds per degree: the
#: calibration the driver encodes a move with.
PulseScale = Mapping[str, tuple[float, float]]

DEFAULT_TOLERANCE_M: Final = 0.001
#: Waypoints are placed to this fraction of the path (bisection end).
_T_EPS: Final = 1e-4
#: Coarse samples of a hop before the largest is refined (the curve is smooth:
#: one or two bumps per hop, so 24 samples never straddle a maximum badly).
_COARSE: Final = 24
_GOLDEN: Final = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class LinePlan:
    """A straight-line move as group moves: go to each waypoint in turn."""

    #: tool0 at the start (from the start degrees) and at the target, metres.
    start: Vec3
    end: Vec3
    #: (start, end) pitch and roll, degrees; both change linearly along the line.
    pitch_deg: tuple[float, float]
    roll_deg: tuple[float, float]
    #: Arm degrees of the five arm joints at each waypoint; the last is the target.
    waypoints: tuple[Mapping[str, float], ...]
    #: Where each waypoint lies along the line, 0 < f <= 1, increasing, last 1.
    fractions: tuple[float, ...]
    #: Largest distance of the tip from the line over all hops (sampled), metres.
    max_deviation_m: float


def _tip(g: Geometry, q: Joints) -> Vec3:
    return tip_at(g, q[0], q[1], q[2], q[3])


class _Line:
    """Distance of points to the segment from p0 to p1."""

    def __init__(self, p0: Vec3, p1: Vec3) -> None:
        self.p0 = p0
        self.d = (p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2])
        self.l2 = self.d[0] ** 2 + self.d[1] ** 2 + self.d[2] ** 2

    def distance(self, p: Vec3) -> float:
        v = (p[0] - self.p0[0], p[1] - self.p0[1], p[2] - self.p0[2])
        t = 0.0
        if self.l2 > 0.0:
            t = min(
                1.0, max(0.0, (v[0] * self.d[0] + v[1] * self.d[1] + v[2] * self.d[2]) / self.l2)
            )
        return math.dist(v, (t * self.d[0], t * self.d[1], t * self.d[2]))


def distance_to_segment(p0: Vec3, p1: Vec3, point: Vec3) -> float:
    """How far `point` is from the segment p0-p1 (metres): what `path=line` holds to 1 mm."""
    return _Line(p0, p1).distance(point)


def _lerp(a: Joints, b: Joints, u: float) -> Joints:
    return (
        a[0] + (b[0] - a[0]) * u,
        a[1] + (b[1] - a[1]) * u,
        a[2] + (b[2] - a[2]) * u,
        a[3] + (b[3] - a[3]) * u,
        a[4] + (b[4] - a[4]) * u,
    )


def _hop_deviation(g: Geometry, line: _Line, a: Joints, b: Joints) -> float:
    # Coarse samples, then a golden-section search around the largest: as exact
    # as dense sampling at a tenth of the cost.
    devs = [line.distance(_tip(g, _lerp(a, b, i / _COARSE))) for i in range(_COARSE + 1)]
    k = max(range(_COARSE + 1), key=devs.__getitem__)
    lo, hi = max(0, k - 1) / _COARSE, min(_COARSE, k + 1) / _COARSE
    best = devs[k]
    x1 = hi - _GOLDEN * (hi - lo)
    x2 = lo + _GOLDEN * (hi - lo)
    f1 = line.distance(_tip(g, _lerp(a, b, x1)))
    f2 = line.distance(_tip(g, _lerp(a, b, x2)))
    for _ in range(20):
        if f1 > f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - _GOLDEN * (hi - lo)
            f1 = line.distance(_tip(g, _lerp(a, b, x1)))
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + _GOLDEN * (hi - lo)
            f2 = line.distance(_tip(g, _lerp(a, b, x2)))
    return max(best, f1, f2)


def _as_joints(degrees: Mapping[str, float], what: str) -> Joints:
    try:
        values = tuple(float(degrees[j]) for j in ARM_JOINTS)
    except KeyError as err:
        raise InvalidInput(f"{what} needs joint {err.args[0]}") from None
    if not all(math.isfinite(v) for v in values):
        raise InvalidInput(f"{what} must be finite: {dict(zip(ARM_JOINTS, values, strict=True))}")
    return values  # type: ignore[return-value]  # five by construction


def segment_deviation(
    geometry: Geometry,
    start_deg: Mapping[str, float],
    end_deg: Mapping[str, float],
    line_start: Vec3,
    line_end: Vec3,
    samples: int = 256,
) -> float:
    """Largest distance (metres) of the tip from the segment line_start..line_end while
    the joints move linearly from start_deg to end_deg, sampled at `samples` + 1 points."""
    if samples < 1:
        raise InvalidInput(f"samples must be >= 1, not {samples}")
    a, b = _as_joints(start_deg, "start"), _as_joints(end_deg, "end")
    line = _Line(line_start, line_end)
    return max(line.distance(_tip(geometry, _lerp(a, b, i / samples))) for i in range(samples + 1))


def as_sent(degrees: Mapping[str, float], pulses: PulseScale) -> dict[str, float]:
    """The degrees the board runs for `degrees`: each joint's pulse rounded to a whole
    microsecond, as the driver encodes it (the joints without a scale are left as given)."""
    out = dict(degrees)
    for joint, (at_zero, per_deg) in pulses.items():
        if joint in out:
            out[joint] = (math.floor(at_zero + out[joint] * per_deg + 0.5) - at_zero) / per_deg
    return out


def _snapper(pulses: PulseScale | None) -> Callable[[Joints], Joints]:
    """The joints as the board will hold them (identity without a pulse scale)."""
    if pulses is None:
        return lambda q: q
    try:
        scales = [(float(pulses[j][0]), float(pulses[j][1])) for j in ARM_JOINTS]
    except (KeyError, IndexError, TypeError, ValueError):
        raise InvalidInput(
            f"pulses needs (us at 0 deg, us per deg) for every arm joint: {ARM_JOINTS}"
        ) from None
    if not all(math.isfinite(u) and math.isfinite(k) and k != 0 for u, k in scales):
        raise InvalidInput(f"pulse scales must be finite with a slope != 0, not {scales}")

    def snap(q: Joints) -> Joints:
        return tuple(  # type: ignore[return-value]  # five by construction
            (math.floor(u + d * k + 0.5) - u) / k for d, (u, k) in zip(q, scales, strict=True)
        )

    return snap


def _failing_stretch(
    ik: Callable[[float], Joints], i: int, n: int, cause: Unreachable
) -> PathUnreachable:
    """Where the line stops being reachable (it fails between check points i - 1 and i of
    n), where it becomes reachable again, and how far out it is at its worst point."""
    lo, hi = (i - 1) / n, i / n
    for _ in range(12):  # name the edge to a fraction of the check step
        mid = (lo + hi) / 2
        try:
            ik(mid)
            lo = mid
        except Unreachable as e:
            hi, cause = mid, e
    first = hi

    def out_by(t: float) -> tuple[float, Unreachable | None]:
        try:
            ik(t)
        except Unreachable as e:
            x = excess(e, cause)
            return (-math.inf, None) if x is None else (x, e)
        return -math.inf, None

    (worst_x, worst), worst_t = out_by(first), first
    until = 1.0
    for k in range(i, n + 1):
        t = max(first, k / n)
        try:
            ik(t)
        except Unreachable as e:
            x = excess(e, cause)
            if x is not None and x > worst_x:
                worst_x, worst, worst_t = x, e, t
            continue
        lo, hi = max(first, (k - 1) / n), t  # failing at lo, reachable at hi
        for _ in range(12):
            mid = (lo + hi) / 2
            try:
                ik(mid)
                hi = mid
            except Unreachable:
                lo = mid
        until = lo
        break
    # The samples are a check step apart: a golden-section search finds the worst between.
    a, b = max(first, worst_t - 1 / n), min(until, worst_t + 1 / n)
    for _ in range(30):
        if b - a < 1e-9:
            break
        x1, x2 = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
        (f1, e1), (f2, e2) = out_by(x1), out_by(x2)
        for f, found in ((f1, e1), (f2, e2)):
            if found is not None and f > worst_x:
                worst_x, worst = f, found
        if f1 > f2:
            b = x2
        else:
            a = x1
    return PathUnreachable(first, cause, until=until, worst=worst or cause)


def plan_line(
    model: ArmModel,
    start_deg: Mapping[str, float],
    target: Vec3,
    pitch_deg: float | None = None,
    roll_deg: float | None = None,
    *,
    tolerance_m: float = DEFAULT_TOLERANCE_M,
    check_step_m: float = 0.001,
    pulses: PulseScale | None = None,
) -> LinePlan:
    """Plan a straight tool move from the arm's degrees to a target point (metres).

    Without a pitch, the reachable pitch nearest the start's is used; without a
    roll, the start's. Every point of the line is checked with IK at least every
    `check_step_m` (and every 0.5 deg of pitch or roll change), and against the
    table (`geometry.table_height`); if one fails, the whole move is refused with
    PathUnreachable naming the failing stretch and how far out its worst point is.

    With `pulses`, each hop is judged as the board will run it: from and to the
    waypoints rounded to whole microseconds (the board interpolates the pulses
    linearly between those), and the line starts where the rounded start puts the
    tip; the waypoints themselves are the exact angles (the driver rounds them).
    """
    if not (math.isfinite(tolerance_m) and tolerance_m > 0):
        raise InvalidInput(f"tolerance must be finite and > 0, not {tolerance_m}")
    if not (math.isfinite(check_step_m) and check_step_m > 0):
        raise InvalidInput(f"check step must be finite and > 0, not {check_step_m}")
    if not all(math.isfinite(float(c)) for c in target) or len(target) != 3:
        raise InvalidInput(f"target must be three finite numbers, not {target}")
    g = model.geometry
    snap = _snapper(pulses)
    q0 = snap(_as_joints(start_deg, "start"))
    pose = forward(g, dict(zip(ARM_JOINTS, q0, strict=True)))
    p0 = pose.position
    p1 = (float(target[0]), float(target[1]), float(target[2]))
    pitch0, roll0 = pose.pitch_deg, q0[4]
    roll1 = roll0 if roll_deg is None else float(roll_deg)
    if pitch_deg is None:
        try:
            _, pitch1 = solve_nearest_pitch(
                model, p1[0], p1[1], p1[2], pitch0, roll1, base_hint_deg=q0[0]
            )
        except Unreachable as err:
            raise PathUnreachable(1.0, err) from None
    else:
        pitch1 = float(pitch_deg)
    d_pitch = wrap_deg(pitch1 - pitch0)
    d_roll = roll1 - roll0
    line = _Line(p0, p1)

    def ik(t: float, base_hint: float) -> Joints:
        p = (p0[0] + t * line.d[0], p0[1] + t * line.d[1], p0[2] + t * line.d[2])
        sol = solve(model, *p, pitch0 + t * d_pitch, roll0 + t * d_roll, base_hint_deg=base_hint)
        under = below_table(model, sol)
        if under is not None:
            raise under
        return (sol["base"], sol["shoulder"], sol["elbow"], sol["wrist"], sol["wrist_rotate"])

    # Refuse whole, before planning, if any point of the line cannot be taken.
    length = math.sqrt(line.l2)
    n = max(
        1,
        math.ceil(length / check_step_m),
        math.ceil(abs(d_pitch) / 0.5),
        math.ceil(abs(d_roll) / 0.5),
    )
    solved: dict[float, Joints] = {}
    base_hint = q0[0]
    for i in range(1, n + 1):
        t = i / n
        try:
            solved[t] = ik(t, base_hint)
        except Unreachable as err:
            raise _failing_stretch(functools.partial(ik, base_hint=base_hint), i, n, err) from None
        # Neighbours a check step apart whose joint midpoint leaves the line: the
        # IK jumped (to the other side of the base axis), and no hop can follow.
        halfway = _tip(g, _lerp(solved.get((i - 1) / n, q0), solved[t], 0.5))
        if line.distance(halfway) > tolerance_m:
            raise PathUnreachable(
                t,
                Unreachable(
                    "the joints would jump here (the line passes the base axis on a side "
                    "the base cannot face)"
                ),
            )
        base_hint = solved[t][0]

    waypoints: list[Joints] = []
    fractions: list[float] = []
    worst = 0.0
    ta, qa = 0.0, q0
    while ta < 1.0:
        q1 = solved[1.0]
        sa = snap(qa)
        dev = _hop_deviation(g, line, sa, snap(q1))
        if dev <= tolerance_m:
            tb, qb = 1.0, q1
        else:
            lo, hi, qb_lo, dev_lo = ta, 1.0, None, 0.0
            while hi - lo > _T_EPS:
                mid = (lo + hi) / 2
                qm = ik(mid, qa[0])
                dm = _hop_deviation(g, line, sa, snap(qm))
                if dm <= tolerance_m:
                    lo, qb_lo, dev_lo = mid, qm, dm
                else:
                    hi = mid
            if qb_lo is None:
                raise PathUnreachable(
                    ta,
                    Unreachable(
                        f"the joints cannot follow the line within {tolerance_m * 1000:g} mm here"
                    ),
                )
            tb, qb, dev = lo, qb_lo, dev_lo
        waypoints.append(qb)
        fractions.append(tb)
        worst = max(worst, dev)
        ta, qa = tb, qb
    return LinePlan(
        start=p0,
        end=p1,
        pitch_deg=(pitch0, pitch0 + d_pitch),
        roll_deg=(roll0, roll1),
        waypoints=tuple(dict(zip(ARM_JOINTS, q, strict=True)) for q in waypoints),
        fractions=tuple(fractions),
        max_deviation_m=worst,
    )
