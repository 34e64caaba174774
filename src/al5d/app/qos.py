"""Measured quality of service per move: request to the arm at its target, against SA03's 2.3 s.

Shared by the demo (DE02) and the benchmarks. The driver reports each move as
it leaves for the board; the emulator's servo model says when every joint came
within the tolerance of its target, after the fact and exactly (no polling).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from dataclasses import dataclass

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Outcome, Result
from al5d.arm.jobs import Sent
from al5d.ssc32u.emulator import Emulator, Record

SA03_BOUND_MS = 2300.0
TOLERANCE_DEG = 1.0


@dataclass(frozen=True, slots=True)
class MoveQoS:
    """One move: what was asked, what was expected, what the emulated arm did."""

    id: str
    instruction: str
    requested_ms: int | None
    expected_ms: float
    reach_ms: float | None  # request -> every joint within TOLERANCE_DEG; None: never got there
    outcome: str

    @property
    def within_bound(self) -> bool | None:
        return None if self.reach_ms is None else self.reach_ms <= SA03_BOUND_MS


def board_record(emulator: Emulator, data: bytes, t_after: float) -> Record | None:
    """The emulator's record of the command `data` written at or after `t_after`."""
    line = data.rstrip(b"\r")
    return next((r for r in emulator.records if r.raw == line and r.t_effect >= t_after), None)


def reach_time(
    emulator: Emulator,
    data: bytes,
    t_after: float,
    joints: Iterable[str],
    tol_deg: float = TOLERANCE_DEG,
) -> float | None:
    """When every joint of the move `data` was within `tol_deg` of its target (None: never)."""
    record = board_record(emulator, data, t_after)
    if record is None:
        return None
    return emulator.reach_time(record.t_effect, tol_deg, joints)


class QoSRecorder:
    """Listens to a driver running on an emulator and measures every move it sends."""

    def __init__(
        self, driver: ArmDriver, emulator: Emulator, tol_deg: float = TOLERANCE_DEG
    ) -> None:
        self.emulator = emulator
        self.tol_deg = tol_deg
        self._lock = threading.Lock()
        self._sent: list[Sent] = []
        self._outcomes: dict[str, Outcome] = {}
        driver.motion_listeners.append(self._on_sent)
        driver.outcome_listeners.append(self._on_outcome)

    def _on_sent(self, sent: Sent) -> None:
        with self._lock:
            self._sent.append(sent)

    def _on_outcome(self, outcome: Outcome) -> None:
        with self._lock:
            self._outcomes[outcome.id] = outcome

    def reach_time(self, sent: Sent) -> float | None:
        """Monotonic time at which the emulated arm reached this move's target (None: never)."""
        return reach_time(
            self.emulator, sent.data, sent.t_write, sent.motion.target.keys(), self.tol_deg
        )

    def rows(self) -> list[MoveQoS]:
        """One row per instruction: a straight line's group moves are one row, reached
        when its last one was."""
        with self._lock:
            last: dict[str, Sent] = {}
            for sent in self._sent:
                last[sent.instr.id] = sent  # in order: the last group move of each wins
            outcomes = dict(self._outcomes)
        rows = []
        for s in last.values():
            outcome = outcomes.get(s.instr.id)
            reached = self.reach_time(s)
            rows.append(
                MoveQoS(
                    id=s.instr.id,
                    instruction=str(s.instr),
                    requested_ms=s.instr.time_ms,
                    expected_ms=outcome.expected_ms if outcome else s.motion.duration_s * 1000,
                    reach_ms=None if reached is None else (reached - s.t_submit) * 1000,
                    outcome=outcome.result.value if outcome else "running",
                )
            )
        return rows


def format_table(rows: list[MoveQoS]) -> str:
    """The QoS table: requested, expected, reached (from the request), and SA03."""
    columns = ("requested", "expected", "reached")
    head = f"{'instruction':<44} " + " ".join(f"{c:>9}" for c in columns) + "  SA03 <= 2.3 s"
    lines = [head, "-" * len(head)]
    for r in rows:
        requested = f"{r.requested_ms} ms" if r.requested_ms else "-"
        reached = f"{r.reach_ms:.0f} ms" if r.reach_ms is not None else "-"
        if r.within_bound is None:
            verdict = f"n/a ({r.outcome})" if r.outcome != Result.DONE.value else "n/a"
        else:
            verdict = "held" if r.within_bound else "MISSED"
        text = r.instruction if len(r.instruction) <= 44 else r.instruction[:41] + "..."
        lines.append(
            f"{text:<44} {requested:>9} {r.expected_ms:>6.0f} ms {reached:>9}  {verdict:<14}"
        )
    reached_rows = [r for r in rows if r.reach_ms is not None]
    held = sum(1 for r in reached_rows if r.within_bound)
    lines.append(
        f"{held} of {len(reached_rows)} moves that reached their target did so within 2.3 s "
        f"(tolerance {TOLERANCE_DEG:g} deg per joint, from the server receiving the instruction)"
    )
    return "\n".join(lines)
