"""The terminal's errors and time (issue 27): an exit code of its own for refused, bad
input, usage and no server, listed in `--help`; a sequence file's errors all at once,
before anything is sent; a hint for metres typed as millimetres; where the time of a
command went (the server's discovery); `al5d shell`, one connection for many lines.

Every command is an `al5d` process of its own, against a real server over real DDS
(`served`), or with none.
"""

from __future__ import annotations

import io
import re
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from al5d import exits
from al5d.app import cli
from al5d.app.report import SLOW_DISCOVERY_S, Timing
from al5d.arm.config import ArmConfig
from al5d.ros.answers import ANSWER_S
from al5d.ros.client import Client, NoServer
from al5d.ssc32u.emulator import Emulator
from al5d_rig.armrig import group_moves
from al5d_rig.domains import alone
from al5d_rig.proc import AL5D, Proc, Tty, patient_config
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Served, served

#: Generous bounds: rclpy's start, discovery and a move on a loaded machine.
CMD_S = 90.0
STATE_S = 30.0
#: What a shell says of its stop on Ctrl-C, answered by the local lane (under its id).
STOPPED_BY_LANE = r"Ctrl-C: stop \[[^\]]+\]: done \(by the local lane\)"


@pytest.fixture(scope="module")
def server(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    with served(config, tmp_path_factory.mktemp("cli"), "al5d_cli_peer") as s:
        yield s


@pytest.fixture
def arm(server: Served) -> Served:
    """The server, its arm released and at rest, whatever the last test left."""
    return server.ready(STATE_S)


def ended(proc: Proc) -> tuple[int, list[str], list[str]]:
    code = proc.wait(CMD_S)
    return code, proc.out.drain(), proc.err.drain()


@pytest.mark.parametrize(
    "args",
    [(), ("send",), ("run",), ("shell",), ("doctor",), ("record",), ("replay",), ("calibrate",)],
)
def test_help_lists_the_exit_codes(args: tuple[str, ...]) -> None:
    code, out, _ = ended(Proc(*args, "--help"))
    assert code == exits.DONE
    text = "\n".join(out)
    assert "exit codes:" in text
    for number, what in exits.TABLE:
        assert f"  {number}  {what}" in text
    assert len({number for number, _ in exits.TABLE}) == len(exits.TABLE)


@pytest.mark.parametrize(
    "args",
    [
        ("send",),
        ("run", "--frobnicate", "x.seq"),
        ("send", "--wait", "soon", "ready"),
        ("send", "--namespace", "a" * 300, "ready"),  # was rcl's traceback
    ],
)
def test_a_usage_error_is_argparses_own_code(args: tuple[str, ...]) -> None:
    code, _, err = ended(Proc(*args, env=alone()))
    assert code == exits.USAGE == 2, err
    assert err[0].startswith("usage: al5d")


@pytest.mark.parametrize(
    "args",
    [
        ("send", "--timeout", "nan", "move", "base=10"),
        ("send", "--timeout", "-1", "move", "base=10"),
        ("send", "--timeout", "0", "move", "base=10"),
        ("send", "--timeout", "inf", "move", "base=10"),
        ("send", "--timeout", "1e10", "move", "base=10"),
        ("send", "--wait", "nan", "ready"),
        ("run", "--timeout", "nan", "x.seq"),
        ("shell", "--wait", "-5"),
        ("record", "--duration", "-1", "/nonexistent/out.mcap"),
        ("replay", "--timeout", "inf", "x.mcap"),
    ],
)
def test_a_wait_that_is_no_number_of_seconds_is_a_usage_error(args: tuple[str, ...]) -> None:
    """NaN, 0, -1 sent the move and then waited for none of it ("no outcome (timed out)",
    and the server halted it, its client gone); inf and 1e10 sent it, then failed with a
    traceback (the standard library's waits end near 9e9 s): each is argparse's error,
    before anything is sent."""
    code, _, err = ended(Proc(*args, env=alone()))
    assert code == exits.USAGE, err
    assert "give a number of seconds above 0, at most 604800" in err[-1], err


@pytest.mark.parametrize(
    ("words", "error"),
    [
        (("move", "base=x"), "al5d send: word 2 'base=x': 'x' is not a number of degrees"),
        (("dance",), "al5d send: word 1 'dance': unknown instruction; expected park | ready"),
        (
            ("mvoe", "base=30"),
            "al5d send: word 1 'mvoe': unknown instruction; did you mean 'move'? expected park",
        ),
        (
            ("wait", "100"),
            "al5d send: word 1 'wait': wait <ms> pauses a sequence file or al5d shell between "
            "instructions; the server has no pause to send it",
        ),
        (
            ("move_to", "x=0.25", "y=0", "z=0.12"),
            "al5d send: word 2 'x=0.25': x=0.25 y=0 z=0.12 look like metres; move_to takes "
            "millimetres: x=250 y=0 z=120",
        ),
    ],
)
def test_bad_input_is_its_own_code_and_needs_no_server(words: tuple[str, ...], error: str) -> None:
    code, out, err = ended(Proc("send", "--wait", "1", *words, env=alone()))
    assert code == exits.BAD_INPUT, err
    assert out == [] and err[0].startswith(error), err


def test_an_option_among_an_instructions_words_leaves_them_one_instruction() -> None:
    """`al5d send move base=10 --timeout 1 time=x`: every word is the instruction's (the third
    is judged, and is bad), not an argument `al5d` does not know (argparse's top-level usage
    and "unrecognized arguments: time=x", an outside try found). An unknown option is
    still argparse's error, under `al5d send`'s usage (it was the top level's)."""
    args = ("send", "--wait", "1", "move", "base=10", "--timeout", "1", "time=x")
    code, out, err = ended(Proc(*args, env=alone()))
    assert code == exits.BAD_INPUT and out == [], err
    assert err[0] == "al5d send: word 3 'time=x': 'x' is not a whole number of ms", err
    code, _, err = ended(Proc("send", "move", "--frob", "base=10", env=alone()))
    assert code == exits.USAGE, err
    assert err[-1] == "al5d send: error: unrecognized arguments: --frob base=10", err
    assert err[0].startswith("usage: al5d send "), err


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--frob", "send", "stop"], "al5d: error: unrecognized arguments: --frob"),
        (["send", "--frob", "stop"], "al5d send: error: unrecognized arguments: --frob"),
        (["run", "x.seq", "--frob"], "al5d run: error: unrecognized arguments: --frob"),
    ],
)
def test_an_unknown_option_is_said_under_the_usage_it_is_on(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as ended_with:
        cli.main(argv)
    assert ended_with.value.code == exits.USAGE
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == said, err


@pytest.mark.parametrize(
    ("command", "said"),
    [
        (
            "send",
            [
                "find the server; default 10",
                "for an outcome; default 120",
                f"(a stop's or release's answer: {ANSWER_S:g})",
            ],
        ),
        (
            "shell",
            ["for an outcome; default 120", f"(a stop's or release's answer: {ANSWER_S:g})"],
        ),
        ("run", ["find the server; default 10", "for an outcome; default 120"]),
        ("replay", ["find the server; default 10", "for an outcome; default 120"]),
        ("calibrate", ["find the server; default 10", "for a move; default 30"]),
    ],
)
def test_a_clients_help_says_how_long_it_waits(
    command: str, said: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside try: `al5d send stop` with no server took 10.9 s, and --help did not say
    that it looks for one for 10 s."""
    with pytest.raises(SystemExit) as ended_with:
        cli.main([command, "--help"])
    assert ended_with.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for words in said:
        assert words in text, text


def test_no_server_is_its_own_code_for_run_too(tmp_path: Path) -> None:
    seq = tmp_path / "ok.seq"
    seq.write_text("ready\n")
    code, _, err = ended(Proc("run", "--wait", "1", str(seq), env=alone()))
    assert code == exits.NO_SERVER, err
    assert any("no al5d server answers" in line for line in err)


def test_bad_grammar_in_a_file_is_said_before_a_server_is_looked_for(tmp_path: Path) -> None:
    """Bad for every server, so said at once, with no server to judge the rest by."""
    seq = tmp_path / "typo.seq"
    seq.write_text("ready\nmove base=x\n")
    code, out, err = ended(Proc("run", "--wait", "30", str(seq), env=alone()))
    assert code == exits.BAD_INPUT, err
    assert out == []
    assert err == [
        f"al5d run: nothing sent: {seq}:2: word 2 'base=x': 'x' is not a number of degrees"
    ]


def test_a_sequence_files_errors_are_said_all_at_once_and_nothing_is_sent(
    arm: Served, tmp_path: Path
) -> None:
    seq = tmp_path / "bad.seq"
    seq.write_bytes(
        b"ready\nmove base=x\nmove base=10 time=300\nwait\n# fine\nmove_to x=0.2 y=0 z=0.1\n"
        b"park \xff\nstop\n"
    )
    moves = len(group_moves(arm.emu.records))
    code, out, err = ended(Proc("run", str(seq)))
    assert code == exits.BAD_INPUT, err
    assert out == []
    assert err == [
        f"al5d run: nothing sent: {seq}:2: word 2 'base=x': 'x' is not a number of degrees",
        f"al5d run: {seq}:4: word 1 'wait': wait takes one number of ms: wait <ms>",
        f"al5d run: {seq}:6: word 2 'x=0.2': x=0.2 y=0 z=0.1 look like metres; move_to takes "
        "millimetres: x=200 y=0 z=100",
        f"al5d run: {seq}:7: not UTF-8 text (byte 0xff at column 6)",
    ]
    assert len(group_moves(arm.emu.records)) == moves
    assert arm.states[-1] == "ready"


#: One problem of each kind the server would refuse, and a pose that is not saved; good
#: lines between them, which are not sent either.
JUDGED = (
    "ready\n"
    "move elbo=20\n"
    "move base=200 time=500\n"
    "move base=10\n"
    "move shoulder=90 elbow=90\n"
    "pose above_cpu\n"
    "park\n"
)


def test_a_sequence_the_server_would_refuse_is_judged_whole_and_nothing_is_sent(
    arm: Served, tmp_path: Path
) -> None:
    (tmp_path / "poses.yaml").write_text("above_cup: {base: -35, shoulder: 40, elbow: 80}\n")
    seq = tmp_path / "judged.seq"
    seq.write_text(JUDGED)
    n0 = len(arm.emu.records)
    outcomes = len(arm.peer.results_now())
    code, out, err = ended(Proc("run", str(seq)))
    assert code == exits.BAD_INPUT, err
    assert out == []
    lines = [line.removeprefix("al5d run: ").removeprefix("nothing sent: ") for line in err]
    assert [line.split(": ", 1)[0] for line in lines] == [f"{seq}:{n}" for n in (2, 3, 5, 6)], err
    assert lines[0].startswith(f"{seq}:2: unknown joint 'elbo'; did you mean 'elbow'?"), err
    assert lines[1] == f"{seq}:3: base: 200 deg is outside the range -90..90", err
    assert "below the table" in lines[2] or "under the table" in lines[2], err
    assert lines[3].startswith(f"{seq}:6: word 2 'above_cpu': no saved pose named 'above_cpu'; "), (
        err
    )
    # No move reached the board, and the server heard of nothing: no outcome of any line.
    time.sleep(1.0)
    assert group_moves(arm.emu.records[n0:]) == []
    assert len(arm.peer.results_now()) == outcomes


def test_a_sequence_is_judged_by_the_servers_own_configuration(
    config: ArmConfig, tmp_path: Path
) -> None:
    """A server started with a base range of -45..45 and a preset of its own (its own file):
    `al5d run`, over its lane and over ROS 2, and `al5d run --check` judge a file by it,
    not by the shipped one (where base=60 is fine, and `wave` no instruction): the one
    line is said, and nothing is sent. The file is gone once the server has read it, as
    for a client on another machine: the server says what it judges with."""
    data = yaml.safe_load(Path(patient_config()).read_text())
    data["joints"]["base"]["range_deg"] = [-45, 45]
    data["presets"]["wave"] = {**data["presets"]["ready"], "base": 20}
    narrow = tmp_path / "narrow.yaml"
    narrow.write_text(yaml.safe_dump(data, sort_keys=False))
    seq = tmp_path / "wide.seq"
    seq.write_text("ready\nwave\nmove base=60\npark\n")
    link = tmp_path / "ssc32u"
    ns = ("--namespace", "narrow")
    with Emulator(config, link=link).start() as emu:
        server = Proc("serve", "--port", str(link), "--config", str(narrow), *ns)
        try:
            server.err.wait_for("STATE: ready", STATE_S)
            narrow.unlink()
            n0 = len(emu.records)
            for args in (("--check",), (), ("--via", "ros")):
                code, out, err = ended(Proc("run", *args, *ns, str(seq)))
                assert code == exits.BAD_INPUT, (args, out, err)
                said = [
                    e.removeprefix("al5d run: ").removeprefix("nothing sent: ")
                    for e in err
                    # A slow discovery is said, and the servers of other names meanwhile.
                    if "to be discovered" not in e and "still looking" not in e
                ]
                assert said == [f"{seq}:3: base: 60 deg is outside the range -45..45"], (args, err)
            assert group_moves(emu.records[n0:]) == []
        finally:
            server.kill()


def test_check_judges_a_file_without_a_server(tmp_path: Path) -> None:
    (tmp_path / "poses.yaml").write_text("above_cup: {base: -35, shoulder: 40, elbow: 80}\n")
    seq = tmp_path / "judged.seq"
    seq.write_text(JUDGED)
    code, out, err = ended(Proc("run", "--check", str(seq), env=alone()))
    assert code == exits.BAD_INPUT, err
    assert out == []
    assert [line.split(": ")[1] for line in err] == [f"{seq}:{n}" for n in (2, 3, 5, 6)], err
    good = tmp_path / "good.seq"
    good.write_text("ready\nmove base=10 &\nwait 100\npose above_cup time=800\npark\n")
    code, out, err = ended(Proc("run", "--check", str(good), env=alone()))
    assert code == exits.DONE, err
    assert out == [
        f"{good}: 5 steps, none a server with the shipped configuration (none on this "
        "machine's lane) would refuse from where the lines before leave the arm; where it "
        "starts is not known, so the table is judged for line 1 only by the server, as it "
        "starts (from a preset, or a move naming every joint, on it is known); nothing sent"
    ], out
    # Moves naming some joints only: none of them is judged against the table here (seen:
    # "none would refuse" of a file whose second line the server refused, below the table).
    partial = tmp_path / "partial.seq"
    partial.write_text("move base=30\nmove shoulder=90 elbow=90 wrist=90\nmove base=-30\n")
    code, out, err = ended(Proc("run", "--check", str(partial), env=alone()))
    assert code == exits.DONE, err
    assert "the table is judged for lines 1, 2 and 3 only by the server" in out[0], out
    # As many problems said as `al5d run` says: the first 100, then how many more (an
    # outside try: 5000 lines said one by one by --check, 100 by run).
    many = tmp_path / "many.seq"
    many.write_text("move base=500\n" * 150)
    code, out, err = ended(Proc("run", "--check", str(many), env=alone()))
    assert code == exits.BAD_INPUT, err
    assert len(err) == 101 and err[-1] == "al5d run: ... and 50 more bad lines", err[-3:]


def test_a_sequence_from_standard_input_runs_and_an_empty_one_says_so(
    arm: Served, tmp_path: Path
) -> None:
    """An outside try: `al5d run -` said "cannot read -", and a file of nothing but comments
    ran without a word (exit 0)."""
    run = Proc("run", "-", stdin=True)
    for line in ("ready", "move base=10 time=200"):
        run.send(line)
    assert run.popen.stdin is not None
    run.popen.stdin.close()
    code, out, err = ended(run)
    assert code == exits.DONE, (out, err)
    assert [line.split(" [")[0] for line in out if ": done" in line] == ["ready", "move"], out
    bad = Proc("run", "-", stdin=True)
    bad.send("move base=x")
    assert bad.popen.stdin is not None
    bad.popen.stdin.close()
    code, out, err = ended(bad)
    assert code == exits.BAD_INPUT, (out, err)
    assert any(line.startswith("al5d run: nothing sent: <stdin>:1: ") for line in err), err
    empty = tmp_path / "empty.seq"
    empty.write_text("# nothing yet\n\n")
    code, out, err = ended(Proc("run", str(empty)))
    assert code == exits.DONE, (out, err)
    assert err == [f"al5d run: {empty}: no instruction in it: nothing sent"], err


def test_a_file_that_cannot_be_read_is_bad_input(tmp_path: Path) -> None:
    code, _, err = ended(Proc("run", str(tmp_path / "missing.seq"), env=alone()))
    assert code == exits.BAD_INPUT
    assert err == [f"al5d run: cannot read {tmp_path / 'missing.seq'}: No such file or directory"]
    # Without a bound, /dev/zero was read until memory ran out (a MemoryError's traceback).
    # A sparse file just over the bound stands for it: a test that fails reads no more.
    big = tmp_path / "big.seq"
    with big.open("wb") as f:
        f.truncate(16 * 2**20 + 1)
    for args in (("run", str(big)), ("run", "--check", str(big))):
        code, _, err = ended(Proc(*args, env=alone()))
        assert code == exits.BAD_INPUT, err
        assert err == [f"al5d run: cannot read {big}: larger than 16 MiB: no sequence file"], err


def test_refused_is_not_done_and_verbose_says_where_the_time_went(arm: Served) -> None:
    code, out, err = ended(Proc("send", "--verbose", "move", "base=200"))
    assert code == exits.NOT_DONE, err
    assert any("refused: base: 200 deg is outside the range" in line for line in out)
    said = "\n".join(err)
    assert re.search(r"^al5d send: ROS started in \d+\.\d\d s$", said, re.M), said
    found = re.search(
        r"^al5d send: waited (\d+\.\d\d) s for the server to be discovered$", said, re.M
    )
    assert found is not None, said
    assert re.search(r"^al5d send: \d+\.\d\d s in all$", said, re.M), said


def test_what_the_server_changed_is_printed_by_send_and_run(arm: Served, tmp_path: Path) -> None:
    """`ready time=10` is slowed to what the servos can do: `al5d send` and `al5d run` print
    the outcome with the time the server raised it to (INF03), not a bare `done`."""
    seq = tmp_path / "fast.seq"
    seq.write_text("park\nready time=10\n")
    raised = re.compile(
        r"^ready \[\S+\]: done: INF03: ready \[\S+\] cannot be done in the requested 10 ms; "
        r"expected \d+ ms",
        re.M,
    )
    for args in (("send", "park"), ("send", "ready", "time=10"), ("run", str(seq))):
        code, out, err = ended(Proc(*args))
        assert code == exits.DONE, (args, out, err)
        if args[0] == "run" or "time=10" in args:
            assert raised.search("\n".join(out)), (args, out)


def test_a_line_waited_for_and_not_done_ends_the_sequence(arm: Served, tmp_path: Path) -> None:
    """A stop (from another terminal) cancels the line running: the sequence ends there, and a
    release meanwhile does not take up its rest (seen: the moves after it ran once the arm
    was released). A stop of the sequence's own, whose move runs in the background, does not
    end it: the lines after it still go."""
    seq = tmp_path / "stopped.seq"
    seq.write_text("move base=60 time=3000\nwait 1500\nmove base=-60 time=2000\nmove elbow=60\n")
    run = Proc("run", str(seq))
    wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
    assert arm.peer.trigger("stop").success
    assert arm.peer.trigger("release").success
    code = run.wait(CMD_S)
    out = run.out.drain()
    assert code == exits.NOT_DONE, out
    assert any("cancelled by stop" in line for line in out), out
    assert out[-1] == "not done: the 3 steps after it not sent", out
    assert not any("base=-60" in line for line in out), out
    own = tmp_path / "own.seq"
    own.write_text("move base=40 time=3000 &\nwait 300\nstop\nrelease\nmove base=0 time=300\n")
    code, out, err = ended(Proc("run", str(own)))
    assert code == exits.NOT_DONE, (out, err)  # the move in the background was cancelled
    assert any(re.match(r"move \[\S+\]: cancelled", line) for line in out), out
    assert any(re.match(r"release \[\S+\]: done", line) for line in out), out
    assert re.match(r"move \[\S+\]: done", out[-1]), out


def test_a_piped_shells_line_not_done_ends_its_input_as_a_sequence_does(arm: Served) -> None:
    """An outside try: a script piped into `al5d shell` went on after another client's
    emergency stop had cancelled its move, and its `release` unlocked the arm for the rest.
    Piped, a line waited for that is not done ends the input, as it ends `al5d run`."""
    shell = Proc("shell", stdin=True)
    try:
        for line in ("move base=60 time=3000", "move base=-60 time=2000", "release", "park"):
            shell.send(line)
        wait_until(lambda: arm.states[-1] == "moving", CMD_S, "moving")
        assert arm.peer.trigger("stop").success
        code, out, err = ended(shell)
    finally:
        shell.kill()
    assert code == exits.NOT_DONE, (out, err)
    assert any("cancelled by stop" in line for line in out), out
    assert out[-1] == "not done: the shell's input ends here: no line after it runs", out
    assert not [line for line in out if line.startswith(("> move base=-60", "> release"))], out
    wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped, not released")


def test_a_slow_discovery_is_said_without_verbose(arm: Served) -> None:
    """The measure is the client's own (its wait for a server under a namespace that has
    none, 1.5 s); what is said of it is what `al5d send` says."""
    client = Client(namespace="nobody_here")
    try:
        with pytest.raises(NoServer):
            client.wait_for_server(1.5)
        assert client.discovery_s >= 1.5 > SLOW_DISCOVERY_S
        err = io.StringIO()
        Timing("al5d send", False, err).discovered(client)
        assert re.fullmatch(
            r"al5d send: waited 1\.\d s for the server to be discovered \(ROS 2 discovery, "
            r"which each new client pays: `al5d shell` pays it once for many instructions\)\n",
            err.getvalue(),
        ), err.getvalue()
    finally:
        client.close()


def test_a_client_started_before_its_server_says_how_long_it_waited(
    config: ArmConfig, tmp_path: Path
) -> None:
    link = tmp_path / "ssc32u"
    client = Proc("send", "--wait", "60", "--verbose", "ready", env=alone())
    with Emulator(config, link=link):
        # The client waits, its ROS started (on a busy host that alone took longer than a
        # head start of 1.5 s: the server was up before the client looked for it); the
        # server comes a while later (its own start is seconds more). Without --verbose the
        # same line is said when discovery was slow (the test before this one).
        client.err.wait_for("ROS started in", 60)
        time.sleep(1.5)
        serve = Proc("serve", "--port", str(link), "--config", patient_config(), env=alone())
        try:
            code, _, err = ended(client)
            assert code == exits.DONE, err
            found = [line for line in err if "s for the server to be discovered" in line]
            assert len(found) == 1, err
            waited = float(re.findall(r"waited (\d+\.\d+) s", found[0])[0])
            assert waited > 1.5 > SLOW_DISCOVERY_S
        finally:
            serve.kill()


def test_the_shell_runs_each_line_over_one_connection(arm: Served) -> None:
    moves = len(group_moves(arm.emu.records))
    shell = Proc("shell", "--verbose", stdin=True)
    try:
        lines = ("ready", "stop", "release", "move base=x", "move base=10 time=200")
        for line in (*lines, "move base=0 &", "exit"):
            shell.send(line)
        code, out, err = ended(shell)
    finally:
        shell.kill()
    assert code == exits.BAD_INPUT, err  # a line was bad; the others ran
    assert out[0] == "> ready" and re.fullmatch(r"ready \[.*\]: done.*", out[1]), out
    # Each line is said before its outcome, the stop's and the release's too.
    assert out[2] == "> stop" and out[4] == "> release", out
    # Each answer names its id, as a warning while it waited would.
    assert re.fullmatch(r"stop \[[^\]]+\]: done \(by the local lane\)", out[3]), out
    assert re.fullmatch(r"release \[[^\]]+\]: done \(by the local lane\)", out[5]), out
    assert "> move base=10 time=200" in out
    assert sum(": done" in line for line in out) == 5, out
    assert "al5d shell: word 2 'base=x': 'x' is not a number of degrees" in err
    # One discovery for all of them.
    assert sum("s for the server to be discovered" in line for line in err) == 1, err
    assert len(group_moves(arm.emu.records)) - moves >= 2


def test_ctrl_c_in_the_shell_stops_a_move_in_the_background(arm: Served) -> None:
    """A move sent with `&` runs while the shell reads its input: Ctrl-C then stops the arm
    too (seen: the move ran on, at a terminal's prompt and piped)."""
    shell = Proc("shell", stdin=True)
    try:
        shell.send("move base=80 time=5000 &")
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        shell.popen.send_signal(signal.SIGINT)
        said = shell.out.wait_for("Ctrl-C: stop [", CMD_S)
        assert re.fullmatch(STOPPED_BY_LANE, said), said
        wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
        assert abs(arm.emu.servo_degrees()["base"] - 80) > 5  # halted on its way
        code, out, err = ended(shell)  # Ctrl-C ended its piped input
    finally:
        shell.kill()
    assert code == exits.INTERRUPTED, (out, err)
    assert any(re.match(r"move \[\S+\]: cancelled", line) for line in out), out
    assert out[-1] == "Ctrl-C: the shell's input ends here: no line after it runs", out
    assert arm.peer.trigger("release").success


def test_help_in_the_shell_says_its_grammar_and_sends_nothing(arm: Served) -> None:
    """An outside try: `help` at the shell's prompt was an unknown instruction (exit 4)."""
    moves = len(group_moves(arm.emu.records))
    shell = Proc("shell", stdin=True)
    try:
        for line in ("help", "?", "exit"):
            shell.send(line)
        code, out, err = ended(shell)
    finally:
        shell.kill()
    assert code == exits.DONE, (out, err)
    said = [line for line in out if line.startswith("move <joint>=<degrees>")]
    assert len(said) == 2, out
    assert any(line.startswith("park | ready | straight_up") for line in out), out
    assert "joints: base shoulder elbow wrist gripper wrist_rotate" in out, out
    assert len(group_moves(arm.emu.records)) == moves


def test_ctrl_c_in_a_piped_shell_stops_the_arm_and_ends_its_input(arm: Served) -> None:
    """Piped, the shell's input is a script: after Ctrl-C stopped the arm, the rest of it
    is not run (as `al5d run`'s is not)."""
    shell = Proc("shell", stdin=True)
    try:
        shell.send("move base=80 time=5000")
        shell.out.wait_for("> move base=80 time=5000", CMD_S)
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        shell.popen.send_signal(signal.SIGINT)
        said = shell.out.wait_for("Ctrl-C: stop [", CMD_S)
        assert re.fullmatch(STOPPED_BY_LANE, said), said
        assert "cancelled" in shell.out.wait_for("move [", CMD_S)
        wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
        assert abs(arm.emu.servo_degrees()["base"] - 80) > 5  # halted on its way
        code, out, err = ended(shell)
    finally:
        shell.kill()
    assert code == exits.INTERRUPTED, (out, err)
    assert out[-1] == "Ctrl-C: the shell's input ends here: no line after it runs", out
    assert arm.peer.trigger("release").success


def test_ctrl_c_in_a_shells_wait_stops_its_move_in_the_background(arm: Served) -> None:
    """Ctrl-C in a line that is not a move (a `wait`), a move of the shell's running in
    the background: the arm stops, and piped the input ends (seen: the shell went on
    reading its input, the test's pipe open, and never ended)."""
    shell = Proc("shell", stdin=True)
    try:
        shell.send("move base=-80 time=5000 &")
        shell.send("wait 60000")
        shell.out.wait_for("wait 60000 ms", CMD_S)
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        shell.popen.send_signal(signal.SIGINT)
        said = shell.out.wait_for("Ctrl-C: stop [", CMD_S)
        assert re.fullmatch(STOPPED_BY_LANE, said), said
        code, out, err = ended(shell)
    finally:
        shell.kill()
    assert code == exits.INTERRUPTED, (out, err)
    assert any(re.match(r"move \[\S+\]: cancelled", line) for line in out), out
    assert out[-1] == "Ctrl-C: the shell's input ends here: no line after it runs", out
    assert abs(arm.emu.servo_degrees()["base"] + 80) > 5  # halted on its way
    assert arm.peer.trigger("release").success


def test_ctrl_c_in_a_piped_shell_with_nothing_running_stops_nothing(arm: Served) -> None:
    """Nothing of the shell's runs: its Ctrl-C ends its input and stops no one's motion (the
    stop is the arm's, another client's move would be cut)."""
    seen = len(arm.states)
    shell = Proc("shell", stdin=True)
    try:
        shell.send("ready")
        assert ": done" in shell.out.wait_for("ready [", CMD_S)
        shell.popen.send_signal(signal.SIGINT)
        code, out, err = ended(shell)
    finally:
        shell.kill()
    assert code == exits.INTERRUPTED, (out, err)
    assert out[-1] == "Ctrl-C: the shell's input ends here: no line after it runs", out
    assert not [line for line in out if line.startswith("Ctrl-C: stop")], out
    assert "stopped" not in arm.states[seen:], arm.states[seen:]


def test_a_stop_typed_at_the_shells_terminal_while_a_move_runs_goes_at_once(
    arm: Served,
) -> None:
    """An outside try: `stop`, typed 1 s into a 5 s move, was read when the move had ended:
    the arm was never stopped, and locked when it was idle. It goes at once now, as
    Ctrl-C's stop does; a line typed before it waits its turn, as typed ahead in a shell."""
    shell = Tty([AL5D, "shell"])
    try:
        shell.wait_for(r"Ctrl-D ends\r\nal5d> ", CMD_S)
        shell.type("move base=80 time=5000\r")
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        shell.type("move elbow=30\rstop\r")  # a line for later, then the stop
        # The stop's answer and the move's outcome, in either order.
        said = (r"stop \[[^\]]+\]: done \(by the local lane\)", r"move \[[^\]]+\]: cancelled")
        wait_until(lambda: all(re.search(s, shell.drawn) for s in said), CMD_S, "both said")
        wait_until(lambda: "stopped" in arm.states, STATE_S, "stopped")
        assert abs(arm.emu.servo_degrees()["base"] - 80) > 5  # halted on its way
        # The line typed ahead runs after the move's outcome, drawn after a prompt: refused,
        # the arm locked by the stop typed after it.
        shell.wait_for(r"al5d> move elbow=30\r\nmove \[[^\]]+\]: refused", CMD_S)
        shell.type("release\r")
        shell.wait_for(r"release \[[^\]]+\]: done \(by the local lane\)", CMD_S)
        wait_until(lambda: arm.states[-1] == "ready", STATE_S, "ready")
        shell.type("exit\r")
        assert shell.proc.wait(CMD_S) == exits.NOT_DONE, shell.drawn  # the move cancelled
    finally:
        shell.close()


def test_a_ctrl_d_typed_while_a_move_runs_ends_the_shell_after_it_and_a_stop_still_goes(
    arm: Served,
) -> None:
    """A second reading: a Ctrl-D typed during a line ended the reading of what was typed,
    and a stop typed after it waited for the move's end (then went to the user's shell)."""
    shell = Tty([AL5D, "shell"])
    try:
        shell.wait_for(r"Ctrl-D ends\r\nal5d> ", CMD_S)
        shell.type("move base=80 time=5000\r")
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        shell.type("\x04")  # at the start of a line: the end of the input
        time.sleep(0.2)
        shell.type("stop\r")
        said = (r"stop \[[^\]]+\]: done \(by the local lane\)", r"move \[[^\]]+\]: cancelled")
        wait_until(lambda: all(re.search(s, shell.drawn) for s in said), CMD_S, "both said")
        assert abs(arm.emu.servo_degrees()["base"] - 80) > 5  # halted on its way
        assert shell.proc.wait(CMD_S) == exits.NOT_DONE, shell.drawn  # its input has ended
    finally:
        shell.close()


def test_ctrl_c_at_the_shells_terminal_stops_the_arm_and_prompts_again(arm: Served) -> None:
    """At a terminal Ctrl-C stops the arm and the prompt comes back: the user goes on."""
    shell = Tty([AL5D, "shell"])
    try:
        shell.wait_for(r"Ctrl-D ends\r\nal5d> ", CMD_S)
        shell.type("move base=80 time=5000\r")
        wait_until(lambda: arm.states[-1] == "moving", STATE_S, "moving")
        shell.proc.send_signal(signal.SIGINT)
        shell.wait_for(STOPPED_BY_LANE, CMD_S)
        shell.wait_for(r"move \[[^\]]+\]: cancelled.*\r\nal5d> ", CMD_S)
        wait_until(lambda: arm.states[-1] == "stopped", STATE_S, "stopped")
        assert abs(arm.emu.servo_degrees()["base"] - 80) > 5  # halted on its way
        shell.type("release\r")
        shell.wait_for(r"release \[[^\]]+\]: done \(by the local lane\)\r\nal5d> ", CMD_S)
        shell.type("exit\r")
        assert shell.proc.wait(CMD_S) == exits.NOT_DONE, shell.drawn  # the move cancelled
    finally:
        shell.close()
