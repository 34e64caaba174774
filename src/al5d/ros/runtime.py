"""The ROS side's fixed parts: public names, QoS profiles, the context, the executor thread."""

from __future__ import annotations

import os
import tempfile
import threading

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
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

#: Instructions and results: reliable and deep, so that a burst loses nothing.
QOS_STREAM = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10_000,
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


class Spinner:
    """An executor spinning in its own thread, stopped in the order rclpy needs."""

    def __init__(self, node: Node, context: Context) -> None:
        self.node = node
        self.context = context
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
        self.context.try_shutdown()
