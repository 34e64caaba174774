"""Translation: the fast encoder gives the protocol's own bytes, over random moves."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from al5d.arm.config import ArmConfig, load_config
from al5d.arm.translate import Translator
from al5d.ssc32u import protocol as p

CONFIG = load_config()
TRANSLATOR = Translator(CONFIG)


@st.composite
def moves(draw: st.DrawFn) -> dict[str, float]:
    names = draw(
        st.lists(st.sampled_from(list(CONFIG.joints)), min_size=1, max_size=6, unique=True)
    )
    return {
        n: draw(st.floats(*CONFIG.joints[n].range_deg, allow_nan=False, allow_infinity=False))
        for n in names
    }


@settings(max_examples=2000, deadline=None)
@given(target=moves(), time_ms=st.integers(0, p.TIME_MAX_MS))
def test_the_fast_encoder_matches_the_checked_encoder_byte_for_byte(
    target: dict[str, float], time_ms: int
) -> None:
    # Pulses by the calibration alone, rounded half up: the translator's tables must agree.
    checked = p.encode_group_move(
        [
            p.ChannelTarget(CONFIG.joints[n].channel, int(CONFIG.joints[n].to_us(d) + 0.5))
            for n, d in target.items()
        ],
        time_ms,
    )
    assert TRANSLATOR.encode(target, time_ms) == checked


def test_the_physical_minimum_is_the_slowest_joint(config: ArmConfig) -> None:
    start = {"base": 0.0, "elbow": 90.0, "wrist": None}
    target = {"base": 90.0, "elbow": 0.0, "wrist": 10.0}
    base = 90 / config.joints["base"].speed_deg_s
    elbow = 90 / config.joints["elbow"].speed_deg_s
    assert TRANSLATOR.minimum_ms(start, target) == max(base, elbow) * 1000
    assert TRANSLATOR.minimum_ms(start, target, 0.5) == max(base, elbow) * 2000


def test_degrees_from_pulses_read_back() -> None:
    degrees = TRANSLATOR.degrees({0: 1500, 1: 600, 2: 0})
    assert degrees["base"] == 0 and degrees["shoulder"] == 90 and degrees["elbow"] is None
