"""The whole owner against a model (issue 22): random sequences and interleavings from many
threads, checked after every step.

`hypothesis.stateful` drives the real owner (`al5d.owner.Owner`, its thread and its
teller) on the emulator (a pty, at 115200 baud so that the wire is quick) with random
sequences of moves, stops (some seen twice, as the
node and the stop watcher both see a stop on the topic), releases (some sent before the
last stop and arriving after it, as a release queued on the topic behind a flood does),
cancels, a board pulled and plugged back, waits and a shutdown; a rule runs several of
them at once from threads of their own. The model is small: what was asked, when, and
what each outcome must be. After every step:

- every request has exactly one outcome (each told once to the listeners), a stop and
  a release at once;
- a release sent before the stop that holds the lock is refused (a stop is never undone
  by an earlier release);
- the state is `ready` only while no move runs or waits: a move pending across a whole
  look at a `ready` arm is a lie (the wedged queue of issue 22);

and at the end of each example:

- no move took effect on the board after a stop's STOP and before a release was asked;
- nothing waits for ever: every outcome comes within a bound, and a probe move after
  stop and release is done.

`make test` runs a bounded number of examples; `make soak` (AL5D_FUZZ_SCALE=10) more. The
core alone, in virtual time and with far more examples, is `test_arm_core_model.py`'s.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import random
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    invariant,
    precondition,
    rule,
)

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig, load_config
from al5d.arm.instruction import Instruction, Outcome, Result
from al5d.arm.states import State
from al5d.model.table import PATH_TOLERANCE_M, below
from al5d.owner.loop import Owner
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Fault
from al5d_rig.fuzzcount import SCALE, count

#: The identities of stop messages: each a new one (the driver remembers those it obeyed).
KEYS = itertools.count()
#: Examples run so far in this process, for the failure messages: how many it took.
EXAMPLES = itertools.count(1)
#: How long any outcome may take once nothing more is asked (the longest queue here is a
#: few dozen moves of a few ms each; a reconnect takes a few tenths of a second).
OUTCOME_BOUND_S = 15.0
JOINTS = ("base", "shoulder", "elbow", "wrist")
#: Instructions carry when they were sent where the driver knows of it (`sent_ns`).
SENT = "sent_ns" in {f.name for f in dataclasses.fields(Instruction)}


#: The stream of the set-points (as the server names ros2_control's joint commands).
STREAM = "joint_commands"
#: The stream's watchdog here (`server.stream_timeout_s`).
STREAM_TIMEOUT_S = 0.15
#: Set-points of the stream not yet ended, at most: the one running (or about to be written
#: in its place) and one waiting behind other moves. A stream never queues.
STREAM_PENDING_MAX = 2


def sent_at(instr: Instruction, t_ns: int) -> Instruction:
    """`instr` as sent at `t_ns` (CLOCK_REALTIME): arriving late, behind others."""
    return dataclasses.replace(instr, sent_ns=t_ns) if SENT else instr


@dataclass
class Asked:
    """One request and what became of it."""

    kind: str
    instr: Instruction
    future: Future[Outcome]
    t_call: float  # CLOCK_MONOTONIC, as the emulator's records
    wall_ns: int  # CLOCK_REALTIME, as instructions are stamped: no later than its sending
    t_done: float = 0.0  # when the submit returned
    late: bool = False  # a release sent before the last stop, arriving after it


@dataclass
class Rig:
    """A driver on an emulated board, kept across examples (a new one after a shutdown)."""

    config: ArmConfig
    workdir: Path
    emu: Emulator | None = None
    driver: Owner | None = None
    told: Counter[str] = field(default_factory=Counter)
    #: The outcomes are counted on the driver's threads while a check reads them (a copy
    #: taken without it once raised "dictionary changed size during iteration").
    told_lock: threading.Lock = field(default_factory=threading.Lock)
    pulled: bool = False
    #: An example failed: the next one starts on a new driver (what went wrong there must
    #: not be found again by every example after it).
    dirty: bool = False

    def fresh(self) -> None:
        self.close()
        pose = dict(self.config.presets["park"])
        link = self.workdir / "ssc32u-model"
        self.emu = Emulator(self.config, baud=115200, link=link, initial_pose=pose).start()
        self.driver = Owner.on_port(self.config, str(link), 115200)
        self.driver.outcome_listeners.append(self._tell)
        self.driver.start()
        self.driver.wait_for_state(State.READY, 20)
        self.pulled = False

    def _tell(self, outcome: Outcome) -> None:
        with self.told_lock:
            self.told.update([outcome.id])

    def told_so_far(self, clear: bool = False) -> dict[str, int]:
        """The outcomes told, by id (and from now on none, with `clear`)."""
        with self.told_lock:
            told = dict(self.told)
            if clear:
                self.told.clear()
        return told

    def close(self) -> None:
        if self.driver is not None:
            self.driver.close(10)
        if self.emu is not None:
            self.emu.close()
        self.driver = self.emu = None


def _config() -> ArmConfig:
    config = load_config()
    # The emulated board is a thread of this busy process: a late answer is not a lost link
    # here (the fault suites test those); reconnecting quickly keeps the examples short.
    # The stream's watchdog is short, so that a quiet stream is held within an example.
    server = config.server.model_copy(
        update={
            "answer_timeout_s": 0.5,
            "reconnect_interval_s": 0.05,
            "stream_timeout_s": STREAM_TIMEOUT_S,
        }
    )
    return config.model_copy(update={"server": server})


_RIG: Rig | None = None


@pytest.fixture(scope="module")
def model_rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    global _RIG
    _RIG = Rig(_config(), tmp_path_factory.mktemp("model"))
    _RIG.fresh()
    try:
        yield _RIG
    finally:
        _RIG.close()
        _RIG = None


def _shutdown_asked(driver: Owner) -> bool:
    return driver.core.shutdown is not None


def small_move(rng: random.Random, ready: dict[str, float]) -> Instruction:
    joints = rng.sample(JOINTS, rng.randint(1, 3))
    time_ms = rng.choice([0, 0, 20, 60])
    return ins.move(time_ms=time_ms, **{j: ready[j] + rng.uniform(-4, 4) for j in joints})


def reported(check: Callable[[ArmProtocol], None]) -> Callable[[ArmProtocol], None]:
    """An invariant whose failure says the example's number and steps (`ArmProtocol.failed`)."""

    @functools.wraps(check)
    def run(machine: ArmProtocol) -> None:
        try:
            check(machine)
        except AssertionError as e:
            raise machine.failed(e) from e

    return run


class ArmProtocol(RuleBasedStateMachine):
    """The rules a client (or several) can play on the arm, and the model's checks."""

    def __init__(self) -> None:
        super().__init__()
        assert _RIG is not None
        self.rig = _RIG
        self._settle()
        self.example = next(EXAMPLES)
        self.steps: list[str] = []
        count("arm protocol: sequences against the model")
        self.asked: list[Asked] = []
        self.lock = threading.Lock()
        self.ready = dict(self.rig.config.presets["ready"])
        self.ended = False
        self.n_records = len(self.emu.records)
        self.problems: list[str] = []

    # -- the rig ---------------------------------------------------------------------

    @property
    def driver(self) -> Owner:
        assert self.rig.driver is not None
        return self.rig.driver

    @property
    def emu(self) -> Emulator:
        assert self.rig.emu is not None
        return self.rig.emu

    def _settle(self) -> None:
        """Back to a connected, released arm at rest, whatever the last example left."""
        rig = self.rig
        if rig.dirty and rig.driver is not None:
            rig.driver.execute(ins.stop(), 5)  # whatever it was doing, a stop before closing
            rig.close()
            rig.dirty = False
        if rig.driver is None or _shutdown_asked(rig.driver):
            if rig.driver is not None:
                assert rig.driver.finished.wait(20), "the shutdown did not end the driver"
            rig.fresh()
            return
        if rig.pulled:
            assert rig.emu is not None
            rig.emu.reconnect()
            rig.pulled = False
        deadline = time.monotonic() + 20
        while rig.driver.state not in (State.READY, State.STOPPED):
            assert time.monotonic() < deadline, f"stuck in {rig.driver.state.value}"
            time.sleep(0.01)
        if rig.driver.locked:
            assert rig.driver.execute(ins.release(), 5).ok

    # -- asking ------------------------------------------------------------------------

    def _submit(self, kind: str, instr: Instruction, late: bool = False, **kw: Any) -> Asked:
        count("arm protocol: requests")
        t, wall = time.monotonic(), time.time_ns()
        future = self.driver.submit(instr, **kw)
        asked = Asked(kind, instr, future, t, wall, time.monotonic(), late)
        with self.lock:
            self.asked.append(asked)
        return asked

    def _moves(self, n: int, seed: int) -> None:
        rng = random.Random(seed)
        for _ in range(n):
            self._submit("move", small_move(rng, self.ready))

    def _stop(self, twice: bool) -> None:
        if not twice:
            self._submit("stop", ins.stop())
            return
        # The node and the stop watcher both see one stop on the topic: one message, one key.
        if not SENT:  # a driver that does not know a stop by its message obeys each submit
            self._submit("stop", ins.stop())
            return
        instr, key = ins.stop(), ("model", next(KEYS))
        first = self._submit("stop", instr, key=key)
        again = self.driver.submit(instr, key=key)
        assert again.result(5) == first.future.result(5), "a stop seen twice, two outcomes"

    def _release(self, late: bool) -> None:
        if late:
            # Sent before the last stop (as a release queued behind a flood on the topic),
            # arriving now.
            stops = [a for a in self.asked if a.kind == "stop"]
            if not stops:
                return
            sent = stops[-1].wall_ns - 1_000_000
            self._submit("release", sent_at(ins.release(), sent), late=True)
            return
        self._submit("release", ins.release())

    def _set_points(self, n: int, seed: int, here: bool) -> None:
        """A stream of set-points (ros2_control's joint commands): near the ready pose, or,
        `here`, where the arm stands (a controller re-activated, holding the arm's pose)."""
        if here:
            pose = self.driver.positions()
            if not any(math.isnan(v) for v in pose.values()):
                self._submit("set-point", ins.move(**pose), stream=STREAM)
            return
        rng = random.Random(seed)
        for _ in range(n):
            joints = rng.sample(JOINTS, rng.randint(1, 3))
            target = {j: self.ready[j] + rng.uniform(-4, 4) for j in joints}
            self._submit("set-point", ins.move(**target), stream=STREAM)

    def _burst(self, n: int, seed: int) -> None:
        """Set-points as fast as a caller can submit them (a teleoperation stream at full
        tilt): each supersedes the last; the newest is where the arm goes."""
        rng = random.Random(seed)
        for k in range(n):
            target = {j: self.ready[j] + 4 * math.sin(k / 7 + rng.random()) for j in JOINTS}
            self._submit("set-point", ins.move(**target), stream=STREAM)

    def _stream_then_stop(self, seed: int) -> None:
        """A stop in the middle of a stream: the stream goes on in its own thread, before,
        during and after the stop (its source does not know of it)."""
        rng = random.Random(seed)
        done = threading.Event()

        def stream() -> None:
            k = 0
            while not done.is_set() or k < 10:
                target = {j: self.ready[j] + 3 * math.sin(k / 5) for j in JOINTS[:2]}
                self._submit("set-point", ins.move(**target), stream=STREAM)
                k += 1
                time.sleep(rng.choice([0, 0.001, 0.003]))

        sender = threading.Thread(target=stream)
        sender.start()
        time.sleep(rng.uniform(0, 0.05))
        self._stop(rng.random() < 0.3)
        time.sleep(rng.uniform(0, 0.02))
        done.set()
        sender.join(10)

    def _cancel(self, pick: int) -> None:
        moves = [a for a in self.asked if a.kind == "move" and not a.future.done()]
        if moves:
            self.driver.cancel(moves[pick % len(moves)].instr.id)

    # -- rules -------------------------------------------------------------------------

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(1, 8), seed=st.integers(0, 2**16))
    def moves(self, n: int, seed: int) -> None:
        self.check_step(f"moves({n})")
        self._moves(n, seed)

    @precondition(lambda self: not self.ended)
    @rule(twice=st.booleans())
    def stop(self, twice: bool) -> None:
        self.check_step(f"stop(twice={twice})")
        self._stop(twice)

    @precondition(lambda self: not self.ended)
    @rule(late=st.booleans())
    def release(self, late: bool) -> None:
        self.check_step(f"release(late={late})")
        # A late release is sent with a time: it stands for one that a stop overtook.
        stops = [a for a in self.asked if a.kind == "stop"]
        stopped_before = self.driver.state is State.STOPPED and bool(stops)
        self._release(late)
        if late and stopped_before and stops:
            last = self.asked[-1]
            outcome = last.future.result(5)
            if outcome.ok:
                self.problems.append(
                    f"a release sent before the stop {stops[-1].instr.id} undid it: {outcome}"
                )

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(1, 6), seed=st.integers(0, 2**16), here=st.booleans())
    def set_points(self, n: int, seed: int, here: bool) -> None:
        self.check_step(f"set_points({n}, here={here})")
        self._set_points(n, seed, here)

    @precondition(lambda self: not self.ended)
    @rule(n=st.integers(20, 300), seed=st.integers(0, 2**16))
    def burst(self, n: int, seed: int) -> None:
        self.check_step(f"burst({n})")
        self._burst(n, seed)

    @precondition(lambda self: not self.ended)
    @rule(seed=st.integers(0, 2**16))
    def stream_then_stop(self, seed: int) -> None:
        self.check_step("stream_then_stop")
        self._stream_then_stop(seed)

    @precondition(lambda self: not self.ended)
    @rule(seed=st.integers(0, 2**16))
    def quiet_stream(self, seed: int) -> None:
        """A set-point of a long move, and then nothing: the watchdog holds the arm."""
        self.check_step("quiet_stream")
        rng = random.Random(seed)
        joint = rng.choice(JOINTS)
        target = {joint: self.ready[joint] + rng.choice([-12, 12])}
        asked = self._submit("set-point", ins.move(time_ms=1500, **target), stream=STREAM)
        try:
            outcome = asked.future.result(OUTCOME_BOUND_S)
        except TimeoutError:
            self.problems.append(f"set-point {asked.instr.id} of a quiet stream never ended")
            return
        # Written, it may not complete its 1.5 s with no set-point after it; refused (held
        # or stopped), cancelled by a stop or a fault, or where the arm is: all fine.
        if outcome.result is Result.DONE and "nothing written" not in outcome.reason:
            self.problems.append(
                f"set-point {asked.instr.id} of a quiet stream ran its 1.5 s: {outcome}"
            )
        if "went quiet" in outcome.reason and self.driver.locked and not self._stopped_since(asked):
            self.problems.append("the watchdog locked the arm (it holds it, it is no stop)")

    def _stopped_since(self, since: Asked) -> bool:
        return any(a.kind == "stop" and a.t_call >= since.t_call for a in self.asked)

    @precondition(lambda self: not self.ended)
    @rule(pick=st.integers(0, 100))
    def cancel(self, pick: int) -> None:
        self.check_step("cancel")
        self._cancel(pick)

    @precondition(lambda self: not self.ended)
    @rule(
        actions=st.lists(
            st.sampled_from(
                ["moves", "stop", "stop twice", "release", "cancel", "set-points", "burst"]
            ),
            min_size=2,
            max_size=4,
        ),
        seed=st.integers(0, 2**16),
    )
    def at_once(self, actions: list[str], seed: int) -> None:
        """Several clients at the same moment, each in a thread of its own."""
        self.check_step(f"at_once({actions})")
        go = threading.Barrier(len(actions))
        runs: dict[str, Callable[[], None]] = {
            "moves": lambda: self._moves(4, seed),
            "stop": lambda: self._stop(False),
            "stop twice": lambda: self._stop(True),
            "release": lambda: self._release(False),
            "cancel": lambda: self._cancel(seed),
            "set-points": lambda: self._set_points(3, seed, False),
            "burst": lambda: self._burst(50, seed),
        }
        errors: list[BaseException] = []

        def run(what: str) -> None:
            try:
                go.wait(5)
                runs[what]()
            except BaseException as e:
                errors.append(e)

        threads = [threading.Thread(target=run, args=(a,)) for a in actions]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert not errors, errors

    @rule(ms=st.integers(0, 60))
    def wait(self, ms: int) -> None:
        self.check_step(f"wait({ms})")
        time.sleep(ms / 1000)

    @precondition(lambda self: not self.ended and not self.rig.pulled)
    @rule()
    def pull(self) -> None:
        self.check_step("pull")
        self.emu.inject(Fault.DISCONNECT)
        self.rig.pulled = True

    @precondition(lambda self: not self.ended and self.rig.pulled)
    @rule()
    def plug(self) -> None:
        self.check_step("plug")
        self.emu.reconnect()
        self.rig.pulled = False

    @precondition(lambda self: not self.ended)
    @rule(dice=st.integers(0, 9))
    def shutdown(self, dice: int) -> None:
        if dice:  # one time in ten: a shutdown ends the example's driver
            return
        self.check_step("shutdown")
        if self.rig.pulled:
            self.emu.reconnect()
            self.rig.pulled = False
        self._submit("shutdown", ins.shutdown())
        self.ended = True

    # -- the model's checks --------------------------------------------------------------

    @invariant()
    @reported
    def answered_at_once(self) -> None:
        """Stops and releases are answered at once (once the owner has taken what was handed
        to it); nothing is answered twice."""
        self.driver.sync()
        for a in list(self.asked):
            if a.kind in ("stop", "release"):
                assert a.future.done(), f"{a.kind} {a.instr.id} not answered at once"
        for ident, n in self.rig.told_so_far().items():
            assert n <= 1, f"{ident} was told {n} outcomes"
        assert not self.problems, self.problems

    @invariant()
    @reported
    def the_stream_never_queues(self) -> None:
        """Every set-point but the newest has ended (superseded, replaced, done...) once its
        submit returned, but for one running and one waiting behind other moves."""
        pending = [a for a in self.asked if a.kind == "set-point" and not a.future.done()]
        assert len(pending) <= STREAM_PENDING_MAX, (
            f"{len(pending)} set-points of the stream pending: "
            + ", ".join(a.instr.id for a in pending[:5])
        )

    @invariant()
    @reported
    def ready_only_when_nothing_waits(self) -> None:
        if self.ended:
            return
        before = {id(a) for a in self.asked if a.kind == "move" and not a.future.done()}
        if not before or self.driver.state is not State.READY:
            return
        time.sleep(0.03)
        still = [
            a
            for a in self.asked
            if id(a) in before and not a.future.done() and a.t_call < time.monotonic() - 0.03
        ]
        if still and self.driver.state is State.READY:
            ids = ", ".join(a.instr.id for a in still[:5])
            raise AssertionError(f"state ready while {len(still)} move(s) wait: {ids}")

    def teardown(self) -> None:
        try:
            self._teardown()
        except BaseException as e:
            raise self.failed(e) from e

    def check_step(self, what: str) -> None:
        self.steps.append(what)

    def failed(self, e: BaseException) -> AssertionError:
        """The failure, with the example's number and steps; the next example gets a new
        driver. Said at once on the real stderr too (how many examples it took to find a
        defect; hypothesis reports the shrunk example only)."""
        self.rig.dirty = True
        text = f"example {self.example}, steps {self.steps}: {e}"
        print(f"\narm model: {text[:300]}", file=sys.__stderr__, flush=True)
        return AssertionError(text)

    def _teardown(self) -> None:
        if self.rig.pulled and not self.ended:
            self.emu.reconnect()
            self.rig.pulled = False
        deadline = time.monotonic() + OUTCOME_BOUND_S
        for a in self.asked:
            try:
                a.future.result(max(0.0, deadline - time.monotonic()))
            except TimeoutError:
                core = self.driver.core
                raise AssertionError(
                    f"{a.kind} {a.instr.id} got no outcome in {OUTCOME_BOUND_S} s "
                    f"(state {self.driver.state.value}; the core: run {core.run}, queue "
                    f"{[j.instr.id for j in core.queue]}, link {core.link}, readback "
                    f"{core.readback})"
                ) from None
        self._no_move_while_stopped()
        self._stream_held_after_a_stop()
        if not self.ended:
            self._probe()
        for ident, n in self.rig.told_so_far(clear=True).items():
            assert n == 1 or not any(a.instr.id == ident for a in self.asked), (ident, n)

    def _probe(self) -> None:
        """The wedge: after stop and release, a move is done. A board plugged back just now
        may not have been found lost yet (its old port fails at the next write): the move
        is then cancelled with that reason, and tried again once the link is back."""
        for _ in range(3):
            self._settle()
            probe = self.driver.submit(ins.move(base=self.ready["base"] + 1))
            try:
                outcome = probe.result(10)
            except TimeoutError:
                raise AssertionError(
                    f"a move after stop and release got no outcome in 10 s "
                    f"(state {self.driver.state.value})"
                ) from None
            if outcome.ok:
                return
            if "the arm starts below the table" in outcome.reason:
                # Not a wedge: the move got its answer. A stop mid-move near the table, and
                # the pose read back at QP's 10 us, can leave the driver believing the arm
                # a millimetre under a table its checked path kept it above (seen once:
                # "the left finger is 1 mm below the table"). Where the board holds the
                # servos must be above it, within the path check's own tolerance.
                self._board_above_the_table()
                return
            assert "the serial link is lost" in outcome.reason, outcome
            time.sleep(0.1)
        raise AssertionError(f"a move after stop and release: {outcome}")

    def _board_above_the_table(self) -> None:
        joints = self.rig.config.joints
        pulses = {name: self.emu.pulse_us(j.channel) for name, j in joints.items()}
        if not all(pulses.values()):
            return  # a channel without a pulse (a board reset): nothing holds the arm there
        pose = {name: joints[name].to_deg(us) for name, us in pulses.items()}
        under = below(self.rig.config.model, pose)
        depth = 0.0 if under is None else under.table_m - under.z_m
        assert depth <= PATH_TOLERANCE_M + 1e-6, (
            f"the board's pulses put the arm {depth * 1000:.2f} mm under the table: {pose}"
        )

    def _stream_held_after_a_stop(self) -> None:
        """After a stop, no set-point of the stream moved the arm before one where the arm
        stood was taken (a target sent again and again is not driven to after a release)."""
        stops = sorted(a.t_done for a in self.asked if a.kind == "stop" and a.future.result().ok)
        points = sorted((a for a in self.asked if a.kind == "set-point"), key=lambda a: a.t_call)
        for i, stopped in enumerate(stops):
            until = stops[i + 1] if i + 1 < len(stops) else math.inf
            resumed = False
            for a in points:
                if not stopped < a.t_call < until:
                    continue
                outcome = a.future.result()
                if not outcome.ok:
                    continue
                if "nothing written" in outcome.reason:
                    resumed = True
                elif not resumed:
                    raise AssertionError(
                        f"set-point {a.instr.id} moved the arm after a stop before the stream "
                        f"was resumed: {outcome}"
                    )

    def _no_move_while_stopped(self) -> None:
        """No move took effect on the board after a stop's STOP and before a release was
        asked (the park of a shutdown aside)."""
        records = self.emu.records[self.n_records :]
        shutdown = min((a.t_call for a in self.asked if a.kind == "shutdown"), default=1e18)
        releases = sorted(
            a.t_call
            for a in self.asked
            if a.kind == "release" and a.future.done() and a.future.result().ok
        )
        stops_at = [
            i for i, r in enumerate(records) if any(isinstance(c, p.Stop) for c in r.commands)
        ]
        for stop in (a for a in self.asked if a.kind == "stop"):
            # The STOP this stop wrote, written before its submit returned and on the board a
            # wire time later: the last STOP by then (a cancel's racing it may be later, which
            # only checks less).
            window = [
                i for i in stops_at if stop.t_call <= records[i].t_effect <= stop.t_done + 0.01
            ]
            if not window:
                continue  # no board then (pulled): nothing went out either
            first = window[-1]
            until = min([t for t in releases if t > stop.t_call] + [shutdown])
            # Skip the rest of this burst of STOPs: a move written before the stop is halted
            # by it, and a move cannot get between the STOPs of one write.
            for r in records[first:]:
                if r.t_effect >= until:
                    break
                if any(isinstance(c, p.GroupMove) for c in r.commands):
                    raise AssertionError(
                        f"a move took effect {1000 * (r.t_effect - records[first].t_effect):.1f} "
                        f"ms after the STOP of stop {stop.instr.id}, before any release: {r.raw!r}"
                    )


ArmProtocol.TestCase.settings = settings(
    max_examples=150 * SCALE,
    stateful_step_count=12,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    derandomize=SCALE == 1,
)


def test_the_arm_protocol_holds_against_the_model(model_rig: Rig) -> None:
    ArmProtocol.TestCase().runTest()
