"""Figures of the robot model: IK time, FK/IK round-trip error, straight-line plans.

Run: .venv/bin/python bench/model_bench.py [--config FILE]. It reads the joint
ranges, presets and calibrations from the arm's YAML (the shipped one by
default) and uses al5d.model (and the driver's pulse scale, for the lines as the
server plans them: judged on whole microseconds).
"""

from __future__ import annotations

import argparse
import itertools
import math
import platform
import random
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from al5d.arm.cartesian import LINE_TOLERANCE_M, pulse_scale
from al5d.arm.config import DEFAULT_CONFIG as SHIPPED
from al5d.arm.config import load_config
from al5d.arm.translate import Translator
from al5d.model import (
    ARM_JOINTS,
    ArmModel,
    PulseScale,
    Unreachable,
    as_sent,
    forward,
    plan_line,
    segment_deviation,
    solve,
)
from al5d.model.transforms import Vec3

SOLVES = 20000
WARMUP = 2000
TOL_M = 0.001


def load_model(path: Path) -> tuple[ArmModel, dict[str, dict[str, float]]]:
    """The model and presets of an arm's configuration file, as the server reads it."""
    config = load_config(path)
    return config.model, {k: dict(v) for k, v in config.presets.items()}


def random_pose(model: ArmModel, rng: random.Random) -> dict[str, float]:
    return {j: rng.uniform(model.ranges.of(j).lo, model.ranges.of(j).hi) for j in ARM_JOINTS}


def ik_timing(model: ArmModel) -> tuple[float, float]:
    """p50 and p99 (ms) of one solve, over random reachable targets (FK of random poses)."""
    rng = random.Random(1)
    targets = []
    for _ in range(SOLVES + WARMUP):
        pose = forward(model.geometry, random_pose(model, rng))
        targets.append((*pose.position, pose.pitch_deg, pose.roll_deg))
    clock = time.perf_counter_ns
    samples = []
    for i, (x, y, z, pitch, roll) in enumerate(targets):
        t0 = clock()
        solve(model, x, y, z, pitch, roll)
        t1 = clock()
        if i >= WARMUP:
            samples.append((t1 - t0) / 1e6)
    q = np.percentile(samples, [50, 99])
    return float(q[0]), float(q[1])


def round_trip_joint_grid(model: ArmModel) -> tuple[int, float]:
    """Max tip error (mm) of IK(FK(q)) over a grid of every joint range, limits included."""
    axes = [
        np.linspace(model.ranges.of(j).lo, model.ranges.of(j).hi, n)
        for j, n in zip(ARM_JOINTS, (9, 25, 28, 19, 3), strict=True)
    ]
    worst = 0.0
    count = 0
    for combo in itertools.product(*axes):
        pose = dict(zip(ARM_JOINTS, map(float, combo), strict=True))
        target = forward(model.geometry, pose)
        back = forward(model.geometry, solve(model, *target.position, target.pitch_deg))
        worst = max(worst, math.dist(back.position, target.position))
        count += 1
    return count, worst * 1000


def round_trip_cartesian_grid(model: ArmModel) -> tuple[int, int, float]:
    """(points, solved, max error mm) over a 10 mm grid in x, y, z and 15 deg of pitch."""
    worst, points, solved = 0.0, 0, 0
    xs = np.arange(-0.20, 0.55, 0.01)
    ys = np.arange(0.0, 0.45, 0.01)  # the workspace is symmetric in y
    zs = np.arange(-0.25, 0.55, 0.01)
    for x, y, z in itertools.product(xs, ys, zs):
        for pitch in range(-90, 91, 15):
            points += 1
            try:
                sol = solve(model, float(x), float(y), float(z), float(pitch))
            except Unreachable:
                continue
            solved += 1
            worst = max(worst, math.dist(forward(model.geometry, sol).position, (x, y, z)))
    return points, solved, worst * 1000


def uniform_hops(model: ArmModel, start: Mapping[str, float], plan: Any) -> int:
    """Fewest equal hops along the line that hold the tolerance (the best fixed split)."""
    p0, p1 = plan.start, plan.end
    (a0, a1), (r0, r1) = plan.pitch_deg, plan.roll_deg
    for n in range(1, 400):
        stops: list[Mapping[str, float]] = [start]
        for i in range(1, n + 1):
            t = i / n
            p = [u + t * (v - u) for u, v in zip(p0, p1, strict=True)]
            stops.append(solve(model, p[0], p[1], p[2], a0 + t * (a1 - a0), r0 + t * (r1 - r0)))
        if all(
            segment_deviation(model.geometry, a, b, p0, p1, 400) <= TOL_M
            for a, b in itertools.pairwise(stops)
        ):
            return n
    return -1


def line_moves(
    model: ArmModel, presets: Mapping[str, Mapping[str, float]], pulses: PulseScale
) -> list[str]:
    """Plans from ready at 1 mm on exact angles (against the best uniform split and a fixed
    step), and as the server plans them (LINE_TOLERANCE_M, judged on whole microseconds)."""
    ready = {j: float(presets["ready"][j]) for j in ARM_JOINTS}
    moves: list[tuple[str, Vec3, float | None]] = [
        ("ready -> left, low", (0.20, 0.15, 0.05), -30.0),
        ("ready -> right, higher, roll 45", (0.15, -0.20, 0.15), -30.0),
        ("ready -> up and level", (0.30, 0.00, 0.20), 0.0),
        ("ready -> down onto the table", (0.15, 0.00, 0.02), -90.0),
        ("ready -> far left, near the base", (0.05, 0.30, 0.10), -30.0),
        ("ready -> left, far and low", (0.10, 0.25, 0.05), -30.0),
    ]
    lines = [
        f"{'move':34} {'length':>8} {'hops':>5} {'best uniform':>12} {'5 mm steps':>10} "
        f"{'max dev':>9} {'plan time':>9} | {'server hops':>11} {'on the wire':>11}"
    ]
    for name, target, pitch in moves:
        roll = 45.0 if "roll" in name else None
        t0 = time.perf_counter()
        plan = plan_line(model, ready, target, pitch, roll, tolerance_m=TOL_M)
        elapsed = (time.perf_counter() - t0) * 1000
        stops = [ready, *plan.waypoints]
        dev = max(
            segment_deviation(model.geometry, a, b, plan.start, plan.end, 2000)
            for a, b in itertools.pairwise(stops)
        )
        served = plan_line(
            model, ready, target, pitch, roll, tolerance_m=LINE_TOLERANCE_M, pulses=pulses
        )
        sent = [as_sent(q, pulses) for q in (ready, *served.waypoints)]
        wire = max(
            segment_deviation(model.geometry, a, b, served.start, served.end, 2000)
            for a, b in itertools.pairwise(sent)
        )
        length = math.dist(plan.start, plan.end) * 1000
        lines.append(
            f"{name:34} {length:6.0f}mm {len(plan.waypoints):5d} "
            f"{uniform_hops(model, ready, plan):12d} {math.ceil(length / 5):10d} "
            f"{dev * 1000:7.4f}mm {elapsed:7.1f}ms | {len(served.waypoints):11d} "
            f"{wire * 1000:9.4f}mm"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", type=Path, default=SHIPPED)
    args = parser.parse_args()
    model, presets = load_model(args.config)
    pulses = pulse_scale(Translator(load_config(args.config)))

    p50, p99 = ik_timing(model)
    print(f"IK solve, {SOLVES} random reachable targets: p50 {p50:.4f} ms, p99 {p99:.4f} ms")
    n, err = round_trip_joint_grid(model)
    print(f"FK -> IK -> FK, joint grid of {n} poses over every range: max error {err:.2e} mm")
    points, solved, err = round_trip_cartesian_grid(model)
    print(
        f"IK -> FK, 10 mm x 15 deg Cartesian grid: {solved} of {points} targets reachable, "
        f"max error {err:.2e} mm"
    )
    print(
        f"Straight lines from ready, tolerance {TOL_M * 1000:g} mm (max dev: 2000 samples/hop); "
        f"as the server plans them, {LINE_TOLERANCE_M * 1000:g} mm on whole microseconds:"
    )
    for line in line_moves(model, presets, pulses):
        print("  " + line)
    print(f"(CPython {platform.python_version()}, {platform.machine()})")


if __name__ == "__main__":
    main()
