"""A client that floods `/al5d/instruction` at a steady rate: run as its own process.

    python -m al5d_rig.flood_client RATE SECONDS PREFIX [--mix] [--keep-last] [--ack-s S]

Publishes RATE moves a second for SECONDS, with ids PREFIX-0, PREFIX-1, ...,
once a line comes on stdin (meanwhile it sends instructions PREFIX-probe-K, which
the server refuses, so that the rig can wait for one's outcome); with --mix, every
500th message is a stop and the next a release (a clumsy user among a hostile
client's traffic). The writer keeps all it has not delivered (KEEP_ALL, as `al5d
send` does), or with --keep-last the last 10,000 only (as clients before issue 9
did). Prints one line of JSON when ready, and one when done: how many it sent, in
how long, how many publishes were refused and sent again (the readers' back-pressure), how
many were given up, and whether every reader acknowledged all of it before it ended.
"""

from __future__ import annotations

import json
import sys
import threading
import time

from al5d_interfaces.msg import ArmInstruction
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import INSTRUCTION_TOPIC

#: How long a refused publish is tried again before it counts as a loss.
RETRY_S = 10.0
#: How long the writer waits for its readers to acknowledge what it sent before the process
#: ends (and its history with it), unless --ack-s says: the rig gives it its whole wait for
#: the flood's outcomes. A flooded server on a busy host takes 100-250 moves a second, so
#: the last thousands of a flood can take a minute; with 30 s, 660 of them once went with
#: the process, the server taking them steadily until it ended.
ACK_S = 30.0


def main() -> int:
    rate, seconds, prefix = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
    mix = "--mix" in sys.argv
    history = HistoryPolicy.KEEP_LAST if "--keep-last" in sys.argv else HistoryPolicy.KEEP_ALL
    qos = QoSProfile(history=history, depth=10_000, reliability=ReliabilityPolicy.RELIABLE)
    context = start_context()
    node = Node(f"al5d_flood_{prefix}", context=context)
    pub = node.create_publisher(ArmInstruction, INSTRUCTION_TOPIC, qos)
    spinner = Spinner(node, context)
    deadline = time.monotonic() + 20
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    print(json.dumps({"ready": True}), flush=True)
    # The writer matching a reader is not the reader matching the writer: a flood begun
    # before the server's reader knows this writer loses its first instructions for good
    # (a volatile reader starts at the writer's sequence number when it matches; seen on a
    # busy machine: up to 6,918 of a flood's first instructions never reached the server).
    # Probes until told to go: the rig says go once a probe's outcome came back.
    go = threading.Event()

    def go_when_told() -> None:
        sys.stdin.readline()
        go.set()

    threading.Thread(target=go_when_told, daemon=True).start()
    probe = 0
    while not go.wait(0 if probe == 0 else 0.2):
        pub.publish(ArmInstruction(instruction="probe", id=f"{prefix}-probe-{probe}"))
        probe += 1
    n = int(rate * seconds)
    failed = retried = 0
    t0 = time.monotonic()
    for i in range(n):
        due = t0 + i / rate
        # A steady rate in 1 ms ticks, sleeping between them: a busy wait would take a
        # whole core from the server and the board on this 2-core machine.
        if (wait := due - time.monotonic()) > 0.001:
            time.sleep(wait)
        word = "move"
        if mix and i % 500 == 499:
            word = "stop"
        elif mix and i % 500 == 0 and i:
            word = "release"
        msg = ArmInstruction(instruction=word, id=f"{prefix}-{i}")
        if word == "move":
            msg.joints = ["base"]
            msg.degrees = [float(i % 60 - 30)]
        # A reliable writer whose history is full of what its readers have not acked yet
        # blocks, then refuses the sample (Fast DDS's max_blocking_time, 100 ms): the
        # readers' back-pressure, seen beside two busy loops at 10,000 a second. A sender
        # that means its instruction sends it again, as a user's client would; given up
        # after RETRY_S, it is a loss the sender sees.
        given_up = time.monotonic() + RETRY_S
        while True:
            try:
                pub.publish(msg)
                break
            except Exception:
                if time.monotonic() > given_up:
                    failed += 1
                    break
                retried += 1
    elapsed = time.monotonic() - t0
    # Let the last samples leave before the writer goes away with the process.
    ack_s = float(sys.argv[sys.argv.index("--ack-s") + 1]) if "--ack-s" in sys.argv else ACK_S
    acked = pub.wait_for_all_acked(Duration(seconds=ack_s))
    done = {"sent": n, "seconds": elapsed, "failed": failed, "retried": retried, "acked": acked}
    print(json.dumps(done), flush=True)
    spinner.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
