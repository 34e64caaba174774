"""A ROS 2 peer of the server for tests and benchmarks: publishes, calls, listens."""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

from al5d_interfaces.action import Move
from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.action.client import ActionClient
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import PING, Names
from al5d.ros.qos import QOS_INSTRUCTIONS, QOS_SERVICES, QOS_STREAM
from al5d.ros.workarounds import Reader, ReaderOnly, taken_by_reader


def wait_until(
    predicate: Any, timeout: float = 10.0, what: str = "condition", seen: Any = None
) -> None:
    """Wait for `predicate()`; else fail saying `what`, and what `seen()` (if given) finds
    then, so that a failure that comes once in many runs says why."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not met in {timeout} s{f': {seen()}' if seen else ''}")
        time.sleep(0.01)


#: How long a safety service's answer is waited for: a new participant's first answers may
#: be dropped (`Peer.trigger`): a CI run with four workers on two cores had a fixture's
#: first stop, or the release after it, unanswered (waited 19 s and 10 s then).
TRIGGER_S = 30.0


def answered(future: Any, timeout: float) -> bool:
    """Whether rclpy's `future` is done within `timeout` seconds."""
    done = threading.Event()
    future.add_done_callback(lambda f: done.set())
    return done.wait(timeout)


def wait_future(future: Any, timeout: float = 10.0) -> Any:
    assert answered(future, timeout), "no answer in time"
    return future.result()


def first_goal_answer(client: ActionClient, probe: Any, timeout: float = 30.0) -> None:
    """Until the action server has answered `client` once, a `probe` goal it rejects at
    once sent again every 2 s: rmw_fastrtps drops an answer whose client it has not matched
    100 ms after the request (ros2/rmw_fastrtps#390, as `Peer.first_answer` says for the
    services), and a first goal whose answer was dropped so is never answered (a CI run:
    a module's first FollowJointTrajectory goal unanswered for 10 s, four workers on two
    idle cores)."""
    deadline = time.monotonic() + timeout
    while True:
        future = client.send_goal_async(probe)
        if answered(future, 2.0):
            assert not future.result().accepted, "the probe goal was accepted"
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"the action server answered no goal in {timeout} s")


class LockedActionClient(ActionClient):
    """rclpy's ActionClient, safe to call from a thread other than its executor's.

    rclpy 7.1 sends a goal, result or cancel request and only then records its
    pending future. A response that the executor thread takes in between is
    dropped ("Ignoring unexpected ... response") and the future never completes
    (ros2/rclpy#1123): a test hung on it once in CI. One lock around each send
    and around the executor's handling of responses closes that window.
    """

    def __init__(self, node: Node, action_type: Any, name: str, deep: bool = True) -> None:
        # Deep service queues, as the server's: a burst of 300 answers must not overwrite
        # each other in this client's readers (rclpy's default keeps the last 10).
        queues = (
            {
                "goal_service_qos_profile": QOS_SERVICES,
                "result_service_qos_profile": QOS_SERVICES,
                "cancel_service_qos_profile": QOS_SERVICES,
            }
            if deep
            else {}
        )
        super().__init__(node, action_type, name, **queues)
        self._send_lock = threading.RLock()

    def send_goal_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._send_lock:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, goal_handle: Any) -> Any:
        with self._send_lock:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle: Any) -> Any:
        with self._send_lock:
            return super()._get_result_async(goal_handle)

    async def execute(self, taken_data: Any) -> None:
        # The base coroutine never suspends for our callbacks (plain functions),
        # so the lock is not held across a switch of tasks.
        with self._send_lock:
            await super().execute(taken_data)


class Peer:
    """A ROS 2 node in the test process: publishes, calls, and listens like any client, to
    the server in `namespace` (none by default).

    It spins rclpy's Python executor. With the events executor, a test process died of a
    segmentation fault now and then (once in a CI run, once in a load suite): three peers
    sending goals from their threads, then closed, crashed within ten rounds, twice in
    two tries, in the executor's thread; with this one, none in 40 rounds. Entities are
    destroyed by `destroy` and `close`, which stop the spinning first. (The events
    executor was also now and then told of one message too few, which a catch-up timer
    here made up for; this one is told of each.)
    """

    def __init__(
        self, results: bool = True, name: str = "al5d_test_peer", namespace: str = ""
    ) -> None:
        self.names = names = Names.of(namespace)
        self.context = start_context()
        self.node = Node(name, context=self.context)
        self.pub = self.node.create_publisher(ArmInstruction, names.instruction, QOS_INSTRUCTIONS)
        self.results: dict[str, InstructionResult] = {}
        self.joint_states: list[JointState] = []
        self._result_sub: Any = None
        if results:  # a benchmark may not want a thousand results arriving as it measures
            self.listen_results()
        self.node.create_subscription(JointState, names.joint_states, self.joint_states.append, 10)
        self.services = {
            n.rsplit("/", 1)[-1]: self.node.create_client(Trigger, n, qos_profile=QOS_SERVICES)
            for n in names.services
        }
        self.move = LockedActionClient(self.node, Move, names.move)
        #: Stop requests sent by `trigger` (a stop unanswered for a second is asked again).
        self.stops_asked = 0
        self._readers: list[Reader] = []
        self.spinner = Spinner(self.node, self.context, kind="single")

    def listen_results(self, on: bool = True) -> None:
        """Take /al5d/result, or stop (a benchmark's burst of results loads this process)."""
        if on and self._result_sub is None:
            self._result_sub = self.node.create_subscription(
                InstructionResult, self.names.result, self._on_result, QOS_STREAM
            )
        elif not on and self._result_sub is not None:
            sub, self._result_sub = self._result_sub, None
            self.destroy(sub)

    def read(self, msg_type: Any, topic: str, callback: Any, qos: Any) -> None:
        """Every message on `topic` to `callback`, taken by a thread of its own as the server
        takes its inputs (`al5d.ros.workarounds.Reader`), not by the executor: a flood's
        10,000 results a second outrun the Python executor (a load test's counter lost 8,803
        of 30,000, the server's results history full)."""
        group = ReaderOnly()
        sub = self.node.create_subscription(
            msg_type, topic, taken_by_reader, qos, callback_group=group
        )
        name = f"{self.node.get_name()}-read-{len(self._readers)}"
        handler = lambda msg, _info: callback(msg)  # noqa: E731
        self._readers.append(Reader(self.node, [(sub, handler)], name, group=group))

    def _on_result(self, msg: InstructionResult) -> None:
        self.results[msg.id] = msg

    def trajectory_writer(self) -> Any:
        """A writer of the server's trajectory topic that the server reads (`until_answered`,
        with empty trajectories, which it refuses). Destroy it with `destroy`."""
        pub = self.node.create_publisher(JointTrajectory, self.names.trajectory, QOS_INSTRUCTIONS)

        def empty(ident: str) -> JointTrajectory:
            probe = JointTrajectory()
            probe.header.frame_id = ident
            return probe

        self.until_answered(pub, empty)
        return pub

    def until_answered(self, pub: Any, probe: Callable[[str], Any], timeout: float = 30.0) -> None:
        """Until the server has answered a message of `pub`'s: `probe(ident)`, a message it
        refuses under that id, sent every 0.2 s once `pub` has matched a reader. The
        writer's count of readers is its own side of the match: a message sent before the
        reader has matched the writer is lost (the topics are volatile: a reader starts at
        the writer's sample of the moment)."""
        prefix = f"probe-{uuid.uuid4().hex[:8]}-"
        numbers = itertools.count()
        deadline = time.monotonic() + timeout
        while not any(i.startswith(prefix) for i in self.results_now()):
            if time.monotonic() > deadline:
                raise AssertionError(f"the server answered no probe in {timeout:g} s")
            if pub.get_subscription_count() > 0:
                pub.publish(probe(f"{prefix}{next(numbers)}"))
            time.sleep(0.2)

    def results_now(self) -> dict[str, InstructionResult]:
        """A copy of the results so far, safe to iterate while the spin thread adds more
        (dict() copies in one step under the GIL; a Python loop over the dict does not)."""
        return dict(self.results)

    def wait_for_server(self) -> None:
        wait_until(
            lambda: (
                self.pub.get_subscription_count() > 0
                and self.node.count_publishers(self.names.result) > 0
            ),
            20,
            "the server's topics",
        )
        # The count may be the stop watcher's reader alone (a participant of its own, often
        # found first); a move sent before the node's reader is matched never reaches it (the
        # topic is volatile): a CI run with four workers saw a test's first move on the topic
        # go unanswered. An answered ping is the node's reader matched, and its results (a
        # peer that takes no results cannot hear one: the counts must do for its floods).
        if self._result_sub is not None:
            self.wait_for_topics("ready-ping-")
        # The safety services are a participant of their own, discovered apart (seen: more
        # than 10 s with four workers beside two busy loops).
        for name, client in self.services.items():
            assert client.wait_for_service(timeout_sec=30), f"no {name} service in 30 s"
        assert self.move.wait_for_server(timeout_sec=30), "no move action in 30 s"
        self.first_answer()

    def wait_for_topics(self, prefix: str, timeout: float = 20.0) -> None:
        """Until a ping sent on the topic has come back answered: both ways matched with the
        server's node that runs now. After a server was killed, the counts may still be the
        dead one's (DDS forgets a killed participant only when its lease ends), and a move
        sent then reaches nobody. The node answers a ping itself: nothing reaches the owner."""
        deadline = time.monotonic() + timeout
        n = 0
        while not any(ident.startswith(prefix) for ident in self.results_now()):
            if time.monotonic() > deadline:
                raise AssertionError(f"no probe {prefix}* answered in {timeout} s")
            self.send(f"{prefix}{n}", PING)
            n += 1
            time.sleep(0.2)

    def first_stop_answer(self) -> None:
        """A stop and a release, so that the server's stop process (a DDS participant of its
        own) has answered this peer once: its first answer may be dropped as `first_answer`
        says, and the stop is asked again a second later (`trigger`). Only where the arm may
        be stopped and released."""
        assert self.trigger("stop").success
        assert self.trigger("release").success

    def first_answer(self, timeout: float = 20.0) -> None:
        """Until the server has answered this peer once. rmw_fastrtps drops an answer when,
        100 ms after the request, the server has not yet matched the client's reader of
        answers (ros2/rmw_fastrtps#390, #467): on a loaded machine the first call to a new
        server can go unanswered. A release changes nothing on an arm that is not stopped."""
        deadline = time.monotonic() + timeout
        while True:
            if answered(self.services["release"].call_async(Trigger.Request()), 2.0):
                return
            if time.monotonic() > deadline:
                raise AssertionError(f"the server answered no release in {timeout} s")

    def send(self, ident: str, instruction: str, time_ms: int = 0, **joints: float) -> None:
        msg = ArmInstruction(
            instruction=instruction,
            joints=list(joints),
            degrees=[float(v) for v in joints.values()],
            time_ms=time_ms,
            id=ident,
        )
        self.pub.publish(msg)

    def result(self, ident: str, timeout: float = 15.0) -> InstructionResult:
        wait_until(lambda: ident in self.results, timeout, f"result {ident}")
        return self.results[ident]

    def trigger(self, name: str) -> Trigger.Response:
        """A safety service's answer, as any ROS client (`ros2 service call`) has it. A stop
        unanswered for a second is asked again: the stop process's participant may drop
        its first answer to this peer (ros2/rmw_fastrtps#390). (The packaged client sends
        its stop on the topic instead, copies of one stop: `al5d.ros.rosstop`.)"""
        client = self.services[name]
        if name != "stop":
            return wait_future(client.call_async(Trigger.Request()), TRIGGER_S)
        # Each stop asked stays awaited: an earlier one's late answer does as well as the last's.
        asked: list[Any] = []
        deadline = time.monotonic() + TRIGGER_S
        while True:
            self.stops_asked += 1
            asked.append(client.call_async(Trigger.Request()))
            answered(asked[-1], 1.0)
            done = [f for f in asked if f.done()]
            if done:
                return done[0].result()
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"no stop of {len(asked)} answered in {TRIGGER_S:g} s (the service "
                    f"{'is' if client.service_is_ready() else 'is not'} listed as ready)"
                )
            print("rospeer: a stop unanswered for 1 s: asked again", flush=True)

    def goal(
        self,
        preset: str = "",
        time_ms: int = 0,
        feedback: list[Any] | None = None,
        accepted: bool = True,
        **joints: float,
    ) -> Any:
        """Send a Move goal; its handle, once the server has accepted it (or, with
        `accepted=False`, rejected it)."""
        goal = Move.Goal(
            preset=preset,
            joints=list(joints),
            degrees=[float(v) for v in joints.values()],
            time_ms=time_ms,
        )
        return self.send_goal(goal, feedback, accepted)

    def send_goal(self, goal: Any, feedback: list[Any] | None = None, accepted: bool = True) -> Any:
        handle = wait_future(
            self.move.send_goal_async(
                goal, feedback_callback=(feedback.append if feedback is not None else None)
            )
        )
        assert handle.accepted is accepted
        return handle

    def destroy(self, *entities: Any) -> None:
        """Destroy subscriptions, publishers, clients or action clients of this peer's node
        while no callback runs (`Spinner.paused` says why)."""
        with self.spinner.paused():
            for entity in entities:
                if isinstance(entity, ActionClient):
                    entity.destroy()
                else:
                    kind = type(entity).__name__.lower()  # subscription, publisher, client
                    getattr(self.node, f"destroy_{kind}")(entity)

    def close(self) -> None:
        for reader in self._readers:
            reader.close()
        self.spinner.close(self.move)
