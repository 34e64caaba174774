"""The stop watcher (`al5d.ros.safety`): the first word of a serialized instruction, and every
message of a batch judged. (A stop both readers see, obeyed once: `test_arm_sequences.py`.)"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest
from al5d_interfaces.msg import ArmInstruction
from hypothesis import given
from hypothesis import strategies as st
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import serialize_message

from al5d.arm.states import State
from al5d.clock import Deadline
from al5d.ros import safety
from al5d.ros.dds import start_context
from al5d.ros.names import Names
from al5d.ros.qos import QOS_INSTRUCTIONS
from al5d.ros.safety import STOP_FILTER, StopNode, first_word
from al5d.ros.workarounds import filter_content
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


def test_a_stop_behind_a_full_batch_is_obeyed_and_moves_never_reach_the_watcher(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The watcher takes what waits a batch at a time: a stop that was the last one of a
    # batch went by unseen once (the node obeyed it later, behind the flood). A batch of 3
    # here: three words DDS's filter lets by (they have "stop" in them) but that are not
    # stops, then the stop, fourth, and one more after it. The moves between them are held
    # back by the filter: the watcher never sees them.
    monkeypatch.setattr(safety, "WATCH_BATCH", 3)
    seen: list[str | None] = []
    watch = safety.StopNode._watch

    def spied(node: safety.StopNode, raw: bytes, info: dict[str, int]) -> None:
        seen.append(first_word(raw))
        watch(node, raw, info)

    monkeypatch.setattr(safety.StopNode, "_watch", spied)
    context = start_context()
    watcher = None
    arm = rig.remote(name="watcher-test")
    try:
        watcher = StopNode(arm, context, Names())
        sender = Node("al5d_watch_test", context=context)
        pub = sender.create_publisher(ArmInstruction, Names().instruction, QOS_INSTRUCTIONS)
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the watcher's reader")
        for word in ("nonstop", "move", "Stopped", "move", "unstoppable"):
            pub.publish(ArmInstruction(instruction=word, joints=["base"], degrees=[1.0]))
        pub.publish(ArmInstruction(instruction="stop", id="fourth"))
        pub.publish(ArmInstruction(instruction="stop!", id="after"))
        wait_until(lambda: rig.driver.state is State.STOPPED, 10, "the stop obeyed")
        wait_until(lambda: len(seen) >= 5, 10, "the watcher's five")
        assert seen == ["nonstop", "stopped", "unstoppable", "stop", "stop!"]
    finally:
        if watcher is not None:
            watcher.close()
        context.try_shutdown()
        arm.close()


#: The stop filter as Python's `re` reads it (the same pattern: Fast DDS's MATCH is a
#: whole-string match).
STOP_FILTER_RE = re.compile(STOP_FILTER.split("'")[1])


@given(
    st.tuples(
        st.text(st.sampled_from(" \t\r\n\x0b\x0c\x1c\x1f\x85\xa0\u3000xé"), max_size=4),
        st.text(st.sampled_from("sStToOpP\u017f\u212a"), min_size=3, max_size=5),
        st.text(max_size=4),
    ).map("".join)
    | st.text()
)
def test_every_word_the_watcher_takes_for_a_stop_passes_the_filter(word: str) -> None:
    # The filter may let by more than stops (the watcher judges each), never less.
    if first_word(raw(word)) == "stop":
        assert STOP_FILTER_RE.fullmatch(word)


WORDS = [
    "stop", "STOP", " Stop ", "stop\n", "\tSTOP\r\n", "\u3000stop\u3000", "\x1cstop\x1f",
    "\x85sToP", "éstop", "xstopx", "move", "sto p", "home", "", "\u017ftop", "st\nop", "ST0P",
]  # fmt: skip


def test_dds_filters_as_the_pattern_reads() -> None:
    # Fast DDS's own regular expressions decide what reaches the watcher: each word of
    # WORDS arrives exactly when Python's reading of the pattern says.
    context = start_context()
    try:
        node = Node("al5d_filter_test", context=context)
        got: list[str] = []
        sub = node.create_subscription(
            ArmInstruction, "al5d_filter_test", lambda m: got.append(m.instruction), 100
        )
        assert filter_content(sub, STOP_FILTER)
        pub = node.create_publisher(ArmInstruction, "al5d_filter_test", 100)
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the filtered reader")
        for word in [*WORDS, "stop-last"]:
            pub.publish(ArmInstruction(instruction=word))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = Deadline(20)
        while "stop-last" not in got and not deadline.expired:
            executor.spin_once(timeout_sec=0.1)
        assert got[:-1] == [w for w in WORDS if STOP_FILTER_RE.fullmatch(w)]
        assert {"stop", "STOP", "stop\n", "\u3000stop\u3000"} < set(got)
        assert not {"move", "sto p", "\u017ftop", "ST0P"} & set(got)
    finally:
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
    # Its last line: Fast DDS writes its own errors on stdout (an idle CI run: "Failed
    # init_port" of its shared-memory transport, before the JSON).
    held = json.loads(done.stdout.strip().splitlines()[-1])
    assert held and held[-1] == "stop", held[-5:]
    assert len(held) <= backlog  # what did not fit was dropped: the oldest
