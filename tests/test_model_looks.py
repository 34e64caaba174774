"""The arm's looks, read back from the URDF by yourdfpy and built as solids by trimesh: at
each preset, with the gripper open and closed, every link's visuals meet its parent's (no
link floats), and the gripper's fingers open and close."""

from __future__ import annotations

import io
from collections.abc import Mapping

import numpy as np
import numpy.typing as npt
import pytest
import trimesh
import yourdfpy  # type: ignore[import-untyped]

from al5d.model import urdf
from al5d.model.chain import BASE_LINK, LINK_OF_JOINT
from al5d.model.looks import SERVO_SIZES_MM
from al5d_rig.model_support import MODEL, PRESETS, SPEEDS

TEXT = urdf(MODEL, SPEEDS)
#: The parts of two links touch when their solids share this much volume (m^3: a cube of
#: a tenth of a millimetre); a part that only grazes another, or floats, shares none.
SHARED_M3 = 1e-12
GRIPPER = {"open": 0.0, "closed": 90.0}


@pytest.fixture(scope="module")
def robot() -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(TEXT), build_scene_graph=True, load_meshes=False)


def parts(robot: yourdfpy.URDF, link: str) -> list[trimesh.Trimesh]:
    """A link's visuals as solids in base_link, for the robot's current joint values."""
    pose = robot.get_transform(frame_to=link, frame_from=BASE_LINK)
    solids = []
    for visual in robot.link_map[link].visuals:
        g = visual.geometry
        if g.box is not None:
            solid = trimesh.creation.box(extents=g.box.size)
        else:
            solid = trimesh.creation.cylinder(radius=g.cylinder.radius, height=g.cylinder.length)
        origin = visual.origin if visual.origin is not None else np.eye(4)
        solid.apply_transform(pose @ origin)
        solids.append(solid)
    return solids


def shared_volume(a: list[trimesh.Trimesh], b: list[trimesh.Trimesh]) -> float:
    """The most volume any part of `a` shares with any part of `b` (0: they do not meet)."""
    best = 0.0
    for pa in a:
        for pb in b:
            if not _boxes_overlap(pa.bounds, pb.bounds):
                continue
            both = trimesh.boolean.intersection([pa, pb], engine="manifold")
            if len(both.faces):
                with np.errstate(divide="ignore", invalid="ignore"):  # a flat one: no centre
                    best = max(best, float(both.volume))
    return best


def _boxes_overlap(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> bool:
    return bool(np.all(a[0] <= b[1]) and np.all(b[0] <= a[1]))


def configure(robot: yourdfpy.URDF, degrees: Mapping[str, float]) -> None:
    values = MODEL.to_urdf(degrees)
    robot.update_cfg({j: values[j] for j in robot.actuated_joint_names if j in values})


def linked_pairs(robot: yourdfpy.URDF) -> list[tuple[str, str]]:
    """(parent, child) of every joint whose links both have visuals (not the gap's frame, not
    tool0): the gripper's fingers hang from the hand."""
    return [
        (j.parent, j.child)
        for j in robot.robot.joints
        if robot.link_map[j.parent].visuals and robot.link_map[j.child].visuals
    ]


@pytest.mark.parametrize("gripper", GRIPPER)
@pytest.mark.parametrize("preset", ["park", "ready", "straight_up"])
def test_consecutive_links_meet_at_every_preset(
    robot: yourdfpy.URDF, preset: str, gripper: str
) -> None:
    configure(robot, {**PRESETS[preset], "gripper": GRIPPER[gripper]})
    pairs = linked_pairs(robot)
    assert len(pairs) == 7, pairs  # base to turntable to ... to the hand, and two fingers
    apart = [
        f"{parent} / {child}"
        for parent, child in pairs
        if shared_volume(parts(robot, parent), parts(robot, child)) < SHARED_M3
    ]
    assert not apart, f"at {preset}, gripper {gripper}: these links' visuals do not meet: {apart}"


def test_the_check_sees_a_link_that_floats(robot: yourdfpy.URDF) -> None:
    """The hand 2 mm further along its axis no longer meets the wrist."""
    configure(robot, PRESETS["ready"])
    wrist, hand = LINK_OF_JOINT["wrist"], LINK_OF_JOINT["wrist_rotate"]
    assert shared_volume(parts(robot, wrist), parts(robot, hand)) >= SHARED_M3
    along = robot.get_transform(frame_to=hand, frame_from=BASE_LINK)[:3, 2]
    moved = trimesh.transformations.translation_matrix(0.002 * along)
    off = [p.copy().apply_transform(moved) for p in parts(robot, hand)]
    assert shared_volume(parts(robot, wrist), off) < SHARED_M3


def test_the_fingers_open_and_close(robot: yourdfpy.URDF) -> None:
    left = LINK_OF_JOINT["gripper_left"]
    right = LINK_OF_JOINT["gripper_right"]

    def gap() -> float:
        a = np.vstack([p.vertices for p in parts(robot, left)])
        b = np.vstack([p.vertices for p in parts(robot, right)])
        # In the hand's frame the fingers face each other across y.
        hand = np.linalg.inv(robot.get_transform(frame_to=LINK_OF_JOINT["wrist_rotate"]))
        ya = trimesh.transform_points(a, hand)[:, 1]
        yb = trimesh.transform_points(b, hand)[:, 1]
        return float(ya.min() - yb.max())

    configure(robot, {**PRESETS["ready"], "gripper": GRIPPER["open"]})
    opened = gap()
    configure(robot, {**PRESETS["ready"], "gripper": GRIPPER["closed"]})
    closed = gap()
    assert opened == pytest.approx(MODEL.geometry.gripper_open, abs=1e-6)
    assert closed == pytest.approx(0.0, abs=1e-6)


def test_the_servos_are_drawn_at_their_sizes(robot: yourdfpy.URDF) -> None:
    """The shoulder's servo (an HS-805BB) is a box of its datasheet's size on the turntable."""
    sizes = {
        tuple(sorted(np.round(np.array(v.geometry.box.size) * 1000, 1)))
        for v in robot.link_map[LINK_OF_JOINT["base"]].visuals
        if v.geometry.box is not None
    }
    assert tuple(sorted(SERVO_SIZES_MM["HS-805BB"])) in sizes
