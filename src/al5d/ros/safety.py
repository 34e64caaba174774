"""The stop, release and shutdown services, and the stop watcher, each on a node and a
thread of its own.

An emergency stop must never queue behind instruction traffic: with one
executor, a stop request waited behind every message taken before it (seconds
under a flood of 10,000 instructions a second). Here the services have their
own node (`al5d_safety`), their own executor and their own thread; the
driver's stop is synchronous and takes microseconds, so each request is
answered as soon as it is taken.

A stop sent on the instruction topic travels with the flood, in the order it
was sent: behind whatever the server has not taken yet (up to its bounded
backlog in DDS, and then behind the sender's own retries when that is full:
0.2 to 3 s at 10,000 messages a second). So a node of its own reads the topic
itself, best effort and without waiting for anyone (the stop watcher), looks
at the first field of each message in its serialized form (no message is built
for anything but a stop), and stops the arm as soon as it sees a stop. The
node `al5d` reads the same stop later, in order; `FirstTaker` makes sure that
each stop is obeyed and answered once, by whichever reader saw it first. What
no reader here can see is a stop still queued in its sender (a client that
floods through the same publisher is slowed by back-pressure, stop included):
the stop service is the way for emergencies.
"""

from __future__ import annotations

import itertools
import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

from al5d_interfaces.msg import ArmInstruction
from rclpy.context import Context
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Instruction, Kind
from al5d.clock import now
from al5d.ros.convert import from_message
from al5d.ros.runtime import (
    QOS_SERVICES,
    QOS_WATCH,
    SAFETY_NODE,
    WATCHER_NODE,
    Names,
    waiting,
)

log = logging.getLogger("al5d")
#: Messages the watcher takes in one call, at most.
WATCH_BATCH = 1000

#: The word of a stop, as both readers compare it (after strip and lower).
_STOP = Kind.STOP.value
#: Longer than this, the first field is not a stop whatever its blanks: the node judges it.
_WORD_MAX = 256


def first_word(raw: bytes) -> str | None:
    """The `instruction` field of a serialized ArmInstruction (CDR: a 4-byte header, then the
    string's length and bytes with its NUL) as the node `al5d` reads it: cut at a NUL,
    stripped and lower-cased; None if it is longer than a stop could be, or the bytes
    are not such a message."""
    if len(raw) < 9 or raw[1] > 1:
        return None
    n = int.from_bytes(raw[4:8], "little" if raw[1] else "big")
    if not 0 < n <= _WORD_MAX or len(raw) < 8 + n:
        return None
    return raw[8 : 7 + n].split(b"\0", 1)[0].decode("utf-8", "replace").strip().lower()


class FirstTaker:
    """The two readers of stops on the topic (the node `al5d`'s, in order, and the watcher's,
    at once): each stop is obeyed by whichever sees it first, and answered once.

    A stop is known by its id. Each reader sees the stream in order, so the n-th stop
    of an id that one reader sees is the n-th that the other sees. What the watcher
    obeyed early, the node passes over when it gets there, unless the node has taken a
    release on the topic since the watcher obeyed it: that release came before the stop
    in the stream, so the node obeys the stop again (without a second outcome), and a
    stop is never undone by a release sent before it. Everything happens under one
    lock, so the node goes on to the next instruction only once an early stop is
    obeyed.

    The watcher may miss a stop (it reads best effort and keeps the last 1000
    messages): a stop the node obeyed is forgotten once the watcher, normally ahead,
    has not seen it for `late_s`, so that a later stop of the same id (clients that
    leave the id empty) is obeyed at once all the same. A stop the watcher obeyed
    waits `early_s` for the node, which lags behind a flood. Bounded to `limit` ids.

    The bounds are where "once" can fail: a watcher more than `late_s` behind the node
    (the node is normally the one behind), a node more than `early_s` behind the watcher,
    or more than `limit` stop ids in flight at once, would obey a stop twice, with two
    outcomes. None of them was seen in the floods of `make soak` (10,000 messages/s)."""

    def __init__(self, late_s: float = 1.0, early_s: float = 60.0, limit: int = 1024) -> None:
        self._lock = threading.Lock()
        #: Stops the watcher obeyed that the node has not reached: the node's count of
        #: releases then, and when.
        self._early: dict[str, deque[tuple[int, float]]] = {}
        #: Stops the node obeyed that the watcher has not seen: when.
        self._late: dict[str, deque[float]] = {}
        self._releases = 0
        self._late_s = late_s
        self._early_s = early_s
        self._limit = limit

    def watcher_saw(self, ident: str, obey: Callable[[], object]) -> None:
        with self._lock:
            t = now()
            if _take(self._late, ident, lambda at: at > t - self._late_s) is not None:
                return
            _put(self._early, ident, (self._releases, t), self._limit)
            obey()

    def node_saw(self, ident: str, obey: Callable[[], object], again: Callable[[], object]) -> None:
        with self._lock:
            t = now()
            early = _take(self._early, ident, lambda e: e[1] > t - self._early_s)
            if early is None:
                _put(self._late, ident, t, self._limit)
                obey()
            elif self._releases > early[0]:
                again()

    def node_released(self, release: Callable[[], object]) -> None:
        with self._lock:
            self._releases += 1
            release()


T = TypeVar("T")


def _take(table: dict[str, deque[T]], key: str, fresh: Callable[[T], bool]) -> T | None:
    """The oldest entry of `key` still fresh, taken out (the stale ones before it dropped)."""
    entries = table.get(key)
    found = None
    while entries and found is None:
        entry = entries.popleft()
        found = entry if fresh(entry) else None
    if entries is not None and not entries:
        del table[key]
    return found


def _put(table: dict[str, deque[T]], key: str, entry: T, limit: int) -> None:
    """Add an entry of `key`, forgetting the oldest key to make room."""
    if len(table) >= limit and key not in table:
        table.pop(next(iter(table)))
    table.setdefault(key, deque()).append(entry)


class SafetyNode(Node):
    """Node `al5d_safety`: `/al5d/stop`, `/al5d/release`, `/al5d/shutdown` (std_srvs/Trigger),
    under the server's namespace."""

    def __init__(self, driver: ArmDriver, context: Context, names: Names) -> None:
        super().__init__(SAFETY_NODE, namespace=names.node_namespace, context=context)
        self.driver = driver
        for name, kind in names.services.items():
            self.create_service(Trigger, name, self._trigger(kind), qos_profile=QOS_SERVICES)

    def _trigger(self, kind: Kind) -> Callable[[Any, Any], Any]:
        def answer(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            future = self.driver.submit(Instruction(kind))
            if future.done():
                outcome = future.result()
                response.success = outcome.ok
                response.message = outcome.reason or f"{kind.value}: {outcome.result.value}"
            else:  # shutdown: parking takes a while; the outcome follows on /al5d/result
                response.success = True
                response.message = "shutting down: parking, then the server ends"
            return response

        return answer


class StopWatcher(Node):
    """Node `al5d_stop_watcher`: reads the instruction topic beside the node `al5d` and obeys
    a stop as soon as it sees one. On a thread of its own: reading a flood takes it
    milliseconds at a time, which the stop service must never wait for (measured: with
    the two on one thread, a stop service call behind 1000 queued moves took 10 ms)."""

    def __init__(
        self, driver: ArmDriver, context: Context, names: Names, stops: FirstTaker
    ) -> None:
        super().__init__(WATCHER_NODE, namespace=names.node_namespace, context=context)
        self.driver = driver
        self.stops = stops
        self.presets = tuple(driver.config.presets)
        self._watcher = self.create_subscription(
            ArmInstruction, names.instruction, self._watch, QOS_WATCH, raw=True
        )

    def _watch(self, raw: bytes) -> None:
        """Every message on the instruction topic, serialized: a stop is obeyed at once.

        Called for one message; takes up to `WATCH_BATCH` more that wait, while it holds
        the GIL: under a flood the executor's thread gets the GIL a few thousand times a
        second at most, and one message each time would leave the watcher behind. A
        failure is logged and the watcher goes on; the node `al5d` still obeys every
        stop, in order."""
        try:
            for each in itertools.chain((raw,), waiting(self._watcher, WATCH_BATCH)):
                if first_word(each) == _STOP:
                    self._obey(each)
        except Exception:
            log.exception("the stop watcher failed on a message; the node still obeys stops")

    def _obey(self, raw: bytes) -> None:
        msg = deserialize_message(raw, ArmInstruction)
        instr = from_message(msg, self.presets, self.driver.config.model)
        # What the node `al5d` would refuse, it refuses (and answers) itself.
        if isinstance(instr, Instruction) and instr.kind is Kind.STOP:
            self.stops.watcher_saw(msg.id, lambda: self.driver.submit(instr))
