"""Rigid transforms as plain tuples: quaternions (x, y, z, w), rotation matrices, RPY."""

from __future__ import annotations

import math
from dataclasses import dataclass

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]

IDENTITY_QUAT: Quat = (0.0, 0.0, 0.0, 1.0)


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product a * b (apply b first, then a)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_from_axis_angle(axis: Vec3, angle: float) -> Quat:
    """Rotation by `angle` radians about the unit vector `axis`."""
    s = math.sin(angle / 2.0)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2.0))


def quat_from_rpy(roll: float, pitch: float, yaw: float) -> Quat:
    """URDF's fixed-axis roll (x), pitch (y), yaw (z): R = Rz(yaw) Ry(pitch) Rx(roll)."""
    qx = quat_from_axis_angle((1.0, 0.0, 0.0), roll)
    qy = quat_from_axis_angle((0.0, 1.0, 0.0), pitch)
    qz = quat_from_axis_angle((0.0, 0.0, 1.0), yaw)
    return quat_mul(qz, quat_mul(qy, qx))


def quat_rotate(q: Quat, v: Vec3) -> Vec3:
    """The vector v rotated by the unit quaternion q."""
    x, y, z, w = q
    # v + 2w (u x v) + 2 u x (u x v), with u the vector part: no matrix needed.
    tx = 2.0 * (y * v[2] - z * v[1])
    ty = 2.0 * (z * v[0] - x * v[2])
    tz = 2.0 * (x * v[1] - y * v[0])
    return (
        v[0] + w * tx + (y * tz - z * ty),
        v[1] + w * ty + (z * tx - x * tz),
        v[2] + w * tz + (x * ty - y * tx),
    )


def matrix_from_quat(q: Quat) -> Mat3:
    """3x3 rotation matrix (rows) of a unit quaternion."""
    x, y, z, w = q
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
        (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
        (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)),
    )


@dataclass(frozen=True)
class Transform:
    """A child frame in its parent: translation (metres) and rotation (quaternion x, y, z, w)."""

    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Quat = IDENTITY_QUAT

    def __mul__(self, other: Transform) -> Transform:
        """Composition: self (parent <- middle) * other (middle <- child) = parent <- child."""
        t = quat_rotate(self.rotation, other.translation)
        return Transform(
            (
                self.translation[0] + t[0],
                self.translation[1] + t[1],
                self.translation[2] + t[2],
            ),
            quat_mul(self.rotation, other.rotation),
        )

    def apply(self, point: Vec3) -> Vec3:
        """A point given in the child frame, expressed in the parent frame."""
        r = quat_rotate(self.rotation, point)
        return (
            r[0] + self.translation[0],
            r[1] + self.translation[1],
            r[2] + self.translation[2],
        )

    def matrix(self) -> tuple[tuple[float, float, float, float], ...]:
        """4x4 homogeneous matrix, rows."""
        r = matrix_from_quat(self.rotation)
        t = self.translation
        return (
            (*r[0], t[0]),
            (*r[1], t[1]),
            (*r[2], t[2]),
            (0.0, 0.0, 0.0, 1.0),
        )


@dataclass(frozen=True)
class Mount:
    """Where an arm's root frame stands in a parent frame it shares with other arms (REP
    105's `world`): the root's origin (metres) and fixed-axis roll, pitch, yaw (radians) in
    the parent, as a URDF fixed joint gives them."""

    parent: str
    xyz: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)

    @property
    def transform(self) -> Transform:
        """The root frame in the parent frame."""
        return Transform(self.xyz, quat_from_rpy(*self.rpy))
