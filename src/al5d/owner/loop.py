"""The owner of the board: one thread holds the arm's core and is the only one that writes to
the board.

`Owner` runs the core (`al5d.arm.core.step`) in a thread of its own, at the stop path's
priority: it takes each input (a request from this process or from a client of its
local lane, the board's bytes, the time passing), steps the core with it, and carries
the effects out: bytes to the board through its `Transport`, outcomes and news to the
lane's clients and its listeners (`al5d.owner.news`), and the rest (in-process futures,
the log) to its teller thread, so that it never runs anyone else's code. Its inbox has
two lanes: every stop waiting is taken before anything else, and goes to the wire in the
same step.

    owner = Owner(config, SerialTransport(port, baud)).start()
    owner.execute(move(base=30, time_ms=800))      # an Outcome
    owner.submit(stop())                           # a Future[Outcome]
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import selectors
import socket
import threading
from collections import deque
from collections.abc import Hashable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import replace
from pathlib import Path
from typing import Any

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.core import step, takes_no_moves, wake_at
from al5d.arm.corestate import (
    Announce,
    Arm,
    Ask,
    Cancel,
    Cancelled,
    Close,
    Core,
    Effect,
    End,
    Failed,
    Gone,
    Input,
    Moved,
    Open,
    Opened,
    Posed,
    Received,
    Reply,
    Resolve,
    Say,
    Send,
    Tick,
)
from al5d.arm.instruction import Instruction, Kind, Outcome, Result
from al5d.arm.resample import Follow
from al5d.arm.states import Event, State
from al5d.arm.validate import Ticket, judge
from al5d.clock import Deadline, now, wall_ns
from al5d.owner import lane as ln
from al5d.owner.conns import Conn, Conns
from al5d.owner.desk import Desk, Request
from al5d.owner.news import News
from al5d.owner.teller import Teller
from al5d.priority import cpu_waited_s, make_urgent
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import LinkLost, SerialFault
from al5d.ssc32u.transport import SerialTransport, Transport

log = logging.getLogger("al5d")

#: Requests other than stops taken in one turn, at most: a stop that comes meanwhile waits
#: for no more than these.
BATCH = 32
#: The work a turn does on those requests, at most (s of the owner's time): a stop that
#: comes meanwhile on a lane waits for the owner's next look at its lanes, and the
#: judgement of a long trajectory takes milliseconds (a second reading: 32 of them in one
#: turn held a stop that long). One request is always taken.
TURN_WORK_S = 0.005
#: The longest the owner sleeps without looking (a lost wake-up is found then).
SLEEP_MAX_S = 0.5
#: A thread that woke this much later than it asked was not running: the host's stall.
LATE_S = 0.002


class Owner:
    """The board's one owner, on `transport`, for the arm of `config`. With `lane`, clients of
    this machine reach it on that Unix socket (`al5d.owner.lane`)."""

    def __init__(
        self,
        config: ArmConfig,
        transport: Transport,
        *,
        lane: Path | None = None,
        config_file: Path | None = None,
        keep_wire: bool = False,
    ) -> None:
        self.config = config
        #: The file the configuration was read from (None: the shipped one, or none).
        self.config_file = config_file
        self.transport = transport
        self.port = transport.port
        self.baud = transport.baud
        self.settings = config.server
        self.arm = Arm.of(config, transport.port, transport.baud)
        self._core = Core.start(self.arm, now())
        self.finished = threading.Event()
        #: Set as the owner begins to end, before it closes its lanes: a client that ends
        #: after this (its lane closed) ends as it should (`finished` comes later).
        self.ending = threading.Event()
        self.ended: End | None = None
        self._teller = Teller()
        self._refs = itertools.count(1)
        self._futures: dict[int, Future[Any]] = {}
        self._stops: deque[Request] = deque()
        self._others: deque[tuple[str, int, Any]] = deque()
        self._pending: deque[Input] = deque()  # inputs the effects made (a port opened)
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._woken = False  # a byte is in the pipe for the next turn (`_wake`)
        self._transport_fd: int | None = None
        self._broken = False  # a write failed in this step: no more of its bytes
        self._free_at = 0.0  # when the bytes written so far reach the board
        self._writes = 0
        self._stalled = 0.0
        self._cpu_waited = cpu_waited_s()
        self._lanes = Conns(self._selector, lambda conn, why: self._desk.dropped(conn, why), lane)
        self._desk = Desk(self._lanes, self, config.server.client_lease_s)
        self._news = News(self._teller, self._lanes, keep_wire=keep_wire)
        # The listeners, told from the teller's thread (`al5d.owner.news`).
        self.outcome_listeners = self._news.outcome_listeners
        self.state_listeners = self._news.state_listeners
        self.motion_listeners = self._news.motion_listeners
        self.pose_listeners = self._news.pose_listeners
        #: Every write to the board: (its bytes, when written, when its last byte arrives).
        self.wire_listeners = self._news.wire_listeners
        #: Told every instruction as the owner takes it (from any client), before it is judged.
        self.submit_listeners = self._news.submit_listeners
        #: Told the socket of each leased lane client lost for its silence (`Conn.lease_s`),
        #: from the teller's thread: the process behind it may hang for good.
        self.lapsed_listeners = self._news.lapsed_listeners
        self._announced = self._news.announced
        self._thread = threading.Thread(target=self._run, name="al5d-owner", daemon=True)
        self._closing = False

    @classmethod
    def on_port(
        cls, config: ArmConfig, port: str, baud: int | None = None, *, lane: Path | None = None
    ) -> Owner:
        """The owner of the board at `port` (a serial device or a pty) at `baud` (the
        config's by default)."""
        return cls(config, SerialTransport(port, baud or config.server.baud), lane=lane)

    # -- the public API (any thread) ---------------------------------------------------------

    def start(self) -> Owner:
        """Start the owner's thread: it opens the port, parks (D1, VE03), then the arm is
        ready."""
        log.info("STATE: %s", self._core.state.value)
        log.debug("EVENT: %s", Event.START.value)
        self._thread.start()
        return self

    @property
    def core(self) -> Core:
        """The core as it is now (a value: safe to read from any thread)."""
        return self._core

    @property
    def state(self) -> State:
        return self._core.state

    @property
    def announced(self) -> State:
        """The state last told (logged, and to the state listeners)."""
        return self._announced.state

    @property
    def locked(self) -> bool:
        return self._core.locked

    @property
    def lane(self) -> Path | None:
        """The local lane's socket, where it could be made."""
        return self._lanes.path

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles (degrees; NaN where unknown since power-up)."""
        return self._core.positions(now() if t is None else t)

    def progress(self, ident: str) -> float | None:
        """0..1 of the instruction `ident` if it is the one running (by its steps)."""
        c = self._core
        run, motion = c.run, c.book.motion
        if run is None or motion is None or run.job.instr.id != ident or not run.steps:
            return None
        return (run.k + motion.progress(now())) / len(run.steps)

    def judge(self, instr: Instruction, follow: Follow | None = None) -> Ticket | str:
        """The one judgement of a motion instruction (D3): its ticket, to submit as it is, or
        the reason to refuse it whole. `follow`: a trajectory's tolerances, where its sender
        gives them; where the arm rests is known here. Refused while the arm takes no move
        (stopped, faulted, shutting down), as its submission would be: a goal judged here
        just after a stop, then submitted after a release, was sent before that release
        (an outside try: a trajectory goal sent as the arm was stopped ran after the
        release, 7 times in 27)."""
        busy = takes_no_moves(self._core)
        if busy:
            return busy
        if follow is not None and follow.start is None and self._core.state is State.READY:
            pose = self._core.book.pose
            start = {j: v for j, v in pose.items() if v is not None}
            follow = replace(follow, start=start)
        return judge(instr, self.arm.limits, follow)

    def submit(
        self,
        what: Instruction | Ticket,
        *,
        key: Hashable | None = None,
        stream: str = "",
        listeners: bool = True,
        client: int = 0,
    ) -> Future[Outcome]:
        """Hand over an instruction (or a ticket of `judge`); its Future resolves to its one
        outcome. `key` identifies a stop message that two readers may both see (obeyed and
        answered once); `stream`: a set-point of that stream (the latest wins); with
        `listeners` False the outcome listeners do not hear of it."""
        instr = what.instr if isinstance(what, Ticket) else what
        ticket = what if isinstance(what, Ticket) else None
        if instr.sent_ns is None:
            # Sent now, as the caller asks: a stop asked later but taken first (the stop's
            # lane) must not take this for a request sent after it.
            instr = replace(instr, sent_ns=wall_ns())
            if ticket is not None:
                ticket = replace(ticket, instr=instr)
        future: Future[Outcome] = Future()
        if self.finished.is_set():
            reason = "the server has ended"
            future.set_result(Outcome(instr.id, instr.name, Result.REFUSED, reason))
            return future
        ref = next(self._refs)
        self._futures[ref] = future
        self.put(Request(ref, instr, ticket, stream, key, client, listeners))
        return future

    def execute(self, instr: Instruction, timeout: float | None = None) -> Outcome:
        """Submit and wait for the outcome."""
        return self.submit(instr).result(timeout)

    def cancel(self, ident: str, reason: str = "cancelled by the client") -> bool:
        """Cancel one move: drop it if it waits, halt the arm (without the lock) if it runs.
        False when it has already ended (or was never here)."""
        future: Future[bool] = Future()
        ref = next(self._refs)
        self._futures[ref] = future
        self._others.append(("cancel", ref, (ident, reason)))
        self._wake()
        if threading.current_thread() is self._thread:
            raise RuntimeError("cancel() from the owner's own thread would wait for itself")
        return future.result(30.0)

    def sync(self, timeout: float = 10.0) -> None:
        """Until the owner has taken every request handed to it so far and told what they
        made (outcomes, listeners): for tests that check what a request did at once."""
        future: Future[bool] = Future()
        self._others.append(("barrier", 0, future))
        self._wake()
        deadline = Deadline(timeout)
        while not future.done():
            if not self._thread.is_alive():
                return  # it has ended: it takes nothing more
            try:
                future.result(min(0.1, deadline.left()))
            except FutureTimeout:
                if deadline.expired:
                    raise

    def wait_for_state(self, state: State, timeout: float = 10.0) -> None:
        """Until `state` is the state told (logged, listeners told), or has been told since
        the call though left again (`StateTold`). Raises TimeoutError."""
        if not self._announced.wait(state, timeout):
            now_ = self._announced.state.value
            raise TimeoutError(f"state {state.value} not reached in {timeout} s (now {now_})")

    @property
    def parked_at_end(self) -> bool | None:
        """After the shutdown: whether the arm reached park (None while it has not ended)."""
        return None if self.ended is None else self.ended.parked

    def close(self, timeout: float = 30.0) -> None:
        """Shut down (park first) unless that has happened, and wait for the owner's end."""
        if self._thread.is_alive() and not self._core.ended and self._core.shutdown is None:
            self.submit(ins.shutdown())
        if self._thread.is_alive():
            self.finished.wait(timeout)
        self._closing = True
        self._wake()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(5)
        self._teller.close()
        self.finished.set()

    def adopt(self, sock: socket.socket) -> None:
        """A lane connection made elsewhere (a socket pair with a bridge this process
        started): a client like any other; closed at once if the owner is ending."""
        if self.ending.is_set():
            sock.close()
            return
        sock.setblocking(False)
        self._others.append(("adopt", 0, sock))
        self._wake()

    # -- taking inputs ---------------------------------------------------------------------

    def put(self, request: Request) -> None:
        """A request for the core, from any thread: a stop on the stops' lane."""
        if request.instr.kind is Kind.STOP:
            self._stops.append(request)
        else:
            self._others.append(("ask", request.ref, request))
        self._wake()

    def _wake(self) -> None:
        # One byte per turn is enough: the turn clears the flag before it looks at its
        # inboxes, so whatever was put before the clear is seen, and whatever after it
        # writes again (a write per request cost the submitter a third of its time).
        if self._woken or self._wake_w < 0:
            return
        self._woken = True
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._wake_w, b"!")

    def _run(self) -> None:
        make_urgent("al5d-owner")
        try:
            self._input(Tick(now(), wall_ns()))
            while not self._core.ended and not self._closing:
                self._turn()
        except BaseException as e:
            log.exception("the owner failed; the server ends")
            self._halt_as_it_fails()
            self._fail_all(f"the owner failed: {e!r}")
        finally:
            self._end()

    def _turn(self) -> None:
        """One turn: wait for something (or the core's next wake), then take it all: the
        board's bytes, every stop, the other requests (`BATCH` at most), the time."""
        self._woken = False
        t = now()
        lease_due = self._lanes.lease_due(self._stalled)
        wake = min(wake_at(self._core), t + SLEEP_MAX_S, lease_due)
        due = self.transport.due() if self._core.link.open else None
        if due is not None:
            wake = min(wake, due)
        busy = self._stops or self._others or self._pending or self._closing
        timeout = 0.0 if busy else max(0.0, wake - t)
        events = self._selector.select(timeout)
        woke = now()
        if not busy and woke - max(wake, t) > LATE_S:
            self._stalled += woke - max(wake, t)
        for key, mask in events:
            self._event(key.data, mask)
        self._read_board(woke)
        while self._stops:
            self._take_stop(self._stops.popleft())
        if woke >= lease_due:  # after the stops: they go to the wire first
            self._lapsed(woke)
        taking = now()
        for _ in range(BATCH):
            if not self._others:
                break
            self._take(self._others.popleft())
            if self._stops or now() - taking > TURN_WORK_S:
                break
        if self._core.link.query is not None:
            # The tick judges the query's deadline: an answer that came while this turn's
            # requests were taken (a write held by a full port) is in the port, and must be
            # read first, or it is taken for none and asked again (twice: a fault).
            self._read_board(now(), ready=self._transport_fd is not None)
        self._input(Tick(now(), wall_ns(), self._host_stalls()))

    def _host_stalls(self) -> float:
        """The owner's own stalls, and, while a query waits for its answer, the host's (the
        time runnable tasks waited for a core: the kernel's work that carries the port's
        bytes, and a board emulated on this host, wait their turn too)."""
        if self._core.link.query is not None:
            waited = cpu_waited_s()
            if waited is not None and self._cpu_waited is not None:
                self._stalled += max(0.0, waited - self._cpu_waited)
            self._cpu_waited = waited
        else:
            self._cpu_waited = None
        return self._stalled

    def _event(self, data: Any, mask: int) -> None:
        if data == "wake":
            with contextlib.suppress(BlockingIOError, OSError):
                os.read(self._wake_r, 4096)
        elif data == "listen":
            # Read as accepted, in this turn: a stop handed over on a new connection (`al5d
            # send stop`, the web page's STOP) goes before what older ones sent meanwhile.
            for conn in self._lanes.accept():
                self._desk.read(conn, self._stalled)
        elif data == "board":
            self._read_board(now(), ready=True)
        elif isinstance(data, Conn):
            if mask & selectors.EVENT_WRITE:
                self._lanes.flush(data)
            if mask & selectors.EVENT_READ:
                self._desk.read(data, self._stalled)

    def _read_board(self, t: float, ready: bool = False) -> None:
        """What the board has sent: when its descriptor is `ready`, or (a transport with
        none, an emulated board) when it is due."""
        if not self._core.link.open:
            return
        if not ready:
            due = self.transport.due()
            if self._transport_fd is not None or due is None or due > t:
                return
        try:
            data = self.transport.read()
        except LinkLost as e:
            self._input(Failed(now(), wall_ns(), e))
            return
        if data:
            self._input(Received(now(), wall_ns(), data))

    def _take_stop(self, request: Request) -> None:
        self._ask(request)

    def _ask(self, r: Request) -> None:
        if r.tell:
            self._news.submitted(r.instr)
        self._input(
            Ask(now(), wall_ns(), r.ref, r.instr, r.ticket, r.stream, r.key, r.client, r.tell)
        )

    def _take(self, entry: tuple[str, int, Any]) -> None:
        what, ref, payload = entry
        t, wall = now(), wall_ns()
        if what == "ask":
            self._ask(payload)
        elif what == "cancel":
            ident, reason = payload
            self._input(Cancel(t, wall, ref, ident, reason))
        elif what == "gone":
            client, why = payload
            self._input(Gone(t, wall, client, why))
        elif what == "adopt":
            self._lanes.connect(payload)
        elif what == "barrier":
            self._teller.put(lambda: _set(payload, True))
        elif what == "judge":
            self._desk.judge(*payload)

    def _input(self, ev: Input) -> None:
        """Step the core with `ev`, carry out its effects, then the inputs they made."""
        self._pending.append(ev)
        while self._pending:
            self._core, effects = step(self._core, self._pending.popleft())
            self._broken = False
            for effect in effects:
                if isinstance(effect, End):  # known before its shutdown's outcome is told
                    self.ended = effect
            for effect in effects:
                self._carry(effect)

    # -- effects ---------------------------------------------------------------------------

    def _carry(self, effect: Effect) -> None:
        if isinstance(effect, Send):
            self._send(effect.data)
        elif isinstance(effect, Resolve):
            self._resolve(effect)
        elif isinstance(effect, Cancelled):
            for resolve in effect.resolves():
                self._resolve(resolve)
        elif isinstance(effect, Posed):
            self._news.posed(effect)
        elif isinstance(effect, Moved):
            self._news.moved(effect.sent)
        elif isinstance(effect, Announce):
            self._news.state(effect, self._core.locked)
        elif isinstance(effect, Reply):
            self._reply(effect.ref, effect.ok)
        elif isinstance(effect, Say):
            level, text = effect.level, effect.text
            self._teller.put(lambda: log.log(level, "%s", text))
        elif isinstance(effect, Open):
            self._open()
        elif isinstance(effect, Close):
            self._close_board()

    def _send(self, data: bytes) -> None:
        if self._broken:
            return
        t = now()
        try:
            self.transport.write(data)
            self._writes += 1
        except LinkLost as e:
            self._broken = True
            self._pending.append(Failed(now(), wall_ns(), e))
            return
        self._free_at = max(t, self._free_at) + p.wire_time_s(len(data), self.baud)
        self._news.wire(data, t, self._free_at)

    def _open(self) -> None:
        t = now()
        try:
            low = self.transport.open()
        except SerialFault as e:  # PortUnavailable, most often: a board unplugged
            self._pending.append(Opened(t, wall_ns(), e))
            return
        except Exception as e:  # a transport's bug must not end the owner
            self._pending.append(Opened(t, wall_ns(), LinkLost(self.port, f"cannot open: {e!r}")))
            return
        fd = self.transport.fileno()
        if fd is not None:
            self._selector.register(fd, selectors.EVENT_READ, "board")
            self._transport_fd = fd
        self._pending.append(Opened(now(), wall_ns(), low_latency=low))

    def _close_board(self) -> None:
        if self._transport_fd is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(self._transport_fd)
            self._transport_fd = None
        self.transport.close()

    def _resolve(self, effect: Resolve) -> None:
        outcome = effect.outcome
        if outcome.result is Result.REFUSED:
            t = now()
            self._teller.put(
                lambda: self._teller.refusals.refused(
                    outcome.instruction, outcome.id, outcome.reason, t
                )
            )
        future = self._futures.pop(effect.ref, None)
        if future is not None:
            self._teller.put(lambda: _set(future, outcome))
        else:
            self._desk.outcome(effect.ref, outcome)
        if effect.tell:
            self._news.outcome(outcome)

    def _reply(self, ref: int, ok: bool) -> None:
        future = self._futures.pop(ref, None)
        if future is not None:
            self._teller.put(lambda: _set(future, ok))
        else:
            self._desk.reply(ref, ok)

    # -- the lane's requests (`al5d.owner.desk.Inbox`: the owner's thread only) -----------------

    def new_ref(self) -> int:
        return next(self._refs)

    def later(self, what: str, ref: int, payload: Any) -> None:
        self._others.append((what, ref, payload))

    def welcome(self, conn: Conn, recorder: bool) -> list[dict[str, Any]]:
        c = self._core
        welcome = {
            "op": "welcome",
            "version": ln.VERSION,
            "config": self.config.model_dump(mode="json"),
            "config_file": str(self.config_file) if self.config_file is not None else "",
            "port": self.port,
            "baud": self.baud,
            "pid": os.getpid(),
            "client": conn.ident,
            "signs": True,  # each sign of a leased client answered (`Remote.quiet`)
            "state": c.state.value,
            "locked": c.locked,
            "pose": c.book.pose,
            "motion": None if c.book.motion is None else ln.motion_out(c.book.motion),
            "t": now(),
            "wall": wall_ns(),
        }
        return [welcome, *self._news.welcomed(conn, recorder)]

    def told_kept(self) -> list[dict[str, Any]]:
        return self._news.told_kept()

    def _lapsed(self, t: float) -> None:
        """Each leased client not heard for its lease, the owner's own stalls since not
        counted, is lost (`Conns.lapsed`: what it commanded, and what the clients it speaks
        for did, is halted); the lapsed listeners are told its socket."""
        for sock in self._lanes.lapsed(t, self._stalled):
            self._news.lapsed(sock)

    # -- the end -------------------------------------------------------------------------------

    def _halt_as_it_fails(self) -> None:
        """The owner's last write, as it fails: ESC and a STOP on every channel, by this
        thread, still the board's one writer. Without it the board would run on what it was
        given (the end of a group move, a trajectory's point) with nobody to stop it."""
        if not self._core.link.open or self._broken:
            return
        data = p.CANCEL + p.encode_stop(sorted(self.arm.channels.values()))
        try:
            self.transport.write(data)
        except Exception:  # the port is the owner's failure, perhaps: nothing more to do
            log.exception("the STOP as the owner failed was not written")

    def _fail_all(self, why: str) -> None:
        for ref, future in list(self._futures.items()):
            if not future.done():
                self._teller.put(
                    lambda f=future: _set(f, Outcome("?", "?", Result.CANCELLED, why))  # type: ignore[misc]
                )
            del self._futures[ref]

    def _end(self) -> None:
        self.ending.set()
        writers = len(self.transport.writers)
        self._teller.put(
            lambda: log.info(
                "board: %d writes, by %d thread%s", self._writes, writers, "s"[: writers != 1]
            )
        )
        self._lanes.close()
        self._close_board()
        wake_fds, self._wake_r, self._wake_w = (self._wake_r, self._wake_w), -1, -1
        for fd in wake_fds:  # not written again (`_wake`): the number may be reused
            with contextlib.suppress(OSError):
                os.close(fd)
        self._teller.put(self.finished.set)
        self._teller.close()
        self.finished.set()


def _set(future: Future[Any], value: Any) -> None:
    if not future.done():
        future.set_result(value)
