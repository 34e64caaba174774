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


class PathUnreachable(Unreachable):
    """A straight-line move fails somewhere along the line; `fraction` says where (0..1)."""

    def __init__(self, fraction: float, cause: Unreachable) -> None:
        self.fraction = fraction
        self.cause = cause
        super().__init__(f"the line fails at {fraction:.0%} of the path: {cause}")


def _deg(value: float, *limits: float) -> str:
    # Whole degrees read best; decimals are added only while the value would
    # print the same as a limit it exceeds ("would need 135 deg, range 0..135").
    for digits in range(7):
        text = f"{value:.{digits}f}"
        if all(text != f"{limit:.{digits}f}" for limit in limits):
            return text
    return text


def _mm_pair(distance_m: float, limit_m: float) -> tuple[str, str]:
    # "333 mm from the shoulder, the arm reaches 333 mm" would hide the difference:
    # add decimals until the two numbers differ (at most six).
    for digits in range(7):
        a = f"{distance_m * 1000:.{digits}f}"
        b = f"{limit_m * 1000:.{digits}f}"
        if a != b:
            return a, b
    return a, b
