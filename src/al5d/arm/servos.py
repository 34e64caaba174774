"""The hobby servos an AL5D is built with, as a table: model -> speed, torque, mass, pulses.

Speeds are the makers' figures at 6 V (seconds per 60 degrees, no load), as
used by the arm's timing model; a config may name a model (`servo: HS-805BB`)
or give `speed_deg_s` itself, which wins. Stall torques (kg cm at 6 V) and masses
are Hitec's datasheets' (../shared/reference/ssc32u-and-al5d.md): the physical twin
(`al5d.twin`) holds each joint with no more than its servo's stall torque.
"""

from __future__ import annotations

from dataclasses import dataclass

from al5d.ssc32u import facts


@dataclass(frozen=True, slots=True)
class ServoModel:
    """One servo model: its top speed and stall torque at 6 V, its mass, the pulses it takes."""

    name: str
    s_per_60deg: float  # at 6 V
    stall_kg_cm: float  # at 6 V
    mass_g: float
    #: The pulses the servo takes; the SSC-32U's whole range unless a datasheet narrows it.
    pulse_us: tuple[int, int] = (facts.PULSE_MIN_US, facts.PULSE_MAX_US)
    note: str = ""

    @property
    def speed_deg_s(self) -> float:
        return 60.0 / self.s_per_60deg


#: The AL5D's usual servos (Lynxmotion's parts list; Hitec's figures at 6 V).
SERVOS: dict[str, ServoModel] = {
    m.name: m
    for m in (
        ServoModel("HS-485HB", 0.18, 6.0, 45, note="base; wrist rotate on some builds"),
        ServoModel("HS-805BB", 0.14, 24.7, 152, note="shoulder"),
        ServoModel("HS-755HB", 0.23, 13.2, 110, note="elbow (0.28 s at 4.8 V)"),
        ServoModel("HS-645MG", 0.20, 9.6, 55, note="wrist"),
        ServoModel("HS-422", 0.16, 4.1, 46, note="gripper (0.21 s at 4.8 V)"),
        # Speed unverified (about that of the HS-485HB, the reference says).
        ServoModel("HS-225MG", 0.18, 4.8, 31, note="wrist rotate on some builds"),
    )
}
#: Each joint's servo on the usual AL5D build: what a joint configured by its speed alone
#: (`speed_deg_s`, no `servo`) is taken to have for its torque and mass.
USUAL_SERVO: dict[str, str] = {
    "base": "HS-485HB",
    "shoulder": "HS-805BB",
    "elbow": "HS-755HB",
    "wrist": "HS-645MG",
    "gripper": "HS-422",
    "wrist_rotate": "HS-485HB",
}
