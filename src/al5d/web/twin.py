"""The physical twin in the page (a server with `--physics`, docs/physics.md): the scene's
objects and the twin's arm in the 3D view beside the commanded one, the camera's picture
and the twin's words in a tab of their own.

Its own node and executor thread in the page's ROS context, its subscriptions best effort
and the newest only (nothing here can hold the twin up); each shown under the page's lock.
Nothing of it shows until the twin speaks: a page of a server without a twin is as it was.
"""

from __future__ import annotations

import collections
import html
import logging
import os
from typing import Any

import numpy as np
import trimesh
import viser
from rclpy.context import Context
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String
from viser.extras import ViserUrdf
from visualization_msgs.msg import Marker, MarkerArray

from al5d.ros.executors import Spinner
from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATEST
from al5d.web.link import QOS_OUTCOMES
from al5d.web.page import Page
from al5d.web.scene import ROOT
from al5d.web.scene import _load_urdf as load_urdf  # the page's own way to read a URDF

log = logging.getLogger("al5d.web")

#: The twin's arm: where the body is, drawn over the commanded arm.
TWIN_RGBA = (1.0, 0.55, 0.1, 0.55)
#: The twin's last words shown.
WORDS = 5


class TwinView:
    """The twin's objects, arm, picture and words on `page`, read in `context`."""

    def __init__(self, page: Page, context: Context, names: Names) -> None:
        self.page = page
        self.server: viser.ViserServer = page.server
        self.robot: ViserUrdf | None = None
        self.urdf: str | None = None
        self.objects: dict[str, Any] = {}
        self.picture: Any = None
        self.words_md: Any = None
        self.words: collections.deque[str] = collections.deque(maxlen=WORDS)
        self.root = self.server.scene.add_frame(f"{ROOT}/twin", show_axes=False)
        self.node = node = Node(
            f"al5d_web_twin_{os.getpid()}", namespace=names.node_namespace, context=context
        )
        node.create_subscription(JointState, names.twin_joint_states, self._on_joints, QOS_LATEST)
        node.create_subscription(MarkerArray, names.twin_objects, self._on_objects, QOS_LATEST)
        node.create_subscription(Image, names.camera_image, self._on_picture, QOS_LATEST)
        node.create_subscription(String, names.twin_held, self._on_held, QOS_OUTCOMES)
        self.spinner = Spinner(node, context, owns_context=False)

    def close(self) -> None:
        self.spinner.close()

    def _on_joints(self, msg: JointState) -> None:
        with self.page.lock:
            urdf = self.page.scene.urdf_text
            if urdf is None:
                return  # the arm's description has not come yet
            robot = self.robot
            if robot is None or urdf != self.urdf:
                if robot is not None:
                    robot.remove()
                self.urdf = urdf
                self.robot = robot = ViserUrdf(
                    self.server,
                    load_urdf(urdf),
                    root_node_name=f"{ROOT}/twin/arm",
                    mesh_color_override=TWIN_RGBA,
                )
            values = dict(zip(msg.name, msg.position, strict=False))
            names = robot.get_actuated_joint_names()
            robot.update_cfg(np.array([values.get(n, 0.0) for n in names]))

    def _on_objects(self, msg: MarkerArray) -> None:
        with self.page.lock, self.server.atomic():
            for marker in msg.markers:
                handle = self.objects.get(marker.ns)
                if handle is None:
                    handle = self.objects[marker.ns] = self._shape(marker)
                p, q = marker.pose.position, marker.pose.orientation
                handle.position = (p.x, p.y, p.z)
                handle.wxyz = (q.w, q.x, q.y, q.z)

    def _shape(self, marker: Marker) -> Any:
        name = f"{ROOT}/twin/objects/{marker.ns}"
        c = marker.color
        colour = (int(c.r * 255), int(c.g * 255), int(c.b * 255))
        s = marker.scale
        if marker.type == Marker.CUBE:
            return self.server.scene.add_box(name, colour, (s.x, s.y, s.z))
        # A cylinder (a cup is one, open at the top: its marker says so in its text).
        r = s.x / 2
        if marker.text == "cup":
            mesh = trimesh.creation.annulus(r_min=r * 0.85, r_max=r, height=s.z)
            floor = trimesh.creation.cylinder(radius=r, height=s.z * 0.05)
            floor.apply_translation((0, 0, -s.z * 0.475))
            mesh = trimesh.util.concatenate([mesh, floor])
        else:
            mesh = trimesh.creation.cylinder(radius=r, height=s.z)
        return self.server.scene.add_mesh_simple(
            name, np.asarray(mesh.vertices), np.asarray(mesh.faces), color=colour, side="double"
        )

    def _on_picture(self, msg: Image) -> None:
        if msg.encoding != "rgb8":
            return
        picture = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 3)
        with self.page.lock:
            if self.picture is None:
                self._tab()
            self.picture.image = picture

    def _on_held(self, msg: String) -> None:
        with self.page.lock:
            self.words.appendleft(str(msg.data))
            if self.words_md is None:
                self._tab()
            self.words_md.content = "\n".join(f"- {html.escape(w)}" for w in self.words)

    def _tab(self) -> None:
        """The Camera tab, made when the twin first speaks."""
        with self.page.panel.tabs.add_tab("Camera", viser.Icon.CAMERA):
            blank = np.zeros((240, 320, 3), dtype=np.uint8)
            self.picture = self.server.gui.add_image(blank, label="the twin's camera")
            self.words_md = self.server.gui.add_markdown("")
        log.info("web: the physical twin speaks: its camera and words in the Camera tab")
