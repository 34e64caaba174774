"""The twin's camera: the scene's view rendered offscreen, in software, and its intrinsics.

MuJoCo renders through the GL that `MUJOCO_GL` names when it is first imported
(`al5d.twin` sets `egl` unless the environment chose: Debian's Mesa renders it on the CPU,
with no display and no GPU). Rendering stays in the thread that made the renderer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from al5d.twin.scene import Camera as CameraSettings


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera's: focal lengths and principal point in pixels (square pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def of(cls, settings: CameraSettings) -> Intrinsics:
        f = settings.height / 2 / math.tan(math.radians(settings.fovy_deg) / 2)
        return cls(settings.width, settings.height, f, f, settings.width / 2, settings.height / 2)


class Camera:
    """Renders the scene's camera (`camera` in the MJCF) from a model's data."""

    def __init__(self, model: mujoco.MjModel, settings: CameraSettings) -> None:
        self.settings = settings
        self.intrinsics = Intrinsics.of(settings)
        self.period_s = 1.0 / settings.rate_hz if settings.rate_hz > 0 else math.inf
        self._renderer = mujoco.Renderer(model, settings.height, settings.width)

    def render(self, data: mujoco.MjData) -> npt.NDArray[np.uint8]:
        """The picture now: height x width x 3, RGB, the top row first."""
        self._renderer.update_scene(data, camera="camera")
        picture: npt.NDArray[np.uint8] = self._renderer.render()
        return picture

    def close(self) -> None:
        self._renderer.close()
