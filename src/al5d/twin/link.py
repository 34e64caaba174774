"""The board's side of the twin: the twin's process started, fed the board's pulses, heard.

`TwinLink(board, config, scene)` starts `al5d.twin.run` in a process of its own, tells it
every change of what the board's channels put out (`Board.observe_pulses`: the board's
listener only puts it in a queue, and a thread of this link writes it to the twin), and
reads what the twin says: a joint held short is logged (logger `al5d.twin`) and kept in
`held`, the objects' latest poses in `objects`. What the board answers is the same with a
twin and without: the twin only listens.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import subprocess
import sys
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from al5d.arm.config import ArmConfig
from al5d.clock import now
from al5d.ssc32u.emulator import Pulse
from al5d.ssc32u.emulator.board import Board
from al5d.twin.run import Start, pulse_line
from al5d.twin.scene import Scene, load_scene

log = logging.getLogger("al5d.twin")

#: How long the twin may take to start (MuJoCo, the model, the GL context, DDS) on a busy
#: host before the board goes on without it.
READY_S = 60.0

_ATTACHED: weakref.WeakKeyDictionary[Board, TwinLink] = weakref.WeakKeyDictionary()


class TwinFailed(RuntimeError):
    """The twin's process did not start: why, as it said (MuJoCo, its GL: `MUJOCO_GL`)."""


@dataclass(frozen=True)
class ObjectPose:
    """An object as the twin last reported it: metres in base_link."""

    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    start: tuple[float, float, float]
    lifted_m: float


def attached(board: Board) -> TwinLink | None:
    """The twin that follows `board`, if one does."""
    return _ATTACHED.get(board)


class TwinLink:
    """The twin of `board`'s arm (`config`) in `scene` (a path; None: the shipped scene), on
    ROS under `namespace` unless `ros` is False. Blocks until the twin runs (`READY_S`)."""

    def __init__(
        self,
        board: Board,
        config: ArmConfig,
        scene: str | Path | None = None,
        namespace: str | None = None,
        *,
        ros: bool = True,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.scene: Scene = load_scene(scene)  # a bad file is said before anything starts
        self.held: list[dict[str, Any]] = []
        self.objects: dict[str, ObjectPose] = {}
        self.deepest_mm: dict[str, float] = {}
        self.ended: dict[str, Any] | None = None
        self.ready: dict[str, Any] | None = None
        #: Why it could not start, as it said (None: it did not say).
        self.failed: str | None = None
        self._say = say or (lambda text: log.warning("twin: %s", text))
        self._changed = threading.Condition()
        self._pulses: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._closed = False
        mechanics = {k: (m.offset_us, m.reversed) for k, m in board.mechanics.items()}
        start = Start(
            config=config.model_dump(mode="json"),
            scene=self.scene.model_dump(mode="json"),
            pose=board.joint_degrees(),
            mechanics=mechanics,
            start=now(),
            namespace=config.server.namespace if namespace is None else namespace,
            ros=ros,
        )
        self._started = now()
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "al5d.twin.run"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.write(start.to_json() + "\n")
        self._proc.stdin.flush()
        board.observe_pulses(self._tell)
        self._reader = threading.Thread(target=self._read, name="twin-reader", daemon=True)
        self._reader.start()
        self._writer = threading.Thread(target=self._write, name="twin-writer", daemon=True)
        self._writer.start()
        with self._changed:
            self._changed.wait_for(
                lambda: self.ready is not None or self.ended is not None, READY_S
            )
        if self.ready is None:
            failed, ended = self.failed, self.ended is not None
            self.close()
            if failed:
                raise TwinFailed(f"the physical twin could not start: {failed}")
            raise TwinFailed(
                f"the physical twin ended as it started (exit {self._proc.poll()})"
                if ended
                else f"the physical twin did not start in {READY_S:.0f} s"
            )
        _ATTACHED[board] = self
        cam = self.ready.get("camera") or "no camera"
        log.info(
            "twin: MuJoCo %s, step %g ms, %s (MUJOCO_GL=%s)",
            self.ready["mujoco"],
            self.ready["step_ms"],
            cam,
            self.ready["gl"],
        )

    def _tell(self, channel: int, pulse: Pulse) -> None:
        """The board's listener (its thread, its lock held): a put, nothing more."""
        if not self._closed:
            self._pulses.put(pulse_line(channel, pulse))

    def _write(self) -> None:
        stdin = self._proc.stdin
        assert stdin is not None
        while (line := self._pulses.get()) is not None:
            try:
                stdin.write(line + "\n")
                if self._pulses.empty():
                    stdin.flush()
            except (BrokenPipeError, ValueError, OSError):
                return  # the twin has ended: the board goes on

    def _read(self) -> None:
        stdout = self._proc.stdout
        assert stdout is not None
        for line in stdout:
            try:
                event = json.loads(line)
            except ValueError:
                continue
            self._handle(event)
        with self._changed:
            if self.ended is None:
                self.ended = {}
            self._changed.notify_all()

    def _handle(self, event: dict[str, Any]) -> None:
        with self._changed:
            if "ready" in event:
                self.ready = event["ready"]
            elif "failed" in event:
                self.failed = str(event["failed"])
            elif "held" in event:
                self.held.append(event["held"])
            elif "objects" in event:
                for name, o in event["objects"]["objects"].items():
                    self.objects[name] = ObjectPose(
                        tuple(o["xyz"]), tuple(o["quat"]), tuple(o["start"]), o["lifted"]
                    )
                self.deepest_mm = event["objects"]["deepest_mm"]
            elif "end" in event:
                self.ended = event["end"]
                self.deepest_mm = event["end"]["deepest_mm"]
            elif "behind" in event:
                log.warning(
                    "twin: slower than real time here: skipped %.2f s (%.2f s in all)",
                    event["behind"]["skipped_s"],
                    event["behind"]["total_s"],
                )
            self._changed.notify_all()
        if "held" in event:
            self._say(event["held"]["text"])

    def wait_for(self, predicate: Callable[[TwinLink], bool], timeout: float) -> bool:
        """Wait until `predicate(self)` holds (what the twin says comes in its own time)."""
        with self._changed:
            return self._changed.wait_for(lambda: predicate(self), timeout)

    def close(self, timeout: float = 10.0) -> None:
        """End the twin (its stdin closed) and wait for its last words."""
        if self._closed:
            return
        self._closed = True
        self._pulses.put(None)
        self._writer.join(timeout)
        if self._proc.stdin is not None:
            with contextlib.suppress(OSError):
                self._proc.stdin.close()
        try:
            self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._reader.join(timeout)
        if self.ended:
            ran = now() - self._started
            log.info(
                "twin: ended after %.1f s: its loop busy %.1f s (%.0f %% of a core), %d "
                "pictures, %.2f s skipped behind real time",
                ran,
                self.ended["busy_s"],
                100 * self.ended["busy_s"] / max(ran, 1e-9),
                self.ended["pictures"],
                self.ended["skipped_s"],
            )
