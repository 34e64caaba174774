"""The threads that run rclpy: an executor spinning in a thread of its own (`Spinner`), and
a publisher's thread (`PublishThread`)."""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from collections.abc import Callable, Iterator
from typing import Any, Generic, Protocol, TypeVar

from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher

from al5d.priority import make_urgent
from al5d.ros.workarounds import StampedExecutor

log = logging.getLogger("al5d")


def make_executor(context: Context, kind: str | None = None) -> Executor:
    """rclpy's C++ EventsExecutor, or with `kind="single"` its Python SingleThreadedExecutor
    (which tells a stamped service when its request was sent: `workarounds.StampedExecutor`).

    The events executor takes each message without rebuilding a wait set of every
    entity in Python, which is what limits the single-threaded one (see the README's
    Performance section for the figures of both). But in rclpy 7.1 it runs a task that
    awaits a future again and again until the future is done (ros2/rclpy#1405, fixed
    later by #1469): a coroutine that waits for the arm would hold a core. The actions,
    whose execute callbacks are such coroutines, have the Python executor.
    """
    if kind == "single":
        return StampedExecutor(context=context)
    from rclpy.experimental.events_executor import EventsExecutor

    return EventsExecutor(context=context)


T = TypeVar("T")

#: How long stopping a spin thread waits for the callback it is in (a busy host's).
HALT_S = 30.0


class Destroyable(Protocol):
    """An action client or server: `Node.destroy_node` leaves them to their owner."""

    def destroy(self) -> None: ...


class PublishThread(Generic[T]):
    """Publishes from a thread of its own: whoever hands an item over (the executor taking
    instructions, the stop) never waits for DDS, and a burst of a thousand is one hand-over."""

    def __init__(self, publisher: Publisher, convert: Callable[[T], Any], name: str) -> None:
        self._publisher = publisher
        self._convert = convert
        self._items: queue.SimpleQueue[T | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, item: T) -> None:
        self._items.put(item)

    def _run(self) -> None:
        while (item := self._items.get()) is not None:
            self._publisher.publish(self._convert(item))

    def close(self, timeout: float = 5.0) -> None:
        """Publish what was handed over, then end."""
        self._items.put(None)
        self._thread.join(timeout)


class Spinner:
    """An executor spinning in its own thread, stopped in the order rclpy needs.

    With `owns_context`, closing it also ends the ROS context (a process with one node);
    `more` nodes share the executor and its thread. An `urgent` spinner (the safety
    services') runs at the stop path's priority (`al5d.priority`).
    """

    def __init__(
        self,
        node: Node,
        context: Context,
        owns_context: bool = True,
        more: list[Node] | None = None,
        kind: str | None = None,
        urgent: bool = False,
    ) -> None:
        self.node = node
        self.urgent = urgent
        self.context = context
        self.owns_context = owns_context
        self.more = list(more or [])
        self.executor = make_executor(context, kind)
        # Python's executor rebuilds its wait set at every turn: an idle one should turn
        # seldom (`close` stirs it). The events executor turns only on events anyway.
        self.turn_s = 1.0 if isinstance(self.executor, SingleThreadedExecutor) else 0.1
        for each in (node, *self.more):
            self.executor.add_node(each)
        # Its callback ends the Python executor's turn, which `wake` alone does not (it waits
        # out its turn when nothing else is ready: up to `turn_s` per close). The events
        # executor's `wake` does (and with this guard its nodes' callbacks failed).
        self._stir = (
            node.create_guard_condition(lambda: None)
            if isinstance(self.executor, SingleThreadedExecutor)
            else None
        )
        self._thread: threading.Thread
        self._start()

    def add(self, node: Node) -> None:
        """Another node for this executor (and its thread)."""
        self.more.append(node)
        self.executor.add_node(node)

    def remove(self, node: Node) -> None:
        """A node of `add` no more: taken out while no callback runs, and destroyed."""
        with self.paused():
            self.executor.remove_node(node)
            self.more.remove(node)
            node.destroy_node()

    def _spin(self) -> None:
        if self.urgent:
            make_urgent(self._thread.name)
        # A callback that raises must not end the thread: the safety node's serves the stop.
        while self._running and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=self.turn_s)
            except Exception:
                if not (self._running and self.context.ok()):
                    return
                log.exception("%s: a callback failed; its executor goes on", self._thread.name)

    def _halt(self) -> bool:
        """Whether the spin thread has ended (a callback may hold it: it is given time)."""
        self._running = False
        if self._stir is not None:
            self._stir.trigger()
        self.executor.wake()
        self._thread.join(HALT_S)
        if self._thread.is_alive():
            log.warning("%s: still in a callback after %.0f s", self._thread.name, HALT_S)
            return False
        return True

    def _start(self) -> None:
        self._running = True
        self._thread = threading.Thread(
            target=self._spin, name=f"{self.node.get_name()}-spin", daemon=True
        )
        self._thread.start()

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """No callback runs inside: the place to destroy an entity of its nodes.

        rclpy 7.1's events executor, spinning while an action client of its node was
        destroyed, called into Python without the GIL and killed the process (closing
        test peers whose action clients had just been busy: a segmentation fault within
        ten rounds). rclpy's Python executors hold an entity while they use it.
        """
        if not self._halt():
            self._start()  # the old thread ends at its next turn
            raise RuntimeError(f"{self._thread.name}: a callback held the executor")
        try:
            yield
        finally:
            self._start()

    def close(self, *entities: Destroyable) -> None:
        """Stop spinning, destroy `entities` (what `destroy_node` leaves: action clients
        and servers), then the nodes, and end the context if it owns it."""
        # Join the spin thread before shutting the executor down, or the process can abort;
        # a thread still in a callback keeps the entities (leaked, not freed under it).
        if self._halt():
            self.executor.shutdown(timeout_sec=1)
            for entity in entities:
                entity.destroy()
        for each in (self.node, *self.more):
            each.destroy_node()
        if self.owns_context:
            self.context.try_shutdown()
