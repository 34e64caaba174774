"""The page's 3D view: the arm from its URDF, the ghost of its target, the arm as it
physically stands where something knows it (an emulated arm's truth), the tool's straight
path, and the gizmo at the tool, all in the arm's base_link, which stands where its mount
puts it in the world (the grid). No lock and no ROS: the page calls it under its own lock.
"""

from __future__ import annotations

import io
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt
import viser
import yourdfpy
from viser.extras import ViserUrdf

from al5d.model import ArmModel, ModelError, joint_positions
from al5d.model.transforms import Transform, Vec3
from al5d.web.plan import Target

log = logging.getLogger("al5d.web")

GHOST_RGBA = (0.25, 0.55, 1.0, 0.35)
#: The arm as it physically stands (`physical_joint_states`: an emulated arm's truth).
PHYSICAL_RGBA = (1.0, 0.5, 0.05, 0.6)
#: The needles of a joint being calibrated: where the ghost has it, where it truly stands.
NEEDLE_COLOURS = {"ghost": (64, 140, 255), "physical": (255, 128, 13)}
#: Where a new page's camera looks from, as a direction from the arm (front right, above),
#: and how much of its field of view (viser's, 75 degrees high) the arm may take at most.
VIEW_FROM: Vec3 = (0.62, -0.53, 0.5)
VIEW_FOV_DEG = 75.0
VIEW_FILL = 0.85
#: What the drawn parts reach beyond the chain's points (the base, the servos, the gripper).
PARTS_M = 0.05
#: The node everything of the arm hangs from: base_link, at its mount's pose.
ROOT = "/base_link"
#: The gizmo while the server is lost: faint, and with nothing left to grab.
TARGET_OFF_OPACITY = 0.25


class ArmScene:
    """The arm, its ghost, the path and the target gizmo on one viser server."""

    def __init__(
        self,
        server: viser.ViserServer,
        model: ArmModel,
        presets: Iterable[Mapping[str, float]] = (),
        joint_prefix: str = "",
    ) -> None:
        self.server = server
        self.model = model
        self.camera, self.look_at = framing(model, presets)
        #: Before the joint names of the URDF the server describes (`server.joint_prefix`).
        self.joint_prefix = joint_prefix
        self.urdf_text: str | None = None
        #: The velocity limits of the URDF shown, by joint (its prefix taken off): the
        #: server's servo speeds.
        self.velocities: dict[str, float] = {}
        self.robot: ViserUrdf | None = None
        self.ghost: ViserUrdf | None = None
        self.physical: ViserUrdf | None = None
        scene = server.scene
        server.initial_camera.position = self.camera
        server.initial_camera.look_at = self.look_at
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
        self.physical_root = scene.add_frame(f"{ROOT}/physical", show_axes=False, visible=False)
        self.path = scene.add_line_segments(
            f"{ROOT}/path", np.zeros((1, 2, 3)), (230, 120, 0), thickness=0.004, visible=False
        )
        # A joint's direction, as the ghost has it and as the arm truly stands (calibration).
        self.needles = {
            which: scene.add_line_segments(
                f"{ROOT}/needle_{which}",
                np.zeros((1, 2, 3)),
                colour,
                thickness=0.003,
                visible=False,
            )
            for which, colour in NEEDLE_COLOURS.items()
        }
        self.target = scene.add_transform_controls(
            f"{ROOT}/target", scale=0.09, disable_rotations=True, depth_test=False, visible=False
        )
        self.target_enabled = True
        #: Where base_link stands in the world (the grid's frame): its mount.
        self.mount_pose = Transform()

    def on_target_drag(self, handler: Callable[[Any], None]) -> None:
        self.target.on_update(handler)

    def load(self, urdf: str) -> bool:
        """Show the arm of `urdf` (and its ghost); False if it is the one shown already."""
        if urdf == self.urdf_text:
            return False
        self.urdf_text = urdf
        for shown in (self.robot, self.ghost, self.physical):
            if shown is not None:
                shown.remove()
        robot = _load_urdf(urdf)
        self.velocities = {
            name.removeprefix(self.joint_prefix): joint.limit.velocity
            for name, joint in robot.joint_map.items()
            if joint.limit is not None and joint.limit.velocity
        }
        self.robot = ViserUrdf(self.server, robot, root_node_name=f"{ROOT}/arm")
        self.ghost = ViserUrdf(
            self.server,
            _load_urdf(urdf),
            root_node_name=f"{ROOT}/ghost",
            mesh_color_override=GHOST_RGBA,
        )
        self.physical = ViserUrdf(
            self.server,
            _load_urdf(urdf),
            root_node_name=f"{ROOT}/physical",
            mesh_color_override=PHYSICAL_RGBA,
        )
        return True

    def place_arm(self, mount: Transform) -> None:
        """base_link where its mount puts it in the world (the grid's frame); a new page's
        camera looks at the arm there."""
        self.mount_pose = mount
        x, y, z, w = mount.rotation
        with self.server.atomic():
            self.mount.position = mount.translation
            self.mount.wxyz = (w, x, y, z)
        self.server.initial_camera.position = mount.apply(self.camera)
        self.server.initial_camera.look_at = mount.apply(self.look_at)

    def _cfg(self, urdf: ViserUrdf, degrees: Mapping[str, float]) -> npt.NDArray[np.float64]:
        values = {self.joint_prefix + n: v for n, v in self.model.to_urdf(degrees).items()}
        return np.array([values.get(n, 0.0) for n in urdf.get_actuated_joint_names()])

    def aim(self, client: viser.ClientHandle, look_at: Vec3, position: Vec3) -> None:
        """One browser's camera at `position`, looking at `look_at` (both in base_link)."""
        camera = client.camera
        try:
            with client.atomic():
                camera.position = self.mount_pose.apply(position)
                camera.look_at = self.mount_pose.apply(look_at)
        except (AssertionError, ValueError):  # a browser that has not said its camera yet
            log.info("web: client %s: its camera is not known yet: left as it is", client)

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

    def show_physical(self, degrees: Mapping[str, float] | None) -> None:
        """The arm as it physically stands (None: hidden: nothing says where)."""
        if degrees is None or self.physical is None:
            self.physical_root.visible = False
            return
        with self.server.atomic():
            self.physical.update_cfg(self._cfg(self.physical, degrees))
            self.physical_root.visible = True

    def show_needles(self, needles: Mapping[str, tuple[Vec3, Vec3]]) -> None:
        """Each needle (`ghost`, `physical`) from its first point to its second; one not
        given is hidden."""
        with self.server.atomic():
            for which, handle in self.needles.items():
                needle = needles.get(which)
                if needle is None:
                    handle.visible = False
                else:
                    handle.points = np.array([needle])
                    handle.visible = True

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


def framing(model: ArmModel, presets: Iterable[Mapping[str, float]]) -> tuple[Vec3, Vec3]:
    """A new page's camera (its position, and where it looks, in base_link): from VIEW_FROM,
    as near as it can be with the arm at every preset (straight up, folded, and the base)
    within VIEW_FILL of the view's height and of as much of its width (a view at least as
    wide as it is high). The arm's extent is the model's own: its joints' points at each
    preset, and PARTS_M around them."""
    points = [(0.0, 0.0, 0.0), (0.0, 0.0, model.geometry.base_height)]
    for pose in presets:
        try:
            points += joint_positions(model.geometry, pose).values()
        except ModelError:
            continue  # a preset without every joint: the others frame the arm
    pts = np.array(points)
    low, high = pts.min(axis=0) - PARTS_M, pts.max(axis=0) + PARTS_M
    low[2] = max(low[2], 0.0)  # the table
    corners = np.array(
        [[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])]
    )
    centre = (low + high) / 2
    way = np.array(VIEW_FROM) / np.linalg.norm(VIEW_FROM)
    right = np.cross(-way, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, -way)
    reach = math.tan(math.radians(VIEW_FOV_DEG) / 2 * VIEW_FILL)

    def fits(distance: float) -> bool:
        seen = corners - (centre + way * distance)
        depth = seen @ -way
        if np.any(depth <= 0):
            return False
        return bool(np.all(np.abs(seen @ right) <= reach * depth)) and bool(
            np.all(np.abs(seen @ up) <= reach * depth)
        )

    near, far = 0.0, 1.0
    while not fits(far):
        far *= 2
    for _ in range(40):  # to well under a millimetre
        mid = (near + far) / 2
        near, far = (near, mid) if fits(mid) else (mid, far)
    x, y, z = (float(v) for v in centre + way * far)
    cx, cy, cz = (float(v) for v in centre)
    return (x, y, z), (cx, cy, cz)


def _load_urdf(text: str) -> yourdfpy.URDF:
    """A URDF from its text; its primitives (boxes, cylinders) become meshes."""
    return yourdfpy.URDF.load(
        io.StringIO(text),
        build_scene_graph=True,
        load_meshes=True,
        build_collision_scene_graph=False,
        load_collision_meshes=False,
    )
