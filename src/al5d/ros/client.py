"""The client of the server: instructions sent, their outcomes waited for, the stop, release
and shutdown (the terminal's commands on it: `al5d.app.terminal`, `al5d.app.shell`).

A server on this machine is reached by its local lane (`al5d.owner.client.Remote`: no
discovery, no DDS); any other over ROS 2, its instruction topic (the stop and the
release too) and its shutdown service.

`Client` is a context manager:

    with Client() as arm:
        print(arm.execute("move base=30 time=800"))   # an Outcome
        print(arm.stop())                             # an Answer
"""

from __future__ import annotations

import atexit
import dataclasses
import difflib
import logging
import math
import numbers
import os
import sys
import threading
import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from al5d.arm.instruction import (
    PRESET_NAMES,
    Instruction,
    Kind,
    Outcome,
    new_id,
    parse_instruction,
)
from al5d.arm.states import State
from al5d.clock import Deadline
from al5d.owner import where
from al5d.owner.client import LaneClosed, LaneStalled, Remote, said_slow
from al5d.ros.answers import (
    ANSWER_S,
    FOR_EVER_S,
    Answer,
    LaneLost,
    LostContact,
    NoOutcome,
    NoServer,
    NotSent,
    elsewhere,
)
from al5d.ros.laneway import LaneWay, Way
from al5d.ros.names import Names
from al5d.ros.reading import ArmView, Reading, Tool

if TYPE_CHECKING:
    from al5d.arm.config import ArmConfig

log = logging.getLogger("al5d")

__all__ = [
    "ANSWER_S",
    "OUTCOME_S",
    "WAIT_S",
    "Answer",
    "Client",
    "LaneLost",
    "LostContact",
    "NoOutcome",
    "NoServer",
    "NotSent",
]

#: The defaults of `al5d send` and `al5d run`: finding the server, and an outcome.
WAIT_S = 10.0
OUTCOME_S = 120.0


def _instruction(instr: object) -> Instruction:
    """`instr` as an Instruction: one, or its text parsed (GrammarError); TypeError for
    anything else (an outside try's `execute(None)` raised AttributeError deep inside)."""
    if isinstance(instr, str):
        return parse_instruction(instr, PRESET_NAMES)
    if not isinstance(instr, Instruction):
        raise TypeError(
            f"an instruction or its text (as `al5d send` takes it), not {type(instr).__name__}"
        )
    return instr


def _seconds(name: str, value: object, *, zero: bool = True) -> float:
    """`value` as seconds to wait: a real number (numpy's too), not below 0 (nor 0 itself
    where not `zero`), `math.inf` for ever (`FOR_EVER_S`). ValueError or TypeError,
    naming `name`, before anything is sent (an outside try's `timeout=-1` sent the move
    and raised at once, the move running on; `nan` and `inf` raised from deep inside)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: seconds as a number, not {type(value).__name__}")
    seconds = float(value)
    if math.isnan(seconds) or seconds < 0 or (seconds == 0 and not zero):
        least = "0 or more" if zero else "more than 0"
        raise ValueError(f"{name}={value!r}: seconds to wait, {least} (math.inf: for ever)")
    return min(seconds, FOR_EVER_S)


def _stop_seconds(value: object) -> float:
    """A stop's timeout: as `_seconds`, but a stop is never refused for it: one that is
    none (0, -1, nan) waits the least a stop waits for its answer (`LaneWay.ask`)."""
    try:
        return _seconds("timeout", value)
    except (TypeError, ValueError):
        return 0.0


#: What a client closed with `halt` and no reason says made it leave.
HALT_WHY = "close(halt=True)"


def _left_halting(exc: object) -> bool:
    """Whether a client left with `exc` raised (a `with` block's, or the script's at exit)
    halts what it commanded: anything but a plain exit (SystemExit, a generator closed
    early: GeneratorExit) or none."""
    return isinstance(exc, BaseException) and not isinstance(exc, (SystemExit, GeneratorExit))


#: The exception that ended the script, if one did (`_note_uncaught`): the clients left
#: open then halt at exit. Not `sys.last_value`, which test runners set for each failure.
_uncaught: list[BaseException] = []
_excepthook = sys.excepthook


def _note_uncaught(kind: type[BaseException], exc: BaseException, tb: Any) -> None:
    _uncaught.append(exc)
    _excepthook(kind, exc, tb)


sys.excepthook = _note_uncaught


class Client:
    """A client of the server in `namespace` (none by default): on this machine by its local
    lane, else a ROS 2 node that publishes instructions and collects their outcomes by id;
    `wait_s`: how long its first use waits for the server. `local`: True, the local lane
    only; False, ROS 2 only; None, the lane where a server's is here.

    A context manager: leaving the `with` block closes it. Left as the block ends (or by
    `sys.exit`), what it sent goes on. Left by an exception (Ctrl-C's KeyboardInterrupt,
    an error of the script), what it commanded and is not over is halted, and its
    waiting moves are cancelled, as for a client killed (`close(halt=True)`). Neither
    stops (locks) the arm. A client left open is closed when the interpreter exits, the
    same way by how the script ended.
    """

    def __init__(
        self, namespace: str | None = None, *, wait_s: float = WAIT_S, local: bool | None = None
    ) -> None:
        self.names = names = Names.of(namespace)
        self.wait_s = wait_s = _seconds("wait_s", wait_s)
        self._closing = threading.Lock()
        self._closed = False
        self._view: ArmView | None = None
        self._way: Way
        lane: LaneWay | None = None
        if local is not False:
            path = where.path(names.namespace)

            def connect(timeout: float) -> Remote:
                return Remote.connect(
                    path,
                    name=f"al5d-client-{os.getpid()}",
                    watch=("state", "pose"),
                    lease=True,
                    timeout=timeout,
                    slow=said_slow(path, timeout),
                )

            try:
                lane = LaneWay(connect, names, wait_s)
            except LaneStalled as e:
                # A server is here: ROS 2 would reach it only through the same owner.
                raise NoServer(f"{e}; nothing sent") from None
            except LaneClosed as e:
                if local:
                    raise NoServer(
                        f"no al5d server on this machine's lane: {e}{elsewhere(names, None)}"
                    ) from None
                log.debug("%s: ROS 2 then", e)
        if lane is not None:
            self._way = lane
        else:
            # rclpy and the messages are imported where the ROS 2 way is taken: a client of
            # a local server (its lane) starts without them (about half a second less).
            from al5d.ros.rosway import RosWay

            self._way = self._ros = RosWay(names, wait_s)
        _open.add(self)

    def __enter__(self) -> Client:
        return self

    @property
    def lane(self) -> Remote | None:
        """The server's local lane, where this client takes it (else None: ROS 2)."""
        return self._way.lane if isinstance(self._way, LaneWay) else None

    def __exit__(self, kind: object, exc: object, tb: object) -> None:
        self.close(halt=_left_halting(exc), why=type(exc).__name__)

    @property
    def via(self) -> str:
        """The way to the server: the local lane (its path), or ROS 2."""
        return self._way.via

    @property
    def discovery_s(self) -> float:
        """Seconds spent waiting for the server (its topics or services) to be discovered."""
        return self._way.discovery_s

    # Over ROS 2, what the commands that publish on their own use (`al5d replay`,
    # `al5d calibrate`): the node, the instruction topic's writer, this client's lease.
    @property
    def node(self) -> Any:
        return self._ros.node

    @property
    def pub(self) -> Any:
        return self._ros.pub

    @property
    def key(self) -> str:
        return self._ros.key

    def lost_contact(self) -> float | None:
        """Over ROS 2, once the server has been heard: for how long it has not been, if more
        than the server's lease of this client and a margin (None: not lost; always None on
        the lane). A shorter silence is said once, as a WARNING, before that."""
        return self._way.lost_contact()

    def out_of_contact(self) -> str | None:
        """Why the server is out of contact (lost over ROS 2, its lane closed), whether or
        not anything waits for it; None while it is in contact."""
        return self._way.out_of_contact()

    @property
    def lost_after_s(self) -> float:
        """Over ROS 2, how long the server may go unheard before this client takes it for
        lost: its lease of this client and a margin (`al5d.ros.leasing.LOST_AFTER_LEASE_S`)."""
        return self._ros.lost_after_s

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this al5d client is closed")

    def wait_for_server(self, timeout: float) -> None:
        """Until our instructions reach a server and its results reach us: over ROS 2 a ping
        of ours answered (`NoServer` if none is within `timeout` s)."""
        self._check_open()
        self._way.wait_for_server(_seconds("timeout", timeout))

    def send(self, instr: Instruction | str, wait_s: float = 0.0) -> Instruction:
        """Send `instr` (or its text, in `al5d send`'s grammar) on the lane or the instruction
        topic, without waiting; its outcome is kept for `outcome`. The instruction sent (its
        `id` names the outcome). `wait_s`: how long its outcome will be waited for (0: for
        ever), from now: the server refuses it as stale if it comes later than that, and
        cancels it (halts it, if it runs) when that has passed without an outcome.
        Over ROS 2 the first use waits for the server, and on the lane a lane that closed
        waits for a server started again (`NoServer`, nothing sent, if none is there within
        the client's `wait_s`). Raises `GrammarError` for text that is not an instruction,
        `LostContact` while the server is out of contact, `NotSent` over ROS 2 while it
        has not acknowledged what this client sent before (as many as DDS keeps): nothing
        is sent then; TypeError for what is neither."""
        instr = self._fresh(_instruction(instr))
        wait_s = _seconds("wait_s", wait_s)
        self._check_open()
        self._way.send(instr, wait_s)
        return instr

    def _fresh(self, instr: Instruction) -> Instruction:
        """`instr` under a new id where this client has sent it already: each send is a
        request with its one outcome (an outside try's loop over the same instructions
        sent one id twice, and its two runs had one outcome between them)."""
        if self._way.sent(instr.id):
            return dataclasses.replace(instr, id=new_id())
        return instr

    def watch(self, ident: str, watcher: Callable[[Outcome], None]) -> None:
        """Call `watcher` with the outcome of `ident` as soon as it comes (at once if it has)."""
        self._way.watch(ident, watcher)

    def outcome(self, ident: str, timeout: float) -> Outcome | None:
        """The outcome of `ident`, sent by this client (and not forgotten): None if it does
        not come within `timeout` seconds, or at once where this client did not send it
        (Ctrl-C before the send was made). Raises `NoOutcome` where the lane closed first,
        `LostContact` where the server went out of contact; ValueError for a timeout that
        is none (`execute`)."""
        return self._way.outcome(ident, _seconds("timeout", timeout))

    def execute(self, instr: Instruction | str, timeout: float = OUTCOME_S) -> Outcome:
        """Send an instruction (or its text, in `al5d send`'s grammar) on the instruction topic
        and return its outcome: done, refused or cancelled.

        The server cancels it (halts it, if it runs) once `timeout` seconds have passed
        since it was sent: its outcome then is that cancel, which the client waits for up
        to `GIVE_UP_WORD_S` more.

        `timeout`: more than 0, `math.inf` for ever. An instruction this client has sent
        already goes under a new id (`send`).

        Raises `GrammarError` for text that is not an instruction, `NoServer` if no server
        is found within `wait_s` (on first use), `NoOutcome` if no outcome comes, not even
        the cancel (`LostContact`, `LaneLost`: the server went out of contact first);
        TypeError for what is neither an instruction nor its text, ValueError for a
        timeout that is none (nothing is sent).
        """
        instr = self._fresh(_instruction(instr))
        timeout = _seconds("timeout", timeout, zero=False)
        self._check_open()
        return self._way.execute(instr, timeout)

    # -- what the client hears of the arm ----------------------------------------------

    def _arm(self) -> ArmView:
        """The view of the arm, made on first use: over ROS 2, subscriptions to the server's
        state and joint states, its model that of the configuration it serves."""
        self._check_open()
        if self._view is None:
            self._view = self._way.view()
        return self._view

    def config(self) -> ArmConfig:
        """The configuration the server judges with (its joints, ranges, presets, table), for
        judging before sending: the lane's welcome holds it, and so does the server's
        latched `al5d/config` over ROS 2 (the parameters' values at its start included,
        wherever the server runs). Kept for the client's life. Waits for the server first
        if it has not been found (raises NoServer); a server that does not say it within
        10 s (an older one): the shipped file, with a warning. Raises ConfigError if what
        the server says is no configuration this version reads.
        """
        self._check_open()
        return self._way.config()

    def read(self, timeout: float | None = None) -> Reading:
        """The arm as last heard: its state, joints (degrees) and tool pose (`Reading`). The
        first read waits for the server's news up to `timeout` (default `wait_s`); raises
        NoServer if none came."""
        timeout = self.wait_s if timeout is None else _seconds("timeout", timeout)
        self._lane_back(timeout)
        reading = self._arm().wait(lambda r: bool(r.state and r.joints_told), timeout)
        if reading is None:
            raise self._way.no_server(self.names.joint_states, timeout)
        return self._arm().reading

    def state(self) -> str:
        """The arm's state word: `ready`, `moving`, `stopped`, `fault`, ... (`read`)."""
        return self.read().state

    def joints(self) -> dict[str, float]:
        """The joints' angles in degrees, as the grammar names them (`read`)."""
        return dict(self.read().joints)

    def tool(self) -> Tool:
        """Where the gripper's tip is, in `move_to`'s millimetres and degrees (`read`); raises
        NoOutcome while a joint's angle is not known (before the first move after power-up)."""
        tool = self.read().tool
        if tool is None:
            raise NoOutcome("the tool's pose is not known: an arm joint's angle is not known yet")
        return tool

    def wait_for_state(self, state: str | State, timeout: float = OUTCOME_S) -> Reading:
        """Until the arm's state is `state` (a word, as `state` says it, or a `State`); the
        reading then.
        Raises NoOutcome if it was not within `timeout` seconds, `LaneLost` where the lane
        closed meanwhile (the server ended: the arm's state is unknown), NoServer where it
        had closed and no server took it again within `wait_s`, as `read`; ValueError at
        once for a word that is no state (an outside try's "Moving" waited 120 s)."""
        state = state.value if isinstance(state, State) else state
        timeout = _seconds("timeout", timeout)
        known = [s.value for s in State]
        if state not in known:
            near = difflib.get_close_matches(state.lower(), known, n=1, cutoff=0.6)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise ValueError(
                f"{state!r} is not a state of the arm{hint} (one of {', '.join(known)})"
            )
        deadline = Deadline(timeout)
        self._lane_back(min(timeout, self.wait_s))
        while True:
            # In slices: a lane that closes tells the view nothing (an outside try: the
            # server killed, this waited its whole timeout and said the arm was 'moving').
            reading = self._arm().wait(lambda r: r.state == state, min(deadline.left(), 0.25))
            if reading is not None:
                return reading
            lane = self.lane
            if lane is not None and lane.closed.is_set():
                raise LaneLost(
                    f"the lane to the owner closed while the arm was waited for to be {state}: "
                    "its state is unknown"
                )
            if deadline.expired:
                raise NoOutcome(
                    f"the arm was not {state} within {timeout:g} s (it is {self.read(0).state!r})"
                )

    def _lane_back(self, timeout: float) -> None:
        """Over the lane, one that has closed (its server ended) opened again to a server
        started since: what was last heard on the old one is not the arm now (an outside
        try: the server killed mid-move, `state()` still said 'moving'). Raises NoServer
        where no server takes it within `timeout`."""
        way = self._way
        if isinstance(way, LaneWay) and way.lane.closed.is_set():
            try:
                way.reopen(timeout)
            except NoServer:
                raise NoServer(
                    "the lane to the server closed (the server ended) and no al5d server "
                    f"took it again within {timeout:g} s: the arm's state is unknown"
                ) from None

    def on_change(self, listener: Callable[[Reading], None]) -> None:
        """Call `listener` with each news of the arm (a `Reading`) on the client's own thread:
        over ROS 2 each joint state the server publishes, over the lane each state and each
        move the owner tells. Keep it short; it must not call the client back and wait."""
        self._arm().on_change(listener)

    def forget(self, ident: str) -> None:
        """The outcome of `ident` is not kept any more."""
        self._way.forget(ident)

    def sent(self, ident: str) -> bool:
        """Whether this client sent `ident` (and has not forgotten it)."""
        return self._way.sent(ident)

    def pending(self) -> list[str]:
        """The ids of what this client sent whose outcome has not come (over the lane)."""
        return self._way.pending()

    def cancel(self, ident: str, reason: str = "cancelled by the client") -> bool:
        """Cancel what this client sent; False when it has ended (or over ROS 2, which has no
        cancel by id: the stop is the way there)."""
        return self._way.cancel(ident, reason)

    def stop(self, timeout: float = ANSWER_S) -> Answer:
        """The emergency stop, by the local lane, or over ROS 2 on the instruction topic,
        sent again until it is answered (`al5d.ros.rosstop.StopCall`): the arm halts and
        stays locked (refusing moves) until a release. Raises `NoServer` where the stop
        reached nobody within `wait_s`, `NoOutcome` where it was sent (a reader of the
        topic took it) but not answered: whether the arm stopped is unknown."""
        self._check_open()
        return self._way.ask(Kind.STOP, _stop_seconds(timeout))

    def release(self, timeout: float = ANSWER_S) -> Answer:
        """Unlock the arm after a stop: over ROS 2 on the instruction topic, with this
        client's lease (`al5d.ros.rosway.RosWay._release`); on the local lane, by it."""
        self._check_open()
        return self._way.ask(Kind.RELEASE, _seconds("timeout", timeout))

    def shutdown(self, timeout: float = ANSWER_S) -> Answer:
        """Park the arm and end the server, by its shutdown service (answered before the
        parking is done)."""
        self._check_open()
        return self._way.ask(Kind.SHUTDOWN, _seconds("timeout", timeout))

    def close(self, halt: bool = False, why: str = HALT_WHY) -> None:
        """End the client's lane, or its node and ROS context; again, or at exit, it does
        nothing. With `halt`, what this client commanded and is not over is halted, and
        its waiting moves are cancelled (`why` says why, in a WARNING, and over ROS 2 to
        the server too): the server takes it for lost at once (over ROS 2, were that word
        lost, once its lease, `server.client_lease_s`, has run out)."""
        with self._closing:
            if self._closed:
                return
            self._closed = True
            _open.discard(self)
            if halt:
                log.warning(
                    "al5d client left by %s: what it commanded and is not over is halted "
                    "(the server takes it for lost)",
                    why,
                )
            self._way.close((why or HALT_WHY) if halt else "")


#: Every client not yet closed, closed at interpreter exit (`_close_open_clients`).
_open: weakref.WeakSet[Client] = weakref.WeakSet()


@atexit.register
def _close_open_clients() -> None:
    """Close what a script left open. rclpy's executor thread and context still alive when
    the interpreter finalizes abort the process ("terminate called without an active
    exception", exit 134) and hide the script's own exit code and traceback."""
    # Not in an interactive session, whose prompt says each error and goes on.
    exc = _uncaught[-1] if _uncaught and not hasattr(sys, "ps1") else None
    for client in list(_open):
        client.close(halt=_left_halting(exc), why=type(exc).__name__)
