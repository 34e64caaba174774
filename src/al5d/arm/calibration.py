"""Calibration: the pulse that truly puts each joint at two reference angles, found by
nudging, becomes the joint's two calibration points in the configuration file.

Per joint, the arm goes to a reference pose (the joint at a reference angle, the others
upright: the `straight_up` preset); the user nudges the pulse in steps until the real
joint stands where the model shows it, and accepts; then the second reference. The two
points found are the joint's new `calibration` (they set offset, scale and direction):

- the offset is how far each found pulse lies from the one the old calibration gave;
- the direction is checked: a joint whose found pulses run the other way than the old
  calibration's (nudging toward +angle moved it toward -angle) is reported `reversed`;
- the limits are checked: a nudge never leaves the servo's pulse range, and a calibration
  that would put an end of the joint's `range_deg` outside it is refused;
- the file is written with a backup beside it and a unified diff, and only if the new text
  loads and validates with the configuration's own code.

Pure: the arm is moved by the caller (`al5d calibrate` through the server, a test through
the board's owner), which hands each pulse's outcome back; `al5d.arm.calfile` writes the file.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from pydantic import ValidationError

from al5d.arm.config import ArmConfig, JointSettings
from al5d.arm.servos import SERVOS
from al5d.ssc32u.facts import PULSE_MAX_US, PULSE_MIN_US

#: A nudge, by default: about half a degree on an AL5D's servos (10 us a degree).
DEFAULT_STEP_US = 5
#: The pose of the joints not being calibrated: upright, clear of the table.
REST_PRESET = "straight_up"
#: A scale found more than this factor off the old one is said (`JointCalibration.describe`).
SCALE_SUSPECT = 1.2
#: A reference angle lies at least this far inside the joint's range, so that a joint
#: that is off by that much can still be nudged to it without leaving the range.
MARGIN_DEG = 20.0


@dataclass(frozen=True)
class Reference:
    """A reference angle of a joint and what the user sees when the joint stands there."""

    deg: float
    looks: str


#: Two landmarks per joint, easy to judge by eye, well inside the shipped ranges.
REFERENCES: dict[str, tuple[Reference, Reference]] = {
    "base": (
        Reference(0, "the arm points straight ahead, square to the base's front"),
        Reference(45, "the arm points halfway between ahead and its right"),
    ),
    "shoulder": (
        Reference(0, "the upper arm stands vertical"),
        Reference(45, "the upper arm leans forward halfway to horizontal"),
    ),
    "elbow": (
        Reference(90, "the forearm is square to the upper arm"),
        Reference(45, "the forearm is halfway between straight and square"),
    ),
    "wrist": (
        Reference(0, "the hand is in line with the forearm"),
        Reference(45, "the hand is bent up halfway to square"),
    ),
    "gripper": (
        Reference(30, "the gripper's servo a third of its travel from fully open"),
        Reference(60, "the gripper's servo two thirds of its travel from fully open"),
    ),
    "wrist_rotate": (
        Reference(0, "the fingers open and close in the arm's plane"),
        Reference(45, "the hand turned halfway to square, the way the model shows"),
    ),
}


class CalibrationRefused(ValueError):
    """A nudge or a calibration that cannot be used; the message says what to do."""


def references(joint: JointSettings) -> tuple[Reference, Reference]:
    """The joint's two reference angles: its landmarks when they lie well inside its range,
    otherwise the quarter points of the range."""
    lo, hi = joint.range_deg
    known = REFERENCES.get(joint.name)
    if known and all(lo + MARGIN_DEG <= r.deg <= hi - MARGIN_DEG for r in known):
        return known
    quarter = (hi - lo) / 4
    return (
        Reference(lo + quarter, "a quarter of the way along the range from its first end"),
        Reference(hi - quarter, "a quarter of the way along the range from its second end"),
    )


def servo_range(joint: JointSettings) -> tuple[int, int]:
    """The pulses the joint's servo takes (its model's, or the board's whole range)."""
    return SERVOS[joint.servo].pulse_us if joint.servo else (PULSE_MIN_US, PULSE_MAX_US)


def pose_for(config: ArmConfig, name: str, us: int) -> dict[str, float]:
    """The whole arm's pose (degrees, as the configuration reads them) that puts joint
    `name` at pulse `us`, the others at rest: the move to send for that pulse."""
    pose = dict(config.presets[REST_PRESET])
    pose[name] = config.joints[name].to_deg(us)
    return pose


def nudged(joint: JointSettings, us: int, steps: int, step_us: int) -> int:
    """The pulse `steps` nudges of `step_us` toward +angle as the configuration has it
    (toward -angle for steps < 0); refused if it leaves the servo's pulse range."""
    sign = 1 if joint.us_per_deg > 0 else -1
    new = us + sign * steps * step_us
    pmin, pmax = servo_range(joint)
    if not pmin <= new <= pmax:
        raise CalibrationRefused(
            f"{joint.name}: {new} us is outside the servo's {pmin}..{pmax} us; nudge the other "
            "way, or re-seat the horn if the joint cannot reach its reference within it"
        )
    return new


@dataclass(frozen=True)
class Point:
    """A pulse found to put the joint at `deg`."""

    deg: float
    us: int


@dataclass(frozen=True)
class JointCalibration:
    """A joint's two points found, and what they change."""

    old: JointSettings
    new: JointSettings
    found: tuple[Point, Point]

    @property
    def name(self) -> str:
        return self.old.name

    @property
    def offsets_us(self) -> tuple[float, float]:
        """How far each found pulse lies from where the old calibration put that angle."""
        a, b = self.found
        return a.us - self.old.to_us(a.deg), b.us - self.old.to_us(b.deg)

    @property
    def reversed(self) -> bool:
        """The joint turns the other way than the old calibration said."""
        return (self.new.us_per_deg > 0) != (self.old.us_per_deg > 0)

    def describe(self) -> str:
        a, b = self.offsets_us
        scale = self.new.us_per_deg / self.old.us_per_deg
        text = (
            f"{self.name}: offset {a:+.0f} us at {self.found[0].deg:g} deg, {b:+.0f} us at "
            f"{self.found[1].deg:g} deg (scale x{abs(scale):.3f})"
        )
        if self.reversed:
            text += (
                "; REVERSED: nudging toward +angle moved the joint toward -angle, the new "
                "calibration turns it round"
            )
        if not 1 / SCALE_SUSPECT <= abs(scale) <= SCALE_SUSPECT:
            # One servo's us per degree hardly differs from another's of its model: a scale
            # this far off is more likely a reference matched at the wrong place.
            text += "; CHECK the scale: was the joint at the ghost at both references?"
        return text


def judge(joint: JointSettings, found: tuple[Point, Point]) -> JointCalibration:
    """The joint with `found` as its calibration points, validated as the file's own code
    does (its range's ends within the servo's pulses); CalibrationRefused says why not."""
    a, b = found
    if a.us == b.us:
        raise CalibrationRefused(
            f"{joint.name}: both references were accepted at {a.us} us; the joint cannot "
            "stand at two angles at one pulse: calibrate it again"
        )
    data = joint.model_dump()
    data["calibration"] = [{"deg": p.deg, "us": p.us} for p in found]
    try:
        new = JointSettings.model_validate(data)
    except ValidationError as e:
        reasons = "; ".join(err["msg"].removeprefix("Value error, ") for err in e.errors())
        lo, hi = joint.range_deg
        raise CalibrationRefused(
            f"{joint.name}: with the pulses found ({a.us} us at {a.deg:g} deg, {b.us} us at "
            f"{b.deg:g} deg): {reasons}; the joint cannot cover its range {lo:g}..{hi:g} deg "
            f"within its servo's pulses: re-seat the horn nearer, or narrow "
            f"joints.{joint.name}.range_deg"
        ) from None
    return JointCalibration(joint, new, found)


class Awaiting(enum.Enum):
    """What the procedure waits for."""

    NUDGE = "nudge"  # the user nudges the current joint toward its reference, then accepts
    DONE = "done"  # every joint calibrated (or skipped or refused)


@dataclass
class Procedure:
    """The guided procedure's state: which joint, which reference, the pulse commanded, the
    points found and the joints' results. The caller moves the arm to `pose()` whenever
    `pulse` changes, and calls `moved` once that move is done (or `not_moved`)."""

    config: ArmConfig
    joints: tuple[str, ...]
    step_us: int = DEFAULT_STEP_US
    results: list[JointCalibration] = field(default_factory=list, init=False)
    refused: dict[str, str] = field(default_factory=dict, init=False)
    skipped: list[str] = field(default_factory=list, init=False)
    #: The pulse asked for (the arm is sent there)...
    pulse: int = field(default=0, init=False)
    #: ...and the last one whose move was done: where the arm is (None: not yet there).
    at: int | None = field(default=None, init=False)
    _index: int = field(default=0, init=False)
    _ref: int = field(default=0, init=False)
    _found: list[Point] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        unknown = [j for j in self.joints if j not in self.config.joints]
        if unknown:
            raise CalibrationRefused(
                f"no joint {unknown[0]!r}; the joints are {', '.join(self.config.joints)}"
            )
        if not 1 <= self.step_us <= 100:
            raise CalibrationRefused(f"a step of {self.step_us} us: give 1..100 us")
        self._begin_reference()

    @property
    def step(self) -> Awaiting:
        return Awaiting.DONE if self._index >= len(self.joints) else Awaiting.NUDGE

    @property
    def joint(self) -> JointSettings:
        return self.config.joints[self.joints[self._index]]

    @property
    def reference(self) -> Reference:
        return references(self.joint)[self._ref]

    @property
    def reference_index(self) -> int:
        return self._ref

    def pose(self) -> dict[str, float]:
        """The move for the current pulse (degrees as the configuration reads them)."""
        return pose_for(self.config, self.joint.name, self.pulse)

    def reference_pose(self) -> dict[str, float]:
        """Where the model shows the arm: the current joint at its reference angle."""
        pose = dict(self.config.presets[REST_PRESET])
        pose[self.joint.name] = self.reference.deg
        return pose

    def nudge(self, steps: int) -> int:
        """Ask for the pulse `steps` nudges on (toward +angle as the configuration has it);
        CalibrationRefused leaves the pulse as it was. Move the arm to `pose()` next."""
        start = self.at if self.at is not None else self.pulse
        self.pulse = nudged(self.joint, start, steps, self.step_us)
        return self.pulse

    def moved(self) -> None:
        """The move to `pose()` is done: the arm is at `pulse`."""
        self.at = self.pulse

    def not_moved(self) -> None:
        """The move to `pose()` was refused or cancelled: the arm stays where it was."""
        if self.at is not None:
            self.pulse = self.at

    def accept(self) -> JointCalibration | None:
        """The joint stands at its reference: the pulse where the arm is is that point. After
        a joint's second point, its calibration (or CalibrationRefused, the joint is then
        left as it was and the procedure goes on with the next)."""
        if self.at is None:
            raise CalibrationRefused("the arm has not reached this reference yet: move it first")
        self._found.append(Point(self.reference.deg, self.at))
        if self._ref == 0:
            self._ref = 1
            self._begin_reference()
            return None
        found = (self._found[0], self._found[1])
        joint = self.joint
        self._next_joint()
        try:
            result = judge(joint, found)
        except CalibrationRefused as e:
            self.refused[joint.name] = str(e)
            raise
        self.results.append(result)
        return result

    def skip(self) -> None:
        """Leave the current joint as it is in the file."""
        self.skipped.append(self.joint.name)
        self._next_joint()

    def _next_joint(self) -> None:
        self._index += 1
        self._ref = 0
        self._found = []
        self._begin_reference()

    def _begin_reference(self) -> None:
        self.at = None
        if self.step is Awaiting.NUDGE:
            self.pulse = round(self.joint.to_us(self.reference.deg))


def summary(procedure: Procedure) -> list[str]:
    """One line per joint: its calibration found, refused, or skipped."""
    lines = [r.describe() for r in procedure.results]
    lines += [f"refused: {reason}" for reason in procedure.refused.values()]
    lines += [f"{name}: skipped, left as it was" for name in procedure.skipped]
    return lines
