"""The arm as ROS sees a robot: its description, its joint states and its transforms.

- `/robot_description` (std_msgs/String, reliable, transient local, depth 1): the
  URDF generated from the configuration, as robot_state_publisher offers it.
- `/joint_states`: the URDF's joint names (behind `server.joint_prefix`: `left_base`),
  REP 103 values (radians, the gap in metres for `gripper`), at the joint-state rate.
- `/tf` at the same rate and `/tf_static` once (latched), base_link to tool0; with a
  mount (`server.mount`), `/tf_static` also holds base_link in the mount's parent frame
  (`world`), so that several arms are one tree.
- `~/tool_pose` (`/al5d/tool_pose`, geometry_msgs/PoseStamped): tool0 in base_link.

Names are relative (`robot_description`, `joint_states`) or private, so that a
namespace puts them under it; `/tf` and `/tf_static` are the one shared tree,
where a namespaced arm's frames carry its prefix.

The one mapping from the arm's degrees to these values is the model's
(`ArmModel.to_urdf`, from `al5d.model.joints.CONVENTIONS`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from al5d.arm.config import ArmConfig
from al5d.model import build_chain, joint_transforms, tool_pose, urdf_from_chain
from al5d.model.transforms import Transform
from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATCHED, profile

#: /tf_static: every transform kept for late joiners (tf2's own profile: depth 1 would
#: do for one message, but other static broadcasters share the topic).
QOS_TF_STATIC = profile(100, latched=True)


def _transform(parent: str, child: str, t: Transform, stamp: object) -> TransformStamped:
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    (msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z) = (
        t.translation
    )
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = t.rotation
    return msg


class RobotPublisher:
    """Publishes the robot's description, joint states, transforms and tool pose for a node."""

    def __init__(self, node: Node, config: ArmConfig, names: Names) -> None:
        self.node = node
        self.model = config.model
        self.chain = build_chain(
            self.model,
            config.speeds_deg_s,
            prefix=names.frame_prefix,
            joint_prefix=config.server.joint_name_prefix,
        )
        self.description = node.create_publisher(String, names.robot_description, QOS_LATCHED)
        self.joint_states = node.create_publisher(JointState, names.joint_states, 10)
        self.tf = node.create_publisher(TFMessage, "/tf", 100)
        self.tf_static = node.create_publisher(TFMessage, "/tf_static", QOS_TF_STATIC)
        self.tool_pose = node.create_publisher(PoseStamped, names.tool_pose, 10)
        #: The joints of /joint_states, as the URDF names them (behind the joint prefix).
        self.names = list(self.chain.movable)
        self._keys = [self.chain.key(n) for n in self.names]
        self._last_degrees: dict[str, float] | None = None
        self._states_msg = JointState()
        self._tf_msg = TFMessage()
        self._pose_msg = PoseStamped()
        self._headers: list[Any] = []
        self._moving = [j for j in self.chain.joints if j.type != "fixed"]
        self._fixed = [j for j in self.chain.joints if j.type == "fixed"]
        self.description.publish(String(data=urdf_from_chain(self.chain, "al5d")))
        stamp = node.get_clock().now().to_msg()
        steps = joint_transforms(self.chain, dict.fromkeys(self._keys, 0.0))
        static = [_transform(j.parent, j.child, steps[j.name], stamp) for j in self._fixed]
        mount = config.server.mount
        if mount is not None:
            frame = mount.frame()
            static.insert(0, _transform(frame.parent, self.chain.root, frame.transform, stamp))
        self.tf_static.publish(TFMessage(transforms=static))

    def publish(self, degrees: Mapping[str, float]) -> bool:
        """Joint states, /tf and the tool pose for the arm's degrees (NaN: unknown yet);
        whether the degrees differ from the last published."""
        if any(v != v for v in degrees.values()):
            return False  # before the first read-back: nothing true to say
        stamp = self.node.get_clock().now().to_msg()
        changed = degrees != self._last_degrees
        if changed:
            self._build(degrees, stamp)
        else:  # an arm at rest: the same messages, stamped anew
            for header in self._headers:
                header.stamp = stamp
        self.joint_states.publish(self._states_msg)
        self.tf.publish(self._tf_msg)
        self.tool_pose.publish(self._pose_msg)
        return changed

    def _build(self, degrees: Mapping[str, float], stamp: object) -> None:
        values = self.model.to_urdf(degrees)
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = self.names
        msg.position = [values[k] for k in self._keys]
        steps = joint_transforms(self.chain, values)
        transforms = [_transform(j.parent, j.child, steps[j.name], stamp) for j in self._moving]
        pose = tool_pose(self.chain, values)
        out = PoseStamped()
        out.header.stamp = stamp
        out.header.frame_id = self.chain.root
        p, q = out.pose.position, out.pose.orientation
        p.x, p.y, p.z = pose.translation
        q.x, q.y, q.z, q.w = pose.rotation
        self._states_msg, self._tf_msg, self._pose_msg = msg, TFMessage(transforms=transforms), out
        self._headers = [msg.header, out.header, *(t.header for t in transforms)]
        self._last_degrees = dict(degrees)
