"""Named poses: the poses file (YAML) that `al5d web` saves and `al5d run` reads.

Each pose is a name and joint angles in degrees, a subset of the arm's joints:

    # poses.yaml
    home: {base: 0, shoulder: 30, elbow: 90, wrist: 0, gripper: 0, wrist_rotate: 0}
    above_cup: {base: -35.5, shoulder: 40, elbow: 80, wrist: -20}

A sequence file names one with `pose <name> [time=<ms>]` (`al5d.arm.instruction`): a
move of those joints, judged by the server as any other. By default the file is
`poses.yaml` beside the sequence file (`al5d run`) or beside the configuration (`al5d
web`, the current directory without `--config`), where the web view saves its
sequences too. A file that is not valid is refused whole, the message naming each pose
and joint that is wrong, a line each; ranges are the server's to judge, as for every move.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import yaml

from al5d.arm.config import ConfigError, load_yaml
from al5d.arm.instruction import (
    MAX_SEQUENCE_ERRORS,
    PRESET_NAMES,
    SequenceStep,
    parse_sequence,
)
from al5d.model import JOINTS

#: The poses file's name, beside the sequence files that use it.
POSES_FILE = "poses.yaml"
#: What a pose's (or a sequence's) name may be: a word of a sequence line, with no `=`,
#: `#` or space, that reads the same in any file system.
NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,39}")
NAME_RULE = "letters, digits, _ and -, starting with a letter, 40 at most"


class PosesError(ConfigError):
    """A poses file, or a change to it, that cannot be used: the message names the file, the
    pose and the joint."""


def name_problem(name: str) -> str | None:
    """Why `name` cannot name a pose or a sequence, or None."""
    if NAME.fullmatch(name):
        return None
    return f"{_quote(name)} is not a name: {NAME_RULE}"


def _quote(text: str) -> str:
    return repr(text) if len(text) <= 40 else repr(text[:40]) + "..."


@dataclass(frozen=True)
class Pose:
    """Joint angles (degrees) under a name, in the arm's joint order."""

    name: str
    joints: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class NamedPoses:
    """The poses of one file, in its order; `path` where they are read and saved, `exists`
    whether that file was there."""

    path: Path
    poses: tuple[Pose, ...] = ()
    exists: bool = True

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.poses)

    def find(self, name: str) -> Pose | None:
        return next((p for p in self.poses if p.name == name), None)

    def unknown(self, name: str) -> str:
        """Why `name` is no pose here, and what there is."""
        if not self.exists:
            return f"no saved pose named {_quote(name)} (no poses file at {self.path})"
        if not self.poses:
            return f"no saved pose named {_quote(name)} ({self.path} holds none)"
        near = difflib.get_close_matches(name, self.names, n=1, cutoff=0.6)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        return f"no saved pose named {_quote(name)}{hint} (in {self.path}: {', '.join(self.names)})"

    def with_pose(self, name: str, degrees: dict[str, float]) -> NamedPoses:
        """This book with `name` at `degrees` (rounded to 0.1 degree): replaced where it
        was, else added at the end."""
        problem = name_problem(name)
        if problem:
            raise PosesError(problem)
        pose = _pose(name, {j: round(v, 1) for j, v in degrees.items()}, "pose")
        if self.find(name) is None:
            return replace(self, poses=(*self.poses, pose))
        return replace(self, poses=tuple(pose if p.name == name else p for p in self.poses))

    def renamed(self, old: str, new: str) -> NamedPoses:
        problem = name_problem(new)
        if problem:
            raise PosesError(problem)
        if self.find(old) is None:
            raise PosesError(self.unknown(old))
        if new != old and self.find(new) is not None:
            raise PosesError(f"a pose named {_quote(new)} is saved already: delete it first")
        return replace(
            self, poses=tuple(replace(p, name=new) if p.name == old else p for p in self.poses)
        )

    def without(self, name: str) -> NamedPoses:
        if self.find(name) is None:
            raise PosesError(self.unknown(name))
        return replace(self, poses=tuple(p for p in self.poses if p.name != name))

    def text(self) -> str:
        """The file's YAML: a pose a line, which `parse_poses` reads back."""
        lines = [
            "# al5d poses: joint angles in degrees, by name.",
            "# A sequence file moves to one with: pose <name> [time=<ms>]",
        ]
        for pose in self.poses:
            angles = ", ".join(f"{j}: {_number(v)}" for j, v in pose.joints)
            lines.append(f"{_key(pose.name)}: {{{angles}}}")
        return "\n".join(lines) + "\n"


def _number(x: float) -> str:
    return str(int(x)) if x == int(x) else repr(x)


def _key(name: str) -> str:
    """The name as a YAML key: in quotes where YAML would read it as something else
    (`no`, `null`, `1e3`)."""
    return name if yaml.safe_load(name) == name else f'"{name}"'


def _pose(name: str, angles: Any, where: str) -> Pose:
    """A pose of `angles`; PosesError naming every joint of it that is wrong, a line each."""
    if not isinstance(angles, dict):
        raise PosesError(f"{where}: joint angles by joint name, e.g. {{base: 0, elbow: 90}}")
    if not angles:
        raise PosesError(f"{where}: no joint angles")
    problems = []
    for joint, value in angles.items():
        if joint not in JOINTS:
            problems.append(f"{where}.{joint}: no such joint; the joints: {', '.join(JOINTS)}")
        elif isinstance(value, bool) or not isinstance(value, int | float):
            problems.append(f"{where}.{joint}: {value!r} is not a number of degrees")
        elif not math.isfinite(value):
            problems.append(f"{where}.{joint}: {value!r} is not a finite number of degrees")
    if problems:
        raise PosesError("\n".join(problems))
    joints = tuple((j, float(angles[j])) for j in JOINTS if j in angles)
    return Pose(name, joints)


def parse_poses(text: str, path: Path) -> NamedPoses:
    """The poses of a file's text. PosesError names the file, the pose and the joint of
    every problem, a line each (the first `MAX_SEQUENCE_ERRORS`, then how many more), so
    that a file written by hand is mended in one go."""
    try:
        data = load_yaml(text)
    except yaml.YAMLError as e:
        raise PosesError(f"{path}: not valid YAML: {e}") from None
    if data is None:
        return NamedPoses(path)
    if not isinstance(data, dict):
        raise PosesError(f"{path}: the file must map pose names to joint angles")
    poses = []
    problems: list[str] = []
    for name, angles in data.items():
        try:
            if not isinstance(name, str):
                raise PosesError(
                    f'{path}: pose {name!r}: a name is text: write it in quotes, "{name}"'
                )
            problem = name_problem(name)
            if problem:
                raise PosesError(f"{path}: pose {problem}")
            poses.append(_pose(name, angles, f"{path}: {name}"))
        except PosesError as e:
            problems.extend(str(e).splitlines())
    if problems:
        told = problems[:MAX_SEQUENCE_ERRORS]
        if len(problems) > len(told):
            told.append(f"... and {len(problems) - len(told)} more problems")
        raise PosesError("\n".join(told))
    return NamedPoses(path, tuple(poses))


def load_poses(path: str | Path, *, required: bool = True) -> NamedPoses:
    """The poses of the file at `path`. A file that is not there is an error if `required`,
    else an empty book that saving creates."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        if required:
            raise PosesError(f"{p}: no such poses file") from None
        return NamedPoses(p, exists=False)
    except (OSError, UnicodeDecodeError) as e:
        why = e.strerror if isinstance(e, OSError) else "not UTF-8 text"
        raise PosesError(f"{p}: cannot read the poses: {why}") from None
    return parse_poses(text, p)


def save_poses(book: NamedPoses) -> NamedPoses:
    """Write the book to its file (whole: a reader never sees half a file); the book saved."""
    write_text(book.path, book.text())
    return replace(book, exists=True)


def write_text(path: Path, text: str) -> None:
    """Replace the file at `path` by `text` at once (a temporary file renamed over it)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def beside(path: str | Path | None) -> Path:
    """The default poses file: beside the file at `path` (a sequence, a configuration), or
    in the current directory."""
    return (Path(path).parent if path is not None else Path()) / POSES_FILE


#: A sequence file's suffix, beside the poses file it names.
SEQUENCE_SUFFIX = ".seq"


def sequence_names(folder: Path) -> tuple[str, ...]:
    """The sequences saved in `folder` (`<name>.seq`, a name as a pose's), sorted."""
    found = (p.stem for p in folder.glob(f"*{SEQUENCE_SUFFIX}") if p.is_file())
    return tuple(sorted(n for n in found if name_problem(n) is None))


def save_sequence(folder: Path, name: str, text: str) -> Path:
    """`text` as the sequence `name` in `folder` (ending with a newline); its path."""
    problem = name_problem(name)
    if problem:
        raise PosesError(problem)
    path = folder / f"{name}{SEQUENCE_SUFFIX}"
    write_text(path, text if text.endswith("\n") or not text else text + "\n")
    return path


def parse_text(text: str, poses: NamedPoses, name: str = "steps") -> list[SequenceStep]:
    """The steps of a sequence's text, read as `al5d run` reads its file; GrammarError
    says every bad line."""
    return parse_sequence(text.encode("utf-8"), name, PRESET_NAMES, poses)


def used_by(folder: Path, pose: str) -> tuple[str, ...]:
    """The sequences in `folder` that name `pose` (which renaming or deleting it breaks)."""
    line = re.compile(rf"^\s*pose\s+{re.escape(pose)}(\s|$)", re.IGNORECASE | re.MULTILINE)
    found = []
    for name in sequence_names(folder):
        try:
            text = (folder / f"{name}{SEQUENCE_SUFFIX}").read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            continue
        if line.search(text):
            found.append(name)
    return tuple(found)
