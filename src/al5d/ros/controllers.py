"""The standard control actions MoveIt drives: FollowJointTrajectory and GripperCommand.

`arm_controller/follow_joint_trajectory` and `gripper_controller/gripper_cmd`
in the server's namespace, the names MoveIt's simple controller manager looks
for with controllers named `arm_controller` and `gripper_controller`. They
behave as ros2_controllers' joint_trajectory_controller and gripper controller
do where it matters to a client:

- the goal callback judges the whole goal and rejects a bad one before it is
  accepted (nothing is written for it; the reason is also published on the
  result topic, with the goal's UUID in hex as the id);
- a new trajectory goal preempts a running one, which ends CANCELED and says so, and a
  new gripper goal preempts the gripper's;
- a cancel halts the arm where it is, without the emergency lock: CANCELED; a goal
  cancelled while it waits to run (for the halt of the goal it preempts) ends
  CANCELED before it runs;
- an emergency stop aborts the goal, and the arm is locked as always.

A trajectory denser than the serial link carries is thinned by the driver's
judgement (`al5d.arm.resample`) within the goal's `path_tolerance` (the
configured default for a joint it does not name), and a goal with a
`goal_time_tolerance` whose points the servos cannot reach in time is rejected
then, with the limit it meets.

Values are the URDF's (REP 103 radians, the gripper's gap in metres); the
one mapping to the arm's degrees is the model's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from control_msgs.action import FollowJointTrajectory, GripperCommand
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from al5d.arm.instruction import Instruction, Kind, Outcome, Result, start_too_far
from al5d.arm.jobs import Sent
from al5d.arm.resample import Follow
from al5d.clock import wall_ns
from al5d.model import ArmModel, ModelError
from al5d.owner.client import Judged, Remote
from al5d.ros.actions import (
    CANCELLED_BEFORE_RUN,
    GoalRunner,
    action_server,
    inactive,
)
from al5d.ros.convert import trajectory_from_message
from al5d.ros.workarounds import preempted

log = logging.getLogger("al5d")
FJT = FollowJointTrajectory.Result
#: The gripper's gap counts as reached within this (metres): a quarter of a servo
#: microsecond's worth is far below it, a visible miss far above.
GRIPPER_REACHED_M = 0.0005


#: A goal_time_tolerance of -1 s is no limit, as ros2_controllers' trajectory controller
#: takes it (its "erase" value); 0 is the default (here none either).
NO_LIMIT_S = -1.0


def _seconds(duration: Any) -> float:
    return float(duration.sec) + float(duration.nanosec) * 1e-9


@dataclass(frozen=True)
class Tolerance:
    """A joint's position tolerance (URDF units); None: not checked."""

    joint: str
    position: float | None


def tolerances(
    given: Sequence[Any], joints: Sequence[str], prefix: str = ""
) -> list[Tolerance] | str:
    """The goal's tolerances for our joints (0: the default, none; -1: no limit), or why not;
    each by the model's name of its joint (the URDF's, `joints`, behind `prefix`)."""
    out: list[Tolerance] = []
    for t in given:
        if t.name not in joints:
            return f"a tolerance names {t.name[:40]!r}, which is not a joint of the trajectory"
        if not math.isfinite(t.position):
            return f"{t.name}: tolerance {t.position} is not a number"
        out.append(Tolerance(t.name[len(prefix) :], t.position if t.position > 0 else None))
    return out


@dataclass
class Running:
    """A trajectory goal while it runs: its points in URDF values, and when it started."""

    handle: ServerGoalHandle
    names: list[str]
    times: list[float]  # each point's time_from_start, seconds
    points: list[list[float]]  # each point's positions, URDF values
    first: list[float]  # where the named joints were when it was accepted
    path: list[Tolerance]
    #: The points sent to the board, by index (a trajectory denser than the wire carries
    #: is thinned: `al5d.arm.resample`); its first and last points always.
    knots: list[int] = field(default_factory=list)
    t0: float | None = None  # when its first move reached the board
    #: When its times count from: `t0`, or, when its first point is at 0 (the start state,
    #: reached at the servos' speed), when that point is reached (as the driver counts).
    origin: float | None = None
    violated: str = ""  # a path tolerance broken: why
    written: int = 0  # its points written so far
    #: Per point written: how late the board will reach it after its time_from_start (s).
    late: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.knots:
            self.knots = list(range(len(self.times)))

    def desired(self, t: float) -> list[float]:
        """Where the trajectory says the joints are at `t` (linear between points, as the
        board moves: its group moves interpolate pulses, which are linear in the values)."""
        if self.t0 is None or self.origin is None or t <= self.t0:  # not yet on the board
            return list(self.first)
        if t < self.origin:  # on the way to a start point at 0
            f = (t - self.t0) / (self.origin - self.t0)
            return [a + (b - a) * f for a, b in zip(self.first, self.points[0], strict=True)]
        s = t - self.origin
        before_t, before = 0.0, self.first
        for at, point in zip(self.times, self.points, strict=True):
            if s < at:
                f = (s - before_t) / (at - before_t)
                return [a + (b - a) * f for a, b in zip(before, point, strict=True)]
            before_t, before = at, point
        return list(before)


@dataclass(frozen=True)
class Accepted:
    """An accepted trajectory goal: its ticket (the owner's) and its tolerances."""

    ticket: Judged
    path: list[Tolerance]
    end: list[Tolerance]


class FollowTrajectoryAction(GoalRunner):
    """`arm_controller/follow_joint_trajectory` on a node, onto the board's owner."""

    def __init__(self, node: Node, arm: Remote, name: str) -> None:
        super().__init__(node, arm)
        self.model: ArmModel = arm.config.model
        #: Before every joint name of a goal and its feedback (`server.joint_prefix`).
        self.prefix = arm.config.server.joint_name_prefix
        self.running: dict[str, Running] = {}
        self.server = action_server(
            node, FollowJointTrajectory, name, self._execute, self._goal, self._cancel
        )
        arm.motion_listeners.append(self._on_motion)

    # -- judging a goal ---------------------------------------------------------------

    name = "follow_joint_trajectory"
    goal_type = JointTrajectory
    preempts = True
    preempted_reason = "preempted by trajectory goal"

    def word(self, goal: Any) -> str:
        return Kind.TRAJECTORY.value

    def goal_message(self, goal: Any, ident: str) -> JointTrajectory:
        """The goal's trajectory, its header's frame the goal's id (as the trajectory topic's
        outcomes are named)."""
        trajectory = goal.trajectory
        msg = JointTrajectory(joint_names=trajectory.joint_names, points=trajectory.points)
        msg.header.stamp = trajectory.header.stamp
        msg.header.frame_id = ident
        return msg

    def judge(self, goal: Any, ident: str, sent: int) -> Accepted | str:
        if len(goal.multi_dof_trajectory.points):
            return "multi-DOF trajectories are not supported: the AL5D has single-DOF joints"
        instr = trajectory_from_message(goal.trajectory, self.model, prefix=self.prefix)
        if isinstance(instr, str):
            return instr
        too_far = start_too_far(instr.start_ns, wall_ns())  # rejected, as the owner would
        if too_far:
            return too_far
        instr = Instruction(
            Kind.TRAJECTORY, points=instr.points, id=ident, sent_ns=sent, start_ns=instr.start_ns
        )
        names = list(goal.trajectory.joint_names)
        path = tolerances(goal.path_tolerance, names, self.prefix)
        end = tolerances(goal.goal_tolerance, names, self.prefix)
        for t in (path, end):
            if isinstance(t, str):
                return t
        assert not isinstance(path, str) and not isinstance(end, str)
        late_s = _seconds(goal.goal_time_tolerance)
        if late_s < 0 and late_s != NO_LIMIT_S:
            return f"goal_time_tolerance {late_s:g} s is negative (-1: no limit; 0: the default)"
        busy = inactive(self.arm)
        if busy:
            return busy
        ticket = self.arm.judge(instr, self._follow(path, late_s))
        if isinstance(ticket, str):
            return ticket
        return Accepted(ticket, path, end)

    def _follow(self, path: list[Tolerance], late_s: float) -> Follow:
        """The goal's tolerances in the arm's degrees, for the owner's judgement (which knows
        where the arm rests)."""
        degrees = {t.joint: self._degrees(t.joint, t.position) for t in path if t.position}
        return Follow(
            {j: d for j, d in degrees.items() if d is not None},
            late_s * 1000.0 if late_s > 0 else None,
        )

    def _degrees(self, joint: str, tolerance: float) -> float | None:
        """A URDF tolerance (radians, or metres for the gripper) in the joint's degrees: the
        least it is anywhere in the joint's range (the gripper's gap is not linear in its
        servo's angle). None: not a joint of the model (validation names it)."""
        try:
            lo, hi = self.model.urdf_limits(joint)
        except ModelError:
            return None
        least = math.inf
        for k in range(9):
            x = lo + (hi - lo) * k / 8
            y = x + tolerance if x + tolerance <= hi else x - tolerance
            a, b = self.model.from_urdf({joint: x})[joint], self.model.from_urdf({joint: y})[joint]
            least = min(least, abs(b - a))
        return least if math.isfinite(least) and least > 0 else None

    # -- running it -------------------------------------------------------------------

    async def _execute(self, handle: ServerGoalHandle) -> Any:
        ident, judged = self._take_judged(handle)
        goal = handle.request
        if judged is None:  # rclpy executes only what the goal callback accepted
            handle.abort()
            return _result(FJT.INVALID_GOAL, "the goal was never judged")
        # A goal cancelled before it began does not preempt: it never would have run.
        if reason := self.ended_before_run(handle, ident, judged.ticket):
            return _unrun(reason)
        if by := await self._preempt(ident, Kind.TRAJECTORY.value):
            self.preempted_first(handle, ident, judged.ticket, by, Kind.TRAJECTORY.value)
            return _preempted_result(by)
        if reason := self.ended_before_run(handle, ident, judged.ticket):
            return _unrun(reason)
        # The model's names (the goal's carry the arm's joint prefix, as its feedback does).
        names = [n[len(self.prefix) :] for n in goal.trajectory.joint_names]
        here = self._actual(names)
        run = Running(
            handle,
            names,
            [_seconds(p.time_from_start) for p in goal.trajectory.points],
            [list(p.positions) for p in goal.trajectory.points],
            here,
            judged.path,
            judged.ticket.knots,
        )
        outcome = await self._run(ident, run, judged.ticket)
        return self._finish(ident, run, outcome, judged.end, goal)

    def _finish(
        self, ident: str, run: Running, outcome: Outcome, end: list[Tolerance], goal: Any
    ) -> Any:
        handle = run.handle
        if by := self.preempter(ident, outcome):
            preempted(handle)
            return _preempted_result(by)
        if outcome.result is Result.CANCELLED and run.violated:
            handle.abort()
            return _result(FJT.PATH_TOLERANCE_VIOLATED, run.violated)
        if outcome.result is Result.CANCELLED and handle.is_cancel_requested:
            handle.canceled()
            if run.t0 is None and not run.written:  # it waited at the owner: dropped there
                return _result(FJT.SUCCESSFUL, CANCELLED_BEFORE_RUN)
            return _result(FJT.SUCCESSFUL, "cancelled: the arm halted where it was")
        if outcome.result is Result.REFUSED:  # the state changed between accept and run
            handle.abort()
            return _result(FJT.INVALID_GOAL, f"refused: {outcome.reason}")
        if not outcome.ok:
            handle.abort()
            # An emergency stop (or a fault) left the arm off its path.
            return _result(FJT.PATH_TOLERANCE_VIOLATED, f"{outcome.result.value}: {outcome.reason}")
        late = run.late[-1] if len(run.late) == len(run.knots) else 0.0
        note = lateness(run)
        allowed = _seconds(goal.goal_time_tolerance)
        if note and allowed > 0 and late > allowed:
            handle.abort()
            return _result(
                FJT.GOAL_TOLERANCE_VIOLATED, f"{note}; goal_time_tolerance is {allowed:g} s"
            )
        actual = dict(zip(run.names, self._actual(run.names), strict=True))
        final = dict(zip(run.names, run.points[-1], strict=True))
        for t in end:
            miss = abs(actual[t.joint] - final[t.joint])
            if t.position is not None and miss > t.position:
                handle.abort()
                return _result(
                    FJT.GOAL_TOLERANCE_VIOLATED,
                    f"{self.prefix}{t.joint} ended {miss:.4g} from its goal, "
                    f"tolerance {t.position:g}",
                )
        handle.succeed()
        return _result(FJT.SUCCESSFUL, note)

    def _on_motion(self, sent: Sent) -> None:
        """Each move of a running goal on the board (any thread): the first starts the goal's
        clock, and each records how late its point comes against its time_from_start."""
        run = self.running.get(sent.instr.id)
        if run is None:
            return
        end = sent.motion.t0 + sent.motion.duration_s
        if run.t0 is None:
            # The path starts where the board starts it, which a read-back after a halt
            # may have corrected since the goal was accepted.
            start = self.model.to_urdf(sent.motion.start)
            run.first = [start.get(n, v) for n, v in zip(run.names, run.first, strict=True)]
            run.t0 = sent.motion.t0
            # A first point the board is sent as 0 ms (under 0.5 ms, in whole ms) goes at
            # the servos' speed: the times count from its end, as the driver's do.
            run.origin = end if round(run.times[0] * 1000.0) == 0 else run.t0
        k, run.written = run.written, run.written + 1
        if k < len(run.knots) and run.origin is not None:
            run.late.append(end - (run.origin + run.times[run.knots[k]]))

    def _actual(self, names: Sequence[str]) -> list[float]:
        values = self.model.to_urdf(self.arm.positions())
        return [values[n] for n in names]

    # -- feedback ---------------------------------------------------------------------

    def feedback(self, degrees: Mapping[str, float], t: float) -> None:
        """Desired, actual and error to every running goal (the joint-state rate); a path
        tolerance broken halts the goal. `degrees`: where the arm is at `t`."""
        if not self.running or any(v != v for v in degrees.values()):
            return
        values = self.model.to_urdf(degrees)
        stamp = self.node.get_clock().now().to_msg()
        for ident, run in list(self.running.items()):
            actual = [values[n] for n in run.names]
            # Not yet on the board (it waits behind another move): its path starts where
            # the board will start it, so nothing is off it yet.
            desired = run.desired(t) if run.t0 is not None else actual
            error = [d - a for d, a in zip(desired, actual, strict=True)]
            fb = FollowJointTrajectory.Feedback()
            fb.header.stamp = stamp
            fb.joint_names = [self.prefix + n for n in run.names]
            fb.desired = JointTrajectoryPoint(positions=desired)
            fb.actual = JointTrajectoryPoint(positions=actual)
            fb.error = JointTrajectoryPoint(positions=error)
            if run.handle.is_active:
                run.handle.publish_feedback(fb)
            for tol in run.path:
                i = run.names.index(tol.joint)
                if tol.position is not None and abs(error[i]) > tol.position and not run.violated:
                    run.violated = (
                        f"{self.prefix}{tol.joint} was {abs(error[i]):.4g} off its path, "
                        f"tolerance {tol.position:g}"
                    )
                    self.arm.cancel(ident, run.violated)


#: A point reached this much after its time_from_start is reported late: less is rounding
#: (times are sent in whole ms, a time's digits change its wire time by a millisecond).
LATE_REPORTED_S = 0.005


def lateness(run: Running) -> str:
    """What the result says of points reached late: the last one, and the latest of those
    before it (a later point may catch up)."""
    parts = []
    before, last = run.late[:-1], run.late[-1:]
    if before and max(before) >= LATE_REPORTED_S:
        k = max(range(len(before)), key=before.__getitem__)
        parts.append(
            f"point {run.knots[k]} was reached {before[k] * 1000.0:.0f} ms after its "
            "time_from_start"
        )
    if last and last[0] >= LATE_REPORTED_S:
        parts.append(
            f"the last point was reached {last[0] * 1000.0:.0f} ms after its time_from_start"
        )
    return "; ".join(parts) + ": faster than the servos can move (INF03)" if parts else ""


def _preempted_result(by: str) -> Any:
    """As the joint_trajectory_controller ends a preempted goal."""
    why = "current goal cancelled due to new incoming action"
    return _result(FJT.INVALID_GOAL, f"preempted by goal {by}: {why}")


def _unrun(reason: str) -> Any:
    """A goal that ended before it ran (`GoalRunner.ended_before_run`): cancelled by its
    client, as the joint_trajectory_controller ends one; or left by every client, as a
    running one is (`_finish`: ended off its path, which a waiting goal never took)."""
    if reason == CANCELLED_BEFORE_RUN:
        return _result(FJT.SUCCESSFUL, reason)
    return _result(FJT.PATH_TOLERANCE_VIOLATED, f"{Result.CANCELLED.value}: {reason}")


def _result(code: int, text: str) -> Any:
    result = FollowJointTrajectory.Result()
    result.error_code = code
    result.error_string = text
    return result


class GripperAction(GoalRunner):
    """`gripper_controller/gripper_cmd`: the gap in metres, through the gripper servo.

    A new goal preempts the gripper's goals before it, as ros2_controllers' gripper
    controller does: they end CANCELED. No force sensing: `effort` is 0 and `stalled`
    always false.
    """

    JOINT = "gripper"

    def __init__(self, node: Node, arm: Remote, name: str) -> None:
        super().__init__(node, arm)
        self.model: ArmModel = arm.config.model
        self.server = action_server(
            node, GripperCommand, name, self._execute, self._goal, self._cancel
        )

    name = "gripper_cmd"
    goal_type = JointState
    preempts = True
    preempted_reason = "preempted by gripper goal"

    def goal_message(self, goal: Any, ident: str) -> JointState:
        """The gap asked for as the gripper joint's position (its max_effort as its effort),
        as a joint command names it."""
        prefix = self.arm.config.server.joint_name_prefix
        msg = JointState(name=[prefix + self.JOINT], position=[goal.command.position])
        msg.effort = [goal.command.max_effort]
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = ident
        return msg

    def judge(self, goal: Any, ident: str, sent: int) -> Judged | str:
        gap = goal.command.position
        if not math.isfinite(gap):
            return f"gripper position {gap} is not a number of metres"
        lo, hi = self.model.urdf_limits(self.JOINT)
        if not lo <= gap <= hi:
            return f"gripper gap {gap:.4g} m is outside {lo:g}..{hi:.4g} m"
        degrees = self.model.from_urdf({self.JOINT: gap})[self.JOINT]
        instr = Instruction(Kind.MOVE, joints=((self.JOINT, degrees),), id=ident, sent_ns=sent)
        busy = inactive(self.arm)
        return busy or self.arm.judge(instr)

    async def _execute(self, handle: ServerGoalHandle) -> Any:
        ident, ticket = self._take_judged(handle)
        if ticket is None:  # rclpy executes only what the goal callback accepted
            handle.abort()
            return GripperCommand.Result()
        result = GripperCommand.Result()
        word = Kind.MOVE.value
        # A goal cancelled before it began does not preempt: it never would have run.
        if self.ended_before_run(handle, ident, ticket):
            result.position = self._gap()
            return result
        if by := await self._preempt(ident, word):
            self.preempted_first(handle, ident, ticket, by, word)
            result.position = self._gap()
            return result
        if self.ended_before_run(handle, ident, ticket):
            result.position = self._gap()
            return result
        outcome = await self._run(ident, handle, ticket)
        result.position = self._gap()
        result.effort = 0.0
        result.stalled = False
        result.reached_goal = (
            outcome.ok
            and abs(result.position - handle.request.command.position) <= GRIPPER_REACHED_M
        )
        # Taken whatever the outcome: a goal preempted as it ended done keeps nothing behind.
        by = self.preempter(ident, outcome)
        if outcome.ok:
            handle.succeed()
        elif by:
            preempted(handle)
        elif outcome.result is Result.CANCELLED and handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
        return result

    def _gap(self) -> float:
        return self.model.to_urdf(self.arm.positions()).get(self.JOINT, math.nan)

    def feedback(self) -> None:
        if not self.running:
            return
        fb = GripperCommand.Feedback()
        fb.position = self._gap()
        fb.stalled = False
        for handle in list(self.running.values()):
            if handle.is_active:
                handle.publish_feedback(fb)
