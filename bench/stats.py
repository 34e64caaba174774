"""Percentiles and the shape of one benchmark figure."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def summary(samples_ms: Sequence[float]) -> dict[str, Any]:
    a = np.asarray(samples_ms, dtype=float)
    return {
        "n": int(a.size),
        "p50_ms": float(np.percentile(a, 50)),
        "p90_ms": float(np.percentile(a, 90)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "mean_ms": float(a.mean()),
    }


def figure(name: str, samples_ms: Sequence[float], **extra: Any) -> dict[str, Any]:
    return {
        "name": name,
        **summary(samples_ms),
        "samples_ms": [float(x) for x in samples_ms],
        **extra,
    }
