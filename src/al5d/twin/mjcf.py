"""The twin's MuJoCo model (MJCF text), made from the same robot model as the URDF.

The links and joints are `al5d.model.build_chain`'s (the URDF's): each link's shape is its
collision and visual geometry, and its mass is the shape's volume at the density of what
it is made of plus the servos it carries (their masses from `al5d.arm.servos`), so that
its inertia follows from the geometry. The joints keep the configuration's ranges. Each
servo is a position actuator whose force never exceeds its stall torque, with the
motor's back-EMF as damping (no-load, it turns at its datasheet speed and no faster), its
rotor's inertia and its gears' friction. The gripper's servo drives both fingers through
a tendon (its shaft, in servo radians) and squeezes with its stall torque over the
gears' lever; an equality keeps the fingers symmetric, as the real gripper's gears do.

Pure: builds text, imports no MuJoCo.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Final

from al5d.arm.config import ArmConfig
from al5d.arm.servos import SERVOS, USUAL_SERVO, ServoModel
from al5d.model import ARM_JOINTS, build_chain
from al5d.model.chain import Chain
from al5d.model.joints import GRIPPER_FINGERS
from al5d.model.looks import Shape
from al5d.model.transforms import quat_from_rpy
from al5d.model.urdf import MATERIALS
from al5d.twin.scene import Scene, SceneObject, rgba

#: kg cm -> N m.
KG_CM: Final = 0.0980665
#: The density of each material's envelope (kg/m^3): the brackets and tubes fill about a
#: seventh of their box ("metal"), the plastic and the servos' cases most of theirs.
DENSITY: Final[Mapping[str, float]] = {"metal": 400.0, "dark": 1200.0}
#: A servo accelerates to its no-load speed in about this long at stall torque: its rotor's
#: inertia seen through the gears (the armature), J = torque * t / speed.
MECHANICAL_TIME_S: Final = 0.02
#: The servo gives its stall torque once this far from its target (its proportional band).
FULL_TORQUE_AT_DEG: Final = 2.0
#: Its gears' friction, as a share of the stall torque: what holds a limp servo.
GEAR_FRICTION: Final = 0.04
#: Contact bits: the arm touches the world (table, objects), never itself.
ARM_BIT, WORLD_BIT = 1, 2
#: The fingers' pads.
FINGER_FRICTION: Final = 1.2
#: A cup's wall is this many flat pieces.
CUP_SEGMENTS: Final = 12
TABLE_THICKNESS: Final = 0.02
#: An object in the gripper (`in_gripper`) has its bottom this far beyond the fingers' tips.
IN_GRIPPER_BELOW: Final = 0.01
#: The room's floor, under the table.
FLOOR_DEPTH: Final = 0.75
#: Where each servo sits (the link that carries it, its box's centre in that link's frame
#: as a function of the geometry, and whether it shows): beside the joint it turns, on the
#: real AL5D. The wrist rotate's and the gripper's are inside their link's block.
SERVO_BOX: Final[Mapping[str, tuple[float, float, float]]] = {
    "HS-805BB": (0.030, 0.066, 0.057),
    "HS-755HB": (0.029, 0.059, 0.050),
}
STANDARD_BOX: Final = (0.020, 0.040, 0.037)


@dataclass(frozen=True)
class Drive:
    """One servo as the twin models it, in the joint's units (rad, or for the gripper the
    servo's own radians on its tendon)."""

    joint: str
    servo: str
    stall_nm: float
    speed_rad_s: float
    #: Position gain: stall torque at FULL_TORQUE_AT_DEG from the target.
    kp: float
    #: Its controller's damping (within the stall torque): critical with the rotor alone;
    #: the twin tunes it to the arm it moves (`al5d.twin.physics.Twin`).
    kv: float
    #: The motor's back-EMF: stall torque / no-load speed.
    damping: float
    armature: float
    frictionloss: float

    @property
    def stall_kg_cm(self) -> float:
        return self.stall_nm / KG_CM


def servo_of(config: ArmConfig, joint: str) -> ServoModel:
    """The joint's servo: the configuration's model, else the usual AL5D's for that joint."""
    name = config.joints[joint].servo or USUAL_SERVO[joint]
    return SERVOS[name]


def gripper_lever(config: ArmConfig) -> float:
    """Metres of gap per radian of the gripper's servo."""
    return config.model.gripper_map.metres_per_deg * 180 / math.pi


def drives(config: ArmConfig) -> dict[str, Drive]:
    """Every joint's servo as the twin models it, by the arm's joint name."""
    out = {}
    for joint in (*ARM_JOINTS, "gripper"):
        servo = servo_of(config, joint)
        stall = servo.stall_kg_cm * KG_CM
        speed = math.radians(config.joints[joint].speed_deg_s)  # the configuration's wins
        kp = stall / math.radians(FULL_TORQUE_AT_DEG)
        armature = stall * MECHANICAL_TIME_S / speed
        damping = stall / speed
        kv = max(0.0, 2 * math.sqrt(kp * armature) - damping)
        out[joint] = Drive(
            joint, servo.name, stall, speed, kp, kv, damping, armature, stall * GEAR_FRICTION
        )
    return out


def _f(values: Iterable[float]) -> str:
    return " ".join(f"{v:.10g}" for v in values)


def _wxyz(rpy: tuple[float, float, float]) -> str:
    x, y, z, w = quat_from_rpy(*rpy)
    return _f((w, x, y, z))


def _geom(parent: ET.Element, shape: Shape, name: str, *, collide: bool = True) -> None:
    density = DENSITY.get(shape.material, DENSITY["dark"])
    attrs = {
        "name": name,
        "pos": _f(shape.center),
        "density": f"{density:g}",
        "material": shape.material,
        "contype": str(ARM_BIT if collide else 0),
        "conaffinity": str(WORLD_BIT if collide else 0),
    }
    if shape.kind == "box":
        attrs |= {"type": "box", "size": _f(s / 2 for s in shape.size)}
    else:
        attrs |= {"type": "cylinder", "size": _f((shape.size[0], shape.size[1] / 2))}
    ET.SubElement(parent, "geom", attrs)


def _servo_geom(
    parent: ET.Element, servo: ServoModel, pos: tuple[float, float, float], visible: bool
) -> None:
    size = SERVO_BOX.get(servo.name, STANDARD_BOX)
    ET.SubElement(
        parent,
        "geom",
        name=f"servo_{parent.get('name')}",
        type="box",
        size=_f(s / 2 for s in size),
        pos=_f(pos),
        mass=f"{servo.mass_g / 1000:g}",
        material="dark",
        contype="0",
        conaffinity="0",
        group="0" if visible else "3",
    )


def _servos(config: ArmConfig, bodies: Mapping[str, ET.Element], chain: Chain) -> None:
    """Each servo's mass on the link that carries it (the base's stands on the table)."""
    g = config.model.geometry
    beside = 0.045
    wrist_block = chain.link(chain.prefix + "wrist_link").shape
    hand_block = chain.link(chain.prefix + "hand_link").shape
    assert wrist_block is not None and hand_block is not None
    _servo_geom(bodies["base"], servo_of(config, "shoulder"), (0, beside, g.base_height), True)
    _servo_geom(bodies["shoulder"], servo_of(config, "elbow"), (0, beside, g.humerus), True)
    _servo_geom(bodies["elbow"], servo_of(config, "wrist"), (0, 0.028, g.ulna), True)
    _servo_geom(bodies["wrist"], servo_of(config, "wrist_rotate"), wrist_block.center, False)
    _servo_geom(bodies["wrist_rotate"], servo_of(config, "gripper"), hand_block.center, False)


def _object(
    world: ET.Element, hand: ET.Element, tip: float, name: str, obj: SceneObject, table_z: float
) -> None:
    """The object standing in the world, or fixed in the `hand` between the fingers (its
    bottom `IN_GRIPPER_BELOW` beyond the tip at `tip`, upright when the gripper points down)."""
    if obj.xyz_mm is None:
        body = ET.SubElement(
            hand, "body", name=name, pos=_f((0, 0, tip + IN_GRIPPER_BELOW)), quat="0 1 0 0"
        )
    else:
        x, y, z = (v / 1000 for v in obj.xyz_mm)
        body = ET.SubElement(
            world,
            "body",
            name=name,
            pos=_f((x, y, table_z + z)),
            quat=_wxyz((0.0, 0.0, math.radians(obj.yaw_deg))),
        )
        ET.SubElement(body, "freejoint", name=name)
    pieces: list[dict[str, str]] = []
    volume = 0.0
    if obj.size_mm is not None:
        sx, sy, sz = (v / 1000 for v in obj.size_mm)
        pieces.append(
            {"type": "box", "size": _f((sx / 2, sy / 2, sz / 2)), "pos": _f((0, 0, sz / 2))}
        )
        volume = sx * sy * sz
    else:
        assert obj.radius_mm is not None and obj.height_mm is not None
        r, h = obj.radius_mm / 1000, obj.height_mm / 1000
        if obj.shape == "cylinder":
            pieces.append({"type": "cylinder", "size": _f((r, h / 2)), "pos": _f((0, 0, h / 2))})
            volume = math.pi * r * r * h
        else:
            assert obj.wall_mm is not None
            wall = obj.wall_mm / 1000
            pieces.append(
                {"type": "cylinder", "size": _f((r, wall / 2)), "pos": _f((0, 0, wall / 2))}
            )
            volume = math.pi * r * r * wall
            mid = r - wall / 2
            width = 2 * mid * math.tan(math.pi / CUP_SEGMENTS) + wall / 2
            wall_h = h - wall
            for i in range(CUP_SEGMENTS):
                a = 2 * math.pi * i / CUP_SEGMENTS
                pieces.append(
                    {
                        "type": "box",
                        "size": _f((wall / 2, width / 2, wall_h / 2)),
                        "pos": _f((mid * math.cos(a), mid * math.sin(a), wall + wall_h / 2)),
                        "quat": _wxyz((0.0, 0.0, a)),
                    }
                )
                volume += wall * width * wall_h
    density = obj.mass_g / 1000 / volume
    r_, g_, b_, _ = rgba(obj.colour)
    for i, piece in enumerate(pieces):
        ET.SubElement(
            body,
            "geom",
            piece,
            name=f"{name}_{i}",
            density=f"{density:.6g}",
            friction=f"{obj.friction:g} 0.005 0.0001",
            rgba=_f((r_, g_, b_, 1.0)),
            contype=str(WORLD_BIT),
            conaffinity=str(ARM_BIT | WORLD_BIT),
        )


def _camera(world: ET.Element, scene: Scene, table_z: float) -> None:
    cam = scene.camera
    if cam is None:
        return
    pos = [v / 1000 for v in cam.position_mm]
    at = [v / 1000 for v in cam.look_at_mm]
    pos[2] += table_z
    at[2] += table_z
    fwd = [a - p for a, p in zip(at, pos, strict=True)]
    n = math.sqrt(sum(v * v for v in fwd))
    fwd = [v / n for v in fwd]
    # x to the picture's right (forward x up), y its up (x x forward).
    right = [fwd[1], -fwd[0], 0.0]
    rn = math.hypot(right[0], right[1])
    right = [1.0, 0.0, 0.0] if rn < 1e-9 else [v / rn for v in right]
    up = [
        right[1] * fwd[2] - right[2] * fwd[1],
        right[2] * fwd[0] - right[0] * fwd[2],
        right[0] * fwd[1] - right[1] * fwd[0],
    ]
    ET.SubElement(
        world,
        "camera",
        name="camera",
        pos=_f(pos),
        xyaxes=_f([*right, *up]),
        fovy=f"{cam.fovy_deg:g}",
    )


def mjcf(config: ArmConfig, scene: Scene) -> str:
    """The twin's MJCF: the arm of `config` (its chain, servos, ranges) in `scene`."""
    chain = build_chain(config.model, config.speeds_deg_s)
    g = config.model.geometry
    table_z = g.table_height
    servos = drives(config)
    root = ET.Element("mujoco", model="al5d_twin")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="true")
    ET.SubElement(
        root,
        "option",
        timestep=f"{scene.physics.step_ms / 1000:g}",
        integrator="implicitfast",
        cone="elliptic",
        impratio="10",
    )
    visual = ET.SubElement(root, "visual")
    cam = scene.camera
    width, height = (cam.width, cam.height) if cam is not None else (320, 240)
    ET.SubElement(visual, "global", offwidth=str(max(width, 64)), offheight=str(max(height, 64)))
    ET.SubElement(visual, "headlight", ambient="0.35 0.35 0.35", diffuse="0.5 0.5 0.5")
    ET.SubElement(visual, "quality", shadowsize="1024")
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "geom", solref="0.004 1", solimp="0.95 0.99 0.0005")
    asset = ET.SubElement(root, "asset")
    for name, colour in MATERIALS.items():
        ET.SubElement(asset, "material", name=name, rgba=_f(colour))
    ET.SubElement(
        asset,
        "texture",
        name="floor",
        type="2d",
        builtin="checker",
        rgb1="0.32 0.34 0.37",
        rgb2="0.27 0.29 0.32",
        width="256",
        height="256",
    )
    ET.SubElement(asset, "material", name="floor", texture="floor", texrepeat="8 8")

    world = ET.SubElement(root, "worldbody")
    ET.SubElement(
        world,
        "light",
        name="sun",
        directional="true",
        pos="0 0 2",
        dir="0.3 0.4 -1",
        diffuse="0.55 0.55 0.55",
        castshadow="false",
    )
    ET.SubElement(
        world,
        "geom",
        name="floor",
        type="plane",
        size="3 3 0.05",
        pos=_f((0, 0, table_z - FLOOR_DEPTH)),
        material="floor",
        contype=str(WORLD_BIT),
        conaffinity=str(ARM_BIT | WORLD_BIT),
    )
    t = scene.table
    ET.SubElement(
        world,
        "geom",
        name="table",
        type="box",
        size=_f((t.size_mm[0] / 2000, t.size_mm[1] / 2000, TABLE_THICKNESS / 2)),
        pos=_f((t.center_mm[0] / 1000, t.center_mm[1] / 1000, table_z - TABLE_THICKNESS / 2)),
        rgba=_f(rgba(t.colour)),
        friction=f"{t.friction:g} 0.005 0.0001",
        contype=str(WORLD_BIT),
        conaffinity=str(ARM_BIT | WORLD_BIT),
    )
    _camera(world, scene, table_z)
    base = ET.SubElement(world, "body", name=chain.root)
    base_shape = chain.link(chain.root).shape
    assert base_shape is not None
    # The housing stands on the table: part of the world, touching nothing.
    _geom(base, base_shape, chain.root, collide=False)

    bodies: dict[str, ET.Element] = {chain.root: base}
    by_joint: dict[str, ET.Element] = {}
    for joint in chain.joints:
        parent = bodies[joint.parent]
        if joint.type == "fixed":
            ET.SubElement(parent, "site", name=joint.child, pos=_f(joint.xyz), size="0.004")
            continue
        if joint.name == "gripper":  # the gap itself: the fingers move, the tendon is the servo
            continue
        body = ET.SubElement(
            parent, "body", name=joint.child, pos=_f(joint.xyz), quat=_wxyz(joint.rpy)
        )
        bodies[joint.child] = body
        by_joint[joint.name] = body
        assert joint.limit is not None
        attrs = {
            "name": joint.name,
            "type": "hinge" if joint.type == "revolute" else "slide",
            "axis": _f(joint.axis),
            "range": _f((joint.limit.lower, joint.limit.upper)),
        }
        if joint.name in servos:
            d = servos[joint.name]
            attrs |= {
                "damping": f"{d.damping:.6g}",
                "armature": f"{d.armature:.6g}",
                "frictionloss": f"{d.frictionloss:.6g}",
            }
        ET.SubElement(body, "joint", attrs)
        shape = chain.link(joint.child).shape
        if shape is not None:
            _geom(body, shape, joint.child)
            if joint.name in GRIPPER_FINGERS:
                finger = body[-1]
                finger.set("friction", f"{FINGER_FRICTION:g} 0.01 0.0001")
                finger.set("condim", "4")
    _servos(config, by_joint, chain)

    for name, obj in scene.objects.items():
        _object(world, by_joint["wrist_rotate"], g.gripper, name, obj, table_z)
        if obj.goal_mm is not None:  # where it is meant to go: a mark on the table, no body
            gx, gy = (v / 1000 for v in obj.goal_mm)
            r, gr, b, _ = rgba(obj.colour)
            ET.SubElement(
                world,
                "geom",
                name=f"{name}_goal",
                type="cylinder",
                size=_f((obj.footprint_mm / 1000 + 0.006, 0.0005)),
                pos=_f((gx, gy, table_z + 0.0005)),
                rgba=_f((r, gr, b, 0.35)),
                contype="0",
                conaffinity="0",
            )

    grip = servos["gripper"]
    lever = gripper_lever(config)
    tendon = ET.SubElement(root, "tendon")
    fixed = ET.SubElement(
        tendon,
        "fixed",
        name="gripper",
        damping=f"{grip.damping:.6g}",
        armature=f"{grip.armature:.6g}",
        frictionloss=f"{grip.frictionloss:.6g}",
    )
    for finger_joint in GRIPPER_FINGERS:
        ET.SubElement(fixed, "joint", joint=finger_joint, coef=f"{1 / lever:.6g}")
    equality = ET.SubElement(root, "equality")
    ET.SubElement(
        equality,
        "joint",
        joint1=GRIPPER_FINGERS[0],
        joint2=GRIPPER_FINGERS[1],
        polycoef="0 1 0 0 0",
        solref="0.004 1",
    )
    actuator = ET.SubElement(root, "actuator")
    for servo_joint, d in servos.items():
        if servo_joint == "gripper":
            lo, hi = 0.0, config.model.geometry.gripper_open / lever
            target = {"tendon": "gripper"}
        else:
            limit = chain.joint(servo_joint).limit
            assert limit is not None
            lo, hi = limit.lower, limit.upper
            target = {"joint": servo_joint}
        ET.SubElement(
            actuator,
            "position",
            target,
            name=servo_joint,
            kp=f"{d.kp:.6g}",
            kv=f"{d.kv:.6g}",
            ctrlrange=_f((lo, hi)),
            forcerange=_f((-d.stall_nm, d.stall_nm)),
        )
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode")
