"""Measured quality of service per move: request to the arm at its target, against SA03's 2.3 s.

Shared by the demo (DE02) and the benchmarks. The owner reports each move as
it leaves for the board; the emulator's servo model says when every joint came
within the tolerance of its target, after the fact and exactly (no polling).
A motion instruction that never sent a move (refused, or cancelled while it
waited) has a row too, with its reason: what the arm was spared is part of what
the demo shows.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from dataclasses import dataclass

from al5d.arm.instruction import SAFETY, Instruction, Outcome, Result
from al5d.arm.jobs import Sent
from al5d.owner.loop import Owner
from al5d.ssc32u.emulator import Emulator, Record

SA03_BOUND_MS = 2300.0
TOLERANCE_DEG = 1.0
#: The instruction column is as wide as its longest text, up to this; a longer text
#: loses words from its middle (its name and its last words, such as `path=line`, stay).
LABEL_MAX = 72


@dataclass(frozen=True, slots=True)
class MoveQoS:
    """One move: what was asked, what was expected, what the emulated arm did."""

    id: str
    instruction: str
    requested_ms: int | None
    expected_ms: float
    reach_ms: float | None  # request -> every joint within TOLERANCE_DEG; None: never got there
    outcome: str
    #: Why it was refused or cancelled, for an instruction that sent no move.
    reason: str = ""

    @property
    def within_bound(self) -> bool | None:
        return None if self.reach_ms is None else self.reach_ms <= SA03_BOUND_MS


def board_record(emulator: Emulator, data: bytes, t_after: float) -> Record | None:
    """The emulator's record of the command `data` written at or after `t_after`: of its
    last line, the move's (a move after a stop first holds the joints whose pose was read
    back, in a line of its own)."""
    line = data.rstrip(b"\r").rsplit(b"\r", 1)[-1]
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
    """Listens to the owner of an emulated board and measures every move it sends."""

    def __init__(self, owner: Owner, emulator: Emulator, tol_deg: float = TOLERANCE_DEG) -> None:
        self.emulator = emulator
        self.tol_deg = tol_deg
        self._lock = threading.Lock()
        self._sent: list[Sent] = []
        self._outcomes: dict[str, Outcome] = {}
        #: Motion instructions by id: an outcome carries only the instruction's name, and a
        #: refused one sends nothing that would tell its text.
        self._submitted: dict[str, Instruction] = {}
        #: Every id once, when it was first submitted or sent (the start-up park is sent
        #: without being submitted): the table's order.
        self._order: dict[str, None] = {}
        owner.motion_listeners.append(self._on_sent)
        owner.outcome_listeners.append(self._on_outcome)
        owner.submit_listeners.append(self._on_submit)

    def _on_submit(self, instr: Instruction) -> None:
        if instr.kind not in SAFETY:
            with self._lock:
                self._submitted.setdefault(instr.id, instr)
                self._order.setdefault(instr.id)

    def _on_sent(self, sent: Sent) -> None:
        with self._lock:
            self._sent.append(sent)
            self._order.setdefault(sent.instr.id)

    def _on_outcome(self, outcome: Outcome) -> None:
        with self._lock:
            self._outcomes[outcome.id] = outcome

    def reach_time(self, sent: Sent) -> float | None:
        """Monotonic time at which the emulated arm reached this move's target (None: never)."""
        return reach_time(
            self.emulator, sent.data, sent.t_write, sent.motion.target.keys(), self.tol_deg
        )

    def rows(self) -> list[MoveQoS]:
        """One row per motion instruction, in the order they came: a straight line's group
        moves are one row, reached when its last one was; one that sent no move (refused,
        or cancelled while it waited) has its reason instead."""
        with self._lock:
            last: dict[str, Sent] = {}
            for sent in self._sent:
                last[sent.instr.id] = sent  # in order: the last group move of each wins
            outcomes = dict(self._outcomes)
            submitted = dict(self._submitted)
            order = list(self._order)
        rows = []
        for ident in order:
            outcome = outcomes.get(ident)
            s = last.get(ident)
            if s is None:
                if outcome is None or outcome.result is Result.DONE:
                    continue  # still waiting, or done without a move (nothing to measure)
                instr = submitted[ident]
                rows.append(
                    MoveQoS(
                        id=ident,
                        instruction=str(instr),
                        requested_ms=instr.time_ms,
                        expected_ms=0.0,
                        reach_ms=None,
                        outcome=outcome.result.value,
                        reason=outcome.reason,
                    )
                )
                continue
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


def label(text: str, width: int = LABEL_MAX) -> str:
    """`text` in at most `width` characters: whole, or its first word and its last (the
    instruction's name, and `path=`/`time=` when they end it) with middle words left out."""
    if len(text) <= width:
        return text
    words = text.split(" ")
    tail_n = 0
    while tail_n < len(words) - 1 and words[-1 - tail_n].startswith(("path=", "time=")):
        tail_n += 1
    head, tail = words[: len(words) - tail_n], words[len(words) - tail_n :]
    while len(head) > 1:
        head.pop()
        short = " ".join([*head, "...", *tail])
        if len(short) <= width:
            return short
    short = " ".join([*head, "...", *tail])
    return short if len(short) <= width else text[: width - 3] + "..."


def format_table(rows: list[MoveQoS]) -> str:
    """The QoS table: requested, expected, reached (from the request), and SA03."""
    columns = ("requested", "expected", "reached")
    width = max([len("instruction"), *(min(len(r.instruction), LABEL_MAX) for r in rows)])
    head = f"{'instruction':<{width}} " + " ".join(f"{c:>9}" for c in columns) + "  SA03 <= 2.3 s"
    lines = [head, "-" * len(head)]
    for r in rows:
        requested = f"{r.requested_ms} ms" if r.requested_ms else "-"
        reached = f"{r.reach_ms:.0f} ms" if r.reach_ms is not None else "-"
        expected = f"{r.expected_ms:>6.0f} ms" if r.expected_ms else f"{'-':>9}"
        if r.reason:
            verdict = f"{r.outcome}: {r.reason}"
        elif r.within_bound is None:
            verdict = f"n/a ({r.outcome})" if r.outcome != Result.DONE.value else "n/a"
        else:
            verdict = "held" if r.within_bound else "MISSED"
        text = label(r.instruction, width)
        lines.append(f"{text:<{width}} {requested:>9} {expected} {reached:>9}  {verdict}")
    reached_rows = [r for r in rows if r.reach_ms is not None]
    held = sum(1 for r in reached_rows if r.within_bound)
    refused = sum(1 for r in rows if r.outcome == Result.REFUSED.value)
    lines.append(
        f"{held} of {len(reached_rows)} moves that reached their target did so within 2.3 s "
        f"(tolerance {TOLERANCE_DEG:g} deg per joint, from the server receiving the instruction)"
        + (f"; {refused} refused whole, nothing sent" if refused else "")
    )
    return "\n".join(lines)
