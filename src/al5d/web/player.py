"""The player of the Teach tab: a sequence's steps sent one after the other, each waited for.

A play sends each step as any instruction (the server judges each move whole before a
byte) and waits for its outcome before the next, as `al5d run` does; it ends at the
first step not done, when the server is lost, and at STOP, which stops the arm. No
viser and no ROS: the tab gives it how to send, whether the server is lost, and where
to say how the play goes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from al5d.arm.instruction import Instruction, Outcome, SequenceStep, Wait

#: How often a step's wait for its outcome looks whether the play was halted.
POLL_S = 0.1


class Player:
    """Plays steps one after the other in a thread of its own: a wait waits, an instruction
    is sent and its outcome waited for (a step ending in `&` is not waited for, but its
    outcome counts at the next step). It ends at the first outcome not done, once `lost`,
    or at `halt`."""

    def __init__(
        self,
        send: Callable[[Instruction], bool],
        lost: Callable[[], bool],
        show: Callable[[str, bool | None], None],
    ) -> None:
        self._send = send
        self._lost = lost
        self._show = show
        self._cv = threading.Condition()
        #: The ids this play sent, and the outcomes of those that came.
        self._sent: set[str] = set()
        self._outcomes: dict[str, Outcome] = {}
        self._halted = threading.Event()
        self._why = ""
        self._thread: threading.Thread | None = None

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, steps: Sequence[tuple[str, SequenceStep]]) -> bool:
        """Play `steps` (each with the line it was read from); False if a play is on."""
        with self._cv:
            if self.busy:
                return False
            self._halted.clear()
            self._sent.clear()
            self._outcomes.clear()
            self._thread = threading.Thread(
                target=self._play, args=(tuple(steps),), name="al5d-web-play", daemon=True
            )
            self._thread.start()
        return True

    def halt(self, why: str) -> None:
        """End the play: nothing more is sent (the caller stops the arm)."""
        if self.busy:
            self._why = why
            self._halted.set()
            with self._cv:
                self._cv.notify_all()

    def on_outcome(self, outcome: Outcome) -> None:
        with self._cv:
            if outcome.id in self._sent:  # every client's outcomes come by
                self._outcomes[outcome.id] = outcome
                self._cv.notify_all()

    def join(self, timeout: float) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def _play(self, steps: tuple[tuple[str, SequenceStep], ...]) -> None:
        n = len(steps)
        behind: list[tuple[int, str, str]] = []  # steps run in the background: k, line, id
        for k, (line, (item, background)) in enumerate(steps, start=1):
            if self._ended(behind, n):
                return
            self._show(f"playing step {k} of {n}: {line} (STOP ends the play)", None)
            if isinstance(item, Wait):
                self._halted.wait(item.ms / 1000)
                continue
            with self._cv:
                self._sent.add(item.id)
            if not self._send(item):  # the page has no server to send it to this moment
                self._show(f"play ended at step {k} of {n}: no contact with the server", False)
                return
            if background:
                behind.append((k, line, item.id))
            elif not self._done(k, n, line, self._outcome(item.id)):
                return
        for k, line, ident in behind:
            if not self._done(k, n, line, self._outcome(ident)):
                return
        if not self._ended([], n):
            self._show(f"played {n} step{'s' if n != 1 else ''}: every one done", True)

    def _outcome(self, ident: str) -> Outcome | None:
        """The outcome of `ident`; None once the play is halted or the server lost."""
        with self._cv:
            while ident not in self._outcomes:
                if self._halted.is_set() or self._lost():
                    return None
                self._cv.wait(POLL_S)
            return self._outcomes[ident]

    def _done(self, k: int, n: int, line: str, outcome: Outcome | None) -> bool:
        """Whether the play goes on after step `k`'s outcome (None: halted or lost)."""
        if outcome is None:
            return not self._ended([], n, k)
        if outcome.ok:
            return True
        reason = f": {outcome.reason}" if outcome.reason else ""
        self._show(f"play ended at step {k} of {n}: {line}: {outcome.result.value}{reason}", False)
        return False

    def _ended(self, behind: list[tuple[int, str, str]], n: int, k: int = 0) -> bool:
        """Whether the play must end now (halted, the server lost, or a step in the
        background not done), said if so."""
        at = f" at step {k} of {n}" if k else ""
        if self._halted.is_set():
            self._show(f"play ended{at} by {self._why}: nothing more sent", False)
            return True
        if self._lost():
            self._show(f"play ended{at}: no contact with the server; nothing more sent", False)
            return True
        with self._cv:
            failed = [(j, line, self._outcomes[i]) for j, line, i in behind if i in self._outcomes]
        return any(not self._done(j, n, line, outcome) for j, line, outcome in failed)
