"""The benchmark picture: one move per joint over time, and the latency histograms."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def draw(r: dict[str, Any], path: Path) -> None:
    fig, axes = plt.subplots(2, 3, figsize=(16, 9))
    ax = axes[0][0]
    traj = r["reach"]["worst_trajectory"]
    t = traj["t_ms"]
    for i, (name, (pulse, servo)) in enumerate(traj["joints"].items()):
        color = f"C{i}"
        ax.plot(t, pulse, color=color, linestyle="--", linewidth=1)
        ax.plot(t, servo, color=color, label=name)
    ax.set_title("worst-case move: commanded pulse (dashed) and emulated servo")
    ax.set_xlabel("ms after the command took effect")
    ax.set_ylabel("degrees")
    ax.legend(fontsize=8)

    def hist(ax: Any, samples: list[float], title: str, xlabel: str = "ms") -> None:
        ax.hist(samples, bins=60)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xlabel)

    hist(axes[0][1], r["ros_latency"]["samples_ms"], "ROS client -> server callback")
    hist(
        axes[0][2],
        r["c2b_9600"]["software"]["samples_ms"] + [],
        "command to board minus wire, 9600",
    )
    hist(
        axes[1][0], r["c2b_115200"]["software"]["samples_ms"], "command to board minus wire, 115200"
    )
    ax = axes[1][1]
    ax.hist(r["stop"]["service software"]["samples_ms"], bins=50, alpha=0.6, label="service")
    ax.hist(r["stop"]["topic software"]["samples_ms"], bins=50, alpha=0.6, label="topic")
    ax.set_title("emergency stop minus wire (1000 moves queued)", fontsize=10)
    ax.set_xlabel("ms")
    ax.legend()
    hist(
        axes[1][2],
        r["reach"]["margin"]["samples_ms"],
        "reach time minus (physics + wire), 200 moves",
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
