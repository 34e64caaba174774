"""A driver on an emulated board, and what the driver tests read from it."""

from __future__ import annotations

import logging
import math
import re
import socket
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import pytest

from al5d.arm.config import ArmConfig, on_embedded_board
from al5d.arm.states import State
from al5d.model import forward
from al5d.model.transforms import Vec3
from al5d.owner.client import Remote
from al5d.owner.loop import Owner
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Record
from al5d.ssc32u.emulator.board import Board
from al5d.ssc32u.facts import CHANNELS, QP_RESOLUTION_US


@dataclass
class Rig:
    driver: Owner
    emu: Emulator
    config: ArmConfig

    def moves(self) -> list[Record]:
        return [r for r in self.emu.records if any(isinstance(c, p.GroupMove) for c in r.commands)]

    def last_move(self) -> p.GroupMove:
        cmd = self.moves()[-1].commands[0]
        assert isinstance(cmd, p.GroupMove)
        return cmd

    def remote(self, **kwargs: Any) -> Remote:
        """A client of the rig's owner over a lane of its own (a socket pair), as the ROS
        bridges are."""
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        self.driver.adopt(ours)
        return Remote(theirs, **kwargs)

    def wait_move_count(self, n: int, timeout: float = 5.0) -> None:
        self.emu.wait_for(
            lambda rs: sum(any(isinstance(c, p.GroupMove) for c in r.commands) for r in rs) >= n,
            timeout,
        )


#: What a fixture would have a failure's reader know (a rig's processes, a page): called when
#: the test's call fails, its text a section of the failure's report (tests/conftest.py).
ON_FAILURE = pytest.StashKey[Callable[[], str]]()

#: The link checks the driver makes on its own: `Q`, or `QP` of one channel (which also
#: finds a board that has reset).
LINK_CHECK = re.compile(rb"Q|QP\d{1,2}")


def written(records: list[Record]) -> list[bytes]:
    """The lines the board received, but the link checks the driver makes on its own."""
    return [r.raw for r in records if not LINK_CHECK.fullmatch(r.raw)]


def group_moves(records: Iterable[Record]) -> list[p.GroupMove]:
    """The group moves in `records` (an emulator's, or a board process's), in order."""
    return [c for r in records for c in r.commands if isinstance(c, p.GroupMove)]


def holds(moves: list[p.GroupMove], points: int, before: Mapping[int, float]) -> int:
    """How many of `moves`, the group moves written for one motion of `points` points, come
    before its points to hold joints known only within a step of `QP` (after a stop) where
    the core judged them from (`al5d.arm.running.plan`): 1 where there is one line more than
    points and the first is untimed and puts each of its channels within a step of `QP`
    of its pulse `before` the motion (`board_pulses`), else 0. Tests after a stop count
    points without it (seen in CI: a fuzz case's 1-point trajectory wrote 2 group moves
    after a halted one). A first point at time 0 where the arm is looks the same: a test
    with one checks where the arm ends as well."""
    if len(moves) != points + 1 or moves[0].time_ms is not None:
        return 0
    return int(
        all(
            # A step, and a microsecond of the degrees' round trip.
            abs(t.pulse_us - before.get(t.channel, -math.inf)) <= QP_RESOLUTION_US + 1
            for t in moves[0].targets
        )
    )


def board_pulses(board: Board) -> dict[int, float]:
    """The pulse `board` (an emulator, or a board process's `model()`) puts out on each of
    its channels now (0 when off)."""
    return {ch: board.pulse_us(ch) for ch in CHANNELS}


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
    """A driver on the emulator, both threads of this process, as a server on its embedded
    board is (`on_embedded_board`): an answer late from a board that shares this
    interpreter is this host's stall, never a cable. (Seen beside two busy loops: a test
    handing over 3,000 moves from its own thread, the board starved, and a lost link, "no
    answer to QP0QP1QP, asked twice, 102 ms late".)"""
    emu = Emulator(config).start()
    driver = Owner.on_port(on_embedded_board(config), emu.port)
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


def tip(rig: Rig) -> Vec3:
    """Where the emulated servos put the tool tip now (metres, base_link)."""
    return forward(rig.config.model.geometry, rig.emu.servo_degrees()).position


def executed_tips(rig: Rig, moves: list[Record], t_end: float, dt: float = 0.0005) -> list[Vec3]:
    """Where the emulated servos put the tip every `dt`, from the first move's effect to
    `t_end`: each move's span from the servo model as that move left it (exact, after the
    fact: no sampling thread to fall behind on a loaded machine)."""
    pose = rig.emu.servo_degrees()  # joints no move touches stay where they are
    tips = []
    for i, rec in enumerate(moves):
        t1 = moves[i + 1].t_effect if i + 1 < len(moves) else t_end
        times = [rec.t_effect + k * dt for k in range(int((t1 - rec.t_effect) / dt) + 1)]
        times += [t1] if i + 1 == len(moves) else []
        span = rig.emu.trajectory(rec.t_effect, times)
        for k in range(len(times)):
            pose = {**pose, **{j: servo[k] for j, (_, servo) in span.items()}}
            tips.append(forward(rig.config.model.geometry, pose).position)
    return tips


def settled_tip(rig: Rig) -> Vec3:
    time.sleep(max(0.0, rig.emu.settle_time(0.01) - time.monotonic()) + 0.02)
    return tip(rig)
