"""Loading and validating the arm configuration."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from al5d.arm.config import (
    DEFAULT_CONFIG,
    ConfigError,
    load_config,
    namespace_problem,
    parse_config,
    with_changes,
)

REPO_CONFIG = Path(__file__).resolve().parents[1] / "config" / "al5d.yaml"


@pytest.fixture
def data() -> dict[str, Any]:
    loaded: dict[str, Any] = yaml.safe_load(REPO_CONFIG.read_text())
    return copy.deepcopy(loaded)


def test_one_default_config_file() -> None:
    # The repository's config/al5d.yaml is the package's own file, not a copy of it.
    assert REPO_CONFIG.resolve() == DEFAULT_CONFIG.resolve()
    assert DEFAULT_CONFIG.is_file() and not DEFAULT_CONFIG.is_symlink()


def test_a_servo_model_gives_the_speed_and_an_explicit_speed_wins(data: dict[str, Any]) -> None:
    cfg = parse_config(data)
    assert cfg.joints["shoulder"].servo == "HS-805BB"
    assert cfg.joints["shoulder"].speed_deg_s == pytest.approx(60 / 0.14)
    data["joints"]["shoulder"]["speed_deg_s"] = 200
    assert parse_config(data).joints["shoulder"].speed_deg_s == 200


def test_shipped_config(data: dict[str, Any]) -> None:
    cfg = parse_config(data)
    assert list(cfg.joints) == ["base", "shoulder", "elbow", "wrist", "gripper", "wrist_rotate"]
    assert cfg.channels == (0, 1, 2, 3, 4, 5)
    assert set(cfg.presets) >= {"park", "ready", "straight_up"}
    assert cfg.joints["base"].range_deg == (-90, 90)
    assert cfg.joints["shoulder"].range_deg == (-30, 90)
    assert cfg.joints["elbow"].range_deg == (0, 135)


def test_calibration_sets_scale_and_direction(data: dict[str, Any]) -> None:
    cfg = parse_config(data)
    shoulder = cfg.joints["shoulder"]
    assert shoulder.to_us(0) == 1500
    assert shoulder.to_us(90) == 600  # mounted reversed
    assert shoulder.us_per_deg == -10
    assert shoulder.to_deg(shoulder.to_us(37.5)) == pytest.approx(37.5)
    assert shoulder.speed_us_s == pytest.approx(60 / 0.14 * 10)  # HS-805BB: 0.14 s / 60 deg


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda d: d["joints"]["base"].update(range_deg=[90, -90]),
            r"joints\.base: .*range_deg \[90.0, -90.0\]",
        ),
        (
            lambda d: d["joints"]["base"].update(channel=40),
            r"joints\.base\.channel: .*channel 40 is outside 0\.\.31",
        ),
        (
            lambda d: d["joints"]["elbow"].update(channel=0),
            r"joints\.elbow\.channel: channel 0 is already used by base",
        ),
        (
            lambda d: d["joints"]["wrist"].update(speed_deg_s=-5),
            r"joints\.wrist\.speed_deg_s: .*greater than 0.*-5",
        ),
        (
            lambda d: d["joints"]["wrist"].update(speed_deg_s="fast"),
            r"joints\.wrist\.speed_deg_s: .*'fast'",
        ),
        (
            lambda d: d["joints"]["base"].update(range_deg=[-120, 90]),
            r"joints\.base: .*-120.0 maps to 300 us",
        ),
        (
            lambda d: d["joints"]["base"]["calibration"][1].update(deg=-90),
            r"joints\.base: .*both reference points",
        ),
        (
            lambda d: d["joints"]["base"]["calibration"][0].update(us=3000),
            r"joints\.base\.calibration\.0\.us",
        ),
        (lambda d: d["joints"]["base"].update(colour="red"), r"joints\.base\.colour: Extra inputs"),
        # An unknown key with the one meant (an outside try: a typo and a key out of its
        # section were each said as "Extra inputs are not permitted", no more).
        (
            lambda d: d["server"].update(queue_capacty=5),
            r"server\.queue_capacty: Extra inputs are not permitted; did you mean "
            r"'server\.queue_capacity'\?",
        ),
        (
            lambda d: d.update(queue_capacity=5),
            r"queue_capacity: Extra inputs are not permitted; did you mean "
            r"'server\.queue_capacity'\?",
        ),
        (
            lambda d: d["presets"]["park"].update(elbow=170),
            r"presets\.park\.elbow: 170.* outside the range 0.0\.\.135\.0",
        ),
        (lambda d: d["presets"]["ready"].pop("wrist"), r"presets\.ready: no angle for wrist"),
        (
            # A typo is an unknown joint and a missing one: the unknown is named.
            lambda d: d["presets"]["ready"].update(elbw=d["presets"]["ready"].pop("elbow")),
            r"presets\.ready\.elbw: no such joint; did you mean 'elbow'\?",
        ),
        (
            # The server parks as it starts and ends without judging the park's path: an
            # outside try's park drove the tool tip 220 mm into the table, twice.
            lambda d: d["presets"]["park"].update(shoulder=90, elbow=90, wrist=0),
            r"presets\.park: below the table: the tool tip would be at z=-220 mm",
        ),
        (
            lambda d: d["presets"].update(
                dip={**d["presets"]["ready"], "shoulder": 90, "elbow": 90, "wrist": 0}
            ),
            r"presets\.dip: below the table",
        ),
        (
            lambda d: d["presets"]["ready"].update(finger=3),
            r"presets\.ready\.finger: no such joint",
        ),
        (
            lambda d: d["presets"].update(Stop=d["presets"]["park"]),
            r"presets\.Stop: the name of an instruction, not a preset",
        ),
        (
            lambda d: d["presets"].update(Help=d["presets"]["park"]),
            r"presets\.Help: a word of sequence files or al5d shell, not a preset",
        ),
        (
            lambda d: d["presets"].update(wait=d["presets"]["park"]),
            r"presets\.wait: a word of sequence files or al5d shell, not a preset",
        ),
        (
            lambda d: d["presets"].pop("straight_up"),
            r"presets\.straight_up: this preset is required",
        ),
        (lambda d: d["server"].update(baud=12345), r"server\.baud: .*baud 12345"),
        (
            lambda d: d["server"].update(trajectory_path_tolerance_deg=0),
            r"server\.trajectory_path_tolerance_deg: Input should be greater than 0",
        ),
        (
            lambda d: d["server"].update(trajectory_path_tolerance_deg=float("inf")),
            r"server\.trajectory_path_tolerance_deg: Input should be a finite number",
        ),
        (
            lambda d: d["server"].update(stream_timeout_s=0),
            r"server\.stream_timeout_s: Input should be greater than 0",
        ),
        (
            lambda d: d["server"].update(stream_timeout_s=600),
            r"server\.stream_timeout_s: Input should be less than or equal to 60",
        ),
        (
            # Said as what it is, not as beyond a bound (it was "less than or equal to 1000").
            lambda d: d["server"].update(joint_state_rate_hz=float("nan")),
            r"server\.joint_state_rate_hz: Input should be a finite number",
        ),
        (
            lambda d: d["server"].update(idle_joint_state_rate_hz=0.5),
            r"server\.idle_joint_state_rate_hz: Input should be greater than or equal to 4",
        ),
        (
            lambda d: d["server"].update(idle_joint_state_rate_hz=30),
            r"server: idle_joint_state_rate_hz 30 must not exceed joint_state_rate_hz 25",
        ),
        (
            lambda d: d["joints"]["elbow"].update(servo="HS-9999"),
            r"joints\.elbow: servo 'HS-9999' is not in the table; known: HS-485HB",
        ),
        (
            lambda d: d["joints"]["elbow"].pop("servo"),
            r"joints\.elbow: give the servo's model .* or its speed_deg_s",
        ),
        (lambda d: d["presets"]["park"].update(base=float("nan")), r"presets\.park\.base"),
        (
            lambda d: d["geometry"].update(ulna_mm=-5),
            r"geometry\.ulna_mm: Input should be greater than 0 \(value: -5\)",
        ),
        (lambda d: d["geometry"].update(ulna=183), r"geometry\.ulna: Extra inputs"),
        (
            lambda d: d["joints"].update(finger=d["joints"].pop("gripper")),
            r"joints: an AL5D has base, .*; missing: gripper; not an AL5D joint: finger",
        ),
        (
            lambda d: d["server"].update(mount={"parent": "/world"}),
            r"server\.mount\.parent: frame '/world': parts separated by '/' \(none leading\)",
        ),
        (
            lambda d: d["server"].update(mount={"xyz": [0.5, 0, 250]}),
            r"server\.mount\.xyz\.2: Input should be less than or equal to 100 \(value: 250\)",
        ),
        (
            lambda d: d["server"].update(mount={"rpy": [0, float("nan"), 0]}),
            r"server\.mount\.rpy\.1: Input should be a finite number",
        ),
        (
            lambda d: d["server"].update(mount={"xyz": [1, 2]}),
            r"server\.mount\.xyz\.2: Field required",
        ),
        (
            lambda d: d["server"].update(namespace="left", mount={"parent": "left/base_link"}),
            r"server: mount\.parent 'left/base_link' is a frame of this arm itself",
        ),
    ],
)
def test_a_bad_config_is_refused_naming_the_key(
    data: dict[str, Any], edit: Any, message: str
) -> None:
    edit(data)
    with pytest.raises(ConfigError, match=message):
        parse_config(data, "arm.yaml")


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("joints: [unclosed")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
    bad.write_text("- just a list")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        load_config(bad)


def test_the_geometry_makes_the_robot_model(data: dict[str, Any]) -> None:
    data["geometry"]["ulna_mm"] = 183.0  # a measured arm
    model = parse_config(data).model
    assert model.geometry.ulna == pytest.approx(0.183)
    assert model.geometry.humerus == pytest.approx(0.14605)
    assert model.urdf_limits("elbow") == pytest.approx((0.0, math.radians(135)))


def test_a_mount_is_optional_and_defaults_to_the_world_frame(data: dict[str, Any]) -> None:
    assert parse_config(data).server.mount is None  # as before: base_link is a root
    data["server"]["mount"] = {"xyz": [0.5, -0.25, 0.0], "rpy": [0, 0, math.pi / 2]}
    mount = parse_config(data).server.mount
    assert mount is not None and mount.parent == "world"
    frame = mount.frame()
    assert frame.transform.apply((1.0, 0.0, 0.0)) == pytest.approx((0.5, 0.75, 0.0))


def test_changes_by_dotted_name_are_validated_like_the_file(data: dict[str, Any]) -> None:
    config = parse_config(data)
    changed = with_changes(config, {"server.joint_state_rate_hz": 50, "geometry.ulna_mm": 183})
    assert changed.server.joint_state_rate_hz == 50 and changed.geometry.ulna_mm == 183
    assert changed.joints == config.joints and changed.presets == config.presets
    with pytest.raises(ConfigError) as bad:
        with_changes(config, {"server.baud": 1234}, "ROS parameters", {"server.baud": "baud"})
    data["server"]["baud"] = 1234
    with pytest.raises(ConfigError) as in_file:
        parse_config(data, "arm.yaml")
    # The same message, but for where it comes from and the name it is known by there.
    expected = str(in_file.value).replace("arm.yaml: server.baud", "ROS parameters: baud")
    assert str(bad.value) == expected


def test_a_namespace_too_long_for_its_lane_is_refused_with_the_reason() -> None:
    """A server's lane is a Unix socket named after its namespace (a path of at most 107
    bytes): a 300-character one ended `al5d send` in rcl's traceback."""
    assert namespace_problem("/" + "a" * 64) is None
    problem = namespace_problem("a" * 65)
    assert problem is not None and "at most 64 characters" in problem, problem
