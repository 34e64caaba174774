"""The bridge's ROS 2 nodes: topics and actions, mapped onto the owner of the board.

A thin adapter: messages become `Instruction`s (`al5d.ros.convert`), stamped with when
they were sent (the DDS sample's source timestamp, so that the owner can order what
comes by different channels: `al5d.arm.core`), handed to the owner over the lane, and
outcomes become `InstructionResult`s. No callback waits for the arm. Three nodes, each
with a thread of its own: `al5d` (the instruction, trajectory and joint-command topics,
read with each message's info by a `workarounds.Reader`; the results and the state; the
server's settings as ROS parameters, `al5d.ros.params`, whose services an executor of
its own answers), `al5d_actions` (the move action and MoveIt's two controllers: an
action's execute callback is a coroutine that awaits the owner's outcome, so that a
thousand waiting goals hold no thread) and `al5d_robot` (the robot's description, joint
states and transforms, from timers on rclpy's events executor, whose idle tick is the
cheaper). The safety services are `al5d.ros.safety`'s.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from dataclasses import replace
from typing import Any

from al5d_interfaces.msg import ArmInstruction, ClientLease, InstructionResult
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from al5d.arm.config import ServerSettings
from al5d.arm.instruction import MAX_ID, MAX_QUOTE, Kind, Outcome, Result, new_id
from al5d.arm.jobs import Sent
from al5d.arm.states import State
from al5d.clock import now
from al5d.owner.client import SILENCE_KEPT_S, LaneClosed, Remote
from al5d.owner.lane import LaneError
from al5d.owner.teller import RefusalLog, Repeats
from al5d.ros import params
from al5d.ros.actions import GoalRunner, MoveAction
from al5d.ros.controllers import FollowTrajectoryAction, GripperAction
from al5d.ros.convert import (
    COPY_MARK,
    came_ns,
    from_message,
    joint_command_from_message,
    outcome_message,
    sent_ns,
    stop_key,
    stop_time,
    trajectory_from_message,
    trajectory_id,
)
from al5d.ros.executors import PublishThread
from al5d.ros.leases import Leases
from al5d.ros.names import ACTIONS_NODE, NODE, PING, ROBOT_NODE, Names, pinned
from al5d.ros.params import Settings
from al5d.ros.qos import QOS_COMMANDS, QOS_INSTRUCTIONS, QOS_LATCHED, QOS_LEASES, QOS_STREAM
from al5d.ros.robot import RobotPublisher
from al5d.ros.workarounds import Handler, Reader, ReaderOnly, taken_by_reader

log = logging.getLogger("al5d")


#: The stream of set-points the joint commands are (`Remote.submit`'s `stream`).
JOINT_COMMANDS = "joint_commands"


#: How often a joint command's refusal is published again when its reason has not changed.
COMMAND_REFUSALS_EVERY_S = 1.0


class ArmNode(Node):
    """Node `al5d`: the server's settings as parameters (`declare`), then every topic of the
    design on the owner, under `names` (`attach`)."""

    def __init__(self, context: Context, names: Names) -> None:
        super().__init__(NODE, namespace=names.node_namespace, context=context)
        self.names = names
        # The inputs a `Reader` takes: the executor that answers the parameter services
        # must leave them alone.
        self.reader_group = ReaderOnly()
        self.settings: Settings | None = None
        #: Told the server's settings when a parameter changes them at run time.
        self.appliers: list[Callable[[ServerSettings], None]] = []
        # (id, monotonic ns) of each instruction message as its callback starts, when tracing
        # (`al5d serve --trace FILE`, used by the benchmarks): an append, nothing more.
        self.trace: list[tuple[str, str, int]] | None = None
        #: Told each message the node read on its input topics, after its handling: (topic,
        #: message, its info). Set before `attach` (`al5d serve --record` records them).
        self.heard: Callable[[str, Any, dict[str, int]], None] | None = None

    # -- parameters -----------------------------------------------------------------

    def declare(self, settings: Settings) -> None:
        """Every parameter at its value in `settings` (what the server runs with, overrides
        and flags applied already), and the check of changes at run time."""
        self.settings = settings
        for name, value in settings.values().items():
            descriptor = ParameterDescriptor(
                description=params.description(name),
                read_only=name not in params.RUNTIME,
                # Validated by the config's code, which takes 50 for 50.0 as a file does.
                dynamic_typing=True,
            )
            self.declare_parameter(name, value, descriptor, ignore_override=True)
        self.add_pre_set_parameters_callback(self._as_declared)
        self.add_on_set_parameters_callback(self._check)
        self.add_post_set_parameters_callback(self._apply)

    def _as_declared(self, changed: list[Parameter]) -> list[Parameter]:
        """An integer for a double parameter is set as that double: its type stays double."""
        assert self.settings is not None
        values = self.settings.values()
        return [
            Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if params.widened(values.get(p.name), p.value)
            else p
            for p in changed
        ]

    def _check(self, changed: list[Parameter]) -> SetParametersResult:
        assert self.settings is not None
        changes = {p.name: p.value for p in changed}
        wrong = params.wrong_type(self.settings.values(), changes)
        got = wrong or params.with_changes(self.settings, changes)
        if isinstance(got, str):
            return SetParametersResult(successful=False, reason=got)
        return SetParametersResult(successful=True)

    def _apply(self, changed: list[Parameter]) -> None:
        assert self.settings is not None
        got = params.with_changes(self.settings, {p.name: p.value for p in changed})
        if isinstance(got, str):  # `_check` has passed it: nothing changed meanwhile
            log.error("parameters %s not applied: %s", [p.name for p in changed], got)
            return
        self.settings = got
        log.info("parameters set: %s", ", ".join(f"{p.name}={p.value!r}" for p in changed))
        for apply in self.appliers:
            apply(got.config.server)

    # -- the arm --------------------------------------------------------------------

    def attach(self, arm: Remote) -> None:
        """The topics, on the owner (once, after `declare`)."""
        names = self.names
        self.arm = arm
        self.model = arm.config.model
        self.presets = tuple(arm.config.presets)
        self._refusals = RefusalLog()
        self._refusals_lock = threading.Lock()
        self.result_pub = self.create_publisher(InstructionResult, names.result, QOS_STREAM)
        self.results: PublishThread[Outcome] = PublishThread(
            self.result_pub, outcome_message, "al5d-results"
        )
        self.state_pub = self.create_publisher(String, names.state, QOS_LATCHED)
        # For clients that judge before they send (`Client.config`), on any machine: the
        # configuration in effect (the parameters' values at start), not a file's name.
        self.config_pub = self.create_publisher(String, names.config, QOS_LATCHED)
        self.config_pub.publish(String(data=json.dumps(arm.config.model_dump(mode="json"))))
        # Read by a thread of their own, with each message's info (see `workarounds.Reader`).
        group = self.reader_group
        instructions = self.create_subscription(
            ArmInstruction,
            names.instruction,
            taken_by_reader,
            QOS_INSTRUCTIONS,
            callback_group=group,
        )
        trajectories = self.create_subscription(
            JointTrajectory,
            names.trajectory,
            taken_by_reader,
            QOS_INSTRUCTIONS,
            callback_group=group,
        )
        commands = self.create_subscription(
            JointState,
            names.joint_commands,
            taken_by_reader,
            QOS_COMMANDS,
            callback_group=group,
        )
        leases = self.create_subscription(
            ClientLease, names.clients, taken_by_reader, QOS_LEASES, callback_group=group
        )
        self.leases = Leases(arm.config.server.client_lease_s)
        #: The last stop said obeyed however late (`_take_instruction`).
        self._late_stop = ""
        self._leases_lock = threading.Lock()
        self._ending = threading.Event()
        self._lease_keeper = threading.Thread(
            target=self._keep_leases, name="al5d-leases", daemon=True
        )
        self._lease_keeper.start()
        self.reader = Reader(
            self,
            [
                (instructions, self._told(names.instruction, self._on_instruction)),
                (trajectories, self._told(names.trajectory, self._on_trajectory)),
                (commands, self._told(names.joint_commands, self._on_joint_command)),
                (leases, self._on_lease),
            ],
            "al5d-inputs",
            group=group,
        )
        # A controller sends a refused set-point again at its rate (held after a stop, or
        # out of range): the result topic hears each reason once a second, not 25 times.
        self._command_refusals = Repeats(COMMAND_REFUSALS_EVERY_S)
        arm.outcome_listeners.append(self._publish_outcome)
        arm.state_listeners.append(self._publish_state)
        self._publish_state(arm.state)

    def _told(self, topic: str, handle: Handler) -> Handler:
        """`handle`, then `heard` told what it was handed (when set)."""
        heard = self.heard
        if heard is None:
            return handle

        def both(msg: Any, info: dict[str, int]) -> None:
            try:
                handle(msg, info)
            finally:
                heard(topic, msg, info)

        return both

    def detach(self) -> None:
        """Hear the owner no more (once, before the node is destroyed)."""
        self._ending.set()
        self.arm.outcome_listeners.remove(self._publish_outcome)
        self.arm.state_listeners.remove(self._publish_state)

    def refuse(self, ident: str, name: str, reason: str) -> None:
        """Refuse what never became an instruction (a malformed message): logged like any
        refusal, and published."""
        refused = Outcome(ident[:MAX_ID], name[:MAX_QUOTE], Result.REFUSED, reason)
        with self._refusals_lock:
            self._refusals.refused(refused.instruction, refused.id, reason, now())
        self.results.put(refused)

    # -- outputs -------------------------------------------------------------------

    def _publish_outcome(self, outcome: Outcome) -> None:
        self.results.put(outcome)

    def _publish_state(self, state: State) -> None:
        self.state_pub.publish(String(data=state.value))

    # -- inputs ---------------------------------------------------------------------

    def _on_lease(self, msg: ClientLease, info: dict[str, int]) -> None:
        came = came_ns(info)
        with self._leases_lock:
            self.leases.heard(str(msg.client), msg.sent_ns, msg.every_ms, now(), came)
        if msg.every_ms == 0:  # closed: what it commanded goes on, unless it left by an error
            why = f"it left by {str(msg.left_by)[:80]}" if msg.left_by else ""
            if why:
                log.warning("client %s: %s, and what it commanded is halted", msg.client, why)
            with contextlib.suppress(LaneClosed):  # the owner has ended
                self.arm.gone(str(msg.client), why)

    def _keep_leases(self) -> None:
        """Every tenth of the lease: a client not heard for the lease is lost, and what it
        commanded is halted. With the leases' lock held, as a request is judged and handed
        over (`_on_instruction`): a client's loss reaches the owner before a request it sent
        since, never after it."""
        while not self._ending.wait(min(0.1, self.leases.lease_s / 10)):
            try:
                with self._leases_lock:
                    self._halt(self.leases.lapsed(now()))
            except LaneClosed:
                return  # the owner has ended

    def _halt(self, lost: Iterable[tuple[str, float]]) -> None:
        """What the clients `lost` (each with how long it was silent, s) commanded is halted.
        Raises LaneClosed: the owner has ended."""
        lease_s = self.leases.lease_s
        for key, silent_s in lost:
            log.warning(
                "lost contact with client %s: no lease for %.1f s (its lease: %g s)",
                key,
                silent_s,
                lease_s,
            )
            self.arm.gone(key, f"no lease heard for {lease_s:g} s")

    def _on_instruction(self, msg: ArmInstruction, info: dict[str, int]) -> None:
        if self.trace is not None:
            self.trace.append((msg.id, "recv", time.monotonic_ns()))
        if msg.instruction == PING:
            self.results.put(Outcome(msg.id or new_id(), PING, Result.DONE))
            return
        # Judged and handed over with the leases' lock held: in one order with the clients'
        # losses (`_keep_leases`, `Leases.judge`).
        with self._leases_lock:
            self._take_instruction(msg, info)

    def _take_instruction(self, msg: ArmInstruction, info: dict[str, int]) -> None:
        sent = sent_ns(info)
        came = came_ns(info)
        client = str(msg.client)
        stale = None
        if sent is not None and client:
            verdict = self.leases.judge(client, sent, msg.wait_ms, now(), came)
            with contextlib.suppress(LaneClosed):  # the owner has ended: refused below
                self._halt(verdict.lost)
            stale = verdict.stale
        if msg.instruction.strip().lower() == "stop":  # as the stop watcher's
            sent = stop_time(sent, came, self.leases.offset(client) if client else None)
        elif sent is not None and client:
            sent = self.leases.on_server_clock(client, sent)
        instr = from_message(msg, self.presets, self.model, sent)
        if isinstance(instr, str):
            self.refuse(msg.id or new_id(), msg.instruction, instr)
            return
        if msg.wait_ms and client:
            # Its sender gives up on a move then (`arm.core`; a stop, a release, a shutdown
            # are obeyed whatever it waits), counted from when it sent it, which only a client
            # with a lease puts on this server's clock (`leases.on_server_clock`).
            instr = replace(instr, wait_ms=msg.wait_ms)
        if stale is not None:
            if instr.kind is not Kind.STOP:  # a stop is obeyed, however late
                self.refuse(instr.id, instr.name, stale)
                return
            # Said as what it is (the refusal's own words, "not run", would say the opposite),
            # once for a stop sent again until answered (its copies `<stop>~<n>`: one stop).
            stop = instr.id.partition(COPY_MARK)[0]
            if stop != self._late_stop:
                self._late_stop = stop
                log.warning(
                    "stop [%s]: sent while its client %s was out of contact: obeyed all the "
                    "same, as a stop always is",
                    stop,
                    client,
                )
        # A stop the stop watcher has obeyed already (the same message, or a copy of the
        # same stop: `stop_key`) is obeyed once.
        key = stop_key(msg, info) if instr.kind is Kind.STOP else None
        self._submitted(self.arm.submit(instr, key=key, client=client), instr.id, instr.name)

    def _on_trajectory(self, msg: JointTrajectory, info: dict[str, int]) -> None:
        """A trajectory is one instruction: every point checked, then all run or none."""
        config = self.arm.config
        prefix = config.server.joint_name_prefix
        instr = trajectory_from_message(msg, config.model, sent_ns(info), prefix)
        if isinstance(instr, str):
            self.refuse(trajectory_id(msg), "trajectory", instr)
            return
        self._submitted(self.arm.submit(instr), instr.id, instr.name)

    def _on_joint_command(self, msg: JointState, info: dict[str, int]) -> None:
        """A set-point of ros2_control's topic-based hardware: judged whole like any move, the
        latest wins. Only refusals are published: a stream of a hundred a second has a
        hundred outcomes a second, which would drown everyone else's on the result topic."""
        config = self.arm.config
        prefix = config.server.joint_name_prefix
        instr = joint_command_from_message(msg, config.model, sent_ns(info), prefix)
        if isinstance(instr, str):
            said = self._said(instr)
            if said is not None:
                # Named as the move it would have been, as the owner's refusals of one are.
                self.refuse(trajectory_id(msg), Kind.MOVE.value, said)
            return
        future = self.arm.submit(instr, listeners=False, stream=JOINT_COMMANDS)
        future.add_done_callback(self._publish_refusal)

    def _submitted(self, future: Future[Outcome], ident: str, name: str) -> None:
        """A request the owner could not take (what the lane refuses) is refused here."""

        def check(done: Future[Outcome]) -> None:
            error = done.exception()
            if isinstance(error, LaneError):
                self.refuse(ident, name, str(error))

        future.add_done_callback(check)

    def _publish_refusal(self, future: Future[Outcome]) -> None:
        if future.exception() is not None:
            return  # the lane closed: the owner has ended
        outcome = future.result()
        if outcome.result is Result.REFUSED:
            said = self._said(outcome.reason)
            if said is not None:
                self.results.put(replace(outcome, reason=said))

    def _said(self, reason: str) -> str | None:
        """A set-point's refusal as published: each reason once a second at most, with how
        many like it were not published since (None: not now)."""
        more = self._command_refusals.news(reason, time.monotonic())
        if not more:
            return None if more is None else reason
        every = self._command_refusals.every_s
        return f"{reason} ({more} more like it in the last {every:g} s not published)"


class RobotNode(Node):
    """Node `al5d_robot`: the arm as a robot (`/robot_description`, `/joint_states`, `/tf`, the
    tool pose), as robot_state_publisher would be beside a driver. It publishes from timers
    on rclpy's events executor, whose idle tick costs a quarter of the Python executor's
    (the idle server's CPU is mostly these ticks)."""

    def __init__(self, arm: Remote, context: Context, names: Names) -> None:
        super().__init__(
            ROBOT_NODE, namespace=names.node_namespace, context=context, cli_args=pinned(ROBOT_NODE)
        )
        self.arm = arm
        self.robot = RobotPublisher(self, arm.config, names)
        # Two timers, one running at a time: the moving rate's while the arm moves (a written
        # move starts it, a second at rest ends it), the idle rate's otherwise.
        settings = arm.settings
        self._rate_lock = threading.Lock()
        self._moving = False
        self._quiet = 0
        self._quiet_ticks = max(1, round(settings.joint_state_rate_hz))
        self.moving_timer = self.create_timer(1.0 / settings.joint_state_rate_hz, self._tick)
        self.moving_timer.cancel()
        self.idle_timer = self.create_timer(
            1.0 / settings.idle_joint_state_rate_hz, self._idle_tick
        )
        arm.motion_listeners.append(self._on_motion)
        #: A sign of this bridge's unanswered by the owner this long: no joint states
        #: (`_owner_silent`), whatever the lease (an outside try: with a 60 s lease a
        #: frozen owner's joint states went on for 60 s, and its clients heard nothing).
        #: The lane's own measure of a silence (a turning owner answers a sign sooner),
        #: not the 1 s its clients say a silence after: theirs counts from here, and they
        #: first said the owner's silence 2.0 to 2.3 s after it began.
        self._owner_silence_s = SILENCE_KEPT_S
        self._silence_said = False

    def set_rates(self, settings: ServerSettings) -> None:
        """The joint-state rates changed (a parameter, at run time): the timer running now
        starts its new period at once."""
        with self._rate_lock:
            self._quiet_ticks = max(1, round(settings.joint_state_rate_hz))
            self.moving_timer.timer_period_ns = round(1e9 / settings.joint_state_rate_hz)
            self.idle_timer.timer_period_ns = round(1e9 / settings.idle_joint_state_rate_hz)
            (self.moving_timer if self._moving else self.idle_timer).reset()

    def detach(self) -> None:
        """Hear the owner no more (once, before the node is destroyed)."""
        self.arm.motion_listeners.remove(self._on_motion)

    def _on_motion(self, _sent: Sent) -> None:
        self._speed_up()

    def _speed_up(self) -> None:
        with self._rate_lock:
            self._quiet = 0
            if not self._moving:
                self._moving = True
                self.idle_timer.cancel()
                self.moving_timer.reset()

    def _owner_silent(self) -> bool:
        """Whether the owner has said nothing for `_owner_silence_s`, its lane open (a frozen
        or stalled process; it answers this bridge's lease signs four times a second).
        Then no joint states go out: they would say where the last move told has the arm
        by now, which nobody knows, and the ROS clients, hearing none, take the server
        for lost as over a lost link and say so (`al5d.ros.leasing`; an outside try: with
        the owner frozen a move over ROS 2 waited 11 s in silence, and a web page showed
        a healthy arm). Said once each way."""
        quiet = self.arm.quiet()
        silent = quiet is not None and quiet > self._owner_silence_s
        if silent != self._silence_said:
            self._silence_said = silent
            if silent:
                log.warning(
                    "the owner has said nothing for %.1f s (busy or stalled): no joint states "
                    "until it does (the ROS clients take the server for lost)",
                    quiet,
                )
            else:
                log.info("the owner is heard again: joint states go out again")
        return silent

    def _tick(self) -> None:
        """/joint_states and /tf (radians, REP 103) at the moving rate, until a second at rest."""
        if self._owner_silent():
            return
        changed = self.robot.publish(self.arm.positions())
        with self._rate_lock:
            self._quiet = 0 if changed else self._quiet + 1
            if self._quiet >= self._quiet_ticks:
                self._moving = False
                self.moving_timer.cancel()
                self.idle_timer.reset()

    def _idle_tick(self) -> None:
        """The same at the idle rate."""
        # A change that no written move announced (a stop's or a reconnection's read-back)
        # brings the moving rate back too.
        if not self._owner_silent() and self.robot.publish(self.arm.positions()):
            self._speed_up()


class ActionsNode(Node):
    """Node `al5d_actions`: the move action, FollowJointTrajectory and GripperCommand, with
    their feedback at the joint-state rate, under the server's namespace."""

    def __init__(self, arm: Remote, context: Context, names: Names) -> None:
        super().__init__(
            ACTIONS_NODE,
            namespace=names.node_namespace,
            context=context,
            cli_args=pinned(ACTIONS_NODE),
        )
        self.arm = arm
        self.move_action = MoveAction(self, arm, names.move)
        self.trajectory_action = FollowTrajectoryAction(self, arm, names.follow_joint_trajectory)
        self.gripper_action = GripperAction(self, arm, names.gripper_command)
        self.actions: tuple[GoalRunner, ...] = (
            self.move_action,
            self.trajectory_action,
            self.gripper_action,
        )
        # The timer runs only while a goal does: rclpy's Python executor rebuilds its wait set
        # at every tick, which an idle server should not pay at the joint-state rate.
        self.timer = self.create_timer(1.0 / arm.settings.joint_state_rate_hz, self._feedback)
        self.timer.cancel()
        for action in self.actions:
            action.started = self.timer.reset

    def set_rate(self, settings: ServerSettings) -> None:
        """The feedback's rate is the joint states' (a parameter changed it at run time)."""
        self.timer.timer_period_ns = round(1e9 / settings.joint_state_rate_hz)

    def _feedback(self) -> None:
        for action in self.actions:
            action.orphans()
        if not any(action.running for action in self.actions):
            self.timer.cancel()
            return
        # One instant for where the arm is and where a trajectory wants it: a thread switch
        # between two readings of the clock would show the arm behind its path.
        t = now()
        degrees = self.arm.positions(t)
        self.move_action.feedback(degrees)
        self.trajectory_action.feedback(degrees, t)
        self.gripper_action.feedback()
