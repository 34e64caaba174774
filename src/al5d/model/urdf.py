"""URDF text from the chain: the robot_description that RViz, MoveIt and /tf tools read."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from typing import Final

from al5d.model.arm import ArmModel
from al5d.model.chain import DEFAULT_EFFORT, Chain, build_chain
from al5d.model.errors import InvalidInput
from al5d.model.looks import Shape
from al5d.model.transforms import Mount

#: RGBA of the materials the shapes use: servo bodies and the base, aluminium, horns.
MATERIALS: Final[Mapping[str, tuple[float, float, float, float]]] = {
    "dark": (0.15, 0.15, 0.17, 1.0),
    "metal": (0.72, 0.74, 0.78, 1.0),
    "white": (0.93, 0.93, 0.9, 1.0),
}


def num(value: float) -> str:
    """A float as URDF text: shortest exact form, no negative zero."""
    v = float(value)
    return "0" if v == 0.0 else repr(v)


def _vec(values: tuple[float, ...]) -> str:
    return " ".join(num(v) for v in values)


def _approx(values: tuple[float, ...]) -> str:
    # Shapes are approximate anyway: micrometres are plenty, and the text stays short.
    return " ".join(num(round(v, 6)) for v in values)


def _geometry(parent: ET.Element, shape: Shape) -> None:
    ET.SubElement(parent, "origin", xyz=_approx(shape.center), rpy=_approx(shape.rpy))
    geometry = ET.SubElement(parent, "geometry")
    if shape.kind == "box":
        ET.SubElement(geometry, "box", size=_approx(shape.size))
    else:
        ET.SubElement(
            geometry, "cylinder", radius=_approx(shape.size[:1]), length=_approx(shape.size[1:2])
        )


#: The fixed joint that hangs the chain's root from a mount's parent frame.
MOUNT_JOINT: Final = "mount"


def urdf_from_chain(chain: Chain, robot_name: str = "al5d", mount: Mount | None = None) -> str:
    """The URDF XML (a string, with declaration) of a chain; with a `mount`, the mount's
    parent is the root link and a fixed joint `mount` (behind the chain's joint prefix)
    holds the chain's root in it (what MoveIt needs to plan in a frame shared by several
    arms: an SRDF's fixed virtual joint has no origin, so it could only put the arm at the
    parent's origin)."""
    return urdf_of_arms([(chain, mount)], robot_name)


def urdf_of_arms(arms: Sequence[tuple[Chain, Mount | None]], robot_name: str = "al5d") -> str:
    """One URDF of several arms, each hung from its mount's parent frame (one link however
    many arms share it); one arm may go without a mount, as `urdf_from_chain`. Each arm's
    links and joints carry their own prefixes: a name twice is refused (InvalidInput)."""
    if len(arms) > 1 and any(mount is None for _, mount in arms):
        raise InvalidInput("several arms in one URDF: each needs a mount (its parent frame)")
    robot = ET.Element("robot", name=robot_name)
    for name, rgba in MATERIALS.items():
        material = ET.SubElement(robot, "material", name=name)
        ET.SubElement(material, "color", rgba=_vec(rgba))
    parents = list(dict.fromkeys(mount.parent for _, mount in arms if mount is not None))
    links = parents + [link.name for chain, _ in arms for link in chain.links]
    joints = [
        *(chain.joint_prefix + MOUNT_JOINT for chain, mount in arms if mount is not None),
        *(joint.name for chain, _ in arms for joint in chain.joints),
    ]
    for kind, names in (("link", links), ("joint", joints)):
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise InvalidInput(
                f"{kind} names given twice: {', '.join(twice)} (each arm needs prefixes of its own)"
            )
    for parent in parents:
        ET.SubElement(robot, "link", name=parent)
    for chain, _ in arms:
        _links(robot, chain)
    for chain, mount in arms:
        if mount is not None:
            element = ET.SubElement(
                robot, "joint", name=chain.joint_prefix + MOUNT_JOINT, type="fixed"
            )
            ET.SubElement(element, "parent", link=mount.parent)
            ET.SubElement(element, "child", link=chain.root)
            ET.SubElement(element, "origin", xyz=_vec(mount.xyz), rpy=_vec(mount.rpy))
        _joints(robot, chain)
    ET.indent(robot, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _links(robot: ET.Element, chain: Chain) -> None:
    for link in chain.links:
        element = ET.SubElement(robot, "link", name=link.name)
        if link.shape is None:
            continue
        for shape in link.visuals or (link.shape,):
            visual = ET.SubElement(element, "visual")
            _geometry(visual, shape)
            ET.SubElement(visual, "material", name=shape.material)
        _geometry(ET.SubElement(element, "collision"), link.shape)


def _joints(robot: ET.Element, chain: Chain) -> None:
    for joint in chain.joints:
        element = ET.SubElement(robot, "joint", name=joint.name, type=joint.type)
        ET.SubElement(element, "parent", link=joint.parent)
        ET.SubElement(element, "child", link=joint.child)
        ET.SubElement(element, "origin", xyz=_vec(joint.xyz), rpy=_vec(joint.rpy))
        if joint.type == "fixed":
            continue
        ET.SubElement(element, "axis", xyz=_vec(joint.axis))
        if joint.limit is not None:
            lim = joint.limit
            ET.SubElement(
                element,
                "limit",
                lower=num(lim.lower),
                upper=num(lim.upper),
                velocity=num(lim.velocity),
                effort=num(lim.effort),
            )
        if joint.mimic is not None:
            m = joint.mimic
            ET.SubElement(
                element,
                "mimic",
                joint=m.joint,
                multiplier=num(m.multiplier),
                offset=num(m.offset),
            )


def urdf(
    model: ArmModel,
    speeds_deg_s: Mapping[str, float],
    *,
    robot_name: str = "al5d",
    prefix: str = "",
    joint_prefix: str = "",
    effort: float = DEFAULT_EFFORT,
) -> str:
    """The AL5D's URDF from the model and the servos' speeds (deg/s per joint)."""
    chain = build_chain(
        model, speeds_deg_s, prefix=prefix, joint_prefix=joint_prefix, effort=effort
    )
    return urdf_from_chain(chain, robot_name)
