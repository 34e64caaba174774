"""The streaming mode (issue 25, item 2) over real DDS: `<ns>/joint_commands` as a stream of
set-points of which only the newest matters, and its watchdog.

`al5d serve` runs in its own process, the emulated board (a pty) in this one, and the peer
publishes as ros2_control's topic-based hardware or a teleoperation node does: a reliable
writer keeping the last command. The server's watchdog is set by its ROS parameter
(`server.stream_timeout_s`), and the elbow is slowed in its configuration so that a move
to a far command lasts seconds: long enough to find the watchdog holding it midway on a
busy machine.
"""

from __future__ import annotations

import math
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest
import yaml
from sensor_msgs.msg import JointState

from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Record
from al5d_rig.armrig import group_moves, group_pulses, pulses
from al5d_rig.proc import patient_config
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Commanded, commanded

NAMESPACE = "stream"
#: The server's watchdog here (its ROS parameter).
TIMEOUT_S = 0.3
#: The elbow's top speed in the server's configuration: 135 degrees take 4.5 s.
SLOW_ELBOW_DEG_S = 30.0


def _stops(records: list[Record]) -> list[Record]:
    return [r for r in records if any(isinstance(c, p.Stop) for c in r.commands)]


def _slow_elbow_config() -> str:
    path = Path(patient_config())
    data = yaml.safe_load(path.read_text())
    data["joints"]["elbow"]["speed_deg_s"] = SLOW_ELBOW_DEG_S
    out = Path(tempfile.mkdtemp(prefix="al5d-test-")) / "al5d.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(out)


@pytest.fixture(scope="module")
def streamed(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Commanded]:
    workdir = tmp_path_factory.mktemp("stream")
    # The model's joint names, without the namespace's prefix (test_ros_prefix has it).
    ros = ("-p", f"server.stream_timeout_s:={TIMEOUT_S}", "-p", "server.joint_prefix:=''")
    with commanded(config, workdir, "al5d_stream_peer", NAMESPACE, _slow_elbow_config(), *ros) as s:
        yield s


def settled(s: Commanded, degrees: Mapping[str, float], timeout: float = 20.0) -> None:
    wait_until(
        lambda: all(abs(s.emu.servo_degrees()[j] - d) < 0.2 for j, d in degrees.items()),
        timeout,
        f"the arm at {dict(degrees)}",
    )


def test_a_burst_of_1000_set_points_writes_a_handful_of_lines_the_last_the_newest(
    streamed: Commanded,
) -> None:
    here = dict(streamed.emu.servo_degrees())
    since = len(streamed.emu.records)
    last = here
    for k in range(1000):
        last = here | {"base": here["base"] + 10 * math.sin(k / 50), "wrist": -10 + k / 100}
        streamed.command(last, f"burst-{k}")
    settled(streamed, last)
    moves = group_moves(streamed.records(since))
    # The wire carries a group move in 40 ms at 9600 baud: the burst, published in well under
    # a second, is a handful of lines, not a thousand, and the last is the newest.
    assert 1 <= len(moves) <= 30, len(moves)
    assert group_pulses(moves[-1]) == pulses(streamed.config, last)
    assert not _stops(streamed.records(since))  # superseded mid-move, never halted


def test_the_watchdog_holds_the_arm_when_the_stream_stops_mid_move(streamed: Commanded) -> None:
    here = dict(streamed.emu.servo_degrees())
    far = here | {"elbow": 130.0 if here["elbow"] < 65 else 5.0}
    since = len(streamed.emu.records)
    streamed.command(far, "far")  # 4 s of a move at the slowed elbow, and then nothing
    wait_until(lambda: _stops(streamed.records(since)), 10, "the watchdog's STOP")
    streamed.proc.err.wait_for("watchdog", 10)
    held = streamed.emu.servo_degrees()["elbow"]
    assert abs(held - far["elbow"]) > 10, held  # halted on its way
    time.sleep(2 * TIMEOUT_S)
    assert abs(streamed.emu.servo_degrees()["elbow"] - held) < 0.5  # and held there
    # Held, not locked: the next set-point moves the arm again.
    back = here | {"elbow": held + (-5 if far["elbow"] > held else 5)}
    streamed.command(back, "back")
    settled(streamed, back)
    assert sum("watchdog" in line for line in streamed.proc.err.all) == 1
    assert not any("STATE: stopped" in line for line in streamed.proc.err.all)


def test_a_stop_during_a_stream_wins_and_the_stream_stays_held(streamed: Commanded) -> None:
    here = dict(streamed.emu.servo_degrees())
    since = len(streamed.emu.records)
    streaming = threading.Event()
    streaming.set()
    sent: list[dict[str, float]] = []

    def stream() -> None:  # a teleoperation node at 50 Hz, which knows nothing of the stop
        k = 0
        while streaming.is_set():
            target = here | {"base": here["base"] + 20 * math.sin(k / 25)}
            streamed.command(target, f"tele-{k}")
            sent.append(target)
            k += 1
            time.sleep(0.02)

    sender = threading.Thread(target=stream)
    sender.start()
    try:
        try:
            wait_until(lambda: len(group_moves(streamed.records(since))) >= 5, 10, "moving")
        except AssertionError:
            told = [r for r in streamed.peer.results_now().values() if r.id.startswith("tele-")]
            raise AssertionError(
                f"the stream did not move the arm in 10 s: {len(sent)} set-points sent, "
                f"{[r.raw for r in streamed.records(since)][-8:]} on the board, told "
                f"{[(r.id, r.outcome, r.reason) for r in told][-4:]}, the server said "
                f"{streamed.proc.err.all[-12:]}"
            ) from None
        t_stop = time.monotonic()
        assert streamed.peer.trigger("stop").success
        time.sleep(0.5)
        records = streamed.records(since)
        stops = [r for r in _stops(records) if r.t_effect >= t_stop]
        assert stops
        after = [r for r in records if r.t_effect > stops[0].t_effect]
        assert not group_moves(after), [r.raw for r in after]  # the stop won
        assert streamed.peer.trigger("release").success
        time.sleep(0.5)  # released, the stream still on its sweep: held
        records = streamed.records(since)
        assert not group_moves([r for r in records if r.t_effect > stops[0].t_effect])
    finally:
        streaming.clear()
        sender.join(5)
    held = [r for r in streamed.peer.results_now().values() if r.id.startswith("tele-")]
    assert any("stream of set-points is held" in r.reason for r in held), held
    # A set-point where the arm stands resumes the stream (nothing written), then it moves.
    resumed = False

    def resume() -> bool:
        nonlocal resumed
        # As a controller re-activated holds the arm: where the joint states say it is.
        state = streamed.peer.joint_states[-1]
        msg = JointState(name=list(state.name), position=list(state.position))
        msg.header.frame_id = "here"
        streamed.commands.publish(msg)  # type: ignore[attr-defined]
        time.sleep(0.2)
        n = len(streamed.emu.records)
        streamed.command(here, "home")
        time.sleep(0.3)
        resumed = bool(group_moves(streamed.records(n)))
        return resumed

    wait_until(resume, 15, "the stream resumed from where the arm stands")
    settled(streamed, here)
