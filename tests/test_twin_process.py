"""`al5d emulator --physics` (issue 47): the board on its pty with its twin in a process of
its own. A 1 kg cup carried out to full reach holds the shoulder short, and the twin says
so in the log and on its topic; the board received the very same bytes as a board without
a twin; the twin's camera, objects and joints are on ROS."""

from __future__ import annotations

import json
import re
import signal
import time
from pathlib import Path
from typing import Any

import yaml
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from al5d import exits
from al5d.arm.config import ArmConfig
from al5d.ros.names import Names
from al5d.ssc32u.driver import SSC32U
from al5d.twin.node import QOS_PICTURES, QOS_WORDS
from al5d_rig.proc import PATIENT_ANSWER_S, Proc
from al5d_rig.rospeer import Peer, wait_until

HEAVY = {
    "camera": {"width": 320, "height": 240, "rate_hz": 10},
    # The table behind the arm: nothing under its reach for the cup to come to rest on.
    "table": {"center_mm": [-250, 0], "size_mm": [200, 200]},
    "objects": {
        "cup": {
            "shape": "cup",
            "radius_mm": 13,
            "height_mm": 55,
            "wall_mm": 2,
            "mass_g": 1000,
            "in_gripper": True,
        }
    },
}
#: The twin's start (MuJoCo, the model, the GL context, DDS) on a busy host.
START_S = 90.0


def pulses(config: ArmConfig, degrees: dict[str, float]) -> dict[int, int]:
    return {config.joints[n].channel: round(config.joints[n].to_us(d)) for n, d in degrees.items()}


def sequence(config: ArmConfig) -> list[tuple[dict[int, int], int, float]]:
    """(pulses, time ms, seconds to wait after): the heavy cup in the gripper held close in,
    the forearm hanging, then out to full reach."""
    ready = {"base": 0, "shoulder": 45, "elbow": 135, "wrist": 0, "gripper": 40, "wrist_rotate": 0}
    steps = [(pulses(config, ready), 0, 2.0), (pulses(config, {"base": 20}), 800, 1.5)]
    steps += [(pulses(config, {"shoulder": 70, "elbow": 40, "wrist": -70}), 1500, 4.0)]
    steps += [(pulses(config, {"base": 0}), 800, 1.5)]
    return steps


def run_board(
    tmp: Path, config: ArmConfig, physics: Path | None, peer: Peer | None = None
) -> tuple[list[tuple[str, Any]], list[str]]:
    """The sequence written to `al5d emulator` (with a twin in `physics`): the lines it
    received (bytes, why ignored) and what it said on stderr."""
    link = tmp / ("twin" if physics else "plain")
    args = ["emulator", "--link", str(link), "--record", "-"]
    board = Proc(*args, *(["--physics", str(physics)] if physics else []))
    try:
        board.out.wait_for(str(link), START_S)
        # A board whose process also steps the physics and renders the camera: on a loaded
        # host it once missed the default 0.05 s for both asks of `Q` (a CI run).
        with SSC32U(str(link), 9600, read_timeout_s=PATIENT_ANSWER_S) as ssc:
            for targets, ms, wait in sequence(config):
                ssc.move(targets, time_ms=ms or None)
                time.sleep(wait if physics else 0.05)
            ssc.is_done()
            if physics:
                board.err.wait_for("shoulder held", 30)
        board.popen.send_signal(signal.SIGINT)
        assert board.wait(60) == 0
    finally:
        board.kill()
    records = [json.loads(x) for x in board.out.drain(1.0) if x.startswith("{")]
    return [(r["raw"], r["ignored"]) for r in records], board.err.drain(0.5)


def test_a_heavy_cup_holds_the_shoulder_short_and_the_board_hears_the_same_bytes(
    tmp_path: Path, config: ArmConfig
) -> None:
    scene = tmp_path / "heavy.yaml"
    scene.write_text(yaml.safe_dump(HEAVY))
    names = Names()
    seen: dict[str, list[Any]] = {
        k: [] for k in ("image", "info", "objects", "tf", "held", "joints")
    }
    peer = Peer(results=False)
    try:
        peer.read(Image, names.camera_image, seen["image"].append, QOS_PICTURES)
        peer.read(CameraInfo, names.camera_info, seen["info"].append, QOS_PICTURES)
        peer.read(MarkerArray, names.twin_objects, seen["objects"].append, 10)
        peer.read(TFMessage, "/tf", seen["tf"].append, 100)
        peer.read(String, names.twin_held, seen["held"].append, QOS_WORDS)
        peer.read(JointState, names.twin_joint_states, seen["joints"].append, 10)
        with_twin, said = run_board(tmp_path, config, scene, peer)
        wait_until(lambda: seen["held"], 10, "the twin's word on its topic")
    finally:
        peer.close()
    without, _ = run_board(tmp_path, config, None)
    # The board's record of the moves, byte for byte: a twin only listens. (The queries are
    # left out: a busy host can make the client ask VER or Q twice in one run, not the other.)
    moves = [(raw, why) for raw, why in with_twin if raw.startswith("#")]
    assert moves == [(raw, why) for raw, why in without if raw.startswith("#")]
    assert len(moves) == len(sequence(config))

    held = [line for line in said if "twin: shoulder held" in line]
    assert held, "\n".join(said[-20:])
    found = re.search(r"shoulder held (\d+) deg past its target: (\d+) kg cm needed", held[0])
    assert found, held[0]
    assert int(found.group(1)) > 5 and int(found.group(2)) > 24.7
    assert held[0].endswith("the servo gives 24.7")
    assert any(m.data.startswith("shoulder held") for m in seen["held"])

    image, info = seen["image"][-1], seen["info"][-1]
    assert (image.width, image.height, image.encoding, image.step) == (320, 240, "rgb8", 960)
    assert len(image.data) == 320 * 240 * 3 and len(set(image.data[::97])) > 10  # not blank
    assert image.header.frame_id == info.header.frame_id == "camera_optical_frame"
    assert (info.width, info.height) == (320, 240) and info.k[2] == 160 and info.k[5] == 120
    assert len(seen["image"]) >= 20  # 10 a second over the sequence's 15 s
    cup = [m for msg in seen["objects"][-1:] for m in msg.markers if m.ns == "cup"]
    assert cup and cup[0].header.frame_id == "base_link"
    frames = {t.child_frame_id for msg in seen["tf"] for t in msg.transforms}
    assert "cup" in frames
    assert {"shoulder", "gripper_left"} <= set(seen["joints"][-1].name)


def test_the_twin_of_an_emulator_in_a_namespace_is_in_that_namespace(tmp_path: Path) -> None:
    """`al5d emulator --namespace left --physics`: the twin's topics are under /left, beside
    the server that drives that board (`al5d web --namespace left` shows it). Before, the
    option reached only the misaligned arm's true angles, and the twin was under the
    configuration's namespace (none). Its joints are named as the server's own there
    (`left_shoulder`): an outside try found them unprefixed, which RViz and a second arm
    match to nothing."""
    link = tmp_path / "left"
    joints: list[JointState] = []
    peer = Peer(results=False)
    board = Proc("emulator", "--link", str(link), "--namespace", "left", "--physics")
    try:
        peer.read(JointState, Names.of("left").twin_joint_states, joints.append, 10)
        board.out.wait_for(str(link), START_S)
        wait_until(lambda: joints, START_S, "the twin's joint states under /left")
        assert {"left_shoulder", "left_gripper_left"} <= set(joints[-1].name), joints[-1].name
        assert all(name.startswith("left_") for name in joints[-1].name), joints[-1].name
        board.popen.send_signal(signal.SIGINT)
        assert board.wait(60) == 0
    finally:
        board.kill()
        peer.close()


def test_a_twin_that_cannot_render_says_why_in_a_line() -> None:
    """`MUJOCO_GL` naming no GL MuJoCo has: the emulator ends at once, exit 2, with the
    twin's reason and what to do, not a traceback (an outside try: a traceback from the
    twin's process, then "did not start in 60 s" after 0.6 s)."""
    board = Proc("emulator", "--physics", env={"MUJOCO_GL": "bogus"})
    try:
        assert board.wait(START_S) == exits.USAGE
    finally:
        board.kill()
    err = "\n".join(board.err.drain())
    assert "the physical twin could not start: RuntimeError: invalid value" in err, err
    assert "MUJOCO_GL=bogus" in err and "egl" in err, err
    assert "Traceback" not in err and "in 60 s" not in err, err
