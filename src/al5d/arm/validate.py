"""Whether an instruction can run, judged whole before anything is written (D3, VE02).

Pure functions of the instruction and the arm's limits: `check` is the fast
path for the usual, valid move; `explain` gives every reason to refuse one,
naming the joint, the value and the range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Instruction, Kind


@dataclass(frozen=True, slots=True)
class Limits:
    """What validation needs of the arm: joint ranges, presets, the longest move time."""

    ranges: Mapping[str, tuple[float, float]]
    presets: Mapping[str, Mapping[str, float]]
    max_time_ms: int

    @classmethod
    def of(cls, config: ArmConfig) -> Limits:
        return cls(
            ranges={n: j.range_deg for n, j in config.joints.items()},
            presets=config.presets,
            max_time_ms=config.server.max_move_time_ms,
        )


def check(instr: Instruction, limits: Limits) -> dict[str, float] | str:
    """The target pose of a motion instruction, or the reason to refuse it whole."""
    time_ms = instr.time_ms
    if time_ms is not None and not 0 <= time_ms <= limits.max_time_ms:
        return explain(instr, limits)
    if instr.kind is Kind.PRESET:
        pose = limits.presets.get(instr.preset)
        return dict(pose) if pose is not None else explain(instr, limits)
    # One pass for the usual, valid move; a NaN fails the range test like any bad value.
    ranges = limits.ranges
    target: dict[str, float] = {}
    for name, deg in instr.joints:
        r = ranges.get(name)
        if r is None or name in target or not r[0] <= deg <= r[1]:
            return explain(instr, limits)
        target[name] = deg
    return target if target else explain(instr, limits)


def explain(instr: Instruction, limits: Limits) -> str:
    """Every reason to refuse the instruction, naming the joint, the value and the range."""
    problems: list[str] = []
    time_ms = instr.time_ms
    if time_ms is not None and time_ms < 0:
        problems.append(f"time {time_ms} ms is negative")
    elif time_ms is not None and time_ms > limits.max_time_ms:
        problems.append(f"time {time_ms} ms is above the limit of {limits.max_time_ms} ms")
    if instr.kind is Kind.PRESET:
        if instr.preset not in limits.presets:
            known = ", ".join(limits.presets)
            return f"unknown preset {instr.preset!r}; presets are {known}"
        return "; ".join(problems)
    if not instr.joints:
        problems.append("a move names no joint")
    ranges = limits.ranges
    seen: set[str] = set()
    for name, deg in instr.joints:
        r = ranges.get(name)
        if r is None:
            problems.append(f"unknown joint {name!r}; joints are {', '.join(ranges)}")
        elif name in seen:
            problems.append(f"{name} is given twice")
        elif not math.isfinite(deg):
            problems.append(f"{name}: {deg} is not a finite number of degrees")
        elif not r[0] <= deg <= r[1]:
            problems.append(f"{name}: {deg:g} deg is outside the range {r[0]:g}..{r[1]:g}")
        seen.add(name)
    return "; ".join(problems)
