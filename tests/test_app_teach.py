"""`al5d run` with saved poses (issue 27, teach and replay): a sequence naming the poses of
`poses.yaml` beside it, or of the file `--poses` names, runs on a real server; an unknown
pose, or a bad poses file, is bad input for the whole file and nothing is sent."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from al5d import exits
from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d_rig.armrig import group_moves
from al5d_rig.proc import Proc
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Served, served

#: Generous bounds: rclpy's start, discovery and a move on a loaded machine.
CMD_S = 90.0

POSES = (
    "home: {base: 0, shoulder: 30, elbow: 90, wrist: 0, gripper: 0, wrist_rotate: 0}\n"
    "cup: {base: -40, shoulder: 40, elbow: 80, wrist: -20, gripper: 10}\n"
)


@pytest.fixture(scope="module")
def arm(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    with served(config, tmp_path_factory.mktemp("teach"), "al5d_teach_peer") as s:
        yield s


def moves(arm: Served, since: int) -> list[p.GroupMove]:
    return group_moves(arm.emu.records[since:])


def pulses(config: ArmConfig, degrees: dict[str, float]) -> set[tuple[int, int]]:
    joints = config.joints
    return {(joints[j].channel, round(joints[j].to_us(d))) for j, d in degrees.items()}


def test_run_moves_to_the_poses_a_sequence_names(arm: Served, tmp_path: Path) -> None:
    (tmp_path / "poses.yaml").write_text(POSES)
    seq = tmp_path / "pick.seq"
    seq.write_text("pose cup time=400\nwait 100\nmove gripper=45 time=200\npose home\n")
    n0 = len(arm.emu.records)
    run = Proc("run", str(seq))
    code = run.wait(CMD_S)
    out = run.out.drain()
    assert code == exits.DONE, (out, run.err.drain())
    assert sum(": done" in line for line in out) == 3, out
    sent = moves(arm, n0)
    cup = {"base": -40, "shoulder": 40, "elbow": 80, "wrist": -20, "gripper": 10}
    home = {"base": 0, "shoulder": 30, "elbow": 90, "wrist": 0, "gripper": 0, "wrist_rotate": 0}
    # A move is one group move for the board, each naming every joint its pose names.
    assert [{(t.channel, t.pulse_us) for t in m.targets} for m in sent] == [
        pulses(arm.config, cup),
        pulses(arm.config, {"gripper": 45}),
        pulses(arm.config, home),
    ]
    assert sent[0].time_ms == 400


def test_run_reads_the_poses_file_it_is_given(arm: Served, tmp_path: Path) -> None:
    elsewhere = tmp_path / "mine"
    elsewhere.mkdir()
    (elsewhere / "arm.yaml").write_text("lean: {base: 15, elbow: 85}\n")
    seq = tmp_path / "lean.seq"
    seq.write_text("ready\npose lean time=300\n")
    n0 = len(arm.emu.records)
    run = Proc("run", "--poses", str(elsewhere / "arm.yaml"), str(seq))
    assert run.wait(CMD_S) == exits.DONE, run.err.drain()
    assert {(t.channel, t.pulse_us) for t in moves(arm, n0)[-1].targets} == pulses(
        arm.config, {"base": 15, "elbow": 85}
    )


def test_an_unknown_pose_or_a_bad_poses_file_sends_nothing(arm: Served, tmp_path: Path) -> None:
    wait_until(lambda: arm.states[-1] == "ready", 30, "ready")
    (tmp_path / "poses.yaml").write_text(POSES)
    seq = tmp_path / "typo.seq"
    seq.write_text("pose home\npose cupp time=300\n")
    n0 = len(arm.emu.records)
    run = Proc("run", str(seq))
    assert run.wait(CMD_S) == exits.BAD_INPUT
    assert run.out.drain() == []
    assert run.err.drain() == [
        f"al5d run: nothing sent: {seq}:2: word 2 'cupp': no saved pose named 'cupp'; did you "
        f"mean 'cup'? (in {tmp_path / 'poses.yaml'}: home, cup)"
    ]
    (tmp_path / "poses.yaml").write_text("home: {base: 0, elbow: ninety}\n")
    run = Proc("run", str(seq))
    assert run.wait(CMD_S) == exits.BAD_INPUT
    assert run.err.drain() == [
        f"al5d run: nothing sent: {tmp_path / 'poses.yaml'}: home.elbow: 'ninety' is not a "
        "number of degrees"
    ]
    missing = tmp_path / "missing.yaml"
    run = Proc("run", "--poses", str(missing), str(seq))
    assert run.wait(CMD_S) == exits.BAD_INPUT
    assert run.err.drain() == [f"al5d run: nothing sent: {missing}: no such poses file"]
    assert moves(arm, n0) == []


def test_the_web_view_will_not_start_on_a_bad_poses_file(tmp_path: Path) -> None:
    bad = tmp_path / "poses.yaml"
    bad.write_text("home: {base: 0, wrist: up}\n")
    web = Proc("web", "--port", "0", "--poses", str(bad))
    assert web.wait(CMD_S) == exits.USAGE
    assert f"{bad}: home.wrist: 'up' is not a number of degrees" in web.err.drain()


def test_the_shell_moves_to_a_pose_by_name(arm: Served, tmp_path: Path) -> None:
    (tmp_path / "mine.yaml").write_text(POSES)
    n0 = len(arm.emu.records)
    shell = Proc("shell", "--poses", str(tmp_path / "mine.yaml"), stdin=True)
    try:
        for line in ("pose cup time=300", "pose mug", "exit"):
            shell.send(line)
        code = shell.wait(CMD_S)
        out, err = shell.out.drain(), shell.err.drain()
    finally:
        shell.kill()
    assert code == exits.BAD_INPUT, err  # a line was bad; the other ran
    assert sum(": done" in line for line in out) == 1, out
    assert (
        f"al5d shell: word 2 'mug': no saved pose named 'mug' (in {tmp_path / 'mine.yaml'}: "
        "home, cup)" in err
    )
    cup = {"base": -40, "shoulder": 40, "elbow": 80, "wrist": -20, "gripper": 10}
    assert [{(t.channel, t.pulse_us) for t in m.targets} for m in moves(arm, n0)] == [
        pulses(arm.config, cup)
    ]
