"""The stop, release and shutdown services, and the stop watcher: the ROS side's safety nodes.

An emergency stop must never queue behind instruction traffic: with one executor, a stop
request waited behind every message taken before it (seconds under a flood of 10,000
instructions a second). Here the services have their own nodes, executors and threads,
and each request is handed to the owner at once (the owner writes a stop before
anything else it has waiting) and answered when the owner has obeyed it. Each request
carries when it was sent (its source timestamp), on which the owner orders a release
against the stops (`al5d.arm.core`, rule 1).

A stop sent on the instruction topic travels with the flood, in the order it was sent:
behind whatever the bridge has not taken yet (up to its bounded backlog in DDS, and
then behind the sender's own retries when that is full). So a node of its own reads
the topic itself, best effort and without waiting for anyone (the stop watcher), looks
at the first field of each message in its serialized form (no message is built for
anything but a stop), and stops the arm as soon as it sees a stop. DDS hands it only
messages that could be a stop (`STOP_FILTER`, a content filter that Fast DDS applies
before Python sees anything): a flood's moves never queue in it. The node `al5d` reads
the same stop later, in order; both submit it with the message's identity, and the
owner obeys and answers it once (rule 3). What no reader here can see is a stop still
queued in its sender (a client that floods through the same publisher is slowed by
back-pressure, stop included): the stop service is the way for emergencies, or a
writer of the stop's own (the Python client's: `al5d.ros.rosway`).

The stop service and the watcher are the node `al5d_stop` (`StopNode`), in a process of
its own (`al5d.ros.stopproc`) at the stop path's priority: in the bridge, its thread
would wait for the interpreter lock behind the flood's. The release and shutdown
services are the node `al5d_safety` (`SafetyNode`), in the bridge on a DDS participant
of its own.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

from al5d_interfaces.msg import ArmInstruction, ClientLease
from rclpy.context import Context
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from al5d.arm.instruction import Instruction, Kind
from al5d.owner.client import LaneClosed, Remote
from al5d.ros.convert import came_ns, from_message, sent_ns, stop_key, stop_time
from al5d.ros.leases import Leases
from al5d.ros.names import SAFETY_NODE, STOP_NODE, Names, pinned
from al5d.ros.qos import QOS_LEASES, QOS_SERVICES, qos_watch
from al5d.ros.workarounds import (
    Reader,
    ReaderOnly,
    filter_content,
    stamped_service,
    taken_by_reader,
)

log = logging.getLogger("al5d")
#: Messages the watcher takes in one call, at most.
WATCH_BATCH = 1000
#: How long a service waits for the owner's answer.
ANSWER_S = 5.0
#: A shutdown is answered at once (the park's outcome follows on the result topic): only a
#: refusal (one under way already) is waited for, this long.
SHUTDOWN_REFUSAL_S = 0.05
PARKING = "shutting down: parking, then the server ends"

#: The word of a stop, as both readers compare it (after strip and lower).
_STOP = Kind.STOP.value
#: Longer than this, the first field is not a stop whatever its blanks: the node judges it.
_WORD_MAX = 256
#: What DDS hands the watcher (`filter_content`): a first field with "stop" in it, in any
#: case, among anything (`[\s\S]`: newlines too). More than `first_word` takes, which judges
#: each; never less.
STOP_FILTER = "instruction MATCH '[\\s\\S]*[sS][tT][oO][pP][\\s\\S]*'"


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


def answered(arm: Remote, kind: Kind, sent: int | None) -> tuple[bool, str]:
    """A safety service's request, obeyed by the owner: the service's answer. A stop is said
    delivered only once the owner has answered it."""
    future = arm.submit(Instruction(kind, sent_ns=sent or None))
    try:
        outcome = future.result(ANSWER_S if kind is not Kind.SHUTDOWN else SHUTDOWN_REFUSAL_S)
    except FutureTimeout:
        if kind is Kind.SHUTDOWN:
            return True, PARKING
        return False, f"{kind.value}: the server did not answer within {ANSWER_S:g} s"
    except LaneClosed as e:
        return False, f"{kind.value}: the server has ended ({e})"
    if kind is Kind.SHUTDOWN and outcome.ok:
        return True, PARKING
    return outcome.ok, outcome.reason or f"{kind.value}: {outcome.result.value}"


def _trigger(arm: Remote, kind: Kind) -> Callable[[Any, Any, int], Any]:
    def answer(request: Trigger.Request, response: Trigger.Response, sent: int) -> Any:
        if kind is Kind.STOP:
            # A service's request names no client whose clock is known.
            sent = stop_time(sent, time.time_ns(), None)
        response.success, response.message = answered(arm, kind, sent)
        return response

    return answer


class SafetyNode(Node):
    """Node `al5d_safety`: `/al5d/release` and `/al5d/shutdown` (std_srvs/Trigger), under the
    server's namespace."""

    def __init__(self, arm: Remote, context: Context, names: Names) -> None:
        super().__init__(
            SAFETY_NODE,
            namespace=names.node_namespace,
            context=context,
            cli_args=pinned(SAFETY_NODE),
        )
        for name, kind in names.services.items():
            if kind is not Kind.STOP:
                stamped_service(self, Trigger, name, _trigger(arm, kind), QOS_SERVICES)


class StopNode(Node):
    """Node `al5d_stop`: the `/al5d/stop` service, and the stop watcher, which reads the
    instruction topic beside the node `al5d` and obeys a stop as soon as it sees one, on
    this machine's clock by its client's lease (`clocks`), as the node `al5d` judges it.

    The watcher has a thread of its own: reading a flood takes it milliseconds at a time,
    which the stop service must never wait for (measured: with the two on one thread, a
    stop service call behind 1000 queued moves took 10 ms)."""

    def __init__(self, arm: Remote, context: Context, names: Names) -> None:
        super().__init__(
            STOP_NODE, namespace=names.node_namespace, context=context, cli_args=pinned(STOP_NODE)
        )
        self.arm = arm
        self.presets = tuple(arm.config.presets)
        self.model = arm.config.model
        stamped_service(self, Trigger, names.private(_STOP), _trigger(arm, Kind.STOP), QOS_SERVICES)
        # Taken by the reader's thread only: the executor that answers the service never
        # waits on it (`ReaderOnly`).
        group = ReaderOnly()
        watched = self.create_subscription(
            ArmInstruction,
            names.instruction,
            taken_by_reader,
            qos_watch(arm.settings.instruction_backlog),
            callback_group=group,
            raw=True,
        )
        # Only what could be a stop reaches this participant: a flood's moves never queue
        # ahead of a stop here, nor take this process's interpreter.
        filter_content(watched, STOP_FILTER)
        # The clients' leases, for their clocks only (what is lost is the node `al5d`'s to
        # halt): a stop is judged as sent on this machine's clock (`convert.stop_time`).
        # Depth 1: a flood of leases never holds the watcher.
        leases = self.create_subscription(
            ClientLease, names.clients, taken_by_reader, QOS_LEASES, callback_group=group
        )
        self.clocks = Leases(arm.config.server.client_lease_s)
        # A thread of its own takes what waits, up to `WATCH_BATCH` at a time, in one go:
        # under a flood, one GIL hand-over a message would leave the watcher behind.
        self.reader = Reader(
            self,
            [(watched, self._watch), (leases, self._on_lease)],
            "al5d-stop-watcher",
            WATCH_BATCH,
            True,
            group,
        )

    def _on_lease(self, msg: ClientLease, info: dict[str, int]) -> None:
        t = time.monotonic()
        self.clocks.heard(str(msg.client), msg.sent_ns, msg.every_ms, t, came_ns(info))
        self.clocks.lapsed(t)  # those lost long ago forgotten

    def _watch(self, raw: bytes, info: dict[str, int]) -> None:
        """A message on the instruction topic, serialized: a stop is obeyed at once. A failure
        is logged and the watcher goes on; the node `al5d` still obeys every stop."""
        if first_word(raw) != _STOP:
            return
        msg = deserialize_message(raw, ArmInstruction)
        offset = self.clocks.offset(str(msg.client)) if msg.client else None
        sent = stop_time(sent_ns(info), came_ns(info), offset)
        instr = from_message(msg, self.presets, self.model, sent)
        if isinstance(instr, Instruction) and instr.kind is Kind.STOP:
            self.arm.submit(instr, key=stop_key(msg, info))

    def close(self) -> None:
        self.reader.close()
