"""`al5d emulator` as a process of its own, driven by the low-level driver."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from al5d import exits
from al5d.app.cli import build_parser
from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.emulator import Emulator, Mechanics, Record
from al5d.ssc32u.emulator.pty import ChooseAnotherLink
from al5d_rig.boardproc import BoardProcess
from al5d_rig.proc import Proc, said, to_another_thread
from al5d_rig.rospeer import wait_until

AL5D = Path(sys.executable).with_name("al5d")


def test_standalone_emulator(tmp_path: Path) -> None:
    link = tmp_path / "ssc32u"
    proc = subprocess.Popen(
        [str(AL5D), "emulator", "--baud", "115200", "--link", str(link)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = said(proc.stdout)
        assert first == str(link)
        assert os.path.realpath(link).startswith("/dev/pts/")
        with SSC32U(first, 115200) as board:
            assert board.firmware == "SSC32-V2.50USB"
            board.move({0: 1500})
            assert board.read_pulses([0]) == {0: 1500}
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    assert not link.exists()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_the_kernel_hands_to_another_thread_ends_the_emulator(
    tmp_path: Path, sig: signal.Signals
) -> None:
    """The kernel hands a process's signal to any thread that does not block it; Python runs
    the handler in the main thread, when that thread next runs. Here SIGTERM (SIGINT) goes
    to another thread than the main one: the emulator ends all the same (its main thread waited in
    `Event.wait()` and never woke: seen as a 10 s teardown beside two busy loops, a board
    stopped and continued, then told to end)."""
    link = tmp_path / "ssc32u"
    proc = subprocess.Popen(
        [str(AL5D), "emulator", "--link", str(link)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and said(proc.stdout) == str(link)
        to_another_thread(proc.pid, sig)
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
        proc.wait(10)
    assert not link.exists()


class Standalone:
    """`al5d emulator` with `args`, its device on a pyserial port of raw bytes."""

    def __init__(self, tmp_path: Path, *args: str) -> None:
        self.link = tmp_path / "board"
        if "--record" not in args:
            args = (*args, "--record", str(tmp_path / "board.jsonl"))
        self.record = Path(args[args.index("--record") + 1])
        self.proc = subprocess.Popen(
            [str(AL5D), "emulator", "--link", str(self.link), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        assert said(self.proc.stdout) == str(self.link)
        self.port = serial.Serial(str(self.link), 9600, timeout=1)

    def ask(self, line: bytes, n: int | None = None) -> bytes:
        self.port.reset_input_buffer()
        self.port.write(line)
        return self.port.read_until(b"\r") if n is None else self.port.read(n)

    def answer_s(self) -> float:
        """The least of 15 Q round trips (three were all 15 ms once beside busy loops)."""
        times = []
        for _ in range(15):
            time.sleep(0.05)
            t0 = time.monotonic()
            assert self.ask(b"Q\r", 1) == b"."
            times.append(time.monotonic() - t0)
        return min(times)

    def flood_then_flush(self) -> int:
        """QP0 after 20 moves of channel 0 and an output flush once the first has arrived
        (the link has read them all from the pty by then: see docs/emulator.md's "What it does
        not model" for a flush at once)."""
        for i in range(20):
            self.port.write(f"#0P{1000 + i * 10}\r".encode())
        # Waited for whole (a busy host may take seconds): flushed before the link has read
        # the moves, the USB link's figure would count a flush the emulator does not model.
        wait_until(lambda: b'"#0P1000"' in self.record.read_bytes(), 30.0, "the first move")
        self.port.reset_output_buffer()
        return self.ask(b"\x1bQP0\r", 1)[0]

    def close(self) -> str:
        self.port.close()
        self.proc.send_signal(signal.SIGTERM)
        _, err = self.proc.communicate(timeout=10)
        assert self.proc.returncode == 0
        return err


def test_standalone_defaults_to_the_real_link_and_takes_the_board_settings(
    tmp_path: Path,
) -> None:
    record = tmp_path / "record.jsonl"
    board = Standalone(
        tmp_path,
        *("--input", "A=0", "--input", "VB=128", "--startup", "#0P1500"),
        *("--power-up", "1=1200", "--register", "R32=-50", "--announce-reset"),
        *("--record", str(record)),
    )
    try:
        # USB: a short answer waits for the 16 ms latency timer; a flush drops nothing.
        assert board.answer_s() >= 0.016 + p.wire_time_s(3, 9600)
        assert board.ask(b"QP0QP1QP2\r", 3) == bytes([150, 120, 0])
        assert board.ask(b"A B\r", 2) == b"01"
        assert board.ask(b"VB VB\r", 2) == bytes([0, 128])
        assert board.ask(b"R32\r") == b"-50\r"
        assert board.ask(b"R0\r") == b"9\r"  # the startup string's and the pulses' bits
        assert board.flood_then_flush() == 119, "the USB link dropped written moves"
        # SIGUSR1: a brown-out, announced, then the power-up settings again.
        board.ask(b"#1P2000\r#2P2000\rVER\r")
        board.proc.send_signal(signal.SIGUSR1)
        assert board.port.read_until(b"\r") == b'"#0P1500;"\r'
        assert board.ask(b"QP0QP1QP2\r", 3) == bytes([150, 120, 0])
    finally:
        err = board.close()
    assert "usb link" in err and "latency timer 16 ms" in err
    records = [Record.from_json(x) for x in record.read_text().splitlines()]
    assert [r.source for r in records if r.raw == b"#0P1500"] == ["startup", "startup"]
    assert sum(r.source == "reset" for r in records) == 1
    assert sum(r.raw.startswith(b"#0P1") and r.source == "serial" for r in records) == 20


def test_standalone_low_latency_and_uart(tmp_path: Path) -> None:
    fast = Standalone(tmp_path, "--latency-timer", "40", "--low-latency")
    try:
        # Its own 40 ms latency timer would make it 40 ms at least: 1 ms plus a busy host's.
        assert fast.answer_s() < 0.020
    finally:
        err = fast.close()
    assert "low-latency mode (1 ms)" in err
    uart = Standalone(tmp_path, "--transport", "uart")
    try:
        assert uart.flood_then_flush() < 119, "the UART link kept what the flush dropped"
    finally:
        err = uart.close()
    assert "uart link" in err


@pytest.mark.parametrize(
    ("flag", "value"),
    [
        ("--input", "I=1"),
        ("--input", "VA=300"),
        ("--input", "A"),
        ("--register", "256=1"),
        ("--register", "0=x"),
        ("--power-up", "0=3000"),
        ("--latency-timer", "0"),
        ("--transport", "can"),
        ("--misalign", "base"),
        ("--misalign", "base=x"),
        ("--misalign", "base=900"),
        ("--misalign", "base=10,20"),
    ],
)
def test_standalone_refuses_bad_settings_before_it_starts(flag: str, value: str) -> None:
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(["emulator", flag, value])
    assert exit_.value.code == 2


def test_a_board_process_replays_its_resets(config: ArmConfig, tmp_path: Path) -> None:
    """The servo model replayed from the record stream of `al5d emulator`: a reset (SIGUSR1)
    turns its pulses off there too, and the move after it runs at full speed."""
    board = BoardProcess(tmp_path / "board", config=config)
    try:
        with SSC32U(board.port) as client:
            client.move({0: 1500, 1: 1200})
            board.wait_for(lambda rs: any(r.raw == b"#0P1500#1P1200" for r in rs))
            assert board.model().pulse_us(0) == 1500
            board.popen.send_signal(signal.SIGUSR1)
            board.wait_for(lambda rs: any(r.source == "reset" for r in rs))
            model = board.model()
            assert model.pulse_us(0) == model.pulse_us(1) == 0
            client.move({0: 2000}, time_ms=1000)
            rec = board.wait_for(lambda rs: rs[-1].raw == b"#0P2000T1000")[-1]
            model = board.model()
            assert model.pulse_us(0, rec.t_effect + 0.01) == 2000  # a first command again
            assert model.pulse_us(1) == 0
    finally:
        board.close()


def test_standalone_takes_a_misaligned_arm() -> None:
    args = build_parser().parse_args(
        ["emulator", "--misalign", "base=40", "--misalign", "elbow=-20,reversed"]
    )
    assert dict(args.misalign) == {"base": Mechanics(40), "elbow": Mechanics(-20, reversed=True)}
    # In a process of its own: the emulator makes the thread that runs it urgent, and a
    # pytest worker whose main thread it was started every later server at nice -10.
    wrong = Proc("emulator", "--misalign", "knee=10")
    assert wrong.wait(30) == exits.USAGE
    assert "--misalign knee: no such joint" in wrong.err.wait_for("al5d emulator:", 5)


@pytest.mark.parametrize("namespace", ["", "right"])
def test_a_misaligned_arm_says_where_it_truly_stands(
    config: ArmConfig, tmp_path: Path, namespace: str
) -> None:
    """`--misalign` publishes the arm's true angles on ROS (physical_joint_states), for the web
    view and `al5d calibrate` to show: the base at the config's 0 deg stands 40 us off. In
    a namespace its joints are named as the server's are (an outside try: `right`'s were
    `base`..., its `/right/joint_states` `right_base`...)."""
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from al5d.ros.dds import start_context
    from al5d.ros.executors import Spinner
    from al5d.ros.names import Names
    from al5d.ros.physical import PhysicalReader
    from al5d.ros.qos import QOS_LATEST

    names = Names.of(namespace)
    prefix = config.server.joint_prefix_in(names.namespace)
    assert bool(prefix) == bool(namespace)
    board = Standalone(tmp_path, "--misalign", "base=40", "--namespace", namespace)
    context = start_context()
    node = Node("al5d_test_physical", context=context)
    reader = PhysicalReader(node, names, config.model, prefix=prefix)
    heard: list[list[str]] = []
    node.create_subscription(
        JointState, names.physical_joint_states, lambda m: heard.append(list(m.name)), QOS_LATEST
    )
    spinner = Spinner(node, context)
    try:
        base = config.joints["base"]
        board.port.write(f"#{base.channel}P{round(base.to_us(0))}\r".encode())
        want = base.to_deg(base.to_us(0) - 40)  # where the servo truly stands (`Mechanics`)
        deadline = time.monotonic() + 30  # DDS's discovery, on a busy host
        seen = None
        while time.monotonic() < deadline:
            seen = reader.next(1.0)
            if seen is not None and abs(seen["base"] - want) < 0.05:
                break
        assert seen is not None and abs(seen["base"] - want) < 0.05, (seen, want)
        assert abs(want) > 3  # 40 us is about 4 degrees: the misalignment is there to see
        # A reader of its own, matched on its own time (a busy CI run read it empty here).
        wait_until(lambda: bool(heard), 30, "the joints' names")
        named = heard[-1]
        assert all(name.startswith(prefix) for name in named) and prefix + "base" in named, named
    finally:
        spinner.close()
        said = f"where the arm truly stands goes on {names.physical_joint_states}"
        assert said in board.close()


def test_a_link_path_that_is_taken_is_refused_and_left_as_it_is(
    config: ArmConfig, tmp_path: Path
) -> None:
    """`--link` never replaces a file, a directory or another board's live link, and a
    board removes only its own link (an outside try: a file named as the link was deleted,
    and a second emulator took the first one's link, which the first removed as it ended)."""
    precious = tmp_path / "important.txt"
    precious.write_text("precious\n")
    (tmp_path / "somedir").mkdir()
    for path, why in (
        (precious, "is a file, not a board's link"),
        (tmp_path / "somedir", "is a directory, not a board's link"),
        (tmp_path / "nodir" / "x", "there is no directory"),
    ):
        proc = Proc("emulator", "--link", str(path))
        assert proc.wait(30) == exits.USAGE
        assert why in "\n".join(proc.err.drain(0.5))
    assert precious.read_text() == "precious\n"
    assert not (tmp_path / "somedir.tmp").exists()
    record = Proc("emulator", "--record", str(tmp_path / "nodir" / "x.jsonl"))
    assert record.wait(30) == exits.USAGE
    assert "--record: cannot write" in "\n".join(record.err.drain(0.5))

    link = tmp_path / "ssc32u"
    first = BoardProcess(link, 9600, config)
    try:
        device = os.readlink(link)
        second = Proc("emulator", "--link", str(link))
        assert second.wait(30) == exits.USAGE
        assert "is in use" in "\n".join(second.err.drain(0.5))
        assert os.readlink(link) == device
    finally:
        first.close()
    assert not link.is_symlink()
    # A link whose board has gone (killed before it could remove it) is taken over.
    os.symlink("/dev/pts/no-such-board", link)
    with Emulator(config, link=link):
        assert os.readlink(link).startswith("/dev/pts/")
    assert not link.is_symlink()
    precious_link = tmp_path / "another.txt"
    precious_link.write_text("kept\n")
    with pytest.raises(ChooseAnotherLink, match="is a file"):
        Emulator(config, link=precious_link).start()
    assert precious_link.read_text() == "kept\n"
