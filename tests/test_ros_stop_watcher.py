"""The stop watcher's pure parts: the first word of a serialized instruction, and which of the
two readers obeys each stop on the topic (`al5d.ros.safety`)."""

from __future__ import annotations

import time

from al5d_interfaces.msg import ArmInstruction
from rclpy.serialization import serialize_message

from al5d.ros.safety import FirstTaker, first_word


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
