"""A board and its physical twin in this process, on a clock the caller keeps.

The board (`al5d.ssc32u.emulator.Board`, no pty) takes each line at the time it is given,
the twin follows its pulses (`Board.observe_pulses`) and is run frame by frame as fast as
it computes: a test or a benchmark of the physics needs neither real time nor a process.
"""

from __future__ import annotations

from collections.abc import Mapping

from al5d.arm.config import ArmConfig
from al5d.model import forward, solve
from al5d.ssc32u.emulator import Mechanics
from al5d.ssc32u.emulator.board import Board
from al5d.ssc32u.protocol import ChannelTarget, encode_group_move
from al5d.twin.physics import FRAME_S, Held, Twin
from al5d.twin.scene import Scene


class TwinRig:
    """`config`'s arm on a board whose twin stands in `scene`, both from the board's power-up."""

    def __init__(
        self,
        config: ArmConfig,
        scene: Scene,
        mechanics: Mapping[str, Mechanics] | None = None,
    ) -> None:
        self.config = config
        self.board = Board(config, mechanics=mechanics)
        self.t = start = self.board.powered_at
        self.twin = Twin(
            config, scene, start=start, pose=self.board.joint_degrees(start), mechanics=mechanics
        )
        self.board.observe_pulses(self.twin.follow)
        self.lines: list[bytes] = []
        self.held: list[Held] = []

    def write(self, line: bytes, after_s: float = 0.0) -> None:
        """The board takes `line` (without its CR) `after_s` from now, the twin run to then."""
        self.run(after_s)
        self.lines.append(line)
        self.board.execute(line, self.t)

    def move(self, degrees: Mapping[str, float], time_ms: int | None = None) -> bytes:
        """A group move to `degrees` (the arm's), in `time_ms`; its bytes."""
        targets = [
            ChannelTarget(self.config.joints[n].channel, round(self.config.joints[n].to_us(d)))
            for n, d in degrees.items()
        ]
        line = encode_group_move(targets, time_ms).rstrip(b"\r")
        self.write(line)
        return line

    def move_to(
        self,
        xyz_mm: tuple[float, float, float],
        pitch_deg: float = -90.0,
        time_ms: int = 1000,
        steps: int = 1,
        **joints: float,
    ) -> None:
        """The tool to `xyz_mm` (base frame) in `steps` group moves along the straight line
        from where the board's pulses put it (each `time_ms`, the twin run through each),
        other joints (the gripper) as given."""
        here = forward(self.config.model.geometry, self.commanded())
        start = [v * 1000 for v in here.position]
        for k in range(1, steps + 1):
            point = [a + (b - a) * k / steps for a, b in zip(start, xyz_mm, strict=True)]
            x, y, z = (v / 1000 for v in point)
            degrees = solve(self.config.model, x, y, z, pitch_deg)
            self.move({**degrees, **joints}, time_ms)
            self.run(time_ms / 1000)

    def commanded(self) -> dict[str, float]:
        """The arm's degrees the board's pulses stand for now."""
        return {
            name: joint.to_deg(self.board.pulse_us(joint.channel, self.t) or joint.to_us(0))
            for name, joint in self.config.joints.items()
        }

    def run(self, seconds: float) -> list[Held]:
        """The twin run `seconds` on from now; what it found held."""
        self.t += seconds
        found = self.twin.advance_to(self.t)
        self.held += found
        return found

    def settle(self, seconds: float = 1.0) -> list[Held]:
        """As `run`: time for the arm to get where it was sent (or be held short of it)."""
        return self.run(max(seconds, FRAME_S))
