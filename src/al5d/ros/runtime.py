"""The ROS side's fixed parts: public names, QoS profiles, the context, the executor thread."""

from __future__ import annotations

import os
import queue
import tempfile
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from al5d.arm.instruction import Kind

NODE = "al5d"
INSTRUCTION_TOPIC = "/al5d/instruction"
RESULT_TOPIC = "/al5d/result"
STATE_TOPIC = "/al5d/state"
MOVE_ACTION = "/al5d/move"
JOINT_STATES_TOPIC = "/joint_states"
TRAJECTORY_TOPIC = "/al5d/joint_trajectory"
SERVICES = {"/al5d/stop": Kind.STOP, "/al5d/release": Kind.RELEASE, "/al5d/shutdown": Kind.SHUTDOWN}

#: Instructions: reliable, and kept until taken (KEEP_ALL), so that a flood faster than
#: the server slows its sender instead of overwriting what it sent (back-pressure).
QOS_INSTRUCTIONS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
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
_BACKLOG_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
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
    </data_reader>
  </profiles>
</dds>
"""


def bound_backlog(topic: str, limit: int) -> str | None:
    """Make Fast DDS keep at most `limit` samples of `topic` in this process's reader.

    With KEEP_ALL and no bound, a flood faster than the server piles up in its reader,
    and a stop sent on the topic waits behind the pile (seconds). With the bound, the
    reader refuses what it cannot hold, and reliable delivery holds it at the sender,
    slowing it. Must run before the ROS context starts. A user's own profiles file
    (FASTRTPS_DEFAULT_PROFILES_FILE) is kept: then the bound is theirs to set; the
    return value says which file applies.
    """
    if os.environ.get(PROFILES_VAR):
        return os.environ[PROFILES_VAR]
    fd, path = tempfile.mkstemp(prefix="al5d-dds-", suffix=".xml")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(_BACKLOG_PROFILE.format(topic=topic, limit=limit, allocated=min(limit, 100)))
    os.environ[PROFILES_VAR] = path
    return None


def start_context() -> Context:
    ros_environment()
    context = Context()
    # Our own SIGINT/SIGTERM handling parks the arm first; rclpy's would just stop.
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    return context


def make_executor(context: Context) -> Executor:
    """rclpy's C++ EventsExecutor, or the Python SingleThreadedExecutor (AL5D_EXECUTOR=single).

    The events executor takes each message without rebuilding a wait set of every
    entity in Python, which is what limits the single-threaded one (see the README's
    Performance section for the figures of both).
    """
    if os.environ.get("AL5D_EXECUTOR", "events") == "single":
        return SingleThreadedExecutor(context=context)
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

    With `owns_context`, closing it also ends the ROS context (a process with one node).
    """

    def __init__(self, node: Node, context: Context, owns_context: bool = True) -> None:
        self.node = node
        self.context = context
        self.owns_context = owns_context
        self.executor = make_executor(context)
        self.executor.add_node(node)
        self._running = True
        self._thread = threading.Thread(
            target=self._spin, name=f"{node.get_name()}-spin", daemon=True
        )
        self._thread.start()

    def _spin(self) -> None:
        while self._running and self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        # Join the spin thread before shutting the executor down, or the process can abort.
        self._running = False
        self.executor.wake()
        self._thread.join(5)
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        if self.owns_context:
            self.context.try_shutdown()
