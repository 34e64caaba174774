"""Calibration on an emulated arm whose joints stand elsewhere than the config believes: the
procedure, played by a user who watches the joints' true angles, finds the offsets (and a
reversed joint), refuses a calibration the servo cannot cover, and writes the file."""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

from al5d.app.calibrate import server_config
from al5d.arm import calfile
from al5d.arm import instruction as ins
from al5d.arm.calfile import edit_calibrations, write_calibration
from al5d.arm.calibration import (
    DEFAULT_STEP_US,
    Awaiting,
    CalibrationRefused,
    JointCalibration,
    Point,
    Procedure,
    judge,
    nudged,
    references,
)
from al5d.arm.config import DEFAULT_CONFIG, ArmConfig, load_config
from al5d.arm.instruction import Result
from al5d.arm.states import State
from al5d.arm.validate import Limits
from al5d.arm.validate import judge as judge_instruction
from al5d.owner.loop import Owner
from al5d.ssc32u.emulator import Emulator, Mechanics
from al5d_rig.calibuser import User, truth

OUTCOME_S = 20.0


class Arm:
    """An emulated arm with `mechanics`, driven by the real driver (every move judged)."""

    def __init__(self, config: ArmConfig, mechanics: Mapping[str, Mechanics]) -> None:
        self.config = config
        self.emu = Emulator(config, mechanics=mechanics).start()
        self.driver = Owner.on_port(config, self.emu.port)
        self.driver.start()
        self.driver.wait_for_state(State.READY, OUTCOME_S)

    def close(self) -> None:
        self.driver.close()
        self.emu.close()

    def true_deg(self, name: str) -> float:
        """Where the joint truly stands once its servo has settled."""
        return self.emu.joint_degrees(self.emu.settle_time(0.01, [name]))[name]

    def go(self, procedure: Procedure) -> bool:
        """Move to the procedure's pulse: True once there, False when the move was refused
        (the server's range: the arm stays where it was)."""
        outcome = self.driver.execute(ins.move(**procedure.pose()), timeout=OUTCOME_S)
        if outcome.result is Result.DONE:
            procedure.moved()
            return True
        assert outcome.result is Result.REFUSED, outcome
        procedure.not_moved()
        return False


@pytest.fixture
def arm_of(config: ArmConfig) -> Iterator[type[Arm]]:
    made: list[Arm] = []

    def make(mechanics: Mapping[str, Mechanics]) -> Arm:
        arm = Arm(config, mechanics)
        made.append(arm)
        return arm

    yield make  # type: ignore[misc]
    for arm in made:
        arm.close()


def play_user(arm: Arm, procedure: Procedure) -> None:
    """The user (`calibuser.User`) at each reference until it is there, then accepts; a
    refused calibration is left in `refused`."""
    while procedure.step is Awaiting.NUDGE:
        name = procedure.joint.name
        user = User(procedure.joint, procedure.reference.deg, procedure.step_us)
        assert arm.go(procedure)
        for _ in range(100):
            before = arm.true_deg(name)
            steps = user.nudge(before)
            if steps is None:
                break
            while True:
                try:
                    procedure.nudge(steps)
                    if arm.go(procedure):
                        break
                except CalibrationRefused:  # beyond the servo's pulses
                    pass
                steps = user.refused(before)
            user.saw(before, arm.true_deg(name))
        else:
            raise AssertionError(f"{name} never reached {procedure.reference.deg} deg")
        with contextlib.suppress(CalibrationRefused):
            procedure.accept()


def test_the_procedure_finds_each_joints_offset_within_a_step(
    config: ArmConfig, arm_of: type[Arm], tmp_path: Path
) -> None:
    mechanics = {
        "base": Mechanics(42),
        "shoulder": Mechanics(-33),
        "elbow": Mechanics(23),
        "wrist": Mechanics(-61),
        "gripper": Mechanics(0),
        "wrist_rotate": Mechanics(17),
    }
    arm = arm_of(mechanics)
    procedure = Procedure(config, tuple(config.joints))
    play_user(arm, procedure)
    assert procedure.refused == {}
    assert [r.name for r in procedure.results] == list(config.joints)
    for result in procedure.results:
        mech = mechanics[result.name]
        assert not result.reversed
        for point, offset in zip(result.found, result.offsets_us, strict=True):
            assert abs(offset - mech.offset_us) <= DEFAULT_STEP_US
            assert abs(point.us - truth(result.old, mech, point.deg)) <= DEFAULT_STEP_US
        # The new calibration puts the whole range where the arm truly is, within a step
        # at the references and, scaled, at the range's ends.
        for deg in result.old.range_deg:
            assert abs(result.new.to_us(deg) - truth(result.old, mech, deg)) <= 3 * DEFAULT_STEP_US

    # Written, it loads; a driver with it puts the misaligned arm where it is asked.
    path = tmp_path / "arm.yaml"
    shutil.copy(DEFAULT_CONFIG, path)
    write_calibration(path, procedure.results)
    calibrated = load_config(path)
    arm.driver.close()
    driver = Owner.on_port(calibrated, arm.emu.port)
    driver.start()
    try:
        driver.wait_for_state(State.READY, OUTCOME_S)
        target = {"base": 30.0, "shoulder": 20.0, "elbow": 60.0, "wrist": -20.0, "gripper": 45.0}
        outcome = driver.execute(ins.move(**target, wrist_rotate=-30.0), timeout=OUTCOME_S)
        assert outcome.result is Result.DONE, outcome
        true = arm.emu.joint_degrees(arm.emu.settle_time(0.01))
        for name, deg in {**target, "wrist_rotate": -30.0}.items():
            step_deg = DEFAULT_STEP_US / abs(config.joints[name].us_per_deg)
            assert true[name] == pytest.approx(deg, abs=step_deg), name
    finally:
        driver.close()


def test_a_reversed_joint_is_found_and_reported(config: ArmConfig, arm_of: type[Arm]) -> None:
    mechanics = {"elbow": Mechanics(0, reversed=True), "wrist": Mechanics(-12, reversed=True)}
    arm = arm_of(mechanics)
    procedure = Procedure(config, ("elbow", "wrist", "base"))
    play_user(arm, procedure)
    by_name = {r.name: r for r in procedure.results}
    assert by_name["elbow"].reversed and by_name["wrist"].reversed
    assert not by_name["base"].reversed
    assert "REVERSED" in by_name["elbow"].describe()
    for name in ("elbow", "wrist"):
        result = by_name[name]
        for point in result.found:
            assert abs(point.us - truth(result.old, mechanics[name], point.deg)) <= DEFAULT_STEP_US
        # The new calibration's scale has the other sign: the config now turns it round.
        assert (result.new.us_per_deg > 0) != (config.joints[name].us_per_deg > 0)


def test_a_calibration_beyond_the_servos_range_is_refused(
    config: ArmConfig, arm_of: type[Arm], tmp_path: Path
) -> None:
    """The base's horn 150 us off: its references can be reached, but its range's end
    (90 deg) would need 2550 us, beyond the servo's 2500: refused, nothing written for it."""
    arm = arm_of({"base": Mechanics(150), "wrist": Mechanics(20)})
    procedure = Procedure(config, ("base", "wrist"), step_us=10)
    play_user(arm, procedure)
    assert list(procedure.refused) == ["base"]
    reason = procedure.refused["base"]
    assert "range_deg end 90" in reason and "outside 500..2500" in reason
    assert "re-seat the horn" in reason
    assert [r.name for r in procedure.results] == ["wrist"]
    path = tmp_path / "arm.yaml"
    shutil.copy(DEFAULT_CONFIG, path)
    write_calibration(path, procedure.results)
    assert load_config(path).joints["base"] == config.joints["base"]


def test_a_nudge_never_leaves_the_servos_pulses(config: ArmConfig) -> None:
    base, shoulder = config.joints["base"], config.joints["shoulder"]
    assert nudged(base, 2495, 1, 5) == 2500
    with pytest.raises(CalibrationRefused, match=r"2505 us is outside the servo's 500\.\.2500"):
        nudged(base, 2500, 1, 5)
    # Toward +angle as the config has it: the shoulder's pulse shrinks as its angle grows.
    assert nudged(shoulder, 1500, 2, 5) == 1490
    with pytest.raises(CalibrationRefused, match="495 us"):
        nudged(shoulder, 505, 2, 5)


def test_the_reference_poses_are_moves_the_server_takes(config: ArmConfig) -> None:
    """Each reference pose is within the ranges and above the table, with room to nudge."""
    limits = Limits.of(config)
    for name, joint in config.joints.items():
        rest = Procedure(config, (name,)).reference_pose()
        for ref in references(joint):
            for margin in (-15.0, 0.0, 15.0):
                pose = {**rest, name: ref.deg + margin}
                verdict = judge_instruction(ins.move(**pose), limits)
                assert not isinstance(verdict, str), (pose, verdict)


def test_the_file_keeps_its_comments_and_takes_block_style(config: ArmConfig) -> None:
    shoulder = config.joints["shoulder"]
    result = JointCalibration(
        shoulder, shoulder, (Point(0, 1512), Point(45, 1061))
    )  # judge's checks are not this test's
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    edited = edit_calibrations(text, [result])
    changed = [
        (a, b) for a, b in zip(text.splitlines(), edited.splitlines(), strict=True) if a != b
    ]
    assert changed == [
        (
            "    calibration: [{deg: 0, us: 1500}, {deg: 90, us: 600}]",
            "    calibration: [{deg: 0, us: 1512}, {deg: 45, us: 1061}]",
        )
    ]
    block = text.replace(
        "    calibration: [{deg: 0, us: 1500}, {deg: 90, us: 600}]\n",
        "    calibration:\n    - deg: 0\n      us: 1500  # horn\n\n    - {deg: 90, us: 600}\n",
    )
    assert block != text
    assert edit_calibrations(block, [result]) == edited
    flow = text.replace("  shoulder:\n", "  shoulder: &s\n", 1)
    flow = (
        flow[: flow.index("  shoulder: &s\n")]
        + "  shoulder: {channel: 1}\n"
        + flow[flow.index("  elbow:") :]
    )
    with pytest.raises(CalibrationRefused, match=r"shoulder\.calibration is not a line"):
        edit_calibrations(flow, [result])


def test_the_file_is_written_with_a_backup_and_a_diff(config: ArmConfig, tmp_path: Path) -> None:
    base = config.joints["base"]
    result = judge(base, (Point(0, 1540), Point(45, 1990)))
    assert result.offsets_us == (40, 40)
    assert "CHECK" not in result.describe()
    assert "CHECK the scale" in judge(base, (Point(0, 1540), Point(45, 1700))).describe()
    real = tmp_path / "real.yaml"
    shutil.copy(DEFAULT_CONFIG, real)
    link = tmp_path / "al5d.yaml"
    link.symlink_to(real)  # as the repository's config/al5d.yaml is
    before = real.read_text(encoding="utf-8")
    written = write_calibration(link, [result], stamp="20261126T061500Z")
    assert link.is_symlink()
    assert written.backup == tmp_path / "real.yaml.20261126T061500Z.bak"
    assert written.backup.read_text(encoding="utf-8") == before
    assert "-    calibration: [{deg: -90, us: 600}, {deg: 90, us: 2400}]" in written.diff
    assert "+    calibration: [{deg: 0, us: 1540}, {deg: 45, us: 1990}]" in written.diff
    assert written.diff.startswith(f"--- {written.backup}\n+++ {link}\n")
    again = load_config(link)
    assert again.joints["base"].to_us(90) == pytest.approx(2440)
    # A second write in the same second keeps the first backup.
    second = write_calibration(link, [result], stamp="20261126T061500Z")
    assert second.backup != written.backup and written.backup.exists()
    assert second.diff == ""


def test_the_shipped_configuration_is_never_written(
    config: ArmConfig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A server started without --config runs with the package's own file: calibrate offered
    to write into it (an install replaces it; an editable one is the source tree). Tried on
    a stand-in for the shipped file, so that a guard that fails writes nothing of ours."""
    shipped = tmp_path / "data" / "al5d.yaml"
    shipped.parent.mkdir()
    shutil.copy(DEFAULT_CONFIG, shipped)
    monkeypatch.setattr(calfile, "DEFAULT_CONFIG", shipped)
    result = judge(config.joints["base"], (Point(0, 1540), Point(45, 1990)))
    before = shipped.read_text(encoding="utf-8")
    link = tmp_path / "al5d.yaml"
    link.symlink_to(shipped)  # as the repository's config/al5d.yaml is
    for path in (shipped, link):
        with pytest.raises(CalibrationRefused, match=r"the shipped configuration .* copy it"):
            write_calibration(path, [result])
    assert shipped.read_text(encoding="utf-8") == before
    assert list(shipped.parent.glob("*.bak")) == []
    assert server_config(link, None)[0] is None  # said before anything moves


def test_a_calibration_that_does_not_validate_writes_nothing(
    config: ArmConfig, tmp_path: Path
) -> None:
    with pytest.raises(CalibrationRefused, match="both references were accepted at 1500 us"):
        judge(config.joints["base"], (Point(0, 1500), Point(45, 1500)))
    result = judge(config.joints["base"], (Point(0, 1540), Point(45, 1990)))
    path = tmp_path / "arm.yaml"
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    # A file with a mistake elsewhere would not load once written: nothing is written.
    for broken, why in (
        (text.replace("baud: 9600", "baud: 9601"), "does not validate: .*baud 9601"),
        (text.replace("joints:\n", "joints_:\n", 1), "no top-level `joints:`"),
    ):
        path.write_text(broken, encoding="utf-8")
        with pytest.raises(CalibrationRefused, match=why):
            write_calibration(path, [result])
        assert path.read_text(encoding="utf-8") == broken
        assert list(tmp_path.glob("*.bak")) == []
