"""A driver on an emulated board, and what the driver tests read from it."""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from al5d.arm.config import ArmConfig
from al5d.arm.driver import ArmDriver
from al5d.arm.states import State
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Record


@dataclass
class Rig:
    driver: ArmDriver
    emu: Emulator
    config: ArmConfig

    def moves(self) -> list[Record]:
        return [r for r in self.emu.records if any(isinstance(c, p.GroupMove) for c in r.commands)]

    def last_move(self) -> p.GroupMove:
        cmd = self.moves()[-1].commands[0]
        assert isinstance(cmd, p.GroupMove)
        return cmd

    def wait_move_count(self, n: int, timeout: float = 5.0) -> None:
        self.emu.wait_for(
            lambda rs: sum(any(isinstance(c, p.GroupMove) for c in r.commands) for r in rs) >= n,
            timeout,
        )


#: The link checks the driver makes on its own: `Q`, or `QP` of one channel (which also
#: finds a board that has reset).
LINK_CHECK = re.compile(rb"Q|QP\d{1,2}")


def written(records: list[Record]) -> list[bytes]:
    """The lines the board received, but the link checks the driver makes on its own."""
    return [r.raw for r in records if not LINK_CHECK.fullmatch(r.raw)]


def pulses(config: ArmConfig, pose: dict[str, float]) -> dict[int, int]:
    return {config.joints[j].channel: round(config.joints[j].to_us(d)) for j, d in pose.items()}


def group_pulses(move: p.GroupMove) -> dict[int, int]:
    return {t.channel: t.pulse_us for t in move.targets}


def min_ms(
    config: ArmConfig, start: dict[str, float], target: dict[str, float], fraction: float = 1.0
) -> int:
    longest = max(
        abs(d - start[j]) / (config.joints[j].speed_deg_s * fraction) for j, d in target.items()
    )
    return math.ceil(longest * 1000 - 1e-9)


def make_rig(config: ArmConfig) -> Iterator[Rig]:
    emu = Emulator(config).start()
    driver = ArmDriver(config, emu.port)
    driver.start()
    try:
        driver.wait_for_state(State.READY, 10)
        yield Rig(driver, emu, config)
    finally:
        driver.close()
        emu.close()


def logged(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    """Log records of the fixture's setup and of the test itself."""
    return caplog.get_records("setup") + caplog.get_records("call")


def state_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()[len("STATE: ") :]
        for r in logged(caplog)
        if r.getMessage().startswith("STATE: ")
    ]
