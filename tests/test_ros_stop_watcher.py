"""The stop watcher (`al5d.ros.safety`): the first word of a serialized instruction, and every
message of a batch judged. (A stop both readers see, obeyed once: `test_arm_sequences.py`.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from al5d_interfaces.msg import ArmInstruction
from rclpy.node import Node
from rclpy.serialization import serialize_message

from al5d.arm.states import State
from al5d.ros import safety
from al5d.ros.dds import start_context
from al5d.ros.names import Names
from al5d.ros.qos import QOS_INSTRUCTIONS
from al5d.ros.safety import first_word, stop_here
from al5d_rig.armrig import Rig
from al5d_rig.rospeer import wait_until


def raw(word: str, **fields: object) -> bytes:
    return bytes(serialize_message(ArmInstruction(instruction=word, **fields)))


def test_the_first_word_is_read_from_the_serialized_message_as_the_node_reads_it() -> None:
    assert first_word(raw("stop", id="x" * 300)) == "stop"
    assert first_word(raw(" STOP\t")) == "stop"
    assert first_word(raw("\u00a0stop\x1f")) == "stop"  # str.strip's blanks, not only ASCII
    assert first_word(raw("move", joints=["base"], degrees=[1.0])) == "move"
    assert first_word(raw("")) == ""
    assert first_word(raw("s" * 300)) is None  # longer than any word a stop could be
    assert first_word(b"\x00\x01") is None
    assert first_word(b"\x07\x07\x00\x00\x05\x00\x00\x00stop\x00") is None  # not plain CDR
    assert first_word(b"\x00\x01\x00\x00\xff\x00\x00\x00stop\x00") is None  # cut short


def test_a_stop_behind_a_full_batch_is_obeyed(rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    # The watcher takes what waits a batch at a time: a stop that was the last one of a
    # batch went by unseen once (the node obeyed it later, behind the flood). A batch of 3
    # here: three moves, then the stop, fourth, and a move after it.
    monkeypatch.setattr(safety, "WATCH_BATCH", 3)
    context = start_context()
    watcher = None
    try:
        watcher = stop_here(rig.driver, context, Names())
        sender = Node("al5d_watch_test", context=context)
        pub = sender.create_publisher(ArmInstruction, Names().instruction, QOS_INSTRUCTIONS)
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the watcher's reader")
        for deg in (1.0, 2.0, 3.0):
            pub.publish(ArmInstruction(instruction="move", joints=["base"], degrees=[deg]))
        pub.publish(ArmInstruction(instruction="stop", id="fourth"))
        pub.publish(ArmInstruction(instruction="move", joints=["base"], degrees=[4.0]))
        wait_until(lambda: rig.driver.state is State.STOPPED, 10, "the stop obeyed")
    finally:
        if watcher is not None:
            watcher.close()
        context.try_shutdown()


def test_a_flood_that_outruns_the_watcher_loses_its_oldest_not_the_stop_sent_last() -> None:
    # Best effort and bounded, the watcher must drop the oldest of what it could not read,
    # never the newest: the stop that came last. A reader deeper than the bound Fast DDS
    # gives the topic (the server's instruction backlog) refuses the newest once full.
    backlog = 50
    done = subprocess.run(
        [sys.executable, "-m", "al5d_rig.watch_backlog", str(backlog)],
        capture_output=True,
        text=True,
        timeout=60,
        env=os.environ.copy(),
    )
    assert done.returncode == 0, done.stderr
    held = json.loads(done.stdout)
    assert held and held[-1] == "stop", held[-5:]
    assert len(held) <= backlog  # what did not fit was dropped: the oldest
