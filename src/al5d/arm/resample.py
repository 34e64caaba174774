"""A trajectory at the link's budget: which points go to the board, judged on wire, path and servos.

The board takes a group move as one line (about 38 bytes for the five arm joints:
39.6 ms at 9600 baud, 3.3 ms at 115200) and moves every servo linearly in pulse
to arrive together at its `T`. The worker writes each line one wire time before
the move before it ends, so that the moves run back to back: two lines cannot
reach the board closer than a line's wire time. A trajectory denser than that is
thinned to knots, some of its points kept exactly (the first and the last
always, each at its own time), the board's own interpolation between them
standing in for the points dropped, so that every joint stays within its path
tolerance of the requested path (linear between points, as the board moves).

The model of what the board does (times in ms, counted as the driver counts
them: from when the first line takes effect, or, when the first point is at 0,
from the end of that move at the servos' speed):

- line 0 (the first knot) takes effect at 0; the line after knot k takes effect
  when knot k is due, provided knot k is a line's time (and margin) after the
  line before took effect; the first is special: the line after it comes at the
  earliest a line's time after it, and until then the arm waits at the first point;
- between knots the board moves linearly from one to the next, arriving at the
  next one's time; the requested path is linear between its points, so the
  largest gap between the two is at a point's time or where the board starts.

What cannot be kept is refused, whole, with the limit that is met and its
numbers: the wire (no thinning keeps the path within tolerance), or the servo
speed (with a time tolerance: a point the servos reach later than it allows).

Pure: the points, the budget in, the knots (or the reason) out.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from al5d.arm.instruction import Point

#: The thinning keeps within this share of a path tolerance; the rest is for the timing
#: (a line that takes effect a few ms late on a busy host) and the pulses' whole us.
SHARE = 0.5
#: Added to a line's wire time between two lines: a wake-up a few ms late, a link check
#: (`QP`, 4 bytes) on the wire between them.
LINE_MARGIN_S = 0.005
#: Pulse digits counted per joint in a line's length ("#<ch>P" and 4 digits; 3 below 1000 us).
PULSE_DIGITS = 4
#: A line's end counted in its length: "T", a step's time (3 digits: 100..999 ms; a longer
#: one's fourth digit is within the margin) and the CR.
TIME_BYTES = 5
#: When the nearest knot misses the path, this many farther ones are tried (a chord that
#: spans a whole wiggle may hold where a shorter one does not).
FARTHER = 8
#: The search gives up after this many point checks (about a second): a refusal then,
#: never a goal callback that holds the executor.
WORK_LIMIT = 3_000_000


@dataclass(frozen=True, slots=True)
class Budget:
    """What the points must keep to: the wire's pace, the path, the servos, the time."""

    #: The least time between two lines taking effect (ms): one line's wire time and margin.
    line_ms: float
    #: Path tolerance per joint (degrees); every joint of the points has one.
    tolerance: Mapping[str, float]
    #: Each joint's servo speed (deg/s).
    speeds: Mapping[str, float]
    #: The longest a step may take (ms): a knot span above it is not taken.
    max_step_ms: float
    #: How late a point may be reached (ms); None: lateness is not judged.
    late_ms: float | None = None
    #: Where the arm is (degrees) when it is known: the first step's speed is judged from there.
    start: Mapping[str, float] | None = None
    #: For the reasons: the link's baud and its longest line (bytes).
    baud: int = 0
    line_bytes: int = 0


@dataclass(frozen=True, slots=True)
class Follow:
    """What a trajectory's sender asks beyond its points: a path tolerance per joint
    (degrees; a joint not named: the configured default), how late a point may be (ms;
    None: not judged), and where the arm is (degrees; None: not known)."""

    tolerance: Mapping[str, float] = field(default_factory=dict)
    late_ms: float | None = None
    start: Mapping[str, float] | None = None


@dataclass(frozen=True, slots=True)
class Plan:
    """The points to send (their indices, the first and the last always) and what the board
    will do with them by the model."""

    knots: tuple[int, ...]
    #: Per joint, the most the board's path is off the requested path (degrees).
    deviation: Mapping[str, float]
    #: The latest a point will be reached after its time (ms).
    late_ms: float

    @property
    def thinned(self) -> bool:
        return len(self.knots) < (self.knots[-1] + 1 if self.knots else 0)


def line_bytes(channels: Sequence[int]) -> int:
    """The bytes of a group move of these channels, at most (but for a time above 999 ms)."""
    return sum(len(f"#{ch}P") + PULSE_DIGITS for ch in channels) + TIME_BYTES


@dataclass(frozen=True, slots=True)
class _Miss:
    """A segment off its path: the worst joint, where, and by how much over its tolerance."""

    ratio: float
    joint: int
    off: float
    at: int  # the point (or, for the start's wait, the knot before it)


class _Path:
    """The points as arrays, and the board's path between two knots checked against them."""

    def __init__(self, points: Sequence[Point], names: list[str], budget: Budget) -> None:
        self.names = names
        self.t = [p.at_ms for p in points]
        self.p = [[dict(p.joints)[j] for j in names] for p in points]
        self.tol = [budget.tolerance[j] * SHARE for j in names]
        self.w = budget.line_ms
        self.max_step = budget.max_step_ms
        self.work = 0

    def after(self, k: int) -> float:
        """When the line after knot `k` takes effect: when `k` is due (a knot after the first
        is a line's time after the one before), or, after the first, a line's time after it."""
        return max(self.w, self.t[0]) if k == 0 else self.t[k]

    def segment(self, i: int, b: int, worst: list[float] | None = None) -> _Miss | None:
        """The board's path from knot `i` to knot `b` against the requested path: the worst
        miss of a tolerance (None: within). With `worst`, every joint's largest gap is kept
        there instead, and nothing is judged."""
        t, p, tol = self.t, self.p, self.tol
        ti, tb = t[i], t[b]
        pi, pb = p[i], p[b]
        # The board starts at the line's effect (the first segment may wait for it); a line
        # that comes after its knot's time leaves the arm at knot i until then.
        go = max(self.after(i), ti)
        span = tb - go
        miss: _Miss | None = None
        joints = range(len(pi))
        self.work += (b - i) * len(pi)

        def check(at: int, f: float, want: Sequence[float]) -> None:
            nonlocal miss
            for j in joints:
                here = pi[j] + (pb[j] - pi[j]) * f
                off = abs(here - want[j])
                if worst is not None:
                    if off > worst[j]:
                        worst[j] = off
                elif off > tol[j]:
                    ratio = off / tol[j] if tol[j] > 0 else float("inf")
                    if miss is None or ratio > miss.ratio:
                        miss = _Miss(ratio, j, off, at)

        for m in range(i + 1, b):
            tm = t[m]
            check(m, 0.0 if tm <= go or span <= 0 else (tm - go) / span, p[m])
            if miss is not None and worst is None:
                return miss
        if go > ti:  # the wait at knot i: the requested path moved on meanwhile
            at = min(go, tb)
            m = bisect.bisect_right(t, at, i, b + 1) - 1
            if m >= b:
                want = p[b]
            else:
                f = (at - t[m]) / (t[m + 1] - t[m])
                want = [a + (c - a) * f for a, c in zip(p[m], p[m + 1], strict=True)]
            check(i, 0.0, want)
        return miss

    def candidates(self, i: int, misses: list[tuple[int, int, _Miss]]) -> Iterator[int]:
        """The knots that may follow knot `i`, the nearest first: the points a line's time
        or more later (or the last point, which nothing follows) whose segment holds, as
        long as they hold. The nearest keeps the path closest at the wire's own pace."""
        t, last = self.t, len(self.t) - 1
        top = min(last, bisect.bisect_right(t, t[i] + self.max_step, i + 1) - 1)
        near = min(last, bisect.bisect_left(t, self.after(i) + self.w, i + 1))
        held, missed = False, 0
        for b in range(near, top + 1):
            if self.work > WORK_LIMIT:
                return
            miss = self.segment(i, b)
            if miss is None:
                held = True
                yield b
                continue
            if held or missed == FARTHER:
                return
            if not missed:
                misses.append((i, b, miss))
            missed += 1


def _names(points: Sequence[Point]) -> list[str] | None:
    """The joints every point names, in the first point's order; None if they differ."""
    names = [j for j, _ in points[0].joints]
    first = set(names)
    for p in points:
        if len(p.joints) != len(names) or {j for j, _ in p.joints} != first:
            return None
    return names


def resample(points: Sequence[Point], budget: Budget) -> Plan | str:
    """The knots of a trajectory at the link's budget, or the reason it cannot be followed.

    A trajectory the wire can carry point by point is kept whole. One that is denser is
    thinned; where no thinning holds the path, it is refused (the wire). With a time
    tolerance, a point the servos would reach later than it allows is refused (servo
    speed). Points that name different joints are kept as they are: a joint a point does
    not name holds, and there is no one path to thin."""
    n = len(points)
    names = _names(points) if n else None
    if names is None:
        return Plan(tuple(range(n)), {}, 0.0)
    path = _Path(points, names, budget)
    t = path.t
    spaced = all(t[k] - path.after(k - 1) >= path.w for k in range(1, n - 1))
    if spaced:
        knots: tuple[int, ...] | str = tuple(range(n))
    else:
        knots = _search(path, budget)
    if isinstance(knots, str):
        return knots
    worst = [0.0] * len(names)
    for i, b in itertools.pairwise(knots):
        path.segment(i, b, worst)
    late = _lateness(path, knots, budget)
    if isinstance(late, str):
        return late
    return Plan(knots, dict(zip(names, worst, strict=True)), late)


def _search(path: _Path, budget: Budget) -> tuple[int, ...] | str:
    """Knots from the first point to the last, each segment within the path tolerance: depth
    first, the nearest candidate first, a point from which the last cannot be reached
    remembered as such (what follows a knot does not depend on how it was reached)."""
    last = len(path.t) - 1
    misses: list[tuple[int, int, _Miss]] = []
    chain = [0]
    todo = [path.candidates(0, misses)]
    dead: set[int] = set()
    while chain:
        if chain[-1] == last:
            return tuple(chain)
        nxt = next((b for b in todo[-1] if b not in dead), None)
        if nxt is None:
            dead.add(chain.pop())
            todo.pop()
            continue
        chain.append(nxt)
        todo.append(path.candidates(nxt, misses))
    return _wire_reason(path, budget, misses)


def _wire_reason(path: _Path, budget: Budget, misses: list[tuple[int, int, _Miss]]) -> str:
    gap = path.w
    head = "the wire: "
    if budget.baud and budget.line_bytes:
        wire = gap - LINE_MARGIN_S * 1000.0
        head += (
            f"at {budget.baud} baud a group move of {budget.line_bytes} bytes takes "
            f"{wire:.1f} ms on the wire, so the board takes one every {gap:.1f} ms at most "
            f"({1000.0 / gap:.0f} a second, with a {LINE_MARGIN_S * 1000:.0f} ms margin); "
        )
    else:
        head += f"the board takes a group move every {gap:.1f} ms at most; "
    if path.work > WORK_LIMIT:
        return head + "no thinning of the points to that pace was found that keeps the path"
    if not misses:
        return head + "no thinning of the points to that pace keeps within the longest move time"
    i, b, miss = min(misses, key=lambda m: m[2].ratio)
    joint = path.names[miss.joint]
    where = "waiting for the next line" if miss.at == i else f"at point {miss.at}"
    tol = budget.tolerance[joint]
    return head + (
        f"the points cannot be thinned to that pace within the path tolerance: the least "
        f"miss, from point {i} ({path.t[i]:.0f} ms) to point {b} ({path.t[b]:.0f} ms), the "
        f"nearest a move's time later, puts {joint} {miss.off:.3g} deg off the requested "
        f"path {where}; its tolerance is {tol:.3g} deg ({SHARE:.0%} of it for the thinning)"
    )


def _lateness(path: _Path, knots: tuple[int, ...], budget: Budget) -> float | str:
    """The latest point (ms after its time) by the servos' speeds and the lines' times; a
    reason when a time tolerance is given and a point would be later than it allows."""
    t, p, names = path.t, path.p, path.names
    speeds = [budget.speeds[j] for j in names]
    start = budget.start
    here: list[float] | None = (
        [start[j] for j in names] if start is not None and all(j in start for j in names) else None
    )
    end = 0.0
    worst, worst_k, wire_late = 0.0, -1, 0.0
    culprit: tuple[int, str, float, float, float] | None = None  # point, joint, deg, ms, deg/s
    for n, k in enumerate(knots):
        if n == 0 and round(t[0]) == 0:
            here, end = p[0], 0.0  # at the servos' speed: the times count from its end
            continue
        a = 0.0 if n == 0 else path.after(knots[n - 1])
        begin = max(a, end)
        need, joint = 0.0, -1
        if here is not None:
            for j, (x, y, v) in enumerate(zip(here, p[k], speeds, strict=True)):
                ms = abs(y - x) / v * 1000.0
                if ms > need:
                    need, joint = ms, j
        window = t[k] - a
        # The servo is to blame where it needs more than the points give it, the wire
        # aside (a line that can only take effect after the point's time is the wire's).
        given = t[k] - (t[knots[n - 1]] if n else 0.0)
        if culprit is None and here is not None and joint >= 0 and need > given:
            # The time it has: the points' less the wire's wait, or theirs where the wire
            # leaves none (it is the servo that cannot make even that).
            has = window if window > 0 else given
            culprit = (k, names[joint], abs(p[k][joint] - here[joint]), has, speeds[joint])
        end = max(t[k], begin + need)
        late = end - t[k]
        if late > worst:
            worst, worst_k, wire_late = late, k, max(0.0, a - t[k])
        here = p[k]
    allowed = budget.late_ms
    if allowed is None or worst <= allowed:
        return worst
    if culprit is not None and worst > wire_late + 1e-9:
        point, name, deg, window, speed = culprit
        asked = f"{deg:.3g} deg in {window:.0f} ms" if window > 0 else f"{deg:.3g} deg at once"
        rate = deg / max(window, 1e-3) * 1000.0
        return (
            f"servo speed: point {point} asks {name} for {asked} ({rate:.0f} deg/s); its "
            f"servo does {speed:.0f} deg/s: point {worst_k} would be reached "
            f"{worst:.0f} ms after its time, beyond the time tolerance of {allowed:.0f} ms"
        )
    return (
        f"the wire: point {worst_k}'s group move cannot reach the board before "
        f"{wire_late:.0f} ms after its time (a move every {path.w:.1f} ms at most): beyond "
        f"the time tolerance of {allowed:.0f} ms"
    )
