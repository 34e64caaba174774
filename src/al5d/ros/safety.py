"""The stop, release and shutdown services, and the stop watcher, each on a node and a
thread of its own.

An emergency stop must never queue behind instruction traffic: with one
executor, a stop request waited behind every message taken before it (seconds
under a flood of 10,000 instructions a second). Here the services have their
own node (`al5d_safety`), their own executor and their own thread; the
driver's stop is synchronous and takes microseconds, so each request is
answered as soon as it is taken. Each request carries when it was sent (its
source timestamp), on which the driver orders a release against the stops
(`al5d.arm.core`, rule 1).

A stop sent on the instruction topic travels with the flood, in the order it
was sent: behind whatever the server has not taken yet (up to its bounded
backlog in DDS, and then behind the sender's own retries when that is full:
0.2 to 3 s at 10,000 messages a second). So a node of its own reads the topic
itself, best effort and without waiting for anyone (the stop watcher), looks
at the first field of each message in its serialized form (no message is built
for anything but a stop), and stops the arm as soon as it sees a stop. The
node `al5d` reads the same stop later, in order; both submit it with the
message's identity, and the driver obeys and answers it once (rule 3). What no
reader here can see is a stop still queued in its sender (a client that floods
through the same publisher is slowed by back-pressure, stop included): the
stop service is the way for emergencies.

Both are the stop path (`SafetyPath`): a DDS participant of their own (an
rclpy context: its own shared-memory port, sockets and receive threads), so
that the flood the node `al5d` takes, its results and the actions' traffic
never stand in the same queues as a stop request; and their threads, the
participant's included, at a higher scheduling priority where the OS allows
(`al5d.priority`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from al5d_interfaces.msg import ArmInstruction
from rclpy.context import Context
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Instruction, Kind
from al5d.priority import built_urgently
from al5d.ros.convert import from_message, sent_ns, stop_key
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import SAFETY_NODE, WATCHER_NODE, Names, pinned
from al5d.ros.qos import QOS_SERVICES, qos_watch
from al5d.ros.workarounds import Reader, stamped_service, taken_by_reader

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


class SafetyNode(Node):
    """Node `al5d_safety`: `/al5d/stop`, `/al5d/release`, `/al5d/shutdown` (std_srvs/Trigger),
    under the server's namespace."""

    def __init__(self, driver: ArmDriver, context: Context, names: Names) -> None:
        super().__init__(
            SAFETY_NODE,
            namespace=names.node_namespace,
            context=context,
            cli_args=pinned(SAFETY_NODE),
        )
        self.driver = driver
        for name, kind in names.services.items():
            stamped_service(self, Trigger, name, self._trigger(kind), QOS_SERVICES)

    def _trigger(self, kind: Kind) -> Callable[[Any, Any, int], Any]:
        def answer(
            request: Trigger.Request, response: Trigger.Response, sent: int
        ) -> Trigger.Response:
            future = self.driver.submit(Instruction(kind, sent_ns=sent or None))
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

    def __init__(self, driver: ArmDriver, context: Context, names: Names) -> None:
        super().__init__(
            WATCHER_NODE,
            namespace=names.node_namespace,
            context=context,
            cli_args=pinned(WATCHER_NODE),
        )
        self.driver = driver
        self.presets = tuple(driver.config.presets)
        watched = self.create_subscription(
            ArmInstruction,
            names.instruction,
            taken_by_reader,
            qos_watch(driver.config.server.instruction_backlog),
            raw=True,
        )
        # A thread of its own takes what waits, up to `WATCH_BATCH` at a time, in one go:
        # under a flood, one GIL hand-over a message would leave the watcher behind.
        self.reader = Reader(
            self, [(watched, self._watch)], "al5d-stop-watcher", WATCH_BATCH, urgent=True
        )

    def _watch(self, raw: bytes, info: dict[str, int]) -> None:
        """A message on the instruction topic, serialized: a stop is obeyed at once. A failure
        is logged and the watcher goes on; the node `al5d` still obeys every stop."""
        if first_word(raw) == _STOP:
            self._obey(raw, info)

    def _obey(self, raw: bytes, info: dict[str, int]) -> None:
        msg = deserialize_message(raw, ArmInstruction)
        instr = from_message(msg, self.presets, self.driver.config.model, sent_ns(info))
        # What the node `al5d` would refuse, it refuses (and answers) itself.
        if isinstance(instr, Instruction) and instr.kind is Kind.STOP:
            self.driver.submit(instr, key=stop_key(info))


class SafetyPath:
    """The stop path of one server: `SafetyNode` and `StopWatcher` on a DDS participant (an
    rclpy context) of their own, every thread of it at the stop path's priority. `args`:
    the server's command line, whose `--ros-args` (remaps: the namespace) apply here too."""

    def __init__(self, driver: ArmDriver, names: Names, args: Sequence[str] | None = None) -> None:
        def build() -> tuple[Context, SafetyNode, StopWatcher, Spinner]:
            # Made here, in a thread at the stop path's priority: the threads the participant
            # starts with its first node (its receive threads) inherit it.
            context = start_context(args or [SAFETY_NODE])
            safety = SafetyNode(driver, context, names)
            watcher = StopWatcher(driver, context, names)
            spinner = Spinner(safety, context, owns_context=False, kind="single", urgent=True)
            return context, safety, watcher, spinner

        self.context, self.safety, self.watcher, self.spinner = built_urgently(
            "al5d-stop-path", build
        )

    def close(self) -> None:
        self.watcher.reader.close()
        self.spinner.close()  # destroys the safety node
        self.watcher.destroy_node()
        self.context.try_shutdown()
