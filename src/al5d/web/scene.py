"""The page's 3D view: the arm from its URDF, the ghost of its target, the tool's straight
path, and the gizmo at the tool, all in the arm's base_link, which stands where its mount
puts it in the world (the grid). No lock and no ROS: the page calls it under its own lock.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt
import viser
import yourdfpy
from viser.extras import ViserUrdf

from al5d.model import ArmModel
from al5d.model.transforms import Transform, Vec3
from al5d.web.plan import Target

log = logging.getLogger("al5d.web")

GHOST_RGBA = (0.25, 0.55, 1.0, 0.35)
#: The camera a new page starts with, in base_link.
CAMERA: Vec3 = (0.42, -0.36, 0.34)
LOOK_AT: Vec3 = (0.04, 0.0, 0.15)
#: The node everything of the arm hangs from: base_link, at its mount's pose.
ROOT = "/base_link"
#: The gizmo while the server is lost: faint, and with nothing left to grab.
TARGET_OFF_OPACITY = 0.25


class ArmScene:
    """The arm, its ghost, the path and the target gizmo on one viser server."""

    def __init__(self, server: viser.ViserServer, model: ArmModel, joint_prefix: str = "") -> None:
        self.server = server
        self.model = model
        #: Before the joint names of the URDF the server describes (`server.joint_prefix`).
        self.joint_prefix = joint_prefix
        self.urdf_text: str | None = None
        self.robot: ViserUrdf | None = None
        self.ghost: ViserUrdf | None = None
        scene = server.scene
        server.initial_camera.position = CAMERA
        server.initial_camera.look_at = LOOK_AT
        # A browser without a GPU draws in software: with shadows (a pass of their own per
        # light) and the environment map's lighting a frame took 183 ms against 67 without
        # (p50, headless Chromium on 2 cores beside a test suite), and a state that comes
        # while a frame is drawn waits for it.
        scene.configure_default_lights(enabled=True, cast_shadow=False)
        scene.configure_environment_map(hdri=None)
        scene.add_grid("/grid", width=0.8, height=0.8, cell_size=0.05, section_size=0.2)
        self.mount = scene.add_frame(ROOT, show_axes=False)
        self.robot_root = scene.add_frame(f"{ROOT}/arm", show_axes=False)
        self.ghost_root = scene.add_frame(f"{ROOT}/ghost", show_axes=False, visible=False)
        self.path = scene.add_line_segments(
            f"{ROOT}/path", np.zeros((1, 2, 3)), (230, 120, 0), thickness=0.004, visible=False
        )
        self.target = scene.add_transform_controls(
            f"{ROOT}/target", scale=0.09, disable_rotations=True, depth_test=False, visible=False
        )
        self.target_enabled = True

    def on_target_drag(self, handler: Callable[[Any], None]) -> None:
        self.target.on_update(handler)

    def load(self, urdf: str) -> bool:
        """Show the arm of `urdf` (and its ghost); False if it is the one shown already."""
        if urdf == self.urdf_text:
            return False
        self.urdf_text = urdf
        if self.robot is not None and self.ghost is not None:
            self.robot.remove()
            self.ghost.remove()
        self.robot = ViserUrdf(self.server, _load_urdf(urdf), root_node_name=f"{ROOT}/arm")
        self.ghost = ViserUrdf(
            self.server,
            _load_urdf(urdf),
            root_node_name=f"{ROOT}/ghost",
            mesh_color_override=GHOST_RGBA,
        )
        return True

    def place_arm(self, mount: Transform) -> None:
        """base_link where its mount puts it in the world (the grid's frame); a new page's
        camera looks at the arm there."""
        x, y, z, w = mount.rotation
        with self.server.atomic():
            self.mount.position = mount.translation
            self.mount.wxyz = (w, x, y, z)
        self.server.initial_camera.position = mount.apply(CAMERA)
        self.server.initial_camera.look_at = mount.apply(LOOK_AT)

    def _cfg(self, urdf: ViserUrdf, degrees: Mapping[str, float]) -> npt.NDArray[np.float64]:
        values = {self.joint_prefix + n: v for n, v in self.model.to_urdf(degrees).items()}
        return np.array([values.get(n, 0.0) for n in urdf.get_actuated_joint_names()])

    def show_arm(self, degrees: Mapping[str, float]) -> None:
        if self.robot is not None:
            self.robot.update_cfg(self._cfg(self.robot, degrees))

    def show_ghost(self, target: Target | None) -> None:
        """The ghost at `target`'s pose, with its straight path if it has one; None: hidden."""
        if target is None or self.ghost is None:
            self.ghost_root.visible = False
            self.path.visible = False
            return
        with self.server.atomic():
            self.ghost.update_cfg(self._cfg(self.ghost, target.degrees))
            self.ghost_root.visible = True
            if len(target.line) >= 2:
                pts = np.array(target.line)
                self.path.points = np.stack([pts[:-1], pts[1:]], axis=1)
                self.path.visible = True
            else:
                self.path.visible = False

    @property
    def target_position(self) -> Vec3:
        x, y, z = (float(v) for v in self.target.position)
        return (x, y, z)

    def place_target(self, xyz_m: Vec3) -> None:
        """The gizmo at a point (metres, base_link), shown."""
        self.target.position = xyz_m
        self.target.visible = True

    def set_target_enabled(self, enabled: bool) -> None:
        """A gizmo that cannot be grabbed (no axis, no plane handle) and is faint, or the
        working one. viser has no disabled gizmo: this is the nearest to a greyed-out one."""
        if enabled == self.target_enabled:
            return
        self.target_enabled = enabled
        with self.server.atomic():
            self.target.disable_axes = not enabled
            self.target.disable_sliders = not enabled
            self.target.opacity = 1.0 if enabled else TARGET_OFF_OPACITY


def _load_urdf(text: str) -> yourdfpy.URDF:
    """A URDF from its text; its primitives (boxes, cylinders) become meshes."""
    return yourdfpy.URDF.load(
        io.StringIO(text),
        build_scene_graph=True,
        load_meshes=True,
        build_collision_scene_graph=False,
        load_collision_meshes=False,
    )
