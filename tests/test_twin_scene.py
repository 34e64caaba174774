"""The twin's scene file (issue 47): the shipped one is valid, and a mistake is said with
its key, its value and why, by the library and by the command line before anything
starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from al5d import exits
from al5d.twin.scene import DEFAULT_SCENE, SceneError, load_scene, parse_scene

CUP = {"shape": "cup", "radius_mm": 13, "height_mm": 55, "wall_mm": 2, "mass_g": 25}


def objects(**each: dict[str, Any]) -> dict[str, Any]:
    return {"objects": {name: {"xyz_mm": [200, 0, 0], **o} for name, o in each.items()}}


def test_the_shipped_scene_is_valid_with_a_cup_a_camera_and_a_2_ms_step() -> None:
    scene = load_scene()
    assert scene.physics.step_ms <= 2
    assert scene.camera is not None and (scene.camera.width, scene.camera.height) == (320, 240)
    assert scene.camera.rate_hz == 10
    assert scene.objects["cup"].shape == "cup"
    assert load_scene(DEFAULT_SCENE) == scene


@pytest.mark.parametrize(
    ("data", "said"),
    [
        (objects(cup={**CUP, "mass_g": -5}), "objects.cup.mass_g: Input should be greater than 0"),
        (objects(cup={**CUP, "wall_mm": None}), "objects.cup: a cup needs wall_mm"),
        (objects(cup={**CUP, "size_mm": [1, 2, 3]}), "objects.cup: a cup has no size_mm"),
        (objects(cup={**CUP, "colour": "red"}), "objects.cup.colour: a colour is written #rrggbb"),
        (objects(cup={**CUP, "wall_mm": 20}), "wall_mm 20 must be thinner than radius_mm"),
        (
            objects(cup={**CUP, "xyz_mm": [900, 0, 0]}),
            "objects.cup.xyz_mm: (900, 0) is off the table",
        ),
        (
            objects(cup={**CUP, "xyz_mm": [200, 0, -3]}),
            "objects.cup.xyz_mm: z -3 is below the table",
        ),
        (
            objects(cup={**CUP, "goal_mm": [0, 900]}),
            "objects.cup.goal_mm: (0, 900) is off the table",
        ),
        (
            objects(cup={**CUP, "xyz_mm": [10, 0, 0]}),
            "objects.cup.xyz_mm: it stands in the arm's base",
        ),
        (objects(cup={**CUP, "shape": "sphere"}), "objects.cup.shape: Input should be 'box'"),
        (objects(cup={**CUP, "weight": 3}), "objects.cup.weight: Extra inputs are not permitted"),
        (objects(tool0=CUP), "objects.tool0: the name of a frame of the arm or the scene"),
        (objects(cup=CUP, mug={**CUP, "xyz_mm": [210, 0, 0]}), "objects.mug: it stands in cup"),
        ({"physics": {"step_ms": 5}}, "physics.step_ms: Input should be less than or equal to 2"),
        ({"camera": {"width": 0}}, "camera.width: Input should be greater than or equal to 16"),
        ({"camera": {"look_at_mm": [500, -330, 280]}}, "look_at_mm: the camera must look at a"),
        ({"table": {"size_mm": [600]}}, "table.size_mm"),
        ([1, 2], "the scene file must hold a mapping"),
    ],
)
def test_a_mistake_is_said_with_its_key(data: Any, said: str) -> None:
    with pytest.raises(SceneError) as caught:
        parse_scene(data, "scene.yaml")
    assert said in str(caught.value)
    assert str(caught.value).startswith("scene.yaml")


def test_a_bad_scene_file_stops_the_emulator_before_it_starts(tmp_path: Path) -> None:
    """`al5d emulator --physics FILE` reads the scene first: exit 2, the key named, no board."""
    bad = tmp_path / "scene.yaml"
    bad.write_text(yaml.safe_dump(objects(cup={**CUP, "friction": 0})))
    done = subprocess.run(
        [sys.executable, "-m", "al5d", "emulator", "--physics", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == exits.USAGE, done.stderr
    assert f"{bad}: objects.cup.friction: Input should be greater than 0" in done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""
    missing = subprocess.run(
        [sys.executable, "-m", "al5d", "emulator", "--physics", str(tmp_path / "none.yaml")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert missing.returncode == exits.USAGE
    assert "none.yaml: cannot read the scene" in missing.stderr


def test_serve_with_a_port_refuses_a_twin(tmp_path: Path) -> None:
    """The twin follows an emulated board's pulses: `al5d serve --port DEV --physics` ran
    without one and said nothing; it is refused, with what to do instead."""
    done = subprocess.run(
        [sys.executable, "-m", "al5d", "serve", "--port", str(tmp_path / "tty"), "--physics"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == exits.USAGE, done.stderr
    assert "--physics runs the twin of the embedded emulated board" in done.stderr
    assert "Traceback" not in done.stderr
