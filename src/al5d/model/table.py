"""Whether the arm's bodies stay above the table: at a pose, and along a group move's path.

The bodies are the URDF's (`chain`): the upper arm, the forearm, the wrist, the
hand and the two fingers, boxes the 3D view draws, and the skeleton's points (the
elbow and wrist axes, the tool tip), which the boxes leave a gap around. The
lowest point of a box is a corner: its centre's height less each half size times
the magnitude of that axis's vertical component. Heights do not depend on the
base (it turns about the vertical), so only shoulder, elbow, wrist, wrist_rotate
and the gripper's gap count; they are evaluated in closed form over many poses at
once with numpy (a test checks them against the chain's own forward kinematics).

A path is the board's: every pulse linear in time from the start to the target,
all servos arriving together; pulses are linear in degrees, so the path is the
straight segment between the two poses in joint space. It is sampled evenly, and
how finely follows from a bound on how fast any body point can move: with the
joints turning by dq_j (radians) over the path, no point moves vertically faster
than K = sum_j L_j |dq_j| per unit of path (L_j: the farthest any body point
beyond joint j is from its axis; the fingers add half the gap's change). Between
two samples h apart a point can dip at most K h / 2 below the lower of them
(a K-Lipschitz function between two values), so `samples(K)` samples keep what
is missed under `PATH_TOLERANCE_M`: the check is exact at the samples and misses
no dip deeper than that between them.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from al5d.model.arm import ArmModel
from al5d.model.chain import LINK_OF_JOINT, build_chain
from al5d.model.errors import BelowTable, InvalidInput
from al5d.model.joints import GRIPPER_FINGERS, JOINTS
from al5d.model.looks import Shape

Array = NDArray[np.float64]

#: A point this little under the table is rounding (a target on the table's top), not under it.
TABLE_SLACK_M: Final = 1e-9
#: The most a path may dip under the table between two of its samples, undetected (metres).
PATH_TOLERANCE_M: Final = 0.0005
#: The most samples of one group move (a full swing of every joint needs about 2,600).
MAX_SAMPLES: Final = 4096
#: The joints the heights depend on, in the order of the arrays below.
HEIGHT_JOINTS: Final = ("shoulder", "elbow", "wrist", "wrist_rotate", "gripper")

#: What a reason calls each body: the skeleton's points first (they win a tie).
_POINTS: Final = ("tool tip", "wrist", "elbow")


@dataclass(frozen=True)
class _Box:
    name: str
    #: Which elevation the link's z follows (1 upper arm, 2 forearm, 3 the hand's).
    segment: int
    #: Whether the link turns with wrist_rotate (the hand and the fingers).
    rolled: bool
    #: Centre in the link frame, on its z axis; half sizes along x, y, z.
    centre_z: float
    half: tuple[float, float, float]
    #: A finger's side (+1 left, -1 right, 0 not a finger): it sits at side * gap / 2 on y,
    #: its centre side * thickness / 2 further out.
    side: float = 0.0
    centre_y: float = 0.0
    #: A finger's origin along the hand (metres from the wrist axis).
    origin_z: float = 0.0


class Heights:
    """The lowest point of each body of one arm, over many poses at once."""

    def __init__(self, model: ArmModel) -> None:
        g = model.geometry
        self.geometry = g
        self.table = g.table_height
        self.gripper_map = model.gripper_map
        chain = build_chain(model, dict.fromkeys(JOINTS, 1.0))
        shapes = {link.name: link.shape for link in chain.links}
        names = {
            LINK_OF_JOINT["shoulder"]: ("upper arm", 1, False),
            LINK_OF_JOINT["elbow"]: ("forearm", 2, False),
            LINK_OF_JOINT["wrist"]: ("wrist", 3, False),
            LINK_OF_JOINT["wrist_rotate"]: ("hand", 3, True),
            LINK_OF_JOINT[GRIPPER_FINGERS[0]]: ("left finger", 3, True),
            LINK_OF_JOINT[GRIPPER_FINGERS[1]]: ("right finger", 3, True),
        }
        fingers = {j.child: j for j in chain.joints if j.mimic is not None}
        boxes: list[_Box] = []
        for link, (name, segment, rolled) in names.items():
            shape = shapes[link]
            assert shape is not None and shape.kind == "box"  # the chain's moving bodies
            half = (shape.size[0] / 2, shape.size[1] / 2, shape.size[2] / 2)
            finger = fingers.get(link)
            if finger is None:
                boxes.append(_Box(name, segment, rolled, shape.center[2], half))
            else:
                side = finger.axis[1]
                boxes.append(
                    _Box(
                        name,
                        segment,
                        rolled,
                        shape.center[2],
                        half,
                        side,
                        shape.center[1],
                        finger.xyz[2],
                    )
                )
        self.boxes = tuple(boxes)
        self.names = (*_POINTS, *(b.name for b in self.boxes))
        self.reach = self._reach(shapes[LINK_OF_JOINT["elbow"]], shapes[LINK_OF_JOINT["shoulder"]])

    def _reach(self, fore: Shape | None, upper: Shape | None) -> dict[str, float]:
        """L_j of the module's docstring: how far any body beyond a joint is from its axis."""
        g = self.geometry
        gap = self.gripper_map.gap_open_m

        def corner(box: _Box, extra_y: float = 0.0) -> tuple[float, float]:
            # (distance from the link origin, distance from the link's z axis) at worst.
            y = abs(box.side) * gap / 2 + abs(box.centre_y) + box.half[1] + extra_y
            z = box.origin_z + abs(box.centre_z) + box.half[2]
            radial = math.hypot(box.half[0], y)
            return math.hypot(radial, z), radial

        hand = [corner(b) for b in self.boxes if b.segment == 3]
        from_wrist = max([g.gripper, *(d for d, _ in hand)])
        roll = max(r for _, r in hand)

        def along(shape: Shape | None) -> float:
            assert shape is not None
            hx, hy, hz = (s / 2 for s in shape.size)
            return math.sqrt(hx * hx + hy * hy + (abs(shape.center[2]) + hz) ** 2)

        elbow = max(along(fore), g.ulna + from_wrist)
        shoulder = max(along(upper), g.humerus + elbow)
        return {"shoulder": shoulder, "elbow": elbow, "wrist": from_wrist, "wrist_rotate": roll}

    def lowest(self, q: Array) -> Array:
        """The lowest height (metres) of each body for poses `q` (n x 5: HEIGHT_JOINTS in
        degrees): an n x len(names) array, columns in the order of `names`."""
        columns = self._columns([q[:, i] for i in range(5)], np.sin, np.cos, np.abs)
        return np.stack(np.broadcast_arrays(*columns), axis=1)

    def lowest_one(self, q: Sequence[float]) -> list[float]:
        """`lowest` of one pose, with `math` (a numpy call costs more than the whole of it)."""
        return self._columns(list(q), math.sin, math.cos, abs)

    def _columns(self, q: list[Any], sin: Any, cos: Any, mag: Any) -> list[Any]:
        """The bodies' lowest heights for q = HEIGHT_JOINTS (floats, or arrays of poses),
        the same arithmetic for both."""
        g = self.geometry
        rad = math.pi / 180.0
        a1 = (90.0 - q[0]) * rad
        a2 = a1 - q[1] * rad
        a3 = a2 + q[2] * rad
        roll = q[3] * rad
        gm = self.gripper_map
        gap = gm.gap_open_m * (gm.closed_deg - q[4]) / (gm.closed_deg - gm.open_deg)
        sin_a = {1: sin(a1), 2: sin(a2), 3: sin(a3)}
        cos_a = {1: cos(a1), 2: cos(a2), 3: cos(a3)}
        z_elbow = g.base_height + g.humerus * sin_a[1]
        z_wrist = z_elbow + g.ulna * sin_a[2]
        z_tip = z_wrist + g.gripper * sin_a[3]
        origin = {1: g.base_height + 0.0 * a1, 2: z_elbow, 3: z_wrist}
        # The hand's axes' vertical parts: x' = cos(roll) x + sin(roll) y, y' = -sin(roll) x
        # + cos(roll) y, with x's vertical part -cos(a3) and y horizontal (the wrist's axis).
        x_hand = -cos(roll) * cos_a[3]
        y_hand = sin(roll) * cos_a[3]
        columns = [z_tip, z_wrist, z_elbow]
        for b in self.boxes:
            s = sin_a[b.segment]
            if b.rolled:
                drop = b.half[0] * mag(x_hand) + b.half[1] * mag(y_hand)
            else:
                drop = b.half[0] * mag(cos_a[b.segment])
            centre = origin[b.segment] + (b.origin_z + b.centre_z) * s
            if b.side:
                centre = centre + (b.side * gap / 2 + b.centre_y) * y_hand
            columns.append(centre - drop - b.half[2] * mag(s))
        return columns

    def speed(self, a: Mapping[str, float], b: Mapping[str, float]) -> float:
        """K of the module's docstring for the segment from `a` to `b` (metres per path)."""
        k = sum(
            self.reach[j] * math.radians(abs(b[j] - a[j]))
            for j in ("shoulder", "elbow", "wrist", "wrist_rotate")
        )
        return k + self.gripper_map.metres_per_deg * abs(b["gripper"] - a["gripper"]) / 2


@functools.lru_cache(maxsize=8)
def heights(model: ArmModel) -> Heights:
    """The model's `Heights` (built once per model)."""
    return Heights(model)


def samples(k: float) -> int:
    """How many steps a segment of speed bound `k` is sampled in (see the module)."""
    return max(1, min(MAX_SAMPLES, math.ceil(k / (2 * PATH_TOLERANCE_M))))


def _row(model: ArmModel, degrees: Mapping[str, float]) -> list[float]:
    """A pose's HEIGHT_JOINTS; without a gripper, the gap that puts a finger lowest."""
    try:
        row = [float(degrees[j]) for j in HEIGHT_JOINTS[:4]]
    except KeyError as err:
        raise InvalidInput(f"the table check needs joint {err.args[0]}") from None
    if not all(math.isfinite(v) for v in row):
        raise InvalidInput(
            f"joint angles must be finite: {dict(zip(HEIGHT_JOINTS, row, strict=False))}"
        )
    row.append(float(degrees.get("gripper", model.gripper_map.open_deg)))
    return row


def below(model: ArmModel, degrees: Mapping[str, float]) -> BelowTable | None:
    """The deepest body under the table for these degrees (the arm joints, the gripper if
    given: without it, open, its widest), or None."""
    h = heights(model)
    z = h.lowest_one(_row(model, degrees))
    lowest = min(z)
    # Among bodies as low to rounding (a finger's end and the tip, pointing down), the
    # first named: the skeleton's points, then the chain's order.
    i = next(k for k, v in enumerate(z) if v <= lowest + TABLE_SLACK_M)
    if z[i] >= h.table - TABLE_SLACK_M:
        return None
    return BelowTable(h.names[i], z[i], h.table)


@dataclass(frozen=True)
class PathBelow:
    """Where a path goes under the table: the body at its deepest, its height, and where
    along the path (for a path that starts under it, where it fails to rise)."""

    body: str
    z_m: float
    table_m: float
    #: The end of the segment it is on ("the target", "point 3") and how far along (0..1).
    segment: str
    fraction: float
    #: The path started under the table and did not rise out of it all the way.
    from_below: bool = False

    def __str__(self) -> str:
        depth = (self.table_m - self.z_m) * 1000
        where = f"at {self.fraction:.0%} of the way to {self.segment}"
        if self.from_below:
            return (
                f"the arm starts below the table and this move does not rise out of it: "
                f"the {self.body} is {depth:.0f} mm below the table {where}, no higher than "
                "just before (only a move that takes it up all the way is taken from there)"
            )
        return (
            f"below the table: the {self.body} would go {depth:.0f} mm under it "
            f"(z={self.z_m * 1000:.0f} mm, the table is at z={self.table_m * 1000:.0f} mm) "
            f"{where}"
        )


def clear_by_bound(h: Heights, rows: Sequence[Sequence[float]], speeds: Sequence[float]) -> bool:
    """Whether every segment is above the table by the bound alone, without sampling: the
    deepest body is K-Lipschitz along a segment (the module's docstring), so between ends
    at heights u and v it is nowhere lower than (u + v - K) / 2, nor than either end. Most
    moves are clear by far, and this costs two poses in `math` a segment where sampling
    costs dozens of numpy's calls (a third of the owner's time for a single move)."""
    deepest = [min(h.lowest_one(row)) for row in rows]
    return all(
        min(u, v, (u + v - k) / 2) >= h.table
        for (u, v), k in zip(itertools.pairwise(deepest), speeds, strict=True)
    )


def path_below(
    model: ArmModel,
    poses: Sequence[Mapping[str, float]],
    labels: Sequence[str] | None = None,
) -> PathBelow | None:
    """Where the board's path through `poses` (the start, then each target in turn) takes a
    body under the table, or None. `labels[i]`: what the end of segment i (from pose i to
    pose i + 1) is called in the reason ("point 3"; by default "the target", or "pose 2").

    A path that starts under the table (the arm bent there by hand, a table set too high)
    is taken only if it rises out: at every sample the deepest body is higher than at the
    sample before, until no body is under the table, and none goes under again.
    """
    if len(poses) < 2:
        return None
    h = heights(model)
    rows = [_row(model, p) for p in poses]
    # Without a gripper in a pose, the one before it holds (the board keeps its pulse).
    for i, p in enumerate(poses):
        if "gripper" not in p and i:
            rows[i][4] = rows[i - 1][4]
    ends = [dict(zip(HEIGHT_JOINTS, row, strict=True)) for row in rows]
    speeds = [h.speed(ends[i], ends[i + 1]) for i in range(len(rows) - 1)]
    if clear_by_bound(h, rows, speeds):
        return None
    qs: list[Array] = []
    where: list[Array] = []
    seg: list[Array] = []
    for i, k in enumerate(speeds):
        a, b = np.array(rows[i]), np.array(rows[i + 1])
        n = samples(k)
        f = np.arange(1, n + 1) / n
        qs.append(a + f[:, None] * (b - a))
        where.append(f)
        seg.append(np.full(n, i))
    q = np.concatenate([np.array([rows[0]]), *qs])
    z = h.lowest(q)
    deepest = z.min(axis=1)
    body = np.argmax(z <= deepest[:, None] + TABLE_SLACK_M, axis=1)  # as `below` names it
    fraction = np.concatenate([[0.0], *where])
    segment = np.concatenate([[0], *seg])
    table = h.table - TABLE_SLACK_M
    under = deepest < table
    if not under.any():
        return None

    def found(i: int, from_below: bool = False) -> PathBelow:
        s = int(segment[i])
        if labels is not None:
            label = labels[s]
        else:
            label = "the target" if len(poses) == 2 else f"pose {s + 1}"
        return PathBelow(
            h.names[int(body[i])],
            float(deepest[i]),
            h.table,
            label,
            float(fraction[i]),
            from_below,
        )

    if not under[0]:
        return found(int(np.argmin(deepest)))  # the worst of it: how far under, and where
    # From under the table: each sample under it must be higher than the one before.
    rising = deepest[1:] > deepest[:-1]
    bad = under[1:] & ~rising
    if bad.any():
        i = int(np.argmax(bad)) + 1
        return found(i, from_below=bool(under[:i].all()))
    return None
