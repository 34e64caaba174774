"""`al5d doctor` (issue 27): against the emulator's pty (right and wrong baud), against
paths that are no board, a port it may not open, a port another program holds; the USB
matching on pyserial's own `ListPortInfo`, and the latency timer on a sysfs tree.

Each `al5d doctor` is a process of its own on an emulated board in this one (or on
`al5d emulator`, a process too). No USB here: a board's listing is pyserial's class
filled in as `comports()` fills it, and the latency timer is read from a directory laid
out as /sys/bus/usb-serial/devices is.
"""

from __future__ import annotations

import io
import os
import pickle
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
import yaml
from serial.tools.list_ports_common import ListPortInfo

from al5d import exits
from al5d.app import doctor as doc
from al5d.arm.config import DEFAULT_CONFIG, ArmConfig
from al5d.ssc32u.emulator import Emulator
from al5d_rig.proc import Proc

DOCTOR_S = 60.0


def run_doctor(*args: str) -> tuple[int, list[str]]:
    proc = Proc("doctor", *args)
    code = proc.wait(DOCTOR_S)
    return code, proc.out.drain() + proc.err.drain()


def config_with(tmp_path: Path, **server: object) -> str:
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["server"].update(server)
    path = tmp_path / "arm.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


def problems(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("PROBLEM")]


@pytest.fixture
def board(config: ArmConfig, tmp_path: Path) -> Iterator[Emulator]:
    with Emulator(config, baud=9600, link=tmp_path / "ssc32u") as emu:
        yield emu


def test_the_emulator_passes_every_check(board: Emulator) -> None:
    code, lines = run_doctor("--port", board.port)
    assert code == exits.DONE, lines
    assert problems(lines) == []
    text = "\n".join(lines)
    assert "SSC32-V2.50USB answered VER at 9600" in text
    assert f"{board.port}: a serial port, free" in text
    assert "channels base 0, shoulder 1, elbow 2, wrist 3, gripper 4, wrist_rotate 5" in text
    assert lines[-1] == "al5d doctor: no problem found"


def test_at_the_wrong_baud_the_board_is_found_at_its_own(tmp_path: Path) -> None:
    """`al5d emulator --baud 38400`; the configuration says 9600, which doctor tries first."""
    link = tmp_path / "ssc32u"
    emu = Proc("emulator", "--baud", "38400", "--link", str(link))
    try:
        emu.err.wait_for("al5d emulator: SSC-32U at 38400 baud", 30)
        code, lines = run_doctor("--port", str(link))
        assert code == exits.NOT_DONE, lines
        text = "\n".join(lines)
        assert "answered VER at 38400 (before it, 9600: no answer)" in text
        assert problems(lines) == [
            "PROBLEM  config: server.baud is 9600, the board answers at 38400"
        ]
        assert "set server.baud: 38400" in text
        # With the board's baud in the configuration, it is asked first and all is well.
        code, lines = run_doctor("--port", str(link), "--config", config_with(tmp_path, baud=38400))
        assert code == exits.DONE, lines
        assert any("answered VER at 38400" in line and "before" not in line for line in lines)
    finally:
        emu.kill()


def test_a_device_that_answers_nothing_is_said_at_every_baud() -> None:
    # A pty nobody answers on: the other end is opened and never read.
    master, slave = os.openpty()
    try:
        code, lines = run_doctor("--port", os.ttyname(slave))
        assert code == exits.NOT_DONE, lines
        (problem,) = problems(lines)
        assert "no SSC-32U answered VER at 9600, 38400, 115200 baud" in problem
        assert "9600: no answer; 38400: no answer; 115200: no answer" in problem
    finally:
        os.close(slave)
        os.close(master)


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        ("missing", "port: {path}: no such device"),
        ("dangling", "port: {path}: no such device (a link to a device that is gone)"),
        ("file", "port: {path}: a regular file, not a serial device"),
        ("directory", "port: {path}: a directory, not a serial device"),
        ("null", "port: /dev/null: a character device but no serial port (not a terminal)"),
    ],
)
def test_a_path_that_is_no_board_is_said_with_what_to_do(
    tmp_path: Path, make: str, problem: str
) -> None:
    path = tmp_path / "port"
    if make == "dangling":
        path.symlink_to(tmp_path / "gone")
    elif make == "file":
        path.write_text("not a board\n")
    elif make == "directory":
        path.mkdir()
    elif make == "null":
        path = Path("/dev/null")
    code, lines = run_doctor("--port", str(path))
    assert code == exits.NOT_DONE, lines
    assert problems(lines) == [f"PROBLEM  {problem.format(path=path)}"], lines
    assert lines[lines.index(problems(lines)[0]) + 1].lstrip().startswith("do: ")
    assert not any("VER" in line for line in lines)  # nothing asked of what is no port


def test_a_port_another_program_holds_is_said(board: Emulator) -> None:
    with serial.Serial(board.port, exclusive=True):  # as al5d serve holds it
        code, lines = run_doctor("--port", board.port)
    assert code == exits.NOT_DONE, lines
    assert problems(lines) == [
        f"PROBLEM  port: {board.port}: a serial port, held by another program "
        "(a running al5d serve?)"
    ]


def port_checks_unprivileged(port: str) -> list[doc.Check]:
    """`al5d doctor`'s port checks as a user the file modes bind: as `nobody` when the tests
    run as root (whom no mode stops), as ourselves otherwise.

    Not a process of `al5d doctor` as `nobody`: this machine's Python lives where only root
    may enter (/root). So a forked child of this process drops to nobody (setgroups, setgid,
    setuid: for good) and runs the same checks the command runs, handing them back by pipe.
    """
    if os.geteuid() != 0:
        return doc.check_port(port)
    read, write = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover (the child)
        code = 1
        try:
            os.close(read)
            os.setgroups([])
            os.setgid(65534)
            os.setuid(65534)
            assert os.geteuid() == 65534 and os.getgroups() in ([], [65534])
            with os.fdopen(write, "wb") as pipe:
                pickle.dump(doc.check_port(port), pipe)
            code = 0
        finally:
            os._exit(code)
    os.close(write)
    with os.fdopen(read, "rb") as pipe:
        data = pipe.read()
    _, status = os.waitpid(child, 0)
    assert os.waitstatus_to_exitcode(status) == 0, "the unprivileged child failed"
    checks: list[doc.Check] = pickle.loads(data)
    return checks


def said(checks: list[doc.Check]) -> str:
    return "\n".join(line for check in checks for line in check.lines())


def test_a_port_only_its_owner_may_open_asks_for_a_udev_rule(board: Emulator) -> None:
    device = board.device  # the pty itself: the link is in a directory only root may enter
    # As root, os.access and open say yes whatever the mode: no test of ours could see it.
    assert os.geteuid() != 0 or os.access(device, os.R_OK | os.W_OK)
    os.chmod(device, 0o000)
    if os.geteuid() == 0:
        advice = 'GROUP="dialout", MODE="0660"'
    else:
        advice = f"it is yours, but its mode forbids you: chmod u+rw {device}"
    text = said(port_checks_unprivileged(device))
    assert f"PROBLEM  permission: {device}: you may not read and write it (c---------" in text
    assert advice in text, text


def test_a_port_of_a_group_says_which_group_to_join(board: Emulator) -> None:
    device = board.device
    if os.geteuid() == 0:
        os.chown(device, 0, 20)  # dialout's gid on Debian and Ubuntu; nobody is not in it
        os.chmod(device, 0o660)
        group = doc._group(20)
        advice = f"join the group {group}: sudo usermod -aG {group} nobody"
    else:  # a user cannot give a file away: the owner's own bits forbid the owner
        os.chmod(device, 0o060)
        advice = f"it is yours, but its mode forbids you: chmod u+rw {device}"
    checks = port_checks_unprivileged(device)
    assert [c.ok for c in checks] == [False], said(checks)
    assert f"PROBLEM  permission: {device}: you may not read and write it" in said(checks)
    assert advice in said(checks)
    # And with the group's rights, the same checks pass: the mode, not the check, decided.
    os.chmod(device, 0o666)
    assert all(c.ok for c in port_checks_unprivileged(device)), said(checks)


def ftdi(device: str, pid: int = 0x6001) -> ListPortInfo:
    """A port as pyserial's Linux listing fills it for an FTDI chip."""
    port = ListPortInfo(device, skip_link_detection=True)
    port.vid, port.pid = 0x0403, pid
    port.serial_number, port.product = "A50285BI", "FT232R USB UART"
    port.apply_usb_info()
    return port


def other(device: str, vid: int | None, pid: int | None) -> ListPortInfo:
    port = ListPortInfo(device, skip_link_detection=True)
    port.vid, port.pid = vid, pid
    if vid is not None:
        port.apply_usb_info()
    return port


def test_boards_are_found_by_the_ftdi_chips_ids() -> None:
    ports = [
        ftdi("/dev/ttyUSB0"),
        ftdi("/dev/ttyUSB1", 0x6015),
        other("/dev/ttyUSB2", 0x0403, 0x6010),  # an FTDI dual-port chip: no SSC-32U
        other("/dev/ttyUSB3", 0x10C4, 0xEA60),  # a CP2102 adapter
        other("/dev/ttyACM0", 0x2341, 0x0043),  # an Arduino
        other("/dev/ttyS0", None, None),
    ]
    boards, check = doc.find_boards(ports)
    assert [b.device for b in boards] == ["/dev/ttyUSB0", "/dev/ttyUSB1"]
    assert check.ok and "0403:6001, FT232R" in check.found and "0403:6015, FT-X" in check.found
    none, missing = doc.find_boards(ports[2:])
    assert none == [] and not missing.ok
    assert "/dev/ttyUSB3 (10c4:ea60" in missing.found and "/dev/ttyS0 (no USB id)" in missing.found


def test_without_port_it_checks_each_board_the_listing_finds(board: Emulator) -> None:
    out = io.StringIO()
    code = doc.doctor(
        None, None, out=out, listed=[ftdi(board.port), other("/dev/ttyS0", None, None)]
    )
    lines = out.getvalue().splitlines()
    assert code == exits.DONE, lines
    assert f"an SSC-32U's FTDI chip at {board.port} (0403:6001, FT232R" in lines[1]
    assert any(f"{board.port}: SSC32-V2.50USB answered VER at 9600" in line for line in lines)


def test_without_port_and_no_board_on_usb_it_says_what_to_plug() -> None:
    out = io.StringIO()
    code = doc.doctor(None, None, out=out, listed=[other("/dev/ttyS0", None, None)])
    assert code == exits.NOT_DONE
    assert "PROBLEM  USB: no FTDI chip (0403:6001 or 0403:6015)" in out.getvalue()
    assert "al5d doctor --port /dev/ttyUSB0" in out.getvalue()


@pytest.mark.parametrize(
    ("timer", "ok", "said"),
    [
        (None, True, "none ("),
        ("1", True, ": 1 ms"),
        ("16", False, "16 ms, and low-latency mode cannot be set here"),
    ],
)
def test_the_latency_timer_from_sysfs(
    board: Emulator, tmp_path: Path, timer: str | None, ok: bool, said: str
) -> None:
    sysfs = tmp_path / "sysfs"
    tty = sysfs / os.path.basename(board.device)
    tty.mkdir(parents=True)
    if timer is not None:
        (tty / "latency_timer").write_text(f"{timer}\n")
    check = doc.check_latency(board.port, sysfs)
    assert check.ok is ok and said in check.found, check
    if not ok:
        assert f"echo 1 | sudo tee {tty / 'latency_timer'}" in check.todo


def test_a_bad_configuration_is_a_problem_naming_its_key(board: Emulator, tmp_path: Path) -> None:
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["joints"]["elbow"]["channel"] = data["joints"]["base"]["channel"]
    path = tmp_path / "arm.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    code, lines = run_doctor("--port", board.port, "--config", str(path))
    assert code == exits.NOT_DONE, lines
    (problem,) = problems(lines)
    assert "joints.elbow.channel: channel 0 is already used by base" in problem
    assert problem.count(str(path)) == 1, problem  # the file named once
    # The board is still checked, at the factory baud.
    assert any("answered VER at 9600" in line for line in lines)
    code, lines = run_doctor("--port", board.port, "--config", str(tmp_path / "none.yaml"))
    (problem,) = problems(lines)
    assert "none.yaml: cannot read the configuration" in problem, problem
    assert "give the path of a configuration file" in lines[lines.index(problem) + 1], lines
