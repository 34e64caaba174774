"""Messages to instructions (`al5d.ros.convert`), pure: a refusal names the first bad point."""

from __future__ import annotations

from typing import Any

import pytest
from al5d_interfaces.msg import ArmInstruction
from builtin_interfaces.msg import Duration
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from al5d.arm.config import load_config
from al5d.arm.instruction import Instruction, Kind
from al5d.ros.convert import URDF_SLACK, from_message, trajectory_from_message

CONFIG = load_config()
MODEL = CONFIG.model
PRESETS = tuple(CONFIG.presets)


def trajectory(points: list[tuple[int, float]]) -> JointTrajectory:
    """Elbow-only points: (time_from_start in ms, elbow in URDF radians)."""
    msg = JointTrajectory(joint_names=["elbow"])
    for ms, elbow in points:
        msg.points.append(
            JointTrajectoryPoint(
                positions=[elbow],
                time_from_start=Duration(sec=ms // 1000, nanosec=ms % 1000 * 10**6),
            )
        )
    return msg


@pytest.mark.parametrize(
    ("points", "first"),
    [
        # A time that does not increase at point 1, a position out of range at point 3.
        ([(100, 1.0), (100, 1.1), (300, 1.2), (400, 9.0)], "point 1: time_from_start 100 ms"),
        # The other way round.
        ([(100, 1.0), (200, 9.0), (300, 1.2), (300, 1.3)], "point 1: elbow: 9 rad is outside"),
    ],
)
def test_a_refused_trajectory_names_its_first_bad_point(
    points: list[tuple[int, float]], first: str
) -> None:
    reason = trajectory_from_message(trajectory(points), MODEL)
    assert isinstance(reason, str) and reason.startswith(first), reason


@pytest.mark.parametrize("finger", ["gripper_left", "gripper_right"])
def test_a_finger_of_the_urdf_is_refused_with_what_to_command_instead(finger: str) -> None:
    # Issue 22, defect 3: the URDF's fingers (mimics of `gripper`) raised KeyError here.
    msg = JointTrajectory(joint_names=["elbow", finger])
    msg.points.append(JointTrajectoryPoint(positions=[1.0, 0.01], time_from_start=Duration(sec=1)))
    reason = trajectory_from_message(msg, MODEL)
    assert isinstance(reason, str), reason
    assert reason.startswith(f"{finger} is a finger of the URDF's gripper") and (
        "command gripper, the gap between the fingers in metres" in reason
    )


@pytest.mark.parametrize("joint", ["base", "shoulder", "elbow", "wrist", "wrist_rotate", "gripper"])
def test_a_point_a_hair_beyond_a_urdf_limit_is_taken_at_the_ranges_end(joint: str) -> None:
    """Within `URDF_SLACK` of a limit (a limit sent back from radians): the end of the range,
    which the arm's check in degrees takes. It refused pi/2 + 1e-9 rad for the base, saying
    `base: -90.0000001 deg is outside the range -90..90` (an outside try)."""
    lo, hi = MODEL.urdf_limits(joint)
    span = getattr(MODEL.ranges, joint)
    for value in (lo - URDF_SLACK / 2, hi + URDF_SLACK / 2):
        msg = JointTrajectory(joint_names=[joint])
        msg.points.append(JointTrajectoryPoint(positions=[value], time_from_start=Duration(sec=2)))
        instr = trajectory_from_message(msg, MODEL)
        assert not isinstance(instr, str), instr
        (degrees,) = (deg for _, deg in instr.points[0].joints)
        assert degrees in (span.lo, span.hi), degrees
    msg = JointTrajectory(joint_names=[joint])
    msg.points.append(JointTrajectoryPoint(positions=[hi + 1e-3], time_from_start=Duration(sec=2)))
    reason = trajectory_from_message(msg, MODEL)
    assert isinstance(reason, str) and "outside its URDF limits" in reason, reason


@pytest.mark.parametrize("word", ["release", "shutdown"])
@pytest.mark.parametrize(
    "fields", [{"joints": ["base"], "degrees": [10.0]}, {"degrees": [10.0]}, {"time_ms": 500}]
)
def test_a_release_or_shutdown_with_joints_or_a_time_is_refused_as_ambiguous(
    word: str, fields: dict[str, Any]
) -> None:
    """As a preset with joints is: a shutdown with joints was taken (an outside try), the
    joints dropped without a word."""
    reason = from_message(ArmInstruction(instruction=word, **fields), PRESETS, MODEL)
    assert reason == f"{word} takes no joints or time (ambiguous); send it alone"
    assert isinstance(from_message(ArmInstruction(instruction=word), PRESETS, MODEL), Instruction)


@pytest.mark.parametrize(
    "fields", [{}, {"joints": ["base"], "degrees": [10.0]}, {"time_ms": 500}, {"degrees": [1.0]}]
)
def test_a_stop_is_taken_whatever_else_its_message_carries(fields: dict[str, Any]) -> None:
    instr = from_message(ArmInstruction(instruction="stop", id="s", **fields), PRESETS, MODEL)
    assert isinstance(instr, Instruction) and instr.kind is Kind.STOP and instr.id == "s"
