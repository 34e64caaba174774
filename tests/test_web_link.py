"""The web view's ROS link (`al5d.web.link.WebNode`) against readers in processes of their own:
whether a jog's set-point has a server to read it, across a server killed outright; and
against a server, the web view as a client with a lease."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest
from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.node import Node

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome
from al5d.model.transforms import Transform
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import Names
from al5d.web import stopping as web_stopping
from al5d.web.link import QOS_OUTCOMES, WebNode
from al5d_rig.proc import Lines, dies_with_parent, freeze, said
from al5d_rig.rospeer import wait_until
from al5d_rig.served import served

NAMES = Names.of("web_link_test")

#: A server's reader of the set-points, alone in a process (as a server's is).
READER = f"""
import time
from rclpy.node import Node
from sensor_msgs.msg import JointState
from al5d.ros.dds import start_context
from al5d.ros.qos import QOS_COMMANDS
node = Node("jog_reader", context=start_context())
node.create_subscription(JointState, {NAMES.joint_commands!r}, lambda msg: None, QOS_COMMANDS)
print("reading", flush=True)
time.sleep(600)
"""


class Quiet:
    """A listener that takes what the link hands over and keeps none of it."""

    def on_description(self, urdf: str) -> None: ...

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None: ...

    def on_state(self, state: str) -> None: ...

    def on_outcome(self, outcome: Outcome) -> None: ...

    def on_instruction(self, instr: object) -> None: ...

    def on_mount(self, parent: str, mount: Transform) -> None: ...

    def on_physical(self, degrees: dict[str, float]) -> None: ...

    def on_answer(self, text: str, ok: bool | None) -> None: ...


class Answers(Quiet):
    """A listener that keeps what the link says of the page's STOPs and RELEASEs."""

    def __init__(self) -> None:
        self.said: list[tuple[str, bool | None]] = []

    def on_answer(self, text: str, ok: bool | None) -> None:
        self.said.append((text, ok))


@contextlib.contextmanager
def reader() -> Iterator[subprocess.Popen[str]]:
    """A reader process, reading; killed at the end (if the test has not killed it)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", READER], stdout=subprocess.PIPE, text=True, env=os.environ.copy()
    )
    try:
        assert proc.stdout is not None and said(proc.stdout) == "reading"
        yield proc
    finally:
        proc.kill()
        proc.wait(10)


def killed(proc: subprocess.Popen[str]) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)


@pytest.fixture
def link(config: ArmConfig) -> Iterator[WebNode]:
    node = WebNode(NAMES, Quiet(), config.model, tuple(config.presets))
    yield node
    node.close()


def test_after_the_server_is_lost_only_a_reader_matched_since_reads_the_jog(
    link: WebNode, config: ArmConfig
) -> None:
    """A server killed outright stays matched until DDS notices (its lease: seconds), and a
    set-point sent to it alone reaches nobody; the page keeps it due until the server that
    comes back has matched."""
    here = dict(config.presets["ready"])
    with reader() as first:
        wait_until(lambda: link.jog(here), 20, "the first reader matched")
        killed(first)
        link.server_lost()  # the page saw its joint states stop
        assert link.jog_pub.get_subscription_count() == 1  # the killed one, still matched
        assert not link.jog(here)
        with reader():
            wait_until(lambda: link.jog(here), 20, "the second reader matched")


def test_a_reader_matched_before_the_loss_was_noticed_reads_once_the_killed_one_has_gone(
    link: WebNode, config: ArmConfig
) -> None:
    """On a busy host the server that comes back can match before the page notices the loss
    (the page's joint states stop only so often): its reader is not new then, and counts
    once DDS has let the killed one go. Before, the jog waited for a match that had already
    happened (the web jog test beside two busy loops: no set-point in 10 s)."""
    here = dict(config.presets["ready"])
    with reader() as first:
        wait_until(lambda: link.jog(here), 20, "the first reader matched")
        with reader():
            wait_until(lambda: link.jog_pub.get_subscription_count() == 2, 20, "both matched")
            killed(first)
            link.server_lost()
            assert not link.jog(here)  # both still matched: the killed one may be the reader
            wait_until(lambda: link.jog(here), 60, "the killed reader gone, the second reading")
            assert link.jog_pub.get_subscription_count() == 1


#: A web view's link to a server elsewhere (no lane of it here: `argv[1]` names none), in a
#: process of its own: it sends an 8 s move once it hears the server.
WEB_MOVE = """
import sys, time
from pathlib import Path
from al5d.arm import instruction as ins
from al5d.arm.config import load_config
from al5d.ros.names import Names, reaches_server
from al5d.web.link import QOS_OUTCOMES, WebNode

class Heard:
    joints = 0
    def on_joints(self, *args):
        self.joints += 1
    def __getattr__(self, name):
        return lambda *args: None

config = load_config()
heard = Heard()
link = WebNode(Names.of(""), heard, config.model, tuple(config.presets))
link.lane = Path(sys.argv[1])
# The server heard, and its node's reader of instructions matched: a move sent before would
# reach nobody. (Two readers counted were once this node's own and the stop watcher's.)
deadline = time.monotonic() + 60
while heard.joints == 0 or not reaches_server(link.node, link.pub, link.names):
    assert time.monotonic() < deadline, "no server found"
    time.sleep(0.05)
link.send(ins.move(base=80, time_ms=8000, id="web-long"))
print("sent", flush=True)
sys.stdin.readline()
"""


def test_a_web_view_that_goes_silent_has_its_move_halted(config: ArmConfig, tmp_path: Path) -> None:
    """The web view is a client with a lease, as the Python client is: its process frozen
    mid-move (as a web view cut off from its server), the server halts the move once the
    lease has run out, and says why. (A page's moves named no lease, and ran on.)"""
    with served(config, tmp_path, "al5d_web_lease_peer") as arm:
        web = subprocess.Popen(
            [sys.executable, "-c", WEB_MOVE, str(tmp_path / "no-lane-here.sock")],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            preexec_fn=dies_with_parent,
        )
        try:
            assert web.stdout is not None
            Lines(web.stdout).wait_for("sent", 90)
            wait_until(lambda: arm.states[-1] == "moving", 30, "the page's move under way")
            freeze(web.pid)
            result = arm.peer.result("web-long", 30)
            assert result.outcome != "done", (result.outcome, result.reason)
            assert "lost contact with the client (web-" in result.reason, result.reason
        finally:
            web.kill()
            web.wait(10)


def test_a_release_ends_the_copies_of_a_stop_still_unanswered(link: WebNode) -> None:
    """A STOP on the topic is sent again until it is answered (here nobody answers: no server);
    a RELEASE from the page ends its copies, so none follows the release: the stop watcher
    could read a later copy before the node had read an earlier one (a lossy link), and
    take it for a stop sent after the release."""
    context = start_context()
    seen: list[str] = []
    node = Node("web_link_listener", context=context)
    node.create_subscription(
        ArmInstruction, NAMES.instruction, lambda m: seen.append(str(m.instruction)), 100
    )
    spinner = Spinner(node, context, kind="single")
    try:
        wait_until(lambda: link.pub.get_subscription_count() > 0, 20, "the listener matched")
        assert link.stop() == "the topic"
        wait_until(lambda: seen.count("stop") >= 3, 20, "the STOP sent again")
        link.release()
        wait_until(lambda: "release" in seen, 20, "the release")
        wait_until(lambda: not copying(), 20, "the copies ended")
        assert seen[-1] == "release", seen
    finally:
        spinner.close()


def test_a_stop_and_a_release_that_nobody_answers_are_said_unanswered(
    link: WebNode, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No server: the page says its STOP and its RELEASE sent and their answers awaited,
    and then that none came (shorter waits than the page's 10 s here), never that they were
    obeyed: whether the arm stopped, or was released, is unknown."""
    monkeypatch.setattr(web_stopping, "LANE_STOP_S", 1.0)
    monkeypatch.setattr(web_stopping, "RELEASE_ANSWER_S", 1.0)
    answers = link.listener = Answers()
    assert link.stop() == "the topic"
    wait_until(lambda: len(answers.said) == 2, 20, "the STOP said unanswered")
    link.release()
    wait_until(lambda: len(answers.said) == 4, 20, "the RELEASE said unanswered")
    time.sleep(0.5)  # nothing more is said of either
    # Copies every 0.25 s in the first second: as many as a busy host's waits let go.
    said = [(re.sub(r"sent [1-4] times", "sent N times", text), ok) for text, ok in answers.said]
    assert said == [
        ("STOP on the topic: sent, the server's answer awaited (sent again until it comes)", None),
        (
            "STOP on the topic: no answer in 1 s (sent N times): whether the arm has stopped "
            "is unknown",
            False,
        ),
        ("RELEASE on the topic: sent, the server's answer awaited", None),
        (
            "RELEASE on the topic: no answer in 1 s: whether the arm was released is unknown "
            "(its state shows it)",
            False,
        ),
    ]


def test_a_stop_by_the_lane_of_a_stalled_server_says_so_while_it_waits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A lane whose owner reads nothing (a listening socket here, as a frozen owner's is):
    the page said only that the STOP's answer was awaited for the whole 10 s, then "no
    answer (timed out)" (an outside try). Now it says, as `al5d send stop` does, that none
    came in 0.8 s and that it still waits, then how long it waited in all."""
    monkeypatch.setattr(web_stopping, "LANE_STOP_S", 2.0)
    said: list[tuple[str, bool | None]] = []
    lane = tmp_path / "lane"
    frozen = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    frozen.bind(str(lane))
    frozen.listen(4)
    try:
        stops = web_stopping.StopRelease(lambda instr: None, lambda t, ok: said.append((t, ok)))
        assert stops.stop(lane) == "the local lane"
        wait_until(lambda: len(said) == 3, 20, "the STOP said unanswered")
        assert said == [
            ("STOP by the local lane: sent, the server's answer awaited", None),
            (
                "STOP by the local lane: no answer in 0.8 s (the server busy or stalled); still "
                "waiting, up to 1.2 s more: whether the arm has stopped is unknown",
                None,
            ),
            (
                "STOP by the local lane: no answer in 2 s: whether the arm has stopped is unknown",
                False,
            ),
        ]
    finally:
        frozen.close()


def test_a_stop_answered_after_the_page_said_none_came_is_said_answered(
    link: WebNode, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A server that stalled past the page's wait obeys its STOP later: the page had said no
    answer came, and its note then said so for good (an outside try: SIGSTOP, STOP, 11 s,
    SIGCONT, the arm STOPPED and the note still "unknown"). The late answer is said."""
    monkeypatch.setattr(web_stopping, "LANE_STOP_S", 1.0)
    answers = link.listener = Answers()
    context = start_context()
    node = Node("web_link_late_server", context=context)
    copies: list[str] = []
    node.create_subscription(ArmInstruction, NAMES.instruction, lambda m: copies.append(m.id), 100)
    results = node.create_publisher(InstructionResult, NAMES.result, QOS_OUTCOMES)
    spinner = Spinner(node, context, kind="single")
    try:
        wait_until(lambda: link.pub.get_subscription_count() > 0, 20, "the listener matched")
        assert link.stop() == "the topic"
        wait_until(lambda: len(answers.said) == 2, 20, "the STOP said unanswered")
        assert answers.said[-1][1] is False and "no answer" in answers.said[-1][0], answers.said
        late = InstructionResult(id=copies[0], instruction="stop", outcome="done")

        def said_late() -> bool:
            results.publish(late)  # again until the page's reader has matched this writer
            return len(answers.said) == 3

        wait_until(said_late, 20, "the late answer said")
        assert answers.said[-1] == ("STOP: done", True), answers.said
    finally:
        spinner.close()


def copying() -> bool:
    """Whether a thread of this process still sends a STOP's copies."""
    return any(t.name.startswith("web-stop-") and t.is_alive() for t in threading.enumerate())
