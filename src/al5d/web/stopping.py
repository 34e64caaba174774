"""The page's STOP and RELEASE: each sent by the one way that reaches the server, its answer
matched and said, of the newest STOP or RELEASE only.

A STOP goes by the server's local lane where the server is on this machine (no discovery),
else on the instruction topic, sent again until one copy is answered; a RELEASE goes on
the topic after the page's own STOPs. What becomes of each is handed to the page
(`Listener.on_answer`) in a thread of its own, in order: a click waits for nothing.
"""

from __future__ import annotations

import itertools
import logging
import queue
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

from al5d.arm.instruction import Instruction, Kind, Outcome, Result, new_id
from al5d.owner import quick
from al5d.ros.convert import COPY_MARK

log = logging.getLogger("al5d.web")

#: How long a STOP by the local lane may take to be handed over (a socket whose owner has
#: not read its backlog), and how long its answer is waited for, in a thread of its own.
LANE_HAND_S = 0.05
LANE_STOP_S = 10.0
#: STOPs said unanswered that are kept for a late answer, at most (the newest).
LATE_KEPT = 64
#: A STOP on the topic (no lane of the server here) is sent again this often in its first
#: second, then every second, until a copy is answered or `LANE_STOP_S` has passed: a
#: server just found may not have matched this writer yet, and a lossy link loses copies.
STOP_FIRST_COPIES_S = 0.25
STOP_COPIES_S = 1.0
#: How long a RELEASE's answer is waited for before the page says none came.
RELEASE_ANSWER_S = 10.0

#: What the page says of a STOP or a RELEASE sent, until its answer comes.
AWAITED = "sent, the server's answer awaited"


def _answered(what: str, result: object, reason: object) -> str:
    """`what`'s answer (its result and reason), as the page says it."""
    return f"{what}: {result or 'an answer with no result'}{f': {reason}' if reason else ''}"


class StopRelease:
    """The page's STOPs and RELEASEs (`stop`, `release`) and what is said of them: their
    answers are found among the server's outcomes (`on_outcome`). Sent by `send`, the
    page's (on the instruction topic, with its lease: no deadline, so a stop is obeyed
    however late)."""

    def __init__(
        self, send: Callable[[Instruction], None], say: Callable[[str, bool | None], None]
    ) -> None:
        self._send = send
        self._tell = say
        #: The STOPs on the topic still sent again: each one's id, what its answer sets and
        #: its number (`_begin`).
        self._stops: dict[str, tuple[threading.Event, int]] = {}
        #: The STOPs said unanswered (by the lane or on the topic), with their numbers: an
        #: answer that comes on the result topic later (a server that stalled past
        #: `LANE_STOP_S` obeyed them after) is said then. Held with `_late_lock` while an
        #: answer is matched, or a STOP said unanswered, so that neither is said after the other.
        self._late: dict[str, int] = {}
        self._late_lock = threading.Lock()
        #: Held while a copy of a STOP or a RELEASE is published: no copy follows a release.
        self._sending = threading.Lock()
        #: The RELEASEs whose answers are awaited, with their numbers; each one's popped
        #: once: by its answer or by its timer (`RELEASE_ANSWER_S`).
        self._releases: dict[str, tuple[threading.Timer, int]] = {}
        # What the page says of its STOPs and RELEASEs goes through a queue to a thread of
        # its own: a STOP hands it over and waits for nothing (the page's widgets take
        # viser's locks), and it is said in the order it was handed over, of the newest
        # STOP or RELEASE only (an old one's late answer would hide the newer's).
        self._numbers = itertools.count(1)
        self._newest = 0
        self._numbering = threading.Lock()  # held for a number and its assignment alone
        self._answers: queue.SimpleQueue[tuple[int, str, bool | None] | None] = queue.SimpleQueue()
        threading.Thread(target=self._say_answers, name="al5d-web-answers", daemon=True).start()

    def stop(self, lane: Path) -> str:
        """The emergency stop: by the local lane `lane` where a server's is on this machine (no
        discovery, no DDS: the owner has it as the socket is read), else on the instruction
        topic, where the server's stop watcher obeys it at once. Only one way: a copy that
        came by the other after a release would lock the arm again (seen in a CI run: a
        STOPPED after the release). For the same reason there is no stop service call here
        (`std_srvs/Trigger` names no stop: the server cannot know it for this one): the
        copies sent again on the topic until one is answered name this page's lease and
        one stop (`<stop>~<n>`, `al5d.ros.convert.stop_key`), which the server obeys once,
        however many of them come, and before or after whichever release. Returns which
        way it went."""
        by_lane = f"web-stop-{new_id()}"
        try:
            # Handed over here (a Unix socket takes it at once); only its answer is waited
            # for, in a thread of its own.
            sock = quick.hand_stop(lane, by_lane, LANE_HAND_S)
        except OSError as e:
            log.warning("web: STOP by the local lane %s failed: %s", lane, e)
            sock = None
        number = self._begin()
        if sock is not None:
            self._say(number, f"STOP by the local lane: {AWAITED}", None)
            threading.Thread(
                target=self._lane_answer, args=(sock, by_lane, number), daemon=True
            ).start()
            return "the local lane"
        stop, answered = f"web-stop-{new_id()}", threading.Event()
        self._stops[stop] = answered, number
        # Handed over before the first copy goes, so that it is never said after the answer.
        self._say(number, f"STOP on the topic: {AWAITED} (sent again until it comes)", None)
        self._stop_copy(stop, 1)  # the first at once, in the click's own thread
        # Then the thread of the copies after it (starting one waits for it to run).
        threading.Thread(
            target=self._stop_again, args=(stop, answered, number), name=stop, daemon=True
        ).start()
        return "the topic"

    def _begin(self) -> int:
        """A new STOP or RELEASE: its number; what is said of those before it is not."""
        with self._numbering:
            number = self._newest = next(self._numbers)
        return number

    def _say(self, number: int, text: str, ok: bool | None) -> None:
        """Hand over what to say of the STOP or RELEASE `number` (a queue's put: no wait)."""
        self._answers.put((number, text, ok))

    def _say_answers(self) -> None:
        while (item := self._answers.get()) is not None:
            number, text, ok = item
            if number == self._newest:
                try:
                    self._tell(text, ok)
                except Exception:  # the next one is said all the same
                    log.exception("web: %s: not shown", text)

    def _stop_copy(self, stop: str, n: int) -> bool:
        """Copy `n` of `stop`, unless it has ended (answered, or a release sent since);
        whether it went."""
        with self._sending:
            if stop not in self._stops:
                return False
            self._send(Instruction(Kind.STOP, id=f"{stop}{COPY_MARK}{n}"))
        return True

    def _stop_again(self, stop: str, answered: threading.Event, number: int) -> None:
        """The copies of `stop` after the first, until one is answered, a release is sent,
        or `LANE_STOP_S` has passed."""
        start = time.monotonic()
        n = 1
        while True:
            elapsed = time.monotonic() - start
            every = STOP_FIRST_COPIES_S if elapsed < 1.0 else STOP_COPIES_S
            if answered.wait(every) or time.monotonic() - start >= LANE_STOP_S:
                break
            n += 1
            try:
                if not self._stop_copy(stop, n):
                    break
            except Exception:  # the next copy may go: only the context's end stops them
                log.exception("web: STOP on the topic: copy %d not sent", n)
        with self._late_lock:
            ended = self._stops.pop(stop, None) is not None
            if not ended or answered.is_set():
                return
            self._unanswered(
                stop,
                number,
                f"STOP on the topic: no answer in {LANE_STOP_S:g} s (sent {n} times): "
                "whether the arm has stopped is unknown",
            )

    def _unanswered(self, stop: str, number: int, text: str) -> None:
        """The STOP `stop` (number `number`) said unanswered, with `text`; its answer, if
        one comes later, said then (under `_late_lock`)."""
        log.warning("web: %s", text)
        self._late[stop] = number
        while len(self._late) > LATE_KEPT:
            del self._late[next(iter(self._late))]
        self._say(number, text, False)

    def _lane_answer(self, sock: socket.socket, stop: str, number: int) -> None:
        def unanswered() -> None:
            # As `al5d send stop` says it: a page that said only that the answer was awaited
            # for the whole 10 s hid a frozen server (an outside try).
            log.warning("web: STOP by the local lane: no answer in %g s", quick.UNANSWERED_S)
            self._say(
                number,
                f"STOP by the local lane: no answer in {quick.UNANSWERED_S:g} s (the server "
                f"busy or stalled); still waiting, up to {LANE_STOP_S - quick.UNANSWERED_S:.1f}"
                " s more: whether the arm has stopped is unknown",
                None,
            )

        try:
            answer = quick.answer(sock, LANE_STOP_S, unanswered)
        except (OSError, EOFError) as e:
            why = f"in {LANE_STOP_S:g} s" if isinstance(e, TimeoutError) else f"({e})"
            with self._late_lock:
                self._unanswered(
                    stop,
                    number,
                    f"STOP by the local lane: no answer {why}: whether the arm has stopped is "
                    "unknown",
                )
            return
        log.info("web: STOP by the local lane: %s", answer.get("result"))
        result = answer.get("result")
        self._say(
            number, _answered("STOP", result, answer.get("reason")), result == Result.DONE.value
        )

    def release(self) -> None:
        """On the topic with the page's lease, as the Python client's: judged on the server's
        clock, and after the page's own stops, which went before it on the same writer (the
        release service takes no lease, and is judged on its sender's clock). A STOP still
        sent again is not sent after it: a copy sent after the release, which the stop
        watcher may read before the node has read an earlier one (a lossy link), would be
        a stop sent after the release, and lock the arm again."""
        release, number = Instruction(Kind.RELEASE), self._begin()
        # Out of the lock a STOP's copy takes: starting a timer waits for its thread to run.
        timer = threading.Timer(RELEASE_ANSWER_S, self._release_unanswered, (release.id,))
        timer.daemon = True
        self._releases[release.id] = timer, number
        self._say(number, f"RELEASE on the topic: {AWAITED}", None)
        timer.start()
        try:
            with self._sending:
                for stop in list(self._stops):
                    unanswered = self._stops.pop(stop, None)
                    if unanswered is not None:
                        log.info("web: STOP on the topic: no more copies (a release was sent)")
                        unanswered[0].set()
                self._send(release)
        except Exception as e:
            if self._releases.pop(release.id, None) is not None:
                timer.cancel()
                self._say(number, f"RELEASE: not sent ({e})", False)
            raise

    def _release_unanswered(self, ident: str) -> None:
        releasing = self._releases.pop(ident, None)
        if releasing is not None:
            log.warning("web: RELEASE on the topic: no answer in %g s", RELEASE_ANSWER_S)
            self._say(
                releasing[1],
                f"RELEASE on the topic: no answer in {RELEASE_ANSWER_S:g} s: whether the arm "
                "was released is unknown (its state shows it)",
                False,
            )

    def on_outcome(self, outcome: Outcome) -> None:
        """The answer of a STOP or RELEASE of this page, if `outcome` is one: said."""
        stop, mark, _ = outcome.id.partition(COPY_MARK)
        done = outcome.result is Result.DONE
        with self._late_lock:
            stopping = self._stops.pop(stop, None) if mark else None
            late = self._late.pop(stop if mark else outcome.id, None)
            if stopping is not None:
                answered, number = stopping
                answered.set()
                log.info("web: STOP on the topic: %s", outcome.reason or outcome.result.value)
                self._say(number, _answered("STOP", outcome.result.value, outcome.reason), done)
            elif late is not None:
                log.info("web: STOP %s answered late: %s", stop, outcome.result.value)
                self._say(late, _answered("STOP", outcome.result.value, outcome.reason), done)
        releasing = self._releases.pop(outcome.id, None)
        if releasing is not None:
            timer, number = releasing
            timer.cancel()
            self._say(number, _answered("RELEASE", outcome.result.value, outcome.reason), done)

    def close(self) -> None:
        for timer, _ in list(self._releases.values()):
            timer.cancel()
        self._answers.put(None)
