"""The twin's ROS node `al5d_twin`: its joints, its objects, its word, its camera.

In the twin's own process (`al5d.twin.run`), on a DDS participant of its own, with
rclpy's public API only: nothing of it runs in the server's or the board's process.

- `~/twin/joint_states` (`/al5d/twin/joint_states`): where the twin's joints are.
- `~/twin/objects` (visualization_msgs/MarkerArray): each object's shape, size, colour
  and pose in base_link, as RViz draws markers; `/tf`: each object's frame (its bottom's
  centre), named as the object, in base_link.
- `~/twin/held` (std_msgs/String): a joint held short of its target, in words.
- `camera/image_raw` (sensor_msgs/Image, rgb8) and `camera/camera_info`, in the frame
  `camera_optical_frame` (z forward, x right, y down), on `/tf_static` from base_link.
"""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np
import numpy.typing as npt
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from al5d.model.chain import BASE_LINK
from al5d.model.joints import GRIPPER_FINGERS
from al5d.model.transforms import Quat, Vec3, quat_mul, quat_rotate
from al5d.ros.dds import start_context
from al5d.ros.names import TWIN_NODE, Names
from al5d.ros.qos import profile
from al5d.ros.robot import QOS_TF_STATIC
from al5d.twin.camera import Intrinsics
from al5d.twin.physics import ObjectState
from al5d.twin.scene import CAMERA_OPTICAL_FRAME, Scene, rgba

#: The camera's pictures: reliable (a recording asks for what it missed) but only the
#: newest two kept, so that a slow reader never holds the twin up.
QOS_PICTURES = profile(2)
#: Its words: each one kept for a reader that is behind.
QOS_WORDS = profile(100)


def _transform(parent: str, child: str, xyz: Vec3, q: Quat, stamp: object) -> TransformStamped:
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = xyz
    r.x, r.y, r.z, r.w = q
    return msg


class TwinNode:
    """The node and its publishers; every publish is the caller's thread's (the twin's loop)."""

    def __init__(
        self,
        names: Names,
        scene: Scene,
        camera_pose: tuple[Vec3, Quat] | None,
        intrinsics: Intrinsics | None,
        joint_prefix: str = "",
    ) -> None:
        self.names = names
        #: Before each URDF joint name, as the server's own joint states and URDF have it
        #: (`server.joint_prefix`, or the namespace's: `left_`).
        self.joint_prefix = joint_prefix
        self.scene = scene
        self.base = names.frame_prefix + BASE_LINK
        self.context = start_context()
        self.node = node = Node(TWIN_NODE, namespace=names.node_namespace, context=self.context)
        self.joints = node.create_publisher(JointState, names.twin_joint_states, 10)
        self.objects = node.create_publisher(MarkerArray, names.twin_objects, 10)
        self.held = node.create_publisher(String, names.twin_held, QOS_WORDS)
        self.tf = node.create_publisher(TFMessage, "/tf", 100)
        self.tf_static = node.create_publisher(TFMessage, "/tf_static", QOS_TF_STATIC)
        self.image = node.create_publisher(Image, names.camera_image, QOS_PICTURES)
        self.info = node.create_publisher(CameraInfo, names.camera_info, QOS_PICTURES)
        self.optical = names.frame_prefix + CAMERA_OPTICAL_FRAME
        self._info = self._camera_info(intrinsics) if intrinsics is not None else None
        if camera_pose is not None:
            xyz, q = camera_pose
            # MuJoCo's camera looks down its -z with y up; the optical frame looks down +z
            # with y down: a half turn about x.
            optical = quat_mul(q, (1.0, 0.0, 0.0, 0.0))
            stamp = node.get_clock().now().to_msg()
            static = [_transform(self.base, self.optical, xyz, optical, stamp)]
            self.tf_static.publish(TFMessage(transforms=static))

    def stamp(self) -> object:
        return self.node.get_clock().now().to_msg()

    def publish_joints(self, values: Mapping[str, float], stamp: object) -> None:
        """The twin's joints, URDF names (prefixed) and values (the fingers' half gaps
        included)."""
        msg = JointState()
        msg.header.stamp = stamp
        names = [n for n in values if n != "gripper"] + ["gripper", *GRIPPER_FINGERS]
        gap = values["gripper"]
        msg.name = [self.joint_prefix + n for n in names]
        msg.position = [float(values[n]) for n in names[:-3]] + [gap, gap / 2, gap / 2]
        self.joints.publish(msg)

    def publish_objects(self, states: Mapping[str, ObjectState], stamp: object) -> None:
        markers = MarkerArray()
        tf = TFMessage()
        for i, (name, state) in enumerate(states.items()):
            obj = self.scene.objects[name]
            marker = Marker()
            marker.header.stamp = stamp
            marker.header.frame_id = self.base
            marker.ns = name
            marker.id = i
            marker.action = Marker.ADD
            height = obj.height / 1000
            if obj.size_mm is not None:
                marker.type = Marker.CUBE
                marker.scale.x, marker.scale.y, marker.scale.z = (v / 1000 for v in obj.size_mm)
            else:
                assert obj.radius_mm is not None
                marker.type = Marker.CYLINDER
                d = obj.radius_mm / 500
                marker.scale.x, marker.scale.y, marker.scale.z = d, d, height
            # A marker's pose is its shape's centre: half its height above its frame.
            up = quat_rotate(state.rotation, (0.0, 0.0, height / 2))
            p = marker.pose.position
            p.x, p.y, p.z = (a + b for a, b in zip(state.position, up, strict=True))
            q = marker.pose.orientation
            q.x, q.y, q.z, q.w = state.rotation
            c = marker.color
            c.r, c.g, c.b, c.a = rgba(obj.colour)
            marker.text = obj.shape
            markers.markers.append(marker)
            child = self.names.frame_prefix + name
            tf.transforms.append(
                _transform(self.base, child, state.position, state.rotation, stamp)
            )
        self.objects.publish(markers)
        self.tf.publish(tf)

    def publish_held(self, text: str) -> None:
        self.held.publish(String(data=text))

    def publish_picture(self, picture: npt.NDArray[np.uint8], stamp: object) -> None:
        height, width = picture.shape[:2]
        msg = Image()
        msg.header.stamp = stamp
        msg.header.frame_id = self.optical
        msg.height, msg.width = height, width
        msg.encoding = "rgb8"
        msg.step = width * 3
        msg.data = picture.tobytes()
        self.image.publish(msg)
        if self._info is not None:
            self._info.header.stamp = stamp
            self.info.publish(self._info)

    def _camera_info(self, k: Intrinsics) -> CameraInfo:
        info = CameraInfo()
        info.header.frame_id = self.optical
        info.width, info.height = k.width, k.height
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.p = [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        return info

    def close(self) -> None:
        self.node.destroy_node()
        self.context.try_shutdown()


def camera_pose(xpos: npt.NDArray[np.float64], xmat: npt.NDArray[np.float64]) -> tuple[Vec3, Quat]:
    """A MuJoCo camera's pose (its frame in base_link) as a position and a quaternion
    (x, y, z, w)."""
    wxyz = np.zeros(4)
    mujoco.mju_mat2Quat(wxyz, np.asarray(xmat, dtype=np.float64).reshape(9))
    w, x, y, z = (float(v) for v in wxyz)
    return (float(xpos[0]), float(xpos[1]), float(xpos[2])), (x, y, z, w)
