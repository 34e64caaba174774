"""Where rclpy (7.1, Jazzy) does not give the server what it needs, and how it is had here.

Each workaround names what it works around and how to tell when it can go.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Coroutine, Iterator
from typing import Any

from rclpy.action.server import ActionServer, GoalEvent, ServerGoalHandle
from rclpy.callback_groups import CallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.task import Future

from al5d.priority import make_urgent

log = logging.getLogger("al5d")

#: What a publish that failed raises (a KEEP_ALL writer whose history is full of what its
#: readers have not acknowledged: "Failed to publish: cannot publish data"). rclpy 7.1
#: names it only in its private module; this name can go when `rclpy.exceptions` has it.
PublishFailed: type[Exception] = _rclpy.RCLError

#: A service callback that is also told when its request was sent (CLOCK_REALTIME ns).
StampedCallback = Callable[[Any, Any, int], Any]
_STAMPED = "al5d_stamped_callback"
#: How long (whole seconds: rclpy's type) an ended goal stays in its action's status
#: messages: long enough for a status reader to see it end.
STATUS_KEPT_S = 1


def stamped_service(
    node: Node, srv_type: Any, name: str, callback: StampedCallback, qos: QoSProfile
) -> Service:
    """A service whose callback gets the request's source timestamp as a third argument, when
    it is spun by a `StampedExecutor` (the order of a release and a stop from different
    channels is judged on when each was sent: `al5d.arm.core`)."""
    srv = node.create_service(srv_type, name, lambda req, resp: resp, qos_profile=qos)
    setattr(srv, _STAMPED, callback)
    return srv


class StampedExecutor(SingleThreadedExecutor):
    """rclpy's SingleThreadedExecutor, which tells a `stamped_service` when its request was
    sent.

    rclpy 7.1 takes a request with its `rmw_service_info_t` (source and received
    timestamps) but hands the callback the request alone (`Executor._take_service`).
    This takes the request the same way and passes `source_timestamp` on. It can go
    when rclpy offers a service callback the request's info, as it does a subscription
    callback (`callback(msg, info)`); until then it depends on `_take_service`'s shape
    (checked by tests/test_ros_stop_watcher.py through the release service)."""

    def _take_service(self, srv: Service) -> Callable[[], Coroutine[Any, Any, None]] | None:
        callback: StampedCallback | None = getattr(srv, _STAMPED, None)
        if callback is None:
            return super()._take_service(srv)  # type: ignore[no-any-return]
        srv_type: Any = srv.srv_type
        try:
            with srv.handle:
                request, header = srv.handle.service_take_request(srv_type.Request)
        except InvalidHandle:
            return None

        async def _execute() -> None:
            if header is None:
                return
            response = callback(request, srv_type.Response(), header.source_timestamp)
            srv.send_response(response, header)

        return _execute


class ReaderOnly(CallbackGroup):
    """The callback group of what a `Reader` takes from (its subscriptions and its guard
    condition), whose node an executor spins all the same (the node `al5d`, for its
    parameter services): rclpy's executors wait only on entities whose group can execute
    (`Executor._wait_for_ready_callbacks`), so they never take the Reader's messages nor
    its wake-up. Checked by tests/test_ros_params.py (instructions taken while the
    parameter services answer)."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        return None


def taken_by_reader(msg: object) -> None:
    """The callback of a subscription a `Reader` takes from: an executor never calls it."""
    raise AssertionError("this input is taken by its reader, not an executor")


#: What a `Reader` hands each message to: the message (or its bytes) and its info.
Handler = Callable[[Any, dict[str, int]], None]


class Reader:
    """Takes the messages of a node's subscriptions, each with its info (source timestamp,
    sequence number), in a thread of its own: a wait set of those subscriptions and a
    guard condition to end it, as rclpy's own `wait_for_message` waits.

    Why not an executor. The order of a stop, a release and a move from different
    channels is judged on when each was sent (`al5d.arm.core`), which is in the message's
    info. rclpy 7.1's events executor cannot hand a callback the info ("SystemError:
    null argument to internal routine" for a two-argument callback), and its Python
    executor costs about 0.2 ms a message more (publish to callback on this machine, p50:
    events executor 0.54 to 0.57 ms, Python executor 0.73 to 0.74, this loop 0.53 to
    0.54) and took 571 messages a second one at a time. This loop wakes once for what
    waits and takes up to `batch` of each subscription's messages in one go. It uses
    rclpy's wait set as `rclpy.wait_for_message` does (`rclpy.impl`); it can go when an
    executor offers both the info and the speed.

    The node must not be spun by an executor, or its subscriptions must be in a
    `ReaderOnly` group (their callbacks are never called); its publishers need none. An
    `urgent` reader (the stop watcher's) runs at the stop path's priority
    (`al5d.priority`)."""

    def __init__(
        self,
        node: Node,
        inputs: list[tuple[Any, Handler]],
        name: str,
        batch: int = 200,
        urgent: bool = False,
        group: ReaderOnly | None = None,
    ) -> None:
        self._node = node
        self._urgent = urgent
        self._inputs = inputs
        self._batch = batch
        self._wake = node.create_guard_condition(lambda: None, callback_group=group or ReaderOnly())
        self._running = True
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self._urgent:
            make_urgent(self._thread.name)
        context = self._node.context
        wait_set = _rclpy.WaitSet(len(self._inputs), 1, 0, 0, 0, 0, context.handle)
        while self._running and context.ok():
            try:
                # Held while waited on, as rclpy's executors hold theirs: a node destroyed
                # meanwhile (its `close` gave up waiting for this thread) is destroyed
                # once the wait ends, not under it.
                with contextlib.ExitStack() as held:
                    wait_set.clear_entities()
                    for sub, _ in self._inputs:
                        held.enter_context(sub.handle)
                        wait_set.add_subscription(sub.handle)
                    held.enter_context(self._wake.handle)
                    wait_set.add_guard_condition(self._wake.handle)
                    wait_set.wait(-1)
                ready = wait_set.get_ready_entities("subscription")
                for sub, handle in self._inputs:
                    if sub.handle.pointer in ready:
                        self._take(sub, handle)
            except InvalidHandle:
                return  # the node is being destroyed
            except Exception:  # a reader of the arm's inputs must never end on a bad message
                if not (self._running and context.ok()):
                    return
                log.exception("%s: reading failed; it goes on", self._thread.name)

    def _take(self, sub: Any, handle: Handler) -> None:
        for _ in range(self._batch):
            with sub.handle:
                got = sub.handle.take_message(sub.msg_type, sub.raw)
            if got is None:
                return
            try:
                handle(got[0], got[1])
            except Exception:
                log.exception("%s: a message's handling failed; it goes on", self._thread.name)

    def close(self) -> None:
        """End the thread (before the node is destroyed)."""
        self._running = False
        self._wake.trigger()
        self._thread.join(5)


class _Allocator(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_void_p)
        for name in ("allocate", "deallocate", "reallocate", "zero", "state")
    ]


class _Strings(ctypes.Structure):
    _fields_ = [
        ("size", ctypes.c_size_t),
        ("data", ctypes.POINTER(ctypes.c_char_p)),
        ("allocator", _Allocator),
    ]


class _FilterOptions(ctypes.Structure):
    """rcl_subscription_content_filter_options_t (rmw's options inside: an expression and its
    parameters)."""

    _fields_ = [("expression", ctypes.c_char_p), ("parameters", _Strings)]


@functools.cache
def _rcl() -> ctypes.CDLL:
    """librcl, as rclpy loaded it (its soname)."""
    rcl = ctypes.CDLL("librcl.so")
    rcl.rcl_get_zero_initialized_subscription_content_filter_options.restype = _FilterOptions
    options = ctypes.POINTER(_FilterOptions)
    rcl.rcl_subscription_content_filter_options_init.argtypes = [
        ctypes.c_void_p,
        ctypes.c_char_p,
        ctypes.c_size_t,
        ctypes.c_void_p,
        options,
    ]
    rcl.rcl_subscription_set_content_filter.argtypes = [ctypes.c_void_p, options]
    rcl.rcl_subscription_content_filter_options_fini.argtypes = [ctypes.c_void_p, options]
    rcl.rcl_subscription_is_cft_enabled.argtypes = [ctypes.c_void_p]
    rcl.rcl_subscription_is_cft_enabled.restype = ctypes.c_bool
    return rcl


def filter_content(sub: Subscription, expression: str) -> bool:
    """Have DDS hand `sub` only the messages `expression` (DDS's SQL filter, as rcl takes it)
    selects; False, said once, where it is refused (the subscription then gets every
    message, as before).

    Fast DDS applies it before anything reaches Python (its publishers filter for the
    readers they know, or the reader's participant does on receipt): a message it refuses
    never queues in the reader (the stop watcher's: a flood's moves queued ahead of a stop
    there, and took its process's interpreter). rclpy 7.1 has no content filter
    (ros2/rclpy#1504), so this calls rcl's (Humble on) through ctypes on the
    subscription's rcl handle; set before the subscription is first taken from, as
    rmw_fastrtps makes its reader again for the filter. It can go when the rclpy in use
    takes `content_filter_options` in `create_subscription` (ros2/rclpy#1506, in Rolling);
    until then it depends on rcl's C structures (checked by tests/test_ros_stop_watcher.py:
    what the filter lets through)."""
    try:
        rcl = _rcl()
        handle = ctypes.c_void_p(sub.handle.pointer)
        options = rcl.rcl_get_zero_initialized_subscription_content_filter_options()
        ret = rcl.rcl_subscription_content_filter_options_init(
            handle, expression.encode(), 0, None, ctypes.byref(options)
        )
        if ret == 0:
            ret = rcl.rcl_subscription_set_content_filter(handle, ctypes.byref(options))
            rcl.rcl_subscription_content_filter_options_fini(handle, ctypes.byref(options))
        if ret == 0 and rcl.rcl_subscription_is_cft_enabled(handle):
            return True
        why = f"rcl returned {ret}"
    except (OSError, AttributeError) as e:
        why = str(e)
    if not _unfiltered.is_set():
        _unfiltered.set()
        log.warning(
            "%s: DDS refused a content filter (%s); it reads every message on the topic",
            sub.topic_name,
            why,
        )
    return False


_unfiltered = threading.Event()  # said once per process


_RANGE = "ROS_AUTOMATIC_DISCOVERY_RANGE"


@contextlib.contextmanager
def discovery_on_our_transports(local: bool) -> Iterator[None]:
    """While a context starts (`rclpy.init`): with `local`, rmw_fastrtps is told the SUBNET
    discovery range, so that the transports of our Fast DDS profile, every socket on the
    loopback interface (`dds.dds_profile`), are the only ones.

    With the LOCALHOST range, rmw_fastrtps (Jazzy) adds a UDP transport of its own, whose
    sockets are bound to every interface (`ss -uanp`: 0.0.0.0 and the host's address,
    beside our 127.0.0.1 ones): discovery stays on this machine, but the participant is
    open to the network. On loopback-only transports the SUBNET range reaches this
    machine alone, and discovery with LOCALHOST and SUBNET peers on it works both ways
    (tests/test_ros_runtime.py). rcl reads the range once, at init, so the environment is
    changed for that call only. It can go when rmw_fastrtps keeps to the transports a
    profile gives it under the LOCALHOST range."""
    if not local:
        yield
        return
    before = os.environ.get(_RANGE)
    os.environ[_RANGE] = "SUBNET"
    try:
        yield
    finally:
        if before is None:
            del os.environ[_RANGE]
        else:
            os.environ[_RANGE] = before


class IdentifiedActionServer(ActionServer):
    """An ActionServer whose goal callback can learn the goal's UUID (`goal_id_now`), and
    whose status messages list only the goals of the last `STATUS_KEPT_S` while each
    result can still be fetched for `results_kept_s`.

    The UUID: rclpy 7.1 hands the goal callback the goal alone; this records the UUID just
    before (it calls the callback within `_execute_goal_request` before its first await,
    in the executor's one thread, so the two cannot be told apart). It can go when
    rclpy's goal callback is given the goal's id or handle; until then it depends on
    `_execute_goal_request`'s shape (checked by tests/test_ros_e2e.py: a refused goal's
    reason comes under its UUID).

    The results: rcl keeps a goal in every status message until its result expires, and
    rclpy visits every kept goal's future at each of the server's wake-ups, so each goal
    costs the server, and each client's status reader, in proportion to the goals kept
    (at 100 goals a second on an idle 2-core machine, with results kept 10 s, 2,133 of
    2,500 goals were answered; with 1 s, all). Here rcl lets a goal go `STATUS_KEPT_S` after
    it ended; its result future is kept aside and a late request for it is answered
    from there. It can go when rcl's status message and result lifetime part (no such
    option in rcl 9); it depends on `_execute_expire_goals` and
    `_execute_get_result_request`'s shape (checked by tests/test_ros_controllers.py: a
    result asked for after its goal left the status message).
    """

    goal_id_now = ""

    def __init__(
        self, node: Any, action_type: Any, name: str, *, results_kept_s: float, **kwargs: Any
    ) -> None:
        super().__init__(node, action_type, name, result_timeout=STATUS_KEPT_S, **kwargs)
        #: The action's status topic (rcl's name for it), which every client of the action
        #: reads: the ROS graph lists the action's clients there.
        self.status_topic = f"{name}/_action/status"
        self._results_kept_s = results_kept_s
        # goal UUID -> (when it left rcl, its result future); in that order.
        self._ended: OrderedDict[bytes, tuple[float, Future]] = OrderedDict()

    async def _execute_goal_request(self, request_header_and_message: Any) -> None:
        _, goal_request = request_header_and_message
        self.goal_id_now = bytes(goal_request.goal_id.uuid).hex()
        await super()._execute_goal_request(request_header_and_message)

    async def _execute_expire_goals(self, expired_goals: Any) -> None:
        now = time.monotonic()
        for goal in expired_goals:
            uuid = bytes(goal.goal_id.uuid)
            if (future := self._result_futures.get(uuid)) is not None:
                self._ended[uuid] = (now, future)
        await super()._execute_expire_goals(expired_goals)
        while self._ended and next(iter(self._ended.values()))[0] < now - self._results_kept_s:
            self._ended.popitem(last=False)

    async def _execute_get_result_request(self, request_header_and_message: Any) -> None:
        request_header, request = request_header_and_message
        uuid = bytes(request.goal_id.uuid)
        kept = self._ended.get(uuid)
        if kept is None or uuid in self._goal_handles:  # a client may reuse a UUID
            await super()._execute_get_result_request(request_header_and_message)
            return
        kept[1].add_done_callback(functools.partial(self._send_result_response, request_header))


def preempted(handle: ServerGoalHandle) -> None:
    """End a goal that a newer one preempted as CANCELED, as the joint_trajectory_controller
    does (MoveIt then reports it preempted, not failed).

    rclpy marks a goal CANCELED only from CANCELING, where a client's cancel request puts
    it; no public call does that for a preemption, so this takes the step rclpy's own
    cancel handling takes (`ActionServer._execute_cancel_request`). It can go when rclpy's
    goal handle can end a goal the server itself cancels (rclcpp's is asked for in
    ros2/rclcpp#1104, a preempt); checked by tests/test_ros_controllers.py (a preempted
    goal ends CANCELED)."""
    try:
        if not handle.is_cancel_requested:
            handle._update_state(GoalEvent.CANCEL_GOAL)
        handle.canceled()
    except Exception:  # another rclpy: the goal ends all the same, ABORTED
        log.warning("a preempted goal could not be marked CANCELED; it is ABORTED")
        handle.abort()
