"""The stop's own process (`al5d.ros.stopproc`): a stop by ROS reaches the owner of the board,
which writes it before anything else, whatever the ROS bridge is doing; no move reaches
the board after that STOP.

The bridge is frozen with SIGSTOP to stand for the worst a flood and a busy host can do to
it (its threads never scheduled): the stop must reach the board all the same."""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest
from std_srvs.srv import Trigger

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome, Result
from al5d.arm.states import State
from al5d.model.transforms import Transform
from al5d.owner.loop import Owner
from al5d.ros.names import Names
from al5d.ros.processes import Child, Setup
from al5d.ros.qos import QOS_SERVICES
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Record
from al5d.web.link import WebNode
from al5d_rig.boardproc import BoardProcess
from al5d_rig.proc import (
    Lines,
    Proc,
    family,
    freeze,
    patient_config,
    run_state,
)
from al5d_rig.rospeer import Peer, wait_until
from al5d_rig.served import StopBursts


@dataclass
class Served:
    emu: BoardProcess
    proc: Proc
    peer: Peer

    @property
    def pid(self) -> int:
        return self.proc.popen.pid

    def child(self, module: bytes) -> int:
        """The pid of the server's process running `module` (its bridge, its stop process)."""
        for pid in family(self.pid):
            with contextlib.suppress(OSError):
                if module in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0"):
                    return pid
        raise AssertionError(f"the server has no {module.decode()} process")

    @property
    def bridge(self) -> int:
        return self.child(b"al5d.app.bridgeproc")

    def stop_process(self) -> int:
        return self.child(b"al5d.ros.stopproc")

    def stops_since(self, n: int) -> list[bytes]:
        return [r.raw for r in self.emu.records[n:] if r.raw.startswith(b"STOP")]

    def moves_after_first_stop(self, n: int) -> list[bytes]:
        records = self.emu.records[n:]
        first = next(i for i, r in enumerate(records) if r.raw.startswith(b"STOP"))
        return [
            r.raw for r in records[first:] if any(isinstance(c, p.GroupMove) for c in r.commands)
        ]

    def wait_stopped(self) -> None:
        self.proc.err.wait_for("STATE: stopped", 20)


#: The lease of the lane's clients in most tests here: a bridge frozen for seconds stands
#: for a busy host, not a hung one (the owner would otherwise take it for lost).
FROZEN_LEASE_S = 60.0


@pytest.fixture
def served(config: ArmConfig, tmp_path: Path) -> Iterator[Served]:
    yield from serve(config, tmp_path, FROZEN_LEASE_S)


@pytest.fixture
def leased(config: ArmConfig, tmp_path: Path) -> Iterator[Served]:
    """A server whose lease of its clients is the shipped one."""
    yield from serve(config, tmp_path, config.server.client_lease_s)


def serve(config: ArmConfig, tmp_path: Path, lease_s: float) -> Iterator[Served]:
    link = tmp_path / "ssc32u"
    # The board in a process of its own: a stall of this busy process (its peer, its
    # readers) must not silence the board's answers, which the owner would rightly take
    # for a lost link (an idle CI run: "no answer to QP3, asked twice" while the bridge
    # was frozen, and this process's stop asked again after 1 s).
    emu = BoardProcess(link, config=config)
    patient = patient_config(client_lease_s=lease_s)
    proc = Proc("serve", "--port", str(link), "--config", patient, "--log-level", "INFO")
    peer = Peer()
    try:
        proc.err.wait_for("STATE: ready", 60)
        peer.wait_for_server()
        peer.first_stop_answer()
        yield Served(emu, proc, peer)
    finally:
        for pid in family(proc.popen.pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        peer.close()
        proc.kill()
        emu.close()


def long_move_running(served: Served, ident: str) -> int:
    """A 6 s move under way on the board; the index of the record after it (a stop's STOPs
    before it may still be on their way when this is sent)."""
    n = len(served.emu.records)
    served.peer.send(ident, "move", time_ms=6000, base=80, shoulder=60, elbow=30)

    def index(records: list[Record]) -> int | None:
        return next((i for i in range(n, len(records)) if b"T6000" in records[i].raw), None)

    records = served.emu.wait_for(lambda rs: index(rs) is not None, 10)
    at = index(records)
    assert at is not None
    return at + 1


def a_move_by_ros_is_done(served: Served) -> None:
    """A move sent by ROS is done, once a new bridge's node and this peer have met."""
    deadline = time.monotonic() + 60
    for k in itertools.count():
        served.peer.send(f"after-{k}", "move", base=-10)
        try:
            assert served.peer.result(f"after-{k}", 3).outcome == "done"
            return
        except AssertionError as e:
            if time.monotonic() > deadline:
                raise AssertionError(f"{e}; {met(served)}") from e


def met(served: Served) -> str:
    """What this peer and the server's bridge know of each other, and the server's last words
    (a failure's account: DDS not matched, or matched and not answering)."""
    peer = served.peer
    lines = served.proc.err.drain(0.5)[-30:]
    return (
        f"readers of our instructions: {peer.pub.get_subscription_count()}, writers of "
        f"results: {peer.node.count_publishers(peer.names.result)}; the server said last:\n"
        + "\n".join(lines)
    )


def test_a_frozen_bridge_does_not_hold_the_stop(served: Served) -> None:
    """SIGSTOP the bridge mid-move: the stop service is answered by the stop's process and
    the STOP written by the owner; once the bridge runs again, the moves it takes that were
    sent before the stop are cancelled by it, the arm is locked, no move after the STOP."""
    n = long_move_running(served, "long")
    bridge = served.bridge
    freeze(bridge)
    try:
        # Moves sent while it is frozen wait in DDS for it; sent before the stop, they are
        # cancelled by it (rule 2) once the bridge hands them over.
        for i in range(5):
            served.peer.send(f"behind-{i}", "move", base=-40 + i)
        bursts = StopBursts(served.peer, served.proc)
        answer = served.peer.trigger("stop")
        assert answer.success, answer.message
        served.emu.wait_for(lambda rs: any(r.raw.startswith(b"STOP") for r in rs[n:]), 10)
        assert run_state(bridge) == "T"
    finally:
        os.kill(bridge, signal.SIGCONT)
    assert served.peer.result("long").reason == "cancelled by stop"
    served.wait_stopped()
    for i in range(5):
        outcome = served.peer.result(f"behind-{i}")
        assert outcome.outcome in ("cancelled", "refused"), outcome
    served.peer.send("locked", "move", base=0)
    assert "send release first" in served.peer.result("locked").reason
    time.sleep(0.5)  # whatever the owner might still write, it has written by now
    assert served.moves_after_first_stop(n) == []
    bursts.check(lambda: len(served.stops_since(n)))


def test_a_stop_on_the_topic_is_written_once_whoever_sees_it_first(served: Served) -> None:
    """A stop on the instruction topic is seen by the node `al5d` (in order) and the stop
    process's watcher (at once): written once, answered once."""
    for rep in range(5):
        n = long_move_running(served, f"move-{rep}")
        bursts = StopBursts(served.peer, served.proc)
        served.peer.send(f"stop-{rep}", "stop")
        assert served.peer.result(f"stop-{rep}").outcome == "done"
        assert served.peer.result(f"move-{rep}").reason == "cancelled by stop"
        wait_until(lambda n=n: len(served.stops_since(n)) >= 6, 10, "the STOPs")
        time.sleep(0.3)
        bursts.check(lambda n=n: len(served.stops_since(n)), on_topic=1)
        assert served.peer.trigger("release").success


def test_when_the_stop_process_ends_the_bridge_serves_the_stop(served: Served) -> None:
    os.kill(served.stop_process(), signal.SIGKILL)
    # The server's word and the bridge's, each written by its own logging thread: the
    # bridge's may come first.
    served.proc.err.wait_for_each(
        ["the stop process ended", "the stop is served by the bridge from now on"], 20
    )
    n = long_move_running(served, "after")
    deadline = time.monotonic() + 20
    while True:  # the server's own stop service may take a moment to be found
        try:
            answer = served.peer.trigger("stop")
            break
        except AssertionError:
            if time.monotonic() > deadline:
                raise
    assert answer.success, answer.message
    assert served.peer.result("after").reason == "cancelled by stop"
    wait_until(lambda: len(served.stops_since(n)) >= 6, 10, "the STOPs")
    # A new stop process is started, and serves the stop while the bridge is frozen (an
    # outside try: with the stop served by the bridge alone, a frozen bridge left none).
    served.proc.err.wait_for_each(
        ["the stop process was started again", "served by the stop process again"], 60
    )
    assert served.peer.trigger("release").success
    n = long_move_running(served, "frozen")
    bridge = served.bridge
    freeze(bridge)
    try:
        answer = served.peer.trigger("stop")
        assert answer.success, answer.message
        wait_until(lambda: len(served.stops_since(n)) >= 6, 10, "the STOPs, the bridge frozen")
    finally:
        os.kill(bridge, signal.SIGCONT)
    assert served.peer.result("frozen").reason == "cancelled by stop"


def test_when_the_bridge_ends_its_motion_halts_and_a_new_bridge_serves_ros(
    served: Served,
) -> None:
    """The bridge killed mid-move: the owner halts what its ROS clients commanded (a lost
    client), the server says so and starts a bridge again, and a move sent by ROS is then
    done. Before, the server went on without a word and with no ROS side: every ROS client
    found no server while `al5d send` on the machine still worked. What the owner halted
    and cancelled as the bridge went has its outcome on the result topic once a new bridge
    is there (an outside try: none ever came)."""
    n = long_move_running(served, "before")
    served.peer.send("queued", "move", base=-30)
    # Taken by the owner in order: once a move refused there is answered, so is the queued
    # move the owner's.
    served.peer.send("barrier", "move", base=1000)
    assert served.peer.result("barrier").outcome == "refused"
    os.kill(served.bridge, signal.SIGKILL)
    served.proc.err.wait_for_each(
        ["before]: lost contact with the client", "the ROS 2 bridge ended (exit code -9)"], 20
    )
    wait_until(lambda: len(served.stops_since(n)) >= 1, 10, "the halt's STOP")
    served.proc.err.wait_for("the ROS 2 bridge was started again", 120)
    for ident in ("before", "queued"):
        result = served.peer.result(ident, 60)
        assert result.outcome == "cancelled" and "lost contact with the client" in result.reason
    a_move_by_ros_is_done(served)


def test_a_hung_bridge_is_lost_to_the_owner_and_what_its_clients_commanded_halts(
    leased: Served,
) -> None:
    """The bridge keeps its ROS clients' leases; hung (SIGSTOP) mid-move, it kept none, and the
    arm moved on to the end while the client said the server would halt it. The owner
    leases the bridge itself: silent for the lease, it is lost, its clients' motion halted;
    hung for good, it is killed, and a bridge is started again."""
    n = long_move_running(leased, "before")
    freeze(leased.bridge)
    leased.proc.err.wait_for("before]: lost contact with the client", 20)
    wait_until(lambda: len(leased.stops_since(n)) >= 1, 10, "the halt's STOP")
    leased.proc.err.wait_for("has not ended in 5 s: killed", 30)
    leased.proc.err.wait_for("the ROS 2 bridge was started again", 120)
    a_move_by_ros_is_done(leased)


def test_a_bridge_that_keeps_ending_is_started_again_three_times_a_minute(
    served: Served,
) -> None:
    """A bridge that cannot run is not started again for ever (each start halts what its
    clients commanded): the fourth end in a minute is said, and the stop still works."""
    from al5d.app.server import RESTARTS_MAX

    for _ in range(RESTARTS_MAX):
        os.kill(served.bridge, signal.SIGKILL)
        served.proc.err.wait_for("the ROS 2 bridge was started again", 120)
    os.kill(served.bridge, signal.SIGKILL)
    served.proc.err.wait_for("not started again; the server goes on without it", 30)
    n = len(served.emu.records)
    assert served.peer.trigger("stop").success
    wait_until(lambda: len(served.stops_since(n)) >= 6, 10, "the STOPs")


def test_a_release_sent_after_the_stop_is_judged_after_it(served: Served) -> None:
    """A stop comes by its own process while the bridge is frozen; a move and a release sent
    after it reach the owner later, by the bridge: the release unlocks the arm (it is not
    refused as "nothing to release", nor undone by the stop), the move sent in between is
    refused. Frozen, the bridge hands them over at once when it runs again."""
    from std_srvs.srv import Trigger

    bridge = served.bridge
    freeze(bridge)
    try:
        assert served.peer.trigger("stop").success
        served.peer.send("between", "move", base=10)
        release = served.peer.services["release"].call_async(Trigger.Request())
        time.sleep(0.5)  # the release waits in DDS for the bridge
    finally:
        os.kill(bridge, signal.SIGCONT)
    wait_until(release.done, 20, "the release's answer")
    answer = release.result()
    assert answer.success, answer.message
    assert served.peer.result("between").outcome == "refused"  # locked, whichever came first
    served.peer.send("after", "move", base=-10)
    assert served.peer.result("after").outcome == "done"


def test_a_stop_goes_on_the_topic_at_once_while_the_stop_process_is_not_found(
    served: Served, tmp_path: Path
) -> None:
    """A client that has found the server's node but not its stop process (frozen here; a
    server just restarted under load has its stop process found seconds after its node)
    sends its stop on the instruction topic at once, and the node obeys it: the client
    does not first wait for the stop service (`SERVICE_GRACE_S`)."""
    from al5d.ros.rosway import SERVICE_GRACE_S

    stop_process = served.stop_process()
    freeze(stop_process)
    script = tmp_path / "stop.py"
    script.write_text(
        "import time\n"
        "from al5d.ros.client import Client\n"
        'with Client(namespace="", local=False, wait_s=60) as arm:\n'
        "    arm.wait_for_server(60)\n"
        "    asked = time.monotonic()\n"
        "    answer = arm.stop()\n"
        "    print(answer.via, answer.success, time.monotonic() - asked, flush=True)\n"
    )
    n = len(served.emu.records)
    try:
        done = subprocess.run(
            [sys.executable, str(script)], capture_output=True, text=True, timeout=120
        )
    finally:
        os.kill(stop_process, signal.SIGCONT)
    assert done.returncode == 0, done.stderr
    via, success, took = done.stdout.split()
    assert (via, success) == ("/al5d/instruction", "True"), done.stdout
    assert float(took) < SERVICE_GRACE_S, done.stdout
    assert "is not available" not in done.stderr, done.stderr
    wait_until(lambda: served.stops_since(n), 10, "the STOP on the board")


def test_a_stop_process_whose_owner_ends_as_it_starts_ends_with_it(
    config: ArmConfig, emulator: Emulator
) -> None:
    """The owner ends (a SIGTERM as `al5d serve` became ready) after it welcomed the stop
    process and before that process's node was up: the process ends at once. It waited for a
    listener of the lane's end added after that end, and `al5d serve` killed it 10 s later
    (found by SIGTERMs at random times during the server's start beside two busy loops)."""
    owner = Owner.on_port(config, emulator.port)
    owner.start()
    child = Child("al5d.ros.stopproc", Setup())
    try:
        owner.wait_for_state(State.READY, 30)
        owner.adopt(child.lane)
        # Frozen as its hello is read (the welcome goes in the same turn), so that the
        # welcome and the lane's end both wait for it, ahead of its node.
        wait_until(
            lambda: any(c.name == "al5d-stop" for c in list(owner._lanes.conns.values())),
            60,
            "the stop process's hello",
        )
        freeze(child.proc.pid)
        owner.close()
        os.kill(child.proc.pid, signal.SIGCONT)
        assert child.proc.wait(30) == 0
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(child.proc.pid, signal.SIGCONT)
        child.close(timeout=1)
        owner.close()


def test_a_web_views_stop_to_a_server_elsewhere_is_one_stop_whatever_comes_after(
    served: Served, config: ArmConfig, tmp_path: Path
) -> None:
    """The web view of a server on another machine (no lane of it here) sends its STOP on
    the instruction topic, again until it is answered: one stop. The stop process frozen
    (as a link that holds one way back): the server's node obeys the stop, the page
    releases the arm, and the stop process, thawed, takes what it held for the stop obeyed
    already, so the arm stays released. (The page called the stop service as well: a
    second stop, which the thawed stop process obeyed after the release.)"""
    heard = Heard()
    link = WebNode(Names.of(""), heard, config.model, tuple(config.presets))
    link.lane = tmp_path / "no-lane-here.sock"  # the server is elsewhere
    stop_process = served.stop_process()
    try:
        wait_until(lambda: heard.joints > 0, 30, "the page's joint states")
        # The stop service matched by the page's participant: a page that called it would now.
        probe = link.node.create_client(Trigger, "/al5d/stop", qos_profile=QOS_SERVICES)
        wait_until(probe.service_is_ready, 30, "the stop service")
        freeze(stop_process)
        try:
            said = served.proc.err
            before = len(said.drain(0))
            way = link.stop()
            stopped = said_after(said, before, "STATE: stopped")
            # The page shows its STOP sent before its user can click RELEASE: a page tells
            # only its newest STOP or RELEASE (a busy CI run's page had not yet told it).
            wait_until(lambda: len(heard.answers) > 0, 30, "the page's STOP told")
            link.release()
            released = said_after(said, stopped, "STATE: ready")
        finally:
            os.kill(stop_process, signal.SIGCONT)
        # The stop process runs again, and takes what waited for it: a move after it is run
        # (one more stop would cancel it or refuse it) and the arm is not stopped again.
        served.peer.send("after-the-thaw", "move", time_ms=1000, base=10)
        result = served.peer.result("after-the-thaw", 30)
        again = [line for line in said.drain(0)[released:] if "STATE: stopped" in line]
        assert result.outcome == "done" and not again, (result.outcome, result.reason, again)
        stop = heard.outcome(lambda o: o.instruction == "stop", 30)
        assert way == "the topic" and stop.result is Result.DONE and "~" in stop.id, (way, stop)
        # The page said its STOP sent and then the release's answer (the STOP's may have come
        # after the release, which ended the wait for it: not said then).
        wait_until(lambda: heard.answers[-1:] == [("RELEASE: done", True)], 30, "released")
        assert heard.answers[0][0].startswith("STOP on the topic: sent"), heard.answers
        assert all(ok is not False for _, ok in heard.answers), heard.answers
    finally:
        link.close()


#: A Python client of a server elsewhere (no lane of it here): it finds the stop service
#: as well (a client that called it would call it then), then stops the arm on a line.
HELD_STOP = """
import sys
from std_srvs.srv import Trigger
from al5d.ros.client import Client
from al5d.ros.qos import QOS_SERVICES
from al5d_rig.rospeer import wait_until
with Client(namespace="", local=False, wait_s=60) as arm:
    arm.wait_for_server(60)
    probe = arm._way.node.create_client(Trigger, "/al5d/stop", qos_profile=QOS_SERVICES)
    wait_until(probe.service_is_ready, 60, "the stop service")
    print("ready", flush=True)
    sys.stdin.readline()
    print("stop:", arm.stop(timeout=30), flush=True)
    sys.stdin.readline()
"""


def test_a_python_clients_stop_held_on_its_way_does_not_lock_the_arm_after_a_release(
    served: Served, tmp_path: Path
) -> None:
    """The Python client's stop to a server elsewhere goes on the instruction topic, again
    until it is answered: one stop. The stop process frozen (as a link that holds one way
    back): the server's node obeys the stop, another client releases the arm, and the stop
    process, thawed, takes what it held for the stop obeyed already, so the arm stays
    released. (The client called the stop service as well: a stop of its own, which the
    thawed stop process obeyed after the release.)"""
    script = tmp_path / "held_stop.py"
    script.write_text(HELD_STOP)
    client = Proc(str(script), program=sys.executable, stdin=True)
    stop_process = served.stop_process()
    try:
        client.out.wait_for("ready", 120)
        freeze(stop_process)
        try:
            said = served.proc.err
            before = len(said.drain(0))
            client.send("")
            answer = client.out.wait_for("stop:", 60)
            stopped = said_after(said, before, "STATE: stopped")
            served.peer.send("another-clients-release", "release")
            assert served.peer.result("another-clients-release", 30).outcome == "done"
            released = said_after(said, stopped, "STATE: ready")
            time.sleep(1.5)  # the client's copies, had it gone on sending
        finally:
            os.kill(stop_process, signal.SIGCONT)
        # The stop process runs again, and takes what waited for it: a move after it is run
        # (one more stop would cancel it or refuse it) and the arm is not stopped again.
        served.peer.send("after-the-held-stop", "move", time_ms=1000, base=10)
        result = served.peer.result("after-the-held-stop", 30)
        # What the thawed process took again only at its writer's next heartbeat (3 s) too.
        time.sleep(4.0)
        again = [line for line in said.drain(0)[released:] if "STATE: stopped" in line]
        assert result.outcome == "done" and not again, (result.outcome, result.reason, again)
        assert re.search(r"stop \[[^\]]+\]: done \(by /al5d/instruction\)", answer), answer
    finally:
        with contextlib.suppress(OSError):  # it has ended: what it said tells why
            client.send("")
        code = client.wait(60)
    assert code == 0, client.err.drain(0.5)[-20:]


def said_after(lines: Lines, since: int, text: str, timeout: float = 30.0) -> int:
    """The index of the first line from `since` on that holds `text`, once one has come."""

    def found() -> int | None:
        return next((i for i, ln in enumerate(lines.drain(0)) if i >= since and text in ln), None)

    wait_until(lambda: found() is not None, timeout, text)
    at = found()
    assert at is not None
    return at


class Heard:
    """A page's listener that counts the joint states and keeps the outcomes."""

    def __init__(self) -> None:
        self.joints = 0
        self.outcomes: list[Outcome] = []
        #: What the link said of the page's STOPs and RELEASEs.
        self.answers: list[tuple[str, bool | None]] = []

    def outcome(self, which: Callable[[Outcome], bool], timeout: float) -> Outcome:
        wait_until(lambda: any(which(o) for o in self.outcomes), timeout, "the outcome")
        return next(o for o in self.outcomes if which(o))

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None:
        self.joints += 1

    def on_outcome(self, outcome: Outcome) -> None:
        self.outcomes.append(outcome)

    def on_description(self, urdf: str) -> None: ...

    def on_state(self, state: str) -> None: ...

    def on_instruction(self, instr: object) -> None: ...

    def on_mount(self, parent: str, mount: Transform) -> None: ...

    def on_physical(self, degrees: dict[str, float]) -> None: ...

    def on_answer(self, text: str, ok: bool | None) -> None:
        self.answers.append((text, ok))


#: A Python client of a server elsewhere that floods it from a thread of its own (as
#: `al5d run`'s lines that end with `&`), then stops on a line.
FLOOD_STOP = """
import sys, threading, time
from al5d.arm import instruction as ins
from al5d.ros.client import Client
with Client(namespace="", local=False, wait_s=60) as arm:
    arm.wait_for_server(60)
    # The server's lease of its clients (a minute here): the client takes the server for
    # lost only after it, so the frozen bridge is a full writer, not a lost server (without
    # the lease, 1.5 s: a CI run beside two busy loops took longer to fill the writer).
    arm.config()
    print("ready", flush=True)
    sys.stdin.readline()
    sent, errors = [0], []
    def flood():
        try:
            for i in range(20000):
                arm.send(ins.move(base=(i % 40) - 20, time_ms=50), wait_s=600)
                sent[0] += 1
        except Exception as e:
            errors.append(f"{type(e).__name__}: {e}")
    flooding = threading.Thread(target=flood, daemon=True)
    flooding.start()
    flooding.join(60)
    print("flooded", sent[0], errors, flush=True)
    print("stop:", arm.stop(timeout=60), flush=True)
    sys.stdin.readline()
"""


def test_a_python_clients_stop_goes_while_its_own_flood_waits_unacknowledged(
    served: Served, tmp_path: Path
) -> None:
    """A client that floods a server which takes nothing (its bridge frozen: its reader
    acknowledges nothing, as a link that holds what goes one way) fills its writer: a
    move more is not sent, and says so (`NotSent`). Its stop goes all the same, on a
    writer of its own: the stop process obeys it while the bridge is still frozen, and
    the bridge, thawed, answers it. (On the moves' writer it failed with them, "Failed to
    publish" after 0.1 s, and never went out.)"""
    script = tmp_path / "flood_stop.py"
    script.write_text(FLOOD_STOP)
    client = Proc(str(script), program=sys.executable, stdin=True)
    bridge = served.bridge
    try:
        client.out.wait_for("ready", 120)
        n = len(served.emu.records)
        freeze(bridge)
        try:
            client.send("")
            flooded = client.out.wait_for("flooded", 90)
            assert "NotSent: " in flooded and "not acknowledged" in flooded, flooded
            served.emu.wait_for(lambda rs: any(r.raw.startswith(b"STOP") for r in rs[n:]), 30)
            assert run_state(bridge) == "T"
        finally:
            os.kill(bridge, signal.SIGCONT)
        answer = client.out.wait_for("stop [", 60)
        assert re.search(r"stop \[[^\]]+\]: done", answer), answer
    finally:
        with contextlib.suppress(OSError):  # it has ended: what it said tells why
            client.send("")
        code = client.wait(60)
    assert code == 0, client.err.drain(0.5)[-20:]
