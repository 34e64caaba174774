"""The calibrations found, written into the configuration file: each joint's
`calibration` line replaced and every other line (comments too) kept, the new text
loaded and validated by the configuration's own code before anything is written, a
backup beside the file and a unified diff.
"""

from __future__ import annotations

import difflib
import os
import re
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from al5d.arm.calibration import CalibrationRefused, JointCalibration, Point
from al5d.arm.config import DEFAULT_CONFIG, ArmConfig, ConfigError, load_yaml, parse_config

_KEY = re.compile(r"^(?P<indent>\s*)(?P<key>[A-Za-z_][\w-]*)\s*:(?P<rest>.*)$")


@dataclass(frozen=True)
class Written:
    """The configuration file written: where, its backup, and the unified diff."""

    path: Path
    backup: Path
    diff: str


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _content(line: str) -> bool:
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith("#")


def _block(lines: list[str], start: int, indent: int) -> int:
    """The end (exclusive) of the block that begins after line `start`: the lines indented
    deeper than `indent`, with blanks and comments among them."""
    end = start + 1
    last = start
    while end < len(lines):
        line = lines[end]
        if _content(line):
            if _indent(line) <= indent:
                break
            last = end
        end += 1
    return last + 1


def _find_key(lines: list[str], lo: int, hi: int, key: str, deeper_than: int) -> int | None:
    for i in range(lo, hi):
        m = _KEY.match(lines[i])
        if m and m["key"] == key and len(m["indent"]) > deeper_than and _content(lines[i]):
            return i
    return None


def _comment(rest: str) -> str:
    """A trailing comment of a one-line value (a `#` after a space, outside quotes)."""
    m = re.search(r"\s#.*$", rest)
    return m.group(0).rstrip() if m and "'" not in rest and '"' not in rest else ""


def _number(x: float) -> str:
    return f"{x:g}" if x != int(x) else str(int(x))


def calibration_line(found: Iterable[Point]) -> str:
    """The YAML flow sequence of two points, as the shipped file writes them."""
    return "[" + ", ".join(f"{{deg: {_number(p.deg)}, us: {p.us}}}" for p in found) + "]"


def edit_calibrations(text: str, results: Iterable[JointCalibration]) -> str:
    """`text` (a configuration file) with each joint's `calibration` replaced by its points
    found, every other line (comments too) kept; CalibrationRefused where the file does not
    hold it as a key of its own under `joints.<name>`."""
    lines = text.splitlines(keepends=True)
    for result in results:
        name = result.name
        top = _find_key(lines, 0, len(lines), "joints", -1)
        if top is None or _indent(lines[top]) != 0:
            raise CalibrationRefused("the file has no top-level `joints:` block to write into")
        joints_end = _block(lines, top, 0)
        at = _find_key(lines, top + 1, joints_end, name, 0)
        if at is None:
            raise CalibrationRefused(
                f"joints.{name} is not a block of its own in the file; set its calibration "
                f"by hand: {calibration_line(result.found)}"
            )
        joint_indent = _indent(lines[at])
        joint_end = _block(lines, at, joint_indent)
        key = _find_key(lines, at + 1, joint_end, "calibration", joint_indent)
        if key is None:
            raise CalibrationRefused(
                f"joints.{name}.calibration is not a line of its own in the file; set it by "
                f"hand: calibration: {calibration_line(result.found)}"
            )
        m = _KEY.match(lines[key])
        assert m is not None
        key_indent = len(m["indent"])
        end = key + 1
        # Its value's lines: deeper, or a block sequence's items at the key's own indent.
        while end < len(lines) and (
            not _content(lines[end])
            or _indent(lines[end]) > key_indent
            or (_indent(lines[end]) == key_indent and lines[end].lstrip().startswith("- "))
        ):
            end += 1
        while end > key + 1 and not _content(lines[end - 1]):
            end -= 1  # blank lines and comments after the value stay
        newline = "\n" if lines[key].endswith("\n") else ""
        comment = _comment(m["rest"]) if end == key + 1 else ""
        replaced = f"{m['indent']}calibration: {calibration_line(result.found)}{comment}{newline}"
        lines[key:end] = [replaced]
    return "".join(lines)


def _backup_path(path: Path, stamp: str) -> Path:
    backup = path.with_name(f"{path.name}.{stamp}.bak")
    n = 1
    while backup.exists():
        n += 1
        backup = path.with_name(f"{path.name}.{stamp}-{n}.bak")
    return backup


def check_written(text: str, source: str, results: Iterable[JointCalibration]) -> ArmConfig:
    """The new text loaded and validated by the configuration's own code, and holding the
    calibrations meant (an edit that landed elsewhere is caught here, before any write)."""
    try:
        data: Any = load_yaml(text)
    except yaml.YAMLError as e:
        raise CalibrationRefused(f"{source}: the edited file is not valid YAML: {e}") from None
    try:
        config = parse_config(data, source)
    except ConfigError as e:
        raise CalibrationRefused(f"the edited file does not validate: {e}") from None
    for result in results:
        got = config.joints[result.name].calibration
        if [(p.deg, p.us) for p in got] != [(p.deg, p.us) for p in result.found]:
            raise CalibrationRefused(
                f"{source}: the edit of joints.{result.name}.calibration did not take; set it "
                f"by hand: {calibration_line(result.found)}"
            )
    return config


def shipped_problem(path: str | Path) -> str:
    """Why the calibrations cannot be written into `path` where it is the configuration the
    package ships (an install replaces it; an editable one is the source tree), or ""."""
    if Path(path).resolve() != DEFAULT_CONFIG.resolve():
        return ""
    return (
        f"the server runs with the shipped configuration ({DEFAULT_CONFIG}), which al5d's "
        "install owns and replaces: copy it (cp "
        f"{DEFAULT_CONFIG} my-arm.yaml), start the server with --config my-arm.yaml, and "
        "calibrate that"
    )


def write_calibration(
    path: str | Path, results: Iterable[JointCalibration], stamp: str | None = None
) -> Written:
    """Write the calibrations found into the configuration file at `path`: first a copy of
    the file as it was beside it (`<name>.<UTC time>.bak`), then the new text, whole (a
    file beside it renamed over it), only once it loads and validates. A path that is a
    symbolic link is written through (the link stays); never the shipped configuration
    (`shipped_problem`: CalibrationRefused)."""
    if problem := shipped_problem(path):
        raise CalibrationRefused(problem)
    given = Path(path)
    real = given.resolve()
    chosen = list(results)
    old = real.read_text(encoding="utf-8")
    new = edit_calibrations(old, chosen)
    check_written(new, str(given), chosen)
    stamp = stamp or time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    backup = _backup_path(real, stamp)
    backup.write_text(old, encoding="utf-8")
    fd, tmp = tempfile.mkstemp(prefix=f".{real.name}.", dir=real.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(new)
        os.chmod(tmp, real.stat().st_mode & 0o7777)
        os.replace(tmp, real)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    diff = "".join(
        difflib.unified_diff(
            old.splitlines(keepends=True),
            new.splitlines(keepends=True),
            fromfile=str(backup),
            tofile=str(given),
        )
    )
    return Written(given, backup, diff)
