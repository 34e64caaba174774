"""Each subpackage's first docstring names every module in it, so that it stays the map of
the package that docs/architecture.md points to; so does the test rig's (al5d_rig).

A module counts as named when the docstring spells it as a module: in backticks (`core`,
or `core.Core`), as a file (core.py) or by its dotted name (al5d.arm.core); a word in
the prose ("the server's node") does not count. A subpackage inside counts as a module
of its parent.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "al5d"
RIG = SRC.with_name("al5d_rig")
PACKAGES = sorted(p.parent for top in (SRC, RIG) for p in top.rglob("__init__.py"))


def members(package: Path) -> list[str]:
    modules = [p.stem for p in package.glob("*.py") if p.name != "__init__.py"]
    subpackages = [p.parent.name for p in package.glob("*/__init__.py")]
    return sorted(modules + subpackages)


def docstring(package: Path) -> str:
    return ast.get_docstring(ast.parse((package / "__init__.py").read_text())) or ""


def named(name: str, text: str) -> bool:
    n = re.escape(name)
    spelled = (rf"`{n}[`.]", rf"(?<![\w.]){n}\.py\b", rf"\bal5d\.(?:\w+\.)*{n}\b")
    return any(re.search(s, text) for s in spelled)


@pytest.mark.parametrize(
    "package", PACKAGES, ids=[str(p.relative_to(SRC.parent)) for p in PACKAGES]
)
def test_the_docstring_names_every_module(package: Path) -> None:
    text = docstring(package)
    assert text, f"{package}/__init__.py has no docstring"
    missing = [m for m in members(package) if not named(m, text)]
    assert not missing, f"{package.relative_to(SRC.parent)}/__init__.py does not name {missing}"


def test_the_check_sees_a_missing_module() -> None:
    """Only a module's spelling counts, not a word of the prose."""
    assert named("link", "link.py    the ROS side")
    assert named("core", "- `core`: the protocol")
    assert named("board", "(`board.Board`: commands)")
    assert named("clock", "al5d.clock    one clock")
    assert not named("server", "the server's node")
    assert not named("link", "`linked` and relink.py")
    assert members(SRC / "ros")  # the glob finds the modules
    assert RIG in PACKAGES
