"""A client of the owner over the local lane: `Remote`, with the owner's own API.

The ROS bridges, the command line, the web view and the Python client reach a server
on this machine through it: a request is a line on the lane's socket, its one outcome
comes back under its ref, and what the client watches (the state, every outcome, the
motion, the pose, the board's bytes) comes as it happens, read by a thread of its own.
The arm's configuration is the server's, as its `welcome` says.

    with Remote.connect(lane.path()) as arm:
        print(arm.execute(move(base=30, time_ms=800)))
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import itertools
import logging
import math
import socket
import termios
import threading
import time
from collections.abc import Callable, Hashable, Iterable
from concurrent.futures import Future, InvalidStateError
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import Any

from al5d.arm.config import DEFAULT_CONFIG, ArmConfig, parse_config
from al5d.arm.instruction import Instruction, Kind, Outcome
from al5d.arm.jobs import Motion, Sent
from al5d.arm.resample import Follow
from al5d.arm.states import State
from al5d.clock import now
from al5d.owner import lane as ln
from al5d.owner import quick
from al5d.owner.teller import StateTold, tell
from al5d.priority import make_urgent

log = logging.getLogger("al5d")

#: How long a client waits for the owner's welcome.
WELCOME_S = 10.0
#: A lane whose owner has left a full queue of connections untaken is tried this often.
CONNECT_AGAIN_S = 0.05


#: A leased client signs this many times in the owner's lease of it: a busy host may hold
#: one or two back; and at least every `SIGN_EVERY_MAX_S`, as the owner answers each: a
#: client hears a turning owner within that however long its lease (`Remote.quiet`).
SIGNS_PER_LEASE = 4
SIGN_EVERY_MAX_S = 0.25
#: A silence of the owner's this long is kept (`Remote.silence`): shorter than any a client
#: says (1 s), longer than a turning owner takes to answer a sign, so that the answers to
#: the signs sent after it do not take its place.
SILENCE_KEPT_S = 0.5


class LaneClosed(ConnectionError):
    """The owner is not there (any more): its lane is closed."""


class LaneStalled(LaneClosed):
    """The owner took the connection but did not answer its hello in time: a server on this
    machine that is busy or stalled (a frozen process), not one that is absent."""


@dataclass(frozen=True, slots=True)
class Judged:
    """An instruction the owner has judged and keeps, to submit as it is (once)."""

    instr: Instruction
    name: str
    #: A trajectory's points that go to the board, by index (a dense one is thinned).
    knots: list[int]


class Remote:
    """The owner, over its lane (a connected socket): submit, cancel, judge, and what it tells."""

    def __init__(
        self,
        sock: socket.socket,
        *,
        name: str = "al5d-client",
        watch: Iterable[str] = ("state", "pose"),
        timeout: float = WELCOME_S,
        on_wire: Callable[[tuple[bytes, float, float]], None] | None = None,
        recorder: bool = False,
        lease: bool = False,
        ros: bool = False,
        slow: Callable[[], None] | None = None,
        asked: float | None = None,
    ) -> None:
        """Say hello on `sock` and wait for the welcome until `timeout` s after `asked` (when
        the connection was asked for, monotonic s; None: now); `slow` is called once, on
        this thread, where it has not come within `quick.UNANSWERED_S` of then (the wait
        goes on). Raises LaneStalled where it does not come, LaneClosed where the lane
        closes first."""
        asked = time.monotonic() if asked is None else asked
        self._sock = sock
        sock.setblocking(True)
        self._send_lock = threading.Lock()
        self._refs = itertools.count(1)
        self._futures: dict[int, Future[Any]] = {}
        self.outcome_listeners: list[Callable[[Outcome], None]] = []
        self.state_listeners: list[Callable[[State], None]] = []
        self.motion_listeners: list[Callable[[Sent], None]] = []
        self.pose_listeners: list[Callable[[], None]] = []
        #: Each instruction another client of the lane asked, and when (wall clock, ns).
        self.asked_listeners: list[Callable[[tuple[Instruction, int]], None]] = []
        #: `on_wire` among them from the start: the owner tells a `recorder` the writes it
        #: kept for it right after the welcome (`Owner`'s keep_wire).
        self.wire_listeners: list[Callable[[tuple[bytes, float, float]], None]] = (
            [on_wire] if on_wire is not None else []
        )
        #: Set once when the lane closes (the owner has ended, or the socket failed).
        self.closed = threading.Event()
        #: When the first of this client's signs that the owner has not answered since it
        #: was last heard went (monotonic; None: none such). The owner's thread answers
        #: each, where its welcome says so (`_signs`: an older version answers none), so a
        #: silence counted from there is the owner's, not this process's own stall
        #: (`quiet`: a process stopped and resumed sends its next sign first).
        self.unanswered: float | None = None
        #: The last silence of the owner's longer than `SILENCE_KEPT_S` that a sign found:
        #: when that sign went and when the owner next said something (monotonic).
        self.silence: tuple[float, float] | None = None
        self._signs = False
        #: Why the owner took this client for lost, where it said so before it closed the
        #: lane (a client stopped and resumed: not a server that ended).
        self.lost_why = ""
        self._welcome: Future[dict[str, Any]] = Future()
        self._pose: dict[str, float | None] = {}
        self._motion: Motion | None = None
        self._running: tuple[str, int, int] | None = None
        self._state = StateTold(State.INITIALIZING)
        self.locked = False
        self._reader = threading.Thread(target=self._read, name=f"{name}-lane", daemon=True)
        self._signer: threading.Thread | None = None  # the lease's signs, if any
        self._reader.start()
        hello = {"op": "hello", "name": name, "watch": list(watch), "version": ln.VERSION}
        if recorder:  # told first the board's writes the owner kept for its recorder
            hello["recorder"] = True
        if lease:  # a process that hangs with its lane open is lost all the same
            hello["lease"] = True
        if ros:  # what it asks came over ROS 2, where a recording has it already
            hello["ros"] = True
        try:
            self._send(hello)
            if slow is not None and timeout > quick.UNANSWERED_S:
                with contextlib.suppress(FutureTimeout):
                    self._welcome.result(max(asked + quick.UNANSWERED_S - time.monotonic(), 0))
                if not self._welcome.done():
                    slow()
            welcome = self._welcome.result(max(asked + timeout - time.monotonic(), 0))
            self.config: ArmConfig = parse_config(welcome["config"], "the server's configuration")
        except FutureTimeout:  # the built-in TimeoutError from Python 3.11 on only
            self.close()
            raise LaneStalled(f"the owner did not answer hello within {timeout:g} s") from None
        except BaseException:  # Ctrl-C, a welcome this version cannot read: nothing left open
            self.close(bye=False)
            raise
        self.settings = self.config.server
        #: The file the server read its configuration from (the shipped one if it said none).
        self.config_file: Path = (
            Path(welcome["config_file"]) if welcome.get("config_file") else DEFAULT_CONFIG
        )
        self.port: str = welcome["port"]
        self.baud: int = welcome["baud"]
        self.client: int = welcome["client"]
        self.pid: int = welcome["pid"]
        self._signs = lease and welcome.get("signs") is True
        if lease:
            every = min(self.settings.client_lease_s / SIGNS_PER_LEASE, SIGN_EVERY_MAX_S)
            self._signer = threading.Thread(
                target=self._sign, args=(every,), name=f"{name}-lease", daemon=True
            )
            self._signer.start()

    def _sign(self, every: float) -> None:
        """A sign to the owner every `every` s while the lane is open: the lease the hello
        asked for (the owner takes a client silent for `server.client_lease_s` for lost), at
        the stop path's priority: a flood's threads in this process must not hold it back."""
        # Quietly where the OS refuses it (a user's command is not to warn of it each time).
        make_urgent("the lane's signs", quiet=True)
        while not self.closed.wait(every):
            if self.unanswered is None:
                self.unanswered = time.monotonic()
            try:
                self._send({"op": "sign"})
            except LaneClosed:
                return

    def quiet(self) -> float | None:
        """For how long the owner has left a sign of this client's unanswered (s), what it
        has sent and this client's reader has not yet read counting as an answer (a
        reader held back is not a silent owner); None where this client is not leased
        (an idle owner says nothing to it), its owner answers no signs (an older
        version), or the lane has closed."""
        if not self._signs or self.closed.is_set():
            return None
        asked = self.unanswered
        if asked is None:
            return 0.0
        unread = array.array("i", [0])
        with contextlib.suppress(OSError):  # closed meanwhile: said by `closed` next time
            fcntl.ioctl(self._sock.fileno(), termios.FIONREAD, unread)
        if unread[0] > 0:
            return 0.0
        return max(time.monotonic() - asked, 0.0)

    @classmethod
    def connect(cls, path: Path, **kwargs: Any) -> Remote:
        """The owner on the lane at `path`, its welcome within `timeout` s (`WELCOME_S`),
        the other keywords as `Remote` takes them. Raises LaneClosed where none is there,
        LaneStalled where one is there but takes no connection or does not welcome it in
        time (busy or stalled: a frozen process)."""
        timeout: float = kwargs.pop("timeout", WELCOME_S)
        slow: Callable[[], None] | None = kwargs.pop("slow", None)
        asked = time.monotonic()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        # Not blocking: with the owner's queue of untaken connections full, a blocking
        # connect would wait, without a word, until the owner turns again.
        sock.setblocking(False)
        try:
            while True:
                try:
                    sock.connect(str(path))
                    break
                except BlockingIOError:  # its queue of connections untaken is full
                    waited = time.monotonic() - asked
                    if waited > timeout:
                        raise LaneStalled(
                            f"the al5d server on this machine's lane ({path}) has taken no "
                            f"connection in {timeout:g} s (too many wait for it): it is "
                            "busy or stalled (a frozen process?)"
                        ) from None
                    if slow is not None and waited > quick.UNANSWERED_S:
                        slow()
                        slow = None  # said once
                    time.sleep(CONNECT_AGAIN_S)
        except OSError as e:
            sock.close()
            if isinstance(e, LaneStalled):
                raise
            raise LaneClosed(f"no al5d server on {path}: {e.strerror or e}") from None
        try:
            return cls(sock, **kwargs, timeout=timeout, slow=slow, asked=asked)
        except LaneStalled as e:
            raise LaneStalled(
                f"the al5d server on this machine's lane ({path}) took the connection but {e}: "
                "it is busy or stalled (a frozen process?)"
            ) from None

    def __enter__(self) -> Remote:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- requests ----------------------------------------------------------------------------

    def _send(self, message: dict[str, Any]) -> None:
        line = ln.dumps(message)
        try:
            with self._send_lock:
                self._sock.sendall(line)
        except OSError as e:
            raise LaneClosed(f"the lane to the owner is closed: {e.strerror or e}") from None

    def _request(self, message: dict[str, Any]) -> Future[Any]:
        future: Future[Any] = Future()
        ref = next(self._refs)
        self._futures[ref] = future
        # After the future is in: `_lost` sets `closed` before it fails the futures it finds,
        # so a lane that closed as this one went in is seen here, not missed by both.
        if self.closed.is_set():
            self._futures.pop(ref, None)
            _fail(future, LaneClosed("the lane to the owner is closed"))
            return future
        try:
            self._send({**message, "ref": ref})
        except LaneClosed as e:
            self._futures.pop(ref, None)
            _fail(future, e)
        return future

    def submit(
        self,
        what: Instruction | Judged,
        *,
        key: Hashable | None = None,
        stream: str = "",
        listeners: bool = True,
        client: str = "",
    ) -> Future[Outcome]:
        """Hand over an instruction (or one judged already); its Future resolves to its one
        outcome, or raises LaneClosed if the lane closes first. `client`: the key of a client
        this one speaks for (`gone`), if it is that one's."""
        message: dict[str, Any] = {"op": "ask", "stream": stream, "tell": listeners}
        if client:
            message["for"] = client
        if isinstance(what, Judged):
            message["ticket"] = what.name
        else:
            if what.sent_ns is None:  # sent now (the owner's clock is this machine's)
                what = replace(what, sent_ns=time.time_ns())
            message["instr"] = ln.instruction_out(what)
        if key is not None:
            message["key"] = key
        return self._request(message)

    def execute(self, instr: Instruction, timeout: float | None = None) -> Outcome:
        return self.submit(instr).result(timeout)

    def gone(self, client: str, why: str) -> None:
        """Client `client`, whom this one speaks for, is lost (`why`: what it commanded is
        halted), or has closed (`why` empty: what it commanded goes on)."""
        self._send({"op": "gone", "for": client, "why": why})

    def cancel(self, ident: str, reason: str = "cancelled by the client") -> bool:
        """Cancel one move; False when it has already ended (or was never there)."""
        ok: bool = self._request({"op": "cancel", "id": ident, "reason": reason}).result(30.0)
        return ok

    def judge(self, instr: Instruction, follow: Follow | None = None) -> Judged | str:
        """The owner's judgement of a motion instruction: kept there to submit as it is, or
        the reason to refuse it whole."""
        message = {
            "op": "judge",
            "instr": ln.instruction_out(instr),
            "follow": ln.follow_out(follow),
        }
        answer: dict[str, Any] = self._request(message).result(30.0)
        if "ticket" in answer:
            knots = [int(k) for k in answer.get("knots", ())]
            return Judged(instr, str(answer["ticket"]), knots)
        return str(answer.get("reason", "refused"))

    def drop(self, judged: Judged) -> None:
        """Let go of a ticket of `judge` that will not be asked with (its goal ended before
        it ran), so that the owner does not keep it. Raises LaneClosed: the owner has
        ended (and keeps nothing)."""
        self._send({"op": "drop", "ticket": judged.name})

    def kept_outcomes(self, timeout: float = 30.0) -> None:
        """The outcomes the owner told while no ROS bridge heard them (the last one ended),
        told now to this client's outcome listeners, before this returns. Raises
        LaneClosed: the owner has ended; TimeoutError: no answer in `timeout`."""
        self._request({"op": "kept"}).result(timeout)

    def ping(self, timeout: float = 5.0) -> float:
        """The owner's clock (CLOCK_MONOTONIC) when it answered."""
        answer: dict[str, Any] = self._request({"op": "ping"}).result(timeout)
        return float(answer["t"])

    # -- what the owner tells ----------------------------------------------------------------

    def positions(self, t: float | None = None) -> dict[str, float]:
        """Estimated joint angles (degrees; NaN where unknown since power-up), as the owner
        told them last: kept up to date where "pose" is among what this client watches."""
        pose, motion = self._pose, self._motion
        est = motion.at(now() if t is None else t) if motion is not None else {}
        return {j: est.get(j, v if v is not None else math.nan) for j, v in pose.items()}

    def progress(self, ident: str) -> float | None:
        running, motion = self._running, self._motion
        if running is None or motion is None or running[0] != ident or not running[2]:
            return None
        return (running[1] + motion.progress(now())) / running[2]

    @property
    def state(self) -> State:
        """The arm's state, as the owner last told it."""
        return self._state.state

    def wait_for_state(self, state: State, timeout: float = 10.0) -> None:
        """Until `state` is the state told, or has been told since the call though left
        again (`StateTold`). Raises TimeoutError."""
        if not self._state.wait(state, timeout):
            raise TimeoutError(f"state {state.value} not reached in {timeout} s")

    def _read(self) -> None:
        lines = ln.Lines()
        try:
            while True:
                data = self._sock.recv(65536)
                if not data:
                    break
                t, unanswered = time.monotonic(), self.unanswered
                if unanswered is not None and t - unanswered > SILENCE_KEPT_S:
                    self.silence = (unanswered, t)
                self.unanswered = None  # the owner said something: it turns
                for message in lines.feed(data):
                    if isinstance(message, ln.LaneError):
                        raise message
                    self._dispatch(message)
        except (OSError, ln.LaneError) as e:
            log.debug("the lane to the owner failed: %s", e)
        finally:
            self._lost()

    def _dispatch(self, m: dict[str, Any]) -> None:
        op = m["op"]
        if op == "outcome":
            self._settle(m.get("ref"), ln.outcome_in(m["outcome"]))
        elif op in ("reply",):
            self._settle(m.get("ref"), bool(m.get("ok")))
        elif op == "lost":  # the owner took this client for lost: it closes the lane next
            self.lost_why = str(m.get("why", ""))[:200]
        elif op in ("judged", "pong"):
            self._settle(m.get("ref"), m)
        elif op == "told":
            tell(self.outcome_listeners, ln.outcome_in(m["outcome"]), "outcome")
        elif op == "state":
            self._new_state(State(m["state"]), bool(m.get("locked")))
        elif op == "posed":
            self._posed(m)
        elif op == "moved":
            self._moved(m)
        elif op == "wire":
            data = str(m["data"]).encode("latin-1")
            tell(self.wire_listeners, (data, float(m["t"]), float(m.get("free_at", 0))), "wire")
        elif op == "asked":
            asked = (ln.instruction_in(m["instr"]), int(m["wall"]))
            tell(self.asked_listeners, asked, "asked")
        elif op == "welcome":
            self._posed(m)
            self._new_state(State(m["state"]), bool(m.get("locked")))
            self._welcome.set_result(m)
        elif op == "error":
            future = self._futures.pop(m["ref"], None) if m.get("ref") is not None else None
            error = ln.LaneError(str(m.get("error")))
            if future is not None:
                _fail(future, error)
            else:
                log.warning("the owner says: %s", error)

    def _settle(self, ref: Any, value: Any) -> None:
        future = self._futures.pop(ref, None) if isinstance(ref, int) else None
        if future is not None and not future.done():
            future.set_result(value)

    def _new_state(self, state: State, locked: bool) -> None:
        self.locked = locked
        self._state.told(state)
        tell(self.state_listeners, state, "state")

    def _posed(self, m: dict[str, Any]) -> None:
        pose = m.get("pose") or {}
        self._pose = {str(k): (None if v is None else float(v)) for k, v in pose.items()}
        motion = m.get("motion")
        self._motion = None if motion is None else ln.motion_in(motion)
        running = m.get("running")
        self._running = (
            None if running is None else (str(running[0]), int(running[1]), int(running[2]))
        )
        _call(self.pose_listeners, "pose")

    def _moved(self, m: dict[str, Any]) -> None:
        instr = Instruction(Kind.MOVE, id=str(m["id"]))
        sent = Sent(
            instr,
            str(m["data"]).encode("latin-1"),
            float(m["t_submit"]),
            float(m["t_write"]),
            ln.motion_in(m["motion"]),
            int(m["step"]),
            int(m["steps"]),
        )
        tell(self.motion_listeners, sent, "motion")

    def _lost(self) -> None:
        if self.closed.is_set():
            return
        self.closed.set()
        closed = (
            f"the server took this client for lost ({self.lost_why}) and closed its lane: it "
            "halts what this client commanded"
            if self.lost_why
            else "the lane to the owner closed"
        )
        for ref, future in list(self._futures.items()):
            _fail(future, LaneClosed(closed))
            self._futures.pop(ref, None)
        if not self._welcome.done():
            self._welcome.set_exception(LaneClosed("the owner closed the lane"))

    def close(self, bye: bool = True, left_by: str = "") -> None:
        """Leave the lane; with `bye`, what this client commanded goes on (without, the owner
        takes it for a lost client); `left_by`: it leaves by that error, which the owner
        says as it halts what this client commanded."""
        if (bye or left_by) and not self.closed.is_set():
            with contextlib.suppress(LaneClosed):
                self._send({"op": "bye", "left_by": left_by} if left_by else {"op": "bye"})
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        if self._reader is not threading.current_thread():
            self._reader.join(5)
        self._lost()
        # Ended when close returns (an outside try found it alive after close, 3 in 20).
        if self._signer is not None and self._signer is not threading.current_thread():
            self._signer.join(5)


def _fail(future: Future[Any], error: Exception) -> None:
    """Fail `future` unless it is done: the lane's reader and a requester may both try."""
    with contextlib.suppress(InvalidStateError):
        future.set_exception(error)


def _call(listeners: list[Callable[[], None]], what: str) -> None:
    """Call each listener; one that raises is logged and the rest still hear."""
    for listener in list(listeners):
        try:
            listener()
        except Exception:
            log.exception("%s listener %r failed", what, listener)


def said_slow(path: Path, timeout: float) -> Callable[[], None]:
    """What a client says where the owner on the lane at `path` has not welcomed it within
    `quick.UNANSWERED_S` of its `timeout` s (`Remote`'s `slow`): a WARNING."""

    def slow() -> None:
        log.warning(
            "the al5d server on this machine's lane (%s) has not answered in %g s (busy or "
            "stalled); waiting up to %.1f s more",
            path,
            quick.UNANSWERED_S,
            timeout - quick.UNANSWERED_S,
        )

    return slow


def local_config(path: Path, timeout: float = WELCOME_S) -> ArmConfig | None:
    """The configuration the server on the lane at `path` judges with (its `welcome`'s), for
    a client that judges before it has found a server its own way; None where none is
    there. After `quick.UNANSWERED_S` without a welcome it says so (`said_slow`). Raises
    LaneStalled where one took the connection but did not answer within `timeout` s."""
    try:
        with Remote.connect(
            path, name="al5d-config", watch=(), timeout=timeout, slow=said_slow(path, timeout)
        ) as lane:
            return lane.config
    except LaneStalled:
        raise
    except LaneClosed:
        return None
