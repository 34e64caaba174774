"""What the owner's thread hands over so that it never runs anyone else's code: outcomes
to in-process futures, the listeners, and the log, told in order by a thread of their own.

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


class RefusalLog:
    """WARNING lines for refusals: each reason the first time in a second, then one line
    with how many more came with the same reason, whatever the order the reasons come in.
    A flood of ten thousand refused instructions a second, or a held stream of set-points
    sent again a hundred times a second, is a few lines a second; every refusal still has
    its outcome."""

    def __init__(self) -> None:
        # reason -> (when it was logged, how many came since)
        self._seen: dict[str, tuple[float, int]] = {}

    def refused(self, name: str, ident: str, reason: str, t: float) -> None:
        log.debug("EVENT: refused")
        self.flush(t)
        seen = self._seen.get(reason)
        if seen is None:
            log.warning("refused %s [%s]: %s", name, ident, reason)
            self._seen[reason] = (t, 0)
        else:
            self._seen[reason] = (seen[0], seen[1] + 1)

    def flush(self, t: float, every: bool = False) -> None:
        """Say the counts of the reasons whose second is over (all of them: `every`)."""
        for reason, (at, more) in list(self._seen.items()):
            if every or t - at >= REFUSAL_EVERY_S:
                del self._seen[reason]
                if more:
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
