"""The arm as a robot in ROS (issue 13): description, transforms, joint states, Cartesian moves.

Over real DDS against `al5d serve` in its own process, the emulated board here.
"""

from __future__ import annotations

import io
import itertools
import math
import statistics
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yourdfpy
from al5d_interfaces.action import Move
from al5d_interfaces.msg import ArmInstruction
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from al5d.arm.config import ArmConfig
from al5d.model import forward
from al5d.model.transforms import Transform
from al5d.ros.qos import QOS_LATCHED
from al5d.ros.robot import QOS_TF_STATIC
from al5d.ssc32u.emulator import Emulator
from al5d_rig.proc import Proc, patient_config
from al5d_rig.rospeer import Peer, wait_future, wait_until


@pytest.fixture(scope="module")
def served(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    link = tmp_path_factory.mktemp("robot") / "ssc32u"
    emu = Emulator(config, link=link).start()
    proc = Proc("serve", "--port", str(link), "--config", patient_config(), "--log-level", "INFO")
    peer = Peer(name="al5d_robot_peer")
    try:
        proc.err.wait_for("STATE: ready", 30)
        peer.wait_for_server()
        yield emu, peer
    finally:
        peer.close()
        proc.kill()
        emu.close()


def latest(peer: Peer, kind: Any, topic: str, qos: Any, n: int = 1) -> list[Any]:
    got: list[Any] = []
    sub = peer.node.create_subscription(kind, topic, got.append, qos)
    try:
        wait_until(lambda: len(got) >= n, 10, topic)
    finally:
        peer.destroy(sub)
    return got


def test_the_description_is_latched_for_a_late_subscriber_and_is_al5d_urdf(
    served: Any, tmp_path: Path
) -> None:
    _, peer = served
    text = latest(peer, String, "/robot_description", QOS_LATCHED)[0].data
    robot = yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=True, load_meshes=False)
    assert robot.validate() and robot.base_link == "base_link" and "tool0" in robot.link_map
    printed = Proc("urdf")
    assert printed.wait(30) == 0
    assert "\n".join(printed.out.drain()).strip() == text.strip()


def test_joint_states_carry_the_urdfs_joint_names(served: Any) -> None:
    _, peer = served
    text = latest(peer, String, "/robot_description", QOS_LATCHED)[0].data
    robot = yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=False, load_meshes=False)
    actuated = [j.name for j in robot.robot.joints if j.type != "fixed" and j.mimic is None]
    peer.joint_states.clear()
    wait_until(lambda: peer.joint_states, 5, "joint_states")
    assert sorted(peer.joint_states[-1].name) == sorted(actuated)


def median_period_ms(peer: Peer, seconds: float) -> float:
    """The median time between the joint states' stamps that come in the next `seconds`."""
    peer.joint_states.clear()
    time.sleep(seconds)
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in peer.joint_states]
    assert len(stamps) >= 3, f"{len(stamps)} joint states in {seconds} s"
    return statistics.median(b - a for a, b in itertools.pairwise(stamps)) * 1000


def test_joint_states_at_the_moving_rate_while_moving_and_the_idle_rate_at_rest(
    served: Any, config: ArmConfig
) -> None:
    emu, peer = served
    moving_ms = 1000 / config.server.joint_state_rate_hz
    idle_ms = 1000 / config.server.idle_joint_state_rate_hz
    split = (moving_ms + idle_ms) / 2
    time.sleep(1.5)  # more than the second at rest after which the idle rate comes
    at_rest = median_period_ms(peer, 1.5)
    base = -40.0 if emu.servo_degrees()["base"] > 0 else 40.0
    peer.send("rate-move", "move", 2500, base=base)
    time.sleep(0.3)
    moving = median_period_ms(peer, 1.5)
    assert peer.result("rate-move").outcome == "done"
    time.sleep(1.5)
    at_rest_again = median_period_ms(peer, 1.5)
    assert at_rest > split and moving < split and at_rest_again > split, (
        at_rest,
        moving,
        at_rest_again,
    )


def test_the_tf_tree_reaches_tool0_where_the_emulated_arm_puts_it(
    served: Any, config: ArmConfig
) -> None:
    emu, peer = served
    peer.send("tf-move", "move", base=30, shoulder=20, elbow=80, wrist=-10, wrist_rotate=40)
    assert peer.result("tf-move").outcome == "done"
    static = latest(peer, TFMessage, "/tf_static", QOS_TF_STATIC)[0].transforms
    moving = latest(peer, TFMessage, "/tf", 100, n=3)[-1].transforms
    parent_of = {t.child_frame_id: t for t in (*static, *moving)}
    frame, chain = "tool0", Transform()
    while frame != "base_link":
        assert frame in parent_of, f"no transform to {frame}: the tree is broken"
        t = parent_of[frame]
        tr, q = t.transform.translation, t.transform.rotation
        chain = Transform((tr.x, tr.y, tr.z), (q.x, q.y, q.z, q.w)) * chain
        frame = t.header.frame_id
    expected = forward(config.model.geometry, emu.servo_degrees()).position
    assert math.dist(chain.translation, expected) < 0.002
    pose = latest(peer, PoseStamped, "/al5d/tool_pose", 10)[0]
    p = pose.pose.position
    assert pose.header.frame_id == "base_link"
    assert math.dist((p.x, p.y, p.z), expected) < 0.002


def test_move_to_over_the_topic_in_ros_units(served: Any, config: ArmConfig) -> None:
    emu, peer = served
    msg = ArmInstruction(
        instruction="move_to",
        joints=["x", "y", "z", "pitch"],
        degrees=[0.28, 0.06, 0.10, math.radians(-30)],
        id="mt-1",
    )
    peer.pub.publish(msg)
    assert peer.result("mt-1").outcome == "done", peer.result("mt-1").reason
    tip = forward(config.model.geometry, emu.servo_degrees()).position
    assert math.dist(tip, (0.28, 0.06, 0.10)) < 0.0015
    msg.degrees, msg.id = [0.6, 0.0, 0.1, 0.0], "mt-far"
    peer.pub.publish(msg)
    far = peer.result("mt-far")
    assert far.outcome == "refused" and "out of reach" in far.reason


def test_move_to_as_a_move_goal_with_a_straight_line(served: Any, config: ArmConfig) -> None:
    emu, peer = served
    start = Move.Goal(joints=["x", "y", "z", "pitch"], degrees=[0.25, -0.12, 0.06, -0.5236])
    assert wait_future(peer.send_goal(start).get_result_async()).result.outcome == "done"
    line = Move.Goal(
        joints=["x", "y", "z", "pitch", "path"], degrees=[0.25, 0.12, 0.14, -0.5236, 1.0]
    )
    n = sum(r.raw.startswith(b"#") for r in emu.records)
    result = wait_future(peer.send_goal(line).get_result_async(), 20).result
    assert result.outcome == "done", result.reason
    assert sum(r.raw.startswith(b"#") for r in emu.records) - n > 1  # cut into group moves
    tip = forward(config.model.geometry, emu.servo_degrees()).position
    assert math.dist(tip, (0.25, 0.12, 0.14)) < 0.0015


def test_move_to_from_the_command_line(served: Any) -> None:
    _, _ = served
    ok = Proc("send", "move_to", "x=280", "y=0", "z=100", "pitch=-30", "path=line")
    assert ok.wait(30) == 0, ok.out.drain()
    refused = Proc("send", "move_to", "x=600", "y=0", "z=100")
    assert refused.wait(30) == 1
    assert any("no pitch reaches" in line for line in refused.out.drain())
