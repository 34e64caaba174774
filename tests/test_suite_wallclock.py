"""How many of the suite's assertions depend on how fast the machine runs (issue 43: halve them).

A behaviour test that asserts a time measured on the wall clock passes or fails with the
host's load; timing belongs to `bench/` (against a floor measured in the same run), and
behaviour to virtual time (`al5d_rig.sim`) or to the order of events. This file counts
what is left, so that the count does not creep back.

What is counted, in each test function that does not drive `Sim` (whose clock is its own):
an `assert` holding an ordering comparison (`<`, `<=`, `>`, `>=`) one of whose sides reads
the clock (`time.monotonic()`, `time.perf_counter()`, `time.time()`), a name assigned from
such a reading in that function, a call to a function of the same file that returns one,
or a field the clock stamped (`elapsed_ms`, `t_effect`, `t_write`). A comparison with a
deadline (a name holding "deadline" or "until") is a bounded wait, not an assertion of a
time, and is not counted.
"""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent

#: Counted as above on the tree of 2026-11-28 (3e53671), when issue 43 was filed: 42.
AT_FILING = 42
LIMIT = AT_FILING // 2

CLOCKS = {"monotonic", "perf_counter", "time", "monotonic_ns", "perf_counter_ns"}
STAMPED = {"elapsed_ms", "t_effect", "t_write"}
ORDERING = (ast.Lt, ast.LtE, ast.Gt, ast.GtE)


def _names(node: ast.AST) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}


def _reads_clock(node: ast.AST) -> bool:
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr in CLOCKS
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == "time"
    )


class _Counter:
    def __init__(self, tree: ast.Module) -> None:
        self.timed_functions: set[str] = set()
        functions = [
            f for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
        ]
        for _ in range(2):  # a helper that calls a timed helper
            for f in functions:
                tainted = self._tainted(f)
                if any(
                    isinstance(r, ast.Return)
                    and r.value is not None
                    and self.timed(r.value, tainted)
                    for r in ast.walk(f)
                ):
                    self.timed_functions.add(f.name)
        self.functions = functions

    def timed(self, node: ast.AST, tainted: set[str]) -> bool:
        for n in ast.walk(node):
            if _reads_clock(n) or (isinstance(n, ast.Attribute) and n.attr in STAMPED):
                return True
            if (
                isinstance(n, ast.Call)
                and isinstance(n.func, ast.Name)
                and n.func.id in self.timed_functions
            ):
                return True
        return bool(_names(node) & tainted)

    def _tainted(self, function: ast.AST) -> set[str]:
        tainted: set[str] = set()
        for _ in range(3):  # names assigned from names assigned from the clock
            for st in ast.walk(function):
                assigns = isinstance(st, (ast.Assign, ast.AnnAssign, ast.AugAssign))
                if assigns and st.value and self.timed(st.value, tainted):
                    targets = st.targets if isinstance(st, ast.Assign) else [st.target]
                    tainted |= {n for t in targets for n in _names(t)}
        return tainted

    def assertions(self) -> list[tuple[int, str]]:
        found = []
        for f in self.functions:
            names = _names(f) | {a.arg for a in f.args.args}
            if {"sim", "Sim"} & names:
                continue  # virtual time
            tainted = self._tainted(f)
            for st in ast.walk(f):
                if isinstance(st, ast.Assert) and self._times(st.test, tainted):
                    found.append((st.lineno, ast.unparse(st.test)))
        return found

    def _times(self, test: ast.expr, tainted: set[str]) -> bool:
        for cmp in ast.walk(test):
            if not isinstance(cmp, ast.Compare) or not any(
                isinstance(o, ORDERING) for o in cmp.ops
            ):
                continue
            sides = [cmp.left, *cmp.comparators]
            waits = any("deadline" in n or "until" in n for s in sides for n in _names(s))
            if not waits and any(self.timed(s, tainted) for s in sides):
                return True
        return False


def wall_clock_assertions(source: str) -> list[tuple[int, str]]:
    """(line, assertion) of each wall-clock assertion in a test file's `source`."""
    return _Counter(ast.parse(source)).assertions()


def test_the_counter_counts_what_it_says() -> None:
    source = """
import time

def took_s(f):
    t0 = time.monotonic()
    f()
    return time.monotonic() - t0

def test_counted(rig):
    t0 = time.monotonic()
    outcome = rig.run()
    took = time.monotonic() - t0
    assert took < 1.0
    assert outcome.elapsed_ms >= 700
    assert took_s(rig.stop) <= 0.5
    assert rig.records[-1].t_effect - rig.records[0].t_effect > 0

def test_not_counted(rig):
    deadline = time.monotonic() + 10
    while not rig.done():
        assert time.monotonic() < deadline, "never done"
    assert rig.outcome.ok and len(rig.records) == 3

def test_in_virtual_time(sim):
    t0 = sim.t
    assert sim.outcome(1).elapsed_ms < 900 and sim.t - t0 < 1.0
"""
    found = [line for line, _ in wall_clock_assertions(source)]
    assert found == [13, 14, 15, 16], wall_clock_assertions(source)


def test_behaviour_tests_hold_at_most_half_the_wall_clock_assertions_they_held() -> None:
    found = [
        f"{path.name}:{line}: {text}"
        for path in sorted(TESTS.glob("test_*.py"))
        for line, text in wall_clock_assertions(path.read_text())
    ]
    print(f"{len(found)} wall-clock assertions (at most {LIMIT}):", *found, sep="\n")
    assert len(found) <= LIMIT, "\n".join(found)
