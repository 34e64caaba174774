"""A trajectory at the link's budget (issue 25): the points thinned to what the wire carries.

Properties over random trajectories, checked against a model of the board written
here from its description (each line takes effect when the knot before it is due;
the board moves linearly in pulse, hence in degrees, from knot to knot), sampled
every millisecond, not only at the points.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig, load_config
from al5d.arm.resample import SHARE, Follow, Plan, resample
from al5d.arm.validate import Limits, budget, check
from al5d.ssc32u.facts import BAUDS

CONFIG = load_config()
JOINTS = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]


def interp(ts: list[float], ps: list[list[float]], t: float) -> list[float]:
    """The requested path: linear between points, held before the first and after the last."""
    if t <= ts[0]:
        return ps[0]
    if t >= ts[-1]:
        return ps[-1]
    k = max(i for i in range(len(ts)) if ts[i] <= t)
    f = (t - ts[k]) / (ts[k + 1] - ts[k])
    return [a + (b - a) * f for a, b in zip(ps[k], ps[k + 1], strict=True)]


def effects(ts: list[float], knots: tuple[int, ...], line_ms: float) -> list[float]:
    """When each knot's line takes effect: the first at 0; the second a line's time after it
    at the earliest (or when the first is due); each later one when the knot before is due."""
    out = [0.0]
    for j in range(1, len(knots)):
        out.append(max(line_ms, ts[knots[0]]) if j == 1 else ts[knots[j - 1]])
    return out


def board(
    ts: list[float], ps: list[list[float]], knots: tuple[int, ...], line_ms: float, t: float
) -> list[float]:
    """Where the board holds the joints at `t`: at a knot until the next line takes effect,
    then linearly to the next knot, there at its time."""
    on = effects(ts, knots, line_ms)
    if t <= ts[knots[0]]:
        return ps[knots[0]]  # the first segment is the requested one (from the start)
    for j in range(1, len(knots)):
        i, b = knots[j - 1], knots[j]
        if t <= ts[b]:
            go = max(on[j], ts[i])
            if t <= go:
                return ps[i]
            f = (t - go) / (ts[b] - go)
            return [x + (y - x) * f for x, y in zip(ps[i], ps[b], strict=True)]
    return ps[knots[-1]]


@st.composite
def trajectories(draw: st.DrawFn) -> tuple[list[ins.Point], int, float]:
    names = draw(st.lists(st.sampled_from(JOINTS), min_size=1, max_size=5, unique=True))
    n = draw(st.integers(2, 40))
    first = draw(st.sampled_from([0.0, draw(st.floats(1, 200))]))
    gaps = draw(st.lists(st.floats(1, 120), min_size=n - 1, max_size=n - 1))
    step = draw(st.floats(0.05, 12))
    here = {j: draw(st.floats(*CONFIG.joints[j].range_deg)) for j in names}
    t, points = first, []
    for k in range(n):
        if k:
            t += gaps[k - 1]
            for j in names:
                lo, hi = CONFIG.joints[j].range_deg
                here[j] = min(hi, max(lo, here[j] + draw(st.floats(-step, step))))
        points.append(ins.Point(tuple(here.items()), t))
    return points, draw(st.sampled_from(BAUDS)), draw(st.floats(0.2, 5))


def limits_at(baud: int, tolerance: float) -> Limits:
    # The wire and the path only: random poses are often under the table (test_arm_table.py).
    return dataclasses.replace(Limits.of(CONFIG, baud), path_tolerance_deg=tolerance, table=False)


@settings(max_examples=300, deadline=None)
@given(trajectories())
def test_a_thinned_trajectory_keeps_its_path_its_ends_its_times_and_the_wire(
    case: tuple[list[ins.Point], int, float],
) -> None:
    points, baud, tolerance = case
    limits = limits_at(baud, tolerance)
    b = budget(tuple(points), limits)
    plan = resample(points, b)
    ts = [p.at_ms for p in points]
    ps = [[v for _, v in p.joints] for p in points]
    w = b.line_ms
    event("refused" if isinstance(plan, str) else "thinned" if plan.thinned else "kept whole")
    if isinstance(plan, str):
        assert plan.startswith(f"the wire: at {baud} baud a group move of ")
        assert "path tolerance" in plan
        return
    knots = plan.knots
    # The ends kept exactly, the points in order.
    assert knots[0] == 0 and knots[-1] == len(points) - 1
    assert all(a < b for a, b in itertools.pairwise(knots))
    # A trajectory the wire carries point by point is not touched.
    if all(ts[k] - (max(w, ts[0]) if k == 1 else ts[k - 1]) >= w for k in range(1, len(ts) - 1)):
        assert knots == tuple(range(len(points)))
        return
    # The wire: each line takes effect a line's time (and margin) after the one before,
    # and before its knot is due (but the last, which nothing follows).
    on = effects(ts, knots, w)
    for j in range(1, len(knots)):
        assert on[j] - on[j - 1] >= w - 1e-9
        if j < len(knots) - 1:
            assert ts[knots[j]] - on[j] >= w - 1e-9
    # Every joint within its share of the tolerance, at every point and every millisecond.
    limit = tolerance * SHARE + 1e-9
    samples = ts + [ts[0] + k for k in range(int(ts[-1] - ts[0]) + 1)]
    for t in samples:
        want, have = interp(ts, ps, t), board(ts, ps, knots, w, t)
        for j, (x, y) in enumerate(zip(want, have, strict=True)):
            assert abs(x - y) <= limit, (t, points[0].joints[j][0], x, y)
    # The reported deviation is the model's.
    assert max(plan.deviation.values()) <= limit
    # The times kept: the steps sent add up to each kept point's time, in whole ms.
    steps = check(ins.trajectory(points), limits)
    assert not isinstance(steps, str)
    assert [s.point for s in steps] == list(knots)
    total = 0
    for s, k in zip(steps, knots, strict=True):
        total += s.time_ms or 0
        assert total == round(ts[k])


@settings(max_examples=200, deadline=None)
@given(
    st.sampled_from(BAUDS),
    st.integers(20, 400),
    st.floats(0.5, 20),
    st.floats(-60, 60),
)
def test_a_straight_path_from_rest_is_never_refused_however_dense(
    baud: int, n: int, dt_ms: float, travel: float
) -> None:
    # At rest for 100 ms (the first line's wait), then straight at a constant speed.
    rest, span = 100.0, dt_ms * n
    points = [ins.Point((("base", 0.0), ("elbow", 90.0)), t) for t in (0.0, rest)]
    for k in range(1, n + 1):
        t = rest + dt_ms * k
        f = (t - rest) / span
        points.append(ins.Point((("base", travel * f), ("elbow", 90.0 - travel * f / 2)), t))
    plan = resample(points, budget(tuple(points), Limits.of(CONFIG, baud)))
    assert isinstance(plan, Plan), plan
    assert plan.knots[-1] == n + 1
    assert max(plan.deviation.values()) <= 1e-6


def test_the_wire_of_one_line_sets_the_pace(config: ArmConfig) -> None:
    # Five joints: "#0P1500" .. "#5P1500" and "T100\r", 40 bytes: 41.7 ms at 9600 baud.
    points = tuple(ins.Point(tuple((j, 0.0) for j in JOINTS), 20.0 * k) for k in range(100))
    b = budget(points, Limits.of(config, 9600))
    assert b.line_bytes == 40 and b.line_ms == pytest.approx(40 * 10 / 9600 * 1000 + 5)
    fast = budget(points, Limits.of(config, 115200))
    assert fast.line_ms == pytest.approx(40 * 10 / 115200 * 1000 + 5)
    # Without a baud (a pure judgement) the points are all kept.
    steps = check(ins.trajectory(list(points)), Limits.of(config))
    assert not isinstance(steps, str) and len(steps) == 100


def test_a_zigzag_too_dense_for_the_wire_is_refused_naming_the_wire_and_the_tolerance(
    config: ArmConfig,
) -> None:
    points = [ins.Point((("base", 20.0 if k % 2 else 0.0),), 20.0 * k) for k in range(50)]
    reason = check(ins.trajectory(points), Limits.of(config, 9600))
    assert isinstance(reason, str)
    assert reason.startswith(
        "the wire: at 9600 baud a group move of 12 bytes takes 12.5 ms on the wire, so the "
        "board takes one every 17.5 ms at most (57 a second"
    )
    assert "puts base 20 deg off the requested path at point 1" in reason
    assert "its tolerance is 1 deg" in reason
    # At 115200 baud the same points are carried one by one.
    steps = check(ins.trajectory(points), Limits.of(config, 115200))
    assert not isinstance(steps, str) and len(steps) == 50


def test_a_goal_s_own_tolerance_wins_over_the_default(config: ArmConfig) -> None:
    # A gentle wave from rest: thinned within 1 deg, but not within 0.01 deg.
    points = [ins.Point((("base", 10 * (1 - math.cos(k / 10))),), 20.0 * k) for k in range(100)]
    limits = Limits.of(config, 9600)
    loose = check(ins.trajectory(points), limits)
    assert not isinstance(loose, str) and len(loose) < 100
    tight = check(ins.trajectory(points), limits, Follow(tolerance={"base": 0.01}))
    assert isinstance(tight, str) and "its tolerance is 0.01 deg" in tight


def test_points_the_servos_cannot_reach_in_time_are_refused_with_a_time_tolerance(
    config: ArmConfig,
) -> None:
    points = [ins.Point((("elbow", 90.0),), 0.0), ins.Point((("elbow", 10.0),), 100.0)]
    limits = Limits.of(config, 9600)
    # 80 deg of elbow (261 deg/s) need 306 ms; asked in 100 ms less the first line's wait
    # (12 bytes, 12.5 ms, and the 5 ms margin).
    reason = check(ins.trajectory(points), limits, Follow(late_ms=100.0))
    assert isinstance(reason, str)
    assert reason.startswith("servo speed: point 1 asks elbow for 80 deg in 82 ms (970 deg/s);")
    assert "its servo does 261 deg/s" in reason and "time tolerance of 100 ms" in reason
    # Without a time tolerance lateness is not judged (INF03 warns as the steps go out);
    # with a generous one it is within.
    assert not isinstance(check(ins.trajectory(points), limits), str)
    assert not isinstance(check(ins.trajectory(points), limits, Follow(late_ms=400.0)), str)
    # The first step is judged from where the arm is, when that is known.
    first = [ins.Point((("base", 80.0),), 50.0)]
    assert not isinstance(check(ins.trajectory(first), limits, Follow(late_ms=10.0)), str)
    far = check(ins.trajectory(first), limits, Follow(late_ms=10.0, start={"base": 0.0}))
    assert isinstance(far, str) and far.startswith("servo speed: point 0 asks base for 80 deg")


def test_a_point_late_for_the_wire_alone_is_refused_naming_the_wire(config: ArmConfig) -> None:
    """An outside try: two points of the five arm joints 20 ms apart, each 0.573 deg of base
    (1.7 ms of its servo), at 9600 baud with a tolerance of 1 ms were refused for the
    servo's speed ("0.573 deg at once (572958 deg/s)"), where the second line cannot take
    effect before 47 ms: the wire's doing, which the refusal now names."""
    still = tuple((j, 0.0) for j in ("shoulder", "elbow", "wrist", "wrist_rotate"))
    points = [
        ins.Point((("base", 0.573), *still), 20.0),
        ins.Point((("base", 1.146), *still), 40.0),
    ]
    limits = Limits.of(config, 9600)
    start = {j: 0.0 for j in ("base", "shoulder", "elbow", "wrist", "wrist_rotate")}
    reason = check(ins.trajectory(points), limits, Follow(late_ms=1.0, start=start))
    assert isinstance(reason, str) and reason.startswith("the wire: point 1's group move"), reason
    assert "beyond the time tolerance of 1 ms" in reason, reason
    # 30 deg there are the servo's doing (90 ms of it), said in the time the points give.
    far = [ins.Point((("base", 0.573), *still), 20.0), ins.Point((("base", 30.573), *still), 40.0)]
    servo = check(ins.trajectory(far), limits, Follow(late_ms=1.0, start=start))
    assert isinstance(servo, str), servo
    assert servo.startswith("servo speed: point 1 asks base for 30 deg in 20 ms (1500 deg/s)")


def test_points_naming_different_joints_are_kept_as_they_are(config: ArmConfig) -> None:
    points = [
        ins.Point((("base", 0.0),), 0.0),
        ins.Point((("elbow", 80.0),), 5.0),
        ins.Point((("base", 5.0),), 10.0),
    ]
    steps = check(ins.trajectory(points), Limits.of(config, 9600))
    assert not isinstance(steps, str) and [s.point for s in steps] == [0, 1, 2]
