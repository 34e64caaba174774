"""The clients' leases: a client that hangs or is cut off leaves nothing moving, one that
closes leaves its motion going, and a request its sender gave up on, or that comes too late
for it, never moves the arm, whatever the client's clock says."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from al5d_interfaces.msg import ArmInstruction

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.owner import where
from al5d.owner.client import Remote
from al5d.ros.actions import NO_CLIENT_LEFT
from al5d.ros.dds import HEARTBEAT_NS, WRITER_MESSAGE
from al5d.ros.leases import FORGET_S, PACE_SLACK, Leases
from al5d_rig import actionclient
from al5d_rig.proc import Lines, Proc, said, stacks
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Served, served

CMD_S = 60.0
DOCS = Path(__file__).parents[1] / "docs"
S = 1_000_000_000  # ns


# -- the bookkeeping, alone --------------------------------------------------------------


def lapsed(leases: Leases, t: float) -> list[str]:
    """The clients `leases` finds lost at `t`."""
    return [key for key, _ in leases.lapsed(t)]


def test_a_client_not_heard_for_its_lease_is_lost_once_and_one_that_closes_is_forgotten() -> None:
    leases = Leases(1.0)
    leases.heard("a", 0, 100, 10.0, 5 * S)
    leases.heard("b", 0, 100, 10.0, 5 * S)
    assert lapsed(leases, 10.9) == []
    leases.heard("b", S // 2, 0, 10.5, 5 * S)  # b closes: forgotten, never lost
    assert lapsed(leases, 11.1) == ["a"]
    assert lapsed(leases, 20.0) == []  # said once
    assert len(leases) == 1
    assert lapsed(leases, 10.0 + FORGET_S + 1) == [] and len(leases) == 0  # forgotten


def test_leases_that_waited_while_the_server_stalled_count_from_when_they_were_sent() -> None:
    """Leases every 0.1 s, read as they come until 10.0 s; the server stalls from then to
    13.0 s (its process frozen), and its client is cut off at 11.0 s. The leases that waited
    are read at once after the stall: the client was there until 11.0 s, not 13.0 s, and
    is lost as soon as the server runs again (it took every client for there a lease
    longer: until 14.0 s)."""
    leases = Leases(1.0)
    for k in range(101):
        leases.heard("c", k * S // 10, 100, k / 10, k * S // 10 + 1_000_000)
    for k in range(101, 111):  # sent until the cut, read after the stall
        leases.heard("c", k * S // 10, 100, 13.0 + k / 10000, 13 * S)
    [(key, silent_s)] = leases.lapsed(13.1)
    assert key == "c" and silent_s == pytest.approx(13.1 - (10.0 + 1.0 * PACE_SLACK))


def test_a_lease_that_waited_out_the_loss_of_its_client_does_not_bring_it_back() -> None:
    """The server, run again after a stall, finds the client lost before it reads the lease
    that waited (sent at 11.0 s, read at 13.0 s): lost it stays. One sent since is back."""
    leases = Leases(1.0)
    for k in range(101):
        leases.heard("c", k * S // 10, 100, k / 10, k * S // 10 + 1_000_000)
    assert lapsed(leases, 13.0) == ["c"]
    leases.heard("c", 11 * S, 100, 13.01, 13 * S)
    assert lapsed(leases, 20.0) == []  # said once: still lost, not lost again
    assert leases.stale("c", 11 * S + 1, 0, 13.02, 13 * S) is not None
    leases.heard("c", 20 * S, 100, 20.0, 20 * S + 1_000_000)  # the link is back
    assert leases.stale("c", 20 * S + 1, 0, 20.01, 20 * S + 2_000_000) is None


@pytest.mark.parametrize(
    ("what", "skew_s", "trip_s", "within"),
    [
        ("as it was", 0.0, 0.001, 1),
        ("0.7 s slower (a longer route)", 0.0, 0.7, 1),
        ("its clock stepped back 5 s meanwhile", -5.0, 0.001, 70),
    ],
)
def test_a_lost_client_whose_leases_come_again_is_back(
    what: str, skew_s: float, trip_s: float, within: int
) -> None:
    """Cut off at 10.0 s and lost; from 20.0 s its leases come again, every 0.1 s: it is
    back at once, or, its clock stepped back, once its clock's old samples are gone
    (`SAMPLES` leases: a stepped clock's first leases look sent long ago)."""
    leases = Leases(1.0)
    for k in range(101):
        leases.heard("c", k * S // 10, 100, k / 10, k * S // 10 + 1_000_000)
    assert lapsed(leases, 11.5) == ["c"]
    for k in range(within):
        sent, came = 20 + k / 10, 20 + k / 10 + trip_s
        leases.heard("c", int((sent + skew_s) * S), 100, came, int(came * S))
        back = leases.stale("c", int((sent + skew_s) * S) + 1, 0, came, int(came * S)) is None
        if back:
            break
    assert back, what
    assert lapsed(leases, came + 0.5) == []


@pytest.mark.parametrize(
    ("what", "sent_s", "came_s"),
    [
        ("its clock stepped back 5 s", lambda k: k / 10 - (5 if k >= 50 else 0), lambda k: k / 10),
        ("its clock stepped on 5 s", lambda k: k / 10 + (5 if k >= 50 else 0), lambda k: k / 10),
        ("its clock 0.5 % slow", lambda k: k / 10 * 0.995, lambda k: k / 10),
        (
            "its clock slewed 8.3 % slow (chrony's most)",
            lambda k: k / 10 / 1.0833,
            lambda k: k / 10,
        ),
        ("its leases 0.3 s apart", lambda k: k * 0.3, lambda k: k * 0.3),
        ("its leases bunched by the link", lambda k: k / 10, lambda k: (k // 5) / 2 + 0.45),
    ],
)
def test_a_client_whose_leases_keep_coming_is_never_lost(
    what: str, sent_s: Callable[[int], float], came_s: Callable[[int], float]
) -> None:
    """A client heard all the time, whatever its clock does or its leases' pace, is there:
    only differences of its own times count, and never for more than they say."""
    leases = Leases(1.0)
    for k in range(20_000):
        t = came_s(k)
        assert lapsed(leases, t) == [], (what, k)  # as long a silence as there is: till now
        leases.heard("c", int(sent_s(k) * S), 100, t, int(t * S))


@pytest.mark.parametrize("skew_s", [-5.0, 0.0, 5.0])
def test_a_requests_age_is_judged_on_the_servers_clock_whatever_the_clients(
    skew_s: float,
) -> None:
    """The client's clock is `skew_s` off the server's; the trip takes 2 ms, once 4 s."""
    leases = Leases(1.0)
    skew = int(skew_s * S)
    trip = 2_000_000
    for k in range(10):  # leases at 10 a second
        sent = 100 * S + k * S // 10
        leases.heard("c", sent + skew, 100, 100.0 + k / 10, sent + trip)
    sent = 101 * S
    assert leases.stale("c", sent + skew, 3000, 101.0, sent + trip) is None
    late = leases.stale("c", sent + skew, 3000, 105.0, sent + 4 * S)
    assert late is not None and "3998 ms after it was sent" in late and "3000 ms" in late
    assert leases.stale("c", sent + skew, 0, 105.0, sent + 4 * S) is None  # it waits for ever
    # Its time of sending on the server's clock, to within the quickest trip.
    assert leases.on_server_clock("c", sent + skew) == sent + trip


def test_what_a_lost_client_sent_before_it_was_heard_again_is_stale() -> None:
    leases = Leases(1.0)
    leases.heard("c", 10 * S, 100, 10.0, 10 * S)
    assert lapsed(leases, 11.5) == ["c"]
    # Sent before the cut, delivered while it is lost.
    lost = leases.stale("c", 10 * S + 1, 0, 16.0, 16 * S)
    assert lost is not None and "is lost" in lost
    leases.heard("c", 16 * S, 100, 16.0, 16 * S)  # the link is back
    back = leases.stale("c", 10 * S + 2, 0, 16.0, 16 * S + 1)
    assert back is not None and "out of contact" in back
    assert leases.stale("c", 16 * S + 5, 0, 16.0, 16 * S + 6) is None  # sent since: run


def test_a_lost_clients_request_sent_since_the_link_came_back_runs_and_brings_it_back() -> None:
    """After a cut the client hears the server (its joint states) before the server hears
    its lease: its first request, on time, is a sign of it."""
    leases = Leases(1.0)
    leases.heard("c", 10 * S, 100, 10.0, 10 * S + 2_000_000)  # trips take 2 ms
    assert lapsed(leases, 11.5) == ["c"]
    late = leases.stale("c", 10 * S + 500_000_000, 0, 16.0, 16 * S)  # sent into the cut
    assert late is not None and "is lost" in late
    assert leases.stale("c", 16 * S, 0, 16.0, 16 * S + 3_000_000) is None  # on time: back
    assert lapsed(leases, 16.5) == []
    older = leases.stale("c", 15 * S, 0, 16.1, 16 * S + 4_000_000)  # sent before that one
    assert older is not None and "out of contact" in older


def test_a_request_that_comes_after_its_clients_lease_ran_out_is_judged_after_that_loss() -> None:
    """The server stalled (frozen) past a client's lease; running again, it reads a request
    the client sent since (it heard the server again) before anything has looked at the
    leases. The client's loss comes with the request's verdict, before it: what the client
    commanded before the stall is halted, then the request runs; never the request taken,
    then the client lost for the silence before it (which halted the request: a CI run)."""
    leases = Leases(1.0)
    leases.heard("c", 10 * S, 100, 10.0, 10 * S + 2_000_000)  # trips take 2 ms
    verdict = leases.judge("c", 13 * S, 0, 13.0, 13 * S + 2_000_000)
    assert [key for key, _ in verdict.lost] == ["c"] and verdict.stale is None, verdict
    assert verdict.lost[0][1] == pytest.approx(3.0)
    # Back, its request a sign of it: lost again only if no lease follows within the lease.
    assert lapsed(leases, 13.9) == []
    assert lapsed(leases, 14.1) == ["c"]
    # One that it sent before the stall, read after it, is judged after the loss too: stale.
    leases.heard("d", 10 * S, 100, 10.0, 10 * S + 2_000_000)
    late = leases.judge("d", 10 * S + 500_000_000, 0, 13.1, 13 * S + 100_000_000)
    assert [key for key, _ in late.lost] == ["d"], late
    assert late.stale is not None and "is lost" in late.stale


def test_a_client_with_no_lease_yet_is_judged_by_its_first_request_and_lost_without_one() -> None:
    leases = Leases(1.0)
    assert leases.stale("", 0, 100, 5.0, 60 * S) is None  # no client named: no lease
    assert leases.stale("new", 0, 100, 5.0, 60 * S) is None  # its first sample: not late
    assert leases.on_server_clock("new", 7) == 60 * S + 7
    # Its request was a sign of it; no lease followed within the lease's time: lost.
    assert lapsed(leases, 5.5) == []
    assert lapsed(leases, 6.1) == ["new"]


# -- on a server ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def arm(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    with served(config, tmp_path_factory.mktemp("leases"), "al5d_leases_peer") as s:
        yield s


def test_a_lane_client_that_speaks_for_others_loses_one_and_the_others_go_on(
    arm: Served,
) -> None:
    """The bridge's way: each ROS client a client of the core of its own on one lane."""
    arm.ready()
    lane = Remote.connect(where.path(), name="speaks-for-two")
    try:
        gone = lane.submit(ins.move(base=-80, time_ms=4000, id="gone-1"), client="a")
        queued = lane.submit(ins.move(base=80, time_ms=400, id="gone-2"), client="a")
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        stays = lane.submit(ins.move(elbow=60, time_ms=400, id="stays"), client="b")
        time.sleep(0.3)
        lane.gone("a", "no lease heard for 1 s")
        for future in (gone, queued):
            outcome = future.result(CMD_S)
            assert outcome.result is ins.Result.CANCELLED, outcome
            assert "lost contact with the client (a: no lease heard for 1 s)" in outcome.reason
        assert stays.result(CMD_S).result is ins.Result.DONE
        assert abs(arm.emu.servo_degrees()["base"] + 80) > 5  # halted on its way
        lane.gone("b", "")  # closed: forgotten, nothing to halt
    finally:
        lane.close()


CLIENT = """
import time
from al5d_interfaces.msg import ArmInstruction

from al5d.arm import instruction as ins
from al5d.ros.client import Client
c = Client(local=False)
c.wait_for_server(60)
c.send(ins.move(base={target}, time_ms=4000, id="{ident}"), wait_s=60)
print("sent", flush=True)
{then}
"""


def ros_client(target: int, ident: str, then: str) -> subprocess.Popen[str]:
    script = CLIENT.format(target=target, ident=ident, then=then)
    return subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)


def test_a_ros_client_that_hangs_mid_move_has_its_move_halted_with_the_reason(
    arm: Served,
) -> None:
    arm.ready()
    client = ros_client(-80, "hung-1", "time.sleep(600)")
    try:
        assert client.stdout is not None and said(client.stdout) == "sent"
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        client.send_signal(signal.SIGSTOP)  # hung: its leases stop, its process stays
        results = arm.peer.results_now
        wait_until(lambda: "hung-1" in results(), CMD_S, "its outcome")
        outcome = results()["hung-1"]
        assert outcome.outcome == "cancelled", outcome
        assert "lost contact with the client" in outcome.reason and "no lease" in outcome.reason
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready: halted, not locked")
        assert abs(arm.emu.servo_degrees()["base"] + 80) > 5
    finally:
        client.kill()
        client.wait(10)


def test_a_ros_client_that_closes_leaves_its_move_going(arm: Served) -> None:
    arm.ready()
    client = ros_client(60, "closed-1", "c.close()")
    assert client.stdout is not None and said(client.stdout) == "sent"
    assert client.wait(CMD_S) == 0
    results = arm.peer.results_now
    wait_until(lambda: "closed-1" in results(), CMD_S, "its outcome")
    assert results()["closed-1"].outcome == "done", results()["closed-1"]
    assert abs(arm.emu.servo_degrees()["base"] - 60) < 1


FAKETIME_LIB = Path("/usr/lib/x86_64-linux-gnu/faketime/libfaketime.so.1")

SKEWED = """
import select, sys, time
# libfaketime 0.9.10 with FAKETIME_DONT_FAKE_MONOTONIC fails Python's time.sleep
# (clock_nanosleep: "OSError: [Errno 22] Invalid argument"); select's timeout is relative.
time.sleep = lambda s: select.select([], [], [], max(0.0, s)) and None
from al5d.ros.client import Client
c = Client(local=False)
c.wait_for_server(60)
print("clock", time.time(), flush=True)
for line in sys.stdin:
    word = line.strip()
    if word == "stop":
        print("stop:", c.stop(), flush=True)
    elif word == "release":  # on the topic, with its lease (Client.release)
        print("release:", c.release(), flush=True)
    else:
        print("move:", c.execute(word, timeout=60), flush=True)
c.close()
"""


#: The skewed client's DDS: the project's (`al5d.ros.dds`) but UDP on the loopback interface
#: only, no shared memory, as a client on another machine has. Fast DDS's shared-memory
#: ports are checked for health by every process that opens them, against the time each
#: wrote there on its own wall clock: with one process 5 s off, the others took its ports'
#: last check for seconds old (or for seconds ahead) on every round, and twice in full runs
#: the skewed client never found the server in 60 s, nothing on its stderr.
ANOTHER_MACHINE_DDS = f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>udp_only</transport_id>
        <type>UDPv4</type>
        <interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="another_machine" is_default_profile="true">
      <rtps>
        <userTransports><transport_id>udp_only</transport_id></userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
      </rtps>
    </participant>
    <data_writer profile_name="al5d_writer" is_default_profile="true">
      <times><heartbeatPeriod><sec>0</sec><nanosec>{HEARTBEAT_NS}</nanosec></heartbeatPeriod></times>
      <propertiesPolicy><properties><property>
        <name>fastdds.max_message_size</name><value>{WRITER_MESSAGE}</value>
      </property></properties></propertiesPolicy>
    </data_writer>
  </profiles>
</dds>
"""


def shared_memory_mapped(pid: int) -> list[str]:
    """The Fast DDS shared-memory files process `pid` has mapped."""
    maps = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return sorted({line.split()[-1] for line in maps if "/dev/shm/fastrtps_" in line})


@pytest.mark.parametrize("skew_s", [-5, 5])
def test_a_client_whose_clock_is_seconds_off_is_judged_on_the_servers_clock(
    arm: Served, skew_s: int, tmp_path: Path
) -> None:
    """A client on a machine whose clock is 5 s behind or ahead (libfaketime; its DDS
    without shared memory, as across a network): a stop and a
    release, each by it (the stop by the service and the topic, the release on the topic,
    as `Client.stop` and `Client.release` send them) or by a client
    whose clock is right, are taken in the order they were sent (a release sent before its
    stop and come after it, too), and its move sent after the release runs."""
    assert FAKETIME_LIB.exists(), "libfaketime: `make faketime` installs it"
    arm.ready()
    profile = tmp_path / "another-machine.xml"
    profile.write_text(ANOTHER_MACHINE_DDS)
    env = {
        **os.environ,
        "LD_PRELOAD": str(FAKETIME_LIB),
        "FAKETIME": f"{skew_s:+d}s",
        # Its monotonic clock faked too, libfaketime 0.9.10's timed waits never end.
        "FAKETIME_DONT_FAKE_MONOTONIC": "1",
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile),
        # As the server's participant is told at its start, so that rmw_fastrtps adds no
        # transport of its own (`al5d.ros.workarounds.discovery_on_our_transports`).
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
    }
    errors = tmp_path / "skewed.err"
    skewed = subprocess.Popen(
        [sys.executable, "-c", SKEWED],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=errors.open("w"),
        text=True,
        env=env,
    )
    assert skewed.stdin is not None and skewed.stdout is not None
    out = Lines(skewed.stdout)

    def ask(word: str) -> str:
        assert skewed.stdin is not None
        skewed.stdin.write(word + "\n")
        skewed.stdin.flush()
        return out.wait_for(f"{word.split()[0]}:", CMD_S)

    lane = Remote.connect(where.path(), name="right-clock")
    try:
        try:
            said = float(out.wait_for("clock", CMD_S).split()[1])
        except AssertionError as e:
            # Seen once in a CI run beside two busy loops: no word in 60 s, nothing on its
            # stderr. Where it waits, for the next reader.
            code = skewed.poll()
            raise AssertionError(
                f"the skewed client (exit {code}) said no clock: {e}\nits stderr:\n"
                f"{errors.read_text()[-4000:]}\nits stacks:\n"
                f"{stacks(skewed.pid) if code is None else '(ended)'}"
            ) from e
        assert abs(said - time.time() - skew_s) < 2.5, said  # its clock is off indeed
        assert shared_memory_mapped(skewed.pid) == []
        # A stop by a client whose clock is right, then a release by the skewed one.
        assert lane.execute(ins.Instruction(ins.Kind.STOP), CMD_S).ok
        wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped")
        time.sleep(0.2)
        assert ": done" in ask("release")
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "released")
        # A stop by the skewed client, then a release by the right one; five times for a
        # clock behind, as either reader of the topic may take the stop first (the node
        # `al5d` alone put a stop on the server's clock: on the code before, one try failed
        # in 2 of 4 runs, five in 5 of 5).
        for _ in range(5 if skew_s < 0 else 1):
            before_stop = time.time_ns()
            time.sleep(0.5)
            assert "]: done" in ask("stop")
            wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped")
            # A release the right client sent before that stop, held up until after it:
            # refused (the stop taken at its sender's clock 5 s behind was undone by it).
            held = lane.execute(ins.Instruction(ins.Kind.RELEASE, sent_ns=before_stop), CMD_S)
            assert held.result is ins.Result.REFUSED, held
            assert "sent before the stop" in held.reason, held
            time.sleep(0.2)
            released = lane.execute(ins.Instruction(ins.Kind.RELEASE), CMD_S)
            assert released.ok, released
            wait_until(lambda: arm.states[-1] == "ready", CMD_S, "released")
        # The skewed client's move, sent after that release, runs.
        assert ": done" in ask(f"move base={10 + skew_s} time=300")
    finally:
        lane.close()
        # Its end closes the client, and libfaketime removes its files in /dev/shm, which
        # a kill leaves behind.
        skewed.stdin.close()
        try:
            skewed.wait(CMD_S)
        except subprocess.TimeoutExpired:
            skewed.kill()
            skewed.wait(10)


def test_a_copy_of_a_clients_stop_that_comes_after_another_clients_release_is_that_stop(
    arm: Served,
) -> None:
    """A client sends its stop again until it is answered (`Client.stop`: `<stop>~<n>`,
    naming itself); a copy still on its way when another client releases the arm is the
    stop obeyed already: answered under its own id, and the arm neither halted nor locked
    again (it was: the move behind it was refused as sent while the arm was locked). A
    stop of another id from the same client is a new stop, and so is a stop sent again
    under an id that marks no copy."""
    arm.ready()

    def stop(ident: str) -> None:
        msg = ArmInstruction(instruction="stop", id=ident, client="laptop-copies")
        arm.peer.pub.publish(msg)

    before = arm.stops()
    stop("copied-stop~1")
    assert arm.peer.result("copied-stop~1", CMD_S).outcome == "done"
    wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped")
    wait_until(lambda: arm.stops() >= before + 6, CMD_S, "its six STOPs on the board")
    stops = arm.stops()
    assert arm.peer.trigger("release").success  # another client's release
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "released")
    stop("copied-stop~2")  # a copy of the same stop, late
    arm.peer.send("after-copy", "move", 300, base=12)  # behind the copy, in order
    copy = arm.peer.result("copied-stop~2", CMD_S)
    assert copy.outcome == "done", copy
    moved = arm.peer.result("after-copy", CMD_S)
    assert moved.outcome == "done", moved
    # The state topic and the result topic are two writers: "ready" may come after "done".
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready after the move")
    assert arm.stops() == stops
    stop("new-stop~1")  # a new stop of the same client: obeyed
    assert arm.peer.result("new-stop~1", CMD_S).outcome == "done"
    wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped again")
    wait_until(lambda: arm.stops() >= stops + 6, CMD_S, "its six STOPs on the board")
    # A stop sent again under the same id (no copy's mark) is a stop again.
    assert arm.peer.trigger("release").success
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "released again")
    stop("new-stop")
    wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped by a plain id")
    assert arm.peer.trigger("release").success
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "released once more")
    stop("new-stop")
    wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped by the same id again")


def action_client(arm: Served, env: dict[str, str]) -> subprocess.Popen[str]:
    """A client of FollowJointTrajectory as MoveIt is (`al5d_rig.actionclient`) whose goal
    takes the base from where it is to -80 deg over 12 s."""
    joints = ["base", "shoulder", "elbow", "wrist", "wrist_rotate"]
    here = arm.emu.servo_degrees()
    start, end = ({**here, "base": b} for b in (here["base"], -80.0))
    urdf = arm.config.model.to_urdf
    points = [(s, [urdf(d)[j] for j in joints]) for s, d in ((0, start), (12, end))]
    return subprocess.Popen(
        actionclient.argv(arm.peer.names.follow_joint_trajectory, joints, points),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, **env},
    )


@pytest.mark.parametrize("how", ["exits", "is killed"])
def test_a_trajectory_goal_whose_every_client_has_left_is_halted(
    arm: Served, tmp_path: Path, how: str
) -> None:
    """MoveIt's way has no lease of ours: its goals are halted once no client of the action
    is left in the ROS graph, a recording's reader of the action's status left out. A
    client that exits leaves the graph at once; one killed, when DDS ends its lease (here
    2 s). On the code before, the arm went on to -80 deg."""
    arm.ready()
    begun = len(arm.proc.err.drain(0))  # the server's log before this test
    recorder = Proc("record", str(tmp_path / "recorded.mcap"))
    profile = tmp_path / "short_lease.xml"
    profile.write_text(actionclient.short_lease_profile(DOCS))
    client = action_client(arm, {"FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)})
    try:
        recorder.out.wait_for("recording to", CMD_S)
        status = f"{arm.peer.names.follow_joint_trajectory}/_action/status"

        def readers() -> set[str]:
            return {r.node_name for r in arm.peer.node.get_subscriptions_info_by_topic(status)}

        wait_until(lambda: "al5d_recorder" in readers(), CMD_S, "the recording's reader")
        assert client.stdout is not None and client.stdin is not None
        assert said(client.stdout) == "accepted"
        assert said(client.stdout) == "feedback"  # the server has matched its readers
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        # The graph as the peer sees it stands for the server's: the client's reader there.
        wait_until(lambda: actionclient.NODE in readers(), CMD_S, "the client's reader")
        time.sleep(1.0)
        # Not before it left (an order, not a time: nothing of the kind in the log yet).
        assert not [line for line in arm.proc.err.drain(0)[begun:] if NO_CLIENT_LEFT in line]
        if how == "exits":
            client.stdin.write("\n")
            client.stdin.flush()
            assert client.wait(CMD_S) == 0
        else:
            client.kill()
        halted = arm.proc.err.wait_for("lost contact with every client of the action", CMD_S)
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready: halted, not locked")
        base = arm.emu.servo_degrees()["base"]
    finally:
        client.kill()
        client.wait(10)
        recorder.popen.send_signal(signal.SIGINT)  # ended: its reader leaves the graph at once
        recorder.wait(20)
        recorder.kill()
    assert "follow_joint_trajectory goals" in halted, halted
    assert base > -70, base  # halted well before the goal's end (12 s), not locked
