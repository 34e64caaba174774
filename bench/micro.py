"""In-process figures: translation, the serial write call, and the owner's throughput."""

from __future__ import annotations

import math
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from stats import figure

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.states import State
from al5d.arm.translate import Translator
from al5d.arm.validate import Limits, judge
from al5d.owner.loop import Owner
from al5d.ssc32u.driver import SSC32U
from al5d_rig.proc import Proc

WARMUP = 2000


def translation(config: ArmConfig, n: int = 20000) -> dict[str, Any]:
    """Instruction -> bytes: validation, the time model and the encoding of a 6-joint move."""
    limits, translator = Limits.of(config), Translator(config)
    pose = dict(config.presets["park"])
    instrs = [
        ins.move(
            base=(i % 170) - 85,
            shoulder=10,
            elbow=60 + i % 50,
            wrist=-20,
            gripper=30,
            wrist_rotate=5,
        )
        for i in range(64)
    ]
    samples = []
    clock = time.perf_counter_ns
    for i in range(n + WARMUP):
        instr = instrs[i % 64]
        t0 = clock()
        ticket = judge(instr, limits)
        assert not isinstance(ticket, str)
        target = ticket.steps[0].target
        minimum = translator.minimum_ms(pose, target)
        data = translator.encode(target, max(instr.time_ms or 0, math.ceil(minimum)))
        t1 = clock()
        if i >= WARMUP:
            samples.append((t1 - t0) / 1e6)
    assert data.endswith(b"\r")
    return figure("translation", samples, unit="instruction -> bytes, 6-joint move")


@contextmanager
def emulator_process(workdir: Path, baud: int = 115200) -> Iterator[str]:
    """`al5d emulator` in its own process (so that it does not share our GIL); yields its port."""
    link = workdir / f"emulator-{baud}"
    proc = Proc("emulator", "--baud", str(baud), "--link", str(link))
    try:
        proc.out.wait_for(str(link), 20)
        yield str(link)
    finally:
        proc.popen.send_signal(signal.SIGTERM)
        proc.wait(20)


def serial_write(workdir: Path, n: int = 2000, baud: int = 115200) -> dict[str, Any]:
    """The write call of the low-level driver on a real pty (the emulator reads the other end),
    and its floor: pyserial's own write of the same bytes on the same port, the two taken in
    turn so that the machine's noise falls on both. Each write comes once the wire has
    carried the one before: the driver holds a move that finds more than its horizon of
    bytes still to go (`WIRE_HORIZON_S`), which would time the wire, not the call."""
    data = b"#0P1500#1P1500#2P1500#3P1500#4P1500#5P1500T500\r"
    gap = 1.5 * len(data) * 10 / baud
    ours: list[float] = []
    floor: list[float] = []
    clock = time.perf_counter_ns
    with emulator_process(workdir, baud) as port, SSC32U(port, baud) as board:
        # The driver's own pyserial port (not public): a second open of the pty is refused
        # (the driver holds it exclusively).
        bare = board.transport._ser  # type: ignore[attr-defined]
        for i in range(n + 100):
            for write, samples in ((board.write, ours), (bare.write, floor)):
                t0 = clock()
                write(data)
                t1 = clock()
                if i >= 100:
                    samples.append((t1 - t0) / 1e6)
                time.sleep(gap)
    out = figure("serial write", ours, unit=f"{len(data)}-byte group move")
    out["floor"] = figure("serial write, pyserial alone", floor, unit="the same bytes")
    return out


def throughput_in_process(config: ArmConfig, workdir: Path, n: int = 50000) -> dict[str, Any]:
    """Instructions per second the owner accepts (taken, judged and queued: until `sync`
    says it has taken the last), and none lost."""
    big = config.model_copy(
        update={"server": config.server.model_copy(update={"queue_capacity": n + 10})}
    )
    with emulator_process(workdir) as port:
        driver = Owner.on_port(big, port, 115200)
        driver.start()
        driver.wait_for_state(State.READY, 10)
        instrs = [ins.move(base=(i % 170) - 85, elbow=60 + i % 50) for i in range(n)]
        for instr in instrs[:2000]:  # warm-up, then cleared
            driver.submit(instr)
        driver.execute(ins.stop(), 5)
        driver.execute(ins.release(), 5)
        instrs = [ins.move(base=(i % 170) - 85, elbow=60 + i % 50) for i in range(n)]
        t0 = time.perf_counter()
        futures = [driver.submit(instr) for instr in instrs]
        driver.sync(60)
        elapsed = time.perf_counter() - t0
        driver.execute(ins.stop(), 5)
        outcomes = [f.result(30) for f in futures]
        driver.close()
    refused = sum(o.result is ins.Result.REFUSED for o in outcomes)
    return {
        "name": "throughput in-process",
        "rate_per_s": n / elapsed,
        "n": n,
        "lost": n - len(outcomes),
        "refused": refused,
    }
