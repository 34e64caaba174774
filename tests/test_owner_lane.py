"""The local lane: clients on this machine reach the owner of the board on a Unix socket of
the user's, without ROS 2 discovery; a client that goes without a word leaves nothing
moving; Ctrl-C cancels what a command sent; bad lines get clear errors and lose nothing."""

from __future__ import annotations

import json
import os
import signal
import socket
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from al5d import exits
from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.owner import quick, where
from al5d.owner.client import Remote
from al5d_rig.proc import AL5D, Proc, patient_config, said
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Served, served

CMD_S = 60.0


@pytest.fixture(scope="module")
def arm(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    with served(config, tmp_path_factory.mktemp("lane"), "al5d_lane_peer") as s:
        yield s


def halted_on_its_way(arm: Served, target: float) -> bool:
    time.sleep(0.3)
    return abs(arm.emu.servo_degrees()["base"] - target) > 5


def test_the_lane_is_the_users_alone(arm: Served) -> None:
    path = where.path()
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_ISSOCK(path.stat().st_mode)


def test_each_namespace_has_a_lane_of_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two namespaces never share a lane, and the servers found by their lanes are named as
    they serve (an outside try: with '_' for '/', `--namespace lab_left` reached the arm
    of `/lab/left`, moved it and stopped it)."""
    monkeypatch.setenv("AL5D_RUNTIME_DIR", str(tmp_path))
    spaces = ["", "lab/left", "lab_left", "/lab/left/", "left", "lab/left_arm", "lab_left/arm"]
    lanes = {where.path(n) for n in spaces}
    assert len(lanes) == len(spaces) - 1  # "/lab/left/" is "lab/left"
    assert where.path("x", "7") != where.path("x", "8")
    listening = []
    for name in ["", "lab/left", "lab_left", "lab_left/arm"]:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.bind(str(where.path(name)))
        sock.listen()
        listening.append(sock)
    try:
        assert where.namespaces() == ["/", "/lab/left", "/lab_left", "/lab_left/arm"]
    finally:
        for sock in listening:
            sock.close()


def test_send_goes_by_the_lane_and_stop_needs_no_import(arm: Served) -> None:
    arm.ready()
    moved = Proc("send", "move", "base=20", "time=300")
    assert moved.wait(CMD_S) == 0
    assert any(": done" in line for line in moved.out.drain())
    # A stop from a bare interpreter: none of al5d's heavy imports (a -X importtime trace),
    # typed alone or with words after it (read as a stop whatever follows).
    env = {**os.environ, "PYTHONPROFILEIMPORTTIME": "1"}
    for words in (["stop"], ["stop", "now"]):
        done = subprocess.run([AL5D, "send", *words], capture_output=True, text=True, env=env)
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip().endswith("done (by the local lane)")
        lines = done.stderr.splitlines()
        imported = {line.split("|")[-1].strip() for line in lines if "|" in line}
        assert not imported & {"rclpy", "numpy", "pydantic", "al5d.arm.config", "serial"}, imported
        wait_until(lambda: arm.states[-1] == "stopped", CMD_S, "stopped")
        assert Proc("send", "release").wait(CMD_S) == 0
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready")


@pytest.mark.parametrize(
    ("argv", "asked"),
    [
        (["send", "stop"], ("", 10.0)),
        (["send", "STOP", "now", "--timeout", "3"], ("", 3.0)),
        (["send", "--namespace", "left", "stop", "--wait", "5"], ("left", 10.0)),
        (["send", "Stop!"], ("", 10.0)),
        (["send", "-n", "left", "stop"], None),  # not an option of `al5d send`: it says so
        (["send", "move", "base=3"], None),
        (["send", "now", "stop"], None),  # not a stop in the grammar: the full way says why
        (["send", "stop", "--via", "ros"], None),
        (["send", "stop", "--timeout"], None),
        (["send", "stop", "--timeout", "soon"], None),
        (["run", "stop"], None),
    ],
)
def test_the_fast_stop_takes_what_the_grammar_reads_as_a_stop(
    argv: list[str], asked: tuple[str, float] | None
) -> None:
    assert quick.parse(argv) == asked


@pytest.mark.parametrize(
    "word", ["stop", "STOP", "stop!", "Stop.", "stop!!", "stop,", "stopp", "sto", "!stop", "stop-"]
)
def test_the_fast_stop_and_the_grammar_read_the_same_words_as_a_stop(word: str) -> None:
    # The fast path imports nothing of the grammar's: the two must agree all the same.
    assert (quick.parse(["send", word]) is not None) is ins.is_stop(word)


def test_ctrl_c_on_send_cancels_what_it_sent(arm: Served) -> None:
    arm.ready()
    send = Proc("send", "move", "base=80", "time=4000")
    wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
    send.popen.send_signal(signal.SIGINT)
    assert send.wait(CMD_S) == exits.INTERRUPTED
    out = send.out.drain()
    assert any(line.endswith("cancelled (Ctrl-C)") for line in out), out
    assert not any("Traceback" in line for line in send.err.drain())
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready: halted, not locked")
    assert halted_on_its_way(arm, 80)


def test_ctrl_c_before_a_server_is_found_says_nothing_was_sent() -> None:
    """No server answers yet: Ctrl-C says that nothing was sent (an outside try was told
    that ROS 2 has no cancel by id and that the move "may still run")."""
    send = Proc("send", "--verbose", "--namespace", "nobody_here", "--wait", "60", "ready")
    send.err.wait_for("ROS started in", CMD_S)
    time.sleep(0.5)  # looking for the server
    send.popen.send_signal(signal.SIGINT)
    assert send.wait(CMD_S) == exits.INTERRUPTED
    out = send.out.drain()
    assert any(line.endswith("Ctrl-C before it was sent: nothing sent") for line in out), out
    assert not any("may still run" in line for line in out), out


@pytest.mark.parametrize("via", ["lane", "ros"])
def test_a_move_its_sender_gave_up_on_is_halted_and_said_so(arm: Served, via: str) -> None:
    """`al5d send --timeout 1` on a 4 s move: the server halts it where it is when its sender
    gives up (no lock), and the command says so: the outcome, not a bare timeout."""
    arm.ready()
    send = Proc("send", "move", "base=-80", "time=4000", "--timeout", "1", "--via", via)
    assert send.wait(CMD_S) == exits.NOT_DONE
    out = send.out.drain()
    assert any(
        line.endswith(
            "cancelled: its sender waited 1000 ms for an outcome and has given up on it: halted"
        )
        for line in out
    ), out
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready: halted, not locked")
    assert halted_on_its_way(arm, -80)


def test_ctrl_c_on_run_cancels_the_line_running_and_those_in_the_background(
    arm: Served, tmp_path: Path
) -> None:
    arm.ready()
    seq = tmp_path / "long.seq"
    seq.write_text("move elbow=40 time=4000 &\nmove base=-80 time=4000\n")
    run = Proc("run", str(seq))
    wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
    time.sleep(0.3)
    run.popen.send_signal(signal.SIGINT)
    assert run.wait(CMD_S) == exits.INTERRUPTED
    out = run.out.drain()
    # Each said once: the line in the background by its outcome's line, as it came; the
    # line waited for by the command's own.
    cancelled = [line for line in out if "Ctrl-C" in line]
    assert len(cancelled) == 2, out
    assert cancelled[0].startswith("move [") and "cancelled by Ctrl-C" in cancelled[0], out
    assert cancelled[1].endswith("cancelled (Ctrl-C)"), out
    assert len({line.split("]")[0] for line in cancelled}) == 2, out
    wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready")


def test_ctrl_c_on_run_in_a_wait_with_nothing_running_says_where_the_sequence_ended(
    arm: Served, tmp_path: Path
) -> None:
    """An outside try: Ctrl-C in a `wait` with nothing running said nothing (exit 130), the
    rest of the file silently not run."""
    arm.ready()
    seq = tmp_path / "waits.seq"
    seq.write_text("ready\nwait 30000\nmove base=30\npark\n")
    run = Proc("run", str(seq))
    run.out.wait_for("wait 30000 ms", CMD_S)
    run.popen.send_signal(signal.SIGINT)
    assert run.wait(CMD_S) == exits.INTERRUPTED
    out = run.out.drain()
    assert out[-1] == "Ctrl-C: the sequence ends here: the 2 steps after it not sent", out
    assert not any(line.startswith("> move") for line in out), out


@pytest.mark.parametrize("command", ["send", "run"])
def test_two_quick_ctrl_cs_do_not_cut_the_cancel(arm: Served, tmp_path: Path, command: str) -> None:
    """A user who presses Ctrl-C twice: the second press, a moment after the first, does not
    cut the cancel the first started (seen: 2 of 5 `al5d send`s and 3 of 8 `al5d run`s left
    their moves running, saying only "al5d: interrupted"). Two signals at once are one to
    Python (its handler runs once for both): the second comes a few milliseconds after the
    first, later in each round, to land at a different point of the cancel."""
    seq = tmp_path / "moves.seq"
    for after_s in (0.001, 0.003, 0.006, 0.01, 0.02, 0.04):
        arm.ready()
        # The side away from where the base is: halted on its way, it is far from there.
        target = -60 if arm.emu.servo_degrees()["base"] > 0 else 60
        seq.write_text(
            f"move elbow=60 time=4000 &\nmove wrist=60 time=4000 &\nmove base={target} time=4000\n"
        )
        send = ("send", "move", f"base={target}", "time=4000")
        proc = Proc(*send) if command == "send" else Proc("run", str(seq))
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        time.sleep(0.3)
        proc.popen.send_signal(signal.SIGINT)
        time.sleep(after_s)
        proc.popen.send_signal(signal.SIGINT)
        code = proc.wait(CMD_S)
        out, err = proc.out.drain(), proc.err.drain()
        assert code == exits.INTERRUPTED, (after_s, code, out, err)
        assert not any("interrupted" in line for line in err), (out, err)
        assert any(line.endswith("cancelled (Ctrl-C)") for line in out), (out, err)
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready: halted, not locked")
        assert halted_on_its_way(arm, target)


def test_a_client_that_sends_and_closes_at_once_leaves_its_move_running(arm: Served) -> None:
    """Leaving the `with` block right after a send never stops the arm (docs/server.md): the
    client says `bye` and closes while the owner may be writing it the move's news, a write
    that fails before the `bye` is read (seen: 2 of 6 moves halted, "its connection
    failed"). Ten rounds, each move then done to its end."""
    from al5d.ros.client import Client

    arm.ready()
    for k in range(10):
        target = 30.0 if k % 2 else -30.0
        seen = len(arm.states)
        with Client(local=True) as client:
            client.send(f"move base={target:g} time=400")
        wait_until(
            lambda seen=seen: "moving" in arm.states[seen:] and arm.states[-1] == "ready",
            CMD_S,
            "moved, then ready",
        )
        # The board (a thread of this busy process) may have read the move a little after the
        # server wrote it, and its servo arrives that much later (a CI run beside two busy
        # loops: 2.1 degrees short as the server said ready); a halted one never arrives.
        wait_until(
            lambda target=target: abs(arm.emu.servo_degrees()["base"] - target) < 1,
            CMD_S,
            f"round {k}: the base at {target:g}, not halted",
        )


def test_a_clients_stop_does_not_wait_behind_what_its_lane_carries(arm: Served) -> None:
    """A second reading: the Python client's stop went on its lane, behind another
    thread's send (a trajectory's megabyte, written under the lane's lock) and behind its
    bytes in the stream. Here that send is held for the whole of the stop: the stop goes
    on a connection of its own, as the web view's and `al5d send stop`'s do."""
    from al5d.ros.client import Client

    arm.ready()
    with Client(local=True) as client:
        assert client.lane is not None
        client.send("move base=40 time=3000")
        wait_until(lambda: "moving" in arm.states[-1:], CMD_S, "moving")
        with client.lane._send_lock:  # another thread's send, under way
            stop = client.stop(timeout=CMD_S)
        assert stop.ok and stop.via == "the local lane", stop
        assert client.release(timeout=CMD_S).ok
    assert halted_on_its_way(arm, 40.0)


def test_a_client_whose_server_was_started_again_reaches_the_new_one() -> None:
    """A client on the lane whose server ended and was started again (killed, then run
    again in the same namespace): its stop, asked as the new server starts, waits for it
    and reaches it, and so do its release and move; one asked while none was there says
    it was not sent. An outside try: the client stayed dead, its stop refused "the lane
    to the owner is closed" for as long as it ran."""
    from al5d.ros.client import Client, NoServer

    namespace = "lane_again"
    first = Proc("serve", "--namespace", namespace, "--config", patient_config())
    again: Proc | None = None
    try:
        first.err.wait_for("STATE: ready", 60)
        with Client(namespace, local=True, wait_s=1) as client:
            assert client.execute("move base=10 time=100", 30).ok
            first.popen.send_signal(signal.SIGKILL)
            first.wait(30)
            wait_until(lambda: client.lane is not None and client.lane.closed.is_set(), 30)
            with pytest.raises(NoServer, match="stop: not sent"):
                client.stop(timeout=1)
            again = Proc("serve", "--namespace", namespace, "--config", patient_config())
            stop = client.stop(timeout=60)  # asked before the new server's lane is there
            assert stop.ok and stop.via.startswith("the local lane"), stop
            # The client's own lane is open again, to the new server (a second reading: a
            # stop on a connection of its own left it closed, and the reads on the old one).
            client.wait_for_state("stopped", 30)
            assert client.read().locked
            assert client.release(timeout=30).ok
            assert client.execute("move base=-10 time=100", 30).ok
            assert client.read().state == "ready"
        again.popen.send_signal(signal.SIGTERM)
        assert again.wait(60) == 0
    finally:
        first.kill()
        if again is not None:
            again.kill()


@pytest.mark.parametrize("how", ["killed", "hung"])
def test_a_client_killed_or_hung_mid_move_leaves_nothing_moving(arm: Served, how: str) -> None:
    """A client that goes without a word (killed, or hung up) is a lost client: its motion is
    halted where it is and its waiting moves cancelled, with the reason. A leased one that
    hangs (SIGSTOP: its lane stays open and says nothing) is lost when its lease runs out."""
    arm.ready()
    script = (
        "import time\n"
        "from al5d.arm import instruction as ins\n"
        "from al5d.owner import where\n"
        "from al5d.owner.client import Remote\n"
        "arm = Remote.connect(where.path(), lease=True)\n"
        "arm.submit(ins.move(base=-80, time_ms=4000, id='lost-1'))\n"
        "arm.submit(ins.move(base=80, time_ms=4000, id='lost-2'))\n"
        "print('sent', flush=True)\n"
        "time.sleep(60)\n"
    )
    client = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert client.stdout is not None and said(client.stdout) == "sent"
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        time.sleep(0.3)
        if how == "killed":
            client.kill()
            client.wait(10)
        else:
            client.send_signal(signal.SIGSTOP)
        results = arm.peer.results_now
        wait_until(lambda: {"lost-1", "lost-2"} <= set(results()), CMD_S, "their outcomes")
        for ident in ("lost-1", "lost-2"):
            outcome = results()[ident]
            assert outcome.outcome == "cancelled" and "lost contact with the client" in (
                outcome.reason
            ), outcome
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "ready")
        assert halted_on_its_way(arm, -80)
    finally:
        client.kill()
        client.wait(10)


#: A client over the lane whose move is cut by its own stop (SIGSTOP by the test, for
#: longer than its lease), then asks again.
STOPPED_CLIENT = """
from al5d.ros.client import Client, LaneLost
c = Client(wait_s=30, local=True)
print("ready", flush=True)
try:
    c.execute("move base=70 time=8000", timeout=60)
except LaneLost as e:
    print(f"lost: {e}", flush=True)
print(f"again: {c.state()}", flush=True)
c.close()
"""


def test_a_client_stopped_for_longer_than_its_lease_is_told_why_its_lane_closed(
    arm: Served,
) -> None:
    """An outside try: a client stopped (Ctrl-Z) for longer than its lease and resumed said
    that the server had ended ("the lane to the owner closed: whether it ran is unknown",
    then "the server's lane had closed (the server ended)"), where the server had taken
    it for lost and halted its move. Now the owner says why as it closes the lane, and
    the client says that."""
    arm.ready()
    client = subprocess.Popen(
        [sys.executable, "-c", STOPPED_CLIENT],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert client.stdout is not None and said(client.stdout) == "ready"
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        client.send_signal(signal.SIGSTOP)
        wait_until(lambda: arm.states[-1] == "ready", CMD_S, "halted as a lost client's")
        client.send_signal(signal.SIGCONT)
        lost = said(client.stdout)
        assert "the server took this client for lost (nothing heard from it" in lost, lost
        assert "halts what this client commanded" in lost and "unknown" not in lost, lost
        assert said(client.stdout) == "again: ready"
        _, err = client.communicate(timeout=CMD_S)
        assert "the server had taken this client for lost" in err, err
        assert "the server ended" not in err, err
        assert client.returncode == 0
    finally:
        client.kill()
        client.wait(10)


def lane_socket() -> socket.socket:
    """A raw connection to the server's lane: the lines a client of any language writes."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(str(where.path()))
    sock.settimeout(CMD_S)
    return sock


def answers(sock: socket.socket, *refs: int) -> tuple[dict[object, dict[str, object]], list[str]]:
    """What the lane said until it answered each of `refs`: the answers by ref (an outcome,
    or an error naming its ref), and every error's words."""
    got: dict[object, dict[str, object]] = {}
    errors: list[str] = []
    buf = b""
    while not all(ref in got for ref in refs):
        buf += sock.recv(65536)
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            message = json.loads(line)
            if message["op"] == "error":
                errors.append(str(message["error"]))
                if message.get("ref") is not None:
                    got[message["ref"]] = message
            elif message["op"] == "outcome":
                got[message["ref"]] = message
    return got, errors


def test_a_stop_on_the_lane_is_obeyed_whatever_it_carries(arm: Served) -> None:
    """As over ROS 2: a stop that carries joints, a time or a preset is a stop, never
    refused for them (a release or a shutdown so carrying is refused: the test below)."""
    arm.ready()
    with lane_socket() as sock:
        sock.sendall(
            b'{"op": "ask", "ref": 1, "instr": {"kind": "move", "joints": [["base", 40]], '
            b'"time_ms": 3000}}\n'
        )
        wait_until(lambda: "moving" in arm.states[-1:], CMD_S, "moving")
        sock.sendall(
            b'{"op": "ask", "ref": 2, "instr": {"kind": "stop", "joints": [["base", 3]], '
            b'"time_ms": 500, "preset": "park"}}\n'
        )
        got, _ = answers(sock, 1, 2)
        moved, stopped = got[1]["outcome"], got[2]["outcome"]
        assert isinstance(stopped, dict) and stopped["result"] == "done", stopped
        assert isinstance(moved, dict) and moved["result"] == "cancelled", moved
        assert "stop" in str(moved["reason"]), moved
        sock.sendall(b'{"op": "ask", "ref": 3, "instr": {"kind": "release"}}\n')
        released = answers(sock, 3)[0][3]["outcome"]
        assert isinstance(released, dict) and released["result"] == "done", released
    assert halted_on_its_way(arm, 40.0)


def test_bad_lines_get_clear_errors_and_the_lane_goes_on(arm: Served) -> None:
    arm.ready()
    sock = lane_socket()
    lines = [
        b"not json\n",
        b"[1, 2]\n",
        b'{"op": "frobnicate", "ref": 1}\n',
        b'{"op": "ask", "ref": 2, "instr": {"kind": "wave"}}\n',
        b'{"op": "ask", "ref": 3, "instr": {"kind": "move", "joints": [["base", "x"]]}}\n',
        b'{"op": "ask", "ref": 4, "instr": {"kind": "move", "joints": [["base", 500]]}}\n',
        b'{"op": "ask", "ref": 6, "instr": {"kind": "move", "wait_ms": -1}}\n',
        b'{"op": "ask", "ref": 7, "instr": {"kind": "move", "wait_ms": 4294967296}}\n',
        b'{"op": "ask", "ref": 8, "instr": {"kind": "move", "sent_ns": -5, "wait_ms": 9}}\n',
        b'{"op": "ask", "ref": 9, "instr": {"kind": "release", "time_ms": 500}}\n',
        b'{"op": "ask", "ref": 10, "instr": {"kind": "shutdown", "joints": [["base", 3]]}}\n',
        b'{"op": "ask", "ref": 11, "instr": {"kind": "preset", "preset": "park", '
        b'"joints": [["base", 3]]}}\n',
        b'{"op": "bye", "ref": 12, "left_by": 5}\n',
        b'{"op": "ask", "ref": 13, "instr": {"kind": "trajectory", '
        b'"start_ns": 9223372036854775808}}\n',
        b'{"op": "ask", "ref": 5, "instr": {"kind": "move", "joints": [["base", 3]]}}\n',
    ]
    sock.sendall(b"".join(lines))
    got, errors = answers(sock, 5)
    sock.close()
    assert any(e.startswith("not JSON") for e in errors), errors
    assert any('not an object with an "op"' in e for e in errors), errors
    assert "no op 'frobnicate'" in str(got[1]["error"])
    assert "no kind 'wave'" in str(got[2]["error"])
    assert "'x' is not a number" in str(got[3]["error"])
    for ref in (6, 7):  # a number past a message's uint32 failed the owner's step
        assert "wait_ms is how long its sender waits" in str(got[ref]["error"])
    assert "sent_ns is a time in ns since 1970" in str(got[8]["error"])
    assert "start_ns is a time in ns since 1970" in str(got[13]["error"])
    assert "bye: left_by must be text" in str(got[12]["error"])
    # As over ROS 2: what the word does not take is refused, not dropped without a word.
    for ref, reason in (
        (9, "release takes no joints or time (ambiguous)"),
        (10, "shutdown takes no joints or time (ambiguous)"),
        (11, "park is a preset: it takes no joints (ambiguous)"),
    ):
        refused = got[ref]["outcome"]
        assert isinstance(refused, dict) and refused["result"] == "refused", refused
        assert reason in str(refused["reason"]), refused
    four, five = got[4]["outcome"], got[5]["outcome"]
    assert isinstance(four, dict) and four["result"] == "refused", four
    assert "outside the range" in str(four["reason"])
    assert isinstance(five, dict) and five["result"] == "done", five
    assert arm.proc.popen.poll() is None


def test_a_remote_reads_the_server_and_hears_what_happens(arm: Served) -> None:
    arm.ready()
    watch = ("state", "outcomes", "motion", "pose")
    with Remote.connect(where.path(), watch=watch) as remote:
        assert remote.config.joints.keys() == arm.config.joints.keys()
        told: list[str] = []
        remote.outcome_listeners.append(lambda o: told.append(o.id))
        outcome = remote.execute(ins.move(base=10, time_ms=200, id="remote-1"), CMD_S)
        assert outcome.ok
        wait_until(lambda: "remote-1" in told, CMD_S, "the outcome told")
        assert remote.positions()["base"] == pytest.approx(10, abs=0.5)
        assert remote.cancel("no-such-move") is False
