"""What the arm looks like (pure): its links' visuals as boxes and cylinders made from the
geometry, for the URDF's `<visual>`s, so that RViz, MoveIt and the web view show one arm.

The AL5D's build: a round base housing on the table; the turntable on it, a cradle holding
the shoulder servo with its shaft on the shoulder axis; at each pitch joint (shoulder,
elbow, wrist) a servo body on the parent link, its shaft on the joint's axis, wrapped by
the child link's U-bracket, whose horns turn on the shaft; aluminium tubes between the
brackets and the next servo; on the wrist bracket the wrist rotate servo, shaft along the
hand; on its horn the gripper (its palm, its servo beside it, two fingers that slide).

Every joint is a shaft that both links hold (a servo body and the horns, a housing and
a turntable on one axis): consecutive links' visuals meet at every pose, never float
apart. The servos' sizes are Hitec's datasheets' (the usual AL5D build); they make the
look only. The collision shapes are the chain's single bodies (`chain.Shape`), which the
table check and MoveIt use: the looks change nothing that is judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, Literal

from al5d.model.geometry import Geometry
from al5d.model.transforms import Vec3

#: A cylinder turned from z onto y (the pitch joints' axes): URDF rpy.
ALONG_Y: Final[Vec3] = (math.pi / 2, 0.0, 0.0)
NO_TURN: Final[Vec3] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Shape:
    """A primitive in a link's frame: a box or a cylinder (along its own z), turned by `rpy`."""

    kind: Literal["box", "cylinder"]
    #: box: full sizes x, y, z; cylinder: (radius, length along z, 0).
    size: Vec3
    #: Centre of the primitive in the link frame.
    center: Vec3
    material: str
    rpy: Vec3 = NO_TURN


#: Hitec's servo bodies as their datasheets give them, length x width x height (mm): the
#: output shaft points along the height (its boss included), a quarter of the length from
#: one end.
SERVO_SIZES_MM: Final = {
    "HS-805BB": (66.0, 30.0, 57.6),
    "HS-755HB": (59.0, 29.0, 50.0),
    "HS-645MG": (40.6, 19.8, 37.8),
    "HS-485HB": (39.8, 19.8, 38.0),
    "HS-422": (40.6, 19.8, 36.6),
    "HS-225MG": (32.3, 16.8, 31.0),
}
#: The servo each joint has in the usual AL5D build (the look's; the configuration's `servo`
#: sets the speeds).
LOOK_SERVOS: Final = {
    "shoulder": "HS-805BB",
    "elbow": "HS-755HB",
    "wrist": "HS-645MG",
    "wrist_rotate": "HS-225MG",
    "gripper": "HS-422",
}

#: Aluminium plate and tube, horns (metres).
PLATE = 0.003
TUBE_RADIUS = 0.008
HORN_RADIUS = 0.012
#: What a part reaches into the one it is fixed to, so that no seam shows between them.
OVERLAP = 0.001
#: The turntable's radius, and the base housing's.
TURNTABLE_RADIUS = 0.045
BASE_RADIUS = 0.048
#: A U-bracket's cross plate clears its servo's body by this much (metres).
BRACKET_CLEARANCE = 0.006


def _servo(name: str) -> tuple[float, float, float]:
    length, width, height = SERVO_SIZES_MM[name]
    return length / 1000, width / 1000, height / 1000


def _box(size: Vec3, center: Vec3, material: str) -> Shape:
    return Shape("box", size, center, material)


def _rod(radius: float, z0: float, z1: float, material: str, x: float = 0.0) -> Shape:
    """A cylinder along the link's z from z0 to z1."""
    return Shape("cylinder", (radius, z1 - z0, 0.0), (x, 0.0, (z0 + z1) / 2), material)


def _servo_on_axis(
    name: str, z_axis: float, x: float = 0.0, lying: bool = False
) -> tuple[Shape, float]:
    """A pitch joint's servo on the parent link: its shaft on the axis at `z_axis` (along
    y), its body along the link, most of it before the axis (`lying`: back along -x, as
    the shoulder's lies on the turntable). The body, and how far its sides reach from the
    axis where the child link turns (what the child's bracket must clear)."""
    length, width, height = _servo(name)
    back, ahead = 0.75 * length, 0.25 * length
    if lying:
        body = _box((length, height, width), (x + (ahead - back) / 2, 0.0, z_axis), "dark")
    else:
        body = _box((width, height, length), (x, 0.0, z_axis + (ahead - back) / 2), "dark")
    return body, max(width / 2, ahead)


def _u_bracket(servo: str, reach: float) -> tuple[tuple[Shape, ...], float]:
    """The child link's U-bracket around its joint's servo (the link's origin on the axis):
    two side plates with their horns on the shaft, joined by a cross plate beyond the servo.
    The shapes, and where the cross plate ends along the link."""
    _, _, height = _servo(servo)
    side = height / 2 + PLATE / 2
    cross = reach + BRACKET_CLEARANCE
    end = cross + PLATE
    plate_len = end + HORN_RADIUS
    shapes: list[Shape] = []
    for y in (side, -side):
        shapes.append(
            _box((2 * HORN_RADIUS, PLATE, plate_len), (0, y, (end - HORN_RADIUS) / 2), "metal")
        )
        # The horn: on the shaft, into the servo's side a little (the two are one at the axis).
        horn_y = y - math.copysign(OVERLAP, y) / 2
        shapes.append(
            Shape("cylinder", (HORN_RADIUS, PLATE + OVERLAP, 0.0), (0, horn_y, 0), "white", ALONG_Y)
        )
    shapes.append(
        _box((2 * HORN_RADIUS, 2 * side + PLATE, PLATE), (0, 0, cross + PLATE / 2), "metal")
    )
    return tuple(shapes), end


def link_looks(
    g: Geometry, finger_len: float, finger: tuple[float, float]
) -> dict[str, tuple[Shape, ...]]:
    """Every link's visuals by the joint that moves it ("root": base_link; the fingers by
    their joints' names `left` and `right`), in each link's frame: the link's origin on its
    joint's axis, z along the link, every joint at 0 with the arm straight up.

    `finger_len` and `finger` (width, thickness) are the chain's fingers, whose frames sit at
    the fingers' inner faces, `finger_len` before the tool tip."""
    looks: dict[str, tuple[Shape, ...]] = {}
    housing = min(0.04, 0.6 * g.base_height)
    looks["root"] = (
        _rod(BASE_RADIUS, 0.0, housing, "dark"),
        # The base servo's horn on top, under the turntable.
        _rod(HORN_RADIUS, housing - OVERLAP, housing + OVERLAP, "white"),
    )

    # The turntable: a plate on the housing (one axis: they meet at any angle), a cradle,
    # and the shoulder servo on the shoulder axis.
    x0 = g.shoulder_offset
    top = housing + PLATE
    shoulder, shoulder_reach = _servo_on_axis(
        LOOK_SERVOS["shoulder"], g.base_height, x0, lying=True
    )
    s_length, s_height, _ = shoulder.size
    s_bottom = shoulder.center[2] - shoulder.size[2] / 2
    # The cradle, from the plate up into the servo (at least a plate's thickness).
    cradle_top = max(s_bottom, top) + OVERLAP
    looks["base"] = (
        _rod(TURNTABLE_RADIUS, housing - OVERLAP, top, "metal"),
        _box(
            (s_length, s_height + 2 * PLATE, cradle_top - top + OVERLAP),
            (shoulder.center[0], 0.0, (top - OVERLAP + cradle_top) / 2),
            "metal",
        ),
        shoulder,
    )

    # The upper arm: the U around the shoulder servo, a tube, the elbow servo at its end.
    u_parts, u_end = _u_bracket(LOOK_SERVOS["shoulder"], shoulder_reach)
    elbow, elbow_reach = _servo_on_axis(LOOK_SERVOS["elbow"], g.humerus)
    elbow_bottom = elbow.center[2] - elbow.size[2] / 2
    looks["shoulder"] = (
        *u_parts,
        _rod(TUBE_RADIUS, u_end - OVERLAP, max(elbow_bottom, u_end) + OVERLAP, "metal"),
        elbow,
    )

    # The forearm: the U around the elbow servo, a tube, the wrist servo at its end.
    u_parts, u_end = _u_bracket(LOOK_SERVOS["elbow"], elbow_reach)
    wrist, wrist_reach = _servo_on_axis(LOOK_SERVOS["wrist"], g.ulna)
    wrist_bottom = wrist.center[2] - wrist.size[2] / 2
    looks["elbow"] = (
        *u_parts,
        _rod(TUBE_RADIUS, u_end - OVERLAP, max(wrist_bottom, u_end) + OVERLAP, "metal"),
        wrist,
    )

    # The wrist: the U around the wrist servo, the wrist rotate servo on it (shaft along z).
    u_parts, u_end = _u_bracket(LOOK_SERVOS["wrist"], wrist_reach)
    finger_origin = g.gripper - finger_len
    r_length, r_width, r_height = _servo(LOOK_SERVOS["wrist_rotate"])
    # Shortened where the geometry's hand is too short for it (the look only).
    r_top = max(min(u_end + r_height, finger_origin - 2 * PLATE), u_end + PLATE)
    looks["wrist"] = (
        *u_parts,
        _box(
            (r_length, r_width, r_top - u_end + OVERLAP),
            (0, 0, (u_end - OVERLAP + r_top) / 2),
            "dark",
        ),
    )

    # The hand: the horn on the wrist rotate shaft, the palm the fingers slide on, its servo.
    width, thickness = finger
    horn_top = r_top + PLATE
    palm_bottom = min(horn_top, finger_origin - PLATE) - OVERLAP
    g_length, g_width, g_height = _servo(LOOK_SERVOS["gripper"])
    reach_y = g.gripper_open / 2 + thickness
    palm_z = finger_origin - palm_bottom + OVERLAP
    looks["wrist_rotate"] = (
        _rod(HORN_RADIUS, r_top - OVERLAP, horn_top, "white"),
        _box((width, 2 * reach_y, palm_z), (0, 0, palm_bottom + palm_z / 2), "metal"),
        # The gripper's servo, beside the palm.
        _box(
            (g_height, g_length, g_width),
            (width / 2 + g_height / 2 - OVERLAP, 0, finger_origin - g_width / 2),
            "dark",
        ),
    )
    # A finger (its frame at its inner face, on the palm): from inside the palm to the tip.
    for name, side in (("left", 1.0), ("right", -1.0)):
        looks[name] = (
            _box(
                (width, thickness, finger_len + OVERLAP),
                (0, side * thickness / 2, (finger_len - OVERLAP) / 2),
                "dark",
            ),
        )
    return looks
