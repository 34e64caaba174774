"""The ROS 2 node `al5d`: topics, services and the move action, mapped onto the arm driver.

A thin adapter: messages become `Instruction`s (`al5d.ros.convert`), outcomes
become `InstructionResult`s. No callback waits for the arm. Services answer as
soon as the driver has taken the instruction (stop and release are synchronous
in the driver, a matter of microseconds). The move action's execute callback
is a coroutine that awaits the driver's outcome, so that a thousand waiting
goals hold no thread. Everything runs in one executor in one thread.
"""

from __future__ import annotations

import logging
import math
import time

import rclpy
from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.context import Context
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Outcome, new_id
from al5d.arm.states import State
from al5d.ros.actions import MoveAction
from al5d.ros.convert import (
    from_message,
    outcome_message,
    trajectory_from_message,
    trajectory_id,
)
from al5d.ros.runtime import (
    INSTRUCTION_TOPIC,
    JOINT_STATES_TOPIC,
    MOVE_ACTION,
    NODE,
    QOS_INSTRUCTIONS,
    QOS_LATCHED,
    QOS_STREAM,
    RESULT_TOPIC,
    STATE_TOPIC,
    TRAJECTORY_TOPIC,
    PublishThread,
    Spinner,
    bound_backlog,
    start_context,
)
from al5d.ros.safety import SafetyNode

log = logging.getLogger("al5d")


class ArmNode(Node):
    """Node `al5d`: every topic, service and action of the design, on one driver."""

    def __init__(self, driver: ArmDriver, context: Context) -> None:
        super().__init__(NODE, context=context)
        self.driver = driver
        self.presets = tuple(driver.config.presets)
        self.joint_names = list(driver.config.joints)
        # (id, monotonic ns) of each instruction message as its callback starts, when tracing
        # (`al5d serve --trace FILE`, used by the benchmarks): an append, nothing more.
        self.trace: list[tuple[str, str, int]] | None = None
        self.result_pub = self.create_publisher(InstructionResult, RESULT_TOPIC, QOS_STREAM)
        self.results: PublishThread[Outcome] = PublishThread(
            self.result_pub, outcome_message, "al5d-results"
        )
        self.state_pub = self.create_publisher(String, STATE_TOPIC, QOS_LATCHED)
        self.joint_pub = self.create_publisher(JointState, JOINT_STATES_TOPIC, 10)
        self.create_subscription(
            ArmInstruction, INSTRUCTION_TOPIC, self._on_instruction, QOS_INSTRUCTIONS
        )
        self.create_subscription(
            JointTrajectory, TRAJECTORY_TOPIC, self._on_trajectory, QOS_INSTRUCTIONS
        )
        self.move_action = MoveAction(self, driver, MOVE_ACTION)
        self.create_timer(1.0 / driver.settings.joint_state_rate_hz, self._tick)
        driver.outcome_listeners.append(self._publish_outcome)
        driver.state_listeners.append(self._publish_state)
        self._publish_state(driver.state)

    # -- outputs -------------------------------------------------------------------

    def _publish_outcome(self, outcome: Outcome) -> None:
        self.results.put(outcome)

    def _publish_state(self, state: State) -> None:
        self.state_pub.publish(String(data=state.value))

    def _tick(self) -> None:
        """/joint_states at a fixed rate (radians, REP 103), and feedback for running goals."""
        degrees = self.driver.positions()
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = self.joint_names
        msg.position = [math.radians(degrees[j]) for j in self.joint_names]
        self.joint_pub.publish(msg)
        self.move_action.feedback(degrees)

    # -- inputs ---------------------------------------------------------------------

    def _on_instruction(self, msg: ArmInstruction) -> None:
        if self.trace is not None:
            self.trace.append((msg.id, "recv", time.monotonic_ns()))
        instr = from_message(msg, self.presets)
        if isinstance(instr, str):
            self.driver.refuse(msg.id or new_id(), msg.instruction, instr)
            return
        self.driver.submit(instr)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        """A trajectory is one instruction: every point checked, then all run or none."""
        instr = trajectory_from_message(msg)
        if isinstance(instr, str):
            self.driver.refuse(trajectory_id(msg), "trajectory", instr)
            return
        self.driver.submit(instr)


class RosServer:
    """The nodes with their executor threads, for `al5d serve`: `al5d` for the instructions,
    the action and the outputs, and `al5d_safety` for the stop, release and shutdown."""

    def __init__(self, driver: ArmDriver, trace: str | None = None) -> None:
        backlog = driver.settings.instruction_backlog
        theirs = bound_backlog(INSTRUCTION_TOPIC, backlog)
        if theirs:
            log.warning("Fast DDS profiles from %s: the instruction backlog is theirs", theirs)
        self.context = start_context()
        self.node = ArmNode(driver, self.context)
        self.safety = SafetyNode(driver, self.context)
        self.trace_path = trace
        if trace is not None:
            self.node.trace = []
            events = self.node.trace
            # ...and when each move's bytes were written: the server's share of the path.
            driver.motion_listeners.append(
                lambda sent: events.append((sent.instr.id, "write", int(sent.t_write * 1e9)))
            )
        self.safety_spinner = Spinner(self.safety, self.context, owns_context=False)
        self.spinner = Spinner(self.node, self.context, owns_context=False)

    def close(self) -> None:
        # Let the last results (the shutdown's) reach their readers before the node goes.
        self.node.results.close()
        self.node.result_pub.wait_for_all_acked(rclpy.duration.Duration(seconds=1))
        self.safety_spinner.close()
        self.spinner.close()
        self.context.try_shutdown()
        if self.trace_path is not None and self.node.trace is not None:
            with open(self.trace_path, "w", encoding="utf-8") as f:
                f.writelines(f"{ident} {what} {t}\n" for ident, what, t in self.node.trace)
