"""The core against an emulated board in virtual time: no pty, no process, no thread, no sleep.

`Sim` plays the owner's part for tests: it hands the pure core (`al5d.arm.core.step`)
each input and carries its effects out against a `VirtualWire` (the board's logic on
a virtual wire), and moves time on from one wake to the next (the core's, or the
board's), so a test of a few seconds of the arm runs in milliseconds and the same
every time.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

from al5d.arm.config import ArmConfig
from al5d.arm.core import step, wake_at
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
from al5d.arm.instruction import Instruction, Outcome
from al5d.arm.states import State
from al5d.arm.validate import Ticket
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator.board import Board, Fault, Record
from al5d.ssc32u.emulator.usb import USB, LinkModel
from al5d.ssc32u.emulator.virtual import VirtualWire
from al5d.ssc32u.errors import LinkLost, PortUnavailable

#: Sending times (CLOCK_REALTIME ns) at the virtual time's start.
WALL0 = 1_700_000_000_000_000_000
#: Virtual time's start (s): a CLOCK_MONOTONIC of a machine up for a day.
T0 = 86_400.0


@dataclass
class Sim:
    """One arm's core on one emulated board, in virtual time."""

    config: ArmConfig
    baud: int = 115_200
    usb: LinkModel = USB
    board: Board = field(init=False)
    wire: VirtualWire = field(init=False)
    core: Core = field(init=False)
    #: Virtual time: a fixed start, so that an example replays to the same float roundings
    #: (from the real clock, a model-based test's failure did not fail again when replayed).
    t: float = T0
    outcomes: dict[int, Outcome] = field(default_factory=dict)
    told: list[Outcome] = field(default_factory=list)  # what the outcome listeners hear
    replies: dict[int, bool] = field(default_factory=dict)
    states: list[State] = field(default_factory=list)
    said: list[Say] = field(default_factory=list)
    moved: list[Moved] = field(default_factory=list)
    posed: list[Posed] = field(default_factory=list)  # what the clients that show the arm hear
    sent: list[tuple[float, bytes]] = field(default_factory=list)
    writers: set[int] = field(default_factory=set)
    ended: End | None = None
    steps: int = 0
    #: Called with every input and the effects it made (a model-based test's check).
    watch: Callable[[Input, tuple[Effect, ...]], None] | None = None
    #: How much of each second the host is short of cores, as the owner tells the core.
    stalling: float = 0.0
    #: How long the core's step of a request takes (its checks: a long trajectory's path
    #: against the table takes milliseconds): what it writes goes that much after the
    #: request's time, as the owner's writes do.
    ask_cost_s: float = 0.0

    def __post_init__(self) -> None:
        self.t0 = self.t
        self.board = Board(self.config, powered_at=self.t, baud=self.baud)
        self.wire = VirtualWire(self.board, self.usb)
        self.core = Core.start(Arm.of(self.config, "virtual", self.baud), self.t)
        self._refs = itertools.count(1)
        self._open = False
        self._made: list[Input] = []
        self._late = False  # time passed unseen (`stall`): the board is read first
        self.stalled_s = 0.0
        self.states.append(self.core.state)

    # -- the owner's part ------------------------------------------------------------------

    @property
    def wall(self) -> int:
        return WALL0 + round((self.t - self.t0) * 1e9)

    def put(self, ev: Input) -> None:
        """Hand the core one input and carry out what it says; then, as the owner does, the
        inputs its effects made (a port opened, a write that failed)."""
        if not isinstance(ev, Received | Failed):
            self.catch_up()
        self._made.append(ev)
        if len(self._made) > 1:
            return  # an effect's: taken once the effects before it are carried out
        while self._made:
            ev = self._made[0]
            self.core, effects = step(self.core, ev)
            self.steps += 1
            if isinstance(ev, Ask):
                self.t += self.ask_cost_s
            for effect in effects:
                self._carry(effect)
            if self.watch is not None:
                self.watch(ev, effects)
            self._made.pop(0)

    def _carry(self, effect: Effect) -> None:
        if isinstance(effect, Send):
            self.writers.add(threading.get_native_id())
            if not self._open or self.board.has_fault(Fault.DISCONNECT):
                self.put(Failed(self.t, self.wall, LinkLost("virtual", "write failed: unplugged")))
                return
            self.wire.write(effect.data, self.t)
            self.sent.append((self.t, effect.data))
        elif isinstance(effect, Open):
            if self.board.has_fault(Fault.DISCONNECT):
                error = PortUnavailable("virtual", "cannot open: unplugged")
                self.put(Opened(self.t, self.wall, error))
            else:
                self._open = True
                self.put(Opened(self.t, self.wall, low_latency=self.usb.low_latency))
        elif isinstance(effect, Close):
            self._open = False
        elif isinstance(effect, Resolve):
            assert effect.ref not in self.outcomes or effect.ref == 0, f"two outcomes for {effect}"
            self.outcomes[effect.ref] = effect.outcome
            if effect.tell:
                self.told.append(effect.outcome)
        elif isinstance(effect, Cancelled):
            for resolve in effect.resolves():
                self._carry(resolve)
        elif isinstance(effect, Reply):
            self.replies[effect.ref] = effect.ok
        elif isinstance(effect, Announce):
            if effect.new is not effect.old:
                self.states.append(effect.new)
        elif isinstance(effect, Moved):
            self.moved.append(effect)
        elif isinstance(effect, Posed):
            self.posed.append(effect)
        elif isinstance(effect, Say):
            self.said.append(effect)
        elif isinstance(effect, End):
            self.ended = effect

    # -- requests --------------------------------------------------------------------------

    def ask(
        self,
        instr: Instruction | Ticket,
        *,
        stream: str = "",
        key: object = None,
        client: int = 0,
        tell: bool = True,
        ref: int | None = None,
    ) -> int:
        """Submit an instruction now; its ref (its outcome comes in `outcomes[ref]`)."""
        ref = ref if ref is not None else self.next_ref()
        ticket = instr if isinstance(instr, Ticket) else None
        plain = instr.instr if isinstance(instr, Ticket) else instr
        self.put(Ask(self.t, self.wall, ref, plain, ticket, stream, key, client, tell))
        return ref

    def next_ref(self) -> int:
        return next(self._refs)

    def cancel(self, ident: str, reason: str = "cancelled by the client") -> int:
        ref = next(self._refs)
        self.put(Cancel(self.t, self.wall, ref, ident, reason))
        return ref

    def gone(self, client: int, why: str = "") -> None:
        self.put(Gone(self.t, self.wall, client, why))

    # -- time ----------------------------------------------------------------------------

    def next_wake(self) -> float:
        """The next time after now that the core or the board wants to be woken."""
        times = [wake_at(self.core)]
        due = self.wire.due() if self._open else None
        if due is not None:
            times.append(max(due, self.t + 1e-6))
        return min(times)

    def advance(self, until: float) -> None:
        """Let time pass until `until`: every wake of the core and the board on the way."""
        while not self.core.ended:
            wake = self.next_wake()
            if wake > until:
                break
            self.t = max(self.t, wake)  # due while nobody looked (`stall`): now
            self._wake()
        self.t = max(self.t, until)
        self._wake()

    def catch_up(self) -> None:
        """After a `stall`, what the board sent meanwhile is read, as the owner running again
        reads it before it takes what waited for it (a stop, a request)."""
        if self._late:
            self._late = False
            self._read()

    def _wake(self) -> None:
        self._late = False
        self._read()
        stalled = self.stalling * (self.t - self.t0) + self.stalled_s
        self.put(Tick(self.t, self.wall, stalled))

    def _read(self) -> None:
        """What the board has sent by now, read (or the port found unplugged)."""
        if self._open and not self.board.has_fault(Fault.DISCONNECT):
            data = self.wire.read(self.t)
            if data:
                self.put(Received(self.t, self.wall, data))
        elif self._open and self.core.link.open:
            self.put(Failed(self.t, self.wall, LinkLost("virtual", "read failed: unplugged")))

    def stall(self, seconds: float) -> None:
        """Time passes and nobody looks (the owner's thread was not running): what was due
        meanwhile is done late, as soon as time is let pass again (the owner's thread runs
        again). The board runs on meanwhile: what was on the wire reaches it, its answers
        wait for the owner to read them, which it does first when it runs again, and it
        counts the time among its stalls (`Tick.stalled`)."""
        self.t += seconds
        self.stalled_s += seconds
        self._late = True
        if self._open:
            self.wire.advance(self.t)

    def run(self, seconds: float) -> None:
        self.advance(self.t + seconds)

    def until(self, done: Callable[[], bool], limit_s: float = 60.0) -> bool:
        """Let time pass until `done()` (checked at every wake), at most `limit_s`."""
        end = self.t + limit_s
        while not done():
            if self.t >= end or self.core.ended:
                return done()
            self.t = min(max(self.t, self.next_wake()), end)
            self._wake()
        return True

    def ready(self, limit_s: float = 30.0) -> Sim:
        assert self.until(lambda: self.core.state is State.READY and self.core.idle, limit_s)
        return self

    def outcome(self, ref: int, limit_s: float = 60.0) -> Outcome:
        assert self.until(lambda: ref in self.outcomes, limit_s), f"no outcome for {ref}"
        return self.outcomes[ref]

    # -- what the board saw ------------------------------------------------------------------

    def degrees(self) -> dict[str, float]:
        """Where the emulated servos are now (virtual time)."""
        return self.board.servo_degrees(self.t)

    @property
    def records(self) -> list[Record]:
        return list(self.board.records)

    def lines(self) -> list[bytes]:
        return [r.raw for r in self.board.records]

    def group_moves(self) -> list[p.GroupMove]:
        return [c for r in self.board.records for c in r.commands if isinstance(c, p.GroupMove)]
