"""The shipped MoveIt configuration (issue 14): generated from the config, so it cannot drift."""

from __future__ import annotations

import ast
import io
import math
import random
import xml.etree.ElementTree as ET
from pathlib import Path

import xacro
import yaml
import yourdfpy

from al5d.app.moveit import arm_chain, moveit_files, write_moveit_config
from al5d.arm.config import DEFAULT_CONFIG, load_config
from al5d.model import forward
from al5d.ros.names import Names
from al5d_rig.proc import Proc

SHIPPED = Path(__file__).resolve().parent.parent / "config" / "moveit"
SHIPPED_CONFIG = SHIPPED / "config"
CONFIG = load_config(None)


def files_in(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def test_the_shipped_files_are_what_the_shipped_config_makes() -> None:
    made = moveit_files(CONFIG)
    assert files_in(SHIPPED) == sorted(made)
    for name, text in made.items():
        assert (SHIPPED / name).read_text(encoding="utf-8") == text, (
            f"config/moveit/{name} is stale: run `al5d moveit config/moveit`"
        )


def test_the_package_is_laid_out_as_the_setup_assistant_lays_one_out() -> None:
    made = set(moveit_files(CONFIG))
    assert {"package.xml", "CMakeLists.txt", ".setup_assistant", "config/moveit.rviz"} <= made
    for name in (
        "al5d.urdf",
        "al5d.urdf.xacro",
        "al5d.srdf",
        "al5d.ros2_control.xacro",
        "joint_limits.yaml",
        "kinematics.yaml",
        "moveit_controllers.yaml",
        "pilz_cartesian_limits.yaml",
        "initial_positions.yaml",
        "ros2_controllers.yaml",
    ):
        assert f"config/{name}" in made
    for name in ("demo", "move_group", "rsp", "moveit_rviz", "spawn_controllers"):
        assert f"launch/{name}.launch.py" in made


def test_al5d_moveit_writes_them(tmp_path: Path) -> None:
    proc = Proc("moveit", str(tmp_path / "out"), "--namespace", "left")
    assert proc.wait(30) == 0
    made = moveit_files(CONFIG, "left")
    assert files_in(tmp_path / "out") == sorted(made)
    for name, text in made.items():
        assert (tmp_path / "out" / name).read_text(encoding="utf-8") == text
    urdf = (tmp_path / "out" / "config" / "al5d.urdf").read_text(encoding="utf-8")
    assert 'link name="left/base_link"' in urdf and 'link name="left/tool0"' in urdf
    assert ET.parse(tmp_path / "out" / "package.xml").getroot().findtext("name") == (
        "al5d_moveit_config"
    )


def test_the_package_takes_the_name_it_is_given(tmp_path: Path) -> None:
    proc = Proc("moveit", str(tmp_path / "out"), "--name", "left_arm_moveit_config")
    assert proc.wait(30) == 0
    assert ET.parse(tmp_path / "out" / "package.xml").getroot().findtext("name") == (
        "left_arm_moveit_config"
    )
    cmake = (tmp_path / "out" / "CMakeLists.txt").read_text()
    assert "project(left_arm_moveit_config NONE)" in cmake
    assistant = yaml.safe_load((tmp_path / "out" / ".setup_assistant").read_text())
    assert assistant["moveit_setup_assistant_config"]["urdf"]["package"] == (
        "left_arm_moveit_config"
    )
    for launch in (tmp_path / "out" / "launch").iterdir():
        assert 'PACKAGE = "left_arm_moveit_config"' in launch.read_text(), launch.name
    bad = Proc("moveit", str(tmp_path / "bad"), "--name", "Left-Arm")
    assert bad.wait(30) == 2
    assert any("REP 144" in line for line in bad.err.drain())
    assert not (tmp_path / "bad").exists()


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
    assert 'link name="base_link"' in moveit_files(load_config(config), "")["config/al5d.urdf"]
    moveit = Proc("moveit", str(tmp_path / "out"), "--config", str(config))
    assert moveit.wait(30) == 0
    urdf_text = (tmp_path / "out" / "config" / "al5d.urdf").read_text()
    assert 'link name="right/base_link"' in urdf_text


def test_every_joint_and_limit_agrees_with_the_urdf_and_the_config() -> None:
    robot = yourdfpy.URDF.load(
        io.StringIO((SHIPPED_CONFIG / "al5d.urdf").read_text(encoding="utf-8")), load_meshes=False
    )
    movable = {j.name: j for j in robot.robot.joints if j.type != "fixed" and j.mimic is None}
    limits = yaml.safe_load((SHIPPED_CONFIG / "joint_limits.yaml").read_text())["joint_limits"]
    assert set(limits) == set(movable)
    model = CONFIG.model
    for name, joint in movable.items():
        lo, hi = model.urdf_limits(name)
        assert math.isclose(joint.limit.lower, lo) and math.isclose(joint.limit.upper, hi)
        assert math.isclose(limits[name]["max_velocity"], joint.limit.velocity)
        if name != "gripper":  # revolute: the servo's speed in rad/s
            speed = math.radians(CONFIG.joints[name].speed_deg_s)
            assert math.isclose(limits[name]["max_velocity"], speed, rel_tol=1e-9)
    srdf = ET.fromstring((SHIPPED_CONFIG / "al5d.srdf").read_text(encoding="utf-8"))
    for preset, degrees in CONFIG.presets.items():
        state = srdf.find(f"group_state[@name='{preset}'][@group='arm']")
        assert state is not None, f"preset {preset} is no named state"
        urdf_values = model.to_urdf(degrees)
        for j in state.findall("joint"):
            assert math.isclose(float(j.get("value", "nan")), urdf_values[j.get("name", "")])
    controllers = yaml.safe_load((SHIPPED_CONFIG / "moveit_controllers.yaml").read_text())
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
    robot = yourdfpy.URDF.load(io.StringIO(made["config/al5d.urdf"]), load_meshes=False)
    assert robot.base_link == "world" and robot.validate()
    assert "virtual_joint" not in made["config/al5d.srdf"]
    mount = config.server.mount
    assert mount is not None
    degrees = dict(config.presets["ready"])
    # Its joints carry the namespace's prefix, as its server's joint states do.
    robot.update_cfg({f"left_{j}": v for j, v in config.model.to_urdf(degrees).items()})
    theirs = robot.get_transform("left/tool0", "world")[:3, 3]
    ours = mount.frame().transform.apply(forward(config.model.geometry, degrees).position)
    assert max(abs(a - b) for a, b in zip(theirs, ours, strict=True)) < 1e-9
    # Without a mount, the URDF is the server's /robot_description, as before.
    assert 'link name="world"' not in moveit_files(CONFIG)["config/al5d.urdf"]
    moveit = Proc("moveit", str(tmp_path / "out"), "--config", str(config_file))
    assert moveit.wait(30) == 0
    assert (tmp_path / "out" / "config" / "al5d.urdf").read_text() == made["config/al5d.urdf"]


def test_the_ros2_control_urdf_puts_the_topic_hardware_on_the_servers_topics(
    tmp_path: Path,
) -> None:
    # Expanded by xacro as MoveItConfigsBuilder and robot_state_publisher would: the
    # ros2_control tag lists what /joint_states carries, its hardware talks on the
    # namespaced server's topics, and the rest is the plain URDF unchanged.
    write_moveit_config(tmp_path, CONFIG, "left")
    text = xacro.process_file(str(tmp_path / "config" / "al5d.urdf.xacro")).toxml()
    plain = yourdfpy.URDF.load(io.StringIO((tmp_path / "config" / "al5d.urdf").read_text()))
    full = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False)
    assert [j.name for j in full.robot.joints] == [j.name for j in plain.robot.joints]
    assert [link.name for link in full.robot.links] == [link.name for link in plain.robot.links]
    control = ET.fromstring(text).find("ros2_control")
    assert control is not None
    assert control.findtext("hardware/plugin") == (
        "joint_state_topic_hardware_interface/JointStateTopicSystem"
    )
    params = {p.get("name"): p.text for p in control.findall("hardware/param")}
    names = Names.of("left")
    assert params["joint_states_topic"] == names.joint_states == "/left/joint_states"
    assert params["joint_commands_topic"] == names.shared("joint_commands")
    assert 0 < float(params["trigger_joint_command_threshold"] or "nan") < 0.01
    movable = [j.name for j in plain.robot.joints if j.type != "fixed" and j.mimic is None]
    joints = control.findall("joint")
    assert [j.get("name") for j in joints] == movable
    park = CONFIG.model.to_urdf(CONFIG.presets["park"])
    for joint in joints:
        assert [c.get("name") for c in joint.findall("command_interface")] == ["position"]
        initial = joint.findtext("state_interface[@name='position']/param[@name='initial_value']")
        name = joint.get("name", "").removeprefix("left_")  # the namespace's joint prefix
        assert math.isclose(float(initial or "nan"), park[name], abs_tol=1e-12)

    # The controllers command those joints; MoveIt's ros2_control set-up names them.
    controllers = yaml.safe_load((tmp_path / "config" / "ros2_controllers.yaml").read_text())
    manager = controllers["/left/controller_manager"]["ros__parameters"]
    trajectory = controllers["/left/joint_trajectory_controller"]["ros__parameters"]
    gripper = controllers["/left/gripper_action_controller"]["ros__parameters"]
    assert manager["joint_trajectory_controller"]["type"] == (
        "joint_trajectory_controller/JointTrajectoryController"
    )
    assert manager["update_rate"] == CONFIG.server.joint_state_rate_hz
    assert trajectory["joints"] + [gripper["joint"]] == movable
    moveit = yaml.safe_load(
        (tmp_path / "config" / "moveit_ros2_control_controllers.yaml").read_text()
    )["moveit_simple_controller_manager"]
    assert moveit["controller_names"] == [
        "joint_trajectory_controller",
        "gripper_action_controller",
    ]
    assert moveit["joint_trajectory_controller"]["joints"] == trajectory["joints"]
    assert moveit["gripper_action_controller"]["joints"] == [gripper["joint"]]
    # Not the driver's action names: both set-ups leave the server's actions up.
    driver = yaml.safe_load((tmp_path / "config" / "moveit_controllers.yaml").read_text())
    assert not set(moveit["controller_names"]) & set(
        driver["moveit_simple_controller_manager"]["controller_names"]
    )


def test_without_a_namespace_the_hardware_uses_the_root_topics(tmp_path: Path) -> None:
    write_moveit_config(tmp_path, CONFIG, "")
    text = xacro.process_file(str(tmp_path / "config" / "al5d.urdf.xacro")).toxml()
    control = ET.fromstring(text).find("ros2_control")
    assert control is not None
    params = {p.get("name"): p.text for p in control.findall("hardware/param")}
    assert params["joint_states_topic"] == "/joint_states"
    assert params["joint_commands_topic"] == "/joint_commands"
    controllers = yaml.safe_load((tmp_path / "config" / "ros2_controllers.yaml").read_text())
    assert set(controllers) == {
        "controller_manager",
        "joint_trajectory_controller",
        "gripper_action_controller",
    }


def test_the_hardware_sends_a_step_of_one_microsecond_on_any_joint() -> None:
    # A command one microsecond of pulse off the state on a single joint is a move the
    # board makes: the topic hardware must send it (its threshold is below it). At rest the
    # hardware then sends the last command again (the board rounds to whole microseconds);
    # the server writes nothing for those (test_ros_joint_commands).
    from al5d.model import moveit as mv

    model = CONFIG.model
    threshold = mv.command_threshold(
        model, {name: joint.us_per_deg for name, joint in CONFIG.joints.items()}
    )
    assert threshold > 0
    rng = random.Random(24)
    for _ in range(200):
        wanted = {j: rng.uniform(*CONFIG.joints[j].range_deg) for j in CONFIG.joints}
        rounded = {
            j: CONFIG.joints[j].to_deg(round(CONFIG.joints[j].to_us(v))) for j, v in wanted.items()
        }
        state = model.to_urdf(rounded)
        for joint in CONFIG.joints.values():
            stepped = rounded | {joint.name: joint.to_deg(joint.to_us(rounded[joint.name]) + 1)}
            moved = model.to_urdf(stepped)
            assert sum(abs(moved[j] - state[j]) for j in moved) > threshold, joint.name


def test_without_a_park_preset_ros2_control_starts_mid_range() -> None:
    from al5d.model import moveit as mv

    presets = {k: v for k, v in CONFIG.presets.items() if k != "park"}
    chain = arm_chain(CONFIG, "")
    start = mv.initial_positions(CONFIG.model, chain, presets)["initial_positions"]
    for joint in chain.movable:
        lo, hi = CONFIG.model.urdf_limits(joint)
        assert math.isclose(start[joint], (lo + hi) / 2, abs_tol=1e-12), joint


#: Two arms on a table, as `al5d moveit --arms` takes them: each its config with its mount.
ARMS = {"left": (0.0, 0.3, 0.0), "right": (0.05, -0.3, 0.0)}


def arm_configs(folder: Path) -> dict[str, Path]:
    files = {}
    for name, xyz in ARMS.items():
        data = yaml.safe_load(DEFAULT_CONFIG.read_text())
        data["server"]["mount"] = {"parent": "world", "xyz": list(xyz), "rpy": [0.0, 0.0, 0.0]}
        files[name] = folder / f"{name}.yaml"
        files[name].write_text(yaml.safe_dump(data))
    return files


def test_al5d_moveit_arms_writes_one_robot_of_both(tmp_path: Path) -> None:
    files = arm_configs(tmp_path)
    spec = ",".join(f"{name}={path}" for name, path in files.items())
    out = tmp_path / "out"
    proc = Proc("moveit", str(out), "--arms", spec, "--name", "al5d_arms_moveit_config")
    assert proc.wait(30) == 0, proc.err.drain()
    config = out / "config"
    urdf = (config / "al5d.urdf").read_text()
    robot = yourdfpy.URDF.load(io.StringIO(urdf), load_meshes=False)
    assert robot.validate() and robot.base_link == "world"
    joints = [j.name for j in robot.robot.joints]
    assert len(joints) == len(set(joints)), "a joint name twice"
    assert {"left_mount", "right_mount", "left_base", "right_gripper"} <= set(joints)
    # Each tool where its mount and the kinematics put it.
    degrees = dict(CONFIG.presets["ready"])
    values = CONFIG.model.to_urdf(degrees)
    robot.update_cfg({f"{arm}_{j}": v for arm in ARMS for j, v in values.items()})
    for arm, xyz in ARMS.items():
        theirs = robot.get_transform(f"{arm}/tool0", "world")[:3, 3]
        tool = forward(CONFIG.model.geometry, degrees).position
        ours = [a + b for a, b in zip(tool, xyz, strict=True)]
        assert max(abs(a - b) for a, b in zip(theirs, ours, strict=True)) < 1e-9, arm

    srdf = ET.fromstring((config / "al5d.srdf").read_text())
    groups = {g.get("name"): g for g in srdf.findall("group")}
    assert set(groups) == {"left_arm", "left_gripper", "right_arm", "right_gripper", "arms"}
    assert [g.get("name") for g in groups["arms"].findall("group")] == ["left_arm", "right_arm"]
    chain = groups["left_arm"].find("chain")
    assert chain is not None and chain.get("tip_link") == "left/tool0"
    both = srdf.find("group_state[@name='ready'][@group='arms']")
    assert both is not None
    assert {j.get("name") for j in both.findall("joint")} == {
        f"{arm}_{j}" for arm in ARMS for j in ("base", "shoulder", "elbow", "wrist", "wrist_rotate")
    }
    for pair in srdf.findall("disable_collisions"):  # within one arm, never across
        assert pair.get("link1", "").split("/")[0] == pair.get("link2", "").split("/")[0]

    limits = yaml.safe_load((config / "joint_limits.yaml").read_text())["joint_limits"]
    movable = {j.name for j in robot.robot.joints if j.type != "fixed" and j.mimic is None}
    assert set(limits) == movable and len(movable) == 12
    assert set(yaml.safe_load((config / "kinematics.yaml").read_text())) == {
        "left_arm",
        "right_arm",
    }
    manager = yaml.safe_load((config / "moveit_controllers.yaml").read_text())[
        "moveit_simple_controller_manager"
    ]
    assert manager["controller_names"] == [
        "left_arm_controller",
        "left_gripper_controller",
        "right_arm_controller",
        "right_gripper_controller",
    ]
    assert manager["right_gripper_controller"]["joints"] == ["right_gripper"]
    assert set(manager["left_arm_controller"]["joints"]) == {
        j for j in movable if j.startswith("left_") and j != "left_gripper"
    }
    # Each server's configuration, as it runs in its namespace, with its mount.
    for arm, xyz in ARMS.items():
        served = load_config(config / "arms" / f"{arm}.yaml")
        assert served.server.namespace == arm and served.server.joint_name_prefix == f"{arm}_"
        assert served.server.mount is not None and served.server.mount.xyz == xyz
    # move_group reaches each server's actions through its remappings.
    move_group = (out / "launch" / "move_group.launch.py").read_text()
    tree = ast.parse(move_group)
    remaps = next(
        ast.literal_eval(n.value)
        for n in tree.body
        if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", None) == "REMAPPINGS"
    )
    assert [
        "/left_arm_controller/follow_joint_trajectory",
        "/left/arm_controller/follow_joint_trajectory",
    ] in remaps
    assert [
        "/right_gripper_controller/gripper_cmd/_action/send_goal",
        "/right/gripper_controller/gripper_cmd/_action/send_goal",
    ] in remaps
    for launch in (out / "launch").iterdir():
        compile(launch.read_text(), str(launch), "exec")


def test_al5d_moveit_arms_refuses_what_cannot_be_one_robot(tmp_path: Path) -> None:
    files = arm_configs(tmp_path)
    cases = {
        "has no server.mount": ["--arms", "left,right"],  # the shipped config: no mount
        "two arms at least": ["--arms", f"left={files['left']}"],
        "named twice": ["--arms", f"left={files['left']},left={files['right']}"],
        "no --namespace": [
            "--arms",
            f"left={files['left']},right={files['right']}",
            "--namespace",
            "x",
        ],
    }
    for said, args in cases.items():
        proc = Proc("moveit", str(tmp_path / "out"), *args)
        assert proc.wait(30) == 2, said
        assert any(said in line for line in proc.err.drain()), said
    assert not (tmp_path / "out").exists()
