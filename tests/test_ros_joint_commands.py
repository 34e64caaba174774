"""ros2_control without C++ (issue 24, item 4): the server takes the commands of ros-controls'
topic-based hardware (`JointStateTopicSystem`) on `<ns>/joint_commands` and publishes the
joint states it reads on `<ns>/joint_states`.

The peer here publishes as that hardware does: sensor_msgs/JointState with the URDF's
joint names and position commands in radians (metres for the gripper's gap), header
stamped, on a reliable writer that keeps the last one. Over real DDS against
`al5d serve` in its own process, the emulated board in this one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from typing import Any

import pytest

from al5d.arm.config import ArmConfig
from al5d.ros.node import COMMAND_REFUSALS_EVERY_S
from al5d_rig.armrig import group_moves, group_pulses, pulses
from al5d_rig.proc import patient_config
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Commanded, commanded

NAMESPACE = "cell"
#: The joints of the AL5D's ros2_control tag, in its order (docs/moveit.md's xacro).
COMMANDED = ("base", "shoulder", "elbow", "wrist", "wrist_rotate", "gripper")


@pytest.fixture(scope="module")
def served(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Commanded]:
    workdir = tmp_path_factory.mktemp("commands")
    # The model's joint names, without the namespace's prefix (test_ros_prefix has it).
    none = ("-p", "server.joint_prefix:=''")
    with commanded(config, workdir, "al5d_hardware_peer", NAMESPACE, patient_config(), *none) as s:
        yield s


def settled(s: Commanded, degrees: Mapping[str, float], timeout: float = 20.0) -> None:
    """Until the emulated servos stand at `degrees` and the joint states say so."""
    urdf = s.config.model.to_urdf(dict(degrees))

    def there() -> bool:
        if not all(abs(s.emu.servo_degrees()[j] - d) < 0.2 for j, d in degrees.items()):
            return False
        last = s.peer.joint_states[-1:]
        return bool(last) and all(
            abs(v - urdf[n]) < 1e-3
            for n, v in zip(last[0].name, last[0].position, strict=True)
            if n in urdf
        )

    try:
        wait_until(there, timeout, f"the arm at {dict(degrees)}")
    except AssertionError as e:
        raise AssertionError(f"{e}: {said(s)}") from e


def said(s: Commanded) -> str:
    """Where the servos are, what the server said last and where its threads are, for a
    failure's reader (seen once beside two busy loops: neither a command nor a move on the
    instruction topic moved the arm for 40 s, and the server said nothing)."""
    return (
        f"servos {s.emu.servo_degrees()}, states {s.peer.joint_states[-1:]}, "
        f"server {s.proc.err.drain(0)[-15:]}\n{s.proc.stacks()}"
    )


def test_a_joint_command_moves_the_arm_and_the_joint_states_say_where(served: Commanded) -> None:
    target = {"base": 20.0, "shoulder": 35.0, "elbow": 80.0, "wrist": -15.0}
    target |= {"wrist_rotate": 30.0, "gripper": 40.0}
    since = len(served.emu.records)
    served.command(target)
    settled(served, target)
    moves = group_moves(served.emu.records[since:])
    assert len(moves) == 1
    assert group_pulses(moves[0]) == pulses(served.config, target)
    # Where the hardware reads the state back: the same names, the same units.
    urdf = served.config.model.to_urdf(target)
    served.peer.joint_states.clear()
    wait_until(lambda: served.peer.joint_states, 10, "joint states")
    state = served.peer.joint_states[-1]
    assert set(state.name) == set(COMMANDED)
    for name, value in zip(state.name, state.position, strict=True):
        assert math.isclose(value, urdf[name], abs_tol=1e-6), name


def test_nan_is_no_command_for_that_joint(served: Commanded) -> None:
    """ros2_control's command interfaces are NaN until a controller sets them (the gripper's,
    while only the arm's controller runs): the other joints move, that one stays."""
    target = dict(served.emu.servo_degrees()) | {"base": -25.0, "wrist": 10.0}
    values = served.config.model.to_urdf(target)
    positions = [math.nan if name == "gripper" else float(v) for name, v in values.items()]
    since = len(served.emu.records)
    served.command(target, "nan-gripper", position=positions)
    settled(served, {"base": -25.0, "wrist": 10.0})
    moves = group_moves(served.emu.records[since:])
    assert len(moves) == 1
    channels = {t.channel for t in moves[0].targets}
    assert served.config.joints["gripper"].channel not in channels
    assert served.config.joints["base"].channel in channels


def test_a_bad_joint_command_is_refused_whole_and_writes_nothing(served: Commanded) -> None:
    here = dict(served.emu.servo_degrees())
    good = {"base": -30.0, "elbow": 60.0}
    since = len(served.emu.records)
    named = {"name": list(COMMANDED)}
    cases: dict[str, tuple[dict[str, list[Any]], str]] = {
        "unknown": ({"name": [*COMMANDED[:5], "finger"]}, "unknown joint 'finger'"),
        "inf": (named | {"position": [math.inf, *[0.0] * 5]}, "base: inf rad is outside"),
        "no command": (named | {"position": [math.nan] * 6}, "NaN is ros2_control's"),
        "far": (named | {"position": [2.0, *[0.0] * 5]}, "base: 2 rad is outside"),
        "short": ({"position": [0.1, 0.2]}, "2 positions for 6 joints"),
        "velocity": ({"velocity": [0.1] * 6}, "positions only"),
    }
    for ident, (raw, reason) in cases.items():
        served.command({**here, **good}, f"bad-{ident}", **raw)
        result = served.peer.result(f"bad-{ident}", 20)
        assert result.outcome == "refused", (ident, result.reason)
        assert reason in result.reason, (ident, result.reason)
        # Whoever refused it (this side, or the owner: "unknown"), it is the move it would be.
        assert result.instruction == "move", (ident, result)
    time.sleep(0.5)  # anything it wrongly wrote would be on the board by now
    assert group_moves(served.emu.records[since:]) == []


def test_a_command_the_arm_is_at_or_going_to_writes_nothing_more(served: Commanded) -> None:
    target = dict(served.emu.servo_degrees()) | {"base": 45.0, "wrist": 20.0}
    since = len(served.emu.records)
    # A controller at 100 Hz holding one set-point (its hardware publishes while the state
    # is off the command: all the way there).
    for _ in range(100):
        served.command(target)
        time.sleep(0.01)
    settled(served, target)
    for _ in range(50):
        served.command(target)
        time.sleep(0.01)
    time.sleep(0.5)
    moves = group_moves(served.emu.records[since:])
    assert len(moves) == 1, [m.targets for m in moves]
    assert group_pulses(moves[0]) == pulses(served.config, target)


def test_the_latest_command_wins(served: Commanded) -> None:
    start = dict(served.emu.servo_degrees())
    since = len(served.emu.records)
    # A long move holds the arm; 60 set-points of a sweep meanwhile replace each other.
    served.peer.send("hold", "move", time_ms=5000, **(start | {"wrist": start["wrist"] + 20}))
    try:
        wait_until(lambda: group_moves(served.emu.records[since:]), 20, "the long move")
    except AssertionError as e:
        raise AssertionError(f"{e}: {said(served)}") from e
    last = start
    for k in range(1, 61):
        last = start | {"base": -60.0 + k, "elbow": 60.0 + k / 2}
        served.command(last)
    # Its source alive, as ros2_control's hardware sends its command at its rate: one that
    # waits while its stream is quiet for `server.stream_timeout_s` is not written.
    deadline = time.monotonic() + 30
    while "hold" not in served.peer.results_now():
        assert time.monotonic() < deadline, said(served)
        time.sleep(0.1)
        served.command(last)
    assert served.peer.result("hold", 30).outcome == "done"
    settled(served, last)
    moves = group_moves(served.emu.records[since:])
    assert len(moves) == 2, len(moves)  # the long move, then the last set-point only
    assert group_pulses(moves[-1]) == pulses(served.config, last)


def test_a_refusal_sent_again_and_again_is_published_once_a_second(served: Commanded) -> None:
    """A controller sends its refused command again at its rate: the result topic hears the
    reason again only after a second, not at the controller's rate."""
    here = dict(served.emu.servo_degrees())
    named = {"name": list(COMMANDED), "position": [3.0, *[0.0] * 5]}
    t0 = time.monotonic()
    for i in range(40):
        served.command(here, f"again-{i}", **named)
        time.sleep(0.005)
    served.command(here, "sentinel", **(named | {"position": [0.0] * 5 + [9.0]}))
    assert served.peer.result("sentinel", 20).outcome == "refused"  # another reason: told
    told = [i for i in range(40) if f"again-{i}" in served.peer.results]
    # The first the server judged is told (the stream keeps the newest command only, so on
    # a busy host the server may read again-6 first: seen, beside two busy loops).
    assert told, told
    # At most one a second of the 40 (sent within `took` seconds).
    took = time.monotonic() - t0
    assert len(told) <= 1 + took / COMMAND_REFUSALS_EVERY_S, (told, took)


def test_alternating_refusals_are_each_published_once_a_second(served: Commanded) -> None:
    """Issue 46: two bad commands in turn are two reasons, each published once a second at
    most whatever the order they come in (each used to be news after the other: every one
    was published)."""
    here = dict(served.emu.servo_degrees())
    # Values no other test sends: a reason told in the last second is not told again.
    bad = (
        {"name": list(COMMANDED), "position": [3.1, *[0.0] * 5]},
        {"name": list(COMMANDED), "position": [0.0] * 5 + [8.0]},
    )
    t0 = time.monotonic()
    for i in range(40):
        served.command(here, f"turn-{i}", **bad[i % 2])
        time.sleep(0.005)
    sentinel = {"name": list(COMMANDED), "position": [0.0, 3.1, *[0.0] * 4]}
    served.command(here, "turn-sentinel", **sentinel)
    assert served.peer.result("turn-sentinel", 20).outcome == "refused"
    took = time.monotonic() - t0
    told = [i for i in range(40) if f"turn-{i}" in served.peer.results]
    # The stream keeps the newest command only: the server may not read every one.
    assert told, told
    assert len(told) <= 2 * (1 + took / COMMAND_REFUSALS_EVERY_S), (told, took)
