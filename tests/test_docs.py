"""The README's and docs/'s examples run as written, and the package's docstrings name its
modules.

Every fenced block says what it is: `sh` and `python` blocks are examples and run; any
other language (`text`, `yaml`, `xml`) is shown, not run. An HTML comment on the line
before a block changes how it runs, visibly in the page's source:

    <!-- example: skip (why) -->      not run: it needs an arm, a ROS install, or runs
                                      until Ctrl-C; the reason is the test's skip reason
    <!-- example: server -->          run while `al5d serve` (embedded emulator) runs;
                                      one server for every such block, started once
    <!-- example: exit N -->         the block must end with exit code N (default 0)
    <!-- example: output -->         (on a `text` block) every line of it is a whole line of
                                      what the example before it printed (an instruction's
                                      id and a time in ms stand for any: `[4d33-1]`, `(311 ms)`)
    <!-- example: synopsis -->       (on a `text` block) a command's options: each is one of
                                      the command's own (its `--help`)

A `text` block right after an example, in the same section, shows what it printed: it is
marked `output` (or, a command's options, `synopsis`).

Shell blocks run in bash with `set -e -o pipefail`, Python blocks in the venv's Python;
the blocks of one page share a working directory (with `config/` of the repository), in
the page's order, so one block may use a file an earlier one wrote.
"""

from __future__ import annotations

import ast
import contextlib
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from al5d_rig.proc import Proc, patient_config

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
BIN = Path(sys.executable).parent
RUN = ("sh", "python")
SHOWN = ("text", "yaml", "xml")
#: One example's bound: a few `al5d send`s, each discovering the server, on a busy host
#: (below pytest's 120 s, which counts the server's start too).
BLOCK_S = 80.0
#: A ROS domain of the examples' own, outside the range tests/conftest.py draws the other
#: suites' from: an `al5d send` of an example talks to every server of its domain, and a
#: suite running beside this one on the host must not be one of them.
DOMAIN = {"ROS_DOMAIN_ID": str(220 + os.getpid() % 13)}

FENCE = re.compile(r"^```([\w-]*)\n(.*?)^```$", re.S | re.M)
MARKER = re.compile(r"<!--\s*example:\s*(.*?)\s*-->\s*\Z", re.S)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    code: str
    #: The marker's words: "skip (...)", "server", "exit 1", "output", "synopsis"; "" without
    #: one.
    marker: str

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"

    def skip_reason(self) -> str | None:
        found = re.match(r"skip\s*\((.*)\)\s*$", self.marker, re.S)
        return found.group(1) if found else None

    @property
    def server(self) -> bool:
        return "server" in self.words()

    @property
    def exit_code(self) -> int:
        found = re.search(r"\bexit (\d+)\b", self.marker)
        return int(found.group(1)) if found else 0

    def words(self) -> set[str]:
        return {w.strip() for w in self.marker.split(",")}


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    found = []
    for m in FENCE.finditer(text):
        before = text[: m.start()].rstrip("\n")
        last = before.rsplit("\n", 1)[-1]
        marker = MARKER.search(last)
        found.append(
            Block(
                page=page,
                line=text.count("\n", 0, m.start()) + 1,
                lang=m.group(1),
                code=m.group(2),
                marker=marker.group(1) if marker else "",
            )
        )
    return found


ALL = [b for page in PAGES for b in blocks(page)]
EXAMPLES = [b for b in ALL if b.lang in RUN]


def test_every_block_says_what_it_is() -> None:
    """A block without a language could hide a command that is never run."""
    unknown = [f"{b.name}: ```{b.lang}" for b in ALL if b.lang not in RUN + SHOWN]
    assert not unknown, "fenced blocks must be sh, python, text, yaml or xml:\n" + "\n".join(
        unknown
    )


def test_every_marker_is_understood() -> None:
    words = {"server", "output", "synopsis"}
    bad = [
        f"{b.name}: {b.marker!r}"
        for b in ALL
        if b.marker
        and b.skip_reason() is None
        and not all(w in words or re.fullmatch(r"exit \d+", w) for w in b.words())
    ]
    assert not bad, (
        "markers are 'skip (why)', 'server', 'exit N', 'output', 'synopsis':\n" + "\n".join(bad)
    )


def follows_an_example(block: Block) -> bool:
    """Whether `block` comes right after an example, in the same section (no heading between)."""
    text = block.page.read_text()
    found = [m for m in FENCE.finditer(text) if text.count("\n", 0, m.start()) + 1 < block.line]
    if not found or found[-1].group(1) not in RUN:
        return False
    end = sum(len(line) + 1 for line in text.splitlines()[: block.line - 1])
    return re.search(r"^#+ ", text[found[-1].end() : end], re.M) is None


def test_what_an_example_printed_is_checked() -> None:
    """A `text` block right after an example shows its output: it is compared with what the
    example printed (or it is the command's synopsis, checked against its options)."""
    unmarked = [
        b.name
        for b in ALL
        if b.lang == "text" and follows_an_example(b) and not {"output", "synopsis"} & b.words()
    ]
    assert not unmarked, "mark these `output` (or `synopsis`):\n" + "\n".join(unmarked)


SYNOPSES = [b for b in ALL if "synopsis" in b.words()]


@pytest.mark.parametrize("block", SYNOPSES, ids=[b.name for b in SYNOPSES])
def test_a_synopsis_names_only_the_commands_options(block: Block) -> None:
    """Each `al5d COMMAND` of the block (a line of its own, and the lines that go on with it)
    names only options of that command's `--help`."""
    commands: list[tuple[str, str]] = []
    for line in block.code.splitlines():
        found = re.match(r"al5d ([\w-]+)", line)
        if found:
            commands.append((found.group(1), line))
        elif commands:
            commands[-1] = (commands[-1][0], commands[-1][1] + "\n" + line)
    assert commands, f"{block.name}: a synopsis starts with `al5d COMMAND`"
    unknown = []
    for command, text in commands:
        done = subprocess.run(
            [str(BIN / "al5d"), command, "--help"], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, f"{block.name}: al5d {command} --help\n{done.stderr}"
        for option in sorted(set(re.findall(r"(?<![\w-])--[\w-]+", text))):
            if not re.search(rf"(?<![\w-]){option}(?![\w-])", done.stdout):
                unknown.append(f"al5d {command} {option}")
    assert not unknown, f"{block.name}: no such options: {unknown}"


def test_the_markers_are_found() -> None:
    """The parser sees the pages' markers (a typo in the comment would run a block that
    needs an arm, or skip none)."""
    assert sum(b.skip_reason() is not None for b in EXAMPLES) >= 5
    assert sum(b.server for b in EXAMPLES) >= 5


def test_python_examples_parse() -> None:
    """Every Python example compiles, the skipped ones too."""
    for b in EXAMPLES:
        if b.lang == "python":
            ast.parse(b.code, filename=b.name)


@pytest.fixture(scope="module")
def workdirs(tmp_path_factory: pytest.TempPathFactory) -> dict[Path, Path]:
    """One working directory per page, with the repository's config/ as a user's clone has it."""
    dirs = {}
    for page in PAGES:
        d = tmp_path_factory.mktemp(page.stem)
        (d / "config").symlink_to(REPO / "config")
        dirs[page] = d
    return dirs


@pytest.fixture(scope="module")
def server() -> Iterator[Proc]:
    """`al5d serve` on its embedded emulator, for the examples that need a server; started
    by the first of them, in the examples' ROS domain."""
    proc = Proc("serve", "--config", patient_config(), "--log-level", "INFO", env=DOMAIN)
    try:
        proc.err.wait_for("STATE: ready", 60)
        yield proc
    finally:
        if proc.popen.poll() is None:
            proc.popen.terminate()  # parks, then ends
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()


def run(block: Block, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **DOMAIN, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    if block.lang == "sh":
        args = ["bash", "-e", "-o", "pipefail", "-c", block.code]
    else:
        args = [sys.executable, "-c", block.code]
    # A process group of its own: what the example left running (a recorder, an emulator)
    # ends with it, and so does everything when it overruns. Not a session of its own: its
    # leader would take the emulator's pty, which an example opens, for its terminal.
    proc = subprocess.Popen(
        args,
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=os.setpgrp,  # process_group=0 from Python 3.11 on
    )
    try:
        out, err = proc.communicate(timeout=BLOCK_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        raise AssertionError(
            f"{block.name}: still running after {BLOCK_S} s\n--- stdout\n{out}--- stderr\n{err}"
        ) from None
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


#: What each example printed (by its name), for an `output` block after it.
PRINTED: dict[str, str] = {}


@pytest.mark.parametrize("block", EXAMPLES, ids=[b.name for b in EXAMPLES])
def test_example_runs(
    block: Block, workdirs: dict[Path, Path], request: pytest.FixtureRequest
) -> None:
    reason = block.skip_reason()
    if reason is not None:
        pytest.skip(f"{block.name}: {reason}")
    if block.server:
        request.getfixturevalue("server")
    done = run(block, workdirs[block.page])
    PRINTED[block.name] = done.stdout + done.stderr
    assert done.returncode == block.exit_code, (
        f"{block.name} exited {done.returncode}, not {block.exit_code}\n"
        f"--- code\n{block.code}--- stdout\n{done.stdout}--- stderr\n{done.stderr}"
    )


OUTPUTS = [b for b in ALL if "output" in b.words()]


@pytest.mark.parametrize("block", OUTPUTS, ids=[b.name for b in OUTPUTS])
def test_shown_output_is_what_the_example_printed(block: Block) -> None:
    """After test_example_runs (pytest runs a file's tests in order)."""
    before = [b for b in EXAMPLES if b.page == block.page and b.line < block.line]
    assert before, f"{block.name}: an output block with no example before it"
    printed = PRINTED.get(before[-1].name)
    if printed is None:
        pytest.fail(f"{block.name}: the example before it did not run")
    lines = {normalised(ln) for ln in printed.splitlines()}
    missing = [ln for ln in block.code.splitlines() if ln.strip() and normalised(ln) not in lines]
    assert not missing, f"{block.name}: not printed as shown: {missing}\n--- printed\n{printed}"


#: What differs from run to run in a line the docs show: an instruction's id (the process's id
#: in hex, a count) and a time in ms. Each stands for any.
VARYING = ((re.compile(r"\[[0-9a-f]+-\d+\]"), "[ID]"), (re.compile(r"\(\d+ ms\)"), "(N ms)"))


def normalised(line: str) -> str:
    for pattern, placeholder in VARYING:
        line = pattern.sub(placeholder, line)
    return line.strip()


def test_a_shown_line_must_be_a_whole_printed_line() -> None:
    """The comparison: a part of a line is not the line, and what varies stands for any."""
    printed = {normalised("move [4d33-1]: refused: elbow: 150 deg is outside the range 0..135")}
    assert normalised("move [77a-12]: refused: elbow: 150 deg is outside the range 0..135") in (
        printed
    )
    assert normalised("refused: elbow: 150 deg is outside the range 0..135") not in printed
    assert normalised("park [1-2]: done (1210 ms)") == normalised("park [ab-7]: done (3 ms)")


LINK = re.compile(r"\]\(([^)\s]+)\)")
#: The requirement ids (docs/glossary.md): the design document's D1..D7 and the
#: assignment's.
REQUIREMENT = re.compile(r"\b(D[1-7]|(?:SA|PO|VE|INF|EX|IM|DE)0\d)\b")


def anchors(page: Path) -> set[str]:
    """GitHub's anchors of a page's headings: lowercase, punctuation gone, spaces as -."""
    found = set()
    for heading in re.findall(r"^#+ (.+)$", FENCE.sub("", page.read_text()), re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        found.add(slug)
    return found


def test_every_relative_link_leads_somewhere() -> None:
    broken = []
    for page in PAGES:
        for target in LINK.findall(FENCE.sub("", page.read_text())):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.name}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert not broken, "\n".join(broken)


def test_every_image_in_docs_is_shown() -> None:
    shown = {t for page in PAGES for t in LINK.findall(page.read_text())}
    images = [p for p in (REPO / "docs").iterdir() if p.suffix in (".png", ".svg", ".jpg")]
    unshown = [p.name for p in images if not any(t.endswith(p.name) for t in shown)]
    assert not unshown, f"images in docs/ no page shows: {unshown}"


def test_every_requirement_id_cited_is_defined_once() -> None:
    """The code, tests, benchmarks and pages cite requirement ids; the glossary defines each."""
    glossary = (REPO / "docs" / "glossary.md").read_text()
    defined = re.findall(r"^\| (\w+) \|", glossary, re.M)
    cited: set[str] = set()
    for folder in ("src", "tests", "bench", "docs"):
        for f in (REPO / folder).rglob("*"):
            if f.suffix in (".py", ".md", ".seq", ".yaml"):
                cited |= set(REQUIREMENT.findall(f.read_text()))
    cited |= set(REQUIREMENT.findall((REPO / "README.md").read_text()))
    ids = [d for d in defined if REQUIREMENT.fullmatch(d)]
    assert sorted(ids) == sorted(set(ids)), "an id defined twice in docs/glossary.md"
    assert not cited - set(ids), f"cited but not in docs/glossary.md: {sorted(cited - set(ids))}"


def test_the_parameter_table_names_every_parameter() -> None:
    """docs/ros.md's table of the node's parameters names each one the node declares
    (an outside try missed `server.table_check`); `geometry.*` are named as a group."""
    from al5d.ros.params import PARAMETERS

    text = (REPO / "docs" / "ros.md").read_text()
    table = text[text.index("| Parameter | Type | What | At run time |") :]
    table = table[: table.index("\n\n")]
    named = set(re.findall(r"`([a-z_.]+)`", table))
    missing = [p for p in PARAMETERS if p not in named and not p.startswith("geometry.")]
    assert not missing, f"not in docs/ros.md's parameter table: {missing}"
