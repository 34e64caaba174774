"""Faults injected at chosen moments, and what the driver made of them (issue 9's fault suite).

Each trial: a driver on an emulated board behind a link, a fault at a moment
(idle, mid-move with moves queued, during a stop, during the start-up or the
shutdown park), then the board back at the same path. It measures the time to
`fault` and back to `ready` (or `stopped`), and checks that every pending
instruction got exactly one outcome, that no move was replayed and that the
pose was learnt again from the board.
"""

from __future__ import annotations

import random
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome, Result
from al5d.arm.states import State
from al5d.owner.loop import Owner
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.emulator import Emulator, Fault
from al5d_rig.armrig import pulses

MOMENTS = ("idle", "mid-move", "during-stop", "startup-park", "shutdown-park")


@dataclass
class Trial:
    moment: str
    fault: str
    to_fault_s: float = float("nan")
    to_back_s: float = float("nan")
    #: Of `to_back_s`, the start-up park that runs again (the servos' travel, not the link's).
    park_s: float = 0.0
    pending: int = 0
    outcomes: int = 0
    replayed: int = 0
    pose_error_deg: float = float("nan")
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.outcomes == self.pending and self.replayed == 0 and not self.notes


def _moves(emu: Emulator, after: float) -> list[bytes]:
    return [r.raw for r in emu.records if r.t_effect > after and r.raw.startswith(b"#")]


def _await(driver: Owner, states: tuple[State, ...], timeout: float) -> float:
    """Seconds until one of `states` is announced (raises TimeoutError after `timeout`)."""
    t0 = time.monotonic()
    while driver.announced not in states:
        if time.monotonic() - t0 > timeout:
            raise TimeoutError(f"none of {[s.value for s in states]} in {timeout} s")
        time.sleep(0.002)
    return time.monotonic() - t0


def run_trial(
    config: ArmConfig, workdir: Path, moment: str, fault: Fault, rng: random.Random
) -> Trial:
    trial = Trial(moment, fault.value)
    link = workdir / f"ssc32u-{moment}-{fault.value}"
    with Emulator(config, link=link) as emu:
        if moment == "startup-park":
            with SSC32U(str(link)) as board:  # a board in use: the start-up park takes time
                board.move(pulses(config, config.presets["straight_up"]))
            emu.wait_for(lambda rs: any(r.raw.startswith(b"#0P") for r in rs))
        driver = Owner.on_port(config, str(link))
        driver.start()
        futures: list[Future[Outcome]] = []
        try:
            if moment == "startup-park":
                emu.wait_for(lambda rs: sum(r.raw.startswith(b"#") for r in rs) >= 2, 10)
                time.sleep(rng.uniform(0.05, 0.4))
            else:
                driver.wait_for_state(State.READY, 10)
            if moment == "idle":
                time.sleep(rng.uniform(0.0, 0.6))
            elif moment == "mid-move":
                futures.append(
                    driver.submit(ins.move(base=80, shoulder=40, elbow=60, time_ms=2000))
                )
                futures += [driver.submit(ins.move(base=b)) for b in (-30, 30, 0)]
                emu.wait_for(lambda rs: any(b"T2000" in r.raw for r in rs), 5)
                time.sleep(rng.uniform(0.05, 1.5))
            elif moment == "during-stop":
                futures.append(driver.submit(ins.move(base=80, time_ms=2000)))
                emu.wait_for(lambda rs: any(b"T2000" in r.raw for r in rs), 5)
                time.sleep(rng.uniform(0.05, 0.5))
                futures.append(driver.submit(ins.stop()))
            elif moment == "shutdown-park":
                assert driver.execute(ins.preset("straight_up"), 10).ok
                futures.append(driver.submit(ins.shutdown()))
                emu.wait_for(lambda rs: rs[-1].raw.startswith(b"#") if rs else False, 5)
                time.sleep(rng.uniform(0.05, 0.3))
            emu.inject(fault)
            try:
                trial.to_fault_s = _await(driver, (State.FAULT,), 10)
            except TimeoutError as e:
                trial.notes.append(f"no fault: {e}")
            trial.pending = len(futures)
            for f in futures:
                try:
                    f.result(5)
                    trial.outcomes += 1
                except TimeoutError:
                    trial.notes.append("an instruction got no outcome")
            if moment == "shutdown-park":
                outcome = futures[-1].result()
                if outcome.result is not Result.CANCELLED or "not parked" not in outcome.reason:
                    trial.notes.append(f"shutdown said: {outcome}")
                driver.finished.wait(5)
                return trial
            t_back = time.monotonic()
            if fault is Fault.DISCONNECT:
                emu.reconnect()
            else:
                emu.clear()
            try:
                trial.to_back_s = _await(driver, (State.READY, State.STOPPED), 10)
            except TimeoutError as e:
                trial.notes.append(f"not back: {e}")
            parks = [r.t_effect for r in emu.records if r.t_effect > t_back and r.raw[:1] == b"#"]
            if moment == "startup-park" and parks and trial.to_back_s == trial.to_back_s:
                trial.park_s = t_back + trial.to_back_s - parks[0]
            time.sleep(0.3)  # anything the driver would replay, it would have written by now
            written = _moves(emu, t_back)
            expected = (
                1 if moment == "startup-park" else 0
            )  # an unfinished start-up park runs again
            trial.replayed = max(0, len(written) - expected)
            actual = emu.servo_degrees()
            believed = driver.positions()
            trial.pose_error_deg = max(abs(actual[j] - believed[j]) for j in actual)
            if trial.pose_error_deg > 1.0:
                trial.notes.append(f"pose not re-learnt: {believed} vs board {actual}")
        finally:
            driver.close(10)
    return trial
