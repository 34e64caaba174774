"""What the owner's thread hands over so that it never runs anyone else's code: outcomes
to in-process futures, the listeners, and the log, told in order by a thread of their own;
and the state told, with waits for one (`StateTold`).

The owner's thread writes to the board and to its clients' sockets, and nothing else:
a listener that takes long (a ROS publisher, a test's check) or a log handler that
waits for a full terminal would otherwise hold up the next stop.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Iterable
from typing import TypeVar

from al5d.arm.states import State
from al5d.clock import now

log = logging.getLogger("al5d")
T = TypeVar("T")

#: A refusal's reason logged once a second at most; the rest are counted and said in one
#: line when the second is over.
REFUSAL_EVERY_S = 1.0


def tell(listeners: Iterable[Callable[[T], None]], value: T, what: str) -> None:
    """Hand `value` to every listener; one that raises is logged and the rest still hear it."""
    for listener in list(listeners):
        try:
            listener(value)
        except Exception:
            log.exception("%s listener %r failed; the owner goes on", what, listener)


class Repeats:
    """Which of a stream of reasons are news: each reason the first time in `every_s`,
    whatever the order the reasons come in, and how many of it came unsaid meanwhile.
    A reason not seen for `every_s` is forgotten: reasons that hold numbers do not pile up.
    Thread-safe (a node's reader and done callbacks both ask)."""

    def __init__(self, every_s: float = REFUSAL_EVERY_S) -> None:
        self.every_s = every_s
        self._lock = threading.Lock()
        # reason -> (when it was said, how many came since)
        self._seen: dict[str, tuple[float, int]] = {}

    def news(self, reason: str, t: float) -> int | None:
        """None when `reason` was said less than `every_s` ago (it is counted); else how many
        came unsaid since it was last said (0: none, or never said)."""
        with self._lock:
            seen = self._seen.get(reason)
            if seen is not None and t - seen[0] < self.every_s:
                self._seen[reason] = (seen[0], seen[1] + 1)
                return None
            self._seen[reason] = (t, 0)
            if len(self._seen) > 64:
                self._forget(t)
            return 0 if seen is None else seen[1]

    def over(
        self, t: float, every: bool = False, keep: str | None = None
    ) -> list[tuple[str, int, float]]:
        """The reasons whose `every_s` is over (all: `every`), but `keep`, forgotten, each
        with how many came unsaid and since when it was said; those with none are left out."""
        with self._lock:
            return self._forget(t, every, keep)

    def _forget(
        self, t: float, every: bool = False, keep: str | None = None
    ) -> list[tuple[str, int, float]]:
        done = [
            (r, n, at)
            for r, (at, n) in self._seen.items()
            if r != keep and (every or t - at >= self.every_s)
        ]
        for reason, _, _ in done:
            del self._seen[reason]
        return [(r, n, at) for r, n, at in done if n]


class RefusalLog:
    """WARNING lines for refusals: each reason once a second at most, whatever the order the
    reasons come in, with how many like it came unsaid since its last line; a reason that
    stops coming has its count said when its second is over. A flood of ten thousand
    refused instructions a second, or a held stream of set-points sent again a hundred
    times a second, is a line a second for each reason; every refusal still has its
    outcome."""

    def __init__(self) -> None:
        self._repeats = Repeats(REFUSAL_EVERY_S)

    def refused(self, name: str, ident: str, reason: str, t: float) -> None:
        log.debug("EVENT: refused")
        self.flush(t, keep=reason)
        more = self._repeats.news(reason, t)
        if more is None:
            return
        if more:
            log.warning("refused %s [%s] and %d more like it: %s", name, ident, more, reason)
        else:
            log.warning("refused %s [%s]: %s", name, ident, reason)

    def flush(self, t: float, every: bool = False, keep: str | None = None) -> None:
        """Say the counts of the reasons whose second is over (all of them: `every`), but
        `keep`'s, which its next line says."""
        for reason, more, at in self._repeats.over(t, every, keep):
            log.warning("refused %d more in %.0f s: %s", more, max(1.0, t - at), reason)


class Teller:
    """One thread that runs what it is handed, in order."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue[Callable[[], object] | None] = queue.SimpleQueue()
        self.refusals = RefusalLog()
        self._thread = threading.Thread(target=self._run, name="al5d-teller", daemon=True)
        self._thread.start()

    def put(self, job: Callable[[], object]) -> None:
        self._jobs.put(job)

    def _run(self) -> None:
        while True:
            try:
                job = self._jobs.get(timeout=REFUSAL_EVERY_S)
            except queue.Empty:
                self.refusals.flush(now())
                continue
            if job is None:
                self.refusals.flush(now(), every=True)
                return
            try:
                job()
            except Exception:
                log.exception("the owner's teller: a job failed; it goes on")

    def close(self, timeout: float = 5.0) -> None:
        """Tell what is left, then end."""
        self._jobs.put(None)
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)


class StateTold:
    """The arm's state as last told, and waits for one: a waiter for a state told and left
    again before its thread ran (a reset's fault, then locked; a stop, then another's
    release) sees that it came. (A wait that looked only at the state of the moment timed
    out on a busy host.)"""

    def __init__(self, state: State) -> None:
        self.state = state
        self._cv = threading.Condition()
        #: How often each state has been told, for the waits.
        self._entered: dict[State, int] = {}

    def told(self, state: State) -> None:
        with self._cv:
            if state is not self.state:
                self._entered[state] = self._entered.get(state, 0) + 1
            self.state = state
            self._cv.notify_all()

    def wait(self, state: State, timeout: float) -> bool:
        """Until `state` is the state told, or has been told since the call though left
        again; False if neither within `timeout` seconds."""
        with self._cv:
            before = self._entered.get(state, 0)

            def came() -> bool:
                return self.state is state or self._entered.get(state, 0) > before

            return self._cv.wait_for(came, timeout)
