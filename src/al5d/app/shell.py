"""`al5d shell`: instructions read a line at a time, at a terminal's prompt or piped, over
one connection kept throughout (the server is discovered once); its `help`, and its Ctrl-C.

A line is a sequence file's (`wait`, `&`, `#`, `pose <name>`), run as `al5d run` runs
one (`al5d.app.terminal`). Ctrl-C, wherever it comes in the shell's loop, stops the arm
where a line of the shell's runs (in the background too) and says so; at a terminal the
prompt comes back, piped the input ends, as `al5d run` does; a second Ctrl-C while the
first one's answers are awaited ends the shell.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import sys
import time
from collections.abc import Generator, Iterable
from pathlib import Path
from typing import TextIO

from al5d import exits
from al5d.app.report import LinkWatch, Report, each_line
from al5d.app.terminal import connect, drain, run_step, stop_or_release
from al5d.app.typed import TypedAhead
from al5d.arm.instruction import (
    SHELL_HELP,
    SHELL_QUIT,
    GrammarError,
    Instruction,
    Kind,
    SequenceStep,
)
from al5d.arm.poses import PosesError, beside, load_poses
from al5d.arm.sequence import SequenceJudge
from al5d.ros.answers import ANSWER_S
from al5d.ros.client import Client, LaneLost, LostContact, NoOutcome, NoServer

SHELL_PROMPT = "al5d> "


#: What `_lines` yields for a Ctrl-C at a terminal's prompt.
CTRL_C = "\x03"


def _lines(
    inp: TextIO, interactive: bool, report: Report | None, typed: TypedAhead | None = None
) -> Generator[str, None, None]:
    """The shell's input, a line at a time; at a terminal with a prompt and line editing,
    and Ctrl-C there drops the line typed, as a shell does: it is `CTRL_C`, after a new
    line. What `report` (its output a terminal) says while the prompt waits goes above it;
    what was `typed` ahead comes first, drawn after a prompt as if typed at it.
    Piped, a Ctrl-C is raised through this, as anywhere else in the shell."""
    if not interactive:
        yield from inp
        return
    import readline  # input() gets editing and history

    def drawn() -> None:  # the prompt is on the screen: what is said goes above it now
        if report is not None:
            report.at_prompt(lambda: SHELL_PROMPT + readline.get_line_buffer())

    # GNU readline's; a readline without it (libedit) draws no prompt again.
    hook = getattr(readline, "set_pre_input_hook", lambda *hook: None)
    hook(drawn)
    try:
        while True:
            if typed is not None and typed.lines:
                ahead = typed.lines.pop(0)
                typed.say(f"{SHELL_PROMPT}{ahead}")
                readline.add_history(ahead)
                yield ahead
                continue
            if typed is not None and typed.ended:
                return
            if typed is not None and typed.unfinished:  # after the prompt, to be ended there
                unfinished, typed.unfinished = typed.unfinished, ""
                readline.set_startup_hook(functools.partial(readline.insert_text, unfinished))
            line: str | None
            try:
                line = input(SHELL_PROMPT)
            except KeyboardInterrupt:
                line = CTRL_C
            except EOFError:
                line = None
            finally:
                readline.set_startup_hook(None)
                if report is not None:
                    report.at_prompt(None)
            if line is None or line == CTRL_C:
                print(file=sys.stdout)
            if line is None:
                return
            yield line
    finally:
        hook()


def shell(
    *,
    wait_s: float,
    timeout: float,
    inp: TextIO = sys.stdin,
    out: TextIO = sys.stdout,
    err: TextIO = sys.stderr,
    namespace: str | None = None,
    verbose: bool = False,
    poses: str | Path | None = None,
    via: str = "auto",
    answer_s: float = ANSWER_S,
) -> int:
    """Read instructions a line at a time (the grammar of a sequence file: `wait`, `&`, `#`,
    `pose <name>` of the file `poses`, by default `poses.yaml` here if there) and run each
    over one connection kept throughout: the server is discovered once.

    A stop or a release goes as with `al5d send` (its answer waited for `answer_s` s, each
    outcome `timeout` s). A bad line is said and skipped. Ctrl-C
    while an instruction runs (in the background too, `&`) is the emergency stop; piped, it
    ends the input too. The exit code at the end: no server; else bad input if a line was
    bad; else whether every instruction was done.
    """
    try:
        book = load_poses(beside(None) if poses is None else poses, required=poses is not None)
    except PosesError as e:
        print(each_line("al5d shell: ", str(e)), file=err)
        return exits.BAD_INPUT
    interactive = inp.isatty()
    # A prompt drawn again below what is said only where both ends are a terminal.
    redraw = interactive and out.isatty()
    started = connect("al5d shell", namespace, wait_s, via, verbose, err)
    if started is None:
        return exits.NO_SERVER
    client, timing = started
    report = Report(out, timeout)
    bad = False
    interrupted = False  # by a Ctrl-C that ended the shell
    background: list[Instruction] = []
    watch = LinkWatch(client, report, background)
    above = _AbovePrompt(report)
    if redraw:  # the client's warnings (a silent server) above the prompt, not in it
        logging.getLogger().addHandler(above)
    try:
        client.wait_for_server(wait_s)
        timing.discovered(client)
        judge = SequenceJudge(client.config())
        if interactive:
            report.line(
                "al5d shell: one instruction a line (as in a sequence file); Ctrl-C while "
                "one runs stops the arm; help lists them; exit or Ctrl-D ends"
            )
        typed = TypedAhead(inp.fileno(), report.line) if interactive else None
        lines = _lines(inp, interactive, report if redraw else None, typed)
        while True:
            step: SequenceStep | None = None  # the line running: a Ctrl-C's is said
            try:
                with watch.waiting():  # a server lost while the shell waits for a line is said
                    line = next(lines, None)
                if line is None:
                    break
                if line == CTRL_C:  # at the prompt: decided below, as everywhere else
                    raise KeyboardInterrupt
                word = line.strip().lower()
                if word in SHELL_QUIT:
                    break
                if word in SHELL_HELP:
                    if not interactive:  # piped, what answers which line is marked
                        report.line(f"> {line.strip()}")
                    config = judge.config
                    for said in shell_help(config.presets, config.joints):
                        report.line(said)
                    continue
                try:
                    step = judge.judge_line(line, book)
                except GrammarError as e:
                    print(f"al5d shell: {e}", file=err, flush=True)
                    bad = True
                    continue
                if step is None:
                    continue
                watch.lost.clear()  # the shell goes on after a loss: a later `wait` waits
                try:
                    with (
                        typed.watching(functools.partial(_typed_stop, client, report, answer_s))
                        if typed is not None
                        else contextlib.nullcontext()
                    ):
                        done = _shell_step(
                            client,
                            report,
                            step,
                            (timeout, answer_s),
                            background,
                            watch,
                            interactive,
                        )
                    if not done and not interactive and isinstance(step[0], Instruction):
                        # As `al5d run`: a line not done (refused, or cancelled: by a stop
                        # from anywhere) ends a script, so that a release after a stop does
                        # not take up the rest of it. (A server lost in a `wait` is said,
                        # and the shell goes on, as after a line that lost it.)
                        report.line("not done: the shell's input ends here: no line after it runs")
                        break
                except (NoOutcome, NoServer) as e:  # a server gone: said, the shell goes on
                    report.line(str(e))
                    report.fail()
                    if isinstance(e, (LostContact, LaneLost)):
                        watch.said_lost()  # contact back is said
                continue
            except KeyboardInterrupt:
                pass
            # Ctrl-C, wherever it found the shell (at the prompt, in a line, between lines):
            # one place decides, so that what it does is not a matter of when it came.
            whole = _ctrl_c(client, report, step, background, timeout)
            if not whole:
                return exits.INTERRUPTED  # a second Ctrl-C: the user leaves, now
            if not interactive:  # piped, it ends the input too, as it ends `al5d run`
                interrupted = True
                break
            lines.close()  # a Ctrl-C may have ended it: a new one, its prompt drawn again
            if typed is not None:
                typed.drop()
            lines = _lines(inp, interactive, report if redraw else None, typed)
        try:
            drain(client, report, background, timeout)
        except KeyboardInterrupt:  # the outcomes waited for at the input's end
            if not _ctrl_c(client, report, None, background, timeout):
                return exits.INTERRUPTED
            interrupted = True
            drain(client, report, background, timeout)
        if interrupted:  # said last, below the outcomes of the lines it cut
            report.line("Ctrl-C: the shell's input ends here: no line after it runs")
            return exits.INTERRUPTED
        if bad:
            return exits.BAD_INPUT
        return exits.DONE if report.all_done else exits.NOT_DONE
    except NoServer as e:
        print(f"al5d shell: {e}", file=err)
        return exits.NO_SERVER
    finally:
        logging.getLogger().removeHandler(above)
        watch.close()
        client.close()
        timing.end()


class _AbovePrompt(logging.Handler):
    """The log's warnings (Python's last resort's, the message alone) said by `report`: at
    a terminal, above the shell's prompt and what is typed after it."""

    def __init__(self, report: Report) -> None:
        super().__init__(logging.WARNING)
        self.report = report

    def emit(self, record: logging.LogRecord) -> None:
        self.report.line(record.getMessage())


def _shell_step(
    client: Client,
    report: Report,
    step: SequenceStep,
    waits: tuple[float, float],
    background: list[Instruction],
    watch: LinkWatch,
    interactive: bool,
) -> bool:
    """One line: `waits`, how long its outcome and a stop's or release's answer are waited
    for. False where a line waited for was not done (`run_step`)."""
    item, in_background = step
    timeout, answer_s = waits
    if isinstance(item, Instruction) and item.kind in (Kind.STOP, Kind.RELEASE):
        if not interactive:
            report.line(f"> {item}")
        answer = stop_or_release(client, item, answer_s)
        if not answer.success:
            report.fail()
        report.line(str(answer))
        return True
    # At a terminal the line typed is on the screen already: it is not echoed.
    return run_step(
        client, report, item, in_background, timeout, background, watch, echo=not interactive
    )


def _typed_stop(client: Client, report: Report, answer_s: float) -> None:
    """A stop typed while a line runs (`TypedAhead`): sent at once, its answer said."""
    try:
        answer = stop_or_release(client, Instruction(Kind.STOP), answer_s)
    except (NoOutcome, NoServer) as e:
        report.line(str(e))
        report.fail()
        return
    if not answer.success:
        report.fail()  # under the report's lock: the reader's thread is not the shell's
    report.line(str(answer))


def _stop(client: Client) -> tuple[str, bool]:
    """The shell's stop on Ctrl-C, said as answered, or why it was not (a server gone: said,
    where the error ended the shell); and whether it was answered."""
    try:
        return str(client.stop()), True
    except (NoOutcome, NoServer) as e:
        return str(e), False


#: After a stop answered, how long the shell waits for the outcomes of the lines it cut,
#: said before the prompt comes back (at once, as a rule: the owner tells them first).
CUT_SAID_S = 5.0


def _ctrl_c(
    client: Client,
    report: Report,
    step: SequenceStep | None,
    background: list[Instruction],
    timeout: float,
) -> bool:
    """Ctrl-C in the shell, `step` the line it came in (None: at the prompt, between lines,
    at the end): where a line of the shell's runs (that one, or one in the background) the
    arm is stopped, and said; the outcomes of the lines it cut are said (or that the line
    was not sent, or, the stop unanswered, that it is not waited for). Nothing running,
    nothing is stopped. False where a second Ctrl-C cut this short (said): the shell ends."""
    item = None if step is None or step[1] else step[0]
    if not isinstance(item, Instruction):
        item = None  # a `wait`: nothing of its own runs
    # A stop or a release line is not kept by id: a Ctrl-C in one stops (again), to be sure.
    stop_line = item is not None and item.kind in (Kind.STOP, Kind.RELEASE)
    try:
        cut = [i for i in (item, *background) if i is not None and _running(client, i)]
        if stop_line or cut:
            said, obeyed = _stop(client)
            report.line(f"Ctrl-C: {said}")
            report.fail()
            if not obeyed:  # a server that does not answer would keep the shell for `timeout`
                for instr in cut:
                    report.lost(instr, NoOutcome(_NOT_WAITED.format(instr.id)))
                return True
        if item is not None and not stop_line and item not in cut:
            if client.sent(item.id):  # its outcome came as the Ctrl-C did: said (once)
                report.outcome(client.outcome(item.id, 0), instr=item)
            else:
                report.not_sent(item)
        deadline = time.monotonic() + CUT_SAID_S
        for instr in cut:  # said here, before the prompt is drawn again (not in its middle)
            if instr is item:  # the line waited for: as long as it would have been
                report.outcome(client.outcome(instr.id, timeout), instr=instr)
            elif outcome := client.outcome(instr.id, max(0.0, deadline - time.monotonic())):
                report.outcome(outcome, instr=instr)  # else its watcher says it, later
    except NoOutcome as e:  # the server gone meanwhile: said, as a line's loss is
        report.line(str(e))
    except KeyboardInterrupt:
        report.line(
            "Ctrl-C again: the shell ends before every answer came (`al5d send stop` halts the arm)"
        )
        return False
    return True


_NOT_WAITED = (
    "[{}]: not waited for: the stop was not answered, whether it runs on is unknown "
    "(`al5d send stop` halts the arm)"
)


def _running(client: Client, instr: Instruction) -> bool:
    """Whether `instr`, sent, may still run: its outcome has not come (or contact with its
    server was lost: it may run on there)."""
    try:
        return client.sent(instr.id) and client.outcome(instr.id, 0) is None
    except NoOutcome:
        return True


def shell_help(presets: Iterable[str], joints: Iterable[str]) -> list[str]:
    """What `help` says at `al5d shell`'s prompt: its grammar (docs/server.md, Instructions),
    with the server's presets and joints."""
    return [
        f"{' | '.join(presets)}  [time=<ms>]",
        "move <joint>=<degrees> [...]  [time=<ms>]",
        "move_to x=<mm> y=<mm> z=<mm> [pitch=<deg>] [roll=<deg>] [gripper=<deg>] [time=<ms>] "
        "[path=joint|line]",
        "stop | release | shutdown",
        "pose <name>  [time=<ms>]  (a pose of the poses file)",
        "wait <ms>  (the shell pauses)",
        "<instruction> &  (runs in the background)    # a comment",
        "exit | quit | Ctrl-D ends the shell; Ctrl-C while a move runs stops the arm",
        f"joints: {' '.join(joints)}",
    ]
