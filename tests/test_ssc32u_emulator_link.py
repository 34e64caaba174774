"""The emulated board's link, from raw bytes: line feeds, output flushes on USB and on a UART,
and the USB chip's latency timer (issue 11)."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from al5d.arm.config import ArmConfig
from al5d.ssc32u import facts
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import UART, USB, Emulator, Fault, LinkModel, Transport
from al5d.ssc32u.emulator.usb import FtdiChip, Packet, byte_arrivals


@pytest.fixture
def usb(config: ArmConfig) -> Iterator[tuple[Emulator, serial.Serial]]:
    with Emulator(config, usb=USB) as emu, serial.Serial(emu.port, 9600, timeout=1) as port:
        yield emu, port


def moves(emu: Emulator) -> list[bytes]:
    """The moves the board ran (not those an ESC cancelled half-way)."""
    return [r.raw for r in emu.records if r.commands and r.raw.startswith(b"#0P")]


def test_an_unplugged_boards_link_is_gone_until_it_is_plugged_back(
    config: ArmConfig, tmp_path: Path
) -> None:
    """Unplugged, the board's link goes, as a USB adapter's device path does; plugged back,
    it leads to the board's new pty. Left to the closed pty, it led to whatever took that
    pty's number next: a reconnecting client opened another process's terminal."""
    link = tmp_path / "ssc32u"
    with Emulator(config, link=link) as emu:
        assert os.readlink(link) == emu.device
        emu.inject(Fault.DISCONNECT)
        assert not os.path.lexists(link)
        with pytest.raises(serial.SerialException):
            serial.Serial(str(link), 9600, timeout=1).close()
        emu.reconnect()
        assert os.readlink(link) == emu.device
        with serial.Serial(str(link), 9600, timeout=1) as port:
            port.write(p.encode_version())
            assert port.read_until(b"\r") == f"{facts.FIRMWARE}\r".encode()
    assert not os.path.lexists(link)


# -- line feeds -------------------------------------------------------------------------------


def test_line_feeds_anywhere_a_blank_may_be(emulator: Emulator) -> None:
    with serial.Serial(emulator.port, 9600, timeout=1) as port:
        port.write(b"\nVER\r")
        assert port.read_until(b"\r") == b"SSC32-V2.50USB\r"
        port.write(b"VER\n\r")
        assert port.read_until(b"\r") == b"SSC32-V2.50USB\r"
        # A CR LF client: the LF starts the next line, and is ignored there.
        port.write(b"#0P1500\r\nVER\r\n")
        assert port.read_until(b"\r") == b"SSC32-V2.50USB\r"
        port.write(b"#9P1800\n\r")
        port.write(b"QP0\r\nQP9\r\n")
        assert port.read(2) == bytes([150, 180])
        port.write(b"#9 P\n1\t7\n00\r\n")
        port.write(b"Q\nP\n9\r\n")
        assert port.read(1) == bytes([170])
    unread = [r.raw for r in emulator.records if not r.commands]
    assert unread == [], "a line feed made the board ignore a line"


@pytest.mark.timeout(120)
def test_random_blanks_and_line_ends_from_raw_bytes(config: ArmConfig) -> None:
    """Any mix of spaces, tabs and LFs in a move and a QP, ended by CR, CR LF or LF CR,
    reaches the board as if it had none."""
    with (
        Emulator(config, baud=115200) as emu,
        serial.Serial(emu.port, 115200, timeout=1) as port,
    ):

        @settings(max_examples=30, deadline=None)
        @given(
            st.integers(0, 31),
            st.integers(50, 250),
            st.lists(st.sampled_from([b" ", b"\t", b"\n"]), min_size=12, max_size=12),
            st.lists(st.booleans(), min_size=12, max_size=12),
            st.sampled_from([b"\r", b"\r\n", b"\n\r"]),
        )
        def check(ch: int, tens: int, blanks: list[bytes], where: list[bool], end: bytes) -> None:
            def spaced(line: bytes) -> bytes:
                out = b""
                for i, c in enumerate(line):
                    out += bytes([c])
                    if where[i % len(where)]:
                        out += blanks[i % len(blanks)]
                return out

            port.reset_input_buffer()
            port.write(spaced(f"#{ch}P{tens * 10}".encode()) + end)
            port.write(spaced(f"QP{ch}".encode()) + end)
            assert port.read(1) == bytes([tens])

        check()


# -- output flushes ---------------------------------------------------------------------------


def _flood_then_flush(emu: Emulator, port: serial.Serial) -> list[bytes]:
    """20 moves (0.17 s of wire at 9600), flushed when the first has arrived: by then the
    link has read them all from the pty, and most have not started on the wire.

    A flush at once, before the link could read them, would find them in the pty, which
    drops them itself whatever the model (docs/emulator.md, "What it does not model")."""
    heard = emu.bytes_heard
    written = 0
    for i in range(20):
        written += port.write(f"#0P{1000 + i * 10}\r".encode())
    emu.wait_for(lambda rs: any(r.raw == b"#0P1000" for r in rs), 2)
    # On a busy host the link's reader can be late to read the pty. What it has not read
    # when the flush comes is the pty's: it drops some, and hands the rest over after
    # the flush's report, where they ran after moves the flush had dropped (a CI run beside
    # two busy loops: 1000, 1010, then 1180 and 1190). The client's `out_waiting` does not
    # see them (0 with bytes still in the master).
    deadline = time.monotonic() + 10
    while emu.bytes_heard - heard < written:
        assert time.monotonic() < deadline, f"the link read {emu.bytes_heard - heard} of {written}"
        time.sleep(0.001)
    port.reset_output_buffer()
    port.write(b"\x1bSTOP0\r")
    emu.wait_for(lambda rs: any(r.raw == b"STOP0" for r in rs), 5)
    return [r.raw for r in emu.records]


def test_a_flush_on_usb_drops_nothing_already_written(
    usb: tuple[Emulator, serial.Serial],
) -> None:
    emu, port = usb
    raws = _flood_then_flush(emu, port)
    assert moves(emu) == [f"#0P{1000 + i * 10}".encode() for i in range(20)]
    # The ESC after the flush ends nothing (every move had its CR), and STOP comes last.
    assert raws[-1] == b"STOP0"


def test_a_flush_on_a_uart_drops_what_has_not_started(config: ArmConfig) -> None:
    with Emulator(config, usb=UART) as emu, serial.Serial(emu.port, 9600) as port:
        _flood_then_flush(emu, port)
        sent = moves(emu)
    assert 1 <= len(sent) < 20
    # What ran is the start of what was written, in order: the flush cut the tail (and the
    # ESC cancelled the line it cut in two).
    assert sent == [f"#0P{1000 + i * 10}".encode() for i in range(len(sent))]


def test_the_default_is_the_boards_usb_link_and_a_uart_is_asked_for(emulator: Emulator) -> None:
    assert emulator.usb == USB == LinkModel() and USB.transport is Transport.USB
    assert not USB.flush_drops_unsent and USB.hold_s == 0.016
    assert UART.flush_drops_unsent and UART.hold_s is None


# -- the latency timer ------------------------------------------------------------------------


#: No answer through the default 16 ms timer comes sooner than this after its query is
#: written (the timer, less a millisecond of slack, and the query's 3 bytes of wire).
TIMER_FLOOR_S = 0.015 + p.wire_time_s(3, 9600)


def _answer_times(emu: Emulator, port: serial.Serial, n: int = 7) -> list[tuple[float, float]]:
    """(seconds from writing `Q` to its answer, from the board hearing it to its answer)."""
    out = []
    for _ in range(n):
        time.sleep(0.05)  # the chip idle again
        emu.clear_records()
        t0 = time.monotonic()
        port.write(b"Q\r")
        assert port.read(1) == b"."
        t1 = time.monotonic()
        heard = emu.wait_for(lambda rs: len(rs) > 0)[0].t_effect
        out.append((t1 - t0, t1 - heard))
    return out


def test_a_short_answer_waits_for_the_16_ms_latency_timer(
    usb: tuple[Emulator, serial.Serial],
) -> None:
    emu, port = usb
    for total, after_cr in _answer_times(emu, port):
        # The answer's byte reaches the chip after the board's delay and its wire time,
        # then waits the whole timer: never earlier, whatever the load.
        assert after_cr >= 0.016 + emu.answer_delay_s + p.wire_time_s(1, 9600) - 1e-4
        assert total >= TIMER_FLOOR_S


def test_low_latency_mode_answers_within_a_few_ms(config: ArmConfig) -> None:
    with (
        Emulator(config, usb=LinkModel(low_latency=True)) as emu,
        serial.Serial(emu.port, 9600, timeout=1) as port,
    ):
        times = _answer_times(emu, port, 15)
    assert all(after_cr >= 0.001 for _, after_cr in times)
    # 3 bytes of wire (3.1 ms), the board's delay and 1 ms in the chip: sooner than the
    # default timer ever answers. The fastest of 15, since a busy host only adds (beside
    # busy loops and four test workers, the median of 7 was once 34 ms).
    assert min(t for t, _ in times) < TIMER_FLOOR_S


def test_the_latency_timer_is_a_setting(config: ArmConfig) -> None:
    with (
        Emulator(config, usb=LinkModel(latency_ms=40)) as emu,
        serial.Serial(emu.port, 9600, timeout=1) as port,
    ):
        times = _answer_times(emu, port, 3)
    assert all(after_cr >= 0.040 for _, after_cr in times)
    with pytest.raises(ValueError, match=r"1\.\.255"):
        LinkModel(latency_ms=0)


def test_a_uart_answers_without_a_latency_timer(config: ArmConfig) -> None:
    with (
        Emulator(config, usb=UART) as emu,
        serial.Serial(emu.port, 9600, timeout=1) as port,
    ):
        times = _answer_times(emu, port, 15)
    # As low latency's above (beside busy loops the UART's median was once 13.3 ms).
    assert min(t for t, _ in times) < TIMER_FLOOR_S


def test_a_long_answer_arrives_whole(config: ArmConfig) -> None:
    """SS of a full startup string is 103 bytes, more than a USB packet: every byte arrives,
    in order, the last after the timer (the packets themselves: the chip's tests below)."""
    text = "#0P1500;" * 12 + "VER;"
    with (
        Emulator(config, baud=115200, usb=USB, startup=text) as emu,
        serial.Serial(emu.port, 115200, timeout=1) as port,
    ):
        t0 = time.monotonic()
        port.write(b"SS\r")
        answer = port.read_until(b"\r")
        took = time.monotonic() - t0
    assert len(text) == facts.STARTUP_MAX_CHARS
    assert answer == b'"' + text.encode() + b'"\r'
    assert took >= 0.016 + p.wire_time_s(3 + 62, 115200)


# -- the chip's model, alone ---------------------------------------------------------------


def test_the_chip_holds_a_short_answer_for_its_timer() -> None:
    chip = FtdiChip(0.016)
    assert chip.feed(byte_arrivals(10.0, 3, 9600), b"abc") == []
    assert chip.due == pytest.approx(10.0 - 2 * p.wire_time_s(1, 9600) + 0.016)
    packet = chip.expire()
    assert packet is not None and packet.data == b"abc"
    assert packet.t == pytest.approx(10.0 - 2 * p.wire_time_s(1, 9600) + 0.016)
    assert chip.expire() is None and chip.due == float("inf")
    # A byte after the timer ran out starts a packet of its own.
    assert chip.feed([20.0, 20.02], b"xy") == [Packet(20.016, b"x")]
    assert chip.expire() == Packet(pytest.approx(20.036), b"y")  # type: ignore[arg-type]


@settings(max_examples=300)
@given(
    st.lists(st.floats(0.0, 0.05), min_size=1, max_size=300),
    st.floats(0.001, 0.03),
    st.integers(1, 62),
)
def test_the_chip_passes_every_byte_once_in_order_and_in_time(
    gaps: list[float], hold: float, payload: int
) -> None:
    arrivals = []
    t = 0.0
    for gap in gaps:
        t += gap
        arrivals.append(t)
    data = bytes(i % 256 for i in range(len(arrivals)))
    chip = FtdiChip(hold, payload)
    packets = []
    for i in range(0, len(data), 7):  # fed as several answers
        packets += chip.feed(arrivals[i : i + 7], data[i : i + 7])
    if (last := chip.expire()) is not None:
        packets.append(last)
    assert b"".join(pk.data for pk in packets) == data
    assert [pk.t for pk in packets] == sorted(pk.t for pk in packets)
    i = 0
    for pk in packets:
        assert 1 <= len(pk.data) <= payload
        first, final = arrivals[i], arrivals[i + len(pk.data) - 1]
        assert pk.t >= final, "a byte left before it came"
        if len(pk.data) < payload:
            assert pk.t == pytest.approx(first + hold), "a short packet left before its timer"
        else:
            assert pk.t == final, "a full packet waited"
        i += len(pk.data)


def test_the_facts_of_the_link_agree() -> None:
    assert facts.LOW_LATENCY_TIMER_MS < facts.LATENCY_TIMER_MS
    assert facts.LATENCY_TIMER_MS in facts.LATENCY_TIMER_RANGE_MS
    # The board's own answer delay is within the manual's, and far below the chip's timer.
    assert facts.ANSWER_DELAY_MAX_S < facts.LATENCY_TIMER_MS / 1000
    assert USB.hold_s == 0.016 and LinkModel(low_latency=True).hold_s == 0.001
