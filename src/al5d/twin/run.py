"""`python -m al5d.twin.run`: the twin in a process of its own, in real time, fed by its board.

Its stdin: first one JSON line that says what to build (`Start`: the arm's configuration,
the scene, the servos' positions and the board's time at the start, the ROS namespace),
then one JSON line per change of a channel's pulses (`{"ch": 1, "pulse": [on, start_us,
end_us, t0, t1, offset_us]}`). Its stdout: one JSON line per event, for its board's
process (`al5d.twin.link`): `ready`, `held` (a joint held short), `objects` (their poses,
a few times a second while they move), `behind` (the physics could not keep up and
skipped time), `end`; or `failed` (it could not start: why). It ends when stdin closes
(its board's process has gone) or at SIGTERM; SIGINT (a terminal's Ctrl-C, which its
board's process handles) does not end it.

A process of its own, so that neither the physics nor the software rendering ever holds
the board's or the server's interpreter, and behind both for the CPU (`NICE`): on a busy
host the twin falls behind first, catches up without pictures (its physics alone takes
about 4 % of a core), and skips ahead only when more than a second behind.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import sys
import threading
import time
import traceback
from dataclasses import asdict, dataclass
from typing import Any, TextIO

from al5d.clock import now

#: The twin's niceness at least: the board (`al5d emulator` runs at -10) and the server (0)
#: go first.
NICE = 5
#: The joints' and the objects' topics, a second.
PUBLISH_HZ = 25.0
#: The objects' poses to the board's process, a second (while they move).
REPORT_HZ = 5.0
#: Behind real time by more than this (its process was not scheduled: a busy host), the
#: twin catches up without pictures, its physics alone (about 30 times real time)...
CATCH_UP_S = 0.06
#: ...and further behind than this, it skips ahead (and says so): the arm's pulses have
#: moved on meanwhile, and the twin follows them from now.
MAX_BEHIND_S = 1.0
#: An object that moved less than this since it was last reported is not reported again.
MOVED_M = 0.0005
#: Words of what MuJoCo raises when the GL its renderer needs is missing, or `MUJOCO_GL`
#: names none (egl, osmesa, glfw: a missing library, no display, no such value).
GL_WORDS = ("OpenGL", "MUJOCO_GL", "glGetError", "GLFW", "EGL", "OSMesa", "mjr_makeContext")


@dataclass(frozen=True)
class Start:
    """What the twin is built from (its stdin's first line)."""

    config: dict[str, Any]
    scene: dict[str, Any]
    pose: dict[str, float]
    mechanics: dict[str, tuple[float, bool]]
    start: float
    namespace: str
    ros: bool = True

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def pulse_line(channel: int, pulse: Any) -> str:
    """A change of a channel's pulses, as the twin reads it."""
    p = [pulse.on, pulse.start_us, pulse.end_us, pulse.t0, pulse.t1, pulse.offset_us]
    return json.dumps({"ch": channel, "pulse": p})


class Loop:
    """The twin, its camera and its node, run in real time from the board's pulses."""

    def __init__(self, start: Start, out: TextIO) -> None:
        from al5d.arm.config import parse_config
        from al5d.ssc32u.emulator import Mechanics
        from al5d.twin.physics import Twin
        from al5d.twin.scene import parse_scene

        self.out = out
        config = parse_config(start.config, "the twin's configuration")
        self.scene = parse_scene(start.scene, "the twin's scene")
        mechanics = {k: Mechanics(off, rev) for k, (off, rev) in start.mechanics.items()}
        self.twin = Twin(
            config, self.scene, start=start.start, pose=start.pose, mechanics=mechanics
        )
        self.camera = None
        cam = self.scene.camera
        if cam is not None and cam.rate_hz > 0:
            from al5d.twin.camera import Camera

            self.camera = Camera(self.twin.model, cam)
        self.node = None
        if start.ros:
            from al5d.ros.names import Names
            from al5d.twin.node import TwinNode, camera_pose

            pose = None
            if self.camera is not None:
                d = self.twin.data
                pose = camera_pose(d.cam_xpos[0], d.cam_xmat[0])
            intrinsics = self.camera.intrinsics if self.camera is not None else None
            prefix = config.server.joint_prefix_in(start.namespace)
            self.node = TwinNode(Names.of(start.namespace), self.scene, pose, intrinsics, prefix)
        self.pulses: queue.SimpleQueue[tuple[int, Any]] = queue.SimpleQueue()
        self.done = threading.Event()
        self.busy_s = 0.0
        self.skipped_s = 0.0
        self.pictures = 0
        self._reported: dict[str, tuple[float, ...]] = {}

    def say(self, kind: str, what: Any) -> None:
        self.out.write(json.dumps({kind: what}) + "\n")
        self.out.flush()

    def read(self, stream: TextIO) -> None:
        """The board's pulses, until the stream ends (then the loop ends too)."""
        from al5d.ssc32u.emulator import Pulse

        for line in stream:
            data = json.loads(line)
            on, start_us, end_us, t0, t1, offset = data["pulse"]
            self.pulses.put(
                (int(data["ch"]), Pulse(bool(on), start_us, end_us, t0, t1, int(offset)))
            )
        self.done.set()

    def run(self) -> None:
        import mujoco

        from al5d.twin.physics import FRAME_S

        twin = self.twin
        cam = self.scene.camera
        if self.camera is not None:
            self.camera.render(twin.data)  # the first picture sets the renderer up (0.3 s)
        # Real time from here: what the board put out meanwhile is followed from now on.
        twin.t = max(twin.t, now())
        self.say(
            "ready",
            {
                "mujoco": mujoco.__version__,
                "step_ms": self.scene.physics.step_ms,
                "camera": None
                if self.camera is None or cam is None
                else f"{cam.width}x{cam.height} at {cam.rate_hz:g} Hz",
                "gl": os.environ.get("MUJOCO_GL", ""),
            },
        )
        next_publish = next_report = next_picture = twin.t
        while not self.done.is_set():
            wait = twin.t + FRAME_S - now()
            if wait > 0 and self.done.wait(wait):
                break
            began = time.perf_counter()
            while True:
                try:
                    twin.follow(*self.pulses.get_nowait())
                except queue.Empty:
                    break
            t = now()
            if t - twin.t > MAX_BEHIND_S:
                behind = t - twin.t - FRAME_S
                self.skipped_s += behind
                twin.t += behind
                self.say(
                    "behind", {"skipped_s": round(behind, 3), "total_s": round(self.skipped_s, 3)}
                )
            for held in twin.advance_to(t):
                self.say("held", {**asdict(held), "text": held.text})
                if self.node is not None:
                    self.node.publish_held(held.text)
            if twin.t >= next_publish:
                next_publish = max(next_publish + 1 / PUBLISH_HZ, twin.t)
                if self.node is not None:
                    stamp = self.node.stamp()
                    self.node.publish_joints(twin.urdf_values(), stamp)
                    self.node.publish_objects(twin.objects(), stamp)
            catching_up = now() - twin.t > CATCH_UP_S
            if self.camera is not None and twin.t >= next_picture and not catching_up:
                next_picture = max(next_picture + self.camera.period_s, twin.t)
                picture = self.camera.render(twin.data)
                self.pictures += 1
                if self.node is not None:
                    self.node.publish_picture(picture, self.node.stamp())
            if twin.t >= next_report:
                next_report = max(next_report + 1 / REPORT_HZ, twin.t)
                self.report_objects()
            self.busy_s += time.perf_counter() - began
        self.report_objects(force=True)
        self.say(
            "end",
            {
                "busy_s": round(self.busy_s, 3),
                "skipped_s": round(self.skipped_s, 3),
                "pictures": self.pictures,
                "deepest_mm": {k: round(v * 1000, 2) for k, v in self.twin.deepest.items()},
            },
        )

    def report_objects(self, force: bool = False) -> None:
        states = self.twin.objects()
        moved = {}
        for name, s in states.items():
            key = (*s.position, *s.rotation, s.lifted_m)  # a tilt that barely moves it too
            last = self._reported.get(name)
            if (
                force
                or last is None
                or max(abs(a - b) for a, b in zip(key, last, strict=True)) > MOVED_M
            ):
                self._reported[name] = key
                moved[name] = {
                    "xyz": [round(v, 5) for v in s.position],
                    "quat": [round(v, 5) for v in s.rotation],
                    "start": [round(v, 5) for v in s.start],
                    "lifted": round(s.lifted_m, 5),
                }
        if moved:
            deepest = {k: round(v * 1000, 2) for k, v in self.twin.deepest.items()}
            self.say("objects", {"objects": moved, "deepest_mm": deepest})

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()
        if self.node is not None:
            self.node.close()


def main() -> int:
    # Behind the board and the server, whose higher priority it may have inherited.
    current = os.nice(0)
    if current < NICE:
        os.nice(NICE - current)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    line = sys.stdin.readline()
    if not line:
        return 0
    start = Start(**json.loads(line))
    try:
        loop = Loop(start, sys.stdout)
    except Exception as e:  # said in a line to the board's process, which ends at it
        gl = os.environ.get("MUJOCO_GL", "")
        why = f"{type(e).__name__}: {e}"
        if not any(word in why for word in GL_WORDS):
            traceback.print_exc()  # not MuJoCo's GL: a defect, with where it is
        else:
            why += (
                f" (MUJOCO_GL={gl}: its camera renders with egl, the default, from Debian's "
                "Mesa, which `make install` installs; osmesa needs libosmesa6; or give the "
                "scene no camera)"
            )
        print(json.dumps({"failed": why}), flush=True)
        return 1
    signal.signal(signal.SIGTERM, lambda signum, frame: loop.done.set())
    threading.Thread(target=loop.read, args=(sys.stdin,), name="twin-pulses", daemon=True).start()
    try:
        loop.run()
    finally:
        loop.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
