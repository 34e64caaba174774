"""The arm's core against a model, driven directly: random sequences and interleavings of
requests, board faults and time, in virtual time (`al5d_rig.sim`), checked after every
input the core takes.

`hypothesis.stateful` plays clients on the pure core (`al5d.arm.core.step`) with an
emulated board on a virtual wire: moves, moves whose sender waits only so long,
set-points of a stream (bursts, a stream that goes quiet, one that goes on through a
stop), trajectories (some to start later: `Instruction.start_ns`), Cartesian lines,
stops (some seen twice, as the bridge's node and the stop watcher both see a stop on the
topic, each reader's time for it a few ms apart), stops that come after a release sent
after them (held up behind a flood, or by a link that was down), releases (some sent
before the last stop and arriving after it), cancels, lost clients, a board pulled and
plugged back, a silent board, a reset, time passing (some of it with the owner's thread
not running: a frozen or starved owner) and a shutdown; several of them at one instant,
in any order. After every input:

- the state and the outcomes agree: `ready`, `stopped`, `fault` and `shutting_down` only
  while no motion request is without its outcome, `moving` only while one is;
- every request has at most one outcome, a stop and a release theirs at once;
- a move whose sender waits for it only so long (`Instruction.wait_ms`) has its outcome
  by then (`GIVE_UP_SLACK_S`, and the time the owner did not run), and is never given up
  on before;
- no move the board had run to its end is reported cut short (cancelled), and none is
  reported done before the board has it where it was sent;
- no line on the wire holds a partial number (a line cut by a stop's ESC holds whole
  commands only), and one thread wrote every byte;
- no trajectory's first line is written before its start;

and at the end of each example:

- no move went to the board after a stop's STOP and before a release was done;
- a stop that comes after a release sent after it is obeyed, and locks the arm all the
  same (the times of two senders differ: a stop is never taken for older and left
  unlocked);
- a release sent before the stop that holds the lock was refused;
- every request has its outcome within a bound of virtual time, and a probe move after
  a stop and a release is done.

`make test` runs a bounded number of examples; `make soak` (AL5D_FUZZ_SCALE=10) more.
The same rules run on the whole server, on a real pty, in `test_arm_model.py`.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import random
import time
from collections.abc import Callable

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig, load_config
from al5d.arm.corestate import Ask, Cancelled, Effect, Input, Moved, Resolve, Send
from al5d.arm.instruction import Instruction, Kind, Point, Result
from al5d.arm.running import OVER_BY_S
from al5d.arm.states import State
from al5d.model.table import PATH_TOLERANCE_M, below
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator.board import Fault
from al5d_rig.fuzzcount import SCALE, count
from al5d_rig.sim import Sim

JOINTS = ("base", "shoulder", "elbow", "wrist")
STREAM = "joint_commands"
#: The stream's watchdog here (`server.stream_timeout_s`): short, to be met in an example.
STREAM_TIMEOUT_S = 0.15
#: Set-points of the stream pending at most: one running (or about to be written in its
#: place) and one waiting behind other moves. A stream never queues.
STREAM_PENDING_MAX = 2
#: Virtual time every outcome comes within, once nothing more is asked.
OUTCOME_BOUND_S = 60.0
#: A move whose sender has given up on it has its outcome this soon after (virtual s): a
#: query's answer, or a line going out, may be waited for first.
GIVE_UP_SLACK_S = 0.1
#: How much earlier than the core's `OVER_BY_S` the board must have finished a move for it
#: to count as run to its end here: the core knows a line's arrival to its wire time and
#: the USB link's.
FINISHED_SLACK_S = 0.01
MOTION = (Kind.MOVE, Kind.PRESET, Kind.MOVE_TO, Kind.TRAJECTORY)
#: States in which no motion request may wait for its outcome.
AT_REST = (State.READY, State.STOPPED, State.FAULT, State.SHUTTING_DOWN)
KEYS = itertools.count()
STEPS = {"inputs": 0, "seconds": 0.0}


def _config() -> ArmConfig:
    config = load_config()
    server = config.server.model_copy(
        update={"reconnect_interval_s": 0.05, "stream_timeout_s": STREAM_TIMEOUT_S}
    )
    return config.model_copy(update={"server": server})


CONFIG = _config()


@dataclasses.dataclass
class Asked:
    ref: int
    kind: str
    instr: Instruction
    t: float
    wall: int
    late: bool = False
    client: int = 0


def _gives_up(asked: Asked) -> float:
    """When the sender of `asked` gives up on it (inf: it waits for ever)."""
    wait_ms = asked.instr.wait_ms
    return asked.t + wait_ms / 1000 if wait_ms else math.inf


class CoreProtocol(RuleBasedStateMachine):
    """The rules clients play on the core, and the model's checks."""

    def __init__(self) -> None:
        super().__init__()
        count("arm core: sequences against the model")
        self.asked: list[Asked] = []
        self.by_ref: dict[int, Asked] = {}
        self.problems: list[str] = []
        self.stop_sends: list[float] = []  # when each stop's STOP burst was written
        self.released: list[float] = []  # when each release was done
        self.stalls: list[tuple[float, float]] = []  # when the owner's thread did not run
        self.reset_seen = False  # the board has reset in this example
        self.starts: dict[str, float] = {}  # a trajectory's start, by id (the sim's clock)
        self.sim = Sim(CONFIG, baud=random.choice((9600, 115_200)))
        self.sim.watch = self._after_input
        self.sim.ready()
        self.ready = dict(CONFIG.presets["ready"])
        self.pulled = False
        self.ended = False
        self.keyed: list[tuple[str, int]] = []  # the keys of the stops obeyed under one
        self.lock_holder: Asked | None = None  # the stop that holds the lock, if one does
        self.n_records = len(self.sim.records)
        self.started = time.perf_counter()

    # -- the checks after every input ---------------------------------------------------

    def _after_input(self, ev: Input, effects: tuple[Effect, ...]) -> None:
        STEPS["inputs"] += 1
        if isinstance(ev, Ask) and ev.instr.kind in (Kind.STOP, Kind.RELEASE):
            resolved = {e.ref for e in effects if isinstance(e, Resolve)}
            if ev.ref not in resolved:
                self.problems.append(f"{ev.instr.kind.value} {ev.instr.id} not answered at once")
        stop = isinstance(ev, Ask) and ev.instr.kind is Kind.STOP
        for e in effects:
            if stop and isinstance(e, Send) and e.data.startswith(p.CANCEL + b"STOP"):
                self.stop_sends.append(self.sim.t)
            if isinstance(e, Moved) and e.sent.step == 0:
                start = self.starts.get(e.sent.instr.id, -math.inf)
                if e.sent.t_write < start - 1e-9:
                    early = (start - e.sent.t_write) * 1000
                    self.problems.append(f"{e.sent.instr.id} written {early:.1f} ms early")
        for e in _resolves(effects):
            asked = self.by_ref.get(e.ref)
            if asked is None:
                continue
            if asked.kind == "release" and e.outcome.ok:
                self.released.append(self.sim.t)
                self.lock_holder = None
            if "given up" in e.outcome.reason:
                count("arm core: moves given up on by their senders")
                if self.sim.t < _gives_up(asked) - 1e-9:
                    self.problems.append(f"{asked.instr.id} given up on before its time")
            if self._late(asked) > GIVE_UP_SLACK_S:
                late = self.sim.t - _gives_up(asked)
                self.problems.append(f"{e.outcome} {late:.3f} s after its sender gave up")
            if e.outcome.result is Result.CANCELLED:
                self._not_finished(asked, e.outcome.reason)
            elif e.outcome.ok and self._judged(asked) and not self._at(asked.instr, self.sim.t):
                self.problems.append(f"{asked.instr.id} done, its joints not yet there")
        state = self.sim.core.state
        pending = self._pending_motion()
        if state in AT_REST and pending:
            ids = ", ".join(a.instr.id for a in pending[:4])
            self.problems.append(f"state {state.value} while {len(pending)} move(s) wait: {ids}")
        if state is State.MOVING and not pending and self.sim.core.run is None:
            self.problems.append("state moving with no move running or waiting")
        overdue = [a for a in pending if self._late(a) > GIVE_UP_SLACK_S]
        if overdue:
            self.problems.append(f"{overdue[0].instr.id} goes on, given up on by its sender")

    def _late(self, asked: Asked) -> float:
        """How long after its sender gave up on `asked` it is now, but for the time the
        owner's thread did not run meanwhile (nothing can be done then)."""
        since = _gives_up(asked)
        stalled = sum(max(0.0, min(b, self.sim.t) - max(a, since)) for a, b in self.stalls)
        return self.sim.t - since - stalled

    def _not_finished(self, asked: Asked, reason: str) -> None:
        """A move reported cancelled had not been run to its end by the board: its line
        written, its joints were not all where it sent them with the board at rest since
        `OVER_BY_S` before, as `Q` would have said (a stop taken by an owner that was
        frozen past the move's end reported `cancelled by stop`). Not where the link is
        lost (a board that does not answer may have run it or not), nor once the board has
        reset: it takes each joint's first line after a reset at full speed, its time
        ignored (D1), and ends it long before the core expects, until the core learns of
        the reset."""
        if not self._judged(asked):
            return
        then = self.sim.t - OVER_BY_S - FINISHED_SLACK_S
        if not self.sim.board.moving(then) and self._at(asked.instr, self.sim.t):
            self.problems.append(f"{asked.instr.id} reported {reason!r}: the board had run it")

    def _judged(self, asked: Asked) -> bool:
        """Whether the board's pulses tell how `asked` ended: a move whose line was written
        (else where the arm is came of other moves), the link not lost, the board never
        reset."""
        return (
            asked.kind in ("move", "set-point")
            and not self.reset_seen
            and not self.sim.core.fault
            and any(m.sent.instr.id == asked.instr.id for m in self.sim.moved)
        )

    def _at(self, instr: Instruction, t: float) -> bool:
        """Whether the board puts out `instr`'s pulses at `t` (to within a microsecond)."""
        joints = CONFIG.joints
        return bool(instr.joints) and all(
            abs(self.sim.board.pulse_us(joints[name].channel, t) - joints[name].to_us(deg)) <= 1.0
            for name, deg in instr.joints
        )

    def _above_the_table(self) -> None:
        """Where the board holds the servos now is above the table, within the path
        check's own tolerance (a board that has reset holds nothing: nothing to check)."""
        joints = CONFIG.joints
        pulses = {
            name: self.sim.board.pulse_us(j.channel, self.sim.t) for name, j in joints.items()
        }
        if not all(pulses.values()):
            return
        pose = {name: joints[name].to_deg(us) for name, us in pulses.items()}
        under = below(CONFIG.model, pose)
        depth = 0.0 if under is None else under.table_m - under.z_m
        assert depth <= PATH_TOLERANCE_M + 1e-6, f"{depth * 1000:.1f} mm under the table: {pose}"

    def _pending_motion(self) -> list[Asked]:
        outcomes = self.sim.outcomes
        return [a for a in self.asked if a.instr.kind in MOTION and a.ref not in outcomes]

    @invariant()
    def no_problem(self) -> None:
        assert not self.problems, self.problems[:3]
        self._above_the_table()
        assert len(self.sim.writers) <= 1
        pending = [a for a in self._pending_motion() if a.kind == "set-point"]
        assert len(pending) <= STREAM_PENDING_MAX, f"{len(pending)} set-points pending"
        assert _cut_lines(self.sim, self.n_records) == []

    # -- asking ------------------------------------------------------------------------

    def _ask(self, kind: str, instr: Instruction, late: bool = False, **kw: object) -> Asked:
        count("arm core: requests")
        self.sim.catch_up()  # the board's bytes first, where the owner did not run (`stall`)
        # Registered before the core sees it: the check after its input knows it waits.
        ref = self.sim.next_ref()
        client = kw.get("client", 0)
        assert isinstance(client, int)
        asked = Asked(ref, kind, instr, self.sim.t, self.sim.wall, late, client)
        self.asked.append(asked)
        self.by_ref[ref] = asked
        locked = self.sim.core.locked
        self.sim.ask(instr, ref=ref, **kw)  # type: ignore[arg-type]
        # The stop that holds the lock: the one sent last since the arm was locked.
        holder = self.lock_holder
        newer = not locked or holder is None or _sent(asked) > _sent(holder)
        if kind == "stop" and self.sim.core.locked and newer:
            self.lock_holder = asked
        return asked

    def _moves(self, n: int, rng: random.Random) -> None:
        for _ in range(n):
            joints = rng.sample(JOINTS, rng.randint(1, 3))
            time_ms = rng.choice([0, 0, 20, 60, 300])
            target = {j: self.ready[j] + rng.uniform(-4, 4) for j in joints}
            self._ask("move", ins.move(time_ms=time_ms, **target))

    def _impatient(self, n: int, rng: random.Random) -> None:
        """Moves whose sender waits only so long for each (some as long as its time, some
        shorter), behind whatever else waits."""
        for _ in range(n):
            target = {j: self.ready[j] + rng.uniform(-4, 4) for j in rng.sample(JOINTS, 2)}
            move = ins.move(time_ms=rng.choice([0, 300, 1500]), **target)
            self._ask("move", dataclasses.replace(move, wait_ms=rng.randint(1, 900)))

    def _stop(self, twice: bool, apart_ms: int = 3) -> None:
        if not twice:
            self._ask("stop", ins.stop())
            return
        instr, key = ins.stop(), ("model", next(KEYS))
        self.keyed.append(key)
        told = len(self.sim.told)
        # Each reader puts the stop's time on this machine's clock by its own measure of
        # its client's: a few ms apart.
        sent = self.sim.wall - 5_000_000
        first = self._ask("stop", dataclasses.replace(instr, sent_ns=sent), key=key)
        later = dataclasses.replace(instr, sent_ns=sent + apart_ms * 1_000_000)
        again = self._ask("stop", later, key=key)
        if self.lock_holder in (first, again):  # the lock counts from the earlier
            self.lock_holder = min(first, again, key=_sent)
        if self.sim.outcomes[first.ref] != self.sim.outcomes[again.ref]:
            self.problems.append("a stop seen twice was answered differently")
        times = sum(o.id == instr.id for o in self.sim.told[told:])
        if times != 1:
            self.problems.append(f"a stop seen twice was told {times} times")

    def _late_stop(self, pick: int) -> None:
        """A stop sent before a release that was done, coming only now (held up behind a
        flood, or across a link that was down): obeyed (its STOP written where the board is
        reached), and the arm locked."""
        outcomes = self.sim.outcomes
        released = [
            _sent(a)
            for a in self.asked
            if a.kind == "release" and a.ref in outcomes and outcomes[a.ref].ok
        ]
        if not released:
            return
        sent = released[pick % len(released)] - (1, 500, 3000)[pick % 3] * 1_000_000
        self.sim.run(0)  # what fell due while the owner did not run (`stall`) is done first
        writes = len(self.sim.sent)
        asked = self._ask("stop", dataclasses.replace(ins.stop(), sent_ns=sent), late=True)
        if not self.sim.outcomes[asked.ref].ok:
            self.problems.append(f"a late stop not obeyed: {self.sim.outcomes[asked.ref]}")
        if not self.sim.core.locked:
            self.problems.append("a late stop left the arm unlocked")
        if self.sim.core.link.open and not any(
            data.startswith(p.CANCEL + b"STOP") for _, data in self.sim.sent[writes:]
        ):
            self.problems.append("a late stop wrote no STOP")

    def _copy(self, pick: int) -> None:
        """A copy of a stop obeyed earlier (its key, an id of its own), coming now, after
        whatever came since (a release): answered and told once under its id, as the stop
        was; it writes nothing and neither locks nor unlocks the arm."""
        if not self.keyed:
            return
        key = self.keyed[pick % len(self.keyed)]
        copy = ins.stop()
        self.sim.run(0)  # what fell due while the owner did not run (`stall`) is done first
        told, locked, sent = len(self.sim.told), self.sim.core.locked, len(self.sim.sent)
        # A copy, not a stop of its own: a release sent between the stop and its copy undoes
        # the stop (`_release` judges by the last stop, not by a copy's later time).
        first = self._ask("copy", copy, key=key)
        again = self._ask("copy", copy, key=key)  # the copy seen by the other reader
        outcomes = self.sim.outcomes
        if outcomes[first.ref] != outcomes[again.ref] or outcomes[first.ref].id != copy.id:
            self.problems.append("a copy of a stop was not answered under its id, once")
        times = sum(o.id == copy.id for o in self.sim.told[told:])
        if times != 1:
            self.problems.append(f"a copy of a stop was told {times} times")
        if self.sim.core.locked != locked or len(self.sim.sent) != sent:
            self.problems.append("a copy of a stop obeyed already acted again")

    def _release(self, late: bool) -> None:
        holder = self.lock_holder
        if not late or holder is None:
            self._ask("release", ins.release())
            return
        # Sent before the stop that holds the lock (a release queued behind a flood on the
        # topic).
        sent = _sent(holder) - 1_000_000
        locked = self.sim.core.locked
        asked = self._ask("release", dataclasses.replace(ins.release(), sent_ns=sent), late=True)
        if locked and self.sim.outcomes[asked.ref].ok:
            self.problems.append(f"a release sent before stop {holder.instr.id} undid it")

    def _set_points(self, n: int, rng: random.Random, here: bool) -> None:
        if here:
            pose = self.sim.core.positions(self.sim.t)
            if not any(math.isnan(v) for v in pose.values()):
                self._ask("set-point", ins.move(**pose), stream=STREAM, tell=False)
            return
        for _ in range(n):
            joints = rng.sample(JOINTS, rng.randint(1, 3))
            target = {j: self.ready[j] + rng.uniform(-4, 4) for j in joints}
            self._ask("set-point", ins.move(**target), stream=STREAM, tell=False)

    def _cancel(self, pick: int) -> None:
        # A trajectory too: one that waits for its start ends with nothing written.
        moves = [a for a in self._pending_motion() if a.kind in ("move", "trajectory")]
        if moves:
            self.sim.cancel(moves[pick % len(moves)].instr.id)

    def _trajectory(self, rng: random.Random) -> None:
        joint = rng.choice(JOINTS)
        step = rng.choice([10.0, 20.0, 40.0])
        points = tuple(
            Point(((joint, self.ready[joint] + 1.5 * (k + 1)),), step * (k + 1))
            for k in range(rng.randint(2, 12))
        )
        instr = ins.trajectory(points)
        ahead_ms = rng.choice([0, 0, 0, 100, 400])
        if ahead_ms:
            count("arm core: trajectories to start later")
            instr = dataclasses.replace(instr, start_ns=self.sim.wall + ahead_ms * 1_000_000)
            self.starts[instr.id] = self.sim.t + ahead_ms / 1000
        self._ask("trajectory", instr)

    # -- rules -------------------------------------------------------------------------

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(1, 8), seed=st.integers(0, 2**16))
    def moves(self, n: int, seed: int) -> None:
        self._moves(n, random.Random(seed))

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(1, 4), seed=st.integers(0, 2**16))
    def impatient_moves(self, n: int, seed: int) -> None:
        self._impatient(n, random.Random(seed))

    @precondition(lambda self: not self.ended)
    @rule(twice=st.booleans(), apart_ms=st.sampled_from([-3, 0, 3]))
    def stop(self, twice: bool, apart_ms: int) -> None:
        self._stop(twice, apart_ms)

    @precondition(lambda self: not self.ended)
    @rule(pick=st.integers(0, 100))
    def copy_of_a_stop(self, pick: int) -> None:
        self._copy(pick)

    @precondition(lambda self: not self.ended)
    @rule(pick=st.integers(0, 100))
    def late_stop(self, pick: int) -> None:
        self._late_stop(pick)

    @precondition(lambda self: not self.ended)
    @rule(late=st.booleans())
    def release(self, late: bool) -> None:
        self._release(late)

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(1, 6), seed=st.integers(0, 2**16), here=st.booleans())
    def set_points(self, n: int, seed: int, here: bool) -> None:
        self._set_points(n, random.Random(seed), here)

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(20, 200), seed=st.integers(0, 2**16), every_ms=st.integers(0, 25))
    def stream(self, n: int, seed: int, every_ms: int) -> None:
        """A stream at up to full tilt, with time passing between its set-points; a stop
        may land in the middle (its source does not know of it)."""
        rng = random.Random(seed)
        stop_at = rng.randrange(n) if rng.random() < 0.3 else -1
        for k in range(n):
            target = {j: self.ready[j] + 4 * math.sin(k / 7 + rng.random()) for j in JOINTS[:2]}
            self._ask("set-point", ins.move(**target), stream=STREAM, tell=False)
            if k == stop_at:
                self._stop(rng.random() < 0.3)
            self.sim.run(every_ms / 1000)

    @precondition(lambda self: not self.ended)
    @rule(seed=st.integers(0, 2**16))
    def quiet_stream(self, seed: int) -> None:
        """A set-point of a long move, and then nothing: the watchdog holds the arm."""
        rng = random.Random(seed)
        joint = rng.choice(JOINTS)
        target = {joint: self.ready[joint] + rng.choice([-12, 12])}
        asked = self._ask("set-point", ins.move(time_ms=1500, **target), stream=STREAM)
        self.sim.until(lambda: asked.ref in self.sim.outcomes, OUTCOME_BOUND_S)
        outcome = self.sim.outcomes.get(asked.ref)
        if outcome is None:
            self.problems.append(f"set-point {asked.instr.id} of a quiet stream never ended")
        elif outcome.result is Result.DONE and "nothing written" not in outcome.reason:
            self.problems.append(f"set-point {asked.instr.id} of a quiet stream ran: {outcome}")

    @precondition(lambda self: not self.ended)
    @rule(seed=st.integers(0, 2**16))
    def trajectory(self, seed: int) -> None:
        self._trajectory(random.Random(seed))

    @precondition(lambda self: not self.ended)
    @rule(dx=st.integers(-30, 30), line=st.booleans())
    def move_to(self, dx: int, line: bool) -> None:
        self._ask("move_to", ins.move_to(220 + dx, 0, 140, pitch=-30, line=line))

    @precondition(lambda self: not self.ended)
    @rule(pick=st.integers(0, 100))
    def cancel(self, pick: int) -> None:
        self._cancel(pick)

    @precondition(lambda self: not self.ended)
    @rule(client=st.integers(1, 3), n=st.integers(1, 4), seed=st.integers(0, 2**16))
    def lost_client(self, client: int, n: int, seed: int) -> None:
        """A client's moves, then the client goes without a word: none of them goes on."""
        rng = random.Random(seed)
        for _ in range(n):
            target = {j: self.ready[j] + rng.uniform(-4, 4) for j in rng.sample(JOINTS, 2)}
            self._ask("move", ins.move(time_ms=200, **target), client=client)
        self.sim.run(rng.uniform(0, 0.3))
        self.sim.gone(client, "its connection closed")
        left = [a for a in self._pending_motion() if a.client == client]
        if left:
            self.problems.append(f"{len(left)} move(s) of a lost client go on")

    @precondition(lambda self: not self.ended)
    @rule(
        actions=st.lists(
            st.sampled_from(
                [
                    "moves",
                    "impatient",
                    "stop",
                    "stop twice",
                    "late stop",
                    "release",
                    "cancel",
                    "set-points",
                ]
            ),
            min_size=2,
            max_size=4,
        ),
        seed=st.integers(0, 2**16),
    )
    def at_once(self, actions: list[str], seed: int) -> None:
        """Several clients' requests at the same instant, in the order given."""
        rng = random.Random(seed)
        runs: dict[str, Callable[[], None]] = {
            "moves": lambda: self._moves(3, rng),
            "impatient": lambda: self._impatient(2, rng),
            "stop": lambda: self._stop(False),
            "stop twice": lambda: self._stop(True),
            "late stop": lambda: self._late_stop(seed),
            "release": lambda: self._release(False),
            "cancel": lambda: self._cancel(seed),
            "set-points": lambda: self._set_points(3, rng, False),
        }
        for what in actions:
            runs[what]()

    @rule(ms=st.integers(0, 400))
    def wait(self, ms: int) -> None:
        self.sim.run(ms / 1000)

    @precondition(lambda self: not self.ended)
    @rule(
        ms=st.integers(1, 1500),
        then=st.sampled_from(["", "stop", "cancel", "set-point"]),
        pick=st.integers(),
    )
    def stall(self, ms: int, then: str, pick: int) -> None:
        """The owner's thread does not run for `ms` (frozen, or starved of the CPU) while
        the board runs on; what was due meanwhile is done when it runs again, after what
        waited for it (`then`: a stop, a cancel, or the stream's next set-point, taken
        first as it runs again)."""
        self.stalls.append((self.sim.t, self.sim.t + ms / 1000))
        self.sim.stall(ms / 1000)
        if then == "stop":
            self._stop(False)
        elif then == "cancel":
            self._cancel(pick)
        elif then == "set-point":
            self._set_points(1, random.Random(pick), False)

    @precondition(lambda self: not self.ended and not self.pulled)
    @rule(fault=st.sampled_from([Fault.DISCONNECT, Fault.NO_ANSWER, Fault.GARBAGE]))
    def pull(self, fault: Fault) -> None:
        self.sim.board.inject(fault)
        self.pulled = True

    @precondition(lambda self: not self.ended and self.pulled)
    @rule()
    def plug(self) -> None:
        self.sim.board.clear()
        self.pulled = False

    @precondition(lambda self: not self.ended)
    @rule()
    def reset(self) -> None:
        self.reset_seen = True
        self.sim.board.reset(self.sim.t)

    @precondition(lambda self: not self.ended)
    @rule(dice=st.integers(0, 9))
    def shutdown(self, dice: int) -> None:
        if dice:  # one time in ten: a shutdown ends the example
            return
        if self.pulled:
            self.sim.board.clear()
            self.pulled = False
        self._ask("shutdown", ins.shutdown())
        self.ended = True

    # -- at the end ----------------------------------------------------------------------

    def teardown(self) -> None:
        sim = self.sim
        if self.pulled:
            sim.board.clear()
        done = sim.until(lambda: all(a.ref in sim.outcomes for a in self.asked), OUTCOME_BOUND_S)
        missing = [a for a in self.asked if a.ref not in sim.outcomes]
        assert done, f"no outcome in {OUTCOME_BOUND_S} s for {[a.instr.id for a in missing[:5]]}"
        assert not self.problems, self.problems[:3]
        self._no_move_while_stopped()
        if not self.ended:
            self._probe()
        STEPS["seconds"] += time.perf_counter() - self.started

    def _no_move_while_stopped(self) -> None:
        """No group move was written after a stop's STOP and before a release was done (the
        park of a shutdown aside)."""
        shutdown = min((a.t for a in self.asked if a.kind == "shutdown"), default=math.inf)
        for stopped in self.stop_sends:
            until = min([t for t in self.released if t >= stopped] + [shutdown])
            moves = [
                data
                for t, data in self.sim.sent
                if stopped < t < until
                and p.CANCEL not in data
                and b"P" in data[:6]
                and data.lstrip(b"\x1b").startswith(b"#")
            ]
            assert not moves, f"a move written after a stop, before a release: {moves[0]!r}"

    def _probe(self) -> None:
        """After a stop and a release, a move is done (nothing is wedged)."""
        sim = self.sim
        for _ in range(3):
            assert sim.until(
                lambda: sim.core.state in (State.READY, State.STOPPED), OUTCOME_BOUND_S
            )
            if sim.core.locked:
                assert sim.outcome(sim.ask(ins.release())).ok
            probe = ins.move(base=self.ready["base"] + 1)
            outcome = sim.outcome(sim.ask(probe), OUTCOME_BOUND_S)
            if outcome.ok or "below the table" in outcome.reason:
                return
            # A reset or a lost link found only now (the pose read back after a stop finds a
            # board that reset before it): the move gets its answer; tried again.
            assert "has reset" in outcome.reason or "link is lost" in outcome.reason, outcome
        raise AssertionError(f"a move after stop and release: {outcome}")


def _sent(asked: Asked) -> int:
    """When `asked` was sent (this machine's clock, ns)."""
    return asked.instr.sent_ns if asked.instr.sent_ns is not None else asked.wall


def _resolves(effects: tuple[Effect, ...]) -> list[Resolve]:
    """Every outcome among `effects`, those of a batch cancelled at once among them."""
    out: list[Resolve] = []
    for e in effects:
        if isinstance(e, Cancelled):
            out.extend(e.resolves())
        elif isinstance(e, Resolve):
            out.append(e)
    return out


def _cut_lines(sim: Sim, since: int) -> list[bytes]:
    """Lines cut short by an ESC that hold anything but whole commands."""
    channels = set(sim.config.channels)
    bad = []
    for record in sim.records[since:]:
        if record.ignored != "cancelled by ESC" or not record.raw:
            continue
        parsed = p.parse_line(record.raw)
        if (
            isinstance(parsed, p.Unrecognized)
            or b"T" in record.raw
            or any(
                not isinstance(cmd, p.GroupMove)
                or any(
                    t.channel not in channels or not 500 <= t.pulse_us <= 2500 for t in cmd.targets
                )
                for cmd in parsed
            )
        ):
            bad.append(record.raw)
    return bad


CoreProtocol.TestCase.settings = settings(
    max_examples=200 * SCALE,
    stateful_step_count=20,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    derandomize=SCALE == 1,
)


def test_the_core_holds_against_the_model() -> None:
    STEPS["inputs"], STEPS["seconds"] = 0, 0.0
    CoreProtocol.TestCase().runTest()
    count("arm core: inputs stepped", STEPS["inputs"])
    if STEPS["seconds"]:
        rate = STEPS["inputs"] / STEPS["seconds"] * 60
        print(
            f"\narm core model: {STEPS['inputs']} inputs in {STEPS['seconds']:.1f} s "
            f"({rate:,.0f} a minute)"
        )
