"""`al5d demo --physics` (issue 47), as a user runs it from a fresh clone: the sequence
picks the scene's cup, lifts it at least 50 mm and sets it down within 10 mm of its
goal; the demo prints its QoS table and where the cup ended. `al5d record` beside it
holds the camera's pictures beside the joint states, read back with the `mcap` reader."""

from __future__ import annotations

import math
import re
import signal
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from al5d.app.demo import Placement, tilt_deg
from al5d.ros.names import Names
from al5d_rig.proc import Proc


def test_the_demo_picks_the_cup_and_sets_it_down_at_its_goal_recorded(tmp_path: Path) -> None:
    names = Names()
    path = tmp_path / "demo.mcap"
    recorder = Proc("record", str(path))
    try:
        recorder.out.wait_for("recording to", 60)
        demo = Proc("demo", "--physics")
        code = demo.wait(400)
        out = demo.out.drain(1.0)
        text = "\n".join(out)
        # What the twin said (how far behind real time it fell, what it skipped), for a miss,
        # and the last of everything else.
        err = demo.err.drain(0.5)
        said = "\n".join([line for line in err[:-30] if "twin" in line] + err[-30:])
        # 0, or 1 when a move's QoS missed SA03's bound on a busy host (the table says MISSED):
        # the cup's measures below are what this test is about. (The cup's own line says
        # MISSED too when it is not at its goal: not counted here.)
        objects = ("cup:", "block:")
        qos_missed = any("MISSED" in line for line in out if not line.startswith(objects))
        assert code == 0 or (code == 1 and qos_missed), text + "\n" + said
        recorder.out.wait_for(f"{names.camera_image}: 1 writer", 5)
        recorder.popen.send_signal(signal.SIGINT)
        assert recorder.wait(60) == 0
    finally:
        recorder.kill()

    assert "QoS achieved per move (DE02):" in text
    placed = [line for line in out if line.startswith("cup: lifted")]
    assert placed, text
    found = re.search(r"lifted (\d+) mm at most; .*?, ([\d.]+) mm from its goal", placed[0])
    assert found, placed[0]
    assert int(found.group(1)) >= 50, text + "\n" + said
    assert float(found.group(2)) <= 10, text + "\n" + said
    assert ": held (" in placed[0]
    block = [line for line in out if line.startswith("block: no goal;")]
    assert block and ": stayed (" in block[0], text  # nothing knocked on the way

    counts: Counter[str] = Counter()
    picture = None
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == names.camera_image and picture is None:
                picture = decoded
    assert counts[names.camera_image] >= 50, counts  # 10 a second through a 15 s demo
    assert counts[names.camera_info] >= 50
    assert counts[names.joint_states] >= 100 and counts[names.twin_joint_states] >= 100
    assert counts[names.twin_objects] > 0
    assert picture is not None
    assert (picture.width, picture.height, picture.encoding) == (320, 240, "rgb8")
    assert len(picture.data) == 320 * 240 * 3


def test_the_demos_verdict_says_how_each_object_ended() -> None:
    """Set down, standing, at its goal: held. A cup fallen on its side, or never lifted, is
    said so and MISSED (an outside try read "set down" of both: 13.1 mm above the table
    was a cup of radius 13 on its side). An object without a goal knocked from where it
    stood is MISSED too (the shipped block, knocked over by `ready`, was said nowhere)."""
    side = (math.sin(math.pi / 4), 0.0, 0.0, math.cos(math.pi / 4))  # 90 deg about x
    assert tilt_deg(side) == pytest.approx(90.0)
    assert tilt_deg((0.0, 0.0, math.sin(0.3), math.cos(0.3))) == pytest.approx(0.0)  # yawed
    goal = (200.0, 110.0)
    placed = Placement("cup", goal, (197.8, 108.7, 0.0), 70.0, 1.0)
    assert placed.held and "set down at (197.8, 108.7) mm" in placed.line()
    fallen = Placement("cup", goal, (211.8, -83.3, 13.1), 14.0, 90.0)
    assert not fallen.held
    assert "lies on its side (90 deg from upright) at (211.8, -83.3)" in fallen.line()
    assert "MISSED" in fallen.line() and "set down" not in fallen.line()
    tipped_at_goal = Placement("cup", goal, (200.0, 110.0, 13.0), 70.0, 85.0)
    assert not tipped_at_goal.held
    upside_down = Placement("cup", goal, (200.0, 110.0, 55.0), 70.0, 178.0)
    assert not upside_down.held and "lies upside down (178 deg" in upside_down.line()
    stayed = Placement("block", None, (300.4, 120.3, 0.0), 0.0, 0.5, (300.0, 120.0))
    assert stayed.held
    assert stayed.line() == (
        "block: no goal; 0.5 mm from where it stood (300, 120): stayed (within 10 mm, upright)"
    )
    knocked = Placement("block", None, (350.4, 36.5, 20.0), 0.0, 90.0, (330.0, 30.0))
    assert not knocked.held
    assert "21.4 mm from where it stood (330, 30), 90 deg from upright: MISSED" in knocked.line()
    never = Placement("cup", goal, (200.0, -100.0, 0.0), 0.0, 0.0)
    assert not never.held
    assert "cup: never lifted; stands at (200.0, -100.0) mm" in never.line()
