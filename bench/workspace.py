"""Draw the AL5D's reachable workspace in its vertical plane, from our IK, into a PNG.

Run: .venv/bin/python bench/workspace.py OUT.png [--config FILE] [--step-mm 4]
One panel per gripper pitch, and one for the union over all pitches (a point is
in it when some pitch, in 5 deg steps, reaches it), each with the ready pose drawn.
The table (`geometry.table_height_mm`) is drawn too: what IK reaches under it,
or with the wrist or the elbow under it, is shaded apart, as move_to refuses it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap
from model_bench import SHIPPED, load_model

from al5d.model import ARM_JOINTS, ArmModel, Unreachable, below_table, joint_positions, solve

PITCHES = (-90.0, -45.0, 0.0, 45.0, 90.0)
#: What a point of the plane is: out of reach, reached only under the table, taken.
OUT, UNDER, TAKEN = 0, 1, 2
COLOURS = ListedColormap(["white", "#f2c6b6", "#74c476"])


def reachable(model: ArmModel, r: float, z: float, pitches: tuple[float, ...]) -> int:
    """Whether the tip reaches (r, z) in the plane straight ahead (base 0) with one of the
    pitches: TAKEN when move_to would take it (the arm above the table), UNDER when IK
    reaches it only with the tip, the wrist or the elbow under the table, else OUT."""
    found = OUT
    for pitch in pitches:
        try:
            sol = solve(model, r, 0.0, z, pitch)
        except Unreachable:
            continue
        if below_table(model, sol) is None:
            return TAKEN
        found = UNDER
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("out", type=Path)
    parser.add_argument("--config", type=Path, default=SHIPPED)
    parser.add_argument("--step-mm", type=float, default=4.0)
    args = parser.parse_args()
    model, presets = load_model(args.config)
    g = model.geometry
    extent = g.max_reach + g.gripper + 0.02
    step = args.step_mm / 1000
    rs = np.arange(-extent, extent + step / 2, step)
    zs = np.arange(-extent + g.base_height, extent + g.base_height + step / 2, step)

    panels: list[tuple[str, tuple[float, ...]]] = [(f"pitch {p:+.0f} deg", (p,)) for p in PITCHES]
    panels.append(("any pitch (5 deg steps)", tuple(float(p) for p in range(-180, 180, 5))))
    fig, axes = plt.subplots(2, 3, figsize=(15, 10), constrained_layout=True)
    ready = {j: float(presets["ready"][j]) for j in ARM_JOINTS} if "ready" in presets else None
    for ax, (title, pitches) in zip(axes.flat, panels, strict=True):
        mask = np.array([[reachable(model, r, z, pitches) for r in rs] for z in zs])
        ax.imshow(
            mask,
            origin="lower",
            extent=(rs[0] * 1000, rs[-1] * 1000, zs[0] * 1000, zs[-1] * 1000),
            cmap=COLOURS,
            vmin=OUT,
            vmax=TAKEN,
            interpolation="nearest",
        )
        table_mm = g.table_height * 1000
        ax.axhspan(zs[0] * 1000, table_mm, facecolor="none", hatch="//", edgecolor="tan", lw=0)
        ax.axhline(table_mm, color="saddlebrown", lw=1.5)
        ax.axvline(0.0, color="grey", lw=0.5, ls=":")
        if ready is not None:
            pts = joint_positions(g, ready)
            chain = [pts[k] for k in ("base", "shoulder", "elbow", "wrist", "tool0")]
            ax.plot([p[0] * 1000 for p in chain], [p[2] * 1000 for p in chain], "o-", color="k")
        area = (mask == TAKEN).sum() * args.step_mm**2 / 100
        ax.set_title(f"{title}: {area:.0f} cm² reachable")
        ax.set_xlabel("forward of the base axis, mm (base 0)")
        ax.set_ylabel("z in base_link, mm")
        ax.set_aspect("equal")
    fig.suptitle(
        "AL5D reachable tool-tip positions in the arm's plane (green; from al5d.model IK, "
        "ranges enforced); the ready pose in black.\nThe table hatched brown, at "
        f"z = {g.table_height * 1000:g} mm: pink is reached only with the tip, the wrist or "
        "the elbow under it (move_to refuses it)"
    )
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
