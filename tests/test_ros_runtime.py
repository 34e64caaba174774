"""The executor threads of the server (`al5d.ros.runtime.Spinner`)."""

from __future__ import annotations

import time

import pytest
from rclpy.node import Node
from rospeer import wait_until
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
