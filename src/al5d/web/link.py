"""The page's ROS side: a client node of the server, by the public names of one namespace
(and its STOP by the server's local lane too, where the server is on this machine).

It reads what any client may read and sends what any client may send; the server
does not know it is a web page. Nothing it does can hold the server up: the
joint states come best effort (a page that falls behind loses samples, it never
makes the server resend them), the instruction and trajectory topics are read
best effort too (to show the target of a move sent by anyone: a reliable reader
could hold up a sender's KEEP_ALL writer), and the server's writers of the state
and the results keep their last samples whatever a reader does.

The goals of the actions (al5d's Move, FollowJointTrajectory, GripperCommand)
are on no topic: the page shows no ghost for them, only their outcomes.
"""

from __future__ import annotations

import itertools
import logging
import os
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Protocol

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory

from al5d.arm.instruction import FRESH_MARK, Instruction, Outcome
from al5d.model import ArmModel
from al5d.model.chain import BASE_LINK
from al5d.model.transforms import Transform
from al5d.owner import where
from al5d.ros.convert import (
    from_message,
    outcome_from_message,
    to_message,
    trajectory_from_message,
)
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.leasing import Leaser, new_key
from al5d.ros.names import PING, Names
from al5d.ros.physical import PhysicalReader
from al5d.ros.qos import (
    QOS_COMMANDS,
    QOS_INSTRUCTIONS,
    QOS_LATCHED,
    QOS_LATEST,
    profile,
)
from al5d.ros.robot import QOS_TF_STATIC
from al5d.web.stopping import StopRelease

#: Outcomes: reliable (a refusal's reason must reach the page) but shallow; the server's
#: writer keeps its own history and is never slowed by a reader's.
QOS_OUTCOMES = profile(100)

log = logging.getLogger("al5d.web")

#: The state: latched as the server writes it, and every change kept until this page takes
#: it (a reader of depth 1 whose executor lagged a short move behind showed READY, READY:
#: the MOVING between them was overwritten before it was taken).
QOS_STATES = profile(20, latched=True)


class Listener(Protocol):
    """What the link hands over, in its executor's thread."""

    def on_description(self, urdf: str) -> None: ...

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None: ...

    def on_state(self, state: str) -> None: ...

    def on_outcome(self, outcome: Outcome) -> None: ...

    def on_instruction(self, instr: Instruction) -> None: ...

    def on_mount(self, parent: str, mount: Transform) -> None: ...

    def on_physical(self, degrees: dict[str, float]) -> None: ...

    def on_answer(self, text: str, ok: bool | None) -> None:
        """What became of the page's last STOP or RELEASE: sent and its answer awaited
        (`ok` None), answered (whether done), or no answer in time (False). Called in a
        thread of the link's own, in order; never of a STOP or RELEASE older than the
        last."""


class WebNode:
    """The web process's node: subscriptions to the server's outputs, the instruction topic
    (the page's moves, STOP and RELEASE, each naming its lease), and its lease: a client
    of the server as the Python client is, whose moves the server halts once it has lost
    it (`al5d.ros.leasing`)."""

    def __init__(
        self,
        names: Names,
        listener: Listener,
        model: ArmModel,
        presets: tuple[str, ...],
        joint_prefix: str = "",
    ) -> None:
        self.names = names
        #: Before the URDF's joint names on the server's topics (`server.joint_prefix`).
        self.joint_prefix = joint_prefix
        self.listener = listener
        self.model = model
        self.presets = presets
        #: Set once the server's state has been heard.
        self.heard = threading.Event()
        self.context = start_context()
        self.node = node = Node(
            f"al5d_web_{os.getpid()}", namespace=names.node_namespace, context=self.context
        )
        self.pub = node.create_publisher(ArmInstruction, names.instruction, QOS_INSTRUCTIONS)
        # The lease on a node of its own, which its own thread spins: this node's callbacks
        # wait for the page's lock, and a lease that waited with them would be held back
        # for a silence of the server that is the page's.
        self.lease_node = Node(
            f"al5d_web_lease_{os.getpid()}", namespace=names.node_namespace, context=self.context
        )
        #: Named in what the page sends, and sent while the page hears the server.
        self.lease = Leaser(self.lease_node, names, new_key("web-"))
        # rclpy's Python executor: two of its events executors in one process are what
        # `al5d_rig.rospeer.Peer` saw crash.
        self.lease_spinner = Spinner(
            self.lease_node, self.context, owns_context=False, kind="single"
        )
        #: The page's STOPs and RELEASEs, and what is said of them.
        self.buttons = StopRelease(self.send, self._on_answer)
        #: The ids of this page's set-points start with it.
        self.jog_prefix = f"web-jog-{os.getpid():x}-"
        self._jog_ids = itertools.count(1)
        # Readers of the jog ever matched and ever gone (the matched event's counts), and
        # both when the page last lost the server (`server_lost`).
        self._jog_seen = self._jog_mark = (0, 0)
        self.jog_pub = node.create_publisher(
            JointState,
            names.joint_commands,
            QOS_COMMANDS,
            event_callbacks=PublisherEventCallbacks(matched=self._on_jog_matched),
        )
        node.create_subscription(String, names.robot_description, self._on_description, QOS_LATCHED)
        node.create_subscription(JointState, names.joint_states, self._on_joints, QOS_LATEST)
        node.create_subscription(String, names.state, self._on_state, QOS_STATES)
        node.create_subscription(InstructionResult, names.result, self._on_result, QOS_OUTCOMES)
        node.create_subscription(
            ArmInstruction, names.instruction, self._on_instruction, QOS_LATEST
        )
        node.create_subscription(JointTrajectory, names.trajectory, self._on_trajectory, QOS_LATEST)
        node.create_subscription(TFMessage, "/tf_static", self._on_static, QOS_TF_STATIC)
        # Where an emulated arm truly stands, if one says (`al5d emulator --misalign`).
        PhysicalReader(node, names, model, listener.on_physical, prefix=joint_prefix)
        #: The local lane of a server of these names on this machine, where the STOP goes
        #: first (no discovery: `al5d.owner.quick`), if a server is there.
        self.lane = where.path(names.namespace)
        self.spinner = Spinner(node, self.context)

    # -- from the server ------------------------------------------------------------

    def _on_description(self, msg: String) -> None:
        self.listener.on_description(str(msg.data))

    def _on_joints(self, msg: JointState) -> None:
        names = [n.removeprefix(self.joint_prefix) for n in msg.name]
        self.listener.on_joints(names, list(msg.position), time.monotonic())

    def _on_state(self, msg: String) -> None:
        self.heard.set()
        self.listener.on_state(str(msg.data))

    def _on_result(self, msg: InstructionResult) -> None:
        if msg.instruction == PING:  # a client's handshake: no news of the arm
            return
        try:
            outcome = outcome_from_message(msg)
        except ValueError:  # an outcome word this page does not know: not the server's
            return
        self.buttons.on_outcome(outcome)
        self.listener.on_outcome(outcome)

    def _on_answer(self, text: str, ok: bool | None) -> None:
        self.listener.on_answer(text, ok)  # the listener of now: a page may set its own

    def _on_instruction(self, msg: ArmInstruction) -> None:
        instr = from_message(msg, self.presets, self.model)
        if not isinstance(instr, str):  # the server refuses it; its outcome will say why
            self.listener.on_instruction(instr)

    def _on_static(self, msg: TFMessage) -> None:
        """The arm's mount: base_link in a frame shared with other arms (`server.mount`)."""
        base = self.names.frame_prefix + BASE_LINK
        for t in msg.transforms:
            if t.child_frame_id == base:
                p, q = t.transform.translation, t.transform.rotation
                mount = Transform((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))
                self.listener.on_mount(str(t.header.frame_id), mount)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        instr = trajectory_from_message(msg, self.model, prefix=self.joint_prefix)
        if not isinstance(instr, str):
            self.listener.on_instruction(instr)

    # -- to the server ---------------------------------------------------------------

    def send(self, instr: Instruction) -> None:
        msg = to_message(instr)
        msg.client = self.lease.key
        self.pub.publish(msg)

    def jog(self, degrees: Mapping[str, float]) -> bool:
        """A set-point of the jog (the arm's degrees) on the server's stream of set-points,
        in the URDF's values as ros2_control's hardware sends them. False when no server
        reads the stream yet: a server just (re)started can send its joint states to this
        page before DDS has matched this writer to its reader, and the set-point is lost.
        After the page lost the server, a reader counts once one has matched or gone since:
        a killed server's reader stays matched until DDS notices it has gone (its lease,
        seconds), and a set-point sent to it alone reaches nobody; the new server's may have
        matched before the page noticed the loss (a busy host), and then counts once the
        killed one's has gone."""
        values = self.model.to_urdf(dict(degrees))
        msg = JointState(position=[float(v) for v in values.values()])
        msg.name = [self.joint_prefix + n for n in values]
        msg.header.stamp = self.node.get_clock().now().to_msg()
        # The set-point's id on the result topic (`convert.trajectory_id`): the page knows
        # its own jog's refusals by it. Marked new since any stop (the page lets its jog go
        # at one; a hand on a slider sent this), so that it resumes the server's stream of
        # set-points, held since a stop (`FRESH_MARK`; a set-point where the arm stands
        # would do too, but the newest set-point of the stream overwrites it, unread, on
        # a busy host: a CI run).
        msg.header.frame_id = f"{self.jog_prefix}{next(self._jog_ids)}{FRESH_MARK}"
        self.jog_pub.publish(msg)
        (matched, gone), (matched_then, gone_then) = self._jog_seen, self._jog_mark
        changed = matched > matched_then or gone > gone_then
        return self.jog_pub.get_subscription_count() > 0 and changed

    def server_lost(self) -> None:
        self._jog_mark = self._jog_seen

    def _on_jog_matched(self, info: QoSPublisherMatchedInfo) -> None:
        # One assignment: `jog`, on another thread, reads both counts of one event.
        self._jog_seen = (info.total_count, info.total_count - info.current_count)

    def stop(self) -> str:
        """The emergency stop (`StopRelease.stop`), by the lane of a server of these names on
        this machine if there is one; which way it went."""
        return self.buttons.stop(self.lane)

    def release(self) -> None:
        """The page's RELEASE (`StopRelease.release`)."""
        self.buttons.release()

    def close(self) -> None:
        self.buttons.close()
        self.lease.close([self.pub])
        self.lease_spinner.close()
        self.spinner.close()
