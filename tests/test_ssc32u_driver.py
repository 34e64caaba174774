"""The low-level driver against the emulator over a real pseudo terminal."""

from __future__ import annotations

import re
import threading
import time

import pytest

from al5d.arm.config import ArmConfig
from al5d.ssc32u.driver import DEFAULT_READ_TIMEOUT_S, SSC32U
from al5d.ssc32u.emulator import UART, Emulator, Fault, LinkModel, Record
from al5d.ssc32u.errors import (
    GarbageAnswer,
    Interrupted,
    LinkLost,
    NoAnswer,
    NotAnSSC32U,
    PortUnavailable,
    SerialFault,
)
from al5d.ssc32u.wire import WIRE_HORIZON_S, WIRE_PIECE_S, tap_writes


def test_connect_checks_the_board(emulator: Emulator, board: SSC32U) -> None:
    assert board.firmware == "SSC32-V2.50USB"
    assert board.version() == "SSC32-V2.50USB"


def test_one_call_per_board_function(emulator: Emulator, board: SSC32U) -> None:
    assert board.read_pulses([0, 1]) == {0: 0, 1: 0}
    assert board.move({0: 1500, 1: 1200}) == b"#0P1500#1P1200\r"
    assert board.is_done()
    board.move({0: 2000, 1: 1800}, time_ms=500)
    assert not board.is_done()
    board.stop([0, 1])
    # QP answers the pulse (held since the STOP, rounded to 1 us) in steps of 10 us.
    assert board.read_pulses([0, 1]) == {
        0: round(emulator.pulse_us(0)) // 10 * 10,
        1: round(emulator.pulse_us(1)) // 10 * 10,
    }
    board.set_offsets({0: 20})
    board.set_outputs({9: True})
    board.cancel()
    raws = [r.raw for r in emulator.wait_for(lambda rs: len(rs) >= 10)]
    assert (
        raws
        == [
            b"QP0QP1",
            b"#0P1500#1P1200",
            b"Q",
            b"#0P2000#1P1800T500",
            b"Q",
            b"",
            b"STOP0",
            b"STOP1",
            b"QP0QP1",
            b"#0PO20",
            b"#9H",
            b"",
        ][: len(raws)]
    )


def test_wire_time_at_the_current_baud(emulator: Emulator, board: SSC32U) -> None:
    assert board.wire_time_s(b"#0P1500\r") == pytest.approx(8 * 10 / 9600)
    assert board.wire_time_s(96) == pytest.approx(0.1)


def test_stop_is_one_write_that_first_cancels_any_partial_line(
    emulator: Emulator, board: SSC32U
) -> None:
    assert board.stop(range(6)) == b"\x1bSTOP0\rSTOP1\rSTOP2\rSTOP3\rSTOP4\rSTOP5\r"


def stack(board: SSC32U, lines: list[bytes]) -> None:
    """Bytes in the port that the driver would never stack itself (it paces its moves: the
    test below), as another writer of the port leaves them."""
    board._ser.write(b"".join(lines))


def test_moves_wait_for_the_wire_so_a_stop_finds_little_ahead(
    emulator: Emulator, board: SSC32U
) -> None:
    line = len(b"#0P1000\r")
    t0 = time.monotonic()
    for i in range(30):
        board.move({0: 1000 + 10 * i})  # 240 bytes: 250 ms of wire at 9600
        # What a stop written now would find ahead of it: the horizon and one move at most.
        assert board.arrival(0) - time.monotonic() <= WIRE_HORIZON_S + board.wire_time_s(line)
    # The writer waited for the wire (a busy host only makes it longer), not the port.
    assert time.monotonic() - t0 >= 29 * board.wire_time_s(line) - WIRE_HORIZON_S
    board.stop([0])
    raws = [r.raw for r in emulator.wait_for(lambda rs: any(r.raw == b"STOP0" for r in rs))]
    # Every move in order; the last may be cut by the stop's ESC, as a half-sent line is.
    moves = [r for r in raws if r.startswith(b"#0P")]
    assert moves == [f"#0P{1000 + 10 * i}".encode() for i in range(len(moves))]
    assert len(moves) >= 29


#: A group move of all six joints with its time: 47 bytes, 49 ms at 9600 baud.
LONG = {ch: 1500 for ch in range(6)}


def test_a_long_move_goes_out_in_pieces_so_a_stop_finds_the_horizon_and_a_piece(
    emulator: Emulator, board: SSC32U
) -> None:
    """A stop finds ahead of it the horizon and one piece at most, not a whole line (at
    9600 baud a line of six joints is 49 ms on the wire)."""
    for i in range(6):
        line = board.move({ch: 1000 + 10 * i + ch for ch in LONG}, time_ms=500)
        assert board.wire_time_s(line) > 2 * WIRE_PIECE_S
        # What a stop written now would find ahead of it (a busy host only makes it less).
        assert board.arrival(0) - time.monotonic() <= WIRE_HORIZON_S + WIRE_PIECE_S
    # The board took each line whole: the pieces are bytes, not commands.
    raws = [r.raw for r in emulator.wait_for(lambda rs: len(rs) >= 6)]
    assert raws == [
        "".join(f"#{ch}P{1000 + 10 * i + ch}" for ch in LONG).encode() + b"T500" for i in range(6)
    ]


def test_a_cancelled_moves_stops_go_out_in_pieces_too(emulator: Emulator, board: SSC32U) -> None:
    """A cancelled move's STOPs (paced: a preempting client has one every goal) leave a stop
    the horizon and a piece at most, not six STOPs (38 ms at 9600 baud)."""
    for i in range(3):
        board.move({ch: 1000 + 10 * i + ch for ch in LONG}, time_ms=500)
        data = board.stop(range(6), paced=True)
        assert board.wire_time_s(data) > WIRE_HORIZON_S + WIRE_PIECE_S
        # What a stop written now would find ahead of it (a busy host only makes it less).
        assert board.arrival(0) - time.monotonic() <= WIRE_HORIZON_S + WIRE_PIECE_S
    # Counted by the last STOP, not by records: what else the board took depends on the
    # host (the stop's flush drops what of the move has not gone out yet).
    done = emulator.wait_for(lambda rs: sum(r.raw == b"STOP5" for r in rs) == 3)
    stops = [f"STOP{ch}".encode() for ch in range(6)]
    # Each whole, in order: bytes were cut into pieces, not lines.
    assert [r.raw for r in done if b"STOP" in r.raw] == 3 * stops


def test_a_query_waits_for_the_wire_so_a_stop_finds_it_alone_ahead(emulator: Emulator) -> None:
    """A query is written whole, once the wire is free: a stop finds at most the query ahead
    of it, not the horizon, a piece and the query."""
    taps: list[tuple[bytes, float, float]] = []
    tap_writes(emulator.port, lambda data, written, arrival: taps.append((data, written, arrival)))
    try:
        with SSC32U(emulator.port, 9600) as board:  # a board opened after the tap hears it
            for i in range(3):
                board.move({ch: 1000 + 10 * i + ch for ch in LONG}, time_ms=500)
                board.read_pulses(range(6))
    finally:
        tap_writes(emulator.port, None)
    queries = [(d, w, a) for d, w, a in taps if d.startswith(b"QP")]
    assert len(queries) == 3
    for data, written, arrival in queries:
        # Its own bytes on the wire from when it was written: nothing before them.
        assert arrival - written == pytest.approx(board.wire_time_s(data), abs=1e-6)


def test_a_stop_between_the_pieces_of_a_line_cancels_it_and_nothing_of_it_follows(
    emulator: Emulator,
) -> None:
    """A stop written while a long line goes out in pieces: the board cancels the half
    it has (the stop's ESC), the rest is never written, the writer hears None, and the next
    write begins with an ESC of its own (a cut line is never left open)."""
    long = {ch: 1500 + ch for ch in range(32)}  # 32 channels: 300 ms on the wire, 34 pieces
    taps: list[bytes] = []
    tap_writes(emulator.port, lambda data, written, arrival: taps.append(data))
    try:
        with SSC32U(emulator.port, 9600) as writer:
            line = b"".join(f"#{ch}P{pw}".encode() for ch, pw in long.items()) + b"\r"

            def write(out: list[float | None]) -> None:
                out.append(writer.write_command(line, unless=lambda: False))

            for _ in range(5):  # until the stop falls between two pieces (a busy host may not)
                emulator.clear_records()
                got: list[float | None] = []
                thread = threading.Thread(target=write, args=(got,))
                thread.start()
                time.sleep(0.1)
                writer.stop(range(32))
                thread.join(5)
                if got == [None]:
                    break
                time.sleep(0.5)  # the line and the STOPs off the wire
            assert got == [None], "no stop fell between the pieces of a line in five tries"
            raws = emulator.wait_for(lambda rs: any(r.raw == b"STOP31" for r in rs))
            cut = [r for r in raws if r.raw.startswith(b"#0P1500")][-1]
            assert cut.ignored == "cancelled by ESC" and not cut.commands, cut
            after = raws[raws.index(cut) + 1 :]
            assert [r.raw for r in after] == [f"STOP{ch}".encode() for ch in range(32)]
            writer.move({0: 1200})
            assert taps[-1] == b"\x1b#0P1200\r"  # the cut line, cancelled once more
    finally:
        tap_writes(emulator.port, None)


def test_a_query_waits_for_the_end_of_a_line_going_out_in_pieces(
    emulator: Emulator, board: SSC32U
) -> None:
    """A query asked while a long line goes out in pieces is written after the line, not
    into it (the board would take its bytes for part of the line, and answer nothing)."""
    line = b"".join(f"#{ch}P{1500 + ch}".encode() for ch in range(32)) + b"\r"
    thread = threading.Thread(target=board.write_command, args=(line,))
    thread.start()
    time.sleep(0.1)  # a third of the line's 300 ms of wire out
    board.is_done()  # answered (a query that the board takes for part of a line is not)
    thread.join(5)
    raws = [r.raw for r in emulator.wait_for(lambda rs: len(rs) >= 2)]
    assert raws[:2] == [line[:-1], b"Q"], raws


def test_stop_on_a_uart_drops_output_still_waiting(config: ArmConfig) -> None:
    with Emulator(config, usb=UART) as emu, SSC32U(emu.port) as board:
        stack(board, [f"#0P{1000 + 10 * i}\r".encode() for i in range(30)])  # 250 ms of wire
        # The first has arrived: the link holds the rest, not yet on the wire.
        emu.wait_for(lambda rs: any(r.raw == b"#0P1000" for r in rs))
        board.stop([0])
        emu.wait_for(lambda rs: any(r.raw == b"STOP0" for r in rs))
        records = [r for r in emu.records if r.raw.startswith(b"#0P")]
    moves = [r.raw for r in records if r.commands]
    assert 1 <= len(moves) < 30
    assert moves == [f"#0P{1000 + 10 * i}".encode() for i in range(len(moves))]
    # The flush may cut the line on the wire in two: the stop's ESC cancels its first half.
    cut = [r for r in records if not r.commands]
    assert cut in ([], records[-1:]), cut
    assert all(r.ignored == "cancelled by ESC" for r in cut), cut


def test_stop_on_the_usb_link_drops_nothing_and_comes_last(
    emulator: Emulator, board: SSC32U
) -> None:
    stack(board, [f"#0P{1000 + 10 * i}\r".encode() for i in range(30)])
    emulator.wait_for(lambda rs: any(r.raw == b"#0P1000" for r in rs))
    board.stop([0])
    raws = [r.raw for r in emulator.wait_for(lambda rs: any(r.raw == b"STOP0" for r in rs))]
    assert [r for r in raws if r.startswith(b"#0P")] == [
        f"#0P{1000 + 10 * i}".encode() for i in range(30)
    ]
    assert raws[-1] == b"STOP0"


def test_a_query_after_a_stop_on_the_usb_link_is_asked_once_and_leaves_nothing(
    config: ArmConfig,
) -> None:
    """On the USB link a stop's flush drops nothing already written: its STOPs queue behind
    the rest of a long move, and so does a query after it. Its deadline allows for that
    (one ask, no retry), and the query after it gets its own answer."""
    with Emulator(config, usb=LinkModel()) as emu, SSC32U(emu.port) as board:
        board.move(dict.fromkeys(range(6), 1500))
        emu.wait_for(lambda rs: any(r.raw.startswith(b"#0P1500") for r in rs))
        board.move({ch: 1200 + ch for ch in range(10)}, time_ms=3000)  # 86 bytes: 90 ms
        board.move({ch: 1800 + ch for ch in range(10)}, time_ms=3000)
        # The first has arrived: the link has long had the second, 90 ms of wire still to
        # go, and the stop's ESC and STOPs go behind it.
        emu.wait_for(lambda rs: any(r.raw.startswith(b"#0P1200") for r in rs))
        board.stop(range(6))
        pulses = board.read_pulses([0])
        assert 1200 <= pulses[0] <= 1800
        assert any(r.raw.startswith(b"#0P1800") for r in emu.records), "the move was dropped"
        assert board.is_done() in (True, False)  # not the QP's byte: GarbageAnswer
        assert board.read_pulses([0, 1]) == {
            0: round(emu.pulse_us(0)) // 10 * 10,
            1: round(emu.pulse_us(1)) // 10 * 10,
        }
    assert [r.raw for r in emu.records].count(b"QP0") == 1, "the first QP was asked again"


def test_a_late_first_answer_is_never_left_for_the_next_query(config: ArmConfig) -> None:
    """A board that answers late once: the query asks again, and the first answer, which
    comes before the second, is not left in the buffer for the next query to read."""
    with Emulator(config, usb=LinkModel()) as emu, SSC32U(emu.port) as board:
        board.move({0: 1500})
        emu.answer_delay_s = 0.08  # beyond the margin: 50 ms, and 16 ms in the USB chip
        t0 = time.monotonic()
        assert board.read_pulses([0]) == {0: 1500}
        assert time.monotonic() - t0 > 0.08
        emu.answer_delay_s = 0.0003
        for _ in range(3):
            assert board.is_done()  # the '.' of Q, not the QP's 150
            assert board.read_pulses([0]) == {0: 1500}
    # Asked again, unless the host was short of cores for the 80 ms (then the first ask
    # waited for its answer: `al5d.priority.cpu_waited_s`); either way, no answer left over.
    assert [r.raw for r in emu.records].count(b"QP0") in (4, 5)


def test_stop_does_not_wait_behind_a_query(emulator: Emulator) -> None:
    # A query that waits 1 s for each of its two asks, so that "the stop did not wait for
    # it" is told apart from a busy machine's scheduling by seconds, not by milliseconds.
    board = SSC32U(emulator.port, 9600, read_timeout_s=1.0)
    emulator.inject(Fault.NO_ANSWER)
    errors: list[BaseException] = []

    def query() -> None:
        try:
            board.is_done()
        except (SerialFault, Interrupted) as e:
            errors.append(e)

    th = threading.Thread(target=query)
    th.start()
    try:
        time.sleep(0.1)  # the query now waits for an answer that will not come
        t0 = time.monotonic()
        board.stop([0, 1])
        took = time.monotonic() - t0
        th.join()
    finally:
        board.close()
    assert took < 1.0  # the query waits at least 2 s; the stop did not wait for it
    assert errors


class TestFaults:
    def test_no_answer(self, emulator: Emulator, board: SSC32U) -> None:
        emulator.inject(Fault.NO_ANSWER)
        # At least twice the wire (4 bytes: 4 ms at 9600, 1 back) and the margin (50 ms, and
        # 16 ms in the USB chip), and the margin once more for the first of the two answers.
        # Found within a second idle is a figure (make soak): a host short of cores adds the
        # excuse an ask and whatever this thread waited for a core (616 ms seen at load 12).
        for query, name in ((board.is_done, "Q"), (lambda: board.read_pulses([0]), "QP")):
            with pytest.raises(NoAnswer, match=rf"no answer to {name}, asked twice") as e:
                query()
            within = re.search(r"within (\d+) ms", str(e.value))
            assert within is not None and 130 <= float(within.group(1)) <= 2000

    def test_one_late_answer_is_asked_again_not_a_fault(
        self, emulator: Emulator, board: SSC32U
    ) -> None:
        emulator.inject(Fault.NO_ANSWER)
        asked: list[bytes] = []

        def on_record(rec: Record) -> None:
            # The second Q is answered: the fault ends as the board takes it (its record
            # comes before its answer). A timer ending the fault 20 ms on was too early
            # beside two busy loops (the first Q came later, and was answered).
            asked.append(rec.raw)
            if asked.count(b"Q") == 2:
                emulator.clear()

        emulator.record_listeners.append(on_record)
        t0 = time.monotonic()
        assert board.is_done()
        # It waited out one read timeout, then asked again.
        assert time.monotonic() - t0 >= DEFAULT_READ_TIMEOUT_S
        assert [r.raw for r in emulator.records].count(b"Q") == 2

    def test_garbage_answer(self, emulator: Emulator, board: SSC32U) -> None:
        emulator.inject(Fault.GARBAGE)
        # Any of the garbage's bytes: on a busy host the first ask's answer can come late, its
        # first byte dropped when the second ask begins.
        with pytest.raises(GarbageAnswer, match=r"not an SSC-32U answer: Q answered b'"):
            board.is_done()
        with pytest.raises(SerialFault, match=r"not an SSC-32U answer: VER answer"):
            board.version()
        emulator.clear()
        assert board.is_done()  # the leftover garbage does not spoil the next answer

    def test_disconnect(self, emulator: Emulator, board: SSC32U) -> None:
        emulator.inject(Fault.DISCONNECT)
        with pytest.raises(LinkLost, match=r"failed: .*Input/output error"):
            board.move({0: 1500})
        with pytest.raises(SerialFault, match=board.port):
            board.is_done()
        with pytest.raises(SerialFault, match="stop could not be written"):
            board.stop([0])
        board.close()  # closing a dead port does not raise

    def test_reconnect_behind_the_same_link(self, config: ArmConfig, tmp_path: object) -> None:
        link = f"{tmp_path}/ssc32u"
        with Emulator(config, link=link) as emu:
            with SSC32U(link) as b:
                b.move({0: 1500})
                emu.wait_for(lambda rs: any(r.raw == b"#0P1500" for r in rs))
            emu.inject(Fault.DISCONNECT)
            with pytest.raises(PortUnavailable, match="cannot open"):
                SSC32U(link)
            emu.reconnect()
            with SSC32U(link) as b:
                assert b.read_pulses([0]) == {0: 1500}  # the board kept its state

    def test_device_that_is_not_an_ssc32u(self, config: ArmConfig) -> None:
        with (
            Emulator(config, version="ARDUINO") as emu,
            pytest.raises(
                NotAnSSC32U, match="answered VER with 'ARDUINO', which is not an SSC-32U"
            ) as caught,
        ):
            SSC32U(emu.port)
        assert caught.value.received == b"ARDUINO"

    def test_silent_device(self, config: ArmConfig) -> None:
        with Emulator(config) as emu:
            emu.inject(Fault.NO_ANSWER)
            with pytest.raises(
                NotAnSSC32U, match=r"does not answer like an SSC-32U at 9600 baud.*received nothing"
            ):
                SSC32U(emu.port)

    def test_wrong_baud(self, config: ArmConfig) -> None:
        with Emulator(config, baud=115200) as emu:
            with pytest.raises(SerialFault, match="does not answer like an SSC-32U at 9600 baud"):
                SSC32U(emu.port, 9600)
            with SSC32U(emu.port, 115200) as b:
                assert b.firmware.startswith("SSC32")

    def test_missing_port(self) -> None:
        with pytest.raises(PortUnavailable, match=r"/dev/nonexistent-ssc32u: cannot open"):
            SSC32U("/dev/nonexistent-ssc32u")

    def test_port_already_in_use(self, emulator: Emulator, board: SSC32U) -> None:
        with pytest.raises(SerialFault, match="cannot open"):
            SSC32U(emulator.port)
