"""Recordings: what happened around the arms, written as rosbag2's MCAP (`al5d record`,
`al5d serve --record`).

A recording is an MCAP file of the `ros2` profile, as `ros2 bag record -s mcap` writes one:
each topic a channel of CDR messages, each message's type a schema of encoding `ros2msg`
(its `.msg` text with every type it uses after it), so that `ros2 bag info`, Foxglove and
the `mcap` tools open it without this package. Messages are recorded as DDS delivered
them (their serialized bytes, never decoded and encoded again), with the time they were
received (log time) and sent (publish time), as rosbag2 does; in a server's own
recording, the arm's inputs as its node read them (encoded again, with their times).

What is recorded, the whole scene: `/tf` and `/tf_static`, and of each arm (every arm
`al5d record` finds, or the namespaces it is given; a server's own) its robot
description, joint states and tool pose, the instructions and their results, the state,
the trajectories and set-points, each action's goals with their contents (the server
publishes each on `~/goals/<action>`: a goal is a service request, which no subscriber
sees) and their status (`/_action/status`); with a physical twin (`--physics`), its
joints, objects and words, and its camera's pictures with their `CameraInfo`. Not the
actions' feedback: its types (`Move_FeedbackMessage`) have names that mcap-ros2-support's
reader refuses, and one such message would stop it reading the whole file. A server's
own recording also has the bytes it wrote to the board, each write with its times
(`BOARD_WRITES`, an `al5d_interfaces/msg/BoardWrite`).

The file itself (its schemas, the board's writes in CDR): `al5d.app.mcapfile`.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from al5d.app.mcapfile import RecordFile, RecordingError

if TYPE_CHECKING:
    from al5d.arm.instruction import Instruction
    from al5d.ros.names import Names

log = logging.getLogger("al5d")

#: The topic of the bytes written to the board, in a server's recording (no DDS topic).
BOARD_WRITES = "board_writes"
INSTRUCTION_TYPE = "al5d_interfaces/msg/ArmInstruction"
#: How often a recorder looks at how many writers each of its topics has matched.
WRITERS_EVERY_S = 0.1


@dataclass(frozen=True)
class Topic:
    """A recorded topic: its full name, its type (`pkg/msg/Type`) and how it is read."""

    name: str
    type: str
    qos: Any  # rclpy QoSProfile


def _reliable(depth: int, latched: bool = False) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
    return QoSProfile(  # type: ignore[no-untyped-call]
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=durability,
    )


def topics(names: Names) -> list[Topic]:
    """What a recording of the arm named by `names` subscribes to."""
    status = "action_msgs/msg/GoalStatusArray"
    reliable = _reliable
    return [
        Topic(names.instruction, INSTRUCTION_TYPE, reliable(1000)),
        Topic(names.result, "al5d_interfaces/msg/InstructionResult", reliable(10_000)),
        # The state's writer keeps the last only (latched): a reader a state behind would
        # miss one (a stop's "stopped" and a release's "ready" a millisecond apart).
        Topic(names.state, "std_msgs/msg/String", reliable(100, latched=True)),
        Topic(names.robot_description, "std_msgs/msg/String", reliable(1, latched=True)),
        Topic(names.joint_states, "sensor_msgs/msg/JointState", reliable(100)),
        Topic(names.tool_pose, "geometry_msgs/msg/PoseStamped", reliable(100)),
        Topic(names.trajectory, "trajectory_msgs/msg/JointTrajectory", reliable(1000)),
        Topic(names.joint_commands, "sensor_msgs/msg/JointState", reliable(1000)),
        Topic(names.goals("move"), INSTRUCTION_TYPE, reliable(1000)),
        Topic(
            names.goals("follow_joint_trajectory"),
            "trajectory_msgs/msg/JointTrajectory",
            reliable(1000),
        ),
        Topic(names.goals("gripper_cmd"), "sensor_msgs/msg/JointState", reliable(1000)),
        Topic(f"{names.move}/_action/status", status, reliable(100)),
        Topic(f"{names.follow_joint_trajectory}/_action/status", status, reliable(100)),
        Topic(f"{names.gripper_command}/_action/status", status, reliable(100)),
        # The physical twin's (al5d.twin), when one runs: what the body did, and what its
        # camera saw (a few pictures deep: each is 230 kB at 320 x 240).
        Topic(names.twin_joint_states, "sensor_msgs/msg/JointState", reliable(100)),
        Topic(names.twin_objects, "visualization_msgs/msg/MarkerArray", reliable(100)),
        Topic(names.twin_held, "std_msgs/msg/String", reliable(100)),
        Topic(names.camera_image, "sensor_msgs/msg/Image", reliable(10)),
        Topic(names.camera_info, "sensor_msgs/msg/CameraInfo", reliable(10)),
    ]


def node_inputs(names: Names) -> frozenset[str]:
    """The arm's input topics that the server's node reads: its own recording has what the
    node read on them (`ServerRecording.heard`), not what a reader of its own matched."""
    return frozenset({names.instruction, names.trajectory, names.joint_commands})


def _put_as_delivered(put: Callable[..., None], channel: int, data: bytes, info: Any) -> None:
    """A message handed to the file with the times and the sequence number of its info."""
    received = info.get("received_timestamp") or time.time_ns()
    sent = info.get("source_timestamp") or received
    put(channel, data, received, sent, info.get("publication_sequence_number") or 0)


def scene_topics() -> list[Topic]:
    """The transforms every arm shares: /tf at the arms' joint-state rate, and /tf_static,
    each server's latched (with the mount that puts its arm in the shared frame)."""
    tf = "tf2_msgs/msg/TFMessage"
    return [Topic("/tf", tf, _reliable(1000)), Topic("/tf_static", tf, _reliable(100, True))]


class Recorder:
    """Subscribes to topics on a node of its own in `context` and hands every message, as
    DDS delivered it, to `file`; each group of topics (`add`: the scene's, an arm's) is
    taken by a thread of its own (`al5d.ros.workarounds.Reader`, which has each message's
    info: when it was sent and its sequence number).

    Like rosbag2's, a recorder misses what a writer published before the two had matched,
    and discovery on a busy host can take seconds. So it says, through `say`, each time the
    number of writers it has matched on a topic changes ("/al5d/result: 1 writer"): what
    is recorded from then on."""

    def __init__(
        self,
        context: Any,
        file: RecordFile,
        recorded: Iterable[Topic] = (),
        namespace: str = "/",
        say: Callable[[str], None] | None = None,
    ) -> None:
        from rclpy.node import Node

        from al5d.ros.names import RECORDER_NODE

        self.file = file
        self.node = Node(RECORDER_NODE, namespace=namespace, context=context)
        self.inputs: list[tuple[Any, Any]] = []
        self._readers: list[Any] = []
        self._lock = threading.Lock()  # the groups, added while the writers are counted
        self._say = say or (lambda text: log.info("recording %s: %s", file.path, text))
        self._ended = threading.Event()
        self.add(recorded)
        self._counter = threading.Thread(target=self._count_writers, name="al5d-record-writers")
        self._counter.start()

    def add(self, recorded: Iterable[Topic]) -> None:
        """Record these topics too, from now on (a thread of their own takes them)."""
        from al5d.ros.workarounds import Reader, ReaderOnly, taken_by_reader

        group = ReaderOnly()
        inputs: list[tuple[Any, Any]] = []
        for topic in recorded:
            channel = self.file.channel(topic.name, topic.type)
            package, kind, name = topic.type.split("/")
            msg_type = getattr(importlib.import_module(f"{package}.{kind}"), name)
            sub = self.node.create_subscription(
                msg_type, topic.name, taken_by_reader, topic.qos, callback_group=group, raw=True
            )
            inputs.append((sub, self._handler(channel)))
        if not inputs:
            return
        reader = Reader(self.node, inputs, f"al5d-record-{len(self._readers)}", group=group)
        with self._lock:
            self.inputs += inputs
            self._readers.append(reader)

    def writers(self) -> int:
        """How many writers the recorder has matched, over every topic."""
        with self._lock:
            inputs = list(self.inputs)
        return sum(sub.get_publisher_count() for sub, _ in inputs)

    def _count_writers(self) -> None:
        """Says each topic's number of matched writers whenever it changes."""
        said: dict[str, int] = {}
        while not self._ended.wait(WRITERS_EVERY_S):
            with self._lock:
                inputs = list(self.inputs)
            for sub, _ in inputs:
                try:
                    n = sub.get_publisher_count()
                except Exception:  # the node is being destroyed
                    return
                if said.get(sub.topic_name, 0) != n:
                    said[sub.topic_name] = n
                    self._say(f"{sub.topic_name}: {n} writer{'' if n == 1 else 's'}")

    def _handler(self, channel: int) -> Any:
        put = self.file.put

        def handle(data: bytes, info: dict[str, int]) -> None:
            _put_as_delivered(put, channel, data, info)

        return handle

    def close(self) -> None:
        """End the readers, then record what DDS delivered meanwhile (a server's last
        results, acknowledged to this reader before its nodes closed)."""
        self._ended.set()
        self._counter.join()
        with self._lock:
            readers, inputs = list(self._readers), list(self.inputs)
        for reader in readers:
            reader.close()
        for sub, handle in inputs:
            while True:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
                if taken is None:
                    break
                handle(*taken)
        self.node.destroy_node()  # type: ignore[no-untyped-call]


class ArmFinder:
    """Finds the arms a recorder records: every server's node the ROS graph shows, whatever
    its name (`al5d.ros.names.server_namespaces`), by its namespace, each told to `found`
    once (a thread that looks every `every_s`)."""

    def __init__(self, node: Any, found: Callable[[str], None], every_s: float = 0.2) -> None:
        self._node = node
        self._found = found
        self._every_s = every_s
        self.namespaces: list[str] = []
        self._ended = threading.Event()
        self._thread = threading.Thread(target=self._run, name="al5d-record-finder", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from al5d.ros.names import server_namespaces

        while not self._ended.is_set():
            try:
                seen = server_namespaces(self._node)
            except Exception:  # the node is being destroyed
                return
            for namespace in sorted(seen):
                if namespace not in self.namespaces:
                    self.namespaces.append(namespace)
                    self._found(namespace)
            self._ended.wait(self._every_s)

    def close(self) -> None:
        self._ended.set()
        self._thread.join()


class ServerRecording:
    """`al5d serve --record`: the file, the board's writes (`tap`), the arm's inputs as the
    server read them (`heard`: its node's topics; `asked`: its local lane), and the other
    topics of the server's arm and the transforms, read by a DDS participant of its own
    (`follow`), which outlives the server's nodes so that their last messages (the
    shutdown's result) are recorded.

    A reader of its own would miss what a client sent as soon as it had matched the node's
    reader and not yet this one's (a one-shot `al5d send --via ros`: 1 of 10 on a busy
    host), and the arm would have obeyed an instruction that a replay leaves out."""

    def __init__(self, path: str) -> None:
        self.file = RecordFile(path)
        self._context: Any = None
        self._recorder: Recorder | None = None

    def tap(self, namespace: str | None) -> Any:
        """The board's writes, on `<ns>/al5d/board_writes`: the driver's `WriteTap`."""
        from al5d.ros.names import Names

        self.file.record_board(Names.of(namespace).private(BOARD_WRITES))
        return self.file.board_tap

    def follow(self, names: Names) -> None:
        from al5d.ros.dds import start_context

        inputs = node_inputs(names)
        try:
            self._context = start_context()
            self._recorder = Recorder(
                self._context,
                self.file,
                [*scene_topics(), *(t for t in topics(names) if t.name not in inputs)],
                names.node_namespace,
            )
        except Exception as e:  # the arm goes on; its board's bytes are still recorded
            log.error("recording %s: the topics cannot be recorded (%s)", self.file.path, e)
            self.close_ros()

    def heard(self, names: Names) -> Callable[[str, Any, dict[str, int]], None]:
        """What records a message the server's node read on one of its input topics, with
        the times and sequence number of its info (the node's `heard`)."""
        from rclpy.serialization import serialize_message

        inputs = node_inputs(names)
        channels = {
            t.name: self.file.channel(t.name, t.type) for t in topics(names) if t.name in inputs
        }
        put = self.file.put

        def record(topic: str, msg: Any, info: dict[str, int]) -> None:
            _put_as_delivered(put, channels[topic], serialize_message(msg), info)

        return record

    def asked(self, names: Names) -> Callable[[Instruction, int], None]:
        """What records an instruction that came by the owner's lane (`al5d send`, `run`,
        `shell`: on no ROS topic) on the arm's instruction topic, as if sent there at its
        wall time: a replay repeats it as it does those that came over ROS."""
        from rclpy.serialization import serialize_message

        from al5d.ros.convert import to_message

        channel = self.file.channel(names.instruction, INSTRUCTION_TYPE)

        def record(instr: Instruction, wall: int) -> None:
            data = serialize_message(to_message(instr))
            self.file.put(channel, data, wall, instr.sent_ns or wall)

        return record

    def close_ros(self) -> None:
        if self._recorder is not None:
            self._recorder.close()
            self._recorder = None
        if self._context is not None:
            self._context.try_shutdown()
            self._context = None

    def close(self) -> None:
        self.close_ros()
        self.file.close()
        if self.file.failed:
            log.error("recording %s failed: %s", self.file.path, self.file.failed)
        else:
            log.info("recorded %s", self.file.summary())


#: `al5d record` warns when it has matched no writer at all this long after its start.
NO_WRITERS_S = 5.0


def record(path: str, namespaces: Sequence[str] | None, duration: float | None) -> int:
    """`al5d record`: the scene and every arm found (or the arms in `namespaces`), until
    SIGINT or SIGTERM (or `duration` seconds); 0, or 2 when the file cannot be written."""
    import signal

    from al5d import exits
    from al5d.interrupts import wait_set
    from al5d.ros.dds import start_context
    from al5d.ros.names import Names

    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: done.set())

    def say(text: str) -> None:
        print(f"al5d record: {text}", flush=True)

    try:
        file = RecordFile(path)
    except RecordingError as e:
        print(f"al5d record: {e}", file=sys.stderr)
        return exits.USAGE
    context = start_context()
    recorder = Recorder(context, file, scene_topics(), say=say)

    def arm(namespace: str) -> None:
        names = Names.of(namespace)
        say(f"recording the arm in {names.node_namespace}")
        recorder.add(topics(names))

    finder = None
    if namespaces:
        for namespace in dict.fromkeys(Names.of(ns).node_namespace for ns in namespaces):
            arm(namespace)
    else:
        finder = ArmFinder(recorder.node, arm)
    print(f"al5d record: recording to {path} (Ctrl-C ends it)", flush=True)
    try:
        first = NO_WRITERS_S if duration is None else min(duration, NO_WRITERS_S)
        if not wait_set(done, first):  # set by a signal's handler, run in this thread
            if first >= NO_WRITERS_S and recorder.writers() == 0:
                domain = os.environ.get("ROS_DOMAIN_ID", "0")
                if namespaces:
                    where = f"the arms in {', '.join(namespaces)} running"
                else:
                    where = "an al5d server running (none found)"
                say(
                    f"warning: no writer matched in {NO_WRITERS_S:g} s: is {where}, in "
                    f"ROS_DOMAIN_ID={domain}? Recording goes on"
                )
            wait_set(done, None if duration is None else max(0.0, duration - first))
    finally:
        if finder is not None:
            finder.close()
        recorder.close()
        context.try_shutdown()
        file.close()
    print(f"al5d record: {file.summary()}", flush=True)
    if file.failed:
        print(f"al5d record: the recording failed: {file.failed}", flush=True)
        return exits.NOT_DONE
    return exits.DONE
