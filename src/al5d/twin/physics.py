"""The twin's physics: the MuJoCo arm following the board's pulses, frame by frame.

A servo gets a pulse every 20 ms (`FRAME_S`), and so does the twin's: at each frame every
actuator's target is what the board puts out on its channel then (`al5d.ssc32u.emulator.
Pulse`), through the calibration (and the arm's true mechanics, where the emulator is told
they differ), and the physics runs the frame in steps of the scene's time step. A channel
without pulses leaves its servo limp. No clock of its own: `advance_to` takes the board's
time, so a test can run it as fast as it computes and the process (`al5d.twin.run`) in
real time.

After each frame it checks what the body did: each object's pose and how high it was
lifted, how deep any link sank into the table or an object, and whether a joint is
held short of its target (`Held`: by its load, or against something).
"""

from __future__ import annotations

import collections
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import mujoco
import numpy as np

from al5d.arm.config import ArmConfig
from al5d.model import ARM_JOINTS
from al5d.model.joints import GRIPPER_FINGERS, joint_from_urdf, joint_to_urdf
from al5d.model.transforms import Quat, Vec3
from al5d.ssc32u.emulator import Mechanics, Pulse
from al5d.twin.mjcf import KG_CM, Drive, drives, gripper_lever, mjcf
from al5d.twin.scene import Scene

#: The servo pulses' period: a servo sees a new target every 20 ms.
FRAME_S: Final = 0.02
#: A joint this far from its target...
SHORT_DEG: Final = 3.0
#: ...giving at least this share of its stall torque...
SATURATED: Final = 0.9
#: ...and turning slower than this...
STILL_DEG_S: Final = 5.0
#: ...for this long, is held there.
HOLD_S: Final = 0.3
#: A finger's contact whose normal is within about 45 deg of the gap's axis squeezes.
SQUEEZE_COS: Final = 0.7
#: The arm's joints, the gripper last: the actuators' order.
DRIVEN: Final = (*ARM_JOINTS, "gripper")


@dataclass(frozen=True)
class Held:
    """A joint held short of its target: by its load (`needed_kg_cm` more than its servo
    gives) or against something (`against`: an object's name, or the table)."""

    joint: str
    short_deg: float
    stall_kg_cm: float
    needed_kg_cm: float | None = None
    against: str | None = None
    #: When it was found (the board's clock).
    t: float = 0.0
    #: Carried past its target (a load that pulled it there), not held short of it.
    past: bool = False

    @property
    def text(self) -> str:
        short = f"{self.short_deg:.0f} deg {'past' if self.past else 'short of'} its target"
        if self.joint == "gripper" and self.against is not None:
            return (
                f"gripper holds the {self.against}: {short}, squeezing with its "
                f"{self.stall_kg_cm:.1f} kg cm"
            )
        if self.against is not None:
            return (
                f"{self.joint} held {short} against the {self.against}: the servo gives its "
                f"{self.stall_kg_cm:.1f} kg cm"
            )
        needed = f"{self.needed_kg_cm:.0f}" if self.needed_kg_cm is not None else "more than that"
        if self.needed_kg_cm is not None and self.needed_kg_cm < self.stall_kg_cm:
            # Its load alone it could hold: what it carries is held back (a load too heavy
            # for the fingers, still on the table), or the fingers' or the hand's contact.
            return (
                f"{self.joint} held {short} by what it holds or touches, not by its load: "
                f"{needed} kg cm needed, the servo gives {self.stall_kg_cm:.1f}"
            )
        return (
            f"{self.joint} held {short}: {needed} kg cm needed, the servo gives "
            f"{self.stall_kg_cm:.1f}"
        )


@dataclass(frozen=True)
class ObjectState:
    """An object of the scene now: its frame (the centre of its bottom) in base_link,
    metres, and how high it has been lifted above where it started, at most."""

    name: str
    position: Vec3
    rotation: Quat  # x, y, z, w
    start: Vec3
    lifted_m: float


@dataclass
class _Watch:
    """A joint's watch for being held: since when, and whether it was said."""

    since: float | None = None
    clear_since: float | None = None
    said: bool = False


@dataclass
class _Ids:
    actuator: dict[str, int] = field(default_factory=dict)
    qpos: dict[str, int] = field(default_factory=dict)
    dof: dict[str, int] = field(default_factory=dict)
    #: Per driven joint, the bodies it moves.
    subtree: dict[str, set[int]] = field(default_factory=dict)
    objects: dict[str, int] = field(default_factory=dict)
    arm_bodies: set[int] = field(default_factory=set)
    hand: int = 0


class Twin:
    """The arm of `config` in `scene`, its servos at `pose` (the arm's degrees; by default
    the park preset) and limp, at the board's time `start`. `mechanics`: joints that stand
    otherwise on their servos than the configuration says (the emulator's)."""

    def __init__(
        self,
        config: ArmConfig,
        scene: Scene,
        *,
        start: float = 0.0,
        pose: Mapping[str, float] | None = None,
        mechanics: Mapping[str, Mechanics] | None = None,
    ) -> None:
        self.config = config
        self.scene = scene
        self.xml = mjcf(config, scene)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self._scratch = mujoco.MjData(self.model)
        self.drives: dict[str, Drive] = drives(config)
        self.mechanics = dict(mechanics or {})
        self.lever = gripper_lever(config)
        self.t = start
        self.steps_per_frame = max(1, round(FRAME_S / self.model.opt.timestep))
        #: What each channel puts out now, and what it will from a later time.
        self.pulses: dict[int, Pulse] = {}
        self._coming: dict[int, collections.deque[Pulse]] = {}
        self.channels = {name: config.joints[name].channel for name in DRIVEN}
        self._ids = self._find_ids()
        self._tune(config.presets["ready"])
        self._gains = {
            name: (
                self.model.actuator_gainprm[i].copy(),
                self.model.actuator_biasprm[i].copy(),
            )
            for name, i in self._ids.actuator.items()
        }
        self._on: dict[str, bool] = {}
        #: Where each joint was when its pulses last changed: whence it went to its target.
        self._origin: dict[str, float] = {}
        self._watch = {name: _Watch() for name in DRIVEN}
        self.deepest: dict[str, float] = {}
        self._lifted: dict[str, float] = dict.fromkeys(self._ids.objects, 0.0)
        pose = dict(pose if pose is not None else config.presets["park"])
        self._place(pose)
        self._start = {name: self._position(name) for name in self._ids.objects}
        for name in DRIVEN:
            self._limp(name, True)

    # -- the model's names -----------------------------------------------------------

    def _find_ids(self) -> _Ids:
        m = self.model
        ids = _Ids()

        def named(kind: Any, name: str) -> int:
            return int(mujoco.mj_name2id(m, kind, name))

        for name in DRIVEN:
            ids.actuator[name] = named(mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        for name in (*ARM_JOINTS, *GRIPPER_FINGERS):
            j = named(mujoco.mjtObj.mjOBJ_JOINT, name)
            ids.qpos[name] = int(m.jnt_qposadr[j])
            ids.dof[name] = int(m.jnt_dofadr[j])
        parents = [int(p) for p in m.body_parentid]

        def below(body: int) -> set[int]:
            out = {body}
            grew = True
            while grew:
                grew = False
                for b, p in enumerate(parents):
                    if p in out and b not in out and b != 0:
                        out.add(b)
                        grew = True
            return out

        for name in ARM_JOINTS:
            ids.subtree[name] = below(int(m.jnt_bodyid[named(mujoco.mjtObj.mjOBJ_JOINT, name)]))
        ids.subtree["gripper"] = {
            int(m.jnt_bodyid[named(mujoco.mjtObj.mjOBJ_JOINT, f)]) for f in GRIPPER_FINGERS
        }
        ids.arm_bodies = ids.subtree["base"] | {named(mujoco.mjtObj.mjOBJ_BODY, "base_link")}
        ids.hand = int(m.jnt_bodyid[named(mujoco.mjtObj.mjOBJ_JOINT, "wrist_rotate")])
        for name in self.scene.objects:
            ids.objects[name] = named(mujoco.mjtObj.mjOBJ_BODY, name)
        return ids

    def _tune(self, pose: Mapping[str, float]) -> None:
        """Each arm servo's controller damping, critical for what it turns at `pose` (its rotor
        and the links beyond it): with the rotor's alone, the base overshot its target by
        20 deg with the arm stretched out, where a real servo stops."""
        m, s = self.model, self._scratch
        for name in ARM_JOINTS:
            s.qpos[self._ids.qpos[name]] = joint_to_urdf(name, pose.get(name, 0.0))
        mujoco.mj_forward(m, s)
        unit, column = np.zeros(m.nv), np.zeros(m.nv)
        for name in ARM_JOINTS:
            dof = self._ids.dof[name]
            unit[:] = 0
            unit[dof] = 1
            mujoco.mj_mulM(m, s, column, unit)
            inertia = float(column[dof])  # the mass matrix's diagonal: the armature included
            d = self.drives[name]
            kv = max(0.0, 2 * math.sqrt(d.kp * inertia) - d.damping)
            m.actuator_biasprm[self._ids.actuator[name], 2] = -kv

    # -- the arm's units ---------------------------------------------------------------

    def _place(self, pose: Mapping[str, float]) -> None:
        """The joints at `pose` (arm degrees), at rest."""
        d = self.data
        for name in ARM_JOINTS:
            d.qpos[self._ids.qpos[name]] = joint_to_urdf(name, pose.get(name, 0.0))
        gap = self.config.model.gripper_map.gap_from_deg(pose.get("gripper", 0.0))
        for finger in GRIPPER_FINGERS:
            d.qpos[self._ids.qpos[finger]] = max(0.0, gap / 2)
        mujoco.mj_forward(self.model, d)

    def _target(self, name: str, t: float) -> float | None:
        """The actuator's target for what the board puts out at `t` (None: no pulses)."""
        pulse = self._pulse(name, t)
        us = pulse.at(t) if pulse is not None else 0.0
        if us <= 0:
            return None
        joint = self.config.joints[name]
        deg = joint.to_deg(self.mechanics.get(name, Mechanics()).true_us(us))
        if name == "gripper":
            return self.config.model.gripper_map.gap_from_deg(deg) / self.lever
        return joint_to_urdf(name, deg)

    def _actual(self, name: str) -> float:
        """The joint's position in its actuator's units."""
        if name == "gripper":
            d = self.data
            return float(sum(d.qpos[self._ids.qpos[f]] for f in GRIPPER_FINGERS)) / self.lever
        return float(self.data.qpos[self._ids.qpos[name]])

    def _degrees(self, name: str, value: float) -> float:
        if name == "gripper":
            return self.config.model.gripper_map.deg_from_gap(value * self.lever)
        return joint_from_urdf(name, value)

    def _span_deg(self, name: str, a: float, b: float) -> float:
        """|a - b| of actuator values, in the joint's degrees (servo degrees, the gripper)."""
        return abs(self._degrees(name, a) - self._degrees(name, b))

    def joint_degrees(self) -> dict[str, float]:
        """Where the twin's joints are, in the arm's degrees."""
        return {name: self._degrees(name, self._actual(name)) for name in DRIVEN}

    def commanded_degrees(self) -> dict[str, float | None]:
        """What each servo is told now, in the arm's degrees (None: limp)."""
        out: dict[str, float | None] = {}
        for name in DRIVEN:
            target = self._target(name, self.t)
            out[name] = None if target is None else self._degrees(name, target)
        return out

    def urdf_values(self) -> dict[str, float]:
        """The twin's joints as the URDF's values (radians; the gap in metres)."""
        values = {name: float(self.data.qpos[self._ids.qpos[name]]) for name in ARM_JOINTS}
        values["gripper"] = self._actual("gripper") * self.lever
        return values

    # -- the board's pulses ---------------------------------------------------------------

    def follow(self, channel: int, pulse: Pulse) -> None:
        """What `channel` puts out from the pulse's time on (the board's `observe_pulses`,
        in order): a servo sees it at its first frame from then."""
        self._coming.setdefault(channel, collections.deque()).append(pulse)

    def _pulse(self, name: str, t: float) -> Pulse | None:
        """What the joint's channel puts out at `t` (None: never anything yet)."""
        channel = self.channels[name]
        coming = self._coming.get(channel)
        while coming and coming[0].t0 <= t + 1e-9:
            self.pulses[channel] = coming.popleft()
            self._origin[name] = self._actual(name)
        return self.pulses.get(channel)

    def _limp(self, name: str, limp: bool) -> None:
        if self._on.get(name) is (not limp):
            return
        self._on[name] = not limp
        i = self._ids.actuator[name]
        gain, bias = self._gains[name]
        self.model.actuator_gainprm[i] = 0.0 if limp else gain
        self.model.actuator_biasprm[i] = 0.0 if limp else bias

    def advance_to(self, t: float) -> list[Held]:
        """Run whole frames until the next would end after `t`; what was found held."""
        found: list[Held] = []
        while self.t + FRAME_S <= t + 1e-9:
            found += self.frame()
        return found

    def frame(self) -> list[Held]:
        """One frame: the servos' targets now, the physics for 20 ms, then the checks."""
        ctrl = self.data.ctrl
        for name in DRIVEN:
            target = self._target(name, self.t)
            self._limp(name, target is None)
            if target is not None:
                i = self._ids.actuator[name]
                lo, hi = self.model.actuator_ctrlrange[i]
                ctrl[i] = min(max(target, lo), hi)
        mujoco.mj_step(self.model, self.data, nstep=self.steps_per_frame)
        self.t += FRAME_S
        for name, body in self._ids.objects.items():
            z = float(self.data.xpos[body][2])
            self._lifted[name] = max(self._lifted[name], z - self._start[name][2])
        touching = self._contacts()
        return self._check_held(touching)

    # -- what the body does ----------------------------------------------------------------

    def _position(self, name: str) -> Vec3:
        x, y, z = (float(v) for v in self.data.xpos[self._ids.objects[name]])
        return (x, y, z)

    def objects(self) -> dict[str, ObjectState]:
        """Every object's pose now, and its lift so far."""
        out = {}
        for name, body in self._ids.objects.items():
            w, x, y, z = (float(v) for v in self.data.xquat[body])
            out[name] = ObjectState(
                name, self._position(name), (x, y, z, w), self._start[name], self._lifted[name]
            )
        return out

    def _name_of_body(self, body: int) -> str:
        for name, b in self._ids.objects.items():
            if b == body:
                return name
        return "table"

    def _contacts(self) -> list[tuple[int, int, int]]:
        """(contact index, arm body, other body) of each contact of the arm with the world;
        the deepest each object (or the table) was sunk into by a link is kept."""
        m, d = self.model, self.data
        out = []
        for i in range(d.ncon):
            c = d.contact[i]
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            arm1, arm2 = b1 in self._ids.arm_bodies, b2 in self._ids.arm_bodies
            if arm1 == arm2:
                continue
            arm, other = (b1, b2) if arm1 else (b2, b1)
            out.append((i, arm, other))
            if c.dist < 0:
                what = self._name_of_body(other)
                self.deepest[what] = max(self.deepest.get(what, 0.0), -float(c.dist))
        return out

    def _carried(self, touching: list[tuple[int, int, int]]) -> set[int]:
        """The objects the arm holds up: touched by it and by nothing of the world."""
        m, d = self.model, self.data
        candidates = {other for _, _, other in touching if other in self._ids.objects.values()}
        for i in range(d.ncon):
            c = d.contact[i]
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            for here, there in ((b1, b2), (b2, b1)):
                if here in candidates and there not in self._ids.arm_bodies:
                    candidates.discard(here)
        return candidates

    def _check_held(self, touching: list[tuple[int, int, int]]) -> list[Held]:
        found = []
        for name in DRIVEN:
            watch = self._watch[name]
            held = self._holding(name)
            if held:
                watch.clear_since = None
                if watch.since is None:
                    watch.since = self.t
                if not watch.said and self.t - watch.since >= HOLD_S - 1e-9:
                    watch.said = True
                    found.append(self._why(name, touching))
            else:
                watch.since = None
                if watch.said:
                    if watch.clear_since is None:
                        watch.clear_since = self.t
                    elif self.t - watch.clear_since >= HOLD_S:
                        watch.said = False
                        watch.clear_since = None
        return found

    def _holding(self, name: str) -> bool:
        """Is the joint short of its target, at its servo's stall, and still?"""
        if not self._on.get(name):
            return False
        i = self._ids.actuator[name]
        target, actual = float(self.data.ctrl[i]), self._actual(name)
        if self._span_deg(name, target, actual) < SHORT_DEG:
            return False
        if abs(float(self.data.actuator_force[i])) < SATURATED * self.drives[name].stall_nm:
            return False
        if name == "gripper":
            speed = abs(float(self.data.qvel[self._ids.dof[GRIPPER_FINGERS[0]]])) * 2 / self.lever
        else:
            speed = abs(float(self.data.qvel[self._ids.dof[name]]))
        return math.degrees(speed) < STILL_DEG_S

    def _gripped(self, touching: list[tuple[int, int, int]]) -> set[int]:
        """The objects both fingers squeeze: touched by each on its inner face (the contact's
        normal across the gap, along the hand's y), not only resting on their tips."""
        fingers = self._ids.subtree["gripper"]
        across = self.data.xmat[self._ids.hand].reshape(3, 3)[:, 1]
        by_object: dict[int, set[int]] = {}
        for index, arm, other in touching:
            normal = np.asarray(self.data.contact[index].frame[:3])
            squeezed = abs(float(normal @ across)) > SQUEEZE_COS
            if arm in fingers and other in self._ids.objects.values() and squeezed:
                by_object.setdefault(other, set()).add(arm)
        return {o for o, touched in by_object.items() if touched == fingers}

    def _why(self, name: str, touching: list[tuple[int, int, int]]) -> Held:
        i = self._ids.actuator[name]
        short = self._span_deg(name, float(self.data.ctrl[i]), self._actual(name))
        stall = self.drives[name].stall_kg_cm
        carried = self._carried(touching) | self._gripped(touching)
        subtree = self._ids.subtree[name]
        if name == "gripper":
            against = [o for _, arm, o in touching if arm in subtree and o != 0]
        else:
            against = [o for _, arm, o in touching if arm in subtree and o not in carried]
        target, actual = float(self.data.ctrl[i]), self._actual(name)
        origin = self._origin.get(name, actual)
        past = (actual - target) * (origin - target) < 0  # beyond it, seen from whence it came
        if against:
            what = self._name_of_body(against[0])
            return Held(name, short, stall, against=what, t=self.t, past=past)
        if name == "gripper":  # closing on nothing, yet short: its fingers' own stops
            return Held(name, short, stall, t=self.t, past=past)
        needed = self._needed(name, carried)
        return Held(name, short, stall, needed_kg_cm=needed / KG_CM, t=self.t, past=past)

    def _needed(self, name: str, carried: set[int]) -> float:
        """The torque (N m) the joint needs to hold the arm at its targets with what it
        carries: gravity on the links there, and the weight of what the gripper holds,
        moved with the hand."""
        m, d, s = self.model, self.data, self._scratch
        s.qpos[:] = d.qpos
        s.qvel[:] = 0
        for joint in ARM_JOINTS:
            if self._on.get(joint):
                s.qpos[self._ids.qpos[joint]] = d.ctrl[self._ids.actuator[joint]]
        mujoco.mj_forward(m, s)
        dof = self._ids.dof[name]
        load = float(s.qfrc_bias[dof])
        hand = self._ids.hand
        jac = np.zeros((3, m.nv))
        for body in carried:
            local = d.xmat[hand].reshape(3, 3).T @ (d.xipos[body] - d.xpos[hand])
            point = s.xpos[hand] + s.xmat[hand].reshape(3, 3) @ local
            mujoco.mj_jac(m, s, jac, None, point, hand)
            weight = np.array([0.0, 0.0, float(m.body_subtreemass[body]) * m.opt.gravity[2]])
            load -= float(jac[:, dof] @ weight)
        return abs(load)
