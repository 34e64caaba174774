"""The hobby servos an AL5D is built with, as a table: model -> speed and pulse range.

Speeds are the makers' figures at 6 V (seconds per 60 degrees, no load), as
used by the arm's timing model; a config may name a model (`servo: HS-805BB`)
or give `speed_deg_s` itself, which wins.
"""

from __future__ import annotations

from dataclasses import dataclass

from al5d.ssc32u import facts


@dataclass(frozen=True, slots=True)
class ServoModel:
    """One servo model: its top speed at 6 V and the pulse widths it takes."""

    name: str
    s_per_60deg: float  # at 6 V
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
        ServoModel("HS-485HB", 0.18, note="base; wrist rotate on some builds"),
        ServoModel("HS-805BB", 0.14, note="shoulder"),
        ServoModel("HS-755HB", 0.23, note="elbow (0.28 s at 4.8 V)"),
        ServoModel("HS-645MG", 0.20, note="wrist"),
        ServoModel("HS-422", 0.16, note="gripper (0.21 s at 4.8 V)"),
    )
}
