"""The owner of the board against the emulator over a real pty, judged by what reached the board."""

from __future__ import annotations

import itertools
import logging
import math
import random
import threading
import time
from concurrent.futures import Future

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome, Result
from al5d.arm.states import TRANSITIONS, State
from al5d.owner.loop import Owner
from al5d.ssc32u import protocol as p
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.emulator import Emulator, Fault
from al5d_rig.armrig import (
    Rig,
    group_pulses,
    logged,
    make_rig,
    min_ms,
    pulses,
    state_lines,
    written,
)
from al5d_rig.rospeer import wait_until


class TestStartup:
    def test_fresh_board_park_is_the_first_move_and_d1_is_logged(
        self, rig: Rig, caplog: pytest.LogCaptureFixture
    ) -> None:
        first = rig.moves()[0]
        move = first.commands[0]
        assert isinstance(move, p.GroupMove)
        assert group_pulses(move) == pulses(rig.config, rig.config.presets["park"])
        assert move.time_ms is None  # positions unknown: the board would ignore T anyway
        assert "first command since power-up" in (first.ignored or "")
        assert any("D1:" in r.getMessage() and r.levelno == logging.WARNING for r in logged(caplog))
        assert rig.driver.positions() == pytest.approx(rig.config.presets["park"])
        assert state_lines(caplog)[:2] == ["initializing", "ready"]

    def test_running_board_parks_at_half_speed(
        self, config: ArmConfig, caplog: pytest.LogCaptureFixture
    ) -> None:
        caplog.set_level(logging.DEBUG, logger="al5d")
        straight = config.presets["straight_up"]
        with Emulator(config) as emu:
            with SSC32U(
                emu.port
            ) as board:  # someone used the arm before: the board knows its pulses
                board.move(pulses(config, straight))
                emu.wait_for(lambda rs: any(r.raw.startswith(b"#0P") for r in rs))
            emu.clear_records()
            driver = Owner.on_port(config, emu.port)
            driver.start()
            try:
                driver.wait_for_state(State.READY, 10)
                park_rec = next(
                    r for r in emu.records if r.commands and isinstance(r.commands[0], p.GroupMove)
                )
                move = park_rec.commands[0]
                assert isinstance(move, p.GroupMove)
                park = config.presets["park"]
                assert group_pulses(move) == pulses(config, park)
                assert move.time_ms == min_ms(config, straight, park, fraction=0.5)
                assert not any("D1:" in r.getMessage() for r in logged(caplog))
                # Half speed: no servo goes faster than half its top speed.
                for name in park:
                    j = config.joints[name]
                    travel_us = abs(j.to_us(park[name]) - j.to_us(straight[name]))
                    assert travel_us / (move.time_ms / 1000) <= j.speed_us_s * 0.5 + 1
            finally:
                driver.close()


class TestMoves:
    @pytest.mark.parametrize("name", ["ready", "straight_up", "park"])
    def test_every_preset(self, rig: Rig, name: str) -> None:
        start = rig.driver.positions()
        outcome = rig.driver.execute(ins.preset(name), 10)
        assert outcome.result is Result.DONE
        pose = rig.config.presets[name]
        move = rig.last_move()
        assert group_pulses(move) == pulses(rig.config, pose)
        expected = min_ms(rig.config, start, pose)
        assert (move.time_ms or 0) == expected
        assert outcome.expected_ms == expected
        assert rig.driver.positions() == pytest.approx(pose)
        assert rig.emu.servo_degrees() == pytest.approx(pose, abs=0.2)

    def test_custom_move_without_time_runs_at_the_physical_minimum(self, rig: Rig) -> None:
        start = rig.driver.positions()
        outcome = rig.driver.execute(ins.move(base=30, wrist=-20), 10)
        assert outcome.ok
        move = rig.last_move()
        assert group_pulses(move) == pulses(
            rig.config, {"base": 30, "wrist": -20}
        )  # only named joints
        assert move.time_ms == min_ms(rig.config, start, {"base": 30, "wrist": -20})
        assert rig.moves()[-1].raw == f"#0P1800#3P1300T{move.time_ms}".encode()

    def test_custom_move_with_time_is_honoured(self, rig: Rig) -> None:
        outcome = rig.driver.execute(ins.move(base=-30, time_ms=700), 10)
        assert outcome.ok and outcome.expected_ms == 700
        assert rig.last_move().time_ms == 700  # done by its time: test_arm_core.py

    def test_a_time_below_the_minimum_is_raised_with_an_inf03_warning(
        self, rig: Rig, caplog: pytest.LogCaptureFixture
    ) -> None:
        start = rig.driver.positions()
        outcome = rig.driver.execute(ins.move(base=90, time_ms=50), 10)
        expected = min_ms(rig.config, start, {"base": 90})
        assert expected > 50
        assert outcome.ok and outcome.expected_ms == expected
        assert rig.last_move().time_ms == expected
        warnings = [
            r.getMessage()
            for r in logged(caplog)
            if r.levelno == logging.WARNING and "INF03" in r.getMessage()
        ]
        assert warnings and f"requested 50 ms; expected {expected} ms" in warnings[-1]
        # The outcome itself says what the server changed (issue 45), not only the log.
        assert f"requested 50 ms; expected {expected} ms" in outcome.reason
        assert str(outcome).endswith(f"expected {expected} ms ({outcome.elapsed_ms:.0f} ms)")

    def test_joints_arrive_together_and_no_faster_than_the_servos(self, rig: Rig) -> None:
        target = {"base": -60, "shoulder": 60, "elbow": 30, "wrist": 45, "gripper": 80}
        start = rig.driver.positions()
        assert rig.driver.execute(ins.move(**target), 10).ok
        rec = rig.moves()[-1]
        minimum = min_ms(rig.config, start, target) / 1000
        arrivals = [rig.emu.settle_time(0.05, [j]) for j in target]
        assert max(arrivals) - min(arrivals) < 0.002
        assert max(arrivals) - rec.t_effect >= minimum - 0.002
        assert rig.emu.servo_degrees() == pytest.approx({**start, **target}, abs=0.2)

    def test_moves_queue_and_run_in_order(self, rig: Rig) -> None:
        futures = [rig.driver.submit(ins.move(base=b)) for b in (10, 20, 30, 40)]
        outcomes = [f.result(10) for f in futures]
        assert all(o.ok for o in outcomes)
        bases = [t.pulse_us for m in rig.moves()[-4:] for t in m.commands[0].targets]  # type: ignore[union-attr]
        assert bases == [1600, 1700, 1800, 1900]


class TestRefusals:
    @pytest.mark.parametrize(
        ("instr", "reason"),
        [
            (ins.move(base=91), "base: 91 deg is outside the range -90..90"),
            (ins.move(elbow=-0.5, base=0), "elbow: -0.5 deg is outside the range 0..135"),
            (ins.move(shoulder=-31), "shoulder: -31 deg is outside the range -30..90"),
            (ins.move(gripper=120), "gripper: 120 deg is outside the range 0..90"),
            (ins.move(finger=3), "unknown joint 'finger'"),
            (ins.move(base=math.nan), "base: nan is not a finite number"),
            (ins.move(base=math.inf), "base: inf is not a finite number"),
            (
                ins.Instruction(ins.Kind.MOVE, joints=(("base", 1.0), ("base", 2.0))),
                "base is given twice",
            ),
            (ins.move(base=10, time_ms=-5), "time -5 ms is negative"),
            (
                ins.move(base=10, time_ms=3_600_000),
                "time 3600000 ms is above the limit of 60000 ms",
            ),
            (ins.Instruction(ins.Kind.MOVE), "a move names no joint"),
            (ins.preset("dance"), "unknown preset 'dance'"),
        ],
    )
    def test_refused_whole_with_nothing_written(
        self, rig: Rig, instr: ins.Instruction, reason: str
    ) -> None:
        before = written(rig.emu.records)
        outcome = rig.driver.execute(instr, 5)
        assert outcome.result is Result.REFUSED
        assert reason in outcome.reason
        time.sleep(0.05)
        assert written(rig.emu.records) == before

    def test_one_bad_joint_refuses_the_whole_move(self, rig: Rig) -> None:
        before = len(rig.moves())
        outcome = rig.driver.execute(ins.move(base=10, elbow=150, wrist=5), 5)
        assert outcome.result is Result.REFUSED and "elbow: 150 deg" in outcome.reason
        time.sleep(0.05)
        assert len(rig.moves()) == before
        assert rig.driver.positions() == pytest.approx(rig.config.presets["park"])

    def test_a_full_queue_refuses(self, config: ArmConfig) -> None:
        small = config.model_copy(
            update={"server": config.server.model_copy(update={"queue_capacity": 3})}
        )
        for rig in make_rig(small):
            running = rig.driver.submit(ins.move(base=80, time_ms=3000))
            rig.wait_move_count(2)  # park, then this one
            queued = [rig.driver.submit(ins.move(base=b)) for b in (1, 2, 3)]
            full = rig.driver.execute(ins.move(base=4), 5)
            assert (
                full.result is Result.REFUSED and "the queue is full (3 moves wait)" in full.reason
            )
            assert not any(f.done() for f in queued) and not running.done()
            rig.driver.execute(ins.stop(), 5)
            assert all(f.result(5).result is Result.CANCELLED for f in [running, *queued])


class TestStop:
    def test_stop_while_moving(self, rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
        running = rig.driver.submit(ins.move(base=80, time_ms=3000))
        queued = [rig.driver.submit(ins.move(base=b)) for b in (-10, -20, -30)]
        rig.wait_move_count(2)
        time.sleep(0.3)
        n_moves = len(rig.moves())
        outcome = rig.driver.execute(ins.stop(), 5)
        # Not behind the 3 s move (how fast: `make bench`; a busy host may take a while).
        assert outcome.ok
        for f in [running, *queued]:
            o = f.result(5)
            assert o.result is Result.CANCELLED and o.reason == "cancelled by stop"
        recs = rig.emu.wait_for(lambda rs: any(r.raw == b"STOP5" for r in rs))
        stops = [r for r in recs if r.commands and isinstance(r.commands[0], p.Stop)]
        assert [r.raw for r in stops] == [f"STOP{ch}".encode() for ch in range(6)]
        assert recs[recs.index(stops[0]) - 1].ignored == "cancelled by ESC"
        # The servo halted where it was: its pulse no longer changes.
        t_stop = stops[0].t_effect
        held = rig.emu.pulse_us(0, t_stop)
        time.sleep(0.2)
        assert rig.emu.pulse_us(0) == held
        assert rig.driver.state is State.STOPPED
        # Locked: moves refused, nothing written.
        refused = rig.driver.execute(ins.preset("ready"), 5)
        assert refused.result is Result.REFUSED and "stopped" in refused.reason
        assert len(rig.moves()) == n_moves
        # The driver read back where the servos stopped.
        rig.emu.wait_for(lambda rs: rs[-1].raw == b"QP0QP1QP2QP3QP4QP5")
        time.sleep(0.05)
        assert rig.driver.positions()["base"] == pytest.approx(
            rig.config.joints["base"].to_deg(held), abs=1.0
        )
        # Release restores.
        assert rig.driver.execute(ins.release(), 5).ok
        assert rig.driver.state is State.READY
        assert rig.driver.execute(ins.move(base=0), 10).ok
        # The outcome is handed over before the state that follows it is announced.
        want = ["stopped", "ready", "moving", "ready"]
        wait_until(lambda: state_lines(caplog)[-4:] == want, 5, f"states {want}")

    def test_stop_when_idle_locks_and_release_when_not_stopped_is_refused(self, rig: Rig) -> None:
        assert rig.driver.execute(ins.release(), 5).result is Result.REFUSED
        assert rig.driver.execute(ins.stop(), 5).ok
        assert rig.driver.state is State.STOPPED
        assert rig.driver.execute(ins.stop(), 5).ok  # again: still stopped
        assert rig.driver.execute(ins.release(), 5).ok

    def test_shutdown_is_allowed_while_stopped(self, rig: Rig) -> None:
        rig.driver.execute(ins.stop(), 5)
        outcome = rig.driver.execute(ins.shutdown(), 10)
        assert outcome.ok and outcome.reason == ""
        assert group_pulses(rig.last_move()) == pulses(rig.config, rig.config.presets["park"])


class TestShutdown:
    def test_shutdown_parks_then_ends(self, rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
        rig.driver.execute(ins.preset("ready"), 10)
        start = rig.driver.positions()
        later = rig.driver.submit(ins.move(base=50))
        outcome = rig.driver.execute(ins.shutdown(), 10)
        assert outcome.ok
        assert later.result(5).result in (Result.CANCELLED, Result.DONE)
        assert rig.driver.finished.wait(5)
        move = rig.last_move()
        park = rig.config.presets["park"]
        assert group_pulses(move) == pulses(rig.config, park)
        if later.result().result is Result.CANCELLED:
            assert move.time_ms == min_ms(rig.config, start, park, fraction=0.5)
        assert rig.emu.servo_degrees() == pytest.approx(park, abs=0.2)
        assert state_lines(caplog)[-1] == "shutting_down"
        assert rig.driver.execute(ins.move(base=1), 5).result is Result.REFUSED


class TestFault:
    def test_a_board_at_another_baud_is_said_once_at_error_with_what_was_received(
        self, config: ArmConfig, caplog: pytest.LogCaptureFixture
    ) -> None:
        caplog.set_level(logging.DEBUG, logger="al5d")
        with Emulator(config, baud=115200) as emu:
            driver = Owner.on_port(config, emu.port, 9600)
            driver.start()
            try:
                driver.wait_for_state(State.FAULT, 5)
                time.sleep(3 * config.server.reconnect_interval_s + 0.5)  # a few retries
                refused = driver.execute(ins.move(base=1), 5)
            finally:
                driver.close()
        errors = [
            r.getMessage()
            for r in logged(caplog)
            if r.levelno >= logging.WARNING and r.getMessage().startswith(("serial", "reconnect"))
        ]
        said = [m for m in errors if "does not answer like an SSC-32U at 9600 baud" in m]
        assert len(said) == 1 and "received nothing" in said[0] and "baud rate" in said[0]
        assert refused.result is Result.REFUSED
        assert "does not answer like an SSC-32U at 9600 baud" in refused.reason

    def test_a_device_that_is_not_a_board_at_reconnect_is_a_warning_and_the_fault_reason(
        self,
        config: ArmConfig,
        linked: tuple[Emulator, Owner],
        caplog: pytest.LogCaptureFixture,
    ) -> None:
        caplog.set_level(logging.DEBUG, logger="al5d")
        emu, driver = linked
        emu.inject(Fault.DISCONNECT)
        driver.submit(ins.move(base=10))  # the write fails: fault
        driver.wait_for_state(State.FAULT, 5)
        emu.version = "ARDUINO"  # another device appears at the same path
        emu.reconnect()
        time.sleep(3 * config.server.reconnect_interval_s + 0.5)
        warned = [
            r.getMessage()
            for r in logged(caplog)
            if r.levelno == logging.WARNING and "reconnect:" in r.getMessage()
        ]
        assert len(warned) == 1 and "answered VER with 'ARDUINO'" in warned[0]
        refused = driver.execute(ins.move(base=1), 5)
        assert "'ARDUINO', which is not an SSC-32U" in refused.reason
        emu.version = "SSC32-V2.50USB"  # the board is back
        driver.wait_for_state(State.READY, 5)
        assert driver.execute(ins.move(base=5), 10).ok

    def test_disconnect_during_a_move_then_recovery(
        self, config: ArmConfig, linked: tuple[Emulator, Owner]
    ) -> None:
        emu, driver = linked
        running = driver.submit(ins.move(base=80, time_ms=2000))
        queued = driver.submit(ins.move(base=0))
        emu.wait_for(lambda rs: any(r.raw.startswith(b"#0P2300") for r in rs))
        emu.inject(Fault.DISCONNECT)
        driver.wait_for_state(State.FAULT, 5)
        for f in (running, queued):
            o = f.result(5)
            assert o.result is Result.CANCELLED and "the serial link is lost" in o.reason
        refused = driver.execute(ins.move(base=10), 5)
        assert refused.result is Result.REFUSED and "serial link is lost" in refused.reason
        emu.clear_records()
        emu.reconnect()
        driver.wait_for_state(State.READY, 5)
        # No stale move replayed; positions re-learned from the board.
        time.sleep(0.1)
        assert not any(r.raw.startswith(b"#") for r in emu.records)
        assert driver.positions()["base"] == pytest.approx(
            config.joints["base"].to_deg(emu.pulse_us(0)), abs=1.0
        )
        assert driver.execute(ins.move(base=5), 10).ok

    def test_stop_during_a_fault_keeps_the_arm_locked_after_reconnect(
        self, linked: tuple[Emulator, Owner]
    ) -> None:
        emu, driver = linked
        emu.inject(Fault.DISCONNECT)
        driver.submit(ins.move(base=10))  # the write fails: fault
        driver.wait_for_state(State.FAULT, 5)
        assert driver.execute(ins.stop(), 5).ok
        emu.reconnect()
        driver.wait_for_state(State.STOPPED, 5)
        assert driver.execute(ins.release(), 5).ok

    def test_the_server_starts_without_a_board_and_connects_later(
        self, config: ArmConfig, tmp_path: object
    ) -> None:
        link = f"{tmp_path}/ssc32u"
        driver = Owner.on_port(config, link)
        driver.start()
        try:
            driver.wait_for_state(State.FAULT, 5)
            with Emulator(config, link=link) as emu:
                driver.wait_for_state(State.READY, 10)
                assert emu.servo_degrees() == pytest.approx(config.presets["park"], abs=0.5)
                driver.close()
        finally:
            driver.close()


def test_state_and_event_lines_follow_the_state_machine(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    rig.driver.execute(ins.preset("ready"), 10)
    rig.driver.submit(ins.move(base=60, time_ms=2000))
    rig.wait_move_count(3)
    rig.driver.execute(ins.stop(), 5)
    rig.driver.execute(ins.move(base=1), 5)
    rig.driver.execute(ins.release(), 5)
    rig.driver.execute(ins.shutdown(), 10)
    assert state_lines(caplog) == [
        "initializing",
        "ready",
        "moving",
        "ready",
        "moving",
        "stopped",
        "ready",
        "shutting_down",
    ]
    events = [
        r.getMessage()[len("EVENT: ") :]
        for r in logged(caplog)
        if r.getMessage().startswith("EVENT: ")
    ]
    assert events == [
        "start",
        "move_done",
        "move",
        "move_done",
        "move",
        "stop",
        "refused",
        "release",
        "shutdown",
    ]
    for r in logged(caplog):
        if r.getMessage().startswith("STATE: "):
            assert r.levelno == logging.INFO
        if r.getMessage().startswith("EVENT: "):
            assert r.levelno == logging.DEBUG
    allowed = {(a.value, b.value) for a, _, b in TRANSITIONS}
    lines = state_lines(caplog)
    assert all((a, b) in allowed for a, b in itertools.pairwise(lines))


def test_every_instruction_gets_exactly_one_outcome(rig: Rig) -> None:
    seen: list[Outcome] = []
    seen_lock = threading.Lock()
    lock = threading.Lock()

    def listen(o: Outcome) -> None:  # runs in whichever thread resolves the outcome
        with seen_lock:
            seen.append(o)

    rig.driver.outcome_listeners.append(listen)
    rng = random.Random(7)
    futures: list[Future[Outcome]] = []
    ids: list[str] = []

    def client(seed: int) -> None:
        r = random.Random(seed)
        for _ in range(60):
            roll = r.random()
            if roll < 0.1:
                instr = ins.stop()
            elif roll < 0.2:
                instr = ins.release()
            elif roll < 0.3:
                instr = ins.move(base=r.uniform(-120, 120))  # sometimes out of range
            else:
                instr = ins.move(
                    time_ms=r.choice([None, 30]), base=r.uniform(-90, 90), elbow=r.uniform(0, 135)
                )
            with lock:
                ids.append(instr.id)
                futures.append(rig.driver.submit(instr))
            time.sleep(r.uniform(0, 0.01))

    threads = [threading.Thread(target=client, args=(rng.random(),)) for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    rig.driver.execute(ins.stop(), 5)
    outcomes = [f.result(10) for f in futures]
    time.sleep(0.05)
    assert sorted(o.id for o in outcomes) == sorted(ids)
    assert sorted(o.id for o in seen if o.id in set(ids)) == sorted(ids)  # once each, no more
    assert {o.result for o in outcomes} == {Result.DONE, Result.REFUSED, Result.CANCELLED}
