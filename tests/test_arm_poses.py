"""The poses file and `pose <name>` lines in sequence files (issue 27, teach and replay):
each error names the file, the pose and the joint (or the line and the word), and what
the web view saves is what `al5d run` reads, and the other way round."""

from __future__ import annotations

from pathlib import Path

import pytest

from al5d.arm.instruction import (
    MAX_SEQUENCE_ERRORS,
    Instruction,
    Kind,
    SequenceErrors,
    Wait,
    parse_sequence,
    parse_sequence_step,
)
from al5d.arm.poses import (
    NAME_RULE,
    NamedPoses,
    PosesError,
    beside,
    load_poses,
    parse_poses,
    parse_text,
    save_poses,
    save_sequence,
    sequence_names,
    used_by,
)
from al5d.model import JOINTS

HOME = {"base": 0.0, "shoulder": 30.0, "elbow": 90.0, "wrist": 0.0, "gripper": 0.0}
FILE = Path("/arm/poses.yaml")


def test_a_poses_file_reads_in_the_arms_joint_order() -> None:
    book = parse_poses(
        "# mine\nhome: {gripper: 0, base: 0, shoulder: 30, elbow: 90, wrist: 0}\n"
        "cup:\n  base: -35.5\n  elbow: 80\n",
        FILE,
    )
    assert book.names == ("home", "cup")
    home = book.find("home")
    assert home is not None
    assert [j for j, _ in home.joints] == [j for j in JOINTS if j in HOME]
    cup = book.find("cup")
    assert cup is not None and cup.joints == (("base", -35.5), ("elbow", 80.0))
    assert parse_poses("", FILE) == NamedPoses(FILE)


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("home: {base: x}", "/arm/poses.yaml: home.base: 'x' is not a number of degrees"),
        ("home: {base: true}", "/arm/poses.yaml: home.base: True is not a number of degrees"),
        ("home: {base: .nan}", "/arm/poses.yaml: home.base: nan is not a finite number"),
        ("home: {elbw: 3}", "/arm/poses.yaml: home.elbw: no such joint; the joints: base, "),
        ("home: {}", "/arm/poses.yaml: home: no joint angles"),
        ("home: 30", "/arm/poses.yaml: home: joint angles by joint name"),
        ("my pose: {base: 0}", "/arm/poses.yaml: pose 'my pose' is not a name: letters, "),
        ("no: {base: 0}", '/arm/poses.yaml: pose False: a name is text: write it in quotes, "'),
        ("- home", "/arm/poses.yaml: the file must map pose names to joint angles"),
        ("home: {base: [", "/arm/poses.yaml: not valid YAML"),
    ],
)
def test_a_bad_poses_file_names_the_pose_and_the_joint(text: str, error: str) -> None:
    with pytest.raises(PosesError) as e:
        parse_poses(text, FILE)
    assert str(e.value).startswith(error), str(e.value)


def test_every_bad_pose_and_joint_of_a_file_is_told_a_line_each() -> None:
    """A file written by hand is mended in one go: each problem named, not only the first;
    the good poses between them are no problem."""
    text = (
        "a: {base: x, elbow: 3, wrist: .inf}\n"
        "ok: {base: 1}\n"
        "b: {bse: 1}\n"
        "my pose: {base: 0}\n"
        "c: 30\n"
    )
    with pytest.raises(PosesError) as e:
        parse_poses(text, FILE)
    assert str(e.value).splitlines() == [
        "/arm/poses.yaml: a.base: 'x' is not a number of degrees",
        "/arm/poses.yaml: a.wrist: inf is not a finite number of degrees",
        "/arm/poses.yaml: b.bse: no such joint; the joints: " + ", ".join(JOINTS),
        "/arm/poses.yaml: pose 'my pose' is not a name: " + NAME_RULE,
        "/arm/poses.yaml: c: joint angles by joint name, e.g. {base: 0, elbow: 90}",
    ]
    many = "".join(f"p{k}: {{base: x}}\n" for k in range(MAX_SEQUENCE_ERRORS + 7))
    with pytest.raises(PosesError) as e:
        parse_poses(many, FILE)
    said = str(e.value).splitlines()
    assert len(said) == MAX_SEQUENCE_ERRORS + 1 and said[-1] == "... and 7 more problems"


@pytest.mark.parametrize(
    ("text", "twice"),
    [("home: {base: 0}\nhome: {base: 20}", "'home'"), ("a: {base: 0, base: 2}", "'base'")],
)
def test_a_name_or_a_joint_written_twice_is_an_error_with_its_line(text: str, twice: str) -> None:
    """PyYAML's safe loader keeps the last of a key written twice, silently (seen: a pose
    written twice by hand took the second): the file is refused, with the line."""
    with pytest.raises(PosesError) as e:
        parse_poses(text, FILE)
    said = str(e.value)
    assert (
        said.startswith("/arm/poses.yaml: not valid YAML: ") and f"{twice} is named twice" in said
    )
    assert "line " in said, said


def test_a_book_saves_renames_and_deletes_and_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "poses.yaml"
    book = load_poses(path, required=False)
    assert not book.exists and book.names == ()
    with pytest.raises(PosesError, match="no such poses file"):
        load_poses(path)
    book = book.with_pose("home", HOME)
    book = book.with_pose("no", {"base": -10.0})  # a YAML word: written in quotes
    # Replaced in place.
    book = save_poses(book.with_pose("home", {**HOME, "base": 5.0, "wrist_rotate": 12.345}))
    assert book.exists and book.names == ("home", "no")
    again = load_poses(path)
    assert again == book
    home = again.find("home")
    assert home is not None and dict(home.joints)["wrist_rotate"] == 12.3  # 0.1 degree
    assert dict(home.joints)["base"] == 5.0
    renamed = again.renamed("no", "cup")
    assert renamed.names == ("home", "cup")
    with pytest.raises(PosesError, match="a pose named 'home' is saved already"):
        renamed.renamed("cup", "home")
    with pytest.raises(PosesError, match="'a b' is not a name"):
        renamed.renamed("cup", "a b")
    with pytest.raises(PosesError, match=r"no saved pose named 'mug' \(in .*: home, cup\)"):
        renamed.without("mug")
    assert renamed.without("home").names == ("cup",)
    with pytest.raises(PosesError, match="'9lives' is not a name"):
        renamed.with_pose("9lives", HOME)


def test_the_default_poses_file_is_beside_the_sequence() -> None:
    assert beside("/arm/pick.seq") == Path("/arm/poses.yaml")
    assert beside(None) == Path("poses.yaml")


def test_a_pose_line_is_a_move_of_its_joints() -> None:
    book = NamedPoses(FILE).with_pose("home", HOME)
    step = parse_sequence_step("pose home time=800 &", poses=book)
    assert step is not None
    move, background = step
    assert isinstance(move, Instruction) and background
    assert move.kind is Kind.MOVE and move.time_ms == 800
    assert dict(move.joints) == HOME
    step = parse_sequence_step("POSE home", poses=book)
    assert step is not None and isinstance(step[0], Instruction) and step[0].time_ms is None


def test_pose_lines_errors_name_the_line_and_the_word_and_nothing_runs() -> None:
    book = NamedPoses(FILE).with_pose("home", HOME).with_pose("cup", {"base": 30.0})
    text = (
        b"pose home time=800\n"
        b"pose hom\n"
        b"pose\n"
        b"pose home speed=3\n"
        b"pose home time=1 time=2\n"
        b"pose home time=-5\n"
        b"pose time=800\n"
    )
    with pytest.raises(SequenceErrors) as e:
        parse_sequence(text, "pick.seq", poses=book)
    assert e.value.errors == (
        "pick.seq:2: word 2 'hom': no saved pose named 'hom'; did you mean 'home'? "
        "(in /arm/poses.yaml: home, cup)",
        "pick.seq:3: word 1 'pose': name a saved pose: pose <name> [time=<ms>]",
        "pick.seq:4: word 3 'speed=3': a pose takes only time=<ms>",
        "pick.seq:5: word 4 'time=2': time given twice",
        "pick.seq:6: word 3 'time=-5': time -5 ms is negative",
        "pick.seq:7: word 2 'time=800': name a saved pose: pose <name> [time=<ms>]",
    )
    with pytest.raises(SequenceErrors, match=r"no poses file at /arm/poses\.yaml"):
        parse_sequence(b"pose home\n", "pick.seq", poses=NamedPoses(FILE, exists=False))
    with pytest.raises(SequenceErrors, match=r"/arm/poses\.yaml holds none"):
        parse_sequence(b"pose home\n", "pick.seq", poses=NamedPoses(FILE))
    with pytest.raises(SequenceErrors, match="no poses were read"):
        parse_sequence(b"pose home\n", "pick.seq")


def test_a_sequence_with_poses_reads_the_same_from_either_side(tmp_path: Path) -> None:
    """What the web view saves `al5d run` reads (and the reverse): one grammar, one file."""
    book = save_poses(
        NamedPoses(tmp_path / "poses.yaml").with_pose("home", HOME).with_pose("cup", {"base": 30.0})
    )
    typed = "pose home time=800\nwait 200\nmove gripper=40 time=300\npose cup &\nready"
    saved = save_sequence(tmp_path, "pick", typed)
    assert saved == tmp_path / "pick.seq"
    by_cli = parse_sequence(saved.read_bytes(), str(saved), poses=load_poses(beside(saved)))
    assert [type(item) for item, _ in by_cli] == [Instruction, Wait, *[Instruction] * 3]
    assert saved.read_text() == typed + "\n"
    by_web = parse_text(saved.read_text(), book)
    assert [(str(i), bg) for i, bg in by_web] == [(str(i), bg) for i, bg in by_cli]
    by_hand = tmp_path / "by_hand.seq"
    by_hand.write_text("# written in an editor\npose cup time=500   # there\n\npose home\n")
    by_web = parse_text(by_hand.read_text(), book)
    by_cli = parse_sequence(by_hand.read_bytes(), str(by_hand), poses=book)
    assert [(str(i), bg) for i, bg in by_web] == [(str(i), bg) for i, bg in by_cli]
    home = "move " + " ".join(f"{j}={v:g}" for j, v in HOME.items())
    assert [str(i) for i, _ in by_cli] == ["move base=30 time=500", home]
    assert sequence_names(tmp_path) == ("by_hand", "pick")
    assert used_by(tmp_path, "cup") == ("by_hand", "pick")
    assert used_by(tmp_path, "home") == ("by_hand", "pick")
    assert used_by(tmp_path, "hom") == ()
    with pytest.raises(PosesError, match=r"'\.\./x' is not a name"):
        save_sequence(tmp_path, "../x", typed)
