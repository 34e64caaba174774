"""What the page knows, as pure functions and small records: no ROS, no viser, no threads.

- `target_of`: where an instruction will leave the arm (the ghost), judged by the
  server's own validation and Cartesian planner, so that the page shows the
  server's refusal reason before the server has said it.
- `OutcomeLog`: the last outcomes, as HTML that quotes no input unescaped.
- `JointHistory`: joint angles over the last seconds, for the plot.
"""

from __future__ import annotations

import html
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from al5d.arm import validate
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Instruction, Kind, Outcome, Result
from al5d.arm.translate import Translator
from al5d.model import ModelError, tool_position
from al5d.model.transforms import Vec3


@dataclass(frozen=True)
class Target:
    """Where an instruction leaves the arm: every joint in degrees, and for a straight-line
    `move_to` the tool's points along the line (metres, base_link), start first."""

    id: str
    degrees: dict[str, float]
    line: tuple[Vec3, ...] = ()


class Planner:
    """Targets of instructions for one arm configuration, the way the server judges them."""

    def __init__(self, config: ArmConfig) -> None:
        self.config = config
        self.limits = validate.Limits.of(config)
        self.translator = Translator(config)
        self.geometry = config.model.geometry

    def target_of(self, instr: Instruction, start: Mapping[str, float]) -> Target | str | None:
        """The pose `instr` leaves the arm in when it starts from `start` (degrees of every
        joint); the reason the server will refuse it; or None when it does not move the arm
        (stop, release)."""
        if instr.kind in (Kind.STOP, Kind.RELEASE):
            return None
        if instr.kind is Kind.SHUTDOWN:
            return Target(instr.id, {**start, **self.config.presets["park"]})
        steps = validate.check(instr, self.limits)
        if isinstance(steps, str):
            return steps
        if instr.kind is Kind.MOVE_TO:
            # Planned from where the arm is, as the server plans it when the move starts.
            steps = validate.planned(instr, start, self.limits, self.translator)
            if isinstance(steps, str):
                return steps
        else:
            # Its path from there against the table, as the server judges it when it starts.
            problem = validate.from_start(instr, steps, start, self.limits)
            if problem:
                return problem
        pose = dict(start)
        poses = [dict(pose)]
        for step in steps:
            pose.update(step.target)
            poses.append(dict(pose))
        line: tuple[Vec3, ...] = ()
        if instr.tool is not None and instr.tool.line:
            try:
                line = tuple(tool_position(self.geometry, p) for p in poses)
            except ModelError:
                line = ()
        return Target(instr.id, pose, line)

    def tool_of(self, degrees: Mapping[str, float]) -> Vec3 | None:
        """Where the tool tip is for these degrees (None before every joint is known)."""
        try:
            return tool_position(self.geometry, degrees)
        except ModelError:
            return None


def outcome_html(outcome: Outcome) -> str:
    """One outcome as a line of HTML. Reasons quote what clients sent (any text, from any
    process on the ROS domain): everything is escaped, nothing is markup."""
    colour = {Result.DONE: "#2b8a3e", Result.REFUSED: "#c92a2a", Result.CANCELLED: "#e67700"}
    text = f"{outcome.instruction} [{outcome.id}]: {outcome.result.value}"
    if outcome.reason:
        text += f": {outcome.reason}"
    if outcome.result is Result.DONE and outcome.elapsed_ms:
        text += f" ({outcome.elapsed_ms:.0f} ms)"
    return (
        f'<div style="color:{colour[outcome.result]};font-size:0.85em;'
        f'overflow-wrap:anywhere">{html.escape(text)}</div>'
    )


class OutcomeLog:
    """The last `size` outcomes, newest first."""

    def __init__(self, size: int = 12) -> None:
        self.items: deque[Outcome] = deque(maxlen=size)

    def add(self, outcome: Outcome) -> None:
        self.items.appendleft(outcome)

    def html(self) -> str:
        if not self.items:
            return '<div style="color:#868e96;font-size:0.85em">no outcome yet</div>'
        return "".join(outcome_html(o) for o in self.items)


class JointHistory:
    """Joint angles (degrees) over the last `seconds`, for the plot: time relative to now."""

    def __init__(self, joints: tuple[str, ...], seconds: float = 10.0) -> None:
        self.joints = joints
        self.seconds = seconds
        self._samples: deque[tuple[float, tuple[float, ...]]] = deque()

    def add(self, t: float, degrees: Mapping[str, float]) -> None:
        self._samples.append((t, tuple(degrees.get(j, math.nan) for j in self.joints)))
        while self._samples and self._samples[0][0] < t - self.seconds:
            self._samples.popleft()

    def series(self, now: float) -> tuple[npt.NDArray[np.float64], ...]:
        """(seconds before now, then one array per joint); two points at least (uPlot's)."""
        samples = [s for s in self._samples if s[0] >= now - self.seconds]
        if len(samples) < 2:
            nothing = (np.array([math.nan, math.nan]) for _ in self.joints)
            return (np.array([-self.seconds, 0.0]), *nothing)
        ts = np.array([t - now for t, _ in samples])
        values = np.array([v for _, v in samples]).T
        return (ts, *(values[i] for i in range(len(self.joints))))
