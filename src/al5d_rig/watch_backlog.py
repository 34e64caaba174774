"""A process with the server's Fast DDS profile (the instruction backlog's bound) and a reader
of the topic as the stop watcher has, which takes nothing while a flood outruns it: run as its
own process (the profile is read once, before a process's first ROS context).

    python -m al5d_rig.watch_backlog BACKLOG

Publishes 3 x BACKLOG moves and then a stop; prints, as JSON, the instructions of the
messages the reader then holds, in order.
"""

from __future__ import annotations

import json
import sys
import time

from al5d_interfaces.msg import ArmInstruction
from rclpy.node import Node

from al5d.ros.dds import dds_profile, start_context
from al5d.ros.names import Names
from al5d.ros.qos import QOS_INSTRUCTIONS, qos_watch


def main() -> int:
    backlog = int(sys.argv[1])
    topic = Names().instruction
    dds_profile((topic, backlog))
    sender, watcher = start_context(), start_context()
    sub = Node("watch_backlog", context=watcher).create_subscription(
        ArmInstruction, topic, lambda msg: None, qos_watch(backlog)
    )
    pub = Node("watch_backlog_sender", context=sender).create_publisher(
        ArmInstruction, topic, QOS_INSTRUCTIONS
    )
    deadline = time.monotonic() + 20
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)  # matched both ways
    for i in range(3 * backlog):
        pub.publish(ArmInstruction(instruction="move", id=str(i)))
    pub.publish(ArmInstruction(instruction="stop", id="last"))
    held: list[str] = []
    deadline = time.monotonic() + 20
    while not held or held[-1] != "stop":
        if time.monotonic() > deadline:
            break
        time.sleep(0.2)
        with sub.handle:
            while (taken := sub.handle.take_message(sub.msg_type, False)) is not None:
                held.append(taken[0].instruction)
    print(json.dumps(held))
    return 0


if __name__ == "__main__":
    sys.exit(main())
