"""`al5d doctor`: what stands between this computer and its SSC-32U, each check said with
what to do about a problem.

The checks, in order: the configuration (its channels), the board among the USB serial
ports (by its FTDI chip's identity), then for each board the port (there, a serial
device, ours to open, free), the USB chip's latency timer, the baud (`VER` at each baud
the board can run at, the configuration's first), and the configuration's baud and
channels against the board found. A check that needs the one before is left out after
a problem.
"""

from __future__ import annotations

import errno
import grp
import os
import pwd
import stat
import sys
import termios
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from serial.tools.list_ports_common import ListPortInfo

from al5d import exits
from al5d.arm.config import ArmConfig, ConfigError, load_config
from al5d.ssc32u.errors import NotAnSSC32U, SerialFault
from al5d.ssc32u.facts import BAUDS, FACTORY_BAUD, LOW_LATENCY_TIMER_MS

#: The SSC-32U's USB port is an FTDI USB serial chip (vendor 0403). Which FTDI single-port
#: chip a given board carries is not in the guide at hand: these are FTDI's default product
#: ids for the FT232R (6001) and the FT-X series, FT231X included (6015). `VER` decides.
FTDI_VENDOR = 0x0403
FTDI_PRODUCTS = {0x6001: "FT232R", 0x6015: "FT-X"}
#: Where Linux's usb-serial drivers show each port's settings (ftdi_sio: latency_timer).
SYSFS_USB_SERIAL = Path("/sys/bus/usb-serial/devices")
#: The group that owns serial ports on Debian, Ubuntu and Fedora (Arch: uucp).
SERIAL_GROUP = "dialout"
UDEV_RULE = (
    'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", GROUP="dialout", MODE="0660" '
    "in /etc/udev/rules.d/99-ssc32u.rules"
)


@dataclass(frozen=True)
class Check:
    """One check's finding: `ok`, what was found, and for a problem what to do."""

    name: str
    ok: bool
    found: str
    todo: str = ""

    def lines(self) -> list[str]:
        head = f"{'ok' if self.ok else 'PROBLEM':8} {self.name}: {self.found}"
        return [head] + ([f"{'':8} do: {self.todo}"] if self.todo else [])


def usb_id(port: ListPortInfo) -> str:
    return f"{port.vid:04x}:{port.pid:04x}" if port.vid is not None else "no USB id"


def is_board(port: ListPortInfo) -> bool:
    """Whether a listed port has the SSC-32U's USB identity (its FTDI chip's ids)."""
    return port.vid == FTDI_VENDOR and port.pid in FTDI_PRODUCTS


def find_boards(ports: Iterable[ListPortInfo]) -> tuple[list[ListPortInfo], Check]:
    """The ports that look like an SSC-32U, and the check that says so."""
    listed = list(ports)
    boards = [p for p in listed if is_board(p)]
    ids = " or ".join(f"{FTDI_VENDOR:04x}:{pid:04x}" for pid in FTDI_PRODUCTS)
    if boards:
        found = ", ".join(f"{p.device} ({_describe(p)})" for p in boards)
        return boards, Check("USB", True, f"an SSC-32U's FTDI chip at {found}")
    others = ", ".join(f"{p.device} ({_describe(p)})" for p in listed) or "none"
    return boards, Check(
        "USB",
        False,
        f"no FTDI chip ({ids}) among the serial ports; the ports: {others}",
        "plug the board's USB cable in (a data cable; the board's own power is separate); "
        "`lsusb` should list 0403; or name its port: al5d doctor --port /dev/ttyUSB0",
    )


def _describe(port: ListPortInfo) -> str:
    chip = FTDI_PRODUCTS.get(port.pid or -1, "") if port.vid == FTDI_VENDOR else ""
    serial = f"serial {port.serial_number}" if port.serial_number else ""
    return ", ".join(w for w in (usb_id(port), chip, port.product or "", serial) if w)


def identity(path: str, ports: Iterable[ListPortInfo]) -> Check:
    """What the USB listing says of the port named on the command line."""
    real = os.path.realpath(path)
    for port in ports:
        if os.path.realpath(port.device) == real:
            if is_board(port):
                return Check("USB", True, f"{path}: an SSC-32U's FTDI chip ({_describe(port)})")
            return Check(
                "USB",
                True,
                f"{path}: {_describe(port)}, not the SSC-32U's FTDI chip (another adapter, "
                "on the board's TTL header?); VER below decides",
            )
    return Check("USB", True, f"{path}: not a USB serial port (the emulator's pty?)")


def _mode(st: os.stat_result) -> str:
    return f"{stat.filemode(st.st_mode)} {_user(st.st_uid)}:{_group(st.st_gid)}"


def _user(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def _group(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _permission_todo(path: str, st: os.stat_result) -> str:
    """What to do when the port may not be opened: the group to join, or a rule to write."""
    if st.st_uid == os.getuid():
        return f"it is yours, but its mode forbids you: chmod u+rw {path}"
    group_rw = st.st_mode & (stat.S_IRGRP | stat.S_IWGRP) == stat.S_IRGRP | stat.S_IWGRP
    if not group_rw or st.st_gid == 0:
        return f"only its owner may open it: give it a group with a udev rule: {UDEV_RULE}"
    group = _group(st.st_gid)
    user = _user(os.getuid())
    try:
        members = grp.getgrgid(st.st_gid).gr_mem
    except KeyError:
        members = []
    if user in members and st.st_gid not in os.getgroups():
        return (
            f"you are in the group {group}, but this login is not yet: log out and back in "
            f"(or run: newgrp {group})"
        )
    return f"join the group {group}: sudo usermod -aG {group} {user}, then log out and back in"


def check_port(path: str) -> list[Check]:
    """The port is there, a serial device, ours to read and write, and no one else's.
    Stops at the first problem (each needs the one before)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        dangling = " (a link to a device that is gone)" if os.path.islink(path) else ""
        return [
            Check(
                "port",
                False,
                f"{path}: no such device{dangling}",
                "plug the board in, check the path (al5d doctor without --port lists the "
                "boards on USB; ls /dev/ttyUSB* /dev/serial/by-id/)",
            )
        ]
    except OSError as e:
        return [Check("port", False, f"{path}: {e.strerror}", "check the path")]
    if not stat.S_ISCHR(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "a regular file"
        return [
            Check(
                "port",
                False,
                f"{path}: {kind}, not a serial device",
                "name the board's device, e.g. /dev/ttyUSB0",
            )
        ]
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except PermissionError:
        return [
            Check(
                "permission",
                False,
                f"{path}: you may not read and write it ({_mode(st)})",
                _permission_todo(path, st),
            )
        ]
    except OSError as e:
        busy = e.errno == errno.EBUSY
        todo = "another program holds it: stop it" if busy else "check the cable and the board"
        return [Check("port", False, f"{path}: cannot open: {e.strerror}", todo)]
    try:
        checks = [Check("permission", True, f"{path}: yours to read and write ({_mode(st)})")]
        try:
            termios.tcgetattr(fd)
        except termios.error:
            checks.append(
                Check(
                    "port",
                    False,
                    f"{path}: a character device but no serial port (not a terminal)",
                    "name the board's device, e.g. /dev/ttyUSB0",
                )
            )
            return checks
        checks.append(_free(path, fd))
        return checks
    finally:
        os.close(fd)


def _free(path: str, fd: int) -> Check:
    """No other program holds the port as the server does (pyserial's exclusive lock)."""
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return Check(
            "port",
            False,
            f"{path}: a serial port, held by another program (a running al5d serve?)",
            f"stop that program first; `fuser -v {path}` names it",
        )
    fcntl.flock(fd, fcntl.LOCK_UN)
    return Check("port", True, f"{path}: a serial port, free")


def check_latency(path: str, sysfs: Path = SYSFS_USB_SERIAL) -> Check:
    """The FTDI chip's latency timer, and whether the low-latency mode the server asks for
    at start can be set here (it sets the timer to 1 ms)."""
    tty = os.path.basename(os.path.realpath(path))
    timer = sysfs / tty / "latency_timer"
    try:
        ms = int(timer.read_text().strip())
    except FileNotFoundError:
        return Check(
            "latency timer",
            True,
            f"{path}: none ({timer} is not there: no USB serial chip, as on a pty)",
        )
    except (OSError, ValueError) as e:
        return Check("latency timer", False, f"{timer}: cannot read it: {e}", "run as root once")
    if ms <= LOW_LATENCY_TIMER_MS:
        return Check("latency timer", True, f"{path}: {ms} ms")
    if _low_latency_settable(path):
        return Check(
            "latency timer",
            True,
            f"{path}: {ms} ms now; the low-latency mode that al5d serve sets at start "
            f"takes it to {LOW_LATENCY_TIMER_MS} ms (tried and undone)",
        )
    return Check(
        "latency timer",
        False,
        f"{path}: {ms} ms, and low-latency mode cannot be set here: every answer of the "
        f"board waits {ms} ms in the USB chip",
        f"echo 1 | sudo tee {timer}, or for good a udev rule: "
        'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1"',
    )


def _low_latency_settable(path: str) -> bool:
    import serial

    try:
        with serial.Serial(path, exclusive=True) as port:
            port.set_low_latency_mode(True)
            port.set_low_latency_mode(False)
    except (OSError, ValueError, AttributeError, serial.SerialException):
        return False
    return True


@dataclass(frozen=True)
class BaudFound:
    """Which baud the board answered `VER` at (None: none), what it said, what the others
    received."""

    baud: int | None
    firmware: str
    tried: tuple[tuple[int, str], ...]
    pulses: dict[int, int]


def find_baud(path: str, first: int, channels: Sequence[int] = ()) -> BaudFound:
    """Ask `VER` at `first`, then at each other baud the board can run at, until one is
    answered; there, read the pulses of `channels` (a `QP`, as cheap)."""
    from al5d.ssc32u.driver import SSC32U

    tried: list[tuple[int, str]] = []
    for baud in (first, *(b for b in BAUDS if b != first)):
        try:
            with SSC32U(path, baud) as board:
                pulses = board.read_pulses(channels) if channels else {}
                return BaudFound(baud, board.firmware, tuple(tried), pulses)
        except NotAnSSC32U as e:
            got = f"received {e.received!r}" if e.received else "no answer"
            tried.append((baud, got))
        except SerialFault as e:
            tried.append((baud, e.what))
    return BaudFound(None, "", tuple(tried), {})


def check_baud(path: str, found: BaudFound) -> Check:
    others = "; ".join(f"{baud}: {got}" for baud, got in found.tried)
    if found.baud is None:
        return Check(
            "baud",
            False,
            f"{path}: no SSC-32U answered VER at {', '.join(map(str, BAUDS))} baud ({others})",
            "check the board's power (its USB chip answers without it, the board does not), "
            "the cable, and that this is the board's port",
        )
    before = f" (before it, {others})" if others else ""
    return Check("baud", True, f"{path}: {found.firmware} answered VER at {found.baud}{before}")


def check_config(path: str | None) -> tuple[ArmConfig | None, Check]:
    name = path or "the shipped configuration"
    try:
        config = load_config(path)
    except ConfigError as e:  # its text names the file
        todo = (
            "fix what it names"
            if path is None or Path(path).is_file()
            else "give the path of a configuration file (--config FILE), or none for the "
            "shipped one"
        )
        return None, Check("config", False, str(e).replace("\n", "; "), todo)
    channels = ", ".join(f"{j} {joint.channel}" for j, joint in config.joints.items())
    return config, Check(
        "config",
        True,
        f"{name}: channels {channels}: distinct, within 0..31, each joint's range within its "
        "servo's pulses; baud " + str(config.server.baud),
    )


def check_against_board(config: ArmConfig, found: BaudFound, config_name: str) -> list[Check]:
    """The configuration's baud against the board's, and what the board puts out on the
    configuration's channels."""
    checks: list[Check] = []
    assert found.baud is not None
    if config.server.baud != found.baud:
        checks.append(
            Check(
                "config",
                False,
                f"server.baud is {config.server.baud}, the board answers at {found.baud}",
                f"set server.baud: {found.baud} in {config_name} (or al5d serve --baud "
                f"{found.baud}), or press the board's baud button until its LEDs say "
                f"{config.server.baud}",
            )
        )
    if found.pulses:
        by_channel = {joint.channel: name for name, joint in config.joints.items()}
        pulses = ", ".join(f"{by_channel[ch]} {us}" for ch, us in sorted(found.pulses.items()))
        silent = [by_channel[ch] for ch, us in found.pulses.items() if us == 0]
        note = (
            f"; none yet on {', '.join(silent)}: the first park moves those at full speed"
            if silent
            else ""
        )
        checks.append(Check("channels", True, f"the board's pulses now (us): {pulses}{note}"))
    return checks


def doctor(
    port: str | None,
    config_path: str | None,
    *,
    out: TextIO = sys.stdout,
    listed: Iterable[ListPortInfo] | None = None,
    sysfs: Path = SYSFS_USB_SERIAL,
) -> int:
    """Every check, a line each; `exits.NOT_DONE` if any found a problem.

    `listed`: the serial ports (pyserial's listing when None)."""
    if listed is None:
        from serial.tools.list_ports import comports

        listed = comports()
    ports = list(listed)
    checks: list[Check] = []

    def say(*new: Check) -> None:
        for check in new:
            checks.append(check)
            for line in check.lines():
                print(line, file=out, flush=True)

    config, config_check = check_config(config_path)
    say(config_check)
    if port is None:
        boards, found_check = find_boards(ports)
        say(found_check)
        paths = [b.device for b in boards]
    else:
        if os.path.exists(port):
            say(identity(port, ports))
        paths = [port]
    for path in paths:
        port_checks = check_port(path)
        say(*port_checks)
        if not all(c.ok for c in port_checks):
            continue
        say(check_latency(path, sysfs))
        first = config.server.baud if config is not None else FACTORY_BAUD
        channels = config.channels if config is not None else ()
        found = find_baud(path, first, channels)
        say(check_baud(path, found))
        if config is not None and found.baud is not None:
            say(*check_against_board(config, found, config_path or "your configuration"))
    problems = sum(not c.ok for c in checks)
    if problems:
        print(f"al5d doctor: {problems} problem{'s' * (problems > 1)} found", file=out)
        return exits.NOT_DONE
    print("al5d doctor: no problem found", file=out)
    return exits.DONE
