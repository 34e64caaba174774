"""How many cases each fuzz suite ran: counted here, printed at the end of the run and
written to build/reliability/fuzz.json (see conftest's terminal summary)."""

from __future__ import annotations

import os
from collections import Counter

CASES: Counter[str] = Counter()
#: `make soak` runs the fuzz suites ten times longer (AL5D_FUZZ_SCALE=10).
SCALE = int(os.environ.get("AL5D_FUZZ_SCALE", "1"))


def examples(n: int) -> int:
    """How many cases a suite tries: `n` in `make test`, more in `make soak`."""
    return n * SCALE


def count(suite: str, n: int = 1) -> None:
    CASES[suite] += n
