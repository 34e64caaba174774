"""Bursts of goals, of result requests and of safety calls: every request answered (issue 10).

Before: the action kept rclpy's queue depth of 10 for its services, so of a
burst of 200 goals 180 were never seen, and of 300 result requests 248 were
lost; and with three goal clients running, some stop and release calls were
never answered.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from al5d_interfaces.action import Move
from std_srvs.srv import Trigger

from al5d.arm.config import ArmConfig
from al5d_rig.boardproc import BoardProcess
from al5d_rig.proc import Proc, patient_config
from al5d_rig.rospeer import Peer, wait_until

pytestmark = pytest.mark.solo  # load suites: alone (see pyproject.toml)


@pytest.fixture(scope="module")
def served(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Proc]:
    """The server, its board in a process of its own."""
    link = tmp_path_factory.mktemp("bursts") / "ssc32u"
    emu = BoardProcess(link, config=config)  # its own GIL: the load here cannot starve it
    # Patient with the board's answers: the busy loops beside it still take its core, and
    # a fault the link's timeout took for one rejected the goals meanwhile (a CI run: 153
    # of 300 rejected, beside two busy loops).
    proc = Proc("serve", "--port", str(link), "--config", patient_config(), "--log-level", "INFO")
    try:
        proc.err.wait_for("STATE: ready", 30)
        yield proc
    finally:
        proc.kill()
        emu.close()


@pytest.fixture(scope="module")
def server(served: Proc) -> Iterator[Peer]:
    peer = Peer(results=False, name="al5d_burst_peer")
    try:
        peer.wait_for_server()
        yield peer
    finally:
        peer.close()


def all_done(futures: list[Any], timeout: float) -> int:
    """How many of `futures` completed within `timeout`."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not all(f.done() for f in futures):
        time.sleep(0.02)
    return sum(f.done() for f in futures)


def test_a_burst_of_300_goals_and_300_result_requests_are_all_answered(
    server: Peer, served: Proc
) -> None:
    peer = server
    goals = [peer.move.send_goal_async(Move.Goal(preset="ready")) for _ in range(300)]
    assert all_done(goals, 30) == 300
    handles = [f.result() for f in goals]
    # Why any was rejected is in the server's log (a CI run beside two busy loops saw
    # some rejected, once in many runs, and did not say why).
    rejected = sum(not h.accepted for h in handles)
    if rejected:  # printed whole: an assertion's message is cut short in the report
        print("\n".join(served.err.drain(0.5)[-60:]))
    assert rejected == 0, f"{rejected} of 300 rejected: the server's log is printed above"
    peer.trigger("stop")  # cancels what waits: every goal has its result now
    results = [h.get_result_async() for h in handles]
    assert all_done(results, 30) == 300
    outcomes = {(r.result().result.outcome, r.result().result.reason[-120:]) for r in results}
    assert {o for o, _ in outcomes} <= {"done", "cancelled"}, outcomes
    peer.trigger("release")


def test_stop_and_release_are_answered_while_three_clients_send_goals(
    server: Peer, tmp_path: Path
) -> None:
    clients = [Peer(results=False, name=f"al5d_goal_client_{i}") for i in range(3)]
    running = True

    def send_goals(client: Peer) -> None:
        while running:
            future = client.move.send_goal_async(Move.Goal(joints=["base"], degrees=[10.0]))
            wait_until(future.done, 10, "a goal's answer")

    threads = [threading.Thread(target=send_goals, args=(c,)) for c in clients]
    try:
        for c in clients:
            assert c.move.wait_for_server(timeout_sec=10)
        for th in threads:
            th.start()
        late = []
        for i in range(40):
            name = "stop" if i % 2 == 0 else "release"
            future = server.services[name].call_async(Trigger.Request())
            if not all_done([future], 5):
                late.append(name)
        assert late == []
    finally:
        running = False
        for th in threads:
            th.join(15)
        for c in clients:
            c.close()
