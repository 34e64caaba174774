"""The ROS side's fixed parts: public names, QoS profiles, the context, the executor thread."""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import queue
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from al5d.arm.config import namespace_problem
from al5d.arm.instruction import Kind
from al5d.priority import make_urgent
from al5d.ros.workarounds import StampedExecutor, discovery_on_our_transports

log = logging.getLogger("al5d")

NODE = "al5d"
SAFETY_NODE = "al5d_safety"
WATCHER_NODE = "al5d_stop_watcher"
ACTIONS_NODE = "al5d_actions"
ROBOT_NODE = "al5d_robot"


@dataclass(frozen=True)
class Names:
    """Every public name of one arm's server, under its namespace (ROS conventions).

    With no namespace the names are the design's (`/al5d/instruction`, `/joint_states`,
    `/arm_controller/follow_joint_trajectory`); with namespace `left` the node-private
    names become `/left/al5d/...`, the robot's and the controllers' `/left/...`, and the
    TF frames `left/base_link`... The one place that spells them, for the server, the
    clients and the web view alike.
    """

    namespace: str = ""

    @classmethod
    def of(cls, namespace: str | None) -> Names:
        """`left`, `/left` or `/lab/left` (None or "" or "/": none); refused with the reason."""
        problem = namespace_problem(namespace or "")
        if problem:
            raise ValueError(problem)
        ns = (namespace or "").strip("/")
        return cls(f"/{ns}" if ns else "")

    @property
    def node_namespace(self) -> str:
        return self.namespace or "/"

    def private(self, name: str) -> str:
        return f"{self.namespace}/{NODE}/{name}"

    def shared(self, name: str) -> str:
        return f"{self.namespace}/{name}"

    @property
    def frame_prefix(self) -> str:
        return f"{self.namespace.lstrip('/')}/" if self.namespace else ""

    @property
    def instruction(self) -> str:
        return self.private("instruction")

    @property
    def result(self) -> str:
        return self.private("result")

    @property
    def state(self) -> str:
        return self.private("state")

    @property
    def move(self) -> str:
        return self.private("move")

    @property
    def trajectory(self) -> str:
        return self.private("joint_trajectory")

    @property
    def tool_pose(self) -> str:
        return self.private("tool_pose")

    @property
    def joint_states(self) -> str:
        return self.shared("joint_states")

    @property
    def joint_commands(self) -> str:
        """Set-points (sensor_msgs/JointState, the URDF's names and values), as ros2_control's
        topic-based hardware (`JointStateTopicSystem`) publishes its commands."""
        return self.shared("joint_commands")

    @property
    def robot_description(self) -> str:
        return self.shared("robot_description")

    @property
    def follow_joint_trajectory(self) -> str:
        return self.shared("arm_controller/follow_joint_trajectory")

    @property
    def gripper_command(self) -> str:
        return self.shared("gripper_controller/gripper_cmd")

    @property
    def services(self) -> dict[str, Kind]:
        return {self.private(k.value): k for k in (Kind.STOP, Kind.RELEASE, Kind.SHUTDOWN)}


#: The names with no namespace, as the design gives them.
DEFAULT_NAMES = Names()
INSTRUCTION_TOPIC = DEFAULT_NAMES.instruction
RESULT_TOPIC = DEFAULT_NAMES.result
STATE_TOPIC = DEFAULT_NAMES.state
MOVE_ACTION = DEFAULT_NAMES.move
TRAJECTORY_TOPIC = DEFAULT_NAMES.trajectory
JOINT_STATES_TOPIC = "joint_states"
SERVICES = DEFAULT_NAMES.services

#: Instructions: reliable, and kept until taken (KEEP_ALL), so that a flood faster than
#: the server slows its sender instead of overwriting what it sent (back-pressure).
QOS_INSTRUCTIONS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


def qos_watch(backlog: int) -> QoSProfile:
    """The stop watcher's reader of the instruction topic: it never slows a sender (best
    effort) and never waits: a flood it cannot keep up with overwrites the oldest.

    As deep as the server's instruction backlog, and no deeper: Fast DDS gives the
    backlog's bound (`dds_profile`) to every reader of the topic in the process, the
    watcher's too, and a KEEP_LAST reader deeper than its bound, once full, refuses the
    newest message instead of dropping the oldest (measured: 5,000 sent to a reader 10,000
    deep bounded at 1,000 kept the first 1,000): a stop that came last would be lost."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=backlog,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


#: Results: reliable and deep; a reader more than 10,000 results behind loses the oldest,
#: and never slows the server (KEEP_ALL here would let a stuck reader block it).
QOS_STREAM = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10_000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
#: The safety services' requests and answers: deep enough for a burst of callers.
QOS_SERVICES = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
#: The stream of set-points (`joint_commands`): the newest is all that matters (ros2_control's
#: hardware writer keeps one too, and so does the web view's jog).
QOS_COMMANDS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
#: The state: latched, so that a late joiner gets the current one.
QOS_LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def ros_environment() -> None:
    """Defaults that must be set before rclpy starts: local discovery, a writable log dir."""
    # Nobody on the network drives the arm unless the user opens it on purpose.
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not any(os.path.isdir(os.environ.get(v, "")) for v in ("ROS_LOG_DIR", "ROS_HOME", "HOME")):
        os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="al5d-ros-log-")


#: Fast DDS reads its XML profiles from this file, named at its start.
PROFILES_VAR = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: The profiles file this project wrote (a child process may write its own over it); any
#: other file in PROFILES_VAR is the user's, and kept.
OURS_VAR = "AL5D_DDS_PROFILES_FILE"
#: Messages a process's shared-memory port holds before Fast DDS drops what comes next (its
#: default is 512: about 50 ms of a 10,000/s flood, or half of the outcomes one stop gives
#: a full queue).
SHM_PORT_QUEUE = 8192
_PROFILES = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <!-- al5d: Fast DDS's own transports (shared memory, UDPv4){udp_note}. -->
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>al5d_shm</transport_id>
        <type>SHM</type>{port_queue}
      </transport_descriptor>
      <transport_descriptor>
        <transport_id>al5d_udp</transport_id>
        <type>UDPv4</type>{loopback}
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="al5d" is_default_profile="true">
      <rtps>
        <userTransports>
          <transport_id>al5d_shm</transport_id>
          <transport_id>al5d_udp</transport_id>
        </userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
      </rtps>
    </participant>{reader}
  </profiles>
</dds>
"""
_LOOPBACK = """
        <interfaceWhiteList>
          <address>127.0.0.1</address>
        </interfaceWhiteList>"""
_PORT_QUEUE = """
        <port_queue_capacity>{n}</port_queue_capacity>"""
_READER = """
    <!-- al5d serve: at most {limit} instructions wait in DDS for the server to take them. -->
    <data_reader profile_name="{topic}">
      <topic>
        <resourceLimitsQos>
          <max_samples>{limit}</max_samples>
          <max_instances>1</max_instances>
          <max_samples_per_instance>{limit}</max_samples_per_instance>
          <allocated_samples>{allocated}</allocated_samples>
        </resourceLimitsQos>
      </topic>
    </data_reader>"""


def local_only() -> bool:
    """Is DDS kept to this machine? Yes unless the user opened discovery to the network
    (`ROS_AUTOMATIC_DISCOVERY_RANGE` SUBNET or SYSTEM_DEFAULT; docs/ros.md, "Reaching the node
    from another machine")."""
    ros_environment()
    return os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"].strip().upper() in ("LOCALHOST", "OFF")


def dds_profile(instructions: tuple[str, int] | None = None) -> str | None:
    """Write this process's Fast DDS profile and name it in FASTRTPS_DEFAULT_PROFILES_FILE;
    the user's own file, if one is named there (then it applies, not ours).

    Every process of the project (the server, the clients, the web view) binds its UDP
    sockets to the loopback interface unless the user opened DDS to the network
    (`local_only`): discovery kept to this machine is not enough, since a participant
    still listens on every interface for anyone who knows its port. Every process's
    shared-memory port is deeper than Fast DDS's default (below). The server's
    (`instructions`: the topic and its backlog) also bounds that topic's reader:

    With KEEP_ALL and no bound, a flood faster than the server piles up in its reader,
    and a stop sent on the topic waits behind the pile (seconds). With the bound, the
    reader refuses what it cannot hold, and reliable delivery holds it at the sender,
    slowing it.

    The port: under a 10,000/s flood Fast DDS's default of 512 messages overflowed now
    and then. What it dropped was lost to the stop watcher (best effort), and a stop
    request, a stop on the topic or an outcome came 1 to 3 s late, when DDS repaired
    the loss (6 stops in 4 floods of 30 s, and once an outcome lost for good, its
    reader 10,000 results behind by then); with 8192, none in 5 floods. A client's port
    overflows as well: a stop that cancels a full queue sends 1,025 outcomes at once,
    and three servers flooded beside busy loops lost 19 to 12,839 outcomes a flood on
    their way to their readers, whose ports held 512.

    Must run before the process's first ROS context starts (Fast DDS reads the file
    once).
    """
    named = os.environ.get(PROFILES_VAR)
    if named and named != os.environ.get(OURS_VAR):
        return named
    local = local_only()
    reader = ""
    if instructions is not None:
        topic, limit = instructions
        reader = _READER.format(topic=topic, limit=limit, allocated=min(limit, 100))
    profile = _PROFILES.format(
        udp_note=", UDP on the loopback interface only" if local else "",
        port_queue=_PORT_QUEUE.format(n=SHM_PORT_QUEUE),
        loopback=_LOOPBACK if local else "",
        reader=reader,
    )
    fd, path = tempfile.mkstemp(prefix="al5d-dds-", suffix=".xml")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(profile)
    # Fast DDS has read it by the time the process ends; a process this one starts that
    # uses DDS writes a file of its own (above: ours is not the user's).
    atexit.register(_remove, path)
    os.environ[PROFILES_VAR] = os.environ[OURS_VAR] = path
    return None


def _remove(path: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def start_context(args: Sequence[str] | None = None) -> Context:
    """A ROS context (a DDS participant); the process's DDS profile first, if none is named.
    `args`: a command line whose `--ros-args` (remaps, parameters) apply to its nodes."""
    ros_environment()
    if not os.environ.get(PROFILES_VAR):
        dds_profile()
    context = Context()
    ours = os.environ.get(PROFILES_VAR) == os.environ.get(OURS_VAR)
    with discovery_on_our_transports(ours and local_only()):
        # Our own SIGINT/SIGTERM handling parks the arm first; rclpy's would just stop.
        rclpy.init(
            args=list(args) if args else None,
            context=context,
            signal_handler_options=SignalHandlerOptions.NO,
        )
    return context


def pinned(name: str) -> list[str]:
    """A node's own arguments that keep its name whatever the command line's `-r __node:=`
    (which renames every node of a context; a node's own rules come first): the server's
    nodes but `al5d` keep theirs, so that each has one name, as the design gives them."""
    return ["--ros-args", "-r", f"__node:={name}"]


def make_executor(context: Context, kind: str | None = None) -> Executor:
    """rclpy's C++ EventsExecutor, or with `kind="single"` its Python SingleThreadedExecutor
    (which tells a stamped service when its request was sent: `workarounds.StampedExecutor`).

    The events executor takes each message without rebuilding a wait set of every
    entity in Python, which is what limits the single-threaded one (docs/architecture.md,
    "How the server reads its inputs", has the figures of both). But in rclpy 7.1 it runs
    a task that awaits a future again and again until the future is done (ros2/rclpy#1405, fixed
    later by #1469): a coroutine that waits for the arm would hold a core. The actions,
    whose execute callbacks are such coroutines, have the Python executor.
    """
    if kind == "single":
        return StampedExecutor(context=context)
    from rclpy.experimental.events_executor import EventsExecutor

    return EventsExecutor(context=context)


T = TypeVar("T")


class PublishThread(Generic[T]):
    """Publishes from a thread of its own: whoever hands an item over (the executor taking
    instructions, the stop) never waits for DDS, and a burst of a thousand is one hand-over."""

    def __init__(self, publisher: Publisher, convert: Callable[[T], Any], name: str) -> None:
        self._publisher = publisher
        self._convert = convert
        self._items: queue.SimpleQueue[T | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, item: T) -> None:
        self._items.put(item)

    def _run(self) -> None:
        while (item := self._items.get()) is not None:
            self._publisher.publish(self._convert(item))

    def close(self, timeout: float = 5.0) -> None:
        """Publish what was handed over, then end."""
        self._items.put(None)
        self._thread.join(timeout)


class Spinner:
    """An executor spinning in its own thread, stopped in the order rclpy needs.

    With `owns_context`, closing it also ends the ROS context (a process with one node);
    `more` nodes share the executor and its thread. An `urgent` spinner (the safety
    services') runs at the stop path's priority (`al5d.priority`).
    """

    def __init__(
        self,
        node: Node,
        context: Context,
        owns_context: bool = True,
        more: list[Node] | None = None,
        kind: str | None = None,
        urgent: bool = False,
    ) -> None:
        self.node = node
        self.urgent = urgent
        self.context = context
        self.owns_context = owns_context
        self.more = list(more or [])
        self.executor = make_executor(context, kind)
        # Python's executor rebuilds its wait set at every turn: an idle one should turn
        # seldom (`close` wakes it). The events executor turns only on events anyway.
        self.turn_s = 1.0 if isinstance(self.executor, SingleThreadedExecutor) else 0.1
        for each in (node, *self.more):
            self.executor.add_node(each)
        self._running = True
        self._thread = threading.Thread(
            target=self._spin, name=f"{node.get_name()}-spin", daemon=True
        )
        self._thread.start()

    def _spin(self) -> None:
        if self.urgent:
            make_urgent(self._thread.name)
        # A callback that raises must not end the thread: the safety node's serves the stop.
        while self._running and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=self.turn_s)
            except Exception:
                if not (self._running and self.context.ok()):
                    return
                log.exception("%s: a callback failed; its executor goes on", self._thread.name)

    def close(self) -> None:
        # Join the spin thread before shutting the executor down, or the process can abort.
        self._running = False
        self.executor.wake()
        self._thread.join(5)
        self.executor.shutdown(timeout_sec=1)
        for each in (self.node, *self.more):
            each.destroy_node()
        if self.owns_context:
            self.context.try_shutdown()
