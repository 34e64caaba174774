"""The executor threads of the server and its peers (`al5d.ros.executors.Spinner`), and
what the server's DDS and threads are given."""

from __future__ import annotations

import contextlib
import ipaddress
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from al5d_interfaces.action import Move
from rclpy.action import ActionClient
from rclpy.node import Node
from std_msgs.msg import String

from al5d.priority import URGENT_NICE
from al5d.ros.actions import outcome_of
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d_rig.proc import Proc, family, thread_nices
from al5d_rig.rospeer import Peer, wait_until


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


def test_a_threads_result_or_error_reaches_the_task_that_awaits_it() -> None:
    """`outcome_of`: a task of the executor awaits another thread's future without holding
    the executor; what the thread raised is raised in the task (a preempted goal's halt
    that failed ends its goal), not lost in a callback with the task waiting for good."""
    context = start_context()
    node = Node("al5d_outcome_of_test", context=context)
    spinner = Spinner(node, context, kind="single")
    pool = ThreadPoolExecutor(max_workers=1)
    try:

        def fails() -> int:
            raise RuntimeError("the halt could not be written")

        async def await_in_task(work: Callable[[], int]) -> int:
            return await outcome_of(node, pool.submit(work))

        executor = node.executor
        assert executor is not None
        good = executor.create_task(await_in_task, lambda: 7)
        bad = executor.create_task(await_in_task, fails)
        executor.wake()
        wait_until(lambda: good.done() and bad.done(), 10, "both tasks ended")
        assert good.result() == 7
        error = bad.exception()
        assert isinstance(error, RuntimeError) and "could not be written" in str(error)
    finally:
        spinner.close()
        pool.shutdown()


@pytest.mark.parametrize("kind", ["events", "single"])
def test_no_callback_runs_while_the_spinner_is_paused_and_close_destroys_what_it_is_given(
    kind: str,
) -> None:
    """An entity is destroyed only where no callback can run (`Spinner.paused`): the events
    executor crashed the process when one was destroyed under it."""
    context = start_context()
    node = Node("al5d_pause_test", context=context)
    heard: list[str] = []
    node.create_subscription(String, "/al5d_pause_test", lambda m: heard.append(m.data), 100)
    pub = node.create_publisher(String, "/al5d_pause_test", 100)
    spinner = Spinner(node, context, kind=kind if kind == "single" else None)
    client = ActionClient(node, Move, "/al5d_pause_test_move")
    try:
        wait_until(lambda: pub.get_subscription_count() > 0, 10, "the match")
        pub.publish(String(data="a"))
        wait_until(lambda: heard == ["a"], 10, "a, spinning")
        with spinner.paused():
            pub.publish(String(data="b"))
            time.sleep(0.5)  # on loopback: long since delivered, not yet taken
            assert heard == ["a"]
        wait_until(lambda: heard == ["a", "b"], 10, "b, spinning again")
    finally:
        spinner.close(client)
    assert client._client_handle.pointer == 0  # destroyed, after the thread had ended


SERVER_PROFILE_CHECK = """
import os
os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
from al5d.ros.dds import dds_profile, start_context
assert dds_profile(("/al5d/instruction", 1000), in_process=IN_PROCESS) is None
from rclpy.node import Node
Node("al5d_profile_check", context=start_context())
print("started")
"""


@pytest.mark.parametrize("in_process", [True, False], ids=["serving", "recording"])
def test_fast_dds_takes_the_servers_profile_whole(in_process: bool) -> None:
    # Fast DDS says nothing but an XMLPARSER error for a profile it cannot
    # read, and goes on with its defaults: the backlog bound and the deeper port lost
    # (and, for a recording server, its recorder's delivery through the transport).
    script = f"IN_PROCESS = {in_process}\n" + SERVER_PROFILE_CHECK
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
    )
    said = done.stdout + done.stderr  # Fast DDS's errors: stdout by default, stderr by ours
    assert done.returncode == 0 and "started" in done.stdout, said
    assert "XMLPARSER" not in said and "Error" not in said, said


OWN_STDOUT_CHECK = """
import os
os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
from al5d.ros.dds import start_context
from rclpy.node import Node
Node("al5d_stdout_check", context=start_context())
print("mine")
"""


def test_fast_dds_logs_on_stderr_and_leaves_a_processs_stdout_its_own() -> None:
    """Fast DDS's default log prints on stdout: a CI run's client script, started while
    other processes held shared-memory ports, printed Fast DDS's "Failed init_port ...
    open_and_lock_file failed" lines among its own words, and the test that read its answer
    failed. Our profile sends Fast DDS's log to stderr (`al5d.ros.dds`). Here Fast DDS is
    made to log an error as the process starts (a discovery server's address it cannot
    read, which it says and goes on without): on the code before, that line came first on
    the process's stdout."""
    env = {**os.environ, "ROS_DISCOVERY_SERVER": "not-an-address:x:y"}
    script = [sys.executable, "-c", OWN_STDOUT_CHECK]
    done = subprocess.run(script, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0 and done.stdout == "mine\n", done.stdout + done.stderr
    plain = re.sub(r"\x1b\[[0-9;]*m", "", done.stderr)  # its colours
    assert "SERVER_CLIENT_DISCOVERY Error" in plain, done.stderr


ACK_CHECK = """
import os, time
os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
from al5d.ros.dds import dds_profile, start_context
assert dds_profile(in_process=False) is None  # through the transport, as between processes
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
node = Node("al5d_ack_check", context=start_context())
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
pub = node.create_publisher(String, "/al5d_ack_check", qos)
node.create_subscription(String, "/al5d_ack_check", lambda _: None, qos)
deadline = time.monotonic() + 30
while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
    time.sleep(0.05)
for k in range(3):
    pub.publish(String(data=str(k)))
    print(pub.wait_for_all_acked(Duration(seconds=1.5)))
"""


def test_a_writer_hears_its_reader_has_what_it_sent_well_within_a_second() -> None:
    """A reader says what it has when its writer asks (a heartbeat): with Fast DDS's 3 s a
    closing client waited its whole 0.5 s for its last words to be heard, and a sample
    lost on a link went again seconds later (`al5d.ros.dds.HEARTBEAT_NS`). Without it, 2
    of these 3 waits of 1.5 s ran out here."""
    done = subprocess.run(
        [sys.executable, "-c", ACK_CHECK], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.split() == ["True"] * 3, done.stdout + done.stderr


#: A writer whose reader (another process, stopped) never acknowledges: how far a thread
#: of the writer's process counts while it sleeps 1 s, and while `acked` waits 1 s.
UNACKED_READER = """
from al5d.ros.dds import start_context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
context = start_context()
node = Node("al5d_unacked_reader", context=context)
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
node.create_subscription(String, "/al5d_unacked", lambda _: None, qos)
executor = SingleThreadedExecutor(context=context)
executor.add_node(node)
executor.spin()
"""
UNACKED = """
import os, signal, subprocess, sys, threading, time
os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
from al5d.ros.dds import acked, start_context
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
reader = subprocess.Popen([sys.executable, "-c", sys.argv[1]])
try:
    node = Node("al5d_unacked_writer", context=start_context())
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(String, "/al5d_unacked", qos)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    os.kill(reader.pid, signal.SIGSTOP)
    for _ in range(20):
        pub.publish(String(data="x" * 1000))
    count, done = [0], threading.Event()
    def counting():
        while not done.is_set():
            count[0] += 1
    thread = threading.Thread(target=counting)
    thread.start()
    time.sleep(0.2)
    c0 = count[0]; time.sleep(1.0); asleep = count[0] - c0
    c0 = count[0]; ok = acked([pub], 1.0); waiting = count[0] - c0
    done.set(); thread.join()
    print(ok, waiting / asleep)
finally:
    reader.kill()
"""


def test_waiting_for_a_reader_that_never_acknowledges_holds_nothing_else_of_the_process() -> None:
    """`al5d.ros.dds.acked` (a closing client's wait for its last words to be heard, the
    server's for its last results) lets the process's other threads run: rclpy's
    `wait_for_all_acked` held the GIL while it waited (a thread counted 1 % of its pace),
    and a CI run's emulated board in a closing client's process went unanswered."""
    done = subprocess.run(
        [sys.executable, "-c", UNACKED, UNACKED_READER], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    ok, share = done.stdout.split()
    assert ok == "False", done.stdout  # the reader was stopped: nothing acknowledged
    assert float(share) > 0.3, done.stdout  # the counting thread ran (about 1 %: held)


def udp_sockets(pid: int) -> list[ipaddress.IPv4Address]:
    """The local address of every UDP socket process `pid` holds (what `ss -uanp` shows),
    read where `ss` reads it: the socket inodes among its file descriptors, and
    /proc/net/udp."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            link = os.readlink(fd)
            if link.startswith("socket:["):
                inodes.add(link[8:-1])
    found = []
    for line in Path(f"/proc/{pid}/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[9] in inodes:
            # Little-endian hex on x86 and arm64 alike, as the kernel prints a __be32 raw.
            found.append(ipaddress.IPv4Address(bytes.fromhex(fields[1].split(":")[0])[::-1]))
    return found


def closed_to_the_network(addresses: list[ipaddress.IPv4Address]) -> bool:
    """Every socket on loopback, or on a multicast group (joined on loopback alone: a group
    address takes no unicast, and the group is joined where the profile allows)."""
    return all(a.is_loopback or a.is_multicast for a in addresses)


def sockets_of_a_server(tmp_path: Path, env: dict[str, str]) -> list[ipaddress.IPv4Address]:
    server = Proc("serve", "--log-level", "INFO", env=env)
    try:
        server.err.wait_for("ROS 2 node", 60)  # every participant made
        # The owner, the bridge and the stop's process: only the last two open DDS.
        return [a for pid in family(server.popen.pid) for a in udp_sockets(pid)]
    finally:
        server.kill()


def test_the_server_and_clients_listen_on_loopback_alone_by_default(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}
    server = sockets_of_a_server(tmp_path, env)
    assert len(server) >= 4 and closed_to_the_network(server), server
    # This process is a client (the test peers, `al5d send`, the web view start alike).
    peer = Peer(name="al5d_loopback_peer")
    try:
        mine = udp_sockets(os.getpid())
        assert mine and closed_to_the_network(mine), mine
    finally:
        peer.close()


def test_the_network_is_opened_on_purpose(tmp_path: Path) -> None:
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    server = sockets_of_a_server(tmp_path, env)
    assert any(a.is_unspecified for a in server), server


def test_the_stop_path_runs_ahead_of_the_rest_or_says_why_not() -> None:
    server = Proc("serve", "--log-level", "INFO")
    try:
        server.err.wait_for("ROS 2 node", 60)
        # The stop's process makes its node after the owner's welcome, later on a busy host.
        deadline = time.monotonic() + 30
        while True:
            nices = [n for pid in family(server.popen.pid) for n in thread_nices(pid)]
            said = server.err.drain(0.2)  # every line so far
            refused = [line for line in said if "refused a higher scheduling" in line]
            if refused or nices.count(URGENT_NICE) >= 4 or time.monotonic() > deadline:
                break
        refused = [line for line in server.err.drain(0.5) if "refused a higher scheduling" in line]
    finally:
        server.kill()
    if refused:  # an OS that allows no lower nice: said once, and nothing is raised
        assert len(refused) == 1 and URGENT_NICE not in nices, (refused, nices)
        return
    # The stop path (the safety services' executor, the stop watcher's reader and the threads
    # of their own DDS participant) ahead; the rest, the flood's reader among them, not.
    urgent = nices.count(URGENT_NICE)
    assert urgent >= 4 and nices.count(0) >= 4, nices
