"""The exceptions the robot model raises when it refuses an input or a target."""

from __future__ import annotations


class ModelError(ValueError):
    """Anything the model refuses; catch this to catch all of them."""


class InvalidInput(ModelError):
    """An input that is malformed: NaN or infinite, a missing joint, a bad length."""


class Unreachable(ModelError):
    """A well-formed target that the arm cannot take; the message says why and by how much."""


class OutOfReach(Unreachable):
    """The wrist point is farther from the shoulder than the arm reaches, or closer."""

    def __init__(self, distance_m: float, limit_m: float, too_close: bool) -> None:
        self.distance_m = distance_m
        self.limit_m = limit_m
        self.too_close = too_close
        dist, limit = _mm_pair(distance_m, limit_m)
        what = "no closer than " if too_close else ""
        super().__init__(
            f"out of reach: {dist} mm from the shoulder, the arm reaches {what}{limit} mm"
        )


class JointOutOfRange(Unreachable):
    """A solution exists but needs one or more joints outside their ranges."""

    def __init__(self, violations: tuple[tuple[str, float, float, float], ...]) -> None:
        # (joint, needed deg, lo, hi), in chain order; the first is the one named first.
        self.violations = violations
        self.joint, self.needed_deg, self.lo_deg, self.hi_deg = violations[0]
        super().__init__(
            "; ".join(
                f"{joint} would need {_deg(needed, lo, hi)} deg, "
                f"its range is {_deg(lo)}..{_deg(hi)}"
                for joint, needed, lo, hi in violations
            )
        )


class BelowTable(Unreachable):
    """A target that would take a point of the arm (the tool tip, the wrist) below the table."""

    def __init__(self, point: str, z_m: float, table_m: float) -> None:
        self.point = point
        self.z_m = z_m
        self.table_m = table_m
        z, table = _mm_pair(z_m, table_m)
        super().__init__(
            f"below the table: the {point} would be at z={z} mm, the table is at z={table} mm"
        )


class PathUnreachable(Unreachable):
    """A straight-line move fails somewhere along the line; `fraction` says where (0..1).

    With `until` and `worst`, the failing stretch is known: it runs from `fraction` to
    `until`, and `worst` is the failure at its worst point (of the same kind as `cause`,
    the failure where the stretch starts), so the reason says by how much at most rather
    than by how little at the edge.
    """

    def __init__(
        self,
        fraction: float,
        cause: Unreachable,
        *,
        until: float | None = None,
        worst: Unreachable | None = None,
    ) -> None:
        self.fraction = fraction
        self.cause = cause
        self.until = until
        self.worst = worst
        text = None if until is None or worst is None else _stretch(cause, worst)
        if text is None:
            super().__init__(f"the line fails at {fraction:.0%} of the path: {cause}")
        else:
            what, detail = text
            assert until is not None
            super().__init__(
                f"the line {what} between {_pct(fraction)} and {_pct(until)} of the path: {detail}"
            )


def _pct(fraction: float) -> str:
    return f"{fraction * 100:.0f} %"


def _stretch(cause: Unreachable, worst: Unreachable) -> tuple[str, str] | None:
    # (what the line does, how much at worst), for the kinds whose worst is a number.
    if isinstance(cause, JointOutOfRange) and isinstance(worst, JointOutOfRange):
        joint = cause.joint
        hit = next((v for v in worst.violations if v[0] == joint), None)
        if hit is None:
            return None
        _, needed, lo, hi = hit
        way = "up to" if needed > hi else "down to"
        return (
            f"leaves the {joint}'s range",
            f"it would need {way} {_deg(needed, lo, hi)} deg, its range is {_deg(lo)}..{_deg(hi)}",
        )
    if isinstance(cause, OutOfReach) and isinstance(worst, OutOfReach):
        if cause.too_close != worst.too_close:
            return None
        dist, limit = _mm_pair(worst.distance_m, worst.limit_m)
        if worst.too_close:
            return (
                "comes closer to the shoulder than the arm folds",
                f"down to {dist} mm from the shoulder, the arm reaches no closer than {limit} mm",
            )
        return (
            "leaves the arm's reach",
            f"up to {dist} mm from the shoulder, the arm reaches {limit} mm",
        )
    if isinstance(cause, BelowTable) and isinstance(worst, BelowTable):
        if cause.point != worst.point:
            return None
        z, table = _mm_pair(worst.z_m, worst.table_m)
        return (
            f"takes the {cause.point} below the table",
            f"down to z={z} mm, the table is at z={table} mm",
        )
    return None


def excess(err: Unreachable, like: Unreachable) -> float | None:
    """How far `err` is beyond the limit that `like` broke (degrees or metres), or None when
    `err` breaks another one: what a failing stretch's worst point is the largest of."""
    if isinstance(like, JointOutOfRange) and isinstance(err, JointOutOfRange):
        hit = next((v for v in err.violations if v[0] == like.joint), None)
        if hit is None:
            return None
        _, needed, lo, hi = hit
        return max(lo - needed, needed - hi)
    if isinstance(like, OutOfReach) and isinstance(err, OutOfReach):
        if like.too_close != err.too_close:
            return None
        return abs(err.distance_m - err.limit_m)
    if isinstance(like, BelowTable) and isinstance(err, BelowTable):
        return err.table_m - err.z_m if like.point == err.point else None
    return None


#: A number this large (or larger) is said in the `g` format: with "f" a 1e308 mm target
#: took 309 digits of a refusal's reason.
BIG = 1e7


def whole_mm(value_m: float) -> str:
    """`value_m` (metres) in whole millimetres, or past `BIG` mm in four figures."""
    mm = value_m * 1000
    text = f"{mm:.4g}" if abs(mm) >= BIG else f"{mm:.0f}"
    return "0" if text == "-0" else text  # y=-0 for a y of 0 the arm's frame made -0.0


def _deg(value: float, *limits: float) -> str:
    # Whole degrees read best; decimals are added only while the value would
    # print the same as a limit it exceeds ("would need 135 deg, range 0..135").
    if abs(value) >= BIG:
        return f"{value:.4g}"
    for digits in range(7):
        text = f"{value:.{digits}f}"
        if all(text != f"{limit:.{digits}f}" for limit in limits):
            return text
    return text


def _mm_pair(distance_m: float, limit_m: float) -> tuple[str, str]:
    # "333 mm from the shoulder, the arm reaches 333 mm" would hide the difference:
    # add decimals until the two numbers differ (at most six).
    if max(abs(distance_m), abs(limit_m)) * 1000 >= BIG:
        return f"{distance_m * 1000:.4g}", f"{limit_m * 1000:.4g}"
    for digits in range(7):
        a = f"{distance_m * 1000:.{digits}f}"
        b = f"{limit_m * 1000:.{digits}f}"
        if float(a) != float(b):  # "-0" and "0" are the same number
            return a, b
    return a, b
