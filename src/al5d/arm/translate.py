"""Degrees to pulse widths, move times and the bytes of a group move, by each joint's calibration.

Translation is on every move's path (the benchmark holds it to 10 us for a
6-joint move), so the per-joint numbers are looked up once, here, and the
move's bytes are built from the protocol's own pieces (`move_prefix`,
`time_suffix`) without re-checking what validation has checked.
"""

from __future__ import annotations

from collections.abc import Mapping

from al5d.arm.config import ArmConfig, JointSettings
from al5d.ssc32u.protocol import move_prefix, time_suffix


class Translator:
    """Degrees to pulse widths and move times for one arm."""

    def __init__(self, config: ArmConfig) -> None:
        self.joints: dict[str, JointSettings] = dict(config.joints)
        #: name -> ("#<ch>P", pulse at 0 degrees, us per degree)
        self._pulse = {
            n: (move_prefix(j.channel), j.to_us(0.0), j.us_per_deg) for n, j in self.joints.items()
        }
        self._s_per_deg = {n: 1.0 / j.speed_deg_s for n, j in self.joints.items()}

    def minimum_ms(
        self, start: Mapping[str, float | None], target: Mapping[str, float], fraction: float = 1.0
    ) -> float:
        """The physical minimum: the largest |delta| / speed over the joints that move."""
        longest = 0.0
        per_deg = self._s_per_deg
        for name, deg in target.items():
            s = start.get(name)
            if s is not None:
                t = abs(deg - s) * per_deg[name]
                if t > longest:
                    longest = t
        return longest * 1000.0 / fraction

    def encode(self, target: Mapping[str, float], time_ms: int) -> bytes:
        """The group move for `target` (degrees) arriving together in `time_ms`."""
        parts = [
            f"{self._pulse[name][0]}{self.pulse_us(name, deg)}" for name, deg in target.items()
        ]
        parts.append(time_suffix(time_ms))
        return "".join(parts).encode("ascii")

    def pulse_us(self, name: str, deg: float) -> int:
        """The pulse width a line writes for joint `name` at `deg` degrees."""
        _, u0, k = self._pulse[name]
        return int(u0 + deg * k + 0.5)

    def degrees(self, pulses: Mapping[int, int]) -> dict[str, float | None]:
        """Angles from pulse widths read back; None where the channel has no pulse yet."""
        out: dict[str, float | None] = {}
        for name, joint in self.joints.items():
            pw = pulses.get(joint.channel, 0)
            out[name] = joint.to_deg(pw) if pw else None
        return out
