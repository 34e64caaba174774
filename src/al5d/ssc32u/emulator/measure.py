"""What observers measure of the emulated servos: pulses, positions, and when a move arrived.

Tests, the benchmarks and the demo's QoS table read these from any thread,
after the fact: each servo's state is remembered as every command left it.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import deque
from collections.abc import Iterable, Mapping
from typing import Protocol

from al5d.clock import now
from al5d.ssc32u import facts
from al5d.ssc32u.emulator.servo import Servo

HISTORY = 100_000  # commands remembered per channel for reach_time


class ServoJoint(Protocol):
    """A servo on a channel with a linear calibration: what the board model needs of a joint.

    The arm's joint configuration has this shape; the board does not import it.
    """

    @property
    def channel(self) -> int: ...
    @property
    def speed_us_s(self) -> float: ...
    @property
    def us_per_deg(self) -> float: ...
    def to_us(self, deg: float) -> float: ...
    def to_deg(self, us: float) -> float: ...


class ArmDescription(Protocol):
    """Joints by name and named poses: what the emulator takes of an arm's configuration."""

    @property
    def joints(self) -> Mapping[str, ServoJoint]: ...
    @property
    def presets(self) -> Mapping[str, Mapping[str, float]]: ...


@dataclasses.dataclass(frozen=True)
class Mechanics:
    """How an emulated joint truly stands on its servo, where the configuration is wrong
    about it: the horn seated `offset_us` off (to stand at an angle the joint needs that
    much more pulse than the calibration says), and `reversed` when the servo turns the
    joint the other way (mirrored about the board's centre pulse). What calibration finds.
    """

    offset_us: float = 0.0
    reversed: bool = False

    def true_us(self, servo_us: float) -> float:
        """The pulse the calibration would need for the angle a servo at `servo_us` gives."""
        us = servo_us - self.offset_us
        return 2 * facts.PULSE_CENTRE_US - us if self.reversed else us


TRUE = Mechanics()


class ServoObserver:
    """The servos as observers see them; the board's model keeps them under `_lock`."""

    config: ArmDescription | None
    _lock: threading.RLock
    _servos: dict[int, Servo]
    #: Joint name -> how it truly stands on its servo (`Mechanics`); absent: as configured.
    mechanics: dict[str, Mechanics]

    def __init__(self) -> None:
        self.mechanics = {}
        # Per channel: the servo as each command left it, to answer "when did that move arrive".
        self._history: dict[int, deque[Servo]] = {}

    def pulse_us(self, channel: int, t: float | None = None) -> float:
        """The pulse the board puts out on `channel` (0 when off)."""
        with self._lock:
            servo = self._servos.get(channel)
            return servo.pulse_at(now() if t is None else t) if servo else 0.0

    def servo_us(self, channel: int, t: float | None = None) -> float:
        """Where the physical servo on `channel` is, as a pulse width."""
        with self._lock:
            servo = self._servos.get(channel)
            if servo is None:
                return 0.0
            return servo.position_at(max(now() if t is None else t, servo.t_position))

    def servo_degrees(self, t: float | None = None) -> dict[str, float]:
        """Every configured joint's physical angle, through the calibration."""
        if self.config is None:
            return {}
        return {
            name: j.to_deg(self.servo_us(j.channel, t)) for name, j in self.config.joints.items()
        }

    def joint_degrees(self, t: float | None = None) -> dict[str, float]:
        """Every configured joint's true angle: where the emulated arm stands, which differs
        from `servo_degrees` (the calibration's reading) by the joint's `mechanics`."""
        if self.config is None:
            return {}
        return {
            name: j.to_deg(self.mechanics.get(name, TRUE).true_us(self.servo_us(j.channel, t)))
            for name, j in self.config.joints.items()
        }

    def _joints(self, joints: Iterable[str] | None, what: str) -> list[tuple[str, ServoJoint]]:
        if self.config is None:
            raise ValueError(f"{what} needs the arm configuration")
        names = list(joints) if joints is not None else list(self.config.joints)
        return [(name, self.config.joints[name]) for name in names]

    def settle_time(self, tol_deg: float = 1.0, joints: Iterable[str] | None = None) -> float:
        """When every joint came (or will come) within `tol_deg` of its final target, to stay."""
        chosen = self._joints(joints, "settle_time")
        with self._lock:
            return max(
                self._servos[j.channel].settle_time(tol_deg * abs(j.us_per_deg)) for _, j in chosen
            )

    def reach_time(
        self, t_effect: float, tol_deg: float = 1.0, joints: Iterable[str] | None = None
    ) -> float | None:
        """When the move that took effect at `t_effect` had every joint within `tol_deg`.

        None if a later command (a move or a STOP) changed one of those joints first:
        that move never arrived. Works after the fact, from the servos' history.
        """
        chosen = self._joints(joints, "reach_time")
        latest = t_effect
        with self._lock:
            for _, joint in chosen:
                snap, later = self._snapshot(joint.channel, t_effect)
                if snap is None:
                    continue  # this joint was not part of that move
                settle = snap.settle_time(tol_deg * abs(joint.us_per_deg))
                if later is not None and later < settle:
                    return None
                latest = max(latest, settle)
        return latest

    def trajectory(
        self, t_effect: float, times: Iterable[float], joints: Iterable[str] | None = None
    ) -> dict[str, tuple[list[float], list[float]]]:
        """Per joint, the commanded pulse and the servo position (both in degrees) at `times`,
        as the move that took effect at `t_effect` left them (for plots)."""
        chosen = self._joints(joints, "trajectory")
        ts = list(times)
        out: dict[str, tuple[list[float], list[float]]] = {}
        with self._lock:
            for name, joint in chosen:
                snap, _ = self._snapshot(joint.channel, t_effect)
                if snap is None:
                    continue
                out[name] = (
                    [joint.to_deg(snap.pulse_at(t)) for t in ts],
                    [joint.to_deg(snap.position_at(t)) for t in ts],
                )
        return out

    def _snapshot(self, channel: int, t_effect: float) -> tuple[Servo | None, float | None]:
        """The servo as the command at `t_effect` left it, and when the next command came."""
        history = list(self._history.get(channel, ()))
        i = next((k for k, snap in enumerate(history) if snap.t0 == t_effect), None)
        if i is None:
            return None, None
        return history[i], (history[i + 1].t0 if i + 1 < len(history) else None)

    def _remember(self, channel: int, servo: Servo) -> None:
        history = self._history.setdefault(channel, deque(maxlen=HISTORY))
        history.append(dataclasses.replace(servo))
