"""`al5d calibrate`: the guided calibration at the terminal (`al5d.arm.calibration`).

The arm moves through the server (`al5d serve`, as `al5d send` does), so that every
nudge is a move judged whole, ranges and table included, before a byte is written. Per
joint and reference, the arm goes to the reference pose; the user nudges the pulse until
the real joint stands where the model says, and accepts. At the end the calibrations
found are written into the server's configuration file (a backup beside it, the diff
printed); the server reads it when it is started again.

At a terminal, single keys: `+`/`-` one step toward +angle/-angle, `]`/`[` ten steps,
Enter accepts, `s` skips the joint, `q` quits without writing. Otherwise (a pipe, a
script) a line each: `+`, `-`, `+N`, `-N`, `ok`, `skip`, `quit`, and `y` or `n` when
asked whether to write.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TextIO

from al5d import exits
from al5d.arm import instruction as ins
from al5d.arm.calfile import shipped_problem, write_calibration
from al5d.arm.calibration import (
    Awaiting,
    CalibrationRefused,
    Procedure,
    summary,
)
from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Outcome

if TYPE_CHECKING:
    from al5d.ros.client import Client

#: A move to a reference pose takes at least this long (the server may take longer): the
#: arm goes there at a walk, not at the servos' top speed.
REFERENCE_MOVE_MS = 1500
#: How long a nudge's report waits for where an emulated arm truly stands after the move.
WITNESS_WAIT_S = 0.5
#: How long a client on the lane of an emulated board waits for the first of its true
#: angles (the witness's DDS discovery: 0.2 s idle, more than a 300 ms move beside a full
#: test run).
WITNESS_FIND_S = 5.0
#: Keys at a terminal -> the line they stand for.
KEYS = {
    "+": "+",
    "=": "+",
    "-": "-",
    "_": "-",
    "]": "+10",
    "[": "-10",
    "\r": "ok",
    "\n": "ok",
    "s": "skip",
    "q": "quit",
    "?": "help",
    "y": "y",
    "n": "n",
}
HELP_TTY = "keys: + - one step, ] [ ten steps, Enter: it is there, s: skip the joint, q: quit"
HELP_LINES = "a line each: + - +N -N (steps), ok (it is there), skip, quit"


@dataclass(frozen=True)
class Command:
    """What the user asked: `nudge` (by `steps`), `ok`, `skip`, `quit` or `help`."""

    kind: str
    steps: int = 0


def parse_command(text: str) -> Command:
    """A line of input as a command; ValueError names what is understood."""
    word = text.strip().lower()
    if word in ("ok", "accept", "a"):
        return Command("ok")
    if word in ("skip", "s"):
        return Command("skip")
    if word in ("quit", "q", "exit"):
        return Command("quit")
    if word in ("help", "?", "h"):
        return Command("help")
    if word in ("+", "-"):
        return Command("nudge", 1 if word == "+" else -1)
    if word[:1] in ("+", "-") and word[1:].isdigit() and 0 < int(word[1:]) <= 1000:
        return Command("nudge", int(word))
    raise ValueError(f"{text.strip()[:40]!r}: {HELP_LINES}")


class Mover(Protocol):
    """What moves the arm: a pose in degrees (as the configuration reads them) and a time."""

    def move(self, pose: Mapping[str, float], time_ms: int | None) -> Outcome: ...


#: Where the arm physically stands, if something says it (an emulated arm's true angles:
#: `al5d.ros.physical`); None for a real arm, which nothing measures.
Witness = Callable[[], Mapping[str, float] | None]


def _no_witness() -> Mapping[str, float] | None:
    return None


class Keys:
    """The user's answers: single keys at a terminal, lines otherwise."""

    def __init__(self, inp: TextIO, interactive: bool) -> None:
        self.inp = inp
        self.interactive = interactive

    def read(self) -> str | None:
        """The next answer as a line's text; None at the end of the input."""
        if not self.interactive:
            line = self.inp.readline()
            return None if line == "" else line.strip()
        ch = self.inp.read(1)
        if ch == "":
            return None
        return KEYS.get(ch, ch)

    @contextlib.contextmanager
    def raw(self) -> Iterator[None]:
        """At a terminal: keys without Enter and not echoed (Ctrl-C still interrupts)."""
        if not self.interactive:
            yield
            return
        import termios
        import tty

        fd = self.inp.fileno()
        saved = termios.tcgetattr(fd)
        try:
            tty.setcbreak(fd, termios.TCSANOW)  # keys typed ahead are kept, not flushed
            yield
        finally:
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def run_procedure(
    procedure: Procedure,
    mover: Mover,
    keys: Keys,
    out: TextIO,
    reference_ms: int = REFERENCE_MOVE_MS,
    witness: Witness = _no_witness,
) -> bool:
    """Guide the user through every joint of `procedure`; False if they quit (or the input
    ended) before the end. With a `witness` that says where the arm truly stands (an
    emulated arm), each nudge says how far the joint is off the reference."""

    def say(text: str) -> None:
        print(text, file=out, flush=True)

    def go(time_ms: int | None) -> None:
        outcome = mover.move(procedure.pose(), time_ms)
        if outcome.ok:
            procedure.moved()
        else:
            procedure.not_moved()
            say(f"  not moved: {outcome}")

    say(HELP_TTY if keys.interactive else HELP_LINES)
    accept = "Enter" if keys.interactive else "ok"  # as the help just said
    begun: tuple[str, int] | None = None
    while procedure.step is Awaiting.NUDGE:
        joint, ref = procedure.joint, procedure.reference
        here = (joint.name, procedure.reference_index)
        if begun != here:
            begun = here
            n = procedure.joints.index(joint.name) + 1
            say(
                f"{joint.name} ({n} of {len(procedure.joints)}), reference "
                f"{procedure.reference_index + 1} of 2: {ref.deg:g} deg: {ref.looks}"
            )
            go(reference_ms)
        offset = procedure.pulse - joint.to_us(ref.deg)
        where = "at" if procedure.at == procedure.pulse else "not yet at"
        true = (witness() or {}).get(joint.name)
        if true is not None:
            say(
                f"  the emulated arm's {joint.name} truly stands at {true:.1f} deg: "
                f"{true - ref.deg:+.1f} deg off {ref.deg:g} deg"
            )
        say(
            f"  {joint.name} {where} {procedure.pulse} us ({offset:+.0f} us from the config's "
            f"{ref.deg:g} deg); nudge until it is there, then {accept}"
        )
        answer = keys.read()
        if answer is None:
            return False
        try:
            command = parse_command(answer)
        except ValueError as e:
            say(f"  {answer[:1]!r}: {HELP_TTY}" if keys.interactive else f"  {e}")
            continue
        if command.kind == "quit":
            return False
        if command.kind == "help":
            say(HELP_TTY if keys.interactive else HELP_LINES)
        elif command.kind == "skip":
            say(f"  {joint.name}: skipped, left as it is in the file")
            procedure.skip()
        elif command.kind == "nudge":
            try:
                procedure.nudge(command.steps)
            except CalibrationRefused as e:
                say(f"  not moved: {e}")
                continue
            go(None)
        else:
            try:
                result = procedure.accept()
            except CalibrationRefused as e:
                say(f"  refused: {e}")
                continue
            if result is not None:
                say(f"  {result.describe()}")
    return True


def calibrate(
    procedure: Procedure,
    mover: Mover,
    path: Path,
    *,
    inp: TextIO = sys.stdin,
    out: TextIO = sys.stdout,
    yes: bool = False,
    reference_ms: int = REFERENCE_MOVE_MS,
    witness: Witness = _no_witness,
) -> int:
    """The whole procedure, then the file written (if the user agrees): the exit code."""

    def say(text: str) -> None:
        print(text, file=out, flush=True)

    keys = Keys(inp, inp.isatty())
    try:
        with keys.raw():
            if not run_procedure(procedure, mover, keys, out, reference_ms, witness):
                say("calibration ended early: nothing written; the arm stays where it is")
                return exits.NOT_DONE
            for line in summary(procedure):
                say(line)
            if not procedure.results:
                say("nothing to write")
                return exits.DONE if not procedure.refused else exits.NOT_DONE
            names = ", ".join(r.name for r in procedure.results)
            if not yes:
                say(f"write the calibration of {names} into {path}? (y/n)")
                answer = keys.read()
                if answer is None or answer.strip().lower() not in ("y", "yes"):
                    say("nothing written")
                    return exits.NOT_DONE
    except KeyboardInterrupt:
        say("\ncalibration ended (Ctrl-C): nothing written; the arm stays where it is")
        return exits.NOT_DONE
    try:
        written = write_calibration(path, procedure.results)
    except (CalibrationRefused, OSError) as e:
        say(f"not written: {e}")
        return exits.NOT_DONE
    say(f"written: {written.path} (the file as it was: {written.backup})")
    out.write(written.diff)
    say(f"restart al5d serve (--config {written.path}) to drive the arm with it")
    return exits.DONE if not procedure.refused else exits.NOT_DONE


class ServerMover:
    """Moves through the server (`al5d.ros.client.Client`): each judged whole there."""

    def __init__(self, client: Client, timeout: float) -> None:
        self.client = client
        self.timeout = timeout

    def move(self, pose: Mapping[str, float], time_ms: int | None) -> Outcome:
        move = ins.Instruction(ins.Kind.MOVE, joints=tuple(pose.items()), time_ms=time_ms)
        return self.client.execute(move, self.timeout)


def server_config(served: Path | None, given: str | None) -> tuple[Path | None, str]:
    """The file to write: the one the server was started with (`served`, None: it did not
    say). `given` (`--config`) must be it; without it, the server's. (None and why, when
    the file is not known to be the server's.)"""
    if served is None:
        return None, (
            "the server did not say which config_file it runs with (it did not answer in "
            "time): nothing is written unless the pulses are known to be that file's; "
            "try again"
        )
    if problem := shipped_problem(served):
        return None, problem
    if given is not None and Path(given).resolve() != served.resolve():
        return None, (
            f"the server runs with {served}, not {given}: the pulses are that file's; "
            f"calibrate with --config {served} (or start the server with --config {given})"
        )
    return served, ""


def stale_calibration(file: ArmConfig, served: ArmConfig, joints: tuple[str, ...]) -> str:
    """Why the file's calibration of `joints` is not the one the server drives them with
    (the file written since the server started), or "". The procedure reads the file's
    pulses while the server turns its degrees into pulses by its own: an outside try's
    second run before the restart wrote a calibration 40 us off, with exit 0."""
    differ = [
        j
        for j in joints
        if j in served.joints and file.joints[j].calibration != served.joints[j].calibration
    ]
    if not differ:
        return ""
    return (
        f"the calibration of {', '.join(differ)} differs from the one the server drives the "
        "arm with (the file changed since the server started: a calibration written and the "
        "server not restarted?): restart the server with this file, then calibrate again; "
        "nothing written"
    )


def calibrate_command(
    *,
    config_path: str | None,
    joints: tuple[str, ...],
    step_us: int,
    namespace: str | None,
    wait_s: float,
    timeout: float,
    yes: bool,
    reference_ms: int,
    inp: TextIO = sys.stdin,
    out: TextIO = sys.stdout,
    err: TextIO = sys.stderr,
) -> int:
    """`al5d calibrate`: find the server, check its file, run the procedure, write."""
    from al5d.arm.config import load_config
    from al5d.ros.client import ANSWER_S, Client, NoOutcome, NoServer
    from al5d.ros.params import served_config_file
    from al5d.ros.physical import OwnPhysicalReader, PhysicalReader

    client = Client(namespace, wait_s=wait_s)
    own: OwnPhysicalReader | None = None
    try:
        client.wait_for_server(wait_s)
        served: Path | None
        if client.lane is not None:
            served = client.lane.config_file
        else:
            served = served_config_file(client.node, client.names, ANSWER_S)
        path, problem = server_config(served, config_path)
        if path is None:
            print(f"al5d calibrate: {problem}", file=err)
            return exits.USAGE
        config: ArmConfig = load_config(path)
        try:
            procedure = Procedure(config, joints or tuple(config.joints), step_us)
        except CalibrationRefused as e:
            print(f"al5d calibrate: {e}", file=err)
            return exits.USAGE
        # Over the lane, whose welcome holds the server's configuration for sure (over ROS 2
        # a server that does not say it is judged by the shipped file: no check there).
        lane = client.lane
        if lane is not None and (stale := stale_calibration(config, lane.config, procedure.joints)):
            print(f"al5d calibrate: {path}: {stale}", file=err)
            return exits.USAGE
        print(f"al5d calibrate: {path}, joints {', '.join(procedure.joints)}", file=out)
        # Where an emulated arm truly stands is on ROS 2 only (`al5d emulator --misalign`).
        physical: PhysicalReader
        prefix = config.server.joint_prefix_in(client.names.namespace)
        if client.lane is not None:
            physical = own = OwnPhysicalReader(client.names, config.model, prefix=prefix)
            if os.path.realpath(client.lane.port).startswith("/dev/pts/"):
                # An emulated board (a pseudo-terminal): its true angles come over ROS 2, to
                # a reader whose discovery, on a loaded host, outlasts the first move.
                physical.next(WITNESS_FIND_S)
        else:
            physical = PhysicalReader(client.node, client.names, config.model, prefix=prefix)

        def witness() -> Mapping[str, float] | None:
            # A sample taken after the move's outcome, where an emulated arm says any.
            if physical.degrees() is None:
                return None
            return physical.next(WITNESS_WAIT_S) or physical.degrees()

        return calibrate(
            procedure,
            ServerMover(client, timeout),
            path,
            inp=inp,
            out=out,
            yes=yes,
            reference_ms=reference_ms,
            witness=witness,
        )
    except NoServer as e:
        print(f"al5d calibrate: {e}", file=err)
        return exits.NO_SERVER
    except NoOutcome as e:
        print(f"al5d calibrate: {e}; nothing written", file=err)
        return exits.NOT_DONE
    finally:
        if own is not None:
            own.close()
        client.close()
