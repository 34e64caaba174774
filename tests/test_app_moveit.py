"""The shipped MoveIt configuration (issue 14): generated from the config, so it cannot drift."""

from __future__ import annotations

import io
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml
import yourdfpy
from proc import Proc

from al5d.app.moveit import moveit_files
from al5d.arm.config import DEFAULT_CONFIG, load_config
from al5d.model import forward
from al5d.ros.runtime import Names

SHIPPED = Path(__file__).resolve().parent.parent / "config" / "moveit"
CONFIG = load_config(None)


def test_the_shipped_files_are_what_the_shipped_config_makes() -> None:
    made = moveit_files(CONFIG)
    assert sorted(p.name for p in SHIPPED.iterdir()) == sorted(made)
    for name, text in made.items():
        assert (SHIPPED / name).read_text(encoding="utf-8") == text, (
            f"config/moveit/{name} is stale: run `al5d moveit config/moveit`"
        )


def test_al5d_moveit_writes_them(tmp_path: Path) -> None:
    proc = Proc("moveit", str(tmp_path / "out"), "--namespace", "left")
    assert proc.wait(30) == 0
    for name, text in moveit_files(CONFIG, "left").items():
        assert (tmp_path / "out" / name).read_text(encoding="utf-8") == text
    urdf = (tmp_path / "out" / "al5d.urdf").read_text(encoding="utf-8")
    assert 'link name="left/base_link"' in urdf and 'link name="left/tool0"' in urdf


def test_the_urdf_and_moveit_files_follow_the_configs_namespace(tmp_path: Path) -> None:
    # A config that puts the arm in `right` (as `al5d serve --config` would) gives frames
    # the server's /right/robot_description has, unless --namespace says otherwise.
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["server"]["namespace"] = "right"
    config = tmp_path / "right.yaml"
    config.write_text(yaml.safe_dump(data))
    urdf = Proc("urdf", "--config", str(config))
    assert urdf.wait(30) == 0
    text = "\n".join(urdf.out.drain())
    assert 'link name="right/base_link"' in text and 'link name="right/tool0"' in text
    assert 'link name="base_link"' in moveit_files(load_config(config), "")["al5d.urdf"]
    moveit = Proc("moveit", str(tmp_path / "out"), "--config", str(config))
    assert moveit.wait(30) == 0
    assert 'link name="right/base_link"' in (tmp_path / "out" / "al5d.urdf").read_text()


def test_every_joint_and_limit_agrees_with_the_urdf_and_the_config() -> None:
    robot = yourdfpy.URDF.load(
        io.StringIO((SHIPPED / "al5d.urdf").read_text(encoding="utf-8")), load_meshes=False
    )
    movable = {j.name: j for j in robot.robot.joints if j.type != "fixed" and j.mimic is None}
    limits = yaml.safe_load((SHIPPED / "joint_limits.yaml").read_text())["joint_limits"]
    assert set(limits) == set(movable)
    model = CONFIG.model
    for name, joint in movable.items():
        lo, hi = model.urdf_limits(name)
        assert math.isclose(joint.limit.lower, lo) and math.isclose(joint.limit.upper, hi)
        assert math.isclose(limits[name]["max_velocity"], joint.limit.velocity)
        if name != "gripper":  # revolute: the servo's speed in rad/s
            speed = math.radians(CONFIG.joints[name].speed_deg_s)
            assert math.isclose(limits[name]["max_velocity"], speed, rel_tol=1e-9)
    srdf = ET.fromstring((SHIPPED / "al5d.srdf").read_text(encoding="utf-8"))
    for preset, degrees in CONFIG.presets.items():
        state = srdf.find(f"group_state[@name='{preset}'][@group='arm']")
        assert state is not None, f"preset {preset} is no named state"
        urdf_values = model.to_urdf(degrees)
        for j in state.findall("joint"):
            assert math.isclose(float(j.get("value", "nan")), urdf_values[j.get("name", "")])
    controllers = yaml.safe_load((SHIPPED / "moveit_controllers.yaml").read_text())
    manager = controllers["moveit_simple_controller_manager"]
    arm = manager["arm_controller"]
    assert set(arm["joints"]) == set(movable) - {"gripper"}
    names = Names()
    for controller in manager["controller_names"]:
        action = f"/{controller}/{manager[controller]['action_ns']}"
        assert action in (names.follow_joint_trajectory, names.gripper_command)


def test_a_mounted_arm_plans_in_its_mounts_frame(tmp_path: Path) -> None:
    """With `server.mount`, MoveIt's URDF has the mount's parent as its root and a fixed
    joint to base_link: a fixed virtual joint in the SRDF has no origin, so only the URDF
    can put the arm anywhere but the parent's origin."""
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["server"]["namespace"] = "left"
    data["server"]["mount"] = {"parent": "world", "xyz": [0.4, -0.3, 0.02], "rpy": [0, 0, 1.2]}
    config_file = tmp_path / "left.yaml"
    config_file.write_text(yaml.safe_dump(data))
    config = load_config(config_file)
    made = moveit_files(config)
    robot = yourdfpy.URDF.load(io.StringIO(made["al5d.urdf"]), load_meshes=False)
    assert robot.base_link == "world" and robot.validate()
    assert "virtual_joint" not in made["al5d.srdf"]
    mount = config.server.mount
    assert mount is not None
    degrees = dict(config.presets["ready"])
    robot.update_cfg(config.model.to_urdf(degrees))
    theirs = robot.get_transform("left/tool0", "world")[:3, 3]
    ours = mount.frame().transform.apply(forward(config.model.geometry, degrees).position)
    assert max(abs(a - b) for a, b in zip(theirs, ours, strict=True)) < 1e-9
    # Without a mount, the URDF is the server's /robot_description, as before.
    assert 'link name="world"' not in moveit_files(CONFIG)["al5d.urdf"]
    moveit = Proc("moveit", str(tmp_path / "out"), "--config", str(config_file))
    assert moveit.wait(30) == 0
    assert (tmp_path / "out" / "al5d.urdf").read_text() == made["al5d.urdf"]
