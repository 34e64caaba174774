"""`al5d calibrate` driven through its stdin, against `al5d serve` on an emulated arm whose
joints stand elsewhere than its config says: every nudge a move through the server."""

from __future__ import annotations

import os
import pty
import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from al5d import exits
from al5d.app.calibrate import Command, parse_command, server_config
from al5d.arm.config import ArmConfig, load_config
from al5d.ros.names import Names
from al5d.ros.physical import PhysicalPublisher
from al5d.ssc32u.emulator import Emulator, Mechanics
from al5d_rig.calibuser import User, truth
from al5d_rig.proc import AL5D, Lines, Proc, patient_config_text

STEP_US = 5
MECHANICS = {"base": Mechanics(42), "elbow": Mechanics(-20, reversed=True)}
HEADER = re.compile(r"^(\w+) \(\d of \d\), reference (\d) of 2: (-?[\d.]+) deg")
PROMPT = "nudge until it is there"


@pytest.fixture
def arm_file(tmp_path: Path) -> Path:
    """The shipped file, comments and all, with a patient answer timeout (a board that is a
    thread of a busy test process)."""
    path = tmp_path / "arm.yaml"
    path.write_text(patient_config_text(), "utf-8")
    return path


@pytest.fixture
def server(config: ArmConfig, arm_file: Path, tmp_path: Path) -> Iterator[Emulator]:
    """`al5d serve` with `arm_file` on a misaligned emulated arm, named as a user in its
    directory would (a relative path); the board."""
    link = tmp_path / "ssc32u"
    emu = Emulator(config, link=link, mechanics=MECHANICS).start()
    given = ("--config", arm_file.name)
    proc = Proc("serve", "--port", str(link), *given, "--log-level", "INFO", cwd=arm_file.parent)
    try:
        proc.err.wait_for("STATE: ready", 30)
        yield emu
    finally:
        proc.kill()
        emu.close()


def test_commands() -> None:
    assert parse_command(" + ") == Command("nudge", 1)
    assert parse_command("-12") == Command("nudge", -12)
    assert parse_command("OK") == Command("ok")
    for bad in ("+0", "+x", "++", "-1001", "forward"):
        with pytest.raises(ValueError, match="a line each"):
            parse_command(bad)


def test_calibrate_through_its_stdin_finds_the_offsets_and_writes_the_file(
    config: ArmConfig, server: Emulator, arm_file: Path, tmp_path: Path
) -> None:
    # Another file than the server's: its pulses would be misread; refused, nothing moved.
    other = tmp_path / "other.yaml"
    other.write_text(arm_file.read_text("utf-8"), "utf-8")
    wrong = Proc("calibrate", "--config", str(other), "--wait", "30")
    assert wrong.wait(60) == exits.USAGE
    assert f"the server runs with {arm_file}" in "\n".join(wrong.err.drain())
    # The server's file by its name in another directory, where a file has that name: that
    # one is another file (an outside try: it was written, the server's left as it was).
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / arm_file.name).write_text(arm_file.read_text("utf-8"), "utf-8")
    decoy = Proc("calibrate", "--config", arm_file.name, "--wait", "30", cwd=elsewhere)
    assert decoy.wait(60) == exits.USAGE
    assert f"the server runs with {arm_file}, not {arm_file.name}" in "\n".join(decoy.err.drain())

    before = arm_file.read_text("utf-8")
    cal = Proc(
        "calibrate",
        *("--joints", "base,elbow", "--step", str(STEP_US), "--time", "300", "--wait", "30"),
        *("--config", str(arm_file)),  # on a shared host, never another test's server's file
        stdin=True,
    )
    try:
        for _ in range(4):  # two joints, two references each
            header = HEADER.match(cal.out.wait_for(" of 2: ", 60))
            assert header is not None
            name, deg = header[1], float(header[3])
            joint = config.joints[name]
            user = User(joint, deg, STEP_US)
            cal.out.wait_for(PROMPT, 60)
            for _ in range(100):
                true = server.joint_degrees(server.settle_time(0.01, [name]))[name]
                steps = user.nudge(true)
                if steps is None:
                    break
                while True:
                    cal.send(f"{steps:+d}")
                    line = cal.out.wait_for("  ", 60)
                    if "not moved" not in line:
                        assert PROMPT in line
                        break
                    cal.out.wait_for(PROMPT, 60)
                    steps = user.refused(true)
                user.saw(true, server.joint_degrees(server.settle_time(0.01, [name]))[name])
            else:
                raise AssertionError(f"{name} never reached {deg} deg")
            cal.send("ok")
        cal.out.wait_for(f"write the calibration of base, elbow into {arm_file}? (y/n)", 60)
        cal.send("y")
        assert cal.wait(60) == exits.DONE
    finally:
        cal.kill()
    out = "\n".join(cal.out.drain())
    assert re.search(r"^base: offset \+4\d us at 0 deg, \+4\d us at 45 deg", out, re.M), out
    assert re.search(r"^elbow: .*REVERSED", out, re.M), out
    written = re.search(r"^written: (\S+) \(the file as it was: (\S+)\)$", out, re.M)
    assert written is not None, out
    assert Path(written[1]) == arm_file
    backup = Path(written[2])
    assert backup.parent == arm_file.parent and backup.name.endswith(".bak")
    assert backup.read_text("utf-8") == before
    assert f"--- {backup}\n+++ {arm_file}\n" in out + "\n"
    assert "+    calibration: [{deg: 0, us: 15" in out  # base's, 42 us off at 0 deg
    again = load_config(arm_file)
    for name, mech in MECHANICS.items():
        old, new = config.joints[name], again.joints[name]
        for point in new.calibration:
            assert abs(point.us - truth(old, mech, point.deg)) <= STEP_US, (name, point)
    # Only the two joints' lines changed; every comment kept.
    changed = [
        (a, b)
        for a, b in zip(before.splitlines(), arm_file.read_text("utf-8").splitlines(), strict=True)
        if a != b
    ]
    assert len(changed) == 2 and all("calibration:" in a for a, _ in changed)


TRULY = re.compile(r"the emulated arm's base truly stands at -?[\d.]+ deg: ([+-][\d.]+) deg off")


def test_an_emulated_arm_says_how_far_the_joint_truly_is_off(
    config: ArmConfig, server: Emulator, arm_file: Path
) -> None:
    """Where the emulated arm truly stands is published (as `al5d emulator --misalign`
    does): each nudge says how far the joint is off its reference, and the nudges close it."""
    physical = PhysicalPublisher(Names(), config.model).start(server.joint_degrees)
    cal = Proc(
        *("calibrate", "--joints", "base", "--time", "300", "--wait", "30"),
        *("--config", str(arm_file)),
        stdin=True,
    )
    try:
        line = cal.out.wait_for("truly stands at", 60)
        found = TRULY.search(line)
        assert found is not None, line
        assert 3.0 < abs(float(found[1])) < 5.0, line  # 42 us: about 4 degrees
        cal.out.wait_for(PROMPT, 60)
        cal.send("+8")  # 40 us: within 2 us of the truth
        line = cal.out.wait_for("truly stands at", 60)
        found = TRULY.search(line)
        assert found is not None, line
        assert abs(float(found[1])) < 0.5, line
        cal.out.wait_for(PROMPT, 60)
        cal.send("quit")
        assert cal.wait(60) == exits.NOT_DONE
    finally:
        cal.kill()
        physical.close()


def test_quitting_writes_nothing(server: Emulator, arm_file: Path) -> None:
    before = arm_file.read_text("utf-8")
    cal = Proc(
        *("calibrate", "--joints", "wrist", "--time", "300", "--wait", "30"),
        *("--config", str(arm_file)),
        stdin=True,
    )
    try:
        assert cal.out.wait_for(PROMPT, 60).endswith(f"{PROMPT}, then ok")
        cal.send("+2")
        cal.out.wait_for(PROMPT, 60)
        cal.send("sideways")
        cal.out.wait_for("'sideways': a line each", 60)
        cal.send("quit")
        assert cal.wait(60) == exits.NOT_DONE
    finally:
        cal.kill()
    assert "nothing written" in cal.out.drain()[-1]
    assert arm_file.read_text("utf-8") == before
    assert list(arm_file.parent.glob("*.bak")) == []


def test_a_file_changed_since_the_server_started_is_not_calibrated(
    server: Emulator, arm_file: Path
) -> None:
    """The procedure reads the file's pulses, the server turns degrees into pulses by the
    calibration it started with: where the two differ (a calibration written, the server
    not restarted), an outside try's second run wrote a calibration 40 us off, exit 0.
    Now it says so and writes nothing."""
    shipped = "calibration: [{deg: -90, us: 600}, {deg: 90, us: 2400}]"
    text = arm_file.read_text("utf-8")
    wrist = text.index("\n  wrist:\n")  # the first such calibration after it is the wrist's
    assert text.index(shipped, wrist) < text.index("\n  gripper:\n"), text
    changed = text[:wrist] + text[wrist:].replace(
        shipped, "calibration: [{deg: -90, us: 640}, {deg: 90, us: 2440}]", 1
    )
    arm_file.write_text(changed, "utf-8")
    cal = Proc(
        *("calibrate", "--joints", "wrist", "--wait", "30", "--config", str(arm_file)),
        stdin=True,
    )
    try:
        assert cal.wait(60) == exits.USAGE
    finally:
        cal.kill()
    said = "\n".join(cal.err.drain())
    assert "the calibration of wrist differs from the one the server drives the arm with" in said
    assert "nothing written" in said
    assert arm_file.read_text("utf-8") == changed


def test_calibrate_at_a_terminal_takes_single_keys(server: Emulator, arm_file: Path) -> None:
    """On a terminal (a pty here): a key each, no Enter after it, Enter itself accepts."""
    main, terminal = pty.openpty()
    popen = subprocess.Popen(
        [AL5D, "calibrate", "--joints", "base", "--time", "300", "--config", str(arm_file)],
        stdin=terminal,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    os.close(terminal)
    assert popen.stdout is not None and popen.stderr is not None
    out, err = Lines(popen.stdout), Lines(popen.stderr)
    try:
        out.wait_for("keys: + - one step", 60)
        out.wait_for(f"{PROMPT}, then Enter", 60)  # the key the help names, not a word
        # 42 us off: ten steps on (+50), two back (+40); the same at the second reference.
        for keys, seen in (
            ("]", "base at 1550 us"),
            ("--", "base at 1540 us"),
            ("\r", "reference 2 of 2"),
            ("]--", "base at 1990 us"),
            ("\r", "(y/n)"),
            ("y", "written: "),
        ):
            os.write(main, keys.encode())
            out.wait_for(seen, 60)
        assert popen.wait(60) == exits.DONE, "\n".join(out.drain() + err.drain())
    finally:
        if popen.poll() is None:
            popen.kill()
        os.close(main)
    assert load_config(arm_file).joints["base"].calibration[0].us == 1540


def test_a_file_the_server_did_not_name_is_not_written(tmp_path: Path) -> None:
    """The pulses found are the server's file's: a `--config` is written only once the
    server has said that it runs with it (before, one it did not answer for was written
    unchecked)."""
    given = tmp_path / "al5d.yaml"
    path, why = server_config(None, str(given))
    assert path is None and "did not say which config_file it runs with" in why
    assert server_config(given, str(given)) == (given, "")
    assert server_config(given, None) == (given, "")
