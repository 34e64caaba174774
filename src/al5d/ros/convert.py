"""ROS messages to instructions and outcomes, and back: pure functions, no node."""

from __future__ import annotations

import math
import time
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import replace

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory

from al5d.arm.instruction import (
    SAFETY,
    TIME_FIELD_MAX_MS,
    Instruction,
    Kind,
    Outcome,
    Point,
    Result,
    ToolTarget,
    new_id,
    quote,
)
from al5d.arm.validate import time_problem
from al5d.model import ArmModel, ModelError
from al5d.model.joints import GRIPPER_FINGERS, Range

#: A `move_to` over ROS names its values in `joints` and gives them in `degrees`, in
#: ROS units: x, y, z in metres (base_link), pitch and roll in radians, gripper the gap
#: in metres (or gripper_deg in the servo's degrees, as the text grammar has it), and
#: path 0 (one group move) or 1 (a straight line).
TOOL_FIELDS = ("x", "y", "z", "pitch", "roll", "gripper", "gripper_deg", "path")


def tool_fields(instr: Instruction) -> tuple[list[str], list[float]]:
    """A `move_to`'s names and values in the message's units."""
    t = instr.tool
    assert t is not None
    pairs: list[tuple[str, float]] = [("x", t.x_m), ("y", t.y_m), ("z", t.z_m)]
    if t.pitch_deg is not None:
        pairs.append(("pitch", math.radians(t.pitch_deg)))
    if t.roll_deg is not None:
        pairs.append(("roll", math.radians(t.roll_deg)))
    if t.gripper_deg is not None:
        pairs.append(("gripper_deg", t.gripper_deg))
    if t.line:
        pairs.append(("path", 1.0))
    return [n for n, _ in pairs], [v for _, v in pairs]


def tool_from_fields(
    names: Sequence[str], values: Sequence[float], model: ArmModel
) -> ToolTarget | str:
    """The target of a `move_to` from a message's or goal's names and values, or why not."""
    if len(names) != len(values):
        return f"joints and degrees differ in length ({len(names)} and {len(values)})"
    given: dict[str, float] = {}
    for name, value in zip(names, values, strict=True):
        if name not in TOOL_FIELDS:
            return f"move_to takes {', '.join(TOOL_FIELDS)}, not {quote(name)}"
        if name in given:
            return f"{name} is given twice"
        given[name] = float(value)
    missing = [k for k in ("x", "y", "z") if k not in given]
    if missing:
        return f"move_to needs {', '.join(missing)} (metres)"
    if "gripper" in given and "gripper_deg" in given:
        return "gripper and gripper_deg are given both: ambiguous"
    path = given.get("path", 0.0)
    if path not in (0.0, 1.0):
        return f"path is 0 (one group move) or 1 (a straight line), not {path:g}"
    gripper = given.get("gripper_deg")
    if "gripper" in given:
        outside = outside_urdf_limits(model, "gripper", given["gripper"])
        if outside:
            return outside
        gripper = model.gripper_map.deg_from_gap(given["gripper"])
    # Degrees to a nanodegree: -30 sent as radians comes back -30, not -29.999999999999996.
    pitch, roll = given.get("pitch"), given.get("roll")
    return ToolTarget(
        given["x"],
        given["y"],
        given["z"],
        None if pitch is None else round(math.degrees(pitch), 9),
        None if roll is None else round(math.degrees(roll), 9),
        gripper,
        path == 1.0,
    )


def to_message(instr: Instruction) -> ArmInstruction:
    """The message of an instruction; a time its uint32 field cannot carry is an error here,
    not a number that wraps around on the way (4294967301 ms would arrive as 5 ms)."""
    if instr.time_ms is not None and not 0 <= instr.time_ms <= TIME_FIELD_MAX_MS:
        raise ValueError(
            f"time {instr.time_ms} ms does not fit the message (0..{TIME_FIELD_MAX_MS})"
        )
    msg = ArmInstruction()
    msg.instruction = instr.name
    if instr.kind is Kind.MOVE_TO:
        msg.joints, msg.degrees = tool_fields(instr)
    else:
        msg.joints = [j for j, _ in instr.joints]
        msg.degrees = [float(d) for _, d in instr.joints]
    msg.time_ms = instr.time_ms or 0
    msg.id = instr.id
    return msg


def move_from_fields(
    joints: Sequence[str], degrees: Sequence[float], time_ms: int | None, ident: str
) -> Instruction | str:
    """A move from a message's or goal's parallel arrays, or why it is not one."""
    if len(joints) != len(degrees):
        return f"joints and degrees differ in length ({len(joints)} and {len(degrees)})"
    pairs = tuple(zip(joints, degrees, strict=True))
    return Instruction(Kind.MOVE, joints=pairs, time_ms=time_ms, id=ident)


#: In a stop's id, what follows it names a copy of the stop before it (`stop_key`).
COPY_MARK = "~"


def sent_ns(info: Mapping[str, int | None]) -> int | None:
    """When a message was sent (CLOCK_REALTIME ns), from the info rclpy hands a callback."""
    return info.get("source_timestamp")


def came_ns(info: Mapping[str, int | None]) -> int:
    """When a message came to this machine (CLOCK_REALTIME ns): its info's, else now."""
    return info.get("received_timestamp") or time.time_ns()


def stop_key(msg: ArmInstruction, info: Mapping[str, int | None]) -> Hashable:
    """What one stop is known by to every reader of its topic (the node and the stop watcher
    both see it; `al5d.arm.core`'s rule 3: obeyed once): a copy of a stop (its id
    `<stop>~<copy>`, `COPY_MARK`) that names its client, by that and the stop's id before
    the mark (the copies `al5d.ros.client` and the web view send until one is answered are
    one stop, so a
    copy that comes after another client's release is the stop obeyed already, and does
    not lock the arm again); any other, by its message (its source timestamp and
    publication sequence number): a stop sent again under the same id is a stop again."""
    stop, mark, _ = msg.id.partition(COPY_MARK)
    if msg.client and stop and mark:
        return ("stop", msg.client, stop)
    return info.get("source_timestamp"), info.get("publication_sequence_number")


def stop_time(sent: int | None, came: int, offset: int | None) -> int:
    """When a stop counts from: when it was sent, on this machine's clock where its
    sender's is known (`offset`: `al5d.ros.leases.Lease.offset_ns`, its client's lease),
    else on its sender's (as its releases are judged), never later than when it came to
    this machine. Taken on its sender's clock, a stop from a client seconds behind was
    undone by a release sent before it that came after it (`al5d.arm.core`, rule 1); one
    from a client seconds ahead would hold every release sent in those seconds.
    Docs/ros.md, "Across a network".
    """
    return came if not sent else min(sent + (offset or 0), came)


def from_message(
    msg: ArmInstruction, presets: tuple[str, ...], model: ArmModel, sent: int | None = None
) -> Instruction | str:
    """The instruction in a message (sent at `sent`, CLOCK_REALTIME ns), or why it is not one."""
    word = msg.instruction.strip().lower()
    ident = msg.id or new_id()
    time_ms = msg.time_ms or None
    if word == Kind.MOVE_TO.value:
        tool = tool_from_fields(msg.joints, msg.degrees, model)
        if isinstance(tool, str):
            return tool
        return Instruction(Kind.MOVE_TO, tool=tool, time_ms=time_ms, id=ident, sent_ns=sent)
    if word in presets:
        if len(msg.joints) or len(msg.degrees):
            return f"{word} is a preset: it takes no joints (ambiguous); send a move instead"
        return Instruction(Kind.PRESET, preset=word, time_ms=time_ms, id=ident, sent_ns=sent)
    if word == Kind.MOVE.value:
        move = move_from_fields(msg.joints, msg.degrees, time_ms, ident)
        return move if isinstance(move, str) else replace(move, sent_ns=sent)
    for kind in SAFETY:
        if word == kind.value:
            if kind is not Kind.STOP and (len(msg.joints) or len(msg.degrees) or time_ms):
                # A stop is obeyed whatever else its message carries.
                return f"{word} takes no joints or time (ambiguous); send it alone"
            return Instruction(kind, id=ident, sent_ns=sent)
    known = " | ".join((*presets, "move", "move_to", *(k.value for k in SAFETY)))
    return f"unknown instruction {quote(msg.instruction)}; expected {known}"


def outcome_message(outcome: Outcome) -> InstructionResult:
    msg = InstructionResult()
    msg.id = outcome.id
    msg.instruction = outcome.instruction
    msg.outcome = outcome.result.value
    msg.reason = outcome.reason
    msg.elapsed_ms = float(outcome.elapsed_ms)
    return msg


def outcome_from_message(msg: InstructionResult) -> Outcome:
    return Outcome(msg.id, msg.instruction, Result(msg.outcome), msg.reason, msg.elapsed_ms)


def trajectory_id(msg: JointTrajectory | JointState) -> str:
    """The id a trajectory's (or a joint command's) outcome carries: `header.frame_id` when
    the sender set it (neither message has an id field, and the frame is unused), else the
    header's stamp, `<sec>.<nanosec>`, which a sender that stamps its messages knows."""
    header: Header = msg.header
    if header.frame_id:
        return str(header.frame_id)
    stamp = header.stamp
    return f"{stamp.sec}.{stamp.nanosec:09d}"


def model_joint(name: str, prefix: str) -> str | None:
    """The model's name of a joint the URDF names `name` behind the arm's joint `prefix`
    (`left_base` -> `base`); None when `name` does not carry the prefix."""
    if not name.startswith(prefix):
        return None
    return name[len(prefix) :]


def not_this_arms(name: str, prefix: str) -> str:
    """Why a joint named without the arm's prefix is none of its joints."""
    return (
        f"{quote(name[:60])} is not a joint of this arm: its joints are named {prefix}base, "
        f"{prefix}shoulder... (server.joint_prefix {prefix!r})"
    )


def joint_command_from_message(
    msg: JointState, model: ArmModel, sent: int | None = None, prefix: str = ""
) -> Instruction | str:
    """The move a joint command asks for (sensor_msgs/JointState, as ros2_control's
    topic-based hardware publishes its position commands: the URDF's names and values), or
    why it is not one. Judged whole: a name the URDF does not have, a value that is not a
    number or is outside its limits, refuses it all. NaN is ros2_control's "no command"
    (a command interface no controller has set yet, such as the gripper's while only the
    arm's controller runs): that joint is left where it is. The fingers, mimics of
    `gripper`, are left out: their commands are the hardware's own. Every name carries
    the arm's joint `prefix` (`server.joint_prefix`)."""
    names = list(msg.name)
    positions = list(msg.position)
    if len(msg.velocity) or len(msg.effort):
        return (
            "a joint command gives velocity or effort: the AL5D's servos take positions only "
            "(give its joints position command interfaces only)"
        )
    if len(positions) != len(names):
        return (
            f"{len(positions)} positions for {len(names)} joints: every joint named needs a "
            "position (in ros2_control, a position command interface)"
        )
    joints: list[tuple[str, float]] = []
    for given, value in zip(names, positions, strict=True):
        name = model_joint(given, prefix)
        if name is None:
            return not_this_arms(given, prefix)
        if name in GRIPPER_FINGERS or (math.isnan(value) and _urdf_limits(model, name) is not None):
            continue
        degrees = arm_degrees(model, name, value, prefix)
        if isinstance(degrees, str):
            return degrees
        joints.append((name, degrees))
    if not joints:
        return (
            "a joint command with no joint of the arm to move (NaN is ros2_control's "
            "'no command yet': no controller has set one)"
        )
    return Instruction(Kind.MOVE, joints=tuple(joints), id=trajectory_id(msg), sent_ns=sent)


def trajectory_from_message(
    msg: JointTrajectory, model: ArmModel, sent: int | None = None, prefix: str = ""
) -> Instruction | str:
    """The trajectory of a message (the URDF's joint values to the arm's degrees, times to
    ms), or why it is not one. The points' joints and times are judged by the driver's
    validation, whole; a name the URDF does not have is kept for it to name. Every name
    carries the arm's joint `prefix` (`server.joint_prefix`). A `header.stamp` that is not
    zero is when it starts (`Instruction.start_ns`), as ros2_control's controllers take it."""
    names: list[str] = []
    for given in msg.joint_names:
        name = model_joint(given, prefix)
        if name is None:
            return not_this_arms(given, prefix)
        if name in GRIPPER_FINGERS:
            return (
                f"{given} is a finger of the URDF's gripper, which follows the joint "
                f"{prefix}gripper (a mimic): command {prefix}gripper, the gap between the "
                "fingers in metres"
            )
        names.append(name)
    points: list[Point] = []
    before = 0.0
    for i, point in enumerate(msg.points):
        if len(point.positions) != len(names):
            return f"point {i}: {len(point.positions)} positions for {len(names)} joints"
        for field in ("velocities", "accelerations"):
            values = getattr(point, field)
            if len(values) and len(values) != len(names):  # empty: not given, as the JTC allows
                return f"point {i}: {len(values)} {field} for {len(names)} joints"
            # Not used (the servos' speeds come from the times), but a goal is taken whole.
            bad = next((v for v in values if not math.isfinite(v)), None)
            if bad is not None:
                return f"point {i}: {field} hold {bad:g}"
        if len(point.effort):  # as the JTC refuses it where it commands no effort
            return f"point {i}: gives effort: the AL5D's servos take positions only"
        t = point.time_from_start
        at_ms = t.sec * 1000.0 + t.nanosec * 1e-6
        # Here too, so that the reason names the first bad point whatever is wrong with it.
        late = time_problem(i, at_ms, before)
        if late:
            return late
        before = at_ms
        degrees: list[tuple[str, float]] = []
        for name, value in zip(names, point.positions, strict=True):
            deg = arm_degrees(model, name, value, prefix)
            if isinstance(deg, str):
                return f"point {i}: {deg}"
            degrees.append((name, deg))
        points.append(Point(tuple(degrees), at_ms))
    stamp = msg.header.stamp
    start = stamp.sec * 1_000_000_000 + stamp.nanosec  # before 1970 (sec < 0): past
    return Instruction(
        Kind.TRAJECTORY,
        points=tuple(points),
        id=trajectory_id(msg),
        sent_ns=sent,
        start_ns=start if start > 0 else None,
    )


#: What a value may be off its URDF limit and still be taken (it is checked again, in the
#: arm's degrees, by the driver): a limit sent back from radians is not always exact.
URDF_SLACK = 1e-9


def _urdf_limits(model: ArmModel, joint: str) -> tuple[float, float] | None:
    """The URDF joint's limits; None if the URDF has no such joint."""
    try:
        return model.urdf_limits(joint)
    except ModelError:
        return None


def outside_urdf_limits(model: ArmModel, joint: str, value: float, prefix: str = "") -> str:
    """Why a URDF joint value is outside its limits, in the sender's units (radians, or
    metres for the gripper's gap) and names (the model's `joint` behind the arm's joint
    `prefix`); "" if it is inside, or not a URDF joint (the driver's validation names
    those)."""
    got = arm_degrees(model, joint, value, prefix)
    return got if isinstance(got, str) else ""


def arm_degrees(model: ArmModel, joint: str, value: float, prefix: str = "") -> float | str:
    """A URDF joint value (REP 103 radians, the gripper's gap in metres) in the arm's degrees,
    or why it is outside its URDF limits (`outside_urdf_limits`); for a joint the URDF does
    not have, the value as degrees (for validation to name). A value `URDF_SLACK` beyond a
    limit at most is that end of the joint's range: the arm's check in degrees has no
    slack, and refused pi/2 + 1e-9 rad as "base: -90.0000001 deg is outside the range
    -90..90", in units and a sign its sender never used."""
    limits = _urdf_limits(model, joint)
    if limits is None:
        return math.degrees(value)
    lo, hi = limits
    if not (math.isfinite(value) and lo - URDF_SLACK <= value <= hi + URDF_SLACK):
        unit = "m" if joint == "gripper" else "rad"
        limits_text = f"{lo:.4g}..{hi:.4g} {unit}"
        return f"{prefix}{joint}: {value:g} {unit} is outside its URDF limits {limits_text}"
    span: Range = getattr(model.ranges, joint)
    return min(max(model.from_urdf({joint: value})[joint], span.lo), span.hi)
