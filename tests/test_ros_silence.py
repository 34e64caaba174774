"""A client whose server goes silent (frozen whole: as a link lost) or away (killed: its lane
closed) says so, and says it right: a stop unanswered then blames the link, not discovery;
a line running in the background is said lost at once, whatever the command is doing.

Each test has a server of its own, frozen or killed: the other files' servers are shared.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from al5d import exits
from al5d.arm.config import ArmConfig
from al5d.owner import where
from al5d.ros.answers import NoOutcome
from al5d.ros.client import Client
from al5d.ros.rosway import LOST_S, silence_warning
from al5d_rig.proc import (
    AL5D,
    Lines,
    Tty,
    dies_with_parent,
    family,
    freeze,
    kill_all,
    patient_config,
)
from al5d_rig.rospeer import wait_until
from al5d_rig.served import served

SCRIPT_S = 90.0
STATE_S = 30.0


def talking(args: list[str]) -> tuple[subprocess.Popen[str], Lines, Lines]:
    """A process of `args` that the test writes to; its lines out and its lines on stderr."""
    proc = subprocess.Popen(
        args,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=dies_with_parent,
    )
    assert proc.stdout is not None and proc.stderr is not None
    return proc, Lines(proc.stdout), Lines(proc.stderr)


@contextlib.contextmanager
def gone(server: list[int], via: str) -> Iterator[None]:
    """The server's processes (`family`) frozen whole, as a lost link is to a ROS client
    (`via` "ros"), thawed on the way out; or killed, its lane closed (`via` "lane")."""
    if via != "ros":
        kill_all(server)
        yield
        return
    # A process of the family that has ended since it was listed (seen beside two busy
    # loops: `ProcessLookupError` at the freeze) has nothing left to freeze.
    for pid in server:
        with contextlib.suppress(ProcessLookupError, FileNotFoundError):  # its /proc gone
            freeze(pid)
    try:
        yield
    finally:
        for pid in server:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)


@contextlib.contextmanager
def stopped(pid: int) -> Iterator[list[float]]:
    """Process `pid` stopped (SIGSTOP) for the block, resumed on the way out; for how long
    (s), in the list yielded once it is over."""
    held: list[float] = []
    freeze(pid)
    start = time.monotonic()
    try:
        yield held
    finally:
        os.kill(pid, signal.SIGCONT)
        held.append(time.monotonic() - start)


#: The client's WARNING of a silence, with the seconds it says.
SILENCE_SAID = re.compile(r"no sign of the server for (\d+\.\d) s")


def test_a_silence_is_said_before_the_client_gives_up_even_when_it_first_looks_late() -> None:
    """The warning comes once the silence passes 1 s; a waiting thread that a loaded host
    held back past the whole window (lost after 1.5 s, first look at 2.3 s) still says it,
    with the silence as it is and that it gives up now, not in a negative time."""
    assert silence_warning(0.9, 1.5) is None
    in_time = silence_warning(1.2, 1.5)
    assert in_time is not None and "for 1.2 s" in in_time and "in 0.3 s" in in_time, in_time
    late = silence_warning(2.3, 1.5)
    assert late is not None and "for 2.3 s" in late, late
    assert "gives up on what it waits for now" in late and "-" not in late, late
    # A short lease (0.3 s, lost after 0.8 s): said after its margin, not after 1 s.
    assert silence_warning(0.25, 0.8) is None
    assert silence_warning(0.5, 0.8) is not None


def said_silence(line: str) -> float:
    """The seconds of silence that the client's WARNING in `line` says."""
    found = SILENCE_SAID.search(line)
    assert found is not None, line
    return float(found.group(1))


SILENT = """
import sys
from al5d.ros.client import Client
c = Client(wait_s=30, local=False)
print(c.execute("ready", timeout=60), flush=True)
sys.stdin.readline()  # the server is silent now
print(c.stop(timeout=30), flush=True)
c.close()
"""


def test_a_stop_unanswered_while_the_server_is_silent_says_the_link_may_be_lost(
    config: ArmConfig, tmp_path: Path
) -> None:
    """A client that has heard its server and then nothing for seconds (a link lost; here
    the server frozen whole) says of a stop unanswered for 0.8 s that nothing has been
    heard from the server, not that discovery has not found it; the server, back, obeys it."""
    with served(config, tmp_path, "al5d_silent_peer") as arm:
        script = tmp_path / "silent.py"
        script.write_text(SILENT)
        client, out, err = talking([sys.executable, str(script)])
        assert client.stdin is not None
        server = family(arm.proc.popen.pid)
        try:
            out.wait_for(": done", SCRIPT_S)
            for pid in server:
                freeze(pid)
            try:
                time.sleep(2.0)  # the client has heard nothing for 1.5 s: lost contact
                client.stdin.write("stop\n")
                client.stdin.flush()
                said = err.wait_for("]: no answer in 0.8 s", SCRIPT_S)
            finally:
                for pid in server:
                    os.kill(pid, signal.SIGCONT)
            assert re.search(
                r"nothing heard from the server for \d+\.\d s: the link may be lost", said
            ), said
            assert "discovery" not in said and "not found" not in said, said
            # Its answer names the stop its warning named (it named none).
            warned = re.search(r"stop (\[[^\]]+\]): no answer", said)
            assert warned is not None, said
            answer = out.wait_for("stop [", SCRIPT_S)
            assert answer.startswith(f"stop {warned.group(1)}: done"), (answer, said)
            wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
            assert client.wait(SCRIPT_S) == 0
            assert not [line for line in err.all if "Traceback" in line], err.all
        finally:
            client.kill()
            client.wait(10)


GIVES_UP = """
import sys
from al5d.ros.client import Client, NoOutcome
c = Client(wait_s=30, local=sys.argv[1] == "lane")
print(c.execute("ready", timeout=60), flush=True)
sys.stdin.readline()  # the server is silent now
try:
    print(c.stop(timeout=2), flush=True)
except NoOutcome as e:
    print(f"gave up: {e}", flush=True)
sys.stdin.readline()  # the server is back
c.close()
"""


@pytest.mark.parametrize("via", ["ros", "lane"])
def test_a_stop_given_up_on_and_obeyed_later_is_said(
    config: ArmConfig, tmp_path: Path, via: str
) -> None:
    """A stop asked while the server is silent (here frozen whole; an outside try: a link
    cut), given up on after its timeout, is obeyed once the server hears it, however late:
    the client that gave up says so when the answer comes, and that it locked the arm (the
    outside try: the arm locked when the link came back, and nobody was told; over the
    local lane too, of a frozen server). `al5d send stop`, which ends when it gives up,
    says that the server obeys it however late."""
    with served(config, tmp_path, f"al5d_late_stop_{via}_peer") as arm:
        script = tmp_path / "gives_up.py"
        script.write_text(GIVES_UP)
        client, out, err = talking([sys.executable, str(script), via])
        assert client.stdin is not None
        server = family(arm.proc.popen.pid)
        send: subprocess.Popen[str] | None = None
        try:
            out.wait_for(": done", SCRIPT_S)
            with gone(server, "ros"):
                client.stdin.write("stop\n")
                client.stdin.flush()
                said = out.wait_for("gave up: ", SCRIPT_S)
                if via == "lane":
                    send, send_out, _ = talking([AL5D, "send", "stop", "--timeout", "2"])
                    ended = send_out.wait_for("stop [", SCRIPT_S)
                    assert "the server obeys a stop however late it takes it" in ended, ended
                    assert send.wait(SCRIPT_S) == 1
            assert "whether the server obeyed is unknown" in said, said
            late = err.wait_for("answered after this client gave up on it", SCRIPT_S)
            assert "the server obeyed it, which locked the arm until a release" in late, late
            wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
            client.stdin.write("\n")
            client.stdin.flush()
            assert client.wait(SCRIPT_S) == 0
            assert not [line for line in err.all if "Traceback" in line], err.all
        finally:
            for proc in (client, send):
                if proc is not None:
                    proc.kill()
                    proc.wait(10)


@pytest.mark.parametrize(("command", "via"), [("shell", "ros"), ("shell", "lane"), ("run", "ros")])
def test_a_background_line_that_lost_its_server_is_said_at_once(
    config: ArmConfig, tmp_path: Path, command: str, via: str
) -> None:
    """A move running in the background, and nothing waited for: `al5d shell` at its prompt,
    `al5d run` in a ten-minute `wait`. The server goes silent (frozen: as a lost link) or
    its lane closes (killed): the command says so for the move at once, not when it next
    waits for something (the run ends, its last line not sent). What the server does
    with a lost client's move is `test_network.py`'s: a frozen server, thawed, may take the
    leases sent before the client went deaf for fresh ones."""
    seq = tmp_path / "long.seq"
    seq.write_text("ready\nmove base=60 time=8000 &\nwait 600000\npark\n")
    args = ["shell"] if command == "shell" else ["run", str(seq)]
    with served(config, tmp_path, f"al5d_prompt_peer_{command}_{via}") as arm:
        shell, out, err = talking([AL5D, *args, "--via", via])
        assert shell.stdin is not None
        server = family(arm.proc.popen.pid)
        try:
            shell.stdin.write("ready\nmove base=60 time=8000 &\n")
            shell.stdin.flush()
            out.wait_for("> move base=60 time=8000 &", SCRIPT_S)
            if command == "run":
                out.wait_for("wait 600000 ms", SCRIPT_S)
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            with gone(server, via):
                lost = out.wait_for("move [", SCRIPT_S)
            assert "whether it ran is unknown" in lost, lost
            if via == "ros":
                assert "lost contact with the server" in lost, lost
                assert said_silence(err.wait_for("no sign of", SCRIPT_S)) >= 1.0
            if command == "run":
                ended = out.wait_for("not done", SCRIPT_S)
                assert ended == "not done: the 1 step after it not sent", ended
            else:
                shell.stdin.write("exit\n")
                shell.stdin.flush()
            assert shell.wait(SCRIPT_S) == exits.NOT_DONE
            assert len([line for line in out.all if line.startswith("move [")]) == 1, out.all
        finally:
            shell.kill()
            shell.wait(10)


@pytest.mark.parametrize("via", ["ros", "lane"])
def test_a_run_in_a_wait_with_nothing_running_says_its_server_is_gone(
    config: ArmConfig, tmp_path: Path, via: str
) -> None:
    """`al5d run` in a ten-minute `wait`, nothing of its own running: the server goes silent
    (frozen) or its lane closes (killed). The run says so within a few seconds and ends, not
    done, its last line not sent (it said nothing until the wait was over)."""
    seq = tmp_path / "wait.seq"
    seq.write_text("ready\nwait 600000\npark\n")
    with served(config, tmp_path, f"al5d_wait_peer_{via}") as arm:
        run, out, err = talking([AL5D, "run", str(seq), "--via", via])
        server = family(arm.proc.popen.pid)
        try:
            out.wait_for("wait 600000 ms", SCRIPT_S)
            with gone(server, via):
                said = out.wait_for("nothing this command sent is running", SCRIPT_S)
            if via == "ros":
                assert said.startswith("lost contact with the server (nothing heard"), said
            else:
                assert said.startswith(
                    "the server on this machine closed its lane (it ended or restarted)"
                ), said
            ended = out.wait_for("not done", SCRIPT_S)
            assert ended == "not done: the 1 step after it not sent", ended
            assert run.wait(SCRIPT_S) == exits.NOT_DONE
            assert (
                len([line for line in out.all if "nothing this command sent is running" in line])
                == 1
            ), out.all
            assert not [line for line in err.all if "Traceback" in line], err.all
        finally:
            run.kill()
            run.wait(10)


def test_the_shells_prompt_says_its_server_lost_and_back_and_keeps_the_line_typed(
    config: ArmConfig, tmp_path: Path
) -> None:
    """`al5d shell` at a terminal, a line half typed at its prompt: the outcome of a line
    run in the background comes; then, nothing of the shell's running, the server goes
    silent (frozen, as a lost link). The shell says each at once, above its prompt, and
    draws the prompt and the half line again below (it said the outcome in the middle of
    the line typed, and nothing of the loss until the next line was refused); it says when
    the server is heard again, and the line, finished, runs."""
    with served(config, tmp_path, "al5d_prompt_tty_peer") as arm:
        shell = Tty([AL5D, "shell", "--via", "ros"])
        server = family(arm.proc.popen.pid)
        try:
            shell.wait_for(r"Ctrl-D ends\r\nal5d> ", SCRIPT_S)
            shell.type("ready\r")
            shell.wait_for(r"ready \[[^\]]+\]: done.*\r\nal5d> ", SCRIPT_S)
            shell.type("move base=-5 time=4000 &\r")  # its outcome comes at the prompt
            shell.wait_for(r"move base=-5 time=4000 &\r\nal5d> ", SCRIPT_S)
            shell.type("move base=5")
            # The outcome above, the prompt and the half line below (or, on a host too busy
            # for the shell to echo it before the outcome came, the half line echoed there).
            shell.wait_for(r"\r\x1b\[Kmove \[[^\]]+\]: done.*\r\nal5d> move base=5", SCRIPT_S)
            with gone(server, "ros"):
                shell.wait_for(
                    r"\r\x1b\[Klost contact with the server \(nothing heard from it for "
                    r"\d+\.\d s\): nothing this command sent is running\r\nal5d> move base=5",
                    SCRIPT_S,
                )
            shell.wait_for(
                r"\r\x1b\[Kcontact with the server again \(\d+\.\d s after it was said lost\)"
                r"\r\nal5d> move base=5",
                SCRIPT_S,
            )
            shell.type(" time=300\r")
            shell.wait_for(r"move \[[^\]]+\]: done", SCRIPT_S)
            wait_until(lambda: abs(arm.emu.servo_degrees()["base"] - 5) < 0.2, STATE_S, "base 5")
            shell.type("exit\r")
            assert shell.proc.wait(SCRIPT_S) == exits.DONE
            assert "Traceback" not in shell.drawn, shell.drawn
        finally:
            shell.close()


@pytest.mark.parametrize("via", ["ros", "lane"])
def test_a_piped_shell_waiting_for_its_next_line_says_its_server_is_gone(
    config: ArmConfig, tmp_path: Path, via: str
) -> None:
    """`al5d shell` reading a pipe, nothing of its own running, waits for its next line:
    the server goes silent (frozen) or its lane closes (killed). The shell says so once, and
    (over ROS 2) when it hears the server again, and runs the next line; its input's end
    ends it, done: a loss while it waited cost no instruction of its."""
    with served(config, tmp_path, f"al5d_prompt_pipe_peer_{via}") as arm:
        shell, out, err = talking([AL5D, "shell", "--via", via])
        assert shell.stdin is not None
        server = family(arm.proc.popen.pid)
        try:
            shell.stdin.write("ready\n")
            shell.stdin.flush()
            assert ": done" in out.wait_for("ready [", SCRIPT_S)
            with gone(server, via):
                said = out.wait_for("nothing this command sent is running", SCRIPT_S)
            if via == "ros":
                assert said.startswith("lost contact with the server (nothing heard"), said
                back = out.wait_for("contact with the server again", SCRIPT_S)
                assert re.fullmatch(r"contact with the server again \(\d+\.\d s after .*\)", back)
                shell.stdin.write("move base=5 time=300\n")
                shell.stdin.flush()
                assert ": done" in out.wait_for("move [", SCRIPT_S)
            else:
                assert said.startswith(
                    "the server on this machine closed its lane (it ended or restarted)"
                ), said
            shell.stdin.close()
            assert shell.wait(SCRIPT_S) == exits.DONE
            assert (
                len([line for line in out.all if "nothing this command sent is running" in line])
                == 1
            ), out.all
            assert not [line for line in err.all if "Traceback" in line], err.all
        finally:
            shell.kill()
            shell.wait(10)


def test_a_shells_ctrl_c_unanswered_by_a_frozen_server_does_not_wait_for_the_move(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: the server frozen as a move ran, Ctrl-C in a piped shell; its stop
    unanswered (said after 10 s), the shell then waited for the move's outcome as long as
    `--timeout` (here 600 s), saying nothing. Now the move is said not waited for, and the
    shell ends (exit 130)."""
    with served(config, tmp_path, "al5d_ctrl_c_frozen_peer") as arm:
        shell, out, err = talking([AL5D, "shell", "--via", "lane", "--timeout", "600"])
        assert shell.stdin is not None
        server = family(arm.proc.popen.pid)
        try:
            shell.stdin.write("move base=60 time=8000\n")
            shell.stdin.flush()
            out.wait_for("> move base=60 time=8000", SCRIPT_S)
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            with gone(server, "ros"):  # frozen, its lane open
                shell.send_signal(signal.SIGINT)
                said = out.wait_for("Ctrl-C: stop [", SCRIPT_S)
                assert "]: no answer" in said, said
                line = out.wait_for("move [", SCRIPT_S)
                assert "not waited for: the stop was not answered" in line, line
                assert shell.wait(SCRIPT_S) == exits.INTERRUPTED, (out.all, err.all)
            assert out.drain()[-1] == "Ctrl-C: the shell's input ends here: no line after it runs"
        finally:
            shell.kill()
            shell.wait(10)


#: A client over the lane that asks a stop or a release (its argument) when told: one
#: connected before the server froze (a new one could not reach a frozen server: it
#: would wait for its welcome).
LANE_ASKS = """
import sys
from al5d.ros.client import Client
c = Client(wait_s=30, local=True)
print("ready", flush=True)
sys.stdin.readline()  # the server is frozen now
print(getattr(c, sys.argv[1])(timeout=60), flush=True)
c.close()
"""


def test_a_stop_by_the_local_lane_unanswered_says_so_while_it_waits(
    config: ArmConfig, tmp_path: Path
) -> None:
    """A stop by the local lane that a frozen server does not answer: `al5d send stop` and
    the client's `stop()` say after 0.8 s that no answer has come, and wait on (an outside
    try: said only when the 10 s timeout ran out, where over ROS 2 the client warns at
    0.8 s); the server, thawed, obeys, and each says it done."""
    with served(config, tmp_path, "al5d_lane_unanswered_peer") as arm:
        script = tmp_path / "lane_asks.py"
        script.write_text(LANE_ASKS)
        client, out, err = talking([sys.executable, str(script), "stop"])
        assert client.stdin is not None
        server = family(arm.proc.popen.pid)
        send: subprocess.Popen[str] | None = None
        try:
            out.wait_for("ready", SCRIPT_S)
            with gone(server, "ros"):  # frozen, its lane open
                send, send_out, send_err = talking([AL5D, "send", "stop", "--timeout", "60"])
                client.stdin.write("stop\n")
                client.stdin.flush()
                said = send_err.wait_for("no answer in 0.8 s by the local lane", SCRIPT_S)
                assert "whether the arm has stopped is unknown" in said, said
                warned = err.wait_for("no answer in 0.8 s by the local lane", SCRIPT_S)
                assert "whether the arm has stopped is unknown" in warned, warned
                # Said while the stop is still awaited: neither has given up.
                assert send.poll() is None and client.poll() is None
                # A second one, left by Ctrl-C while it waits: said, no traceback.
                cut, cut_out, cut_err = talking([AL5D, "send", "stop", "--timeout", "60"])
                cut_err.wait_for("no answer in 0.8 s by the local lane", SCRIPT_S)
                cut.send_signal(signal.SIGINT)
                left = cut_out.wait_for("Ctrl-C: left before its answer", SCRIPT_S)
                assert "whether the arm has stopped is unknown" in left, left
                assert cut.wait(SCRIPT_S) == exits.INTERRUPTED
                assert not [x for x in cut_err.drain(5.0) if "Traceback" in x], cut_err.all
            answer = send_out.wait_for("stop [", SCRIPT_S)
            assert answer.endswith("done (by the local lane)"), answer
            assert send.wait(SCRIPT_S) == 0
            assert re.match(r"stop \[[^\]]+\]: done", out.wait_for("stop", SCRIPT_S)), out.all
            wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
            assert client.wait(SCRIPT_S) == 0
            assert not [x for x in err.all + send_err.all if "Traceback" in x], err.all
        finally:
            for proc in (client, send):
                if proc is not None:
                    proc.kill()
                    proc.wait(10)


def test_a_client_of_a_stalled_server_on_this_machine_says_so_and_keeps_its_wait(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: with the server frozen, a new `al5d send --wait 3` said nothing for
    10 s (the lane's own wait for its welcome), then looked for the server over ROS 2 and
    ended "no al5d server answers ... is 'al5d serve' running?" with a server there; `al5d
    run --check` judged the file against the shipped configuration "(none on this
    machine's lane)". Now each says after 0.8 s that the server here has not answered, the
    send ends within its --wait as a server busy or stalled, nothing sent, and the check
    says whose configuration it judged with and why."""
    sequence = tmp_path / "one.seq"
    sequence.write_text("move base=10\n")
    with served(config, tmp_path, "al5d_stalled_peer") as arm:
        server = family(arm.proc.popen.pid)
        n0 = len(arm.emu.records)
        with gone(server, "ros"):  # frozen, its lane open
            send, _, send_err = talking([AL5D, "send", "--wait", "3", "move base=30"])
            check, check_out, _ = talking([AL5D, "run", "--check", str(sequence)])
            run, _, run_err = talking([AL5D, "run", "--wait", "3", str(sequence)])
            try:
                said = send_err.wait_for("has not answered in 0.8 s", SCRIPT_S)
                assert "busy or stalled" in said, said
                assert send.wait(SCRIPT_S) == exits.NO_SERVER
                ended = send_err.drain(5.0)
                assert [x for x in ended if "did not answer" in x and "busy or stalled" in x], (
                    send_err.all
                )
                assert [x for x in ended if "hello within 3 s:" in x], send_err.all  # its wait
                assert not [x for x in send_err.all if "is 'al5d serve' running" in x]
                judged = check_out.wait_for("nothing sent", SCRIPT_S)
                assert "lane" in judged and "took the connection but" in judged, judged
                assert "busy or stalled" in judged, judged
                assert check.wait(SCRIPT_S) == 0
                said = run_err.wait_for("has not answered in 0.8 s", SCRIPT_S)
                assert "busy or stalled" in said, said
                assert run.wait(SCRIPT_S) == exits.NO_SERVER
                ended = run_err.drain(5.0)
                assert [x for x in ended if "took the connection but" in x], run_err.all
                assert not [x for x in run_err.all if "cannot read" in x], run_err.all
            finally:
                for proc in (send, check, run):
                    proc.kill()
                    proc.wait(10)
        wait_until(lambda: arm.peer.trigger("release") is not None, STATE_S, "the server back")
        assert not [r for r in arm.emu.records[n0:] if b"#0P" in r.raw], "the move was sent"


KILLED = """
from al5d.ros.client import Client, LaneLost, NoOutcome, NoServer
c = Client(wait_s=2, local=True)
c.send("move base=-50 time=6000")
c.wait_for_state("moving", 30)
print("waiting", flush=True)
try:
    c.wait_for_state("ready", 120)
    print("ready", flush=True)
except LaneLost as e:
    print(f"lost: {e}", flush=True)
except NoOutcome as e:
    print(f"no outcome: {e}", flush=True)
except NoServer as e:  # killed before the wait began: no server took the lane again
    print(f"no server: {e}", flush=True)
try:
    print(f"state: {c.state()}", flush=True)
except NoServer as e:
    print(f"no server: {e}", flush=True)
c.close()
"""


def test_a_lane_client_whose_server_was_killed_does_not_say_the_arm_moves(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: the server killed mid-move, the client's `state()` still said
    'moving', and `wait_for_state("ready", 3)` waited its 3 s to say "it is 'moving'". Now
    a wait for a state ends as the lane closes, saying the state is unknown (one that
    begins after it closed waits `wait_s` for a server to take the lane again, as a read
    does: a CI run beside two busy loops killed the server first), and a read after it,
    no server taking the lane again, says so too."""
    with served(config, tmp_path, "al5d_killed_reader_peer") as arm:
        script = tmp_path / "killed.py"
        script.write_text(KILLED)
        client, out, err = talking([sys.executable, str(script)])
        try:
            out.wait_for("waiting", SCRIPT_S)
            with gone(family(arm.proc.popen.pid), "lane"):  # killed, its lane closed
                lost = out.wait_for(": ", SCRIPT_S)
                # The lane closed during the wait, or (a busy host) before it began.
                assert lost.startswith(
                    ("lost: the lane to the owner closed", "no server: the lane to the server")
                ), out.all
                assert "state is unknown" in lost, lost
                read = out.wait_for(": ", SCRIPT_S)
                assert read.startswith("no server: the lane to the server closed"), out.all
                assert "the arm's state is unknown" in read, read
                assert client.wait(SCRIPT_S) == 0, err.all
        finally:
            client.kill()
            client.wait(10)


def test_ctrl_c_on_a_send_whose_server_is_frozen_says_its_cancel_unanswered(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: Ctrl-C on `al5d send` while the server was frozen said nothing for
    12 s, until the server came back and answered the cancel. Now the cancel unanswered is
    said after 0.8 s, while it is still awaited; the server back, the move is cancelled,
    said, and the command ends 130."""
    with served(config, tmp_path, "al5d_cancel_frozen_peer") as arm:
        # Long: the move must still run when the cancel is taken (after the freeze).
        send, out, err = talking([AL5D, "send", "move base=80 time=30000"])
        server = family(arm.proc.popen.pid)
        try:
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            with gone(server, "ros"):  # frozen, its lane open
                send.send_signal(signal.SIGINT)
                said = out.wait_for("its cancel not answered in 0.8 s", SCRIPT_S)
                assert "busy or stalled" in said, said
                assert send.poll() is None
            assert out.wait_for("cancelled (Ctrl-C)", SCRIPT_S).startswith("move [")
            assert send.wait(SCRIPT_S) == exits.INTERRUPTED
            assert not [x for x in err.all if "Traceback" in x], err.all
        finally:
            send.kill()
            send.wait(10)


def test_a_shells_stop_line_waits_for_its_answer_as_al5d_send_stop_does(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: a `stop` typed in a shell whose server was frozen was waited for up
    to the shell's --timeout (120 s), where `al5d send stop` gives up after 10 s. Now the
    shell's stop line waits as long (said after 0.8 s, given up on after 10 s, the shell
    going on), unless --timeout is given."""
    with served(config, tmp_path, "al5d_shell_stop_frozen_peer") as arm:
        shell, out, err = talking([AL5D, "shell", "--via", "lane"])
        assert shell.stdin is not None
        server = family(arm.proc.popen.pid)
        try:
            shell.stdin.write("ready\n")
            shell.stdin.flush()
            out.wait_for("ready [", SCRIPT_S)
            with gone(server, "ros"):  # frozen, its lane open
                shell.stdin.write("stop\n")
                shell.stdin.flush()
                said = err.wait_for("no answer in 0.8 s by the local lane", SCRIPT_S)
                # 10 s from the stop's start, less the 0.8 s and its hand-over.
                assert re.search(r"up to 9\.\d s more", said), said
                warned = re.search(r"stop (\[[^\]]+\]): no answer", said)
                assert warned is not None, said
                # The stop it gives up on is the one it warned of.
                gave_up = out.wait_for(f"stop {warned.group(1)}: no answer", SCRIPT_S)
                assert "within 10 s" in gave_up, gave_up
                assert shell.poll() is None  # the shell goes on
            shell.stdin.close()
            assert shell.wait(SCRIPT_S) == exits.NOT_DONE
        finally:
            shell.kill()
            shell.wait(10)


def test_a_request_in_flight_to_a_frozen_server_on_the_lane_is_said_while_it_waits(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: with the server frozen (its lane open), a move already sent waited
    in silence (a client's 16.5 s, a shell's line 20 s): the owner says nothing while idle,
    so its silence was not seen. Now the owner answers each lease sign, and a move waited
    for, by `al5d send` and by a shell's line, and a client's release, say within seconds
    that the server has said nothing, while they still wait; thawed, each move ends
    done, the release is answered."""
    with served(config, tmp_path, "al5d_lane_in_flight_peer") as arm:
        shell, shell_out, shell_err = talking([AL5D, "shell", "--via", "lane"])
        assert shell.stdin is not None
        send: subprocess.Popen[str] | None = None
        release: subprocess.Popen[str] | None = None
        server = family(arm.proc.popen.pid)
        try:
            shell.stdin.write("ready\n")
            shell.stdin.flush()
            shell_out.wait_for("ready [", SCRIPT_S)
            script = tmp_path / "lane_asks.py"
            script.write_text(LANE_ASKS)
            release, release_out, release_err = talking([sys.executable, str(script), "release"])
            release_out.wait_for("ready", SCRIPT_S)
            send, send_out, send_err = talking([AL5D, "send", "move base=40 time=4000"])
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            shell.stdin.write("move base=-20 time=500\n")
            shell.stdin.flush()
            with gone(server, "ros"):  # frozen, its lane open
                for err in (send_err, shell_err):
                    said = err.wait_for("no word from the server on this machine's lane", SCRIPT_S)
                    assert "busy or stalled" in said and "still waiting, up to" in said, said
                assert send.poll() is None and shell.poll() is None  # both still wait
                # A release's answer awaited: said too (it is no move: no deadline to say).
                assert release.stdin is not None
                release.stdin.write("release\n")
                release.stdin.flush()
                said = release_err.wait_for("no word from the server", SCRIPT_S)
                assert said.startswith("release ["), said
                assert release.poll() is None
            done = send_out.wait_for("move [", SCRIPT_S)
            assert "done" in done, done
            assert send.wait(SCRIPT_S) == 0
            line = shell_out.wait_for("move [", SCRIPT_S)
            assert "done" in line, shell_out.all
            # The arm was not stopped: refused, once the server answers.
            assert "refused" in release_out.wait_for("release", SCRIPT_S)
            assert release.wait(SCRIPT_S) == 0
            shell.stdin.close()
            assert shell.wait(SCRIPT_S) == 0
            assert not [x for x in send_err.all + shell_err.all if "Traceback" in x]
        finally:
            for proc in (shell, send, release):
                if proc is not None:
                    proc.kill()
                    proc.wait(10)


@pytest.mark.parametrize("lease_s", [1.0, 60.0])
def test_a_ros_client_of_a_server_whose_owner_alone_stalls_is_told_and_its_move_halted(
    config: ArmConfig, tmp_path: Path, lease_s: float
) -> None:
    """An outside try: with the owner frozen and its ROS 2 bridge alive, `al5d send --via
    ros` said nothing for 11 s: the bridge went on publishing joint states (where the last
    move told had the arm by then) and so answered the client's lease. Now the bridge,
    not hearing its owner for its lease, publishes none and says why: the client says the
    silence and gives up naming the lost contact, and the owner, thawed, halts the move
    as the lost client's (it was to run 60 s). With a 60 s lease the joint states stop
    as soon (an outside try: they went on for the whole lease), and the client, which
    hears the server's lease as it finds it, waits that lease out, as the server does (an
    outside try: it gave up after 1.5 s, saying the server had halted what it commanded,
    which it would do a minute later): thawed within it, its move goes on."""
    lease = patient_config(client_lease_s=lease_s)
    with served(config, tmp_path, "al5d_owner_alone_peer", lease) as arm:
        send, out, err = talking([AL5D, "send", "--via", "ros", "move base=60 time=60000"])
        owner = arm.proc.popen.pid
        try:
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            with stopped(owner) as frozen:
                said = err.wait_for("no sign of the server for", SCRIPT_S)
                assert said_silence(said) >= 1.0, said
                if lease_s > 10:
                    left = re.search(r"gives up on what it waits for in (\d+\.\d) s", said)
                    assert left is not None and float(left.group(1)) > lease_s - 10, said
                    # Well past the 1.5 s a client that knew no lease gave up after.
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        send.wait(3 * LOST_S)
                    assert send.poll() is None, "it gave up within its server's lease"
                else:
                    assert send.wait(SCRIPT_S) != 0
            if lease_s > 10:
                said = arm.proc.err.wait_for("the owner has said nothing for", SCRIPT_S)
                found = re.search(r"said nothing for (\d+\.\d) s", said)
                assert found is not None and float(found.group(1)) < 10, said  # not its lease
                arm.proc.err.wait_for("heard again", SCRIPT_S)
                # The client's warning is not its last word while it waits on; the silence
                # it says is the one it warned of, within the freeze (and its thaw's second).
                again = err.wait_for("the server is heard again", SCRIPT_S)
                assert 1.0 <= said_again(again) <= frozen[0] + 1.0, (again, frozen)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    send.wait(3 * LOST_S)
                assert send.poll() is None and arm.states[-1] == "moving"
                return
            lost = out.wait_for("lost contact with the server", SCRIPT_S)
            assert lost.startswith("move ["), lost
            arm.proc.err.wait_for_each(
                ["the owner has said nothing for", "lost contact with client", "heard again"],
                SCRIPT_S,
            )
            # Halted well before its 60 s (after the thaw: the bridge's loss of the client).
            wait_until(lambda: arm.states[-1] == "ready", STATE_S, "ready")
        finally:
            send.kill()
            send.wait(10)


def said_again(line: str) -> float:
    """The seconds of silence a client's word that the server answers again says."""
    found = re.search(r"again,? after (\d+\.\d) s", line)
    assert found is not None, line
    return float(found.group(1))


def test_a_lane_client_says_when_its_stalled_server_answers_again(
    config: ArmConfig, tmp_path: Path
) -> None:
    """With a 60 s lease, a frozen server's silence said by a lane client waiting for its
    move was its last word until the outcome, a minute later, though the server had
    turned again within seconds. Now the client says that the server answers again, and
    waits on: the move goes on."""
    lease = patient_config(client_lease_s=60.0)
    with served(config, tmp_path, "al5d_lane_again_peer", lease) as arm:
        send, _, err = talking([AL5D, "send", "--via", "lane", "move base=60 time=60000"])
        owner = arm.proc.popen.pid
        try:
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            with stopped(owner) as frozen:
                err.wait_for("no word from the server on this machine's lane", SCRIPT_S)
            again = err.wait_for("answers again", SCRIPT_S)
            assert again.startswith("move ["), again
            assert 1.0 <= said_again(again) <= frozen[0] + 1.0, (again, frozen)
            with contextlib.suppress(subprocess.TimeoutExpired):
                send.wait(3 * LOST_S)
            assert send.poll() is None and arm.states[-1] == "moving"
            assert len([x for x in err.drain(0.1) if "again" in x]) == 1, err.all  # once
        finally:
            send.kill()
            send.wait(10)


def test_a_client_of_a_frozen_server_whose_lane_takes_no_more_connections_ends_saying_so(
    config: ArmConfig, tmp_path: Path
) -> None:
    """A server frozen with its lane's queue of connections untaken full (64): `al5d send`
    by the lane waited in its connect for ever, without a word. Now it says at 0.8 s that
    the server has not answered, and ends within its wait, nothing sent, naming the
    stalled server."""
    with served(config, tmp_path, "al5d_lane_queue_peer") as arm:
        with lane_full(arm.proc.popen.pid) as waiting:
            # Not a lane left behind, which a server starting would take over.
            assert where.answers(where.path())
            send, out, err = talking(
                [AL5D, "send", "--via", "lane", "--wait", "3", "move base=10 time=500"]
            )
            try:
                assert send.wait(SCRIPT_S) == exits.NO_SERVER
            finally:
                send.kill()
            said = err.drain() + out.drain()
            assert any("has not answered in 0.8 s" in line for line in said), said
            ended = [line for line in said if "has taken no connection in" in line]
            assert ended and "stalled" in ended[0] and "nothing sent" in ended[0], said
        assert len(waiting) >= 64, len(waiting)  # the owner's queue (`listen(64)`)


@contextlib.contextmanager
def lane_full(owner: int) -> Iterator[list[socket.socket]]:
    """The server's owner `owner` frozen, and its lane's queue of connections not taken
    filled (the connections, yielded, closed once it is thawed on the way out)."""
    waiting: list[socket.socket] = []
    try:
        freeze(owner)
        while True:  # the queue filled as the owner takes none
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.setblocking(False)
            try:
                sock.connect(str(where.path()))
            except BlockingIOError:
                sock.close()
                break
            waiting.append(sock)
        yield waiting
    finally:
        os.kill(owner, signal.SIGCONT)
        for sock in waiting:
            sock.close()


@pytest.mark.parametrize(
    "options", [(), ("--verbose",)], ids=["the-quick-way", "the-full-command-line"]
)
def test_a_stop_typed_while_the_lane_of_a_frozen_server_is_full_goes_by_ros_2(
    config: ArmConfig, tmp_path: Path, options: tuple[str, ...]
) -> None:
    """`al5d send stop` to a server whose owner is frozen, its lane's queue of connections
    full: it waited 10 s for a connection and ended 'nothing sent', the arm moving on once
    the owner turned again. Now it says so at once and goes by ROS 2, whose stop node holds
    a connection to the owner: the owner, thawed, stops the arm first, and the command
    says the stop done. So does the full command line (`--verbose` is not the quick
    way's)."""
    with served(config, tmp_path, "al5d_full_lane_stop_peer") as arm:
        move, _, _ = talking([AL5D, "send", "--via", "lane", "move base=60 time=60000"])
        stop = None
        try:
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            with lane_full(arm.proc.popen.pid):
                stop, out, err = talking([AL5D, "send", *options, "stop", "--timeout", "60"])
                went = err.wait_for("takes no new connection", SCRIPT_S)
                assert "it goes by ROS 2" in went, went
                # Asked of the stop node, and handed to the owner (which does not answer).
                err.wait_for("no answer in 0.8 s", SCRIPT_S)
            done = out.wait_for("stop", SCRIPT_S)
            assert stop.wait(SCRIPT_S) == exits.DONE, (done, err.drain(), out.drain())
            assert re.match(r"stop \[[^\]]+\]: done \(by /al5d/", done), done
            wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
        finally:
            for proc in (move, stop):
                if proc is not None:
                    proc.kill()
                    proc.wait(10)


def test_a_python_clients_stop_while_the_lane_of_a_frozen_server_is_full_is_obeyed(
    config: ArmConfig, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A Python client's stop (by the lane) to a server whose owner is frozen for longer
    than the stop's wait, its lane's queue of connections full: it said 'not sent: no al5d
    server takes its lane', of a server that is there, and the arm moved on once the owner
    turned again. Now it goes on the client's own connection, says it has no answer
    (whether obeyed unknown), and the owner, thawed, obeys it; the client says so, under
    the stop's one id."""
    caplog.set_level(logging.WARNING, logger="al5d")
    with (
        served(config, tmp_path, "al5d_full_lane_client_peer") as arm,
        Client(local=True) as client,
    ):
        client.send("move base=60 time=60000")
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        with (
            lane_full(arm.proc.popen.pid),
            pytest.raises(NoOutcome, match="no answer on the local lane within 2 s") as raised,
        ):
            client.stop(timeout=2.0)
        wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
        ident = re.match(r"stop (\[[^\]]+\])", str(raised.value))
        assert ident is not None, raised.value

        def said() -> list[str]:
            return [r.getMessage() for r in caplog.records]

        wait_until(lambda: any("answered after" in m for m in said()), STATE_S, "the answer")
        for words in ("it goes on this client's own connection", "answered after"):
            found = [m for m in said() if words in m]
            assert found and found[0].startswith(f"stop {ident.group(1)}: "), said()


def test_a_ros_client_that_was_itself_stopped_says_so_and_tells_the_servers_outcome(
    config: ArmConfig, tmp_path: Path
) -> None:
    """An outside try: `al5d send --via ros` stopped by Ctrl-Z (SIGSTOP) for 4 s during its
    move, then resumed, said 'lost contact with the server ... the link may be lost', of a
    server that had been there all along and had halted the move, its client's lease run
    out. Now the client finds that it was held itself, says so, and hears the server's
    outcome of its move: halted for the lost contact with the client."""
    with served(config, tmp_path, "al5d_held_client_peer") as arm:
        send, out, err = talking([AL5D, "send", "--via", "ros", "move base=60 time=60000"])
        try:
            wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
            freeze(send.pid)
            try:
                arm.proc.err.wait_for("lost contact with client", SCRIPT_S)
                time.sleep(3 * LOST_S)  # the client's lease and its margin, and more
            finally:
                os.kill(send.pid, signal.SIGCONT)
            outcome = out.wait_for("move [", SCRIPT_S)
            assert "lost contact with the client" in outcome, outcome
            held = err.wait_for("this client was held for", SCRIPT_S)
            assert "has taken it for lost, and halted what of this client" in held, held
            assert send.wait(SCRIPT_S) != 0
            said = out.drain() + err.drain()
            assert not [x for x in said if "lost contact with the server" in x], said
            assert not [x for x in said if "link may be lost" in x], said
        finally:
            send.kill()
            send.wait(10)
