"""The client commands at the terminal: `al5d send`, `al5d run` and `al5d shell`, on
`al5d.ros.client.Client` (a local server by its lane, any other over ROS 2), and how they
report.

`al5d send` sends one instruction and waits for its outcome (over ROS 2 a stop goes
on the topic, copies of one stop until one is answered: `Client.stop`; a release goes
on the topic too, with the client's lease: `Client.release`). `al5d run` runs a
sequence file: each instruction waits for its outcome before the next line, unless
the line ends with `&` (then the client goes on at once, so that, say, a `stop` can
land in the middle of a move); `wait <ms>` pauses. `al5d shell` reads instructions a
line at a time and keeps its one connection: the server's discovery is paid once, not
per command.
Ctrl-C on `al5d send` or `al5d run` cancels what the command sent and is still running or
waiting, and says so (over ROS 2, which has no cancel by id, it says that the server was
not told). Exit codes: `al5d.exits` (done, not done, bad input, no server, interrupted).
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import TextIO

from al5d import exits
from al5d.app.report import LinkWatch, Report, Timing, each_line
from al5d.app.shellhelp import shell_help
from al5d.arm.config import load_config
from al5d.arm.instruction import (
    PRESET_NAMES,
    SHELL_HELP,
    SHELL_QUIT,
    GrammarError,
    Instruction,
    Kind,
    Outcome,
    Result,
    SequenceStep,
    Wait,
    parse_instruction,
)
from al5d.arm.poses import PosesError, beside, load_poses
from al5d.arm.sequence import SequenceJudge, judge_sequence, judged_steps, read_sequence
from al5d.owner import where
from al5d.owner.client import local_config
from al5d.ros.answers import GIVE_UP_WORD_S
from al5d.ros.client import (
    Answer,
    Client,
    LaneLost,
    LostContact,
    NoOutcome,
    NoServer,
)
from al5d.ros.names import Names

#: `--via`: the local lane where a server's is here (auto), only the lane, or only ROS 2.
VIA = {"auto": None, "lane": True, "ros": False}


def interrupted(
    client: Client, report: Report, sent: list[Instruction], watched: Collection[str] = ()
) -> int:
    """Ctrl-C: what the command sent and is not over is cancelled, and said: by its outcome's
    line where its outcome is printed as it comes (`watched`: the lines run in the
    background), else by a line of its own. Inside `interrupts.cancelling` a second Ctrl-C
    meanwhile is let be; a third leaves, and says what may still run."""
    pending = set(client.pending()) if client.lane is not None else {i.id for i in sent}
    try:
        for instr in sent:
            if instr.id not in pending:
                continue
            if client.lane is None:
                report.line(
                    f"{instr.name} [{instr.id}]: Ctrl-C: not cancelled: ROS 2 has no cancel by "
                    "id (it may still run; `al5d send stop` halts the arm)"
                )
            # The owner tells the outcome before it answers the cancel: a watched line's
            # outcome has come, and its watcher said it.
            elif client.cancel(instr.id, "cancelled by Ctrl-C") and (
                instr.id not in watched or client.outcome(instr.id, 0) is None
            ):
                report.line(f"{instr.name} [{instr.id}]: cancelled (Ctrl-C)")
    except KeyboardInterrupt:
        report.line(
            "Ctrl-C again: left before every cancel was answered: what was sent may still "
            "run (`al5d send stop` halts the arm)"
        )
    return exits.INTERRUPTED


def _stop_or_release(client: Client, instr: Instruction, timeout: float) -> Answer:
    """A stop or a release, as `Client.stop` and `Client.release` send them."""
    call = client.stop if instr.kind is Kind.STOP else client.release
    return call(timeout)


def send(
    text: str,
    *,
    wait_s: float,
    timeout: float,
    out: TextIO = sys.stdout,
    err: TextIO = sys.stderr,
    namespace: str | None = None,
    verbose: bool = False,
    via: str = "auto",
) -> int:
    """Send one instruction and print its outcome; a stop or a release as `Client.stop`
    and `Client.release` send them, printed with what carried it."""
    try:
        instr = parse_instruction(text, PRESET_NAMES)
    except GrammarError as e:
        print(f"al5d send: {e}", file=err)
        return exits.BAD_INPUT
    timing = Timing("al5d send", verbose, err)
    try:
        client = Client(namespace, wait_s=wait_s, local=VIA[via])
    except NoServer as e:
        print(f"al5d send: {e}", file=err)
        return exits.NO_SERVER
    timing.ros_started()
    report = Report(out, timeout)
    sent: list[Instruction] = []
    try:
        if instr.kind in (Kind.STOP, Kind.RELEASE):
            answer = _stop_or_release(client, instr, timeout)
            timing.discovered(client)
            report.line(str(answer))
            return exits.DONE if answer.success else exits.NOT_DONE
        client.wait_for_server(wait_s)
        timing.discovered(client)
        sent.append(instr)  # from here it may have gone: Ctrl-C cancels it
        try:
            outcome: Outcome | None = client.execute(instr, timeout)
        except (LostContact, LaneLost) as e:  # said as it is, not as a timeout
            report.line(str(e))
            return exits.NOT_DONE
        except NoOutcome:
            outcome = None
        report.outcome(outcome, instr=instr)
        return exits.DONE if report.all_done else exits.NOT_DONE
    except NoOutcome as e:
        report.line(str(e))
        return exits.NOT_DONE
    except NoServer as e:
        print(f"al5d send: {e}", file=err)
        return exits.NO_SERVER
    except KeyboardInterrupt:
        if not sent and instr.kind not in (Kind.STOP, Kind.RELEASE):
            # Before a server was found: nothing can run (an outside try was told it may).
            report.line(f"{instr.name} [{instr.id}]: Ctrl-C before it was sent: nothing sent")
            return exits.INTERRUPTED
        return interrupted(client, report, sent or [instr])
    finally:
        client.close()
        timing.end()


def run(
    path: str | Path,
    *,
    wait_s: float,
    timeout: float,
    out: TextIO = sys.stdout,
    err: TextIO = sys.stderr,
    namespace: str | None = None,
    verbose: bool = False,
    poses: str | Path | None = None,
    via: str = "auto",
) -> int:
    """Run a sequence file; 0 if every instruction was done, 1 if any was not.

    The file is judged whole against the server's configuration (`Client.config`) before
    its first line is sent, and every bad line is said (a file with a line of bad grammar
    at once, before the server is found, judged against the shipped configuration). Each
    outcome is printed when it comes: a line run in the background (`&`) reports as soon as
    its outcome arrives, not after the next line's. Its `pose <name>` lines name poses of
    the file `poses` (by default `poses.yaml` beside the sequence, if there).
    """
    try:
        book = load_poses(beside(path) if poses is None else poses, required=poses is not None)
        data = read_sequence(path)
        # A line of bad grammar is bad for every server: said at once, before one is found
        # its own way, with every other problem as the server on this machine's lane
        # judges it (instantly), or a server with the shipped configuration.
        here = local_config(where.path(Names.of(namespace).namespace))
        first = judge_sequence(data, here or load_config(), str(path), book)
        if any(problem.grammar for problem in first.problems):
            raise first.error()
    except OSError as e:
        print(f"al5d run: cannot read {path}: {e.strerror}", file=err)
        return exits.BAD_INPUT
    except (PosesError, GrammarError) as e:  # each problem a line
        print(each_line("al5d run: ", f"nothing sent: {e}"), file=err)
        return exits.BAD_INPUT
    timing = Timing("al5d run", verbose, err)
    try:
        client = Client(namespace, wait_s=wait_s, local=VIA[via])
    except NoServer as e:
        print(f"al5d run: {e}", file=err)
        return exits.NO_SERVER
    timing.ros_started()
    report = Report(out, timeout)
    sent: list[Instruction] = []
    background: list[Instruction] = []
    watch = LinkWatch(client, report, background)
    try:
        client.wait_for_server(wait_s)
        timing.discovered(client)
        try:
            steps = judged_steps(data, str(path), book, client.config())
        except GrammarError as e:
            print(each_line("al5d run: ", f"nothing sent: {e}"), file=err)
            return exits.BAD_INPUT
        for n, (item, in_background) in enumerate(steps):
            if isinstance(item, Instruction):
                sent.append(item)
            if not _step(client, report, item, in_background, timeout, background, watch):
                # As the web view's Teach tab: a line waited for and not done (refused, or
                # cancelled: by a stop, say) ends the sequence, so that a release after a
                # stop does not take up the rest of it.
                if left := len(steps) - n - 1:
                    report.line(f"not done: the {left} step{'s'[: left != 1]} after it not sent")
                break
        _drain(client, report, background, timeout)
        return exits.DONE if report.all_done else exits.NOT_DONE
    except NoServer as e:
        print(f"al5d run: {e}", file=err)
        return exits.NO_SERVER
    except NoOutcome as e:
        report.line(str(e))
        return exits.NOT_DONE
    except KeyboardInterrupt:
        return interrupted(client, report, sent, {i.id for i in background})
    finally:
        watch.close()
        client.close()
        timing.end()


def _step(
    client: Client,
    report: Report,
    item: Instruction | Wait,
    in_background: bool,
    timeout: float,
    background: list[Instruction],
    watch: LinkWatch,
    *,
    echo: bool = True,
) -> bool:
    """One step of a sequence, on the instruction topic: its outcome waited for and printed,
    or (in the background) printed when it comes; `echo`: the step is printed first. False
    when its outcome, waited for, was not done (or did not come), or contact was lost
    during a `wait`; a release refused (the arm was not stopped) is not that."""
    if isinstance(item, Wait):
        if echo:
            report.line(f"wait {item.ms} ms")
        watch.sleep(item.ms / 1000)
        return not watch.lost.is_set()
    if echo:
        report.line(f"> {item}{' &' if in_background else ''}")
    if in_background:
        background.append(item)
        client.watch(item.id, functools.partial(report.outcome, instr=item))
    client.send(item, timeout)
    if in_background:
        return True
    outcome = client.outcome(item.id, timeout + GIVE_UP_WORD_S)
    report.outcome(outcome, instr=item)
    if outcome is not None and item.kind is Kind.RELEASE:
        return True  # refused where nothing is stopped: nothing to release, nothing lost
    return outcome is not None and outcome.result is Result.DONE


def _drain(client: Client, report: Report, background: list[Instruction], timeout: float) -> None:
    """Wait for the outcomes of the lines run in the background (each printed as it came)."""
    for item in background:
        if item.id in report.said:
            continue
        if not client.sent(item.id):
            report.not_sent(item)
            continue
        try:
            outcome = client.outcome(item.id, timeout + GIVE_UP_WORD_S)
        except NoOutcome as e:  # contact lost: said for each line, once
            report.lost(item, e)
            continue
        if outcome is None:
            report.outcome(None, instr=item)
    background.clear()


SHELL_PROMPT = "al5d> "


#: What `_lines` yields for a Ctrl-C while the input was read (at the prompt).
CTRL_C = "\x03"


def _lines(inp: TextIO, interactive: bool, report: Report | None) -> Iterator[str]:
    """The shell's input, a line at a time; at a terminal with a prompt and line editing,
    and Ctrl-C there drops the line typed, as a shell does. A Ctrl-C is `CTRL_C` (piped, the
    input's end then). What `report` (its output a terminal) says while the prompt waits
    goes above it."""
    if not interactive:
        try:
            yield from inp
        except KeyboardInterrupt:
            yield CTRL_C
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
            try:
                line = input(SHELL_PROMPT)
            except KeyboardInterrupt:
                line = CTRL_C
            except EOFError:
                line = None
            finally:
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
) -> int:
    """Read instructions a line at a time (the grammar of a sequence file: `wait`, `&`, `#`,
    `pose <name>` of the file `poses`, by default `poses.yaml` here if there) and run each
    over one connection kept throughout: the server is discovered once.

    A stop or a release goes as with `al5d send`. A bad line is
    said and skipped. Ctrl-C while an instruction runs (in the background too, `&`) is the
    emergency stop. The exit
    code at the end: no server; else bad input if a line was bad; else whether every
    instruction was done.
    """
    try:
        book = load_poses(beside(None) if poses is None else poses, required=poses is not None)
    except PosesError as e:
        print(each_line("al5d shell: ", str(e)), file=err)
        return exits.BAD_INPUT
    interactive = inp.isatty()
    # A prompt drawn again below what is said only where both ends are a terminal.
    redraw = interactive and out.isatty()
    timing = Timing("al5d shell", verbose, err)
    try:
        client = Client(namespace, wait_s=wait_s, local=VIA[via])
    except NoServer as e:
        print(f"al5d shell: {e}", file=err)
        return exits.NO_SERVER
    timing.ros_started()
    report = Report(out, timeout)
    bad = False
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
        lines = _lines(inp, interactive, report if redraw else None)
        while True:
            with watch.waiting():  # a server lost while the shell waits for a line is said
                line = next(lines, None)
            if line is None:
                break
            if line == CTRL_C:
                # Ctrl-C while a move of the shell's runs in the background stops the arm,
                # as it does while one runs in the foreground (seen: the move ran on).
                if any(client.sent(i.id) and client.outcome(i.id, 0) is None for i in background):
                    report.line(f"Ctrl-C: {_stop(client)}")
                    report.all_done = False
                continue
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
                _shell_step(client, report, step, timeout, background, watch, interactive)
            except KeyboardInterrupt:
                report.line(f"Ctrl-C: {_stop(client)}")
                report.all_done = False
                item, in_background = step
                if isinstance(item, Instruction) and not in_background:
                    if client.sent(item.id):
                        report.outcome(client.outcome(item.id, timeout), instr=item)
                    else:
                        report.not_sent(item)
            except (NoOutcome, NoServer) as e:  # a server gone: said, and the shell goes on
                report.line(str(e))
                report.all_done = False
                if isinstance(e, (LostContact, LaneLost)):
                    watch.said_lost()  # contact back is said
        _drain(client, report, background, timeout)
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
    timeout: float,
    background: list[Instruction],
    watch: LinkWatch,
    interactive: bool,
) -> None:
    item, in_background = step
    if isinstance(item, Instruction) and item.kind in (Kind.STOP, Kind.RELEASE):
        if not interactive:
            report.line(f"> {item}")
        answer = _stop_or_release(client, item, timeout)
        report.all_done &= answer.success
        report.line(str(answer))
        return
    # At a terminal the line typed is on the screen already: it is not echoed.
    _step(client, report, item, in_background, timeout, background, watch, echo=not interactive)


def _stop(client: Client) -> str:
    """The shell's stop on Ctrl-C, said as answered, or why it was not (a server gone: the
    shell goes on, where the error ended it)."""
    try:
        return str(client.stop())
    except (NoOutcome, NoServer) as e:
        return str(e)
