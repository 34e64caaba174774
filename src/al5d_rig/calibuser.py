"""The user of a calibration, played by a test: one who sees where the emulated joint truly
stands (`Emulator.joint_degrees`), never the offsets it was given."""

from __future__ import annotations

from dataclasses import dataclass

from al5d.arm.config import JointSettings
from al5d.ssc32u.emulator import Mechanics
from al5d.ssc32u.facts import PULSE_CENTRE_US


def truth(joint: JointSettings, mech: Mechanics, deg: float) -> float:
    """The pulse that truly puts the emulated joint at `deg`."""
    us = joint.to_us(deg)
    return (2 * PULSE_CENTRE_US - us if mech.reversed else us) + mech.offset_us


@dataclass
class User:
    """At one reference: nudges toward where the model shows the joint, about as many steps
    as it looks off (as one types `+12`), the other way once a nudge took it further off (a
    reversed joint), a smaller nudge after a refusal; content within half a step."""

    joint: JointSettings
    reference_deg: float
    step_us: int
    way: int = 1
    steps: int = 0

    def nudge(self, true_deg: float) -> int | None:
        """The signed steps to nudge the joint standing at `true_deg`; None: it is there."""
        off = self.reference_deg - true_deg
        if abs(off) <= self.step_us / 2 / abs(self.joint.us_per_deg) + 1e-6:
            return None
        self.steps = max(1, round(abs(off) * abs(self.joint.us_per_deg) / self.step_us))
        return self.steps * self.way if off > 0 else -self.steps * self.way

    def refused(self, true_deg: float) -> int:
        """The nudge was refused (beyond a range): a smaller one the same way."""
        assert self.steps > 1, "a single step refused"
        self.steps //= 2
        off = self.reference_deg - true_deg
        return self.steps * self.way if off > 0 else -self.steps * self.way

    def saw(self, before_deg: float, after_deg: float) -> None:
        if abs(self.reference_deg - after_deg) > abs(self.reference_deg - before_deg):
            self.way = -self.way
