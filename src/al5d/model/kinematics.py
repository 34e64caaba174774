"""Forward and inverse kinematics of the AL5D in closed form, in the arm's own degrees.

The arm works in one vertical plane that the base turns. In that plane, with
elevations measured from the horizontal (+ up): the upper arm stands at
90 - shoulder, the forearm at 90 - shoulder - elbow, and the gripper at its
pitch = 90 - shoulder - elbow + wrist. Roll is wrist_rotate. The base's +deg
turns right, so the plane's heading in base_link (REP 103, + to the left) is
-base. Single solves use `math` (a numpy call costs more than the whole solve).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from al5d.model import table
from al5d.model.arm import ArmModel
from al5d.model.errors import (
    BelowTable,
    InvalidInput,
    JointOutOfRange,
    OutOfReach,
    Unreachable,
    whole_mm,
)
from al5d.model.geometry import Geometry
from al5d.model.joints import ARM_JOINTS
from al5d.model.transforms import Mat3, Quat, Vec3, matrix_from_quat

#: A solution this close outside a limit is rounding, not a violation; it is snapped.
#: Near full stretch (elbow 0) a last-bit error of the target moves the angles by
#: about 1e-6 deg (the acos slope is infinite there), hence not 1e-12.
LIMIT_SLACK_DEG = 1e-5
#: Wrist points this close beyond the reach are rounding too (metres).
REACH_SLACK_M = 1e-12
#: Targets closer than this to the base axis have no heading; the base hint (or 0) is used.
AXIS_EPS_M = 1e-9


@dataclass(frozen=True)
class ToolPose:
    """Where tool0 (the gripper tip) is, in base_link."""

    #: Metres.
    position: Vec3
    #: Orientation of tool0 (z out of the gripper), quaternion (x, y, z, w), w >= 0.
    quaternion: Quat
    #: The same orientation as a rotation matrix (rows).
    matrix: Mat3
    #: Angle of the gripper axis to the horizontal, degrees, + up, in (-180, 180].
    pitch_deg: float
    #: Rotation about the gripper axis, degrees (= wrist_rotate).
    roll_deg: float


def wrap_deg(angle: float) -> float:
    """An angle in degrees brought into (-180, 180]."""
    a = math.fmod(angle + 180.0, 360.0)
    if a <= 0.0:
        a += 360.0
    return a - 180.0


def _arm_values(degrees: Mapping[str, float]) -> tuple[float, float, float, float, float]:
    try:
        values = tuple(float(degrees[j]) for j in ARM_JOINTS)
    except KeyError as err:
        raise InvalidInput(f"forward kinematics needs joint {err.args[0]}") from None
    if not all(math.isfinite(v) for v in values):
        raise InvalidInput(
            f"joint angles must be finite: {dict(zip(ARM_JOINTS, values, strict=True))}"
        )
    return values  # type: ignore[return-value]  # five by construction


def _planar(
    g: Geometry, shoulder: float, elbow: float, wrist: float
) -> tuple[float, float, float, float, float, float, float, float]:
    # (r, z) of the shoulder, elbow, wrist and tip in the arm's plane.
    a1 = math.radians(90.0 - shoulder)
    a2 = a1 - math.radians(elbow)
    a3 = a2 + math.radians(wrist)
    rs, zs = g.shoulder_offset, g.base_height
    re, ze = rs + g.humerus * math.cos(a1), zs + g.humerus * math.sin(a1)
    rw, zw = re + g.ulna * math.cos(a2), ze + g.ulna * math.sin(a2)
    rt, zt = rw + g.gripper * math.cos(a3), zw + g.gripper * math.sin(a3)
    return rs, zs, re, ze, rw, zw, rt, zt


def tool_position(geometry: Geometry, degrees: Mapping[str, float]) -> Vec3:
    """Position of tool0 in base_link (metres) for the arm's degrees."""
    base, shoulder, elbow, wrist, _ = _arm_values(degrees)
    return tip_at(geometry, base, shoulder, elbow, wrist)


def tip_at(g: Geometry, base: float, shoulder: float, elbow: float, wrist: float) -> Vec3:
    """tool0 in base_link (metres) from the four angles that place it, unchecked: the hot
    path of planning a straight line, which samples thousands of poses it made itself."""
    *_, rt, zt = _planar(g, shoulder, elbow, wrist)
    heading = math.radians(-base)
    return (rt * math.cos(heading), rt * math.sin(heading), zt)


def joint_positions(geometry: Geometry, degrees: Mapping[str, float]) -> dict[str, Vec3]:
    """Positions in base_link (metres) of base (on the table), shoulder, elbow, wrist, tool0.

    The wrist rotate turns about the gripper axis through the wrist point, so it
    has no point of its own; the wrist's point is the wrist pitch axis.
    """
    base, shoulder, elbow, wrist, _ = _arm_values(degrees)
    rs, zs, re, ze, rw, zw, rt, zt = _planar(geometry, shoulder, elbow, wrist)
    c, s = math.cos(math.radians(-base)), math.sin(math.radians(-base))
    return {
        "base": (0.0, 0.0, 0.0),
        "shoulder": (rs * c, rs * s, zs),
        "elbow": (re * c, re * s, ze),
        "wrist": (rw * c, rw * s, zw),
        "tool0": (rt * c, rt * s, zt),
    }


#: A point this little under the table is rounding (a target on the table's top), not under it.
TABLE_SLACK_M = table.TABLE_SLACK_M


def below_table(model: ArmModel, degrees: Mapping[str, float]) -> BelowTable | None:
    """The deepest body of the arm under the table for these degrees, or None: the tool
    tip, the wrist, the elbow, and the bodies the 3D view draws (`table`: the fingers,
    the hand, the forearm...; without a gripper in `degrees`, open, its widest).

    The table (`geometry.table_height`) is not part of IK: a target under it is a
    target the arm could take were the table not there, and the caller decides.
    """
    return table.below(model, degrees)


def tool_quaternion(base_deg: float, pitch_deg: float, roll_deg: float) -> Quat:
    """Orientation of tool0 for a heading, pitch and roll: Rz(-base) Ry(90 - pitch) Rz(roll).

    At pitch 90 (pointing up) tool0 is aligned with base_link; at pitch 0 and base 0
    its z points forward (+x) and its x down, as ROS-Industrial's tool0 does.
    """
    yaw = math.radians(-base_deg) / 2.0
    tilt = math.radians(90.0 - pitch_deg) / 2.0
    roll = math.radians(roll_deg) / 2.0
    # Closed form of qz(yaw) * qy(tilt) * qz(roll) (a z-y-z Euler product).
    ct, st = math.cos(tilt), math.sin(tilt)
    q = (
        -st * math.sin(yaw - roll),
        st * math.cos(yaw - roll),
        ct * math.sin(yaw + roll),
        ct * math.cos(yaw + roll),
    )
    return q if q[3] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def forward(geometry: Geometry, degrees: Mapping[str, float]) -> ToolPose:
    """The pose of tool0 for the arm's degrees (the five arm joints; others are ignored)."""
    base, shoulder, elbow, wrist, wrist_rotate = _arm_values(degrees)
    *_, rt, zt = _planar(geometry, shoulder, elbow, wrist)
    heading = math.radians(-base)
    pitch = wrap_deg(90.0 - shoulder - elbow + wrist)
    q = tool_quaternion(base, pitch, wrist_rotate)
    return ToolPose(
        position=(rt * math.cos(heading), rt * math.sin(heading), zt),
        quaternion=q,
        matrix=matrix_from_quat(q),
        pitch_deg=pitch,
        roll_deg=wrist_rotate,
    )


def solve(
    model: ArmModel,
    x: float,
    y: float,
    z: float,
    pitch_deg: float,
    roll_deg: float = 0.0,
    *,
    base_hint_deg: float | None = None,
) -> dict[str, float]:
    """Arm degrees of the five arm joints that put tool0 at (x, y, z) with that pitch and roll.

    One branch (elbow up, the only one the elbow's 0..135 range allows). The base
    faces the target, or faces away from it (the arm reaching back over the base
    axis) when only that is in range or only that works. When both would do, the
    one nearer `base_hint_deg` is taken (e.g. the current base, so a path that
    passes over the base axis does not swing round); on the axis itself the base
    is the hint, or 0. Raises
    OutOfReach or JointOutOfRange (both Unreachable) for a target the arm cannot
    take, InvalidInput for NaN or infinity; never returns NaN.
    """
    if not (
        math.isfinite(x)
        and math.isfinite(y)
        and math.isfinite(z)
        and math.isfinite(pitch_deg)
        and math.isfinite(roll_deg)
        and (base_hint_deg is None or math.isfinite(base_hint_deg))
    ):
        raise InvalidInput(
            f"target must be finite: x={x}, y={y}, z={z}, pitch={pitch_deg}, roll={roll_deg}"
        )
    r = math.hypot(x, y)
    if r <= AXIS_EPS_M:
        on_axis = 0.0 if base_hint_deg is None else base_hint_deg
        return _solve_in_plane(model, on_axis, 0.0, z, pitch_deg, roll_deg)
    base = -math.degrees(math.atan2(y, x))
    # The base may also face away from the target, the arm reaching back over the
    # base axis (r < 0 in its plane, shoulder leaning back); pitch stays relative
    # to the arm's heading, as forward() defines it. Facing the target comes first.
    flipped = base - 180.0 if base > 0.0 else base + 180.0
    rng = model.ranges.base
    if not rng.lo - LIMIT_SLACK_DEG <= flipped <= rng.hi + LIMIT_SLACK_DEG:
        return _solve_in_plane(model, base, r, z, pitch_deg, roll_deg)
    if not rng.lo - LIMIT_SLACK_DEG <= base <= rng.hi + LIMIT_SLACK_DEG:
        return _solve_in_plane(model, flipped, -r, z, pitch_deg, roll_deg)
    first, second = (base, r), (flipped, -r)
    if base_hint_deg is not None and abs(flipped - base_hint_deg) < abs(base - base_hint_deg):
        first, second = second, first
    try:
        return _solve_in_plane(model, first[0], first[1], z, pitch_deg, roll_deg)
    except Unreachable as preferred:
        try:
            return _solve_in_plane(model, second[0], second[1], z, pitch_deg, roll_deg)
        except Unreachable:
            raise preferred from None


def _solve_in_plane(
    model: ArmModel, base: float, r: float, z: float, pitch_deg: float, roll_deg: float
) -> dict[str, float]:
    # The planar 3-link problem once the base (and so the plane) is chosen; r may be < 0.
    g = model.geometry
    rg = model.ranges
    p = math.radians(pitch_deg)
    wr = r - g.shoulder_offset - g.gripper * math.cos(p)
    wz = z - g.base_height - g.gripper * math.sin(p)
    h, u = g.humerus, g.ulna
    d2 = wr * wr + wz * wz
    d = math.sqrt(d2)
    far, near = h + u, abs(h - u)
    if d > far:
        if d - far > REACH_SLACK_M:
            raise OutOfReach(d, far, too_close=False)
        d, d2 = far, far * far
    elif d < near:
        if near - d > REACH_SLACK_M:
            raise OutOfReach(d, near, too_close=True)
        d, d2 = near, near * near
    cos_inner = max(-1.0, min(1.0, (h * h + u * u - d2) / (2.0 * h * u)))
    elbow = 180.0 - math.degrees(math.acos(cos_inner))
    if d > 0.0:
        cos_a = max(-1.0, min(1.0, (h * h + d2 - u * u) / (2.0 * h * d)))
        elevation = math.atan2(wz, wr) + math.acos(cos_a)
    else:
        # Only when humerus == ulna, folded flat: the elbow then needs 180 and is refused.
        elevation = math.pi / 2.0
    shoulder = wrap_deg(90.0 - math.degrees(elevation))
    wrist = wrap_deg(pitch_deg - 90.0 + shoulder + elbow)
    out = {
        "base": base,
        "shoulder": shoulder,
        "elbow": elbow,
        "wrist": wrist,
        "wrist_rotate": wrap_deg(roll_deg),
    }
    bad: list[tuple[str, float, float, float]] | None = None
    for name, rng in (
        ("base", rg.base),
        ("shoulder", rg.shoulder),
        ("elbow", rg.elbow),
        ("wrist", rg.wrist),
        ("wrist_rotate", rg.wrist_rotate),
    ):
        v = out[name]
        if v < rng.lo:
            if rng.lo - v <= LIMIT_SLACK_DEG:
                out[name] = rng.lo
            else:
                bad = (bad or []) + [(name, v, rng.lo, rng.hi)]
        elif v > rng.hi:
            if v - rng.hi <= LIMIT_SLACK_DEG:
                out[name] = rng.hi
            else:
                bad = (bad or []) + [(name, v, rng.lo, rng.hi)]
    if bad:
        raise JointOutOfRange(tuple(bad))
    return out


def solve_nearest_pitch(
    model: ArmModel,
    x: float,
    y: float,
    z: float,
    preferred_pitch_deg: float = 0.0,
    roll_deg: float = 0.0,
    *,
    step_deg: float = 0.5,
    base_hint_deg: float | None = None,
) -> tuple[dict[str, float], float]:
    """IK without a given pitch: the reachable pitch closest to the preferred one.

    Returns (arm degrees, pitch in degrees, in (-180, 180]). The search steps
    outward from the preferred pitch by `step_deg` on both sides, then bisects
    to the edge of the first reachable interval (to 1e-9 deg); a reachable
    interval narrower than the step can be missed. Raises Unreachable when no
    pitch works, with the reason at the preferred pitch.
    """
    if not (math.isfinite(preferred_pitch_deg) and math.isfinite(step_deg) and step_deg > 0):
        raise InvalidInput(
            f"preferred pitch and step must be finite, step > 0: {preferred_pitch_deg}, {step_deg}"
        )

    def attempt(pitch: float) -> dict[str, float] | None:
        try:
            return solve(model, x, y, z, pitch, roll_deg, base_hint_deg=base_hint_deg)
        except Unreachable:
            return None

    p0 = preferred_pitch_deg
    try:
        return solve(model, x, y, z, p0, roll_deg, base_hint_deg=base_hint_deg), wrap_deg(p0)
    except Unreachable as err:
        first_error = err

    def edge(bad: float, good: float, sol: dict[str, float]) -> tuple[dict[str, float], float]:
        # The feasible end always holds a solution, so what is returned is solvable.
        while abs(good - bad) > 1e-9:
            mid = (bad + good) / 2.0
            found = attempt(mid)
            if found is None:
                bad = mid
            else:
                good, sol = mid, found
        return sol, good

    steps = math.ceil(180.0 / step_deg)
    previous = 0.0
    for k in range(1, steps + 1):
        offset = min(k * step_deg, 180.0)
        hits: list[tuple[float, dict[str, float], float]] = []
        for sign in (1.0, -1.0):
            if sign < 0 and offset >= 180.0:
                break  # p0 + 180 and p0 - 180 are the same pitch
            found = attempt(p0 + sign * offset)
            if found is not None:
                sol, pitch = edge(p0 + sign * previous, p0 + sign * offset, found)
                hits.append((abs(pitch - p0), sol, pitch))
        if hits:
            _, sol, _ = min(hits, key=lambda h: h[0])
            # The solution's own pitch: at an edge a joint was snapped onto its limit,
            # which moves the pitch by up to LIMIT_SLACK_DEG from the bisected one.
            return sol, wrap_deg(90.0 - sol["shoulder"] - sol["elbow"] + sol["wrist"])
        previous = offset
    raise Unreachable(
        f"no pitch reaches x={whole_mm(x)} y={whole_mm(y)} z={whole_mm(z)} mm; "
        f"at pitch {p0:.0f} deg: {first_error}"
    )
