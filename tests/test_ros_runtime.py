"""The executor threads of the server (`al5d.ros.runtime.Spinner`), and the test peer's
catch-up of messages its executor was not told of (`rospeer.CatchUp`)."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rospeer import CatchUp, wait_until
from std_msgs.msg import String

from al5d.ros.runtime import Spinner, start_context


@pytest.mark.parametrize("kind", ["events", "single"])
def test_a_callback_that_raises_does_not_end_the_executor_thread(
    kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    """The safety node's thread serves the stop: one failing callback must not end it."""
    context = start_context()
    node = Node("al5d_spinner_test", context=context)
    heard: list[str] = []

    def on_message(msg: String) -> None:
        if msg.data == "bad":
            raise RuntimeError("a callback bug")
        heard.append(msg.data)

    node.create_subscription(String, "/al5d_spinner_test", on_message, 10)
    pub = node.create_publisher(String, "/al5d_spinner_test", 10)
    spinner = Spinner(node, context, kind=kind)
    try:
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the match")
        pub.publish(String(data="bad"))
        time.sleep(0.2)
        pub.publish(String(data="good"))
        wait_until(lambda: heard == ["good"], 10, "the next message")
        assert "a callback failed" in caplog.text
    finally:
        spinner.close()


def test_the_catch_up_takes_what_waits_in_a_quiet_input_and_leaves_a_busy_one() -> None:
    context = start_context()
    node = Node("al5d_catch_up_test", context=context)
    heard: list[str] = []
    catch_up = CatchUp(limit=2)
    catch_up.subscribe(node, String, "/al5d_catch_up_test", lambda m: heard.append(m.data), 100)
    pub = node.create_publisher(String, "/al5d_catch_up_test", 100)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the match")

        def send(*words: str) -> None:
            for w in words:
                pub.publish(String(data=w))
            time.sleep(0.3)  # on loopback

        send("a")
        executor.spin_once(timeout_sec=5)  # the executor's own notice: the input is busy
        send("b", "c", "d")
        assert catch_up.run() == {} and heard == ["a"]  # busy: left to the executor
        taken = catch_up.run()  # quiet since: taken here, `limit` at a time
        assert taken == {"/al5d_catch_up_test": 2} and heard == ["a", "b", "c"]
        assert catch_up.run() == {"/al5d_catch_up_test": 1} and heard[-1] == "d"
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()


SERVER_PROFILE_CHECK = """
import os
os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
from al5d.ros.runtime import server_dds_profile, start_context
assert server_dds_profile("/al5d/instruction", 1000) is None
from rclpy.node import Node
Node("al5d_profile_check", context=start_context())
print("started")
"""


def test_fast_dds_takes_the_servers_profile_whole() -> None:
    # Fast DDS says nothing but an XMLPARSER error for a profile it cannot
    # read, and goes on with its defaults: the backlog bound and the deeper port lost.
    done = subprocess.run(
        [sys.executable, "-c", SERVER_PROFILE_CHECK], capture_output=True, text=True, timeout=60
    )
    said = done.stdout + done.stderr  # Fast DDS logs its errors on stdout
    assert done.returncode == 0 and "started" in done.stdout, said
    assert "XMLPARSER" not in said and "Error" not in said, said
