"""Teach and replay: the page's Teach tab, its poses file and sequence files.

Save where the arm is under a name, list, rename and delete the poses; build a sequence
(saved poses, times, waits, the gripper) as the text of a sequence file, save it, load
it, play it. The poses are `al5d.arm.poses`'s file (`--poses`, by default `poses.yaml`
beside the configuration, else in the current directory) and the sequences are
`<name>.seq` beside it: `al5d run pick.seq` runs what the page saved, and the page plays
what an editor wrote. Every change reads the file again first, so that an edit made
meanwhile in an editor is kept, not overwritten.

A play (`al5d.web.player`) sends each step as any instruction and waits for its outcome
before the next, as `al5d run` does.
"""

from __future__ import annotations

import html
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import viser

from al5d.arm.instruction import Instruction, Outcome
from al5d.arm.poses import (
    SEQUENCE_SUFFIX,
    NamedPoses,
    Pose,
    PosesError,
    load_poses,
    name_problem,
    parse_text,
    save_poses,
    save_sequence,
    sequence_names,
    used_by,
)
from al5d.arm.sequence import Line, SequenceJudge
from al5d.model.transforms import Transform
from al5d.web.page import Page
from al5d.web.panel import status_html
from al5d.web.player import Player

#: The element of the Teach tab's status line, and of its list of poses (tests find them).
STATUS = "al5d-teach-status"
POSES = "al5d-poses"
#: What an empty dropdown shows (viser's needs an option).
NONE = "(none)"


class Teach:
    """The Teach tab of `page`, its files (the poses at `poses_path`, the sequences beside
    them) and its player."""

    def __init__(self, page: Page, poses_path: Path) -> None:
        self.page = page
        self.path = poses_path
        self.folder = poses_path.parent
        self._lock = threading.RLock()
        #: The poses the list shows.
        self._shown: tuple[Pose, ...] | None = None
        book = load_poses(poses_path, required=False)  # a bad file: PosesError, at start
        self.player = Player(self._send, lambda: page.lost, self._show)
        #: A sequence judged whole before anything of it is sent, as `al5d run` judges one.
        self.judge = SequenceJudge(page.config)
        config = page.config
        self.gui = gui = page.server.gui
        tabs: Any = page.panel.tabs
        with tabs.add_tab("Teach", viser.Icon.SCHOOL):
            with gui.add_folder("Poses"):
                self.pose_name: Any = gui.add_text("pose name", "", hint=f"e.g. home ({NAME_HINT})")
                self.save_pose = gui.add_button("save pose", icon=viser.Icon.DEVICE_FLOPPY)
                self.pose: Any = gui.add_dropdown("pose", book.names or (NONE,))
                # A row: "rename" names the chosen pose by the pose name typed above.
                self.pose_actions = gui.add_button_group("", POSE_ACTIONS)
                self.poses_html = gui.add_html("")
            with gui.add_folder("Sequence"):
                self.steps: Any = gui.add_text(
                    "steps", "", multiline=True, hint="one step a line, as in a sequence file"
                )
                self.move_ms = gui.add_number(
                    "step time (ms)", 1000, min=0, max=config.server.max_move_time_ms, step=100
                )
                lo, hi = config.joints["gripper"].range_deg
                self.gripper = gui.add_number("step gripper (deg)", lo, min=lo, max=hi, step=1)
                self.wait_ms = gui.add_number("wait (ms)", 500, min=0, max=60_000, step=100)
                self.add = gui.add_button_group("add", ADD_STEPS)
                self.play = gui.add_button("play", color="green", icon=viser.Icon.PLAYER_PLAY)
                saved = sequence_names(self.folder) or (NONE,)
                self.sequence: Any = gui.add_dropdown("saved", saved)
                self.sequence_name: Any = gui.add_text("sequence name", "", hint=NAME_HINT)
                self.save_sequence = gui.add_button("save sequence", icon=viser.Icon.DEVICE_FLOPPY)
                self.load = gui.add_button("load sequence", icon=viser.Icon.FOLDER_OPEN)
            self.status = gui.add_html(
                status_html(f"poses and sequences in {self.folder}", None, STATUS)
            )
        self._show_poses(book)
        # What needs the server goes off with it, as the page's other controls do.
        for control in (self.save_pose, self.play):
            control.disabled = page.lost
            page.panel.controls.append(control)
        self._wire()

    def _wire(self) -> None:
        self.page.panel.stop.on_click(self._on_stop)
        self.save_pose.on_click(_by_user(lambda e: self._save_pose(e.client)))
        handlers: list[tuple[Any, Callable[[], None]]] = [
            (self.play, self._play),
            (self.save_sequence, self._save_sequence),
            (self.load, self._load),
        ]
        for button, handler in handlers:
            button.on_click(_by_user(_ignoring_event(handler)))
        by_action = dict(zip(POSE_ACTIONS, (self._go_to, self._rename, self._delete), strict=True))
        self.pose_actions.on_click(_by_user(lambda e: by_action[e.target.value]()))
        steps: dict[str, Callable[[], str]] = {
            "pose": lambda: f"pose {self.pose.value}{self._time()}",
            "gripper": lambda: f"move gripper={self._gripper()}{self._time()}",
            "wait": lambda: f"wait {int(self.wait_ms.value)}",
        }
        self.add.on_click(_by_user(lambda e: self._add(steps[e.target.value]())))
        self.steps.on_update(_by_user(lambda _: self._check(str(self.steps.value))))
        self.pose_name.on_update(_by_user(lambda _: self._pose_named()))
        self.sequence_name.on_update(_by_user(lambda _: self._sequence_named()))
        self.sequence.on_update(_by_user(lambda _: self._sequence_chosen()))

    # -- what the link hands over, the page's STOP, and the player's way out ----------

    def on_outcome(self, outcome: Outcome) -> None:
        self.player.on_outcome(outcome)

    async def _on_stop(self, event: Any) -> None:
        # On viser's event loop, as the page's own STOP (which stops the arm).
        self.player.halt("STOP")

    def _send(self, instr: Instruction) -> bool:
        return self.page.send_instruction(instr)  # as the page's own moves: it ends a jog

    def _show(self, text: str, ok: bool | None) -> None:
        with self._lock:
            self.status.content = status_html(text, ok, STATUS)

    # -- poses ---------------------------------------------------------------------

    def _book(self) -> NamedPoses | None:
        """The poses as the file has them now (the list shows them: an editor may have
        changed them); None (and why, said) if it cannot be read."""
        try:
            book = load_poses(self.path, required=False)
        except PosesError as e:
            # Its first problem, and how many more (the file names each, a line each).
            first, *more = str(e).splitlines() or [""]
            also = f"; and {len(more)} more problems" if more else ""
            self._show(f"{first}{also} (fix the file: nothing was changed)", False)
            return None
        self._show_poses(book)
        return book

    def _show_poses(self, book: NamedPoses, selected: str | None = None) -> None:
        with self._lock:
            if book.poses != self._shown:
                self._shown = book.poses
                self.pose.options = book.names or (NONE,)
                self.poses_html.content = poses_html(book)
            if selected is not None:
                self.pose.value = selected

    def _changed(self, book: NamedPoses, said: str, selected: str | None = None) -> None:
        try:
            book = save_poses(book)
        except OSError as e:
            self._show(f"cannot write {self.path}: {e.strerror}", False)
            return
        self._show_poses(book, selected)
        self._show(said, True)

    def _save_pose(self, client: Any, replace: bool = False) -> None:
        """Where the arm is, under the name typed; a name saved already is replaced only once
        the user who clicked has said so (`replace`)."""
        name = str(self.pose_name.value).strip()
        degrees = self.page.degrees
        book = self._book()
        if book is None:
            return
        if degrees is None:
            self._show("the arm's pose is not known yet: nothing saved", False)
            return
        try:
            new = book.with_pose(name, degrees)
        except PosesError as e:
            self._show(f"not saved: {e}", False)
            return
        if book.find(name) is not None and not replace:
            self._ask_replace(client, name)
            return
        verb = "replaced" if book.find(name) is not None else "saved"
        self._changed(new, f"{verb} pose {name!r} in {self.path}", name)

    def _ask_replace(self, client: Any, name: str) -> None:
        """Ask the user who clicked whether the pose saved as `name` goes (a window over the
        page, theirs alone)."""
        pose = self._shown_pose(name)
        self._show(f"pose {name!r} is saved already: replace it, or keep it?", None)
        gui = client.gui if client is not None else self.gui
        with gui.add_modal(f"Replace pose {name!r}?") as modal:
            gui.add_html(
                '<div style="font-size:0.9em;padding:0 0.6em">'
                f"{html.escape(pose)}<br>would become where the arm is now.</div>"
            )
            replace = gui.add_button("replace", color="red", icon=viser.Icon.DEVICE_FLOPPY)
            keep = gui.add_button("keep it", icon=viser.Icon.X)

        def answered(replacing: bool) -> None:
            modal.close()
            if replacing:
                self._save_pose(client, replace=True)
            else:
                self._show(f"not saved: pose {name!r} kept as it was", None)

        replace.on_click(_by_user(lambda _: answered(True)))
        keep.on_click(_by_user(lambda _: answered(False)))

    def _shown_pose(self, name: str) -> str:
        with self._lock:
            pose = next((p for p in self._shown or () if p.name == name), None)
        if pose is None:
            return f"The pose {name!r}"
        angles = ", ".join(f"{j} {v:g}" for j, v in pose.joints)
        return f"The pose {name!r} ({angles})"

    def _pose_named(self) -> None:
        """What `save pose` would do with the name typed."""
        name = str(self.pose_name.value).strip()
        book = self._book()
        if book is None:
            return
        problem = name_problem(name)
        if problem:
            self._show(problem, False)
        elif book.find(name) is not None:
            self._show(f"pose {name!r} is saved: save pose asks before it replaces it", None)
        else:
            self._show(f"pose {name!r}: a new name", None)

    def _selected(self, book: NamedPoses) -> str | None:
        name = str(self.pose.value)
        if book.find(name) is None:
            self._show("choose a saved pose first" if name == NONE else book.unknown(name), False)
            return None
        return name

    def _go_to(self) -> None:
        book = self._book()
        name = None if book is None else self._selected(book)
        if book is None or name is None:
            return
        if self.player.busy:
            self._show("a sequence is playing: STOP ends it", False)
            return
        if self.page.lost:
            self._show("no contact with the server: nothing sent", False)
            return
        steps = parse_text(f"pose {name}{self._time()}", book)
        item, _ = steps[0]
        assert isinstance(item, Instruction)
        if self._send(item):
            self._show(f"sent: pose {name}{self._time()}", None)
        else:
            self._show("not sent: no contact with the server", False)

    def _rename(self) -> None:
        book = self._book()
        old = None if book is None else self._selected(book)
        if book is None or old is None:
            return
        new = str(self.pose_name.value).strip()
        try:
            renamed = book.renamed(old, new)
        except PosesError as e:
            self._show(f"not renamed: {e}", False)
            return
        self._changed(renamed, f"renamed pose {old!r} to {new!r}{self._still(old)}", new)

    def _delete(self) -> None:
        book = self._book()
        name = None if book is None else self._selected(book)
        if book is None or name is None:
            return
        self._changed(book.without(name), f"deleted pose {name!r}{self._still(name)}")

    def _still(self, name: str) -> str:
        using = used_by(self.folder, name)
        if not using:
            return ""
        files = [f"{s}{SEQUENCE_SUFFIX}" for s in using]
        if len(files) == 1:
            return f"; {files[0]} still names it: edit it"
        return f"; {', '.join(files[:-1])} and {files[-1]} still name it: edit them"

    # -- the sequence --------------------------------------------------------------

    def _time(self) -> str:
        ms = int(self.move_ms.value)
        return f" time={ms}" if ms else ""

    def _gripper(self) -> str:
        return f"{float(self.gripper.value):g}"

    def _add(self, line: str) -> None:
        with self._lock:
            text = str(self.steps.value)
            if text and not text.endswith("\n"):
                text += "\n"
            text += line + "\n"
            self.steps.value = text
        self._check(text)

    def _parse(self, text: str, book: NamedPoses) -> tuple[Line, ...] | str:
        """The steps of `text` judged whole as `al5d run` judges a file, from where the arm
        is (`al5d.arm.sequence`), or why it cannot be played (every problem, with its line)."""
        judged = self.judge.judge_text(text, "steps", book, self.page.degrees)
        if judged.ok:
            return judged.lines
        return "; ".join(f"line {p.number} ({p.text}): {p.reason}" for p in judged.problems)

    def _check(self, text: str) -> None:
        """Say whether `text` would play, as it is typed."""
        book = self._book()
        if book is None:
            return
        steps = self._parse(text, book)
        if isinstance(steps, str):
            self._show(steps, False)
        else:
            self._show(f"{len(steps)} step{'s' if len(steps) != 1 else ''}: ready to play", True)

    def _play(self) -> None:
        if self.player.busy:
            self._show("a sequence is playing: STOP ends it", False)
            return
        text = str(self.steps.value)
        book = self._book()
        if book is None:
            return
        if self.page.lost:
            self._show("nothing played: no contact with the server", False)
            return
        if self.page.degrees is None:
            self._show("nothing played: the arm's pose is not known yet", False)
            return
        steps = self._parse(text, book)
        if isinstance(steps, str):
            self._show(f"nothing played: {steps}", False)
            return
        if not steps:
            self._show("nothing to play: add steps first", False)
            return
        if not self.player.start([(line.text, line.step) for line in steps]):
            self._show("a sequence is playing: STOP ends it", False)

    def _saved_sequences(self) -> None:
        """The list of saved sequences as the folder has it now (an editor may add some)."""
        with self._lock:
            self.sequence.options = sequence_names(self.folder) or (NONE,)

    def _sequence_named(self) -> None:
        """What `save sequence` and `load sequence` would do with the name typed."""
        self._saved_sequences()
        name = str(self.sequence_name.value).strip()
        problem = name_problem(name)
        if problem:
            self._show(problem, False)
        elif (self.folder / f"{name}{SEQUENCE_SUFFIX}").exists():
            self._show(f"sequence {name!r} is saved: load it, or save to replace it", None)
        else:
            self._show(f"sequence {name!r}: a new name", None)

    def _sequence_chosen(self) -> None:
        name = str(self.sequence.value)
        if name != NONE:
            with self._lock:
                self.sequence_name.value = name
            self._sequence_named()

    def _save_sequence(self) -> None:
        name = str(self.sequence_name.value).strip()
        text = str(self.steps.value)
        try:
            path = save_sequence(self.folder, name, text)
        except PosesError as e:
            self._show(f"not saved: {e}", False)
            return
        except OSError as e:
            self._show(f"cannot write {self.folder}: {e.strerror}", False)
            return
        self._saved_sequences()
        with self._lock:
            self.sequence.value = name
        book = self._book()
        steps = "" if book is None else self._parse(text, book)
        if isinstance(steps, str) and steps:
            self._show(f"saved {path}, but it will not play: {steps}", False)
        else:
            self._show(f"saved {path}: al5d run {path}", True)

    def _load(self) -> None:
        """The sequence named in the box into the steps (what they held is replaced)."""
        self._saved_sequences()
        name = str(self.sequence_name.value).strip()
        problem = name_problem(name)
        if problem:
            self._show(f"nothing loaded: {problem}", False)
            return
        path = self.folder / f"{name}{SEQUENCE_SUFFIX}"
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            why = e.strerror if isinstance(e, OSError) else "not UTF-8 text"
            self._show(f"cannot read {path}: {why}", False)
            return
        with self._lock:
            self.steps.value = text
            self.sequence.value = name
        self._check(text)


NAME_HINT = "letters, digits, _ and -"
#: The buttons of the chosen pose, and those that add a step to the sequence.
POSE_ACTIONS = ("go to", "rename", "delete")
ADD_STEPS = ("pose", "gripper", "wait")


def _by_user(handler: Callable[[Any], None]) -> Callable[[Any], None]:
    """A viser handler that calls `handler` for a user's input only (not the page's own)."""

    def on_event(event: Any) -> None:
        if event.client is not None:
            handler(event)

    return on_event


def _ignoring_event(handler: Callable[[], None]) -> Callable[[Any], None]:
    return lambda _: handler()


def poses_html(book: NamedPoses) -> str:
    """The saved poses, a line each with its angles; names are escaped (a file's text)."""
    if not book.poses:
        body = '<span style="color:#868e96">no pose saved yet</span>'
    else:
        body = "<br>".join(
            f"<b>{html.escape(p.name)}</b> "
            + " ".join(f"{html.escape(j)} {v:g}" for j, v in p.joints)
            for p in book.poses
        )
    return (
        f'<div id="{POSES}" style="font-family:monospace;font-size:0.8em;padding:0 0.6em;'
        f'overflow-wrap:anywhere">{body}</div>'
    )


class Listeners:
    """What the ROS link hands over: all of it to the page, the outcomes to the player too."""

    def __init__(self, page: Page, teach: Teach) -> None:
        self.page = page
        self.teach = teach

    def on_description(self, urdf: str) -> None:
        self.page.on_description(urdf)

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None:
        self.page.on_joints(names, positions, t)

    def on_state(self, state: str) -> None:
        self.page.on_state(state)

    def on_outcome(self, outcome: Outcome) -> None:
        self.page.on_outcome(outcome)
        self.teach.on_outcome(outcome)

    def on_instruction(self, instr: Instruction) -> None:
        self.page.on_instruction(instr)

    def on_mount(self, parent: str, mount: Transform) -> None:
        self.page.on_mount(parent, mount)

    def on_physical(self, degrees: dict[str, float]) -> None:
        self.page.on_physical(degrees)

    def on_answer(self, text: str, ok: bool | None) -> None:
        self.page.on_answer(text, ok)
