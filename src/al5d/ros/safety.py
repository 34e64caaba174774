"""The stop, release and shutdown services, and the stop watcher: the server's stop path.

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
for anything but a stop), and stops the arm as soon as it sees a stop. DDS hands
it only messages that could be a stop (`STOP_FILTER`, a content filter that Fast
DDS applies before Python sees anything): a flood's moves never queue in it. The
node `al5d` reads the same stop later, in order; both submit it with the
message's identity, and the driver obeys and answers it once (rule 3). What no
reader here can see is a stop still queued in its sender (a client that floods
through the same publisher is slowed by back-pressure, stop included): the
stop service is the way for emergencies.

The stop service and the watcher are the node `al5d_stop` (`StopNode`), which runs
in a process of its own (`al5d.ros.stopproc`) that writes the STOP itself: in the
server, its thread would wait for the interpreter lock behind the flood's
(`al5d.ssc32u.stopline` says why and how the two processes' writes keep their
order). The release and shutdown services are the node `al5d_safety`. Both are the
stop path (`SafetyPath`): DDS participants of their own (an rclpy context: its own
shared-memory port, sockets and receive threads), so that the flood the node `al5d`
takes, its results and the actions' traffic never stand in the same queues as a stop
request; and their threads, the participants' included, at a higher scheduling
priority where the OS allows (`al5d.priority`). Where the stop process cannot run
(or ends), `al5d_stop` runs in the server, obeying through the driver, and one log
line says so.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from al5d_interfaces.msg import ArmInstruction
from rclpy.context import Context
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from al5d.arm.config import ArmConfig
from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Instruction, Kind
from al5d.priority import built_urgently
from al5d.ros.convert import from_message, sent_ns, stop_key
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import SAFETY_NODE, STOP_NODE, Names, pinned
from al5d.ros.qos import QOS_SERVICES, qos_watch
from al5d.ros.workarounds import (
    Reader,
    ReaderOnly,
    filter_content,
    stamped_service,
    taken_by_reader,
)

if TYPE_CHECKING:
    from al5d.model.arm import ArmModel
    from al5d.ros.stopproc import StopProcess

log = logging.getLogger("al5d")
#: Messages the watcher takes in one call, at most.
WATCH_BATCH = 1000

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


class SafetyNode(Node):
    """Node `al5d_safety`: `/al5d/release` and `/al5d/shutdown` (std_srvs/Trigger), under the
    server's namespace."""

    def __init__(self, driver: ArmDriver, context: Context, names: Names) -> None:
        super().__init__(
            SAFETY_NODE,
            namespace=names.node_namespace,
            context=context,
            cli_args=pinned(SAFETY_NODE),
        )
        self.driver = driver
        for name, kind in names.services.items():
            if kind is not Kind.STOP:
                stamped_service(self, Trigger, name, self._trigger(kind), QOS_SERVICES)

    def _trigger(self, kind: Kind) -> Callable[[Any, Any, int], Any]:
        def answer(
            request: Trigger.Request, response: Trigger.Response, sent: int
        ) -> Trigger.Response:
            response.success, response.message = submitted(self.driver, kind, sent)
            return response

        return answer


def submitted(driver: ArmDriver, kind: Kind, sent: int | None) -> tuple[bool, str]:
    """A safety service's request, obeyed by the driver: the service's answer."""
    future = driver.submit(Instruction(kind, sent_ns=sent or None))
    if not future.done():  # shutdown: parking takes a while; the outcome follows on /al5d/result
        return True, "shutting down: parking, then the server ends"
    outcome = future.result()
    return outcome.ok, outcome.reason or f"{kind.value}: {outcome.result.value}"


def stop_instruction(
    raw: bytes, info: dict[str, int], presets: tuple[str, ...], model: ArmModel
) -> Instruction | None:
    """The stop in a serialized message the watcher saw; None if the node `al5d` would
    refuse it (and answer it) as something else."""
    msg = deserialize_message(raw, ArmInstruction)
    instr = from_message(msg, presets, model, sent_ns(info))
    return instr if isinstance(instr, Instruction) and instr.kind is Kind.STOP else None


#: What the node `al5d_stop` does with a stop service's request (sent at the given time):
#: the service's answer.
ServiceStop = Callable[[int | None], tuple[bool, str]]
#: ...and with a valid stop the watcher saw: the message's bytes, its info, the stop.
TopicStop = Callable[[bytes, dict[str, int], Instruction], None]


class StopNode(Node):
    """Node `al5d_stop`: the `/al5d/stop` service, and the stop watcher, which reads the
    instruction topic beside the node `al5d` and obeys a stop as soon as it sees one.

    The watcher has a thread of its own: reading a flood takes it milliseconds at a time,
    which the stop service must never wait for (measured: with the two on one thread, a
    stop service call behind 1000 queued moves took 10 ms). What a stop does is given
    (`on_service`, `on_topic`): the server's driver obeys it, or the stop process writes
    it and tells the server."""

    def __init__(
        self,
        context: Context,
        names: Names,
        stops: StopSetup,
        on_service: ServiceStop,
        on_topic: TopicStop,
    ) -> None:
        super().__init__(
            STOP_NODE,
            namespace=names.node_namespace,
            context=context,
            cli_args=pinned(STOP_NODE),
        )
        self.stops = stops
        self.on_service = on_service
        self.on_topic = on_topic
        stamped_service(self, Trigger, names.private(_STOP), self._answer, QOS_SERVICES)
        # Taken by the reader's thread only: the executor that answers the service never
        # waits on it (`ReaderOnly`).
        group = ReaderOnly()
        watched = self.create_subscription(
            ArmInstruction,
            names.instruction,
            taken_by_reader,
            qos_watch(stops.backlog),
            callback_group=group,
            raw=True,
        )
        # Only what could be a stop reaches this participant: a flood's moves never queue
        # ahead of a stop here, nor take this process's interpreter.
        filter_content(watched, STOP_FILTER)
        # A thread of its own takes what waits, up to `WATCH_BATCH` at a time, in one go:
        # under a flood, one GIL hand-over a message would leave the watcher behind.
        self.reader = Reader(
            self, [(watched, self._watch)], "al5d-stop-watcher", WATCH_BATCH, True, group
        )

    def _answer(
        self, request: Trigger.Request, response: Trigger.Response, sent: int
    ) -> Trigger.Response:
        response.success, response.message = self.on_service(sent or None)
        return response

    def _watch(self, raw: bytes, info: dict[str, int]) -> None:
        """A message on the instruction topic, serialized: a stop is obeyed at once. A failure
        is logged and the watcher goes on; the node `al5d` still obeys every stop."""
        if first_word(raw) == _STOP:
            instr = stop_instruction(raw, info, self.stops.presets, self.stops.model)
            if instr is not None:  # what the node `al5d` would refuse, it refuses itself
                self.on_topic(raw, info, instr)

    def close(self) -> None:
        self.reader.close()


@dataclass(frozen=True)
class StopSetup:
    """What the node `al5d_stop` needs of the server's config, wherever it runs."""

    channels: tuple[int, ...]
    presets: tuple[str, ...]
    model: ArmModel
    backlog: int

    @classmethod
    def of(cls, config: ArmConfig) -> StopSetup:
        channels = tuple(sorted(j.channel for j in config.joints.values()))
        return cls(channels, tuple(config.presets), config.model, config.server.instruction_backlog)


def stop_here(driver: ArmDriver, context: Context, names: Names) -> StopNode:
    """The node `al5d_stop` in the server: its stops obeyed by the driver."""

    def on_topic(raw: bytes, info: dict[str, int], instr: Instruction) -> None:
        driver.submit(instr, key=stop_key(info))

    return StopNode(
        context,
        names,
        StopSetup.of(driver.config),
        lambda sent: submitted(driver, Kind.STOP, sent),
        on_topic,
    )


class SafetyPath:
    """The stop path of one server: `SafetyNode` on a DDS participant (an rclpy context) of
    its own, every thread of it at the stop path's priority, and `StopNode` in the stop
    process (`stop`, started early by `RosStart`) or, where there is none or it ends,
    here. `args`: the server's command line, whose `--ros-args` (remaps: the namespace)
    apply here too."""

    def __init__(
        self,
        driver: ArmDriver,
        names: Names,
        args: Sequence[str] | None = None,
        stop: StopProcess | None = None,
    ) -> None:
        self.driver = driver
        self.names = names
        self.here: tuple[StopNode, Spinner] | None = None
        self._lock = threading.Lock()
        self._closed = False

        def build() -> tuple[Context, SafetyNode, Spinner]:
            # Made here, in a thread at the stop path's priority: the threads the participant
            # starts with its first node (its receive threads) inherit it.
            context = start_context(args or [SAFETY_NODE])
            safety = SafetyNode(driver, context, names)
            spinner = Spinner(safety, context, owns_context=False, kind="single", urgent=True)
            return context, safety, spinner

        self.context, self.safety, self.spinner = built_urgently("al5d-stop-path", build)
        self.stop = stop
        if stop is None or not stop.serve(driver, self.take_over):
            self.take_over()

    def take_over(self) -> None:
        """Serve the stop here (the stop process could not start, or has ended)."""
        with self._lock:
            if self.here is not None or self._closed:
                return

            def build() -> tuple[StopNode, Spinner]:
                node = stop_here(self.driver, self.context, self.names)
                return node, Spinner(node, self.context, False, kind="single", urgent=True)

            self.here = built_urgently("al5d-stop-here", build)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            here = self.here
        if self.stop is not None:
            self.stop.close()
        if here is not None:
            here[0].close()
            here[1].close()  # destroys the stop node
        self.spinner.close()  # destroys the safety node
        self.context.try_shutdown()
