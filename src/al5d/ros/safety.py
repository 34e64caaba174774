"""The stop, release and shutdown services, and the stop watcher, on a node and a thread of
their own.

An emergency stop must never queue behind instruction traffic: with one
executor, a stop request waited behind every message taken before it (seconds
under a flood of 10,000 instructions a second). Here the services have their
own node (`al5d_safety`), their own executor and their own thread; the
driver's stop is synchronous and takes microseconds, so each request is
answered as soon as it is taken.

A stop sent on the instruction topic travels with the flood, in the order it
was sent: behind whatever the server has not taken yet (up to its bounded
backlog in DDS, and then behind the sender's own retries when that is full:
0.2 to 3 s at 10,000 messages a second). So this node also reads the topic
itself, best effort and without waiting for anyone (the stop watcher), looks
at the first field of each message in its serialized form (no message is built
for anything but a stop), and stops the arm as soon as it sees a stop. The
node `al5d` reads the same stop later, in order; `FirstTaker` makes sure that
each stop is obeyed and answered once, by whichever reader saw it first.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from al5d_interfaces.msg import ArmInstruction
from rclpy.context import Context
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Instruction, Kind
from al5d.ros.convert import from_message
from al5d.ros.runtime import QOS_SERVICES, QOS_WATCH, SAFETY_NODE, Names

#: The serialized word of a stop, as the watcher compares it (after strip and lower).
_STOP = Kind.STOP.value.encode("ascii")


def first_word(raw: bytes) -> bytes | None:
    """The `instruction` field of a serialized ArmInstruction (CDR: a 4-byte header, then the
    string's length and bytes with its NUL), stripped and lower-cased; None if it is
    longer than a stop could be, or the bytes are not such a message."""
    if len(raw) < 9 or raw[1] > 1:
        return None
    n = int.from_bytes(raw[4:8], "little" if raw[1] else "big")
    if not 0 < n <= 64 or len(raw) < 8 + n:
        return None
    return raw[8 : 7 + n].strip().lower()


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
    obeyed. Bounded: a sender that repeats one id, or stops the watcher missed (it
    keeps the last 1000 messages), never grow it beyond `limit` ids."""

    def __init__(self, limit: int = 1024) -> None:
        self._lock = threading.Lock()
        #: Stops the watcher obeyed that the node has not reached: the node's count of
        #: releases when each was obeyed.
        self._early: dict[str, deque[int]] = {}
        #: Stops the node obeyed that the watcher has not seen (or never will).
        self._late: Counter[str] = Counter()
        self._releases = 0
        self._limit = limit

    def watcher_saw(self, ident: str, obey: Callable[[], object]) -> None:
        with self._lock:
            if self._late[ident] > 0:
                self._late[ident] -= 1
                return
            _bound(self._early, ident, self._limit)
            self._early.setdefault(ident, deque()).append(self._releases)
            obey()

    def node_saw(self, ident: str, obey: Callable[[], object], again: Callable[[], object]) -> None:
        with self._lock:
            early = self._early.get(ident)
            if not early:
                _bound(self._late, ident, self._limit)
                self._late[ident] += 1
                obey()
                return
            releases_then = early.popleft()
            if not early:
                del self._early[ident]
            if self._releases > releases_then:
                again()

    def node_released(self, release: Callable[[], object]) -> None:
        with self._lock:
            self._releases += 1
            release()


def _bound(table: dict[str, Any], key: str, limit: int) -> None:
    """Make room for `key` in `table` by forgetting its oldest key."""
    if len(table) >= limit and key not in table:
        table.pop(next(iter(table)))


class SafetyNode(Node):
    """Node `al5d_safety`: `/al5d/stop`, `/al5d/release`, `/al5d/shutdown` (std_srvs/Trigger),
    under the server's namespace."""

    def __init__(
        self, driver: ArmDriver, context: Context, names: Names, stops: FirstTaker
    ) -> None:
        super().__init__(SAFETY_NODE, namespace=names.node_namespace, context=context)
        self.driver = driver
        self.stops = stops
        self.presets = tuple(driver.config.presets)
        for name, kind in names.services.items():
            self.create_service(Trigger, name, self._trigger(kind), qos_profile=QOS_SERVICES)
        self._watcher = self.create_subscription(
            ArmInstruction, names.instruction, self._watch, QOS_WATCH, raw=True
        )

    def _watch(self, raw: bytes) -> None:
        """Every message on the instruction topic, serialized: a stop is obeyed at once.

        Called for one message; takes every other one waiting too, while it holds the
        GIL: under a flood the executor's thread gets the GIL a few thousand times a
        second at most, and one message each time would leave the watcher behind."""
        handle = self._watcher.handle
        with handle:
            while True:
                if first_word(raw) == _STOP:
                    self._obey(raw)
                taken = handle.take_message(ArmInstruction, True)
                if taken is None:
                    return
                raw = taken[0]

    def _obey(self, raw: bytes) -> None:
        msg = deserialize_message(raw, ArmInstruction)
        instr = from_message(msg, self.presets, self.driver.config.model)
        # What the node `al5d` would refuse, it refuses (and answers) itself.
        if isinstance(instr, Instruction):
            self.stops.watcher_saw(msg.id, lambda: self.driver.submit(instr))

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
