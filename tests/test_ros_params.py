"""`al5d serve` as a ROS node takes `--ros-args` (issue 24, item 2): parameters named after the
config's keys, remaps of its namespace and name, refusals with the config's messages.

Over real DDS against `al5d serve` in its own process, the emulated board in this one.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.action import get_action_names_and_types
from tf2_msgs.msg import TFMessage

from al5d.arm.config import (
    DEFAULT_CONFIG,
    EMBEDDED_ANSWER_S,
    ArmConfig,
    ConfigError,
    load_config,
)
from al5d.ros import params
from al5d.ros.robot import QOS_TF_STATIC
from al5d.ssc32u.emulator import Emulator
from al5d_rig.armrig import group_moves
from al5d_rig.proc import Proc, patient_config, patient_config_text
from al5d_rig.rospeer import Peer, wait_future, wait_until

#: The node `al5d`, renamed by `-r __node:=`: the others keep their names.
RENAMED = "left_arm"
OTHERS = ("al5d_robot", "al5d_actions", "al5d_safety", "al5d_stop")


@dataclass
class Served:
    emu: Emulator
    proc: Proc
    peer: Peer
    link: Path


@pytest.fixture(scope="module")
def served(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    link = tmp_path_factory.mktemp("params") / "ssc32u"
    emu = Emulator(config, link=link).start()
    # The flags win over the parameters (the board is at 9600), which win over the file.
    proc = Proc(
        "serve",
        "--log-level",
        "INFO",
        "--baud",
        "9600",
        "--ros-args",
        "-p",
        "baud:=115200",
        "-p",
        f"port:={link}",
        "-p",
        f"config_file:={patient_config()}",
        "-p",
        "server.joint_state_rate_hz:=30",
        "-r",
        "__ns:=/left",
        "-r",
        f"__node:={RENAMED}",
    )
    peer = Peer(name="al5d_params_peer", namespace="left")
    try:
        proc.err.wait_for("STATE: ready", 30)
        peer.wait_for_server()
        yield Served(emu, proc, peer, link)
    finally:
        peer.close()
        proc.kill()
        emu.close()


def _value(v: ParameterValue) -> Any:
    return {
        ParameterType.PARAMETER_STRING: v.string_value,
        ParameterType.PARAMETER_INTEGER: v.integer_value,
        ParameterType.PARAMETER_DOUBLE: v.double_value,
        ParameterType.PARAMETER_DOUBLE_ARRAY: list(v.double_array_value),
    }.get(v.type)


def get(peer: Peer, *names: str) -> dict[str, Any]:
    client = peer.node.create_client(GetParameters, f"/left/{RENAMED}/get_parameters")
    try:
        assert client.wait_for_service(timeout_sec=20)
        answer = wait_future(client.call_async(GetParameters.Request(names=list(names))), 20)
        return {n: _value(v) for n, v in zip(names, answer.values, strict=True)}
    finally:
        peer.destroy(client)


def set_one(peer: Peer, name: str, value: ParameterValue) -> Any:
    client = peer.node.create_client(SetParameters, f"/left/{RENAMED}/set_parameters")
    try:
        assert client.wait_for_service(timeout_sec=20)
        request = SetParameters.Request(parameters=[Parameter(name=name, value=value)])
        return wait_future(client.call_async(request), 20).results[0]
    finally:
        peer.destroy(client)


def double(x: float) -> ParameterValue:
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=x)


def test_a_client_over_ros_finds_the_renamed_node(served: Served) -> None:
    """`-r __node:=left_arm` leaves the topics where they were, so that the clients find the
    server (docs/ros.md): a client over ROS 2, as on another machine, has its move done.
    Before, it looked for a node named `al5d` and said that no server answers."""
    from al5d.ros.client import Client

    with Client("left", local=False, wait_s=60) as client:
        outcome = client.execute("move base=4", timeout=60)
    assert outcome.ok, outcome


def test_the_renamed_node_says_its_config_file(served: Served) -> None:
    """`al5d calibrate` and the web view's Calibrate tab write only the file the server
    runs with, asked of its node: the renamed node is asked by its name (before, `al5d`
    was asked, nothing answered, and the page wrote its own file unchecked)."""
    from al5d.ros.names import Names
    from al5d.ros.params import served_config_file

    served_file = served_config_file(served.peer.node, Names.of("left"), 30)
    assert served_file == Path(patient_config())


def test_the_recorder_finds_the_renamed_node(served: Served) -> None:
    """`al5d record` records every arm the graph shows: the renamed node's too (before, it
    looked for nodes named `al5d`, and found none here)."""
    from al5d.app.record import ArmFinder

    found: list[str] = []
    finder = ArmFinder(served.peer.node, found.append)
    try:
        wait_until(lambda: "/left" in found, 30, "the arm in /left")
    finally:
        finder.close()


def test_a_namespace_remap_moves_every_node_name_and_frame(served: Served) -> None:
    node = served.peer.node
    expected = {(RENAMED, "/left"), *((name, "/left") for name in OTHERS)}
    wait_until(
        lambda: expected <= set(node.get_node_names_and_namespaces()), 20, "the server's nodes"
    )

    def strays() -> set[str]:
        return {
            n for n, ns in node.get_node_names_and_namespaces() if n in OTHERS and ns != "/left"
        }

    # Waited for, not read once: a server of the test before, killed, stays in the graph
    # until its participant's lease runs out (a busy CI run saw its nodes at "/" here). A
    # node that the remap did not move would stay for good.
    wait_until(lambda: not strays(), 60, "no node of the server's names outside /left")

    # The graph is learnt entity by entity: the nodes seen does not mean all their topics,
    # services and actions are (seen beside two busy loops: one action of three so far).
    def names(of: Callable[[], Iterable[tuple[str, Any]]]) -> set[str]:
        return {name for name, _ in of()}

    want_topics = {
        "/left/al5d/instruction",
        "/left/al5d/result",
        "/left/al5d/state",
        "/left/joint_states",
        "/left/joint_commands",
        "/left/robot_description",
    }
    want_services = {
        "/left/al5d/stop",
        "/left/al5d/release",
        "/left/al5d/shutdown",
        f"/left/{RENAMED}/set_parameters",
    }
    want_actions = {
        "/left/al5d/move",
        "/left/arm_controller/follow_joint_trajectory",
        "/left/gripper_controller/gripper_cmd",
    }
    wait_until(
        lambda: (
            want_topics <= names(node.get_topic_names_and_types)
            and want_services <= names(node.get_service_names_and_types)
            and want_actions <= names(lambda: get_action_names_and_types(node))
        ),
        20,
        "the server's topics, services and actions under /left",
    )
    # As the nodes above: a killed server's topics stay until its participant's lease runs
    # out (a busy CI run saw /al5d/clients, /al5d/goals/move, ... here).
    wait_until(
        lambda: (
            not {
                t
                for t in names(node.get_topic_names_and_types)
                if t.startswith("/al5d/") or t == "/joint_states"
            }
        ),
        60,
        "no topic of the server's outside /left",
    )
    frames: set[str] = set()
    sub = node.create_subscription(
        TFMessage,
        "/tf_static",
        lambda m: frames.update(t.child_frame_id for t in m.transforms),
        QOS_TF_STATIC,
    )
    try:
        wait_until(lambda: frames, 20, "the static frames")
    finally:
        served.peer.destroy(sub)
    assert all(f.startswith("left/") for f in frames), frames
    # The port parameter named the board: a move reaches it.
    before = len(served.emu.records)
    served.peer.send("p-1", "move", time_ms=200, base=25)
    assert served.peer.result("p-1").outcome == "done"
    assert group_moves(served.emu.records[before:])


def test_the_parameters_read_back_what_the_server_runs_with(served: Served) -> None:
    got = get(
        served.peer,
        "port",
        "config_file",
        "baud",
        "server.namespace",
        "server.joint_state_rate_hz",
        "server.queue_capacity",
        "server.mount.parent",
        "geometry.ulna_mm",
    )
    assert got == {
        "port": str(served.link),
        "config_file": patient_config(),
        "baud": 9600,
        "server.namespace": "left",
        "server.joint_state_rate_hz": 30.0,
        "server.queue_capacity": 1024,
        "server.mount.parent": "",
        "geometry.ulna_mm": 187.325,
    }


def test_a_change_the_server_cannot_take_is_refused_with_the_reason(served: Served) -> None:
    peer = served.peer
    text = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="/dev/ttyUSB9")
    port = set_one(peer, "port", text)
    assert not port.successful and "read-only" in port.reason and "port" in port.reason
    bad = set_one(peer, "server.joint_state_rate_hz", double(-3.0))
    assert not bad.successful
    assert bad.reason == (
        "ROS parameters: server.joint_state_rate_hz: Input should be greater than or equal to 4 "
        "(value: -3.0)"
    )
    # Too slow for the clients, whose sign of the server's life the joint states are.
    slow = set_one(peer, "server.idle_joint_state_rate_hz", double(0.001))
    assert not slow.successful and "greater than or equal to 4" in slow.reason, slow.reason
    # Dynamically typed (so that 50 is taken for 50.0), but a flag or text is no rate: true
    # was taken as 1 Hz, and the parameter read back as a boolean.
    flag = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True)
    text = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="40")
    for value, said in ((flag, "true or false True"), (text, "text '40'")):
        wrong = set_one(peer, "server.joint_state_rate_hz", value)
        assert not wrong.successful
        assert wrong.reason == f"server.joint_state_rate_hz: expected a number, got {said}"
    above = set_one(peer, "server.idle_joint_state_rate_hz", double(45.0))
    assert not above.successful
    assert "idle_joint_state_rate_hz 45 must not exceed joint_state_rate_hz 30" in above.reason
    assert get(peer, "port", "server.joint_state_rate_hz") == {
        "port": str(served.link),
        "server.joint_state_rate_hz": 30.0,
    }


def test_a_change_the_server_can_take_is_applied(served: Served) -> None:
    peer = served.peer
    # An integer, as `ros2 param set ... 40` sends it: taken as the double 40.0.
    forty = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=40)
    done = set_one(peer, "server.joint_state_rate_hz", forty)
    assert done.successful, done.reason
    served.proc.err.wait_for("parameters set: server.joint_state_rate_hz=40.0", 20)
    rate = get(peer, "server.joint_state_rate_hz")["server.joint_state_rate_hz"]
    assert rate == 40.0 and type(rate) is float, rate
    # Now 45 is below it.
    assert set_one(peer, "server.idle_joint_state_rate_hz", double(35.0)).successful
    # The joint states come on, at the new rates, and moves go on as before.
    peer.joint_states.clear()
    peer.send("p-2", "move", time_ms=300, base=-25)
    assert peer.result("p-2").outcome == "done"
    wait_until(lambda: len(peer.joint_states) > 5, 10, "joint states")


def serve_refused(*args: str, config: str | None = None) -> str:
    """`al5d serve` that must not start: its exit code is 2 and its error, the config's."""
    where = ["--config", config] if config else []
    proc = Proc("serve", *where, *args)
    assert proc.wait(60) == 2, proc.err.drain()
    lines = proc.err.drain()
    assert not any("STATE:" in line for line in lines), lines  # no arm was started
    return "\n".join(lines)


def test_a_bad_parameter_gets_the_configs_message_and_exit_2(tmp_path: Path) -> None:
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["server"]["joint_state_rate_hz"] = -5
    in_file = tmp_path / "bad.yaml"
    in_file.write_text(yaml.safe_dump(data))
    message = "server.joint_state_rate_hz: Input should be greater than or equal to 4 (value: -5)"
    assert f"{in_file}: {message}" in serve_refused(config=str(in_file))
    # A parameter's integer is taken as its number (as `ros2 param set` is, at run time).
    message = message.replace("-5)", "-5.0)")
    as_parameter = serve_refused("--ros-args", "-p", "server.joint_state_rate_hz:=-5")
    assert f"ROS parameters: {message}" in as_parameter
    # As a launch file gives parameters: a params file, for every node.
    params = tmp_path / "params.yaml"
    params.write_text(
        yaml.safe_dump({"/**": {"ros__parameters": {"server": {"joint_state_rate_hz": -5}}}})
    )
    assert f"ROS parameters: {message}" in serve_refused("--ros-args", "--params-file", str(params))
    assert "ROS parameters: baud: baud 1234: the SSC-32U runs at" in serve_refused(
        "--ros-args", "-p", "baud:=1234"
    )
    assert "ROS parameters: server.joint_state_rate: not a parameter of al5d" in serve_refused(
        "--ros-args", "-p", "server.joint_state_rate:=50"
    )
    assert "joints and presets are set in the config file only" in serve_refused(
        "--ros-args", "-p", "joints.base.channel:=3"
    )
    assert "the remap __ns:=/left and server.namespace 'right' disagree" in serve_refused(
        "--ros-args", "-r", "__ns:=/left", "-p", "server.namespace:=right"
    )
    assert "ROS arguments: Failed to parse ROS arguments" in serve_refused(
        "--ros-args", "-r", "not-a-rule"
    )


def test_the_parameters_say_the_answer_timeout_the_embedded_emulator_runs_with() -> None:
    # The embedded board is threads of the server's process: its answers are awaited at
    # least EMBEDDED_ANSWER_S (al5d.arm.config), and `ros2 param get` says so; a port's
    # board keeps the file's (or the parameter's) timeout.
    shipped = load_config().server.answer_timeout_s
    assert shipped < EMBEDDED_ANSWER_S
    embedded = params.resolve({}, params.Flags())
    assert embedded.values()["server.answer_timeout_s"] == EMBEDDED_ANSWER_S
    on_port = params.resolve({}, params.Flags(port="/dev/ttyUSB0"))
    assert on_port.values()["server.answer_timeout_s"] == shipped
    raised = params.resolve({"server.answer_timeout_s": 2.5}, params.Flags())
    assert raised.config.server.answer_timeout_s == 2.5


def test_a_parameter_of_the_wrong_type_is_refused_at_the_start_as_at_run_time() -> None:
    """Text for a rate was taken at the start (the config's validation reads "40" as 40) and
    refused when set later: refused at both, in the same words; an integer for a number is
    that number at both."""
    for value, said in (("40", "text '40'"), (True, "true or false True")):
        with pytest.raises(ConfigError) as e:
            params.resolve({"server.joint_state_rate_hz": value}, params.Flags())
        assert str(e.value) == (
            f"ROS parameters: server.joint_state_rate_hz: expected a number, got {said}"
        )
    with pytest.raises(ConfigError, match=r"baud: expected an integer, got a number 9600\.0"):
        params.resolve({"baud": 9600.0}, params.Flags())
    rate = params.resolve({"server.joint_state_rate_hz": 40}, params.Flags())
    taken = rate.values()["server.joint_state_rate_hz"]
    assert taken == 40.0 and type(taken) is float


def test_a_config_file_named_relative_to_the_server_is_said_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`ros2 param get` (and a client that writes the file: the web view's calibration)
    reads the whole path: a relative one, read in the client's directory, is another file."""
    (tmp_path / "arm.yaml").write_text(patient_config_text(), "utf-8")
    monkeypatch.chdir(tmp_path)
    for given, flags in (
        ({"config_file": "arm.yaml"}, params.Flags()),
        ({}, params.Flags(config="arm.yaml")),
    ):
        settings = params.resolve(given, flags)
        assert settings.values()["config_file"] == str(tmp_path / "arm.yaml"), given
    assert params.resolve({}, params.Flags()).values()["config_file"] == ""
