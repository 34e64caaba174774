"""The arm as it physically stands, where something knows it: an emulated arm's true joint
angles (`al5d emulator --misalign`: an arm other than its configuration says) on the topic
`physical_joint_states` (sensor_msgs/JointState: the URDF's names and values, as
/joint_states, the server's joint prefix in a namespace too), so that the web view and
`al5d calibrate` can show it beside what the model believes. A real arm has no such
topic: nothing measures where it stands.

`PhysicalPublisher` publishes it from a process of its own (the emulator's);
`PhysicalReader` keeps the latest, on a client's node.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping

from rclpy.node import Node
from sensor_msgs.msg import JointState

from al5d.model import ArmModel, ModelError
from al5d.ros.dds import start_context
from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATEST

#: How often the physical pose is published: enough for a person watching it move.
RATE_HZ = 20.0
#: A reader's latest sample older than this is no longer where the arm stands.
FRESH_S = 1.0


class PhysicalPublisher:
    """Publishes, once started, `read()` (arm degrees of every joint) RATE_HZ times a second
    from a thread of its own, on a DDS participant of its own, until closed; each URDF
    joint named with `prefix` (the server's: `ServerSettings.joint_prefix_in`)."""

    def __init__(
        self, names: Names, model: ArmModel, rate_hz: float = RATE_HZ, *, prefix: str = ""
    ) -> None:
        self.model = model
        self.prefix = prefix
        self._period = 1.0 / rate_hz
        self.context = start_context()
        self.node = Node(
            f"al5d_physical_{os.getpid()}", namespace=names.node_namespace, context=self.context
        )
        self.pub = self.node.create_publisher(JointState, names.physical_joint_states, QOS_LATEST)
        self._done = threading.Event()
        self._read: Callable[[], Mapping[str, float]] | None = None
        self._given = threading.Event()
        # Started now, waiting for `start`: a thread takes its maker's priority, and the
        # emulator's process makes its own threads urgent once its board is made.
        self._thread = threading.Thread(target=self._run, name="al5d-physical", daemon=True)
        self._thread.start()

    def start(self, read: Callable[[], Mapping[str, float]]) -> PhysicalPublisher:
        """Publish `read()` from now on."""
        self._read = read
        self._given.set()
        return self

    def _run(self) -> None:
        self._given.wait()
        while not self._done.wait(self._period):
            assert self._read is not None
            values = self.model.to_urdf(dict(self._read()))
            msg = JointState(
                name=[self.prefix + name for name in values],
                position=[float(v) for v in values.values()],
            )
            msg.header.stamp = self.node.get_clock().now().to_msg()
            self.pub.publish(msg)

    def close(self) -> None:
        self._done.set()
        self._given.set()
        self._thread.join(2.0)
        self.node.destroy_node()
        self.context.try_shutdown()


class PhysicalReader:
    """The latest physical pose published for one arm, read on `node` (which its owner spins);
    `on_pose` is called with each (arm degrees) in the executor's thread. Its joints'
    names may carry `prefix` (the server's joint prefix), or none."""

    def __init__(
        self,
        node: Node,
        names: Names,
        model: ArmModel,
        on_pose: Callable[[dict[str, float]], None] | None = None,
        *,
        prefix: str = "",
    ) -> None:
        self.model = model
        self.on_pose = on_pose
        self.prefix = prefix
        self._latest: tuple[float, dict[str, float]] | None = None
        self._cv = threading.Condition()
        node.create_subscription(JointState, names.physical_joint_states, self._on, QOS_LATEST)

    def _on(self, msg: JointState) -> None:
        try:
            bare = (name.removeprefix(self.prefix) for name in msg.name)
            named = zip(bare, msg.position, strict=True)
            degrees = self.model.from_urdf(dict(named))
        except (ModelError, ValueError):
            return  # not this arm's joints
        with self._cv:
            self._latest = (time.monotonic(), degrees)
            self._cv.notify_all()
        if self.on_pose is not None:
            self.on_pose(degrees)

    def degrees(self, fresh_s: float = FRESH_S) -> dict[str, float] | None:
        """Where the joints stand, if a sample came within `fresh_s` (None: nothing says)."""
        with self._cv:
            latest = self._latest
        if latest is None or time.monotonic() - latest[0] > fresh_s:
            return None
        return dict(latest[1])

    def next(self, timeout: float) -> dict[str, float] | None:
        """The first sample that comes from now on, within `timeout` (None: none came)."""
        deadline = time.monotonic() + timeout
        with self._cv:
            before = self._latest
            while self._latest is before:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cv.wait(left)
            assert self._latest is not None
            return dict(self._latest[1])


class OwnPhysicalReader(PhysicalReader):
    """A `PhysicalReader` on a node and DDS participant of its own, spun until `close`: for a
    client that has no node (one on the server's local lane)."""

    def __init__(self, names: Names, model: ArmModel, *, prefix: str = "") -> None:
        from al5d.ros.executors import Spinner

        context = start_context()
        node = Node(f"al5d_witness_{os.getpid()}", namespace=names.node_namespace, context=context)
        super().__init__(node, names, model, prefix=prefix)
        self._spinner = Spinner(node, context)

    def close(self) -> None:
        self._spinner.close()
