"""The floor of the ROS figures: the least a driver in Python can do between a message and
the board, run beside `al5d serve` in the same benchmark.

A bare rclpy node (rclpy's events executor, its fastest) that holds the port with pyserial
and does nothing but write: a `move` on the instruction topic becomes the group move our
server would write for it (the same bytes, so the same wire time), a `stop` on the topic
or a call of the stop service becomes ESC and STOP for every channel. No validation, no
queue, no state, no link checks. Each instruction is answered `done` on the result topic
once written, so that the benchmark can pace itself as it does with the server.

`python bench/floor_node.py --port PATH --baud B [--trace FILE]`; says "ready" on stdout
once its subscription, publisher and service exist; ends on SIGTERM or SIGINT. With
--trace it writes, as it ends, when each instruction reached its callback, as `al5d serve
--trace` does ("recv", CLOCK_MONOTONIC in ns); an instruction `latency` is only traced and
answered (the ROS latency trial sends faster than the wire would carry moves).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import serial
from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.node import Node
from std_srvs.srv import Trigger

from al5d.arm.config import load_config
from al5d.arm.translate import Translator
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import Names
from al5d.ros.qos import QOS_INSTRUCTIONS, QOS_SERVICES, QOS_STREAM
from al5d.ssc32u import protocol as p

NAME = "al5d_floor"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", required=True)
    parser.add_argument("--baud", type=int, default=9600)
    parser.add_argument("--trace", type=Path)
    args = parser.parse_args()
    config = load_config()
    translator = Translator(config)
    stop = p.CANCEL + p.encode_stop(sorted(j.channel for j in config.joints.values()))
    port = serial.Serial(args.port, args.baud, timeout=0)
    fd = port.fileno()
    names = Names()
    context = start_context()
    node = Node(NAME, context=context)
    results = node.create_publisher(InstructionResult, names.result, QOS_STREAM)
    pose: dict[str, float | None] = {}
    received: list[tuple[str, int]] = []

    def on_instruction(msg: ArmInstruction) -> None:
        received.append((msg.id, time.monotonic_ns()))
        if msg.instruction == "stop":
            os.write(fd, stop)
        elif msg.instruction == "move":
            target = dict(zip(msg.joints, msg.degrees, strict=True))
            time_ms = max(msg.time_ms, round(translator.minimum_ms(pose, target)))
            os.write(fd, translator.encode(target, time_ms))
            pose.update(target)
        results.publish(InstructionResult(id=msg.id, instruction=msg.instruction, outcome="done"))

    def on_stop(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        os.write(fd, stop)
        response.success = True
        return response

    node.create_subscription(ArmInstruction, names.instruction, on_instruction, QOS_INSTRUCTIONS)
    node.create_service(Trigger, f"/{NAME}/stop", on_stop, qos_profile=QOS_SERVICES)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: done.set())
    spinner = Spinner(node, context)  # rclpy's events executor, in a thread of its own
    print("ready", flush=True)
    done.wait()
    spinner.close()
    port.close()
    if args.trace is not None:
        args.trace.write_text("".join(json.dumps([i, "recv", t]) + "\n" for i, t in received))
    return 0


if __name__ == "__main__":
    sys.exit(main())
