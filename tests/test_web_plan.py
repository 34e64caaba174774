"""The web view's pure parts: targets (the ghost and the local precheck), the debounce of
slider drags, the outcome log's escaping, the plot's history, and the websocket guard."""

from __future__ import annotations

import math

import pytest

from al5d.arm import instruction as ins
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome, Result
from al5d.model import tool_position
from al5d.web.guard import allowed_hosts, connection_problem, is_loopback
from al5d.web.plan import JointHistory, OutcomeLog, Planner, Target


@pytest.fixture
def planner(config: ArmConfig) -> Planner:
    return Planner(config)


@pytest.fixture
def ready(config: ArmConfig) -> dict[str, float]:
    return dict(config.presets["ready"])


def test_a_preset_and_a_move_leave_the_arm_where_they_say(
    planner: Planner, ready: dict[str, float], config: ArmConfig
) -> None:
    target = planner.target_of(ins.preset("straight_up"), ready)
    assert isinstance(target, Target) and target.degrees == config.presets["straight_up"]
    target = planner.target_of(ins.move(base=30, elbow=45), ready)
    assert isinstance(target, Target)
    assert target.degrees == {**ready, "base": 30, "elbow": 45}
    assert planner.target_of(ins.stop(), ready) is None
    assert planner.target_of(ins.release(), ready) is None


def test_the_local_reason_is_the_servers(planner: Planner, ready: dict[str, float]) -> None:
    assert planner.target_of(ins.move(elbow=150), ready) == (
        "elbow: 150 deg is outside the range 0..135"
    )
    reason = planner.target_of(ins.move_to(500, 0, 100), ready)
    assert isinstance(reason, str) and "out of reach" in reason


def test_a_straight_line_has_its_path_from_the_tool(
    planner: Planner, ready: dict[str, float]
) -> None:
    target = planner.target_of(ins.move_to(230, -120, 120, line=True), ready)
    assert isinstance(target, Target)
    start = tool_position(planner.geometry, ready)
    assert target.line[0] == pytest.approx(start)
    assert target.line[-1] == pytest.approx((0.230, -0.120, 0.120), abs=1e-6)
    assert tool_position(planner.geometry, target.degrees) == pytest.approx(target.line[-1])
    joint = planner.target_of(ins.move_to(230, -120, 120), ready)
    assert isinstance(joint, Target) and joint.line == ()


def test_outcomes_are_escaped_newest_first() -> None:
    log = OutcomeLog(size=2)
    log.add(Outcome("a", "move", Result.DONE, elapsed_ms=120))
    log.add(Outcome("b", "<img src=x onerror=alert(1)>", Result.REFUSED, "unknown <b>"))
    log.add(Outcome("c", "stop", Result.DONE))
    text = log.html()
    assert "<img" not in text and "&lt;img src=x onerror=alert(1)&gt;" in text
    assert text.index("[c]") < text.index("[b]") and "[a]" not in text


def test_the_history_keeps_the_last_seconds() -> None:
    h = JointHistory(("base", "elbow"), seconds=10)
    empty = h.series(0.0)
    assert len(empty) == 3 and all(len(a) == 2 for a in empty)
    for k in range(300):
        h.add(k * 0.05, {"base": float(k), "elbow": 1.0})
    ts, base, elbow = h.series(15.0)
    assert ts[0] >= -10 and ts[-1] == pytest.approx(-0.05)
    assert base[-1] == 299 and set(elbow) == {1.0}
    h.add(15.0, {"base": 1.0})
    assert math.isnan(h.series(15.0)[2][-1])  # a joint not given is a gap, not a zero


def test_the_guard_lets_only_the_page_in() -> None:
    loop = allowed_hosts("127.0.0.1")
    ok = connection_problem("http://127.0.0.1:8080", "127.0.0.1:8080", loop)
    assert ok is None
    assert connection_problem("http://localhost:8080", "localhost:8080", loop) is None
    assert connection_problem("http://[::1]:8080", "[::1]:8080", loop) is None
    assert "not this page" in (
        connection_problem("http://evil.example", "127.0.0.1:8080", loop) or ""
    )
    # DNS rebinding: the attacker's name resolved to us; Origin and Host agree, the name does not.
    rebound = connection_problem("http://evil.example:8080", "evil.example:8080", loop)
    assert rebound is not None and "evil.example" in rebound
    assert connection_problem(None, "127.0.0.1:8080", loop) is not None
    assert connection_problem("null", "127.0.0.1:8080", loop) is not None
    anywhere = allowed_hosts("0.0.0.0")
    assert anywhere is None
    assert connection_problem("http://192.0.2.7:8080", "192.0.2.7:8080", anywhere) is None
    assert connection_problem("http://evil.example:8080", "evil.example:8080", anywhere)
    lab = allowed_hosts("arm.lab")
    assert connection_problem("http://arm.lab:8080", "arm.lab:8080", lab) is None
    assert is_loopback("localhost") and is_loopback("127.0.0.2") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.7")


def test_a_trajectory_leaves_the_arm_at_its_last_point(
    planner: Planner, ready: dict[str, float]
) -> None:
    points = (
        ins.Point((("base", 10.0),), 1000.0),
        ins.Point((("base", -30.0), ("elbow", 60.0)), 2000.0),
    )
    target = planner.target_of(ins.Instruction(ins.Kind.TRAJECTORY, points=points), ready)
    assert isinstance(target, Target)
    assert target.degrees == {**ready, "base": -30.0, "elbow": 60.0}
