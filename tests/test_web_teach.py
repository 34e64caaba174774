"""Teach and replay in a real browser (issue 27): the Teach tab saves two poses where the
arm stands, builds a sequence of them, saves it where `al5d run` reads it, plays it (the
board's record shows its moves), and a play stopped by STOP halfway sends nothing more.

Four processes, as tests/test_web.py: the emulated board in this one behind a pty link,
`al5d serve`, `al5d web --poses` in a folder of the test's own, and Chromium.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Instruction, Outcome, Result, parse_sequence
from al5d.arm.poses import beside, load_poses
from al5d.ssc32u import protocol as p
from al5d.web.plan import Planner
from al5d.web.player import Player
from al5d_rig.armrig import group_moves
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Served, served
from al5d_rig.webrig import WebProc, chromium, dismiss_notifications, open_page, wait_text

DOCS = Path(__file__).resolve().parents[1] / "docs"
#: AL5D_UPDATE_DOCS=1 copies the Teach tab's screenshot to docs/teach.png (for docs/web.md).
UPDATE_DOCS = os.environ.get("AL5D_UPDATE_DOCS") == "1"
STATUS = "#al5d-teach-status"

#: Two poses well above the table, apart in every joint.
A = {"base": -30, "shoulder": 40, "elbow": 80, "wrist": -10, "gripper": 20, "wrist_rotate": 0}
B = {"base": 30, "shoulder": 20, "elbow": 70, "wrist": 10, "gripper": 0, "wrist_rotate": 15}
C = {"base": 10, "shoulder": 30, "elbow": 75, "wrist": 0, "gripper": 10, "wrist_rotate": -10}


@dataclass
class Rig:
    arm: Served
    web: WebProc
    folder: Path
    page: Any

    def moves(self, since: int) -> list[p.GroupMove]:
        return group_moves(self.arm.emu.records[since:])

    def state(self, state: str, timeout: float = 15.0) -> None:
        wait_until(lambda: self.arm.states[-1] == state, timeout, f"state {state}")

    def ready(self) -> None:
        """The arm unlocked and ready, whatever a test before left it in (a release is
        refused, and changes nothing, where nothing is stopped)."""
        self.arm.peer.trigger("release")
        self.state("ready")


@pytest.fixture(scope="module")
def rig(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    workdir = tmp_path_factory.mktemp("teach-web")
    folder = workdir / "arm"
    folder.mkdir()
    with served(config, workdir, "al5d_teach_web_peer") as arm:
        web = WebProc("--poses", str(folder / "poses.yaml"))
        try:
            with chromium() as browser:
                page = open_page(browser, web.url)
                dismiss_notifications(page)
                page.get_by_role("tab", name="Teach").click()
                yield Rig(arm, web, folder, page)
        finally:
            web.close()


def pulses(config: ArmConfig, degrees: dict[str, float]) -> set[tuple[int, int]]:
    joints = config.joints
    return {(joints[j].channel, round(joints[j].to_us(d))) for j, d in degrees.items()}


def targets(move: p.GroupMove) -> set[tuple[int, int]]:
    return {(t.channel, t.pulse_us) for t in move.targets}


def put_arm_at(rig: Rig, name: str, degrees: dict[str, float]) -> None:
    """The arm at `degrees` (sent by a ROS peer), once the page shows it there: its tool
    readout within 0.5 mm of where the pose puts the tool."""
    arm = rig.arm
    arm.peer.send(f"teach-{name}", "move", time_ms=300, **degrees)
    assert arm.peer.result(f"teach-{name}").outcome == "done"
    tool = Planner(arm.config).tool_of(degrees)
    assert tool is not None
    want = [v * 1000 for v in tool]

    def there(text: str) -> bool:
        found = re.search(r"x (\S+) y (\S+) z (\S+)", text)
        return found is not None and all(
            abs(float(v) - w) < 0.5 for v, w in zip(found.groups(), want, strict=True)
        )

    wait_text(rig.page, "#al5d-tool", there, 15)


def type_into(rig: Rig, label: str, text: str, echo: str) -> None:
    """`text` typed into the box `label`, once the page's server has it (its echo in the
    status): viser's client sends a panel's changes through one sender that keeps only the
    latest of those 50 ms apart, so a click right after could take the typing's place."""
    rig.page.get_by_label(label, exact=True).fill(text)
    wait_text(rig.page, STATUS, lambda t: echo in t)


def click(rig: Rig, button: str, then: str, timeout: float = 10.0) -> str:
    rig.page.get_by_role("button", name=button, exact=True).click()
    return wait_text(rig.page, STATUS, lambda t: then in t, timeout)


def test_save_two_poses_build_a_sequence_and_play_it(rig: Rig, tmp_path: Path) -> None:
    config = rig.arm.config
    for name, degrees in (("a", A), ("b", B)):
        put_arm_at(rig, name, degrees)
        type_into(rig, "pose name", name, f"pose {name!r}: a new name")
        click(rig, "save pose", f"saved pose {name!r}")
    book = load_poses(rig.folder / "poses.yaml")
    assert book.names == ("a", "b")
    for name, degrees in (("a", A), ("b", B)):
        pose = book.find(name)
        assert pose is not None
        assert dict(pose.joints) == pytest.approx(degrees, abs=0.11)
    listed = rig.page.inner_text("#al5d-poses")
    assert "a base -30" in listed and "b base 30" in listed, listed

    # Built from what was typed and from the buttons (the pose chosen is the last saved).
    type_into(rig, "steps", "pose a time=600\nmove gripper=45 time=300\nwait 200", "3 steps")
    click(rig, "pose", "4 steps")
    type_into(rig, "sequence name", "pick", "sequence 'pick': a new name")
    click(rig, "save sequence", "saved")
    saved = rig.folder / "pick.seq"
    text = saved.read_text()
    assert text == "pose a time=600\nmove gripper=45 time=300\nwait 200\npose b time=1000\n"
    # `al5d run`'s reading of it: the poses file beside it.
    steps = parse_sequence(saved.read_bytes(), str(saved), poses=load_poses(beside(saved)))
    assert [str(item) for item, _ in steps][-1].startswith("move base=30 shoulder=20")

    n0 = len(rig.arm.emu.records)
    click(rig, "play", "played 4 steps: every one done", 30)
    moves = rig.moves(n0)
    assert [targets(m) for m in moves] == [
        pulses(config, A),
        pulses(config, {"gripper": 45}),
        pulses(config, B),
    ]
    assert [m.time_ms for m in moves] == [600, 300, 1000]
    rig.state("ready")

    shot = tmp_path / "teach.png"
    rig.page.screenshot(path=str(shot))
    if UPDATE_DOCS:
        shutil.copyfile(shot, DOCS / "teach.png")


def write_poses(rig: Rig, more: str = "") -> None:
    """Poses a and b (and `more`), as an editor writes them: the page reads the file at
    each use."""
    text = "".join(
        f"{name}: {{{', '.join(f'{j}: {v}' for j, v in pose.items())}}}\n"
        for name, pose in (("a", A), ("b", B))
    )
    (rig.folder / "poses.yaml").write_text(text + more)


def test_a_sequence_written_by_hand_plays_and_stop_halfway_ends_it(rig: Rig) -> None:
    config = rig.arm.config
    write_poses(rig, "lean: {base: 15, elbow: 85}\n")
    # The first step long enough for the click to land in it: a click waits on the page's
    # renderer, which draws the moving arm on the CPU (SwiftShader): 0.75 s here with
    # nothing else running, 0.1 to 1.9 s beside two busy loops, and a CI run of four
    # workers played all three steps (5.5 s and the way home) before its click came.
    (rig.folder / "halfway.seq").write_text(
        "# by hand\npose a time=30000\npose b time=500\nready\n"
    )
    rig.ready()
    type_into(rig, "sequence name", "halfway", "sequence 'halfway' is saved")
    click(rig, "load sequence", "3 steps: ready to play")
    wait_text(rig.page, "#al5d-poses", lambda t: "lean base 15 elbow 85" in t)
    n0 = len(rig.arm.emu.records)
    before = set(rig.arm.peer.results_now())
    rig.page.get_by_role("button", name="play", exact=True).click()
    wait_text(rig.page, STATUS, lambda t: "playing step 1 of 3: pose a time=30000" in t)
    rig.state("moving")
    started = time.monotonic()
    rig.page.get_by_role("button", name="STOP", exact=True).click()
    took = time.monotonic() - started
    # The click reached the web view (where it did not, its log since says what it did).
    rig.web.proc.err.wait_for("web: STOP clicked", 15)
    try:
        text = wait_text(rig.page, STATUS, lambda t: "play ended" in t)
    except AssertionError as e:
        raise AssertionError(f"{e} (the click took {took:.1f} s)") from None
    # The play learns of the click, or first (on a busy host) of its step cancelled by the
    # stop the click sent: either way it ends there (nothing more sent: the outcomes below).
    assert "by STOP: nothing more sent" in text or "cancelled: cancelled by stop" in text, text
    rig.state("stopped")
    channels = {joint.channel for joint in config.joints.values()}
    wait_until(
        lambda: (
            {
                c.channel
                for r in rig.arm.emu.records[n0:]
                for c in r.commands
                if isinstance(c, p.Stop)
            }
            == channels
        ),
        15,
        "a STOP for every channel",
    )
    assert [targets(m) for m in rig.moves(n0)] == [pulses(config, A)]

    def moves_told() -> list[str]:
        results = rig.arm.peer.results_now()
        return [
            r.outcome for i, r in results.items() if i not in before and r.instruction == "move"
        ]

    wait_until(lambda: moves_told() == ["cancelled"], 15, "the first step cancelled")
    assert rig.arm.peer.trigger("release").success
    rig.state("ready")
    # The second step was never sent (a locked server would have refused it: an outcome).
    assert moves_told() == ["cancelled"]
    assert [targets(m) for m in rig.moves(n0)] == [pulses(config, A)]


def test_a_step_the_server_would_refuse_plays_nothing(rig: Rig) -> None:
    write_poses(rig)
    rig.ready()
    # Judged as it is typed, as `al5d run` judges a file: every line the server would refuse.
    type_into(
        rig, "steps", "pose b\nmove elbow=200\nmove elbo=20", "line 2 (move elbow=200): elbow"
    )
    said = rig.page.inner_text(STATUS)
    assert "; line 3 (move elbo=20): unknown joint 'elbo'; did you mean 'elbow'?" in said, said
    n0 = len(rig.arm.emu.records)
    text = click(rig, "play", "nothing played")
    assert "line 2 (move elbow=200): elbow: 200 deg is outside" in text, text
    type_into(rig, "steps", "pose b\npose c", "no saved pose named 'c'")
    text = click(rig, "play", "nothing played")
    assert "word 2 'c': no saved pose named 'c'" in text, text
    assert rig.moves(n0) == []


def choose(rig: Rig, label: str, option: str) -> None:
    rig.page.get_by_label(label, exact=True).click()
    rig.page.get_by_role("option", name=option, exact=True).click()


def test_saving_over_a_saved_pose_asks_first(rig: Rig) -> None:
    write_poses(rig)
    rig.ready()
    put_arm_at(rig, "c", C)
    type_into(rig, "pose name", "a", "pose 'a' is saved: save pose asks before it replaces it")
    # Kept: the file as it was.
    click(rig, "save pose", "pose 'a' is saved already: replace it, or keep it?")
    dialog = rig.page.get_by_role("dialog")
    assert "Replace pose 'a'?" in dialog.inner_text()
    assert "base -30" in dialog.inner_text()  # what would go
    dialog.get_by_role("button", name="keep it").click()
    wait_text(rig.page, STATUS, lambda t: t == "not saved: pose 'a' kept as it was")
    pose = load_poses(rig.folder / "poses.yaml").find("a")
    assert pose is not None and dict(pose.joints) == pytest.approx(A)
    # Replaced, once the user said so.
    click(rig, "save pose", "pose 'a' is saved already")
    rig.page.get_by_role("dialog").get_by_role("button", name="replace").click()
    wait_text(rig.page, STATUS, lambda t: t.startswith("replaced pose 'a'"))
    pose = load_poses(rig.folder / "poses.yaml").find("a")
    assert pose is not None and dict(pose.joints) == pytest.approx(C, abs=0.11)


def test_a_pose_renamed_or_deleted_says_which_sequences_still_name_it(rig: Rig) -> None:
    write_poses(rig, "lone: {base: 5}\nshared: {base: 6}\n")
    (rig.folder / "onlylone.seq").write_text("pose lone\n")
    for name in ("shared1", "shared2"):
        (rig.folder / f"{name}.seq").write_text("pose shared time=300\n")
    try:
        type_into(rig, "pose name", "lone2", "pose 'lone2': a new name")
        choose(rig, "pose", "lone")
        rig.page.get_by_role("button", name="rename", exact=True).click()
        text = wait_text(rig.page, STATUS, lambda t: t.startswith("renamed pose 'lone'"))
        assert text.endswith("; onlylone.seq still names it: edit it"), text
        choose(rig, "pose", "shared")
        rig.page.get_by_role("button", name="delete", exact=True).click()
        text = wait_text(rig.page, STATUS, lambda t: t.startswith("deleted pose 'shared'"))
        assert text.endswith("shared1.seq and shared2.seq still name it: edit them"), text
    finally:
        for name in ("onlylone", "shared1", "shared2"):
            (rig.folder / f"{name}.seq").unlink()


class Arm:
    """The player's way to the server, answering each instruction as `answer` says (None:
    no outcome, the move still going)."""

    def __init__(self, answer: Callable[[Instruction], Outcome | None]) -> None:
        self.answer = answer
        self.sent: list[str] = []
        self.lost = False
        self.said: list[tuple[str, bool | None]] = []
        self.player = Player(self.send, lambda: self.lost, lambda t, ok: self.said.append((t, ok)))

    def send(self, instr: Instruction) -> bool:
        if self.lost:
            return False
        self.sent.append(str(instr))
        outcome = self.answer(instr)
        if outcome is not None:
            self.player.on_outcome(outcome)
        return True

    def play(self, text: str) -> str:
        steps = parse_sequence(text.encode())
        lines = [line for line in text.splitlines() if line]
        assert self.player.start(list(zip(lines, steps, strict=True)))
        self.player.join(10)
        assert not self.player.busy
        return self.said[-1][0]


def done(instr: Instruction) -> Outcome:
    return Outcome(instr.id, instr.name, Result.DONE)


def test_the_player_plays_every_step_and_waits_for_those_in_the_background() -> None:
    arm = Arm(done)
    said = arm.play("move base=10 &\nwait 10\nmove base=20 time=100\nready")
    assert said == "played 4 steps: every one done"
    assert arm.sent == ["move base=10", "move base=20 time=100", "ready"]
    assert [t for t, _ in arm.said][:2] == [
        "playing step 1 of 4: move base=10 & (STOP ends the play)",
        "playing step 2 of 4: wait 10 (STOP ends the play)",
    ]


def test_the_player_ends_at_a_step_not_done_in_the_background_too() -> None:
    def refuse_base(instr: Instruction) -> Outcome:
        if instr.joints and instr.joints[0][0] == "base":
            return Outcome(instr.id, instr.name, Result.REFUSED, "base: no")
        return done(instr)

    arm = Arm(refuse_base)
    said = arm.play("move base=10 &\nwait 10\nmove elbow=20")
    assert said == "play ended at step 1 of 3: move base=10 &: refused: base: no"
    assert arm.sent == ["move base=10"]
    arm = Arm(refuse_base)
    assert arm.play("ready\nmove base=1\nready").startswith("play ended at step 2 of 3")
    assert arm.sent == ["ready", "move base=1"]


def test_the_player_ends_when_the_server_is_lost_or_at_stop() -> None:
    arm = Arm(lambda instr: None)  # no outcome: the server gone
    arm.player.start([("ready", (parse_sequence(b"ready")[0]))])
    wait_until(lambda: arm.sent == ["ready"], 5, "the first step sent")
    arm.lost = True
    arm.player.join(10)
    assert arm.said[-1] == (
        "play ended at step 1 of 1: no contact with the server; nothing more sent",
        False,
    )
    arm = Arm(done)
    steps = parse_sequence(b"ready\nwait 60000\npark")
    arm.player.start(list(zip(["ready", "wait 60000", "park"], steps, strict=True)))
    wait_until(lambda: arm.said and "step 2 of 3" in arm.said[-1][0], 5, "the wait")
    arm.player.halt("STOP")
    arm.player.join(10)
    assert not arm.player.busy
    assert arm.said[-1] == ("play ended by STOP: nothing more sent", False)
    assert arm.sent == ["ready"]
