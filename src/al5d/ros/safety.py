"""The stop, release and shutdown services, on a node and an executor thread of their own.

An emergency stop must never queue behind instruction traffic: with one
executor, a stop request waited behind every message taken before it (seconds
under a flood of 10,000 instructions a second). Here the services have their
own node (`al5d_safety`), their own executor and their own thread; the
driver's stop is synchronous and takes microseconds, so each request is
answered as soon as it is taken.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.context import Context
from rclpy.node import Node
from std_srvs.srv import Trigger

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Instruction, Kind
from al5d.ros.runtime import QOS_SERVICES, SAFETY_NODE, Names


class SafetyNode(Node):
    """Node `al5d_safety`: `/al5d/stop`, `/al5d/release`, `/al5d/shutdown` (std_srvs/Trigger),
    under the server's namespace."""

    def __init__(self, driver: ArmDriver, context: Context, names: Names) -> None:
        super().__init__(SAFETY_NODE, namespace=names.node_namespace, context=context)
        self.driver = driver
        for name, kind in names.services.items():
            self.create_service(Trigger, name, self._trigger(kind), qos_profile=QOS_SERVICES)

    def _trigger(self, kind: Kind) -> Callable[[Any, Any], Any]:
        def answer(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            future = self.driver.submit(Instruction(kind))
            if future.done():
                outcome = future.result()
                response.success = outcome.ok
                response.message = outcome.reason or f"{kind.value}: {outcome.result.value}"
            else:  # shutdown: parking takes a while; the outcome follows on /al5d/result
                response.success = True
                response.message = "shutting down: parking, then the server ends"
            return response

        return answer
