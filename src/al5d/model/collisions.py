"""Which link pairs can never touch: the sampled self-collision analysis MoveIt's setup does.

Each link's shape is enclosed in a capsule (a segment and a radius), the chain is
posed at many joint values at once with numpy, and a pair whose capsules stay
apart by a margin in every sample is reported as never touching. Capsules enclose
the shapes, so a pair they keep apart is apart; the reverse does not hold, which
errs toward keeping a check, the safe side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from al5d.model.chain import Chain, Joint, Link
from al5d.model.looks import Shape
from al5d.model.transforms import matrix_from_quat, quat_from_rpy

Array = NDArray[np.float64]

#: Capsules closer than this in some sample keep their pair checked (metres).
NEVER_MARGIN_M: Final = 0.005
DEFAULT_SAMPLES: Final = 20000


@dataclass(frozen=True)
class PairReport:
    """A pair of links, with why collision checking between them is off."""

    link1: str
    link2: str
    #: "Adjacent" (joined by a joint), "Never" (apart in every sample), or
    #: "User" (the two fingers, which close onto each other by design).
    reason: str
    #: Smallest capsule distance seen (metres); 0 for pairs not sampled.
    min_distance_m: float = 0.0


def _capsule(shape: Shape) -> tuple[Array, Array, float]:
    # Segment end points in the link frame and a radius that encloses the shape.
    c = np.asarray(shape.center, dtype=float)
    if shape.kind == "cylinder":
        radius, length = shape.size[0], shape.size[1]
        axis, half = 2, length / 2.0
    else:
        half_sizes = [s / 2.0 for s in shape.size]
        axis = int(np.argmax(half_sizes))
        others = [h for i, h in enumerate(half_sizes) if i != axis]
        radius, half = math.hypot(*others), half_sizes[axis]
    offset = np.zeros(3)
    offset[axis] = half
    return c - offset, c + offset, radius


def _motion(joint: Joint, values: Array) -> Array:
    # (N, 4, 4) transforms of a joint for N values: origin, then motion.
    n = len(values)
    origin = np.eye(4)
    origin[:3, :3] = np.asarray(matrix_from_quat(quat_from_rpy(*joint.rpy)))
    origin[:3, 3] = joint.xyz
    motion = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    axis = np.asarray(joint.axis, dtype=float)
    if joint.type == "revolute":
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        s, c = np.sin(values)[:, None, None], np.cos(values)[:, None, None]
        motion[:, :3, :3] = np.eye(3) + s * k + (1.0 - c) * (k @ k)
    elif joint.type == "prismatic":
        motion[:, :3, 3] = values[:, None] * axis
    result: Array = origin @ motion
    return result


def _sample_values(chain: Chain, samples: int, seed: int) -> dict[str, Array]:
    rng = np.random.default_rng(seed)
    movable = [chain.joint(name) for name in chain.movable]
    corners = np.array(np.meshgrid(*[[0.0, 1.0]] * len(movable))).reshape(len(movable), -1)
    fractions = np.concatenate([corners, rng.random((len(movable), samples))], axis=1)
    out: dict[str, Array] = {}
    for joint, f in zip(movable, fractions, strict=True):
        assert joint.limit is not None  # movable joints all have limits
        out[joint.name] = joint.limit.lower + f * (joint.limit.upper - joint.limit.lower)
    return out


def _segment_distance(p1: Array, q1: Array, p2: Array, q2: Array) -> Array:
    # Closest distance between segments p1q1 and p2q2, row-wise (Ericson, RTCD 5.1.9).
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-15, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        s = np.where(
            t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s)
        )
    t = np.clip(t, 0.0, 1.0)
    gap = (p1 + d1 * s[:, None]) - (p2 + d2 * t[:, None])
    dist: Array = np.sqrt(np.einsum("ij,ij->i", gap, gap))
    return dist


def disabled_pairs(
    chain: Chain, samples: int = DEFAULT_SAMPLES, seed: int = 0
) -> tuple[PairReport, ...]:
    """Link pairs to leave out of self-collision checking, for the SRDF.

    Deterministic for a given seed; every joint's limit corners are sampled too.
    """
    values = _sample_values(chain, samples, seed)
    n = len(next(iter(values.values())))
    poses: dict[str, Array] = {chain.root: np.broadcast_to(np.eye(4), (n, 4, 4))}
    for joint in chain.joints:
        if joint.type == "fixed":
            v = np.zeros(n)
        elif joint.mimic is not None:
            m = joint.mimic
            v = m.multiplier * values[m.joint] + m.offset
        else:
            v = values[joint.name]
        poses[joint.child] = poses[joint.parent] @ _motion(joint, v)

    bodies: list[Link] = [link for link in chain.links if link.shape is not None]
    adjacent = {frozenset((j.parent, j.child)) for j in chain.joints}
    fingers = {
        j.child for j in chain.joints if j.type == "prismatic"
    }  # the gripper's two finger links
    capsules: dict[str, tuple[Array, Array, float]] = {}
    for link in bodies:
        assert link.shape is not None
        a, b, radius = _capsule(link.shape)
        pose = poses[link.name]
        capsules[link.name] = (
            pose[:, :3, :3] @ a + pose[:, :3, 3],
            pose[:, :3, :3] @ b + pose[:, :3, 3],
            radius,
        )
    reports: list[PairReport] = []
    for i, first in enumerate(bodies):
        for second in bodies[i + 1 :]:
            pair = frozenset((first.name, second.name))
            if pair in adjacent:
                reports.append(PairReport(first.name, second.name, "Adjacent"))
                continue
            if pair <= fingers:
                reports.append(PairReport(first.name, second.name, "User"))
                continue
            a1, b1, r1 = capsules[first.name]
            a2, b2, r2 = capsules[second.name]
            closest = float(np.min(_segment_distance(a1, b1, a2, b2))) - r1 - r2
            if closest > NEVER_MARGIN_M:
                reports.append(PairReport(first.name, second.name, "Never", closest))
    return tuple(reports)
