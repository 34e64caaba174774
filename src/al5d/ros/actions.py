"""The move action (`/al5d/move`): goals judged whole before they are accepted.

Like ros2_controllers' trajectory controller, the goal callback validates the
whole goal and rejects a bad one before accepting it; the reason is also
published on `/al5d/result`, with the goal's UUID (hex) as the id, so that a
client can match it. An accepted goal's instruction carries the same id.

Every goal of every action, as it comes, is also published on `~/goals/<action>`
(its contents under its UUID in hex), so that a recording holds what each goal asked:
a goal is a service request, which no subscriber sees.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import Any, TypeVar

from al5d_interfaces.action import Move
from al5d_interfaces.msg import ArmInstruction
from rclpy.action.server import CancelResponse, GoalResponse, ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future as RosFuture

from al5d.arm.instruction import NOT_RUN, Instruction, Kind, Outcome, Result
from al5d.arm.states import refusal
from al5d.clock import wall_ns
from al5d.model import ArmModel
from al5d.owner.client import Judged, LaneClosed, Remote
from al5d.ros.convert import move_from_fields, tool_from_fields
from al5d.ros.names import RECORDER_NODE, Names
from al5d.ros.qos import QOS_SERVICES, QOS_STREAM
from al5d.ros.workarounds import IdentifiedActionServer, preempted

log = logging.getLogger("al5d")

#: The reason of a goal cancelled by its client before it was handed to the owner.
CANCELLED_BEFORE_RUN = f"cancelled by the client{NOT_RUN}"
#: The reason of a goal halted because no client of its action is left (`GoalRunner.orphans`).
NO_CLIENT_LEFT = "lost contact with every client of the action: none is left in the ROS graph"
#: How long a finished goal's result is kept for its client to fetch (rclpy keeps them
#: 900 s by default). Its status leaves the status messages sooner:
#: `workarounds.IdentifiedActionServer` says why.
RESULT_KEPT_S = 10.0


def action_server(
    node: Node,
    action_type: Any,
    name: str,
    execute: Callable[[ServerGoalHandle], Any],
    goal: Callable[[Any], GoalResponse],
    cancel: Callable[[ServerGoalHandle], CancelResponse],
) -> IdentifiedActionServer:
    """An action server with deep service queues and a short status history."""
    return IdentifiedActionServer(
        node,
        action_type,
        name,
        execute_callback=execute,
        goal_callback=goal,
        cancel_callback=cancel,
        goal_service_qos_profile=QOS_SERVICES,
        result_service_qos_profile=QOS_SERVICES,
        cancel_service_qos_profile=QOS_SERVICES,
        results_kept_s=RESULT_KEPT_S,
    )


T = TypeVar("T")


async def outcome_of(node: Node, future: Future[T]) -> T:
    """Await a driver future (or a thread's) inside the node's executor without holding its
    thread."""
    executor = node.executor
    done: RosFuture = RosFuture(executor=executor)

    def hand_over(f: Future[T]) -> None:
        # What the thread raised is raised in the awaiting task (rclpy then ends the goal),
        # not in this callback, where it would leave the task waiting for good.
        error = f.exception()
        if error is not None:
            done.set_exception(error)
        else:
            done.set_result(f.result())
        if executor is not None:
            executor.wake()  # the awaiting task runs at the executor's next turn

    future.add_done_callback(hand_over)
    outcome: T = await done
    return outcome


def inactive(arm: Remote) -> str:
    """Why the arm takes no moves now (stopped, faulted, shutting down), or "". Like an
    inactive ros2_controllers controller, the goal is then rejected, not aborted later."""
    return refusal(arm.state, "see /al5d/state")


def goal_instruction(goal: Any, ident: str, model: ArmModel, sent: int) -> Instruction | str:
    """The instruction of a Move goal, or why it is not one (a preset and joints: ambiguous).

    Joints named x, y and z make a Cartesian goal (`move_to`, in ROS units: see
    `al5d.ros.convert.TOOL_FIELDS`). `sent`: when the goal was accepted.
    """
    instr = _goal_instruction(goal, ident, model)
    return instr if isinstance(instr, str) else replace(instr, sent_ns=sent)


def _goal_instruction(goal: Any, ident: str, model: ArmModel) -> Instruction | str:
    time_ms = goal.time_ms or None
    if goal.preset and (len(goal.joints) or len(goal.degrees)):
        return (
            f"the goal names a preset ({goal.preset[:40]!r}) and joints: ambiguous; "
            "name one or the other"
        )
    if goal.preset:
        return Instruction(Kind.PRESET, preset=goal.preset, time_ms=time_ms, id=ident)
    if {"x", "y", "z"} & set(goal.joints):
        tool = tool_from_fields(goal.joints, goal.degrees, model)
        if isinstance(tool, str):
            return tool
        return Instruction(Kind.MOVE_TO, tool=tool, time_ms=time_ms, id=ident)
    return move_from_fields(goal.joints, goal.degrees, time_ms, ident)


class GoalRunner:
    """What every action of ours shares: its running goals by instruction id (the goal's
    UUID in hex), a cancel that halts the arm where it is (without the lock), or, of
    a goal accepted that has not yet run, ends it before it runs; and, for an action whose
    newest goal wins (`preempts`), the halt of the goals before it."""

    #: The action's name (its goals' topic: `~/goals/<name>`).
    name = "goal"
    #: Whether a new goal preempts the goals before it, running or waiting, as
    #: ros2_controllers' trajectory and gripper controllers do; else it waits behind them.
    preempts = False
    #: The reason a preempted goal's halt, or its end, gives: then it ends CANCELED.
    preempted_reason = "preempted by goal"
    server: IdentifiedActionServer
    #: The message a goal's contents are published as (`goal_message`), on `~/goals/<name>`.
    goal_type: Any = ArmInstruction

    def __init__(self, node: Node, arm: Remote) -> None:
        self.node = node
        topic = Names.of(node.get_namespace()).goals(self.name)
        self.goals = node.create_publisher(self.goal_type, topic, QOS_STREAM)
        self.arm = arm
        self.running: dict[str, Any] = {}
        #: Each accepted goal's judgement, until its execution takes it: a goal is converted
        #: and judged once, in its goal callback. Its instruction counts as sent when it was
        #: accepted, so that a stop between the accept and the execution cancels it.
        self.judged: dict[str, Any] = {}
        #: Called when a goal starts to run (the node's feedback timer runs only then).
        self.started: Callable[[], object] | None = None
        #: Publishes a rejected goal's reason on the result topic (the node `al5d`'s).
        self.refuse: Callable[[str, str, str], None] | None = None
        #: Publishes on the result topic the outcome of a goal that ended before the owner
        #: had it (cancelled, or preempted, while it waited): every goal has one there.
        self.tell: Callable[[Outcome], None] | None = None
        #: Of each goal a newer one preempted while it ran: the first such goal (its halt
        #: names that one), until the goal's end takes it (`preempter`).
        self.preempters: dict[str, str] = {}
        #: Goals waiting for the goals they preempt to be halted, each with the goal that
        #: preempted it meanwhile ("": none has).
        self.starting: dict[str, str] = {}
        #: The goals (running or waiting) that a client of the action was in the ROS graph
        #: for, while they were (`orphans`).
        self.seen: set[str] = set()
        #: Goals accepted, not yet handed to the owner, whose every client has left.
        self.left: set[str] = set()
        # A preempted goal's halt waits for the wire (tens of ms at 9600 baud): this thread
        # writes it, and the executor's answers the goals that come meanwhile (a preempting
        # client at 100 goals a second outran an executor that wrote each halt itself).
        self._halts = ThreadPoolExecutor(max_workers=1, thread_name_prefix="al5d-preempt")

    def judge(self, goal: Any, ident: str, sent: int) -> Any:
        """What the goal asks for, ready to run, or the reason to reject it (a str)."""
        raise NotImplementedError

    def goal_message(self, goal: Any, ident: str) -> Any:
        """The goal's contents as `goal_type`, under its id."""
        raise NotImplementedError

    def word(self, goal: Any) -> str:
        """The instruction a goal is (`trajectory`, `move`, a preset's name): what a
        rejected goal's refusal names on the result topic, as an accepted goal's outcome
        does (a client that reads the results by instruction sees both)."""
        return Kind.MOVE.value

    def _goal(self, goal: Any) -> GoalResponse:
        ident = self.server.goal_id_now
        self.goals.publish(self.goal_message(goal, ident))
        judged = self.judge(goal, ident, wall_ns())
        if isinstance(judged, str):
            self.node_al5d_refuse(ident, self.word(goal), judged)
            return GoalResponse.REJECT
        self.judged[ident] = judged
        return GoalResponse.ACCEPT

    def _take_judged(self, handle: ServerGoalHandle) -> tuple[str, Any]:
        """The goal's id and the judgement its goal callback made (None if it made none)."""
        ident = bytes(handle.goal_id.uuid).hex()
        return ident, self.judged.pop(ident, None)

    def node_al5d_refuse(self, ident: str, word: str, reason: str) -> None:
        """A rejected goal's reason on the result topic too, under the goal's UUID, named as
        the instruction `word` it would have been."""
        if self.refuse is not None:
            self.refuse(ident, word, reason)

    async def _run(self, ident: str, entry: Any, ticket: Judged) -> Outcome:
        """Submit the goal's ticket and await its outcome, listed as running meanwhile."""
        self.running[ident] = entry
        if self.started is not None:
            self.started()
        try:
            return await outcome_of(self.node, self.arm.submit(ticket))
        except BaseException:
            self.preempters.pop(ident, None)  # its end, which takes it, never comes
            raise
        finally:
            self.running.pop(ident, None)

    def waiting(self, ident: str) -> bool:
        """Whether goal `ident` is accepted and has not yet been handed to the owner."""
        return ident in self.judged or ident in self.starting

    async def _preempt(self, ident: str, word: str) -> str:
        """The newest goal wins (`preempts`), as in the JTC: halt the goals running (in the
        halts' thread), and end those still waiting for theirs. The goal that preempted
        `ident` (the instruction `word`) meanwhile, or ""."""
        if not self.preempts:
            return ""
        ended = list(self.running)
        for other in ended:
            # The first goal to preempt it is the one its halt names (a goal that came
            # while the halt was on its way said another: the newest).
            self.preempters.setdefault(other, ident)
        for other in self.starting:
            self.starting[other] = ident
        if not ended:
            return ""
        self.starting[ident] = ""
        reason = f"{self.preempted_reason} {ident}"
        try:
            await outcome_of(
                self.node, self._halts.submit(lambda: [self.arm.cancel(o, reason) for o in ended])
            )
        except Exception as e:  # the owner gone, or silent: rclpy aborts the goal
            self.not_run(ident, word, f"not run: the halt before it failed: {e}")
            raise
        finally:
            by = self.starting.pop(ident, "")
        return by

    def orphans(self) -> None:
        """End the goals whose every client has left: no client of the action is in the ROS
        graph now (each reads the action's status topic; a recording's reader is not one),
        and one was while the goal was running or waiting. Their commander is gone (its
        process ended, or DDS ended its participant's lease: killed, cut off, or stalled
        longer than the lease). Running goals are halted where the arm is; goals accepted
        that wait to run end before they run (`ended_before_run`).

        rclpy does not say which client sent a goal (its request header has no writer), so
        a goal of a client that has gone runs on while another client of the action stays.
        A goal no client was seen for (one whose reader the graph did not list yet) runs
        on: the graph is not read as a client's absence before it has shown one."""
        waiting = set(self.judged) | set(self.starting)
        active = set(self.running) | waiting
        self.seen &= active
        self.left &= waiting
        if not active:
            return
        try:
            readers = self.node.get_subscriptions_info_by_topic(self.server.status_topic)
        except Exception:  # the node closing: a graph that cannot be read says nothing
            return
        if any(r.node_name != RECORDER_NODE for r in readers):  # a recording commands nothing
            self.seen |= active
            return
        doomed, self.seen = self.seen, set()
        if not doomed:
            return
        self.left |= doomed & waiting
        log.warning("%s goals %s: %s", self.name, ", ".join(sorted(doomed)), NO_CLIENT_LEFT)
        self._halts.submit(self._cancel_each, sorted(doomed - waiting), NO_CLIENT_LEFT)

    def _cancel_each(self, idents: list[str], reason: str) -> None:
        """Cancel each of the running goals `idents` (the halts' thread); a failure is
        logged, as nobody waits for this."""
        for ident in idents:
            try:
                self.arm.cancel(ident, reason)
            except Exception as e:
                log.error("%s goal %s: not cancelled: %s", self.name, ident, e)

    def preempter(self, ident: str, outcome: Outcome) -> str:
        """The goal that preempted goal `ident`, ended with `outcome`, if its halt was the
        preemption's ("": not preempted; a stop that came first aborts it)."""
        by = self.preempters.pop(ident, "")
        cut = outcome.result is Result.CANCELLED
        return by if cut and outcome.reason.startswith(self.preempted_reason) else ""

    def preempted_first(
        self, handle: ServerGoalHandle, ident: str, ticket: Judged, by: str, word: str
    ) -> None:
        """Goal `ident` (the instruction `word`), preempted by goal `by` before the owner
        had it, ends CANCELED: said on the result topic as the owner says one it drops
        while it waits (`NOT_RUN`), its ticket dropped."""
        self.not_run(ident, word, f"{self.preempted_reason} {by}{NOT_RUN}")
        self.drop(ticket)
        preempted(handle)

    def _cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        """A running goal is halted where it is; one still waiting to run is taken off
        before it runs (`ended_before_run`): a cancel the server accepts is always obeyed
        (an outside try: one that came while its goal waited for the goal it preempted
        was refused, and the goal then ran)."""
        ident = bytes(handle.goal_id.uuid).hex()
        if ident in self.running:
            return CancelResponse.ACCEPT if self.arm.cancel(ident) else CancelResponse.REJECT
        return CancelResponse.ACCEPT if self.waiting(ident) else CancelResponse.REJECT

    def not_run(self, ident: str, word: str, reason: str) -> None:
        """Goal `ident`, the instruction `word`, ended CANCELLED before the owner had it:
        its outcome on the result topic too."""
        if self.tell is not None:
            self.tell(Outcome(ident, word, Result.CANCELLED, reason))

    def ended_before_run(self, handle: ServerGoalHandle, ident: str, ticket: Judged) -> str:
        """Why the goal ended while it waited, or "": its cancel was accepted (it ends
        CANCELED), or every client of its action left (`orphans`: ABORTED). Said on the
        result topic; the goal is never handed to the owner (its ticket dropped)."""
        if ident in self.left:
            self.left.discard(ident)
            reason = f"{NO_CLIENT_LEFT}{NOT_RUN}"
            handle.abort()
        elif handle.is_cancel_requested:
            reason = CANCELLED_BEFORE_RUN
            handle.canceled()
        else:
            return ""
        self.not_run(ident, self.word(handle.request), reason)
        self.drop(ticket)
        return reason

    def drop(self, ticket: Judged) -> None:
        """The owner lets go of a ticket that will not run (a goal that ended first)."""
        with contextlib.suppress(LaneClosed):  # the owner has ended: it keeps nothing
            self.arm.drop(ticket)


class MoveAction(GoalRunner):
    """`/al5d/move` on a node: validate in the goal callback, run, report, cancel."""

    def __init__(self, node: Node, arm: Remote, name: str) -> None:
        super().__init__(node, arm)
        self.joint_names = list(arm.config.joints)
        self.server = action_server(node, Move, name, self._execute, self._goal, self._cancel)

    name = "move"

    def word(self, goal: Any) -> str:
        if goal.preset:
            return str(goal.preset)
        return Kind.MOVE_TO.value if {"x", "y", "z"} & set(goal.joints) else Kind.MOVE.value

    def goal_message(self, goal: Any, ident: str) -> ArmInstruction:
        """The goal as the instruction it is (`ArmInstruction`'s words and units)."""
        msg = ArmInstruction(instruction=self.word(goal), joints=list(goal.joints), id=ident)
        msg.degrees = list(goal.degrees)
        msg.time_ms = goal.time_ms
        return msg

    def judge(self, goal: Any, ident: str, sent: int) -> Judged | str:
        instr = goal_instruction(goal, ident, self.arm.config.model, sent)
        if isinstance(instr, str):
            return instr
        # Rejected at once, as the controllers' goals are (it was taken, then aborted).
        return inactive(self.arm) or self.arm.judge(instr)

    async def _execute(self, handle: ServerGoalHandle) -> Move.Result:
        ident, ticket = self._take_judged(handle)
        result = Move.Result()
        if ticket is None:  # rclpy executes only what the goal callback accepted
            result.outcome, result.reason = "refused", "the goal was never judged"
            handle.abort()
            return result
        if reason := self.ended_before_run(handle, ident, ticket):
            result.outcome, result.reason = Result.CANCELLED.value, reason
            return result
        outcome = await self._run(ident, handle, ticket)
        result.outcome = outcome.result.value
        result.reason = outcome.reason
        result.expected_ms = float(outcome.expected_ms)
        result.elapsed_ms = float(outcome.elapsed_ms)
        if outcome.ok:
            handle.succeed()
        elif handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
        return result

    def feedback(self, degrees: dict[str, float]) -> None:
        """Current degrees and progress to every running goal (the joint-state rate)."""
        for ident, handle in list(self.running.items()):
            progress = self.arm.progress(ident)
            if progress is not None and handle.is_active:
                fb = Move.Feedback()
                fb.joints = self.joint_names
                fb.degrees = [degrees[j] for j in self.joint_names]
                fb.progress = progress
                handle.publish_feedback(fb)
