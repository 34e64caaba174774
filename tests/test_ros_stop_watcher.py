"""The stop watcher (`al5d.ros.safety`): the first word of a serialized instruction, which of
the two readers obeys each stop on the topic, and every message of a batch judged."""

from __future__ import annotations

import time

import pytest
from al5d_interfaces.msg import ArmInstruction
from armrig import Rig
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rospeer import wait_until

from al5d.arm.states import State
from al5d.ros import safety
from al5d.ros.runtime import QOS_INSTRUCTIONS, Names, start_context
from al5d.ros.safety import FirstTaker, StopWatcher, first_word


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


class Log:
    def __init__(self) -> None:
        self.done: list[str] = []

    def __call__(self, what: str) -> object:
        return lambda: self.done.append(what)


def test_each_stop_is_obeyed_by_the_reader_that_sees_it_first() -> None:
    taker, log = FirstTaker(), Log()
    taker.watcher_saw("a", log("watcher a"))
    taker.node_saw("a", log("node a"), log("node a again"))
    taker.node_saw("b", log("node b"), log("node b again"))
    taker.watcher_saw("b", log("watcher b"))
    assert log.done == ["watcher a", "node b"]


def test_a_release_between_is_never_undone_and_never_undoes_a_later_stop() -> None:
    taker, log = FirstTaker(), Log()
    # The stream: release r, then stop s; the watcher sees s before the node takes r.
    taker.watcher_saw("s", log("watcher s"))
    taker.node_released(log("release r"))
    taker.node_saw("s", log("node s"), log("node s again"))
    # The stream: stop t, then release u; the node takes both after the watcher saw t.
    taker.watcher_saw("t", log("watcher t"))
    taker.node_saw("t", log("node t"), log("node t again"))
    taker.node_released(log("release u"))
    assert log.done == ["watcher s", "release r", "node s again", "watcher t", "release u"]


def test_repeated_ids_are_counted_in_order_and_the_tables_stay_bounded() -> None:
    taker, log = FirstTaker(limit=8), Log()
    for _ in range(3):
        taker.watcher_saw("same", log("w"))
    for _ in range(3):
        taker.node_saw("same", log("n"), log("again"))
    taker.node_saw("same", log("n"), log("again"))  # one the watcher missed
    assert log.done == ["w", "w", "w", "n"]
    for i in range(100):  # stops the watcher never sees
        taker.node_saw(f"id{i}", log("n"), log("again"))
    assert len(taker._late) <= 8 and len(taker._early) <= 8


def test_a_stop_the_watcher_missed_does_not_make_it_pass_over_the_next() -> None:
    taker, log = FirstTaker(late_s=0.05), Log()
    taker.node_saw("", log("node: a stop the watcher missed"), log("again"))
    time.sleep(0.1)
    taker.watcher_saw("", log("watcher: the next stop with the same (empty) id"))
    assert log.done == [
        "node: a stop the watcher missed",
        "watcher: the next stop with the same (empty) id",
    ]


def test_the_last_message_of_a_batch_is_judged_too(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The watcher takes what waits after the message it was called with, a batch at most;
    # a stop that was the last one taken went by unseen (the node obeyed it later, behind
    # the flood). A batch of 3 here: three moves, then the stop, fourth.
    monkeypatch.setattr(safety, "WATCH_BATCH", 3)
    context = start_context()
    try:
        watcher = StopWatcher(rig.driver, context, Names(), FirstTaker())
        sender = Node("al5d_watch_test", context=context)
        pub = sender.create_publisher(ArmInstruction, Names().instruction, QOS_INSTRUCTIONS)
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the watcher's reader")
        for deg in (1.0, 2.0, 3.0):
            pub.publish(ArmInstruction(instruction="move", joints=["base"], degrees=[deg]))
        pub.publish(ArmInstruction(instruction="stop", id="last"))
        handle = watcher._watcher.handle
        with handle:
            first = None
            deadline = time.monotonic() + 10
            while first is None and time.monotonic() < deadline:
                first = handle.take_message(ArmInstruction, True)
                time.sleep(0.01)
        assert first is not None
        time.sleep(0.5)  # the other three on loopback
        watcher._watch(first[0])
        assert rig.driver.state is State.STOPPED
    finally:
        context.try_shutdown()
