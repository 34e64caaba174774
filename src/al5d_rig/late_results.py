"""A server's instruction and result topics alone, whose answers reach a new client late:
`python -m al5d_rig.late_results LATE_S` (in the domain of its environment).

Every instruction is answered `done`, but the answers to instructions that come within
LATE_S of a client's first are not published: so it is when the server's result writer
has not yet matched the client's reader (each side of a topic matches the other when it
hears of it, apart; on a loaded host seconds apart), and a result published then reaches
nobody. It prints `ready` once it serves, and on SIGTERM the instructions it heard:
`heard <name> <answered>` a line each."""

from __future__ import annotations

import signal
import sys
import threading
import time

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.node import Node

from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import NODE, Names
from al5d.ros.qos import QOS_INSTRUCTIONS, QOS_STREAM


def main(late_s: float) -> None:
    names = Names()
    context = start_context()
    node = Node(NODE, namespace=names.node_namespace, context=context)
    results = node.create_publisher(InstructionResult, names.result, QOS_STREAM)
    heard: list[tuple[str, bool]] = []
    first: list[float] = []

    def on_instruction(msg: ArmInstruction) -> None:
        now = time.monotonic()
        first[:] = first or [now]
        answered = now - first[0] >= late_s
        heard.append((str(msg.instruction), answered))
        if answered:
            results.publish(
                InstructionResult(id=msg.id, instruction=msg.instruction, outcome="done")
            )

    node.create_subscription(ArmInstruction, names.instruction, on_instruction, QOS_INSTRUCTIONS)
    spinner = Spinner(node, context, kind="single")
    ended = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: ended.set())
    print("ready", flush=True)
    ended.wait()
    spinner.close()
    for name, answered in heard:
        print(f"heard {name} {answered}", flush=True)


if __name__ == "__main__":
    main(float(sys.argv[1]))
