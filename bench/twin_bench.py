"""The physical twin's speed (`make bench`): physics and camera on one core, flat out.

`run` starts this file as a process pinned to one core (Mesa's software renderer on one
thread there), which drives a board (no pty) through a pick-and-place's moves on a clock
of its own, the twin (`al5d.twin`) following it with the scene's 2 ms step and its
camera at 10 Hz at 320 x 240 (the shipped scene), as fast as it computes. The real-time
factor is the seconds simulated over the seconds it took; a frame is 20 ms of physics
(the servos' pulse period), with the camera's picture when one is due.

Run alone: .venv/bin/python bench/twin_bench.py [--seconds 20]; with `--picture FILE`, the
picture of docs/physics.md instead: the twin's camera (at 640 x 480) as the arm carries
the cup toward its goal.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
#: Simulated seconds of the benchmark's run.
SECONDS = 20.0
#: The pick-and-place's poses (the arm's degrees) and each move's time.
POSES: list[tuple[dict[str, float], int]] = [
    ({"base": 0, "shoulder": 30, "elbow": 90, "wrist": 0, "gripper": 0, "wrist_rotate": 0}, 1500),
    ({"base": 26, "shoulder": 35, "elbow": 110, "wrist": -55, "gripper": 0}, 1500),
    ({"base": 26, "shoulder": 52, "elbow": 108, "wrist": -70, "gripper": 0}, 1000),
    ({"gripper": 45}, 600),
    ({"base": 26, "shoulder": 35, "elbow": 110, "wrist": -55}, 1000),
    ({"base": -29, "shoulder": 35, "elbow": 110, "wrist": -55}, 2000),
    ({"base": -29, "shoulder": 50, "elbow": 108, "wrist": -68}, 1000),
    ({"gripper": 0}, 600),
    ({"base": 0, "shoulder": 30, "elbow": 90, "wrist": 0}, 1500),
]


def child(seconds: float) -> dict[str, Any]:
    """In the pinned process: the twin run for `seconds` of simulated time, measured."""
    import numpy as np

    from al5d.arm.config import load_config
    from al5d.twin.camera import Camera
    from al5d.twin.physics import FRAME_S
    from al5d.twin.scene import load_scene
    from al5d_rig.twinrig import TwinRig

    config = load_config()
    scene = load_scene()
    assert scene.camera is not None
    rig = TwinRig(config, scene)
    camera = Camera(rig.twin.model, scene.camera)
    frames: list[float] = []
    pictures: list[float] = []
    next_picture = rig.t
    plan = list(POSES)
    next_move = rig.t
    end = rig.t + seconds
    started = time.perf_counter()
    while rig.t < end:
        if rig.t >= next_move:
            pose, ms = plan[0]
            plan = plan[1:] + plan[:1]
            rig.move(pose, ms)
            next_move = rig.t + ms / 1000 + 0.3
        began = time.perf_counter()
        rig.run(FRAME_S)
        if rig.t >= next_picture:
            drawn = time.perf_counter()
            camera.render(rig.twin.data)
            pictures.append((time.perf_counter() - drawn) * 1000)
            next_picture += camera.period_s
        frames.append((time.perf_counter() - began) * 1000)
    wall = time.perf_counter() - started
    camera.close()
    a = np.asarray(frames)
    return {
        "simulated_s": seconds,
        "wall_s": wall,
        "rtf": seconds / wall,
        "step_ms": scene.physics.step_ms,
        "camera": f"{scene.camera.width}x{scene.camera.height} at {scene.camera.rate_hz:g} Hz",
        "frame_p50_ms": float(np.percentile(a, 50)),
        "frame_p99_ms": float(np.percentile(a, 99)),
        "frame_max_ms": float(a.max()),
        "picture_p50_ms": float(np.percentile(pictures, 50)),
        "pictures": len(pictures),
        "gl": os.environ.get("MUJOCO_GL", ""),
        "cpu": sorted(os.sched_getaffinity(0)),
    }


def run(log: Callable[[str], None], seconds: float = SECONDS) -> dict[str, Any]:
    """The child's figures, run on one core (the last), llvmpipe on one thread."""
    log(f"the physical twin: {seconds:g} s of physics and camera on one core")
    core = max(os.sched_getaffinity(0))
    env = {**os.environ, "LP_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, str(HERE / "twin_bench.py"), "--child", "--seconds", str(seconds)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        preexec_fn=lambda: os.sched_setaffinity(0, {core}),
    )
    figures: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return figures


def rows(r: dict[str, Any]) -> list[tuple[str, str, str, str, bool | None]]:
    return [
        (
            f"physical twin on one core ({r['step_ms']:g} ms step, camera {r['camera']})",
            f"real-time factor {r['rtf']:.1f}; frame (20 ms of physics) p50 "
            f"{r['frame_p50_ms']:.2f} ms, p99 {r['frame_p99_ms']:.2f} ms; a picture "
            f"{r['picture_p50_ms']:.1f} ms",
            "-",
            "real-time factor >= 1",
            r["rtf"] >= 1.0,
        )
    ]


def picture(path: Path) -> None:
    """The shipped scene's camera, 640 x 480, mid-carry: the cup picked and on its way."""
    from matplotlib import image

    from al5d.arm.config import load_config
    from al5d.model import solve
    from al5d.twin.camera import Camera
    from al5d.twin.scene import load_scene
    from al5d_rig.twinrig import TwinRig

    config = load_config()
    scene = load_scene()
    assert scene.camera is not None
    settings = scene.camera.model_copy(update={"width": 640, "height": 480})
    scene = scene.model_copy(update={"camera": settings})
    rig = TwinRig(config, scene)
    rig.move(dict(config.presets["ready"]))
    rig.settle(1.5)
    rig.move_to((200, -100, 100), time_ms=1200, gripper=0)
    rig.move_to((200, -100, 20), time_ms=300, steps=6, gripper=0)
    rig.move({"gripper": 45}, 600)
    rig.settle(1.0)
    rig.move_to((200, -100, 100), time_ms=300, steps=6)
    rig.move(solve(config.model, 0.2, 0.11, 0.1, -90.0), 2500)  # carried to its goal...
    rig.run(1.1)  # ...and on its way there
    camera = Camera(rig.twin.model, settings)
    image.imsave(path, camera.render(rig.twin.data))
    camera.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=SECONDS)
    parser.add_argument("--picture", type=Path, help="write docs/physics.md's picture there")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.picture is not None:
        picture(args.picture)
        return 0
    if args.child:
        print(json.dumps(child(args.seconds)))
        return 0
    r = run(lambda text: print(text, file=sys.stderr), args.seconds)
    for row in rows(r):
        print(f"{row[0]}: {row[1]} (target {row[3]})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
