"""What a client knows of the arm: its state, its joints in degrees and its tool's pose, as
heard from the server (over the local lane, or ROS 2's topics), with waits and callbacks.

One writer: the backend's reader thread (the lane's, or the client's spinner) hands each
piece of news to `ArmView.heard`; a reader takes a `Reading`, a frozen copy, under the
view's condition. The tool's pose is the model's forward kinematics of the joints heard,
in the grammar's units (`move_to`'s millimetres and degrees), so that it can be pasted
into a `move_to`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import astuple, dataclass, field, replace
from typing import Any

from al5d.clock import Deadline
from al5d.model import ArmModel
from al5d.model.kinematics import forward

log = logging.getLogger("al5d")

#: Readings kept for the waits: more than a waiter woken late misses (joint states come
#: 10 to 25 times a second).
RECENT = 64
#: The arm joints whose angles put the tool where it is (the gripper's opening does not).
_TOOL_JOINTS = ("base", "shoulder", "elbow", "wrist", "wrist_rotate")


@dataclass(frozen=True, slots=True)
class Tool:
    """Where the gripper's tip is, as `move_to` names it: millimetres in base_link, the
    gripper's pitch (+ up) and roll in degrees."""

    x: float
    y: float
    z: float
    pitch: float
    roll: float

    def __str__(self) -> str:
        words = zip(("x", "y", "z", "pitch", "roll"), astuple(self), strict=True)
        return " ".join(f"{k}={_tenths(v)}" for k, v in words)


def _tenths(value: float) -> str:
    """`value` to a tenth, without a sign on a zero (-0.0 reads as a mistake)."""
    text = f"{value:.1f}"
    return "0.0" if text == "-0.0" else text


@dataclass(frozen=True, slots=True)
class Reading:
    """The arm as last heard: its state word (`ready`, `moving`, `stopped`, ...; "" before
    any news), whether a stop holds it locked, its joints in degrees (those known), the tool's
    pose (None until every arm joint is known), when this was heard (time.monotonic), and
    whether the joints have been told at all (one not known since power-up is left out of
    `joints` even then)."""

    state: str = ""
    locked: bool = False
    joints: Mapping[str, float] = field(default_factory=dict)
    tool: Tool | None = None
    t: float = -math.inf
    joints_told: bool = False


def tool_of(model: ArmModel, joints: Mapping[str, float]) -> Tool | None:
    """The tool's pose for `joints` (degrees); None if an arm joint is not known."""
    if any(not math.isfinite(joints.get(j, math.nan)) for j in _TOOL_JOINTS):
        return None
    pose = forward(model.geometry, joints)
    x, y, z = (1000.0 * v for v in pose.position)
    return Tool(x, y, z, pose.pitch_deg, pose.roll_deg)


class ArmView:
    """The latest `Reading`, kept by one writer (`heard`), with waits and callbacks.

    `live`: where the joints can be told at any moment (the lane's client estimates them
    along the move the owner told it of), read by `reading` instead of the last news."""

    def __init__(
        self, model: ArmModel, live: Callable[[], Mapping[str, float]] | None = None
    ) -> None:
        self.model = model
        self._live = live
        self._cv = threading.Condition()
        self._reading = Reading()
        self._listeners: list[Callable[[Reading], None]] = []
        #: The last readings, each with its number (`_heard`: how many so far): a wait sees
        #: one that came and went before its thread ran (a fault, then locked, told back
        #: to back on a busy host).
        self._heard = 0
        self._recent: deque[tuple[int, Reading]] = deque(maxlen=RECENT)

    @property
    def reading(self) -> Reading:
        with self._cv:
            heard = self._reading
        if self._live is None:
            return heard
        joints = {j: v for j, v in self._live().items() if math.isfinite(v)}
        return replace(heard, joints=joints, tool=tool_of(self.model, joints))

    def heard(
        self,
        state: str | None = None,
        locked: bool | None = None,
        joints: Mapping[str, float] | None = None,
    ) -> None:
        """News of the arm: what is None has not changed. Listeners are called with the new
        reading on this (the backend's) thread. With `live` joints, a reading heard without
        joints has them as they are now (an outside try: the end of a move, told as its
        state, gave the joints as the move had begun until its pose was told after it)."""
        if joints is None and self._live is not None:
            joints = self._live()
        with self._cv:
            old = self._reading
            known = (
                old.joints
                if joints is None
                else {j: v for j, v in joints.items() if math.isfinite(v)}
            )
            new = Reading(
                old.state if state is None else state,
                old.locked if locked is None else locked,
                known,
                old.tool if joints is None else tool_of(self.model, known),
                time.monotonic(),
                old.joints_told or joints is not None,
            )
            self._reading = new
            self._heard += 1
            self._recent.append((self._heard, new))
            self._cv.notify_all()
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener(new)
            except Exception:
                log.exception("a client's listener of the arm %r failed", listener)

    def on_change(self, listener: Callable[[Reading], None]) -> None:
        """Call `listener` with each new reading (on the client's reader thread: keep it short)."""
        with self._cv:
            self._listeners.append(listener)

    def wait(self, until: Callable[[Reading], bool], timeout: float) -> Reading | None:
        """The reading now if `until` holds for it, else the first heard since the call for
        which it does, though others followed it; None if none came within `timeout`."""
        deadline = Deadline(timeout)
        with self._cv:
            since = self._heard
            while True:
                if until(self._reading):
                    return self._reading
                for number, reading in self._recent:
                    if number > since and until(reading):
                        return reading
                since = self._heard
                if deadline.expired:
                    return None
                self._cv.wait(deadline.left())


def follow_lane(remote: Any, view: ArmView) -> None:
    """`view` kept by what the owner tells `remote` (an `al5d.owner.client.Remote` that
    watches "state" and "pose")."""

    def state(_: object) -> None:
        view.heard(remote.state.value, remote.locked)

    def pose() -> None:
        view.heard(joints=remote.positions())

    remote.state_listeners.append(state)
    remote.pose_listeners.append(pose)
    view.heard(remote.state.value, remote.locked, remote.positions())


def follow_ros(node: Any, names: Any, prefix: str, view: ArmView) -> None:
    """`view` kept by the server's state and joint states topics, read by `node`
    (`names`: the server's `al5d.ros.names.Names`; `prefix`: its joints' prefix)."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from al5d.ros.qos import QOS_LATCHED, QOS_LATEST

    def on_state(msg: String) -> None:
        state = str(msg.data)
        view.heard(state, state == "stopped")

    def on_joints(msg: JointState) -> None:
        values = {
            n[len(prefix) :]: float(v)
            for n, v in zip(msg.name, msg.position, strict=False)
            if n.startswith(prefix)
        }
        view.heard(joints=view.model.from_urdf(values))

    node.create_subscription(String, names.state, on_state, QOS_LATCHED)
    node.create_subscription(JointState, names.joint_states, on_joints, QOS_LATEST)
