"""The arm configuration: joints, calibration, servo speeds, presets and server settings.

Loaded from YAML and validated with pydantic so that a mistake is reported
with the key, the value and the reason. The default is the package's own
`al5d/data/al5d.yaml` (the repository's `config/al5d.yaml` links to it), found
the same way by the server, the tests and an installed package. The emulator
and the arm driver read the same file, so what the emulated servos do and what
the driver expects of them come from one place.
"""

from __future__ import annotations

import difflib
import functools
import math
import re
from collections.abc import Hashable, Mapping
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from al5d.arm.instruction import PRESET_NAMES, SEQUENCE_ONLY, SHELL_HELP, SHELL_QUIT, Kind
from al5d.arm.servos import SERVOS
from al5d.model import JOINTS as AL5D_JOINTS
from al5d.model import ArmModel
from al5d.model.chain import BASE_LINK, LINK_OF_JOINT, TOOL_LINK
from al5d.model.transforms import Mount as ModelMount
from al5d.ssc32u.driver import DEFAULT_READ_TIMEOUT_S
from al5d.ssc32u.facts import BAUDS, CHANNELS, FACTORY_BAUD, PULSE_MAX_US, PULSE_MIN_US

#: Every arm has these presets (PO01..PO03); a config may add more.
REQUIRED_PRESETS = PRESET_NAMES
DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "data" / "al5d.yaml"

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class ConfigError(ValueError):
    """The configuration file cannot be used; the message names the key and the reason."""


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class ReferencePoint(_Frozen):
    """A measured calibration point: at `deg` degrees the servo needs `us` microseconds."""

    deg: FiniteFloat
    us: FiniteFloat = Field(ge=PULSE_MIN_US, le=PULSE_MAX_US)


class JointSettings(_Frozen):
    """One joint: its channel, safe range, calibration and servo (model, or speed)."""

    name: str = ""
    channel: int
    range_deg: tuple[FiniteFloat, FiniteFloat]
    calibration: tuple[ReferencePoint, ReferencePoint]
    #: A model of `al5d.arm.servos.SERVOS`; it gives the speed unless speed_deg_s is given.
    servo: str | None = None
    speed_deg_s: FiniteFloat = Field(gt=0, le=10000)
    unit: str = "deg"

    @model_validator(mode="before")
    @classmethod
    def _speed_from_servo(cls, data: Any) -> Any:
        if not isinstance(data, Mapping) or data.get("speed_deg_s") is not None:
            return data
        model = data.get("servo")
        if model is None:
            raise ValueError("give the servo's model (servo: HS-485HB) or its speed_deg_s")
        if model not in SERVOS:
            raise ValueError(f"servo {model!r} is not in the table; known: {', '.join(SERVOS)}")
        return {**data, "speed_deg_s": SERVOS[model].speed_deg_s}

    @field_validator("channel")
    @classmethod
    def _channel_exists(cls, v: int) -> int:
        if v not in CHANNELS:
            raise ValueError(f"channel {v} is outside 0..31")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> JointSettings:
        lo, hi = self.range_deg
        if not lo < hi:
            raise ValueError(f"range_deg [{lo}, {hi}]: the first value must be below the second")
        a, b = self.calibration
        if a.deg == b.deg:
            raise ValueError(f"calibration: both reference points are at {a.deg} degrees")
        if a.us == b.us:
            raise ValueError(f"calibration: both reference points give {a.us} us")
        if self.servo is not None and self.servo not in SERVOS:
            known = ", ".join(SERVOS)
            raise ValueError(f"servo {self.servo!r} is not in the table; known: {known}")
        pmin, pmax = SERVOS[self.servo].pulse_us if self.servo else (PULSE_MIN_US, PULSE_MAX_US)
        for end in (lo, hi):
            us = self.to_us(end)
            if not pmin <= us <= pmax:
                raise ValueError(f"range_deg end {end} maps to {us:.0f} us, outside {pmin}..{pmax}")
        return self

    @property
    def us_per_deg(self) -> float:
        """Signed scale: the sign is the joint's direction."""
        a, b = self.calibration
        return (b.us - a.us) / (b.deg - a.deg)

    def to_us(self, deg: float) -> float:
        a = self.calibration[0]
        return a.us + (deg - a.deg) * self.us_per_deg

    def to_deg(self, us: float) -> float:
        a = self.calibration[0]
        return a.deg + (us - a.us) / self.us_per_deg

    def in_range(self, deg: float) -> bool:
        lo, hi = self.range_deg
        return lo <= deg <= hi

    @property
    def speed_us_s(self) -> float:
        return self.speed_deg_s * abs(self.us_per_deg)


#: One segment of a ROS name: a letter, then letters, digits and underscores.
_NAME_SEGMENT = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


#: The longest namespace: its server's lane is a Unix socket named after it, whose path
#: holds at most 107 bytes (a 300-character one ended `al5d send` in rcl's traceback).
NAMESPACE_MAX = 64


def namespace_problem(namespace: str) -> str | None:
    """Why `namespace` (`left`, `/left`, `/lab/left`; "" or "/" for none) is no ROS namespace."""
    ns = namespace.strip("/")
    if len(ns) > NAMESPACE_MAX:
        return (
            f"namespace {namespace[:40]!r}...: at most {NAMESPACE_MAX} characters (its server's "
            "local lane is a socket named after it)"
        )
    if ns and not all(_NAME_SEGMENT.fullmatch(seg) for seg in ns.split("/")):
        return (
            f"namespace {namespace[:40]!r}: each part must start with a letter and hold only "
            "letters, digits and underscores"
        )
    return None


def frame_problem(frame: str) -> str | None:
    """Why `frame` (`world`, `lab/table`) is no TF frame name, or None."""
    if (
        not frame
        or frame.startswith("/")
        or not all(_NAME_SEGMENT.fullmatch(seg) for seg in frame.split("/"))
    ):
        return (
            f"frame {frame[:40]!r}: parts separated by '/' (none leading), each starting with a "
            "letter and holding only letters, digits and underscores"
        )
    return None


def joint_prefix_problem(prefix: str) -> str | None:
    """Why `prefix` cannot start the URDF's joint names ("" is none), or None: letters,
    digits and underscores, a letter first, so that every joint name stays one MoveIt and
    ros2_control take as a YAML key and a parameter name."""
    if prefix and not _NAME_SEGMENT.fullmatch(prefix):
        return (
            f"joint_prefix {prefix[:40]!r}: letters, digits and underscores, starting with a "
            "letter (e.g. left_), or '' for none"
        )
    return None


def default_joint_prefix(namespace: str) -> str:
    """The joints' prefix of an arm in `namespace` that names none: the namespace's parts
    joined by underscores, and one after (`left` -> `left_`, `/lab/left` -> `lab_left_`);
    none without a namespace."""
    ns = namespace.strip("/")
    return f"{ns.replace('/', '_')}_" if ns else ""


#: A mount's offset, metres: a lab's size, not a typo's (an x of 5e3 is a unit mistaken).
MOUNT_REACH_M = 100.0
Metres = Annotated[float, Field(allow_inf_nan=False, ge=-MOUNT_REACH_M, le=MOUNT_REACH_M)]
Radians = Annotated[float, Field(allow_inf_nan=False, ge=-math.tau, le=math.tau)]


class Mount(_Frozen):
    """`server.mount`: where the arm's base_link stands in a frame it shares with other arms
    (and the room): published as a static transform from `parent`, so that several arms
    are one TF tree. `xyz` in metres, `rpy` fixed-axis roll, pitch, yaw in radians, as a
    URDF joint's origin."""

    parent: str = "world"
    xyz: tuple[Metres, Metres, Metres] = (0.0, 0.0, 0.0)
    rpy: tuple[Radians, Radians, Radians] = (0.0, 0.0, 0.0)

    @field_validator("parent")
    @classmethod
    def _frame(cls, v: str) -> str:
        problem = frame_problem(v)
        if problem:
            raise ValueError(problem)
        return v

    def frame(self) -> ModelMount:
        """The mount as the robot model takes it."""
        return ModelMount(self.parent, self.xyz, self.rpy)


#: The joint states are the server's sign of life: the web view takes the server for lost
#: after 1 s without one, a client says so after 1 s, and holds its lease back after 0.5 s
#: (`al5d.ros.leasing.Leaser`). At 0.001 Hz (accepted once) both said the server was
#: lost while it ran.
MIN_JOINT_STATE_RATE_HZ = 4.0


#: The longest lease of a client (`server.client_lease_s`), in seconds.
MAX_CLIENT_LEASE_S = 60.0


class ServerSettings(_Frozen):
    """How the high-level driver behaves, independent of the arm's geometry."""

    queue_capacity: int = Field(default=1024, ge=1, le=1_000_000)
    #: Instruction messages that may wait in DDS for the server to take them (back-pressure
    #: beyond: the sender is slowed, nothing is lost); the stop watcher's reader holds as
    #: many, newest kept (`al5d.ros.qos.qos_watch`).
    instruction_backlog: int = Field(default=1000, ge=10, le=1_000_000)
    startup_speed_fraction: float = Field(default=0.5, gt=0, le=1)
    max_move_time_ms: int = Field(default=60_000, ge=1, le=65_535)
    #: /joint_states, /tf and the tool pose while the arm moves (the web view wants >= 20)...
    joint_state_rate_hz: float = Field(default=25.0, ge=MIN_JOINT_STATE_RATE_HZ, le=1000)
    #: ...and once it has been at rest for a second: the same messages, restamped. Each
    #: publishing tick costs the server about 0.7 ms of CPU with one subscriber, the larger
    #: part of its idle load (bench: idle CPU); MoveIt waits for a state newer than its
    #: request, up to one period of this rate.
    idle_joint_state_rate_hz: float = Field(default=10.0, ge=MIN_JOINT_STATE_RATE_HZ, le=1000)
    reconnect_interval_s: float = Field(default=0.5, gt=0, le=60)
    #: The link (and that the board has not reset) is checked with a `QP` of one channel
    #: (4 bytes) this often while the arm is idle...
    idle_check_interval_s: float = Field(default=0.5, gt=0, le=60)
    #: ...and this often while a move runs: a dead link is a fault within about 0.3 s.
    moving_check_interval_s: float = Field(default=0.15, gt=0, le=60)
    #: How late an answer may be beyond its wire time (and the USB chip's latency timer)
    #: before it is asked once more and then is a fault: a Bluetooth or radio serial link
    #: takes tens of milliseconds each way, and needs more than the board's 5 ms.
    answer_timeout_s: float = Field(default=DEFAULT_READ_TIMEOUT_S, gt=0, le=5)
    baud: int = Field(default=FACTORY_BAUD)
    #: How far (degrees) a joint may be off a trajectory's path when the trajectory is denser
    #: than the wire carries and is thinned (`arm.resample`), where its sender gives no
    #: tolerance (a FollowJointTrajectory goal's path_tolerance does).
    #: The watchdog of a stream of set-points (`joint_commands`, the web view's jog): when
    #: none has come for this long while the arm still moves toward the last, the arm is
    #: held where it is (its source has stopped, or lost its link).
    stream_timeout_s: float = Field(default=0.5, gt=0, le=60)
    #: A ROS client that commands motion sends its lease a few times a second; when none
    #: has come for this long, the client is lost (cut off, killed, hung) and what it
    #: commanded is halted, its queued moves cancelled (docs/ros.md, "Across a network").
    client_lease_s: float = Field(default=1.0, gt=0, le=MAX_CLIENT_LEASE_S)
    trajectory_path_tolerance_deg: FiniteFloat = Field(default=1.0, gt=0, le=45)
    #: Every move (joint or Cartesian, a trajectory's every point and the path between, a
    #: set-point) is refused whole if its path would take a body of the arm under the table
    #: (`geometry.table_height_mm`); false: only the joints' ranges hold it.
    table_check: bool = Field(default=True, strict=True)
    #: The ROS namespace of this arm's names ("" none; `left` gives /left/al5d/...).
    namespace: str = ""
    #: Where the arm stands in a shared frame (None: nowhere said; base_link is a root).
    mount: Mount | None = None
    #: Put before every URDF joint name (/joint_states, the trajectory and gripper actions,
    #: joint_commands, the URDF), so that several arms make one robot (`left_base`): None
    #: takes the namespace's (`default_joint_prefix`), "" none.
    joint_prefix: str | None = None

    @property
    def joint_name_prefix(self) -> str:
        """The prefix the URDF's joint names carry: `joint_prefix`, or the namespace's."""
        return self.joint_prefix_in(self.namespace)

    def joint_prefix_in(self, namespace: str) -> str:
        """The joints' prefix of this arm served in `namespace` (a `--namespace` that
        overrides the file's): `joint_prefix`, or that namespace's."""
        if self.joint_prefix is not None:
            return self.joint_prefix
        return default_joint_prefix(namespace)

    @model_validator(mode="after")
    def _idle_rate_not_above_moving(self) -> ServerSettings:
        if self.idle_joint_state_rate_hz > self.joint_state_rate_hz:
            raise ValueError(
                f"idle_joint_state_rate_hz {self.idle_joint_state_rate_hz:g} must not exceed "
                f"joint_state_rate_hz {self.joint_state_rate_hz:g}"
            )
        return self

    @model_validator(mode="after")
    def _mount_outside_the_arm(self) -> ServerSettings:
        if self.mount is None:
            return self
        ns = self.namespace.strip("/")
        prefix = f"{ns}/" if ns else ""
        own = {prefix + link for link in (BASE_LINK, TOOL_LINK, *LINK_OF_JOINT.values())}
        if self.mount.parent in own:
            raise ValueError(
                f"mount.parent {self.mount.parent!r} is a frame of this arm itself; the mount "
                "hangs the arm from a frame outside it (e.g. world)"
            )
        return self

    @field_validator("joint_prefix")
    @classmethod
    def _joint_prefix(cls, v: str | None) -> str | None:
        problem = None if v is None else joint_prefix_problem(v)
        if problem:
            raise ValueError(problem)
        return v

    @field_validator("namespace")
    @classmethod
    def _ros_namespace(cls, v: str) -> str:
        problem = namespace_problem(v)
        if problem:
            raise ValueError(problem)
        return v

    @field_validator("baud")
    @classmethod
    def _known_baud(cls, v: int) -> int:
        if v not in BAUDS:
            raise ValueError(f"baud {v}: the SSC-32U runs at {', '.join(map(str, BAUDS))}")
        return v


class GeometrySettings(_Frozen):
    """The arm's lengths in millimetres; the defaults are Lynxmotion's published constants.

    Arms differ (sources give an ulna of 177 to 187 mm): measure yours.
    """

    #: Table to the shoulder axis, along the base axis.
    base_height_mm: FiniteFloat = Field(default=67.31, gt=0, le=1000)
    #: Base axis to the shoulder axis, horizontally along the arm (0 on the AL5D).
    shoulder_offset_mm: FiniteFloat = Field(default=0.0, ge=0, le=1000)
    #: Shoulder axis to elbow axis (5.75 in).
    humerus_mm: FiniteFloat = Field(default=146.05, gt=0, le=1000)
    #: Elbow axis to the wrist pitch axis (7.375 in).
    ulna_mm: FiniteFloat = Field(default=187.325, gt=0, le=1000)
    #: Wrist pitch axis to the tool tip (tool0), the wrist rotate included.
    gripper_mm: FiniteFloat = Field(default=100.0, gt=0, le=1000)
    #: The gap between the fingers fully open (the gripper's range's first end).
    gripper_open_mm: FiniteFloat = Field(default=32.0, gt=0, le=500)
    #: The table's top above base_link (0: the base stands on it; < 0 on a plate).
    #: Cartesian moves that would take the arm below it are refused.
    table_height_mm: FiniteFloat = Field(default=0.0, ge=-1000, le=1000)

    @model_validator(mode="after")
    def _table_below_shoulder(self) -> GeometrySettings:
        if self.table_height_mm >= self.base_height_mm:
            raise ValueError(
                f"table_height_mm {self.table_height_mm:g} must be below the shoulder axis "
                f"(base_height_mm {self.base_height_mm:g})"
            )
        return self

    def metres(self) -> dict[str, float]:
        """The lengths in metres, named as `al5d.model.Geometry` names them."""
        return {name.removesuffix("_mm"): value / 1000.0 for name, value in self}


class ArmConfig(_Frozen):
    """The whole arm: joints by name, presets in degrees, geometry, server settings."""

    joints: dict[str, JointSettings]
    presets: dict[str, dict[str, FiniteFloat]]
    geometry: GeometrySettings = GeometrySettings()
    server: ServerSettings = ServerSettings()

    @model_validator(mode="before")
    @classmethod
    def _name_joints(cls, data: Any) -> Any:
        if isinstance(data, Mapping) and isinstance(data.get("joints"), Mapping):
            joints = {
                name: ({**j, "name": name} if isinstance(j, Mapping) else j)
                for name, j in data["joints"].items()
            }
            data = {**data, "joints": joints}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> ArmConfig:
        missing = [j for j in AL5D_JOINTS if j not in self.joints]
        extra = [j for j in self.joints if j not in AL5D_JOINTS]
        if missing or extra:
            raise ValueError(
                f"joints: an AL5D has {', '.join(AL5D_JOINTS)}"
                + (f"; missing: {', '.join(missing)}" if missing else "")
                + (f"; not an AL5D joint: {', '.join(extra)}" if extra else "")
            )
        seen: dict[int, str] = {}
        for name, joint in self.joints.items():
            if not name.isidentifier() or name != name.lower():
                raise ValueError(f"joints.{name}: a joint name is a lower-case identifier")
            if joint.channel in seen:
                raise ValueError(
                    f"joints.{name}.channel: channel {joint.channel} is already used by "
                    f"{seen[joint.channel]}"
                )
            seen[joint.channel] = name
        for preset in REQUIRED_PRESETS:
            if preset not in self.presets:
                raise ValueError(f"presets.{preset}: this preset is required")
        words = {k.value for k in Kind}
        typed = {*SEQUENCE_ONLY, *SHELL_QUIT, *SHELL_HELP}
        for preset, pose in self.presets.items():
            if preset.strip().lower() in words:
                # `stop` as a preset would be a move to the arm and a stop to whoever reads it.
                raise ValueError(f"presets.{preset}: the name of an instruction, not a preset")
            if preset.strip().lower() in typed:
                # A sequence file's `wait`, the shell's `help`: read as theirs, the preset
                # could never be sent from either.
                raise ValueError(
                    f"presets.{preset}: a word of sequence files or al5d shell, not a preset"
                )
            for jname in pose:
                if jname not in self.joints:
                    # Before the missing ones: a typo (`elbw`) is both, and this names it.
                    near = difflib.get_close_matches(jname, self.joints, n=1, cutoff=0.6)
                    hint = f"; did you mean {near[0]!r}?" if near else ""
                    raise ValueError(f"presets.{preset}.{jname}: no such joint{hint}")
            missing = [j for j in self.joints if j not in pose]
            if missing:
                raise ValueError(f"presets.{preset}: no angle for {', '.join(missing)}")
            for jname, deg in pose.items():
                joint = self.joints[jname]
                if not joint.in_range(deg):
                    lo, hi = joint.range_deg
                    raise ValueError(
                        f"presets.{preset}.{jname}: {deg} is outside the range {lo}..{hi}"
                    )
        return self

    @model_validator(mode="after")
    def _presets_above_the_table(self) -> ArmConfig:
        # The server parks as it starts and as it ends without judging the park's path (it
        # is how the arm is made safe, from wherever it is): its pose at least must be above
        # the table. Every other preset is a target too: one under the table is refused at
        # every use, so it is said here, once.
        from al5d.model.kinematics import below_table

        for preset, pose in self.presets.items():
            under = below_table(self.model, pose)
            if under is not None:
                raise ValueError(f"presets.{preset}: {under}")
        return self

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(j.channel for j in self.joints.values())

    @functools.cached_property
    def model(self) -> ArmModel:
        """The arm as a robot model (ranges and geometry): kinematics, URDF, MoveIt data."""
        ranges = {name: j.range_deg for name, j in self.joints.items()}
        return ArmModel.from_config(ranges, self.geometry.metres())

    @property
    def speeds_deg_s(self) -> dict[str, float]:
        return {name: j.speed_deg_s for name, j in self.joints.items()}


def _keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    """Every key of `model` a file may hold, dotted (`server.queue_capacity`); a mapping's
    own keys (joints by name, presets) not followed."""
    out = []
    for name, field in model.model_fields.items():
        out.append(prefix + name)
        kind = field.annotation
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            out += _keys(kind, f"{prefix}{name}.")
    return out


def _unknown_key_hint(loc: tuple[Any, ...]) -> str:
    """The hint for a key no section has ("; did you mean ...?"): a close one beside it, or
    one of the same name in a section (`queue_capacity` for `server.queue_capacity`)."""
    keys = _keys(ArmConfig)
    if "joints" in loc[:1] and len(loc) == 3:  # joints.<name>.<key>
        keys = [f"joints.{loc[1]}.{k}" for k in _keys(JointSettings)]
    dotted = ".".join(str(x) for x in loc)
    parent = dotted.rpartition(".")[0]
    last = str(loc[-1])
    beside = {k.rpartition(".")[2]: k for k in keys if k.rpartition(".")[0] == parent}
    near = [beside[n] for n in difflib.get_close_matches(last, beside, n=1, cutoff=0.75)]
    if not near:
        near = [k for k in keys if k.rpartition(".")[2] == last and k != dotted][:1]
    return f"; did you mean {near[0]!r}?" if near else ""


def describe_errors(err: ValidationError, source: str, names: Mapping[str, str]) -> str:
    """pydantic's errors as lines `SOURCE: the.key: why (value: ...)`, a key known to the user
    by another name (a ROS parameter's) given by `names`; an unknown key with the one meant,
    where one is close."""
    lines = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"])
        loc = names.get(loc, loc)
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg += _unknown_key_hint(e["loc"])
        shown = e.get("input")
        value = "" if isinstance(shown, Mapping) else f" (value: {shown!r})"
        # A check of the whole names the keys it judges in its message.
        lines.append(f"{source}: {loc}: {msg}{value}" if loc else f"{source}: {msg}{value}")
    return "\n".join(lines)


def parse_config(
    data: Any, source: str = "<config>", names: Mapping[str, str] | None = None
) -> ArmConfig:
    """Validate already-loaded YAML data; raise ConfigError naming the key on failure (by
    `names`, where a key is known to the user by another name: a ROS parameter's)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: the file must hold a mapping with joints and presets")
    try:
        return ArmConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(describe_errors(e, source, names or {})) from None


#: `server.answer_timeout_s` at least this on the embedded emulator. That board is threads
#: of the server's own process, sharing its interpreter (one GIL) and the host's cores with
#: the owner: an answer late from it is this host's stall, never a cable (seen: `al5d demo
#: --physics` beside a test run and two busy loops lost its link, "no answer to QP4, asked
#: twice, 218 ms late"). A real board, or `al5d emulator` in a process of its own, keeps the
#: configured timeout.
EMBEDDED_ANSWER_S = 1.0


def on_embedded_board(config: ArmConfig) -> ArmConfig:
    """`config` as a server runs it on the embedded emulator (`EMBEDDED_ANSWER_S`)."""
    if config.server.answer_timeout_s >= EMBEDDED_ANSWER_S:
        return config
    server = config.server.model_copy(update={"answer_timeout_s": EMBEDDED_ANSWER_S})
    return config.model_copy(update={"server": server})


def with_changes(
    config: ArmConfig,
    changes: Mapping[str, Any],
    source: str = "<config>",
    names: Mapping[str, str] | None = None,
) -> ArmConfig:
    """`config` with keys changed by their dotted names (`server.joint_state_rate_hz`),
    validated whole by the same code as a file; ConfigError names the key, from `source`."""
    data: dict[str, Any] = config.model_dump()
    for dotted, value in changes.items():
        *path, last = dotted.split(".")
        here = data
        for key in path:
            if not isinstance(here.get(key), dict):
                here[key] = {}
            here = here[key]
        here[last] = value
    return parse_config(data, source, names)


class _UniqueKeys(yaml.SafeLoader):
    """PyYAML's safe loader, but a mapping that names a key twice is an error: the safe one
    keeps the last, silently (seen: a pose written twice by hand took the second)."""


def _mapping(loader: _UniqueKeys, node: yaml.MappingNode) -> dict[Any, Any]:
    loader.flatten_mapping(node)  # `<<` merges: a key they bring may be named again
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node)
        if isinstance(key, Hashable) and key in seen:
            raise yaml.constructor.ConstructorError(
                "while reading a mapping",
                node.start_mark,
                f"{key!r} is named twice",
                key_node.start_mark,
            )
        seen.add(key)
    return loader.construct_mapping(node, deep=True)


_UniqueKeys.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def load_yaml(text: str) -> Any:
    """YAML text's data, as `yaml.safe_load` reads it but a key named twice in a mapping is
    a `yaml.YAMLError` (with its line)."""
    return yaml.load(text, Loader=_UniqueKeys)


def read_yaml(
    path: Path, what: str = "the configuration", error: type[ConfigError] = ConfigError
) -> Any:
    """A YAML file's data; `error` says, naming the file, why it cannot be read (`what` it
    was to be) or is not YAML."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise error(f"{path}: cannot read {what}: {e.strerror}") from None
    try:
        return load_yaml(text)
    except yaml.YAMLError as e:
        raise error(f"{path}: not valid YAML: {e}") from None


def load_config(path: str | Path | None = None) -> ArmConfig:
    """Read and validate a configuration file (the shipped default when `path` is None)."""
    p = Path(path) if path is not None else DEFAULT_CONFIG
    return parse_config(read_yaml(p), str(p))
