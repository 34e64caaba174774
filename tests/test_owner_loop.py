"""The owner's loop on an emulated board in this process (`VirtualTransport`): what the loop
itself must get right, apart from the core's rules."""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import math
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Kind, Point
from al5d.arm.states import State
from al5d.owner import lane as ln
from al5d.owner import quick
from al5d.owner.client import SIGN_EVERY_MAX_S, Remote
from al5d.owner.loop import Owner
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator.board import Board
from al5d.ssc32u.emulator.virtual import VirtualTransport
from al5d_rig.rospeer import wait_until

#: How long a stop's write is held here: longer than a query's answer may take (its wire
#: time, the USB chip's 16 ms and `answer_timeout_s`, 50 ms) and the excuse for the host's
#: stalls (`al5d.arm.link.EXCUSE_MAX_S`, 150 ms), as a write to a full port at 9600 baud
#: (or one by a thread that waited for a core) may be held.
HELD_S = 0.3


class HeldWrites(VirtualTransport):
    """The virtual board, whose writes of anything but a query are held `HELD_S` after their
    bytes are on the wire once `held` is set; every write is kept (`writes`), a query's is
    said (`asked`)."""

    def __init__(self, board: Board) -> None:
        super().__init__(board)
        self.asked = threading.Event()
        self.writes: list[bytes] = []
        self.held = False

    def _write(self, data: bytes) -> None:
        super()._write(data)
        self.writes.append(data)
        if data.startswith(b"Q"):
            self.asked.set()
        elif self.held:
            time.sleep(HELD_S)


def test_an_answer_that_came_while_the_owner_wrote_is_read_before_its_deadline_is_judged(
    config: ArmConfig, caplog: pytest.LogCaptureFixture
) -> None:
    """A query's answer that came while the owner took a turn's requests (here a stop whose
    write a full port holds) was left in the port while the query's deadline was judged:
    the query was asked again, and the second ask's answer, left the same way, was a lost
    link ("no answer to QP, asked twice, 4 ms late", under a burst of 300 goals in CI).
    Here the idle check's query is followed at once by such a stop: its answer is read,
    and the next query is the stop's own, not the check asked again."""
    caplog.set_level(logging.WARNING, logger="al5d")
    transport = HeldWrites(Board(config, baud=config.server.baud))
    owner = Owner(config, transport).start()
    try:
        owner.wait_for_state(State.READY, 10)
        transport.held = True
        transport.asked.clear()
        assert transport.asked.wait(10), "no idle check asked of the board in 10 s"
        check = len(transport.writes) - 1
        owner.submit(ins.stop()).result(10)
        owner.wait_for_state(State.STOPPED, 10)
        owner.sync()

        def query_after_the_stop() -> tuple[bytes, bytes] | None:
            """The last query before the stop (the check, unless this thread stalled past
            the next one), and the first after it."""
            after = transport.writes[check:]
            esc = next((i for i, w in enumerate(after) if w.startswith(b"\x1b")), None)
            if esc is None:
                return None
            before = [w for w in after[:esc] if w.startswith(b"Q")][-1]
            following = next((w for w in after[esc + 1 :] if w.startswith(b"Q")), None)
            return None if following is None else (before, following)

        deadline = time.monotonic() + 10
        while (got := query_after_the_stop()) is None:
            assert time.monotonic() < deadline, "no query after the stop in 10 s"
            time.sleep(0.05)
        before, following = got
        after = transport.writes[check:]
        assert following != before, f"the check was asked again: {after}"
        assert owner.state is State.STOPPED, caplog.text
    finally:
        transport.held = False
        owner.close()


def test_writes_before_a_recorder_connects_are_kept_for_it(config: ArmConfig) -> None:
    """`al5d serve --record` with ROS: the bridge records the board's writes, and connects
    while the park may be on the wire already (an idle CI run's recording lacked the park's
    lines). With `keep_wire` the owner keeps them and tells the recorder (`recorder` in its
    hello) right after its welcome; another client watching the wire, even one that came
    first, hears only what follows its own hello."""
    transport = HeldWrites(Board(config, baud=config.server.baud))
    where = Path(tempfile.mkdtemp(prefix="al5d-"))  # short: a socket's path has a limit
    lane = where / "lane"
    owner = Owner(config, transport, lane=lane, keep_wire=True).start()
    try:
        owner.wait_for_state(State.READY, 10)
        owner.sync()
        before = [w for w in transport.writes if w.startswith(b"#")]
        assert before, transport.writes  # the park
        heard: list[bytes] = []
        other: list[bytes] = []
        n = len(transport.writes)
        with (
            Remote.connect(lane, watch=("wire",), on_wire=lambda w: other.append(w[0])),
            Remote.connect(
                lane, watch=("wire",), on_wire=lambda w: heard.append(w[0]), recorder=True
            ),
        ):
            owner.submit(ins.move(id="after", base=10)).result(10)
            owner.sync()
            deadline = time.monotonic() + 10
            while len(heard) < len(transport.writes) or not other:
                assert time.monotonic() < deadline, f"the writes not told: {heard}"
                time.sleep(0.01)
        # Every write from the start, in order, to the recorder; only the new ones to the
        # other (from one after `n`: an idle check may go out before its hello is taken).
        assert heard == transport.writes[: len(heard)]
        assert [w for w in heard if w.startswith(b"#")][: len(before)] == before
        at = next(i for i in range(n, len(transport.writes)) if transport.writes[i] == other[0])
        assert other == transport.writes[at : at + len(other)]
    finally:
        owner.close()
        shutil.rmtree(where, ignore_errors=True)


class HeldOnce(VirtualTransport):
    """The virtual board, whose next write once `hold` is set waits for `release`; the
    writes are kept, each with the bytes the test's peek found waiting then (`peek`)."""

    def __init__(self, board: Board) -> None:
        super().__init__(board)
        self.hold = False
        self.holding = threading.Event()
        self.release = threading.Event()
        self.peek: Callable[[], int] = lambda: 0
        self.writes: list[tuple[bytes, int]] = []

    def _write(self, data: bytes) -> None:
        super()._write(data)
        self.writes.append((data, self.peek()))
        if self.hold:
            self.hold = False
            self.holding.set()
            self.release.wait(10)


@contextlib.contextmanager
def two_lanes(
    config: ArmConfig, kind: type[Owner]
) -> Iterator[tuple[Owner, HeldOnce, socket.socket, socket.socket]]:
    """An owner of `kind` on a board whose writes can be held (`HeldOnce`), ready, with two
    lane connections: the owner, the board, and the client ends (judges, stops)."""
    transport = HeldOnce(Board(config, baud=config.server.baud))
    owner = kind(config, transport).start()
    pairs = [socket.socketpair() for _ in range(2)]
    try:
        owner.wait_for_state(State.READY, 10)
        for _, end in pairs:
            owner.adopt(end)
        owner.sync()
        yield owner, transport, pairs[0][0], pairs[1][0]
    finally:
        transport.release.set()
        owner.close()
        for a, b in pairs:
            a.close()
            b.close()


def test_a_stop_read_in_a_turn_goes_before_the_judgements_read_in_it(config: ArmConfig) -> None:
    """A trajectory's judgement takes milliseconds. Judged as its connection was read, a
    burst of them held a stop that the same turn read from another connection until all
    were judged; taken in its turn among the requests, it waits for none of them. Here
    the owner is held in a write while twenty judgements and then a stop arrive on two
    connections: when the stop's STOP goes out, no judgement has been answered yet. (The
    twenty are 60 kB: they fit in the socket's buffer, 208 kB by default on Linux, while
    the owner is held.)"""
    with two_lanes(config, Owner) as (owner, transport, judges, stops):
        judges.setblocking(False)

        def waiting() -> int:
            try:
                return len(judges.recv(1 << 20, socket.MSG_PEEK | socket.MSG_DONTWAIT))
            except BlockingIOError:
                return 0

        transport.peek = waiting
        points = [Point((("base", 0.1 * k),), 20.0 * (k + 1)) for k in range(100)]
        burst = b"".join(
            ln.dumps({"op": "judge", "ref": k, "instr": ln.instruction_out(ins.trajectory(points))})
            for k in range(20)
        )
        transport.hold = True
        owner.submit(ins.move(base=1))  # a write, which the transport holds
        assert transport.holding.wait(10)
        judges.sendall(burst)
        stops.sendall(ln.dumps({"op": "ask", "ref": 1, "instr": ln.instruction_out(ins.stop())}))
        transport.release.set()
        owner.wait_for_state(State.STOPPED, 10)
        owner.sync()
        stop_writes = [peeked for data, peeked in transport.writes if b"STOP" in data]
        assert stop_writes and stop_writes[0] == 0, (stop_writes, transport.writes[-30:])
        transport.peek = lambda: 0
        judges.setblocking(True)
        judges.settimeout(30)
        answered = b""
        while answered.count(b'"judged"') < 20:
            answered += judges.recv(1 << 16)


def test_a_wait_for_a_state_entered_and_left_before_the_waiter_runs_ends(
    config: ArmConfig,
) -> None:
    """A state told and left again at once (a stop, then a release; a reset's fault, then
    locked) before a waiter for it has run: the waiter still sees that it came. (It looked
    only at the state told last: a test waiting for a reset's fault timed out on a busy
    host when locked had followed.) Here the owner's teller is held while the stop and the
    release are taken, so that the two are told back to back."""
    owner = Owner(config, VirtualTransport(Board(config, baud=config.server.baud))).start()
    try:
        owner.wait_for_state(State.READY, 10)
        held = threading.Event()
        owner._teller.put(held.wait)
        owner.submit(ins.stop())
        wait_until(lambda: owner.state is State.STOPPED, 10, "stopped (the core's state)")
        owner.submit(ins.release())
        wait_until(lambda: owner.state is State.READY, 10, "ready (the core's state)")
        came: list[BaseException | None] = []

        def wait() -> None:
            try:
                owner.wait_for_state(State.STOPPED, 10)
                came.append(None)
            except BaseException as e:  # handed to the test's thread
                came.append(e)

        waiter = threading.Thread(target=wait)
        waiter.start()
        time.sleep(0.1)  # the waiter waits (nothing told yet: it would wait all the same)
        held.set()
        waiter.join(30)
        assert came == [None], came
        assert owner.announced is State.READY
    finally:
        owner.close()


def test_a_motion_judged_while_the_arm_takes_no_moves_is_refused_then(config: ArmConfig) -> None:
    """An action's goal is judged at the owner when it comes, and submitted later: one
    judged just after a stop and submitted after a release ran (an outside try: 7 times in
    27, a trajectory goal sent as the arm was stopped moved it after the release). The
    judgement is refused while the arm is locked, as the submission would be then."""
    owner = Owner(config, VirtualTransport(Board(config, baud=config.server.baud))).start()
    ours, theirs = socket.socketpair()
    try:
        owner.wait_for_state(State.READY, 10)
        owner.adopt(theirs)
        owner.sync()
        ours.settimeout(30)
        lines = ours.makefile("rb")

        def judged(ref: int) -> dict[str, object]:
            instr = ln.instruction_out(ins.move(time_ms=500, base=10))
            ours.sendall(ln.dumps({"op": "judge", "ref": ref, "instr": instr}))
            while True:
                message = ln.loads(lines.readline())
                if message.get("op") == "judged" and message.get("ref") == ref:
                    return message

        assert "ticket" in judged(1)
        assert owner.submit(ins.stop()).result(10).ok
        refused = judged(2)
        assert "ticket" not in refused and "send release first" in str(refused["reason"]), refused
        assert owner.submit(ins.release()).result(10).ok
        ticket = judged(3)["ticket"]
        # A goal that ends before it runs lets go of its ticket: the owner keeps none.
        ours.sendall(ln.dumps({"op": "drop", "ticket": ticket}))
        ours.sendall(ln.dumps({"op": "ask", "ref": 4, "ticket": ticket}))
        while (message := ln.loads(lines.readline())).get("ref") != 4:
            pass
        assert message["op"] == "error" and "no ticket" in str(message["error"]), message
    finally:
        owner.close()
        ours.close()
        theirs.close()


#: Lines a lane client sent that ended the owner's thread (an outside reading: a client of
#: the lane is any process of the user's), each with what its error says now.
KILLING_LINES = [
    (b'{"op": "hello", "watch": [[1]]}', "hello: watch is a list of"),
    (b'{"op": "ask", "ref": 1, "instr": {"kind": "move", "points": 5}}', "points is not a list"),
    (b'{"op": "ask", "ref": 2, "instr": {"kind": "move", "points": true}}', "points is not a"),
    (b'{"op": "ping", "ref": NaN}', "NaN is not JSON"),
    (
        b'{"op": "ask", "ref": 4, "key": '
        + b"[" * 600
        + b"]" * 600
        + b', "instr": {"kind": "stop"}}',
        "key: nested deeper than",
    ),
    (b'{"op": "ask", "ref": ' + b"[" * 980 + b"]" * 980 + b"}", "ref must be a number or text"),
    (b'{"op": "ping", "x": ' + b"[" * 50_000 + b"]" * 50_000 + b"}", "nested too deep"),
    (
        b'{"op": "ask", "ref": 3, "instr": {"kind": "move", "joints": [["base", 1'
        + b"0" * 400
        + b"]]}}",
        "no number a double holds",
    ),
]


def _answers(sock: socket.socket, ref: str, timeout: float = 30) -> list[dict[str, object]]:
    """The owner's messages on `sock` up to the pong of the ping `ref` sent now; an
    AssertionError if the connection ends first (the owner gone)."""
    sock.sendall(ln.dumps({"op": "ping", "ref": ref}))
    sock.settimeout(timeout)
    got: list[dict[str, object]] = []
    buf = b""
    while True:
        data = sock.recv(1 << 16)
        assert data, f"the owner closed the lane before the pong of {ref}: {got[-5:]}"
        buf += data
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            message = ln.loads(line)
            if message.get("op") == "pong" and message.get("ref") == ref:
                return got
            got.append(message)


def test_a_lane_line_that_ended_the_owner_gets_its_error_and_the_owner_goes_on(
    config: ArmConfig,
) -> None:
    owner = Owner(config, VirtualTransport(Board(config, baud=config.server.baud))).start()
    ours, theirs = socket.socketpair()
    try:
        owner.wait_for_state(State.READY, 10)
        owner.adopt(theirs)
        for k, (line, error) in enumerate(KILLING_LINES):
            ours.sendall(line + b"\n")
            errors = [str(m.get("error")) for m in _answers(ours, f"p{k}") if m["op"] == "error"]
            assert any(error in e for e in errors), (line[:80], errors)
        assert not owner.ending.is_set()
        assert owner.submit(ins.move(base=5, time_ms=100)).result(10).ok
    finally:
        owner.close()
        ours.close()
        theirs.close()


def _nested(depth: int) -> object:
    """A list nested `depth` deep (Python reads JSON, and hashes and writes it, by
    recursion: near its limit a value a client sent ended the owner's thread)."""
    value: list[object] = []
    for _ in range(depth - 1):
        value = [value]
    return value


def _json() -> st.SearchStrategy[object]:
    leaves = (
        st.none()
        | st.booleans()
        | st.integers()
        | st.integers(min_value=10**300, max_value=10**320)
        | st.floats()
        | st.sampled_from(["nan", "inf", "-inf", "base", "wire", "move", ""])
        | st.text(max_size=8)
        | st.integers(1, 900).map(_nested)
    )
    return st.recursive(
        leaves,
        lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner),
        max_leaves=12,
    )


def _lane_messages() -> st.SearchStrategy[dict[str, object]]:
    """Messages as a client of the lane might send them: every op, every field the desk
    reads, each a value of the right shape or any JSON at all (no shutdown: it ends the
    owner as asked; no lease: this connection would be lost while the test waits)."""
    anything = _json()
    kinds = st.sampled_from([k.value for k in Kind if k is not Kind.SHUTDOWN]) | anything
    pair = st.tuples(st.sampled_from(["base", "elbow", "x"]) | anything, anything).map(list)
    joints = st.lists(pair, max_size=3) | anything
    point = st.tuples(joints, anything).map(list)
    instr = st.fixed_dictionaries(
        {"kind": kinds},
        optional={
            name: anything | shaped
            for name, shaped in {
                "id": st.text(max_size=8),
                "preset": st.sampled_from(["park", "ready", "nope"]),
                "time_ms": st.integers(-10, 5000),
                "joints": joints,
                "points": st.lists(point, max_size=3),
                "tool": st.lists(anything, min_size=7, max_size=7),
                "sent_ns": st.integers(),
                "wait_ms": st.integers(),
                "start_ns": st.integers(),
            }.items()
        },
    )
    fields = {
        "ref": anything,
        "instr": instr | anything,
        "follow": st.fixed_dictionaries({}, optional={"tolerance": anything, "late_ms": anything})
        | anything,
        "ticket": anything,
        "id": anything,
        "reason": anything,
        "watch": st.lists(st.sampled_from(ln.WATCHES) | anything, max_size=3) | anything,
        "name": anything,
        "recorder": anything,
        "ros": anything,
        "for": anything,
        "why": anything,
        "stream": anything,
        "key": anything,
        "tell": anything,
    }
    ops = st.sampled_from(
        ["ask", "judge", "drop", "cancel", "hello", "kept", "ping", "sign", "bye", "gone", "no"]
    )
    return st.fixed_dictionaries({"op": ops}, optional=fields)


def test_no_message_of_a_lane_client_ends_the_owner(config: ArmConfig) -> None:
    """Whatever a lane client sends, each message gets its answer or its error and the owner
    goes on (hypothesis: messages of every op with fields of any JSON)."""
    owner = Owner(config, VirtualTransport(Board(config, baud=config.server.baud))).start()
    ours, theirs = socket.socketpair()
    sent = itertools.count()
    try:
        owner.wait_for_state(State.READY, 10)
        owner.adopt(theirs)

        @settings(max_examples=400, deadline=None, database=None)
        @given(_lane_messages())
        def one(message: dict[str, object]) -> None:
            ours.sendall(json.dumps(message).encode() + b"\n")  # NaN as JSON never says
            _answers(ours, f"p{next(sent)}")
            assert not owner.ending.is_set(), message

        one()
        assert owner.submit(ins.stop()).result(10).ok
        assert owner.submit(ins.release()).result(10).ok
        assert owner.submit(ins.move(base=5, time_ms=100)).result(10).ok
    finally:
        owner.close()
        ours.close()
        theirs.close()


class FailsOnRead(VirtualTransport):
    """The virtual board, whose reading raises once `fail` is set (an owner's bug); every
    write is kept (`writes`)."""

    def __init__(self, board: Board) -> None:
        super().__init__(board)
        self.fail = False
        self.writes: list[bytes] = []

    def _write(self, data: bytes) -> None:
        super()._write(data)
        self.writes.append(data)

    def read(self) -> bytes:
        if self.fail:
            raise RuntimeError("a bug of the test's own, in the owner's thread")
        return super().read()


def test_an_owner_that_fails_stops_the_board_with_its_last_write(config: ArmConfig) -> None:
    """Without it, the board ran the group move it held to its end with nobody to stop it."""
    transport = FailsOnRead(Board(config, baud=config.server.baud))
    owner = Owner(config, transport).start()
    try:
        owner.wait_for_state(State.READY, 10)
        moving = owner.submit(ins.move(base=60, time_ms=5000))
        owner.wait_for_state(State.MOVING, 10)
        transport.fail = True
        assert owner.ending.wait(10)
        outcome = moving.result(10)
        assert not outcome.ok and "the owner failed" in outcome.reason, outcome
        last = transport.writes[-1]
        assert last == p.CANCEL + p.encode_stop(sorted(owner.arm.channels.values())), last
        assert len(transport.writers) == 1  # the owner's thread, to its end
    finally:
        owner.close()


class SlowJudge(Owner):
    """The owner, whose every judgement takes `JUDGE_S`, as a long trajectory's does."""

    JUDGE_S = 0.02

    def judge(self, instr: ins.Instruction, follow: object = None) -> object:  # type: ignore[override]
        time.sleep(self.JUDGE_S)
        return super().judge(instr)


def test_a_stop_sent_while_the_owner_judges_waits_for_one_judgement_not_the_turns(
    config: ArmConfig,
) -> None:
    """Ten judgements read in one turn, each taking 20 ms: a stop sent on another connection
    once the first is answered goes out after at most two more (the turn's work is
    bounded, `TURN_WORK_S`), not after the ten (a second reading: the 32 requests a turn
    took held a stop that long)."""
    with two_lanes(config, SlowJudge) as (owner, transport, judges, stops):
        instr = ln.instruction_out(ins.move(time_ms=500, base=10))
        burst = b"".join(ln.dumps({"op": "judge", "ref": k, "instr": instr}) for k in range(10))
        transport.hold = True
        owner.submit(ins.move(base=1))  # a write, which the transport holds
        assert transport.holding.wait(10)
        judges.sendall(burst)  # read whole in the owner's next turn
        transport.release.set()
        judges.settimeout(30)
        first = judges.recv(1 << 16)
        assert b'"judged"' in first, first
        answered = first.count(b'"judged"')

        def waiting() -> int:
            try:
                return answered + judges.recv(1 << 20, socket.MSG_PEEK).count(b'"judged"')
            except BlockingIOError:
                return answered

        judges.setblocking(False)
        transport.peek = waiting
        stops.sendall(ln.dumps({"op": "ask", "ref": 1, "instr": ln.instruction_out(ins.stop())}))
        owner.wait_for_state(State.STOPPED, 10)
        owner.sync()
        judged_before = [peeked for data, peeked in transport.writes if b"STOP" in data]
        assert judged_before and judged_before[0] <= answered + 2, judged_before


def test_a_lane_stop_stamped_in_the_future_is_taken_as_sent_when_it_came(
    config: ArmConfig,
) -> None:
    """An outside try: a stop sent with `sent_ns` of 2**63 - 1 held every release refused
    ("sent before the stop") until the server ended. And a connection says hello once: a
    flood of them, each welcomed as it was read, held other lanes' stops up to 0.9 s."""
    owner = Owner(config, VirtualTransport(Board(config, baud=config.server.baud))).start()
    ours, theirs = socket.socketpair()
    try:
        owner.wait_for_state(State.READY, 10)
        owner.adopt(theirs)
        hello = {"op": "hello", "name": "twice", "watch": []}
        ours.sendall(ln.dumps(hello) + ln.dumps(hello))
        errors = [str(m.get("error")) for m in _answers(ours, "h") if m["op"] == "error"]
        assert errors == ["hello: once a connection"], errors
        stop = {"kind": "stop", "id": "ahead", "sent_ns": 2**63 - 1}
        ours.sendall(ln.dumps({"op": "ask", "ref": 1, "instr": stop}))
        owner.wait_for_state(State.STOPPED, 10)
        released = owner.submit(ins.release()).result(10)
        assert released.ok, released
        assert owner.submit(ins.move(base=5, time_ms=100)).result(10).ok
    finally:
        owner.close()
        ours.close()
        theirs.close()


@pytest.mark.parametrize("lease_s", [1.0, 60.0])
def test_a_leased_clients_signs_are_answered_so_that_it_hears_the_owner_turn(
    config: ArmConfig, lease_s: float
) -> None:
    """An idle owner said nothing to its clients: one whose owner had frozen (its lane open)
    could not tell it from a quiet one, and waited for an outcome without a word. A leased
    client's signs (four a second at least) are answered by the owner's thread: its
    `quiet` stays short while the owner turns (without the answers it grew to the whole
    3 s here); a client not leased is told nothing while idle, and says so (None). A long
    lease signs as often (a 60 s lease signed every 15 s: a client could not tell a
    turning owner from a frozen one)."""
    server = config.server.model_copy(update={"client_lease_s": lease_s})
    config = config.model_copy(update={"server": server})
    owner = Owner(config, VirtualTransport(Board(config, baud=config.server.baud))).start()
    pairs = [socket.socketpair() for _ in range(2)]
    try:
        owner.wait_for_state(State.READY, 10)
        for _, theirs in pairs:
            owner.adopt(theirs)
        with (
            Remote(pairs[0][0], lease=True, watch=()) as leased,
            Remote(pairs[1][0], watch=()) as idle,
        ):
            every = SIGN_EVERY_MAX_S
            quiet: list[float] = []
            end = time.monotonic() + 12 * every
            while time.monotonic() < end:
                time.sleep(every / 5)
                said = leased.quiet()
                quiet.append(math.inf if said is None else said)
                assert idle.quiet() is None
            assert max(quiet) < 6 * every, quiet
    finally:
        owner.close()
        for pair in pairs:
            for sock in pair:
                sock.close()


def test_a_stop_on_a_new_connection_goes_before_what_an_older_one_sent_in_the_same_stall(
    config: ArmConfig,
) -> None:
    """An owner held (here in a write to the board; a frozen process in an outside try)
    while a client it knows sends a move and then a new connection hands it a stop (`al5d
    send stop`, the web page's STOP): the new connection was accepted in the first turn
    after, but read only in the next, so the older one's move was taken first (in the
    outside try, a lost client's halt ran 1 ms before the STOP). A new connection is read
    as it is accepted: the STOP goes out before any of the move's bytes."""
    transport = HeldOnce(Board(config, baud=config.server.baud))
    where = Path(tempfile.mkdtemp(prefix="al5d-"))  # short: a socket's path has a limit
    lane = where / "lane"
    owner = Owner(config, transport, lane=lane).start()
    older = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        owner.wait_for_state(State.READY, 10)
        older.connect(str(lane))
        owner.sync()
        transport.hold = True  # the next write: the idle check's query
        assert transport.holding.wait(30), "no write held"
        held = len(transport.writes)
        move = ln.instruction_out(ins.move(time_ms=500, base=30))
        older.sendall(ln.dumps({"op": "ask", "ref": 1, "instr": move}))
        stop = quick.hand_stop(lane, "new-stop", 1.0)
        assert stop is not None
        transport.release.set()
        answer = quick.answer(stop, 10)
        assert answer.get("result") == "done", answer
        owner.sync()
        after = [data for data, _ in transport.writes[held:]]
        first_stop = next(i for i, data in enumerate(after) if b"STOP" in data)
        assert not [d for d in after[:first_stop] if d.startswith(b"#")], after
    finally:
        transport.release.set()
        older.close()
        owner.close()
        shutil.rmtree(where, ignore_errors=True)
