"""The twin's scene file: the table, the objects on it, the camera and the physics' step.

YAML validated with pydantic, as the arm's configuration is: a mistake is reported with
the key, the value and the reason (`SceneError`). Lengths in millimetres, masses in
grams, angles in degrees, all in the arm's base frame (x forward, y left, z up); an
object's `xyz_mm` is where the centre of its bottom stands, its z above the table's top
(`geometry.table_height_mm` of the arm's configuration). The default is the package's
`al5d/data/scene.yaml`: a cup on the table, in reach.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, model_validator

from al5d.arm.config import ConfigError, describe_errors, read_yaml
from al5d.model.chain import BASE_LINK, LINK_OF_JOINT, TOOL_LINK

DEFAULT_SCENE = Path(__file__).resolve().parent.parent / "data" / "scene.yaml"
#: The arm's base housing (`al5d.model.chain`), which no object may stand in at the start.
BASE_RADIUS_MM = 48.0
#: The camera's own frames on /tf (an object may not take their names).
CAMERA_FRAME = "camera"
CAMERA_OPTICAL_FRAME = "camera_optical_frame"
RESERVED = frozenset(
    {BASE_LINK, TOOL_LINK, *LINK_OF_JOINT.values(), CAMERA_FRAME, CAMERA_OPTICAL_FRAME, "table"}
)
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_COLOUR = re.compile(r"#[0-9a-fA-F]{6}")

Mm = Annotated[float, Field(allow_inf_nan=False, ge=-5000, le=5000)]
PositiveMm = Annotated[float, Field(allow_inf_nan=False, gt=0, le=2000)]
Friction = Annotated[float, Field(allow_inf_nan=False, gt=0, le=5)]


class SceneError(ConfigError):
    """The scene file cannot be used; the message names the key and the reason."""


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


def _colour(value: str) -> str:
    if not _COLOUR.fullmatch(value):
        raise ValueError(f"a colour is written #rrggbb (e.g. #d9480f), not {value!r}")
    return value.lower()


Colour = Annotated[str, AfterValidator(_colour)]


def rgba(colour: str, alpha: float = 1.0) -> tuple[float, float, float, float]:
    """`#rrggbb` as red, green, blue and alpha in 0..1."""
    r, g, b = (int(colour[i : i + 2], 16) / 255 for i in (1, 3, 5))
    return (r, g, b, alpha)


class Physics(_Frozen):
    """`physics`: MuJoCo's time step. 2 ms or finer keeps the contacts stiff (a grasp's
    fingers sink less than a millimetre) and the servos' loops stable."""

    step_ms: float = Field(default=2.0, gt=0.05, le=2.0, allow_inf_nan=False)


class Table(_Frozen):
    """`table`: its top, a rectangle at the arm's table height, and its surface."""

    size_mm: tuple[PositiveMm, PositiveMm] = (600.0, 700.0)
    center_mm: tuple[Mm, Mm] = (170.0, 0.0)
    friction: Friction = 0.7
    colour: Colour = "#b89b72"

    def holds(self, x: float, y: float) -> bool:
        """Is the point (mm) over the table's top?"""
        (w, d), (cx, cy) = self.size_mm, self.center_mm
        return abs(x - cx) <= w / 2 and abs(y - cy) <= d / 2

    def describe(self) -> str:
        (w, d), (cx, cy) = self.size_mm, self.center_mm
        return f"x {cx - w / 2:g}..{cx + w / 2:g} mm, y {cy - d / 2:g}..{cy + d / 2:g} mm"


class Camera(_Frozen):
    """`camera`: where it is, where it looks, its picture and how often it takes one
    (`rate_hz` 0: no camera; the picture is rendered in software)."""

    position_mm: tuple[Mm, Mm, Mm] = (500.0, -330.0, 280.0)
    look_at_mm: tuple[Mm, Mm, Mm] = (170.0, 0.0, 70.0)
    width: int = Field(default=320, ge=16, le=1920)
    height: int = Field(default=240, ge=16, le=1080)
    #: The vertical field of view.
    fovy_deg: float = Field(default=50.0, ge=5, le=160, allow_inf_nan=False)
    rate_hz: float = Field(default=10.0, ge=0, le=60, allow_inf_nan=False)

    @model_validator(mode="after")
    def _looks_somewhere(self) -> Camera:
        if math.dist(self.position_mm, self.look_at_mm) < 1:
            raise ValueError("look_at_mm: the camera must look at a point away from itself")
        return self


class SceneObject(_Frozen):
    """An object on the table: a `box` (`size_mm` x, y, z), a `cylinder` (`radius_mm`,
    `height_mm`) or a `cup` (a cylinder open at the top, walls `wall_mm` thick)."""

    shape: Literal["box", "cylinder", "cup"]
    size_mm: tuple[PositiveMm, PositiveMm, PositiveMm] | None = None
    radius_mm: PositiveMm | None = None
    height_mm: PositiveMm | None = None
    wall_mm: PositiveMm | None = None
    mass_g: float = Field(gt=0, le=20_000, allow_inf_nan=False)
    #: Sliding friction against whatever it touches (the larger of the two applies).
    friction: Friction = 0.8
    #: The centre of its bottom; z above the table's top (0: standing on it).
    xyz_mm: tuple[Mm, Mm, Mm] | None = None
    #: It starts in the gripper, fixed to the hand between the fingers, upright when the
    #: gripper points down (a payload: a tool, or a cup handed to the arm); no `xyz_mm`.
    in_gripper: bool = Field(default=False, strict=True)
    yaw_deg: float = Field(default=0.0, ge=-360, le=360, allow_inf_nan=False)
    colour: Colour = "#1971c2"
    #: Where it is meant to go (x, y on the table): `al5d demo --physics` measures against it.
    goal_mm: tuple[Mm, Mm] | None = None

    @model_validator(mode="after")
    def _sizes_of_its_shape(self) -> SceneObject:
        needs = {"box": ("size_mm",), "cylinder": ("radius_mm", "height_mm")}
        needs["cup"] = (*needs["cylinder"], "wall_mm")
        sizes = ("size_mm", "radius_mm", "height_mm", "wall_mm")
        missing = [k for k in needs[self.shape] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"a {self.shape} needs {', '.join(missing)}")
        extra = [k for k in sizes if k not in needs[self.shape] and getattr(self, k) is not None]
        if extra:
            raise ValueError(f"a {self.shape} has no {', '.join(extra)}")
        if self.in_gripper == (self.xyz_mm is not None):
            raise ValueError(
                "an object in the gripper has no xyz_mm" if self.in_gripper else "xyz_mm: missing"
            )
        if self.shape == "cup" and self.wall_mm is not None and self.radius_mm is not None:
            if self.wall_mm >= self.radius_mm:
                raise ValueError(f"wall_mm {self.wall_mm:g} must be thinner than radius_mm")
            if self.height_mm is not None and self.wall_mm >= self.height_mm:
                raise ValueError(f"wall_mm {self.wall_mm:g} must be thinner than height_mm")
        return self

    @property
    def height(self) -> float:
        """Its height, mm."""
        if self.size_mm is not None:
            return self.size_mm[2]
        assert self.height_mm is not None
        return self.height_mm

    @property
    def footprint_mm(self) -> float:
        """The radius of a circle about its centre that holds its footprint, mm."""
        if self.size_mm is not None:
            return math.hypot(self.size_mm[0], self.size_mm[1]) / 2
        assert self.radius_mm is not None
        return self.radius_mm


class Scene(_Frozen):
    """The whole scene: physics, table, camera (None: none) and the objects by name."""

    physics: Physics = Physics()
    table: Table = Table()
    camera: Camera | None = Camera()
    objects: dict[str, SceneObject] = {}

    @model_validator(mode="after")
    def _objects_fit(self) -> Scene:
        for name, obj in self.objects.items():
            if not _NAME.fullmatch(name):
                raise ValueError(
                    f"objects.{name}: a name starts with a letter and holds only letters, digits "
                    "and underscores (it is the object's frame on /tf)"
                )
            if name in RESERVED:
                raise ValueError(f"objects.{name}: the name of a frame of the arm or the scene")
            if obj.xyz_mm is None:
                continue  # in the gripper
            x, y, z = obj.xyz_mm
            if not self.table.holds(x, y):
                raise ValueError(
                    f"objects.{name}.xyz_mm: ({x:g}, {y:g}) is off the table "
                    f"({self.table.describe()})"
                )
            if z < 0:
                raise ValueError(f"objects.{name}.xyz_mm: z {z:g} is below the table's top")
            if obj.goal_mm is not None and not self.table.holds(*obj.goal_mm):
                gx, gy = obj.goal_mm
                raise ValueError(
                    f"objects.{name}.goal_mm: ({gx:g}, {gy:g}) is off the table "
                    f"({self.table.describe()})"
                )
            if math.hypot(x, y) < BASE_RADIUS_MM + obj.footprint_mm and z < 70:
                raise ValueError(f"objects.{name}.xyz_mm: it stands in the arm's base")
        if sum(obj.in_gripper for obj in self.objects.values()) > 1:
            raise ValueError("objects: only one object fits in the gripper")
        names = [name for name, obj in self.objects.items() if obj.xyz_mm is not None]
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                if _overlap(self.objects[a], self.objects[b]):
                    raise ValueError(f"objects.{b}: it stands in {a} at the start")
        return self


def _overlap(a: SceneObject, b: SceneObject) -> bool:
    """Do the two objects' bounding cylinders meet?"""
    assert a.xyz_mm is not None and b.xyz_mm is not None
    (ax, ay, az), (bx, by, bz) = a.xyz_mm, b.xyz_mm
    apart = math.hypot(ax - bx, ay - by) >= a.footprint_mm + b.footprint_mm
    return not apart and az < bz + b.height and bz < az + a.height


def parse_scene(data: Any, source: str = "<scene>") -> Scene:
    """Validate already-loaded YAML; SceneError names the key on failure."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SceneError(f"{source}: the scene file must hold a mapping (physics, table, ...)")
    try:
        return Scene.model_validate(data)
    except ValidationError as e:
        raise SceneError(describe_errors(e, source, {})) from None


def load_scene(path: str | Path | None = None) -> Scene:
    """Read and validate a scene file (the shipped default when `path` is None)."""
    p = Path(path) if path is not None else DEFAULT_SCENE
    return parse_scene(read_yaml(p, "the scene", SceneError), str(p))
