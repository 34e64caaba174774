"""Does a publish that DDS blocks hold the whole Python process? (issue 23)

A reliable publisher whose subscriber never takes: with KEEP_ALL the writer's
history fills, and each `publish` waits for the rmw's blocking time before it
fails. This measures the longest publish and, meanwhile, the longest 1 ms sleep of
another thread of the same process. If the second follows the first, the publish
holds the GIL while it waits: every thread of that process stalls behind a slow
subscriber. Measured here (rclpy 7.1, Fast DDS): keep all, 103.5 ms publishes and a
106.0 ms sleep (floor 1.8 ms); keep last 100, 9.5 ms and 12.8 ms (floor 2.7 ms).
The server's writers keep the last (its results 10,000 deep); the instruction
topic's writers, in clients and the web view, keep all.

    .venv/bin/python bench/blocked_publish.py [SECONDS] [DEPTH]

Without DEPTH the publisher keeps all (as a flooding client's instructions); with
DEPTH it keeps the last DEPTH (as the server's results, 10,000 deep).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

TOPIC = "al5d_bench_blocked_publish"


def writer_qos(depth: int | None) -> QoSProfile:
    if depth is None:
        return QoSProfile(
            history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, depth=1
        )
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE, depth=depth
    )


#: The subscriber: matched, never spun, so its reader fills and stops acknowledging.
SUBSCRIBER = f"""
import time, rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("al5d_bench_never_takes")
qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, depth=1)
node.create_subscription(String, "{TOPIC}", lambda m: None, qos)
print("ready", flush=True)
time.sleep(3600)
"""


def main(seconds: float, depth: int | None) -> int:
    sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER], stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout is not None and sub.stdout.readline().strip() == "ready"
        rclpy.init()
        node = rclpy.create_node("al5d_bench_publishes")
        pub = node.create_publisher(String, TOPIC, writer_qos(depth))
        print("writer:", "keep all" if depth is None else f"keep last {depth}")
        while pub.get_subscription_count() < 1:
            time.sleep(0.05)
        time.sleep(1.0)
        stall = [0.0]
        done = threading.Event()

        def watch() -> None:
            while not done.is_set():
                t0 = time.monotonic()
                time.sleep(0.001)
                stall[0] = max(stall[0], time.monotonic() - t0)

        threading.Thread(target=watch, daemon=True).start()
        time.sleep(0.5)
        floor = stall[0]  # the same sleep before any publish blocked: this machine's noise
        stall[0] = 0.0
        msg = String(data="x" * 100)
        longest, sent, failed = 0.0, 0, 0
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            t0 = time.monotonic()
            try:
                pub.publish(msg)
                sent += 1
            except Exception:  # rclpy's RCLError: the blocking time ran out
                failed += 1
            longest = max(longest, time.monotonic() - t0)
        done.set()
        print(f"publishes: {sent} taken, {failed} failed after waiting")
        print(f"longest publish:                          {longest * 1000:7.1f} ms")
        print(f"longest 1 ms sleep of another thread:     {stall[0] * 1000:7.1f} ms")
        print(f"  the same before any publish (the floor): {floor * 1000:7.1f} ms")
        node.destroy_node()
        rclpy.shutdown()
    finally:
        sub.kill()
        sub.wait(10)
    return 0


if __name__ == "__main__":
    args = sys.argv[1:]
    sys.exit(main(float(args[0]) if args else 10.0, int(args[1]) if len(args) > 1 else None))
