"""The client commands at the terminal: `al5d send` and `al5d run` (and the steps that
`al5d shell`, `al5d.app.shell`, runs as they do), on `al5d.ros.client.Client` (a local
server by its lane, any other over ROS 2).

`al5d send` sends one instruction and waits for its outcome (over ROS 2 a stop goes
on the topic, copies of one stop until one is answered: `Client.stop`; a release goes
on the topic too, with the client's lease: `Client.release`). `al5d run` runs a
sequence file: each instruction waits for its outcome before the next line, unless
the line ends with `&` (then the client goes on at once, so that, say, a `stop` can
land in the middle of a move); `wait <ms>` pauses.
Ctrl-C on `al5d send` or `al5d run` cancels what the command sent and is still running or
waiting, and says so (over ROS 2, which has no cancel by id, it says that the server was
not told). Exit codes: `al5d.exits` (done, not done, bad input, no server, interrupted).
"""

from __future__ import annotations

import functools
import sys
import threading
from collections.abc import Collection
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import TextIO

from al5d import exits
from al5d.app.report import LinkWatch, Report, Timing, each_line
from al5d.arm.config import load_config
from al5d.arm.instruction import (
    PRESET_NAMES,
    GrammarError,
    Instruction,
    Kind,
    Outcome,
    Result,
    Wait,
    parse_instruction,
)
from al5d.arm.poses import PosesError, beside, load_poses
from al5d.arm.sequence import judge_sequence, judged_steps, read_sequence
from al5d.owner import quick, where
from al5d.owner.client import LaneStalled, local_config
from al5d.ros.answers import ANSWER_S, GIVE_UP_WORD_S
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


def connect(
    prog: str, namespace: str | None, wait_s: float, via: str, verbose: bool, err: TextIO
) -> tuple[Client, Timing] | None:
    """The client of the command `prog` (`via`: a key of `VIA`), and its timing, started;
    None where there is no server to reach (`--via lane` with none here), said on `err`."""
    timing = Timing(prog, verbose, err)
    try:
        client = Client(namespace, wait_s=wait_s, local=VIA[via])
    except NoServer as e:
        print(f"{prog}: {e}", file=err)
        return None
    timing.ros_started()
    return client, timing


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
            elif _cancel(client, report, instr) and (
                instr.id not in watched or client.outcome(instr.id, 0) is None
            ):
                report.line(f"{instr.name} [{instr.id}]: cancelled (Ctrl-C)")
    except KeyboardInterrupt:
        report.line(
            "Ctrl-C again: left before every cancel was answered: what was sent may still "
            "run (`al5d send stop` halts the arm)"
        )
    return exits.INTERRUPTED


def _cancel(client: Client, report: Report, instr: Instruction) -> bool:
    """Ctrl-C's cancel of `instr` by the lane: whether it was cancelled. One the server does
    not answer within `quick.UNANSWERED_S` (busy or stalled) is said so at once, while it
    is still awaited (an outside try: a frozen server's Ctrl-C said nothing for 12 s)."""
    what = f"{instr.name} [{instr.id}]: Ctrl-C"
    timer = threading.Timer(
        quick.UNANSWERED_S,
        report.line,
        [
            f"{what}: its cancel not answered in {quick.UNANSWERED_S:g} s (the server busy or "
            "stalled); still waiting: Ctrl-C twice more leaves (`al5d send stop` halts the "
            "arm)"
        ],
    )
    timer.daemon = True
    timer.start()
    try:
        return client.cancel(instr.id, "cancelled by Ctrl-C")
    except FutureTimeout:  # `Remote.cancel`'s own wait (the built-in one from 3.11 on)
        report.line(
            f"{what}: its cancel not answered: whether it runs on is unknown (`al5d send "
            "stop` halts the arm)"
        )
        return False
    finally:
        timer.cancel()


def stop_or_release(client: Client, instr: Instruction, timeout: float) -> Answer:
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
    answer_s: float = ANSWER_S,
) -> int:
    """Send one instruction and print its outcome within `timeout` s; a stop or a release as
    `Client.stop` and `Client.release` send them, their answer waited for `answer_s` s,
    printed with what carried it."""
    try:
        instr = parse_instruction(text, PRESET_NAMES)
    except GrammarError as e:
        print(f"al5d send: {e}", file=err)
        return exits.BAD_INPUT
    if instr.kind is Kind.STOP and via == "auto":
        # As the quick path (`al5d.owner.quick.stop`) does: by the lane, the client would
        # wait for a connection a stalled server does not take, and end with nothing sent.
        full = quick.full(where.path(Names.of(namespace).namespace))
        if full is not None:
            print(f"al5d send: stop: {full}; {quick.BY_ROS}", file=err)
            via = "ros"
    started = connect("al5d send", namespace, wait_s, via, verbose, err)
    if started is None:
        return exits.NO_SERVER
    client, timing = started
    report = Report(out, timeout)
    sent: list[Instruction] = []
    try:
        if instr.kind in (Kind.STOP, Kind.RELEASE):
            answer = stop_or_release(client, instr, answer_s)
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
    name = "<stdin>" if str(path) == "-" else str(path)  # as each problem names the file
    try:
        book = load_poses(beside(path) if poses is None else poses, required=poses is not None)
        data = read_sequence(path)
        # A line of bad grammar is bad for every server: said at once, before one is found
        # its own way, with every other problem as the server on this machine's lane
        # judges it (instantly), or a server with the shipped configuration.
        here = (
            None
            if via == "ros"  # the lane not asked: the way the user chose is ROS 2
            else local_config(where.path(Names.of(namespace).namespace), max(wait_s, 1.0))
        )
        first = judge_sequence(data, here or load_config(), name, book)
        if any(problem.grammar for problem in first.problems):
            raise first.error()
    except LaneStalled as e:  # before OSError, of which it is one
        print(f"al5d run: {e}; nothing sent", file=err)
        return exits.NO_SERVER
    except OSError as e:
        print(f"al5d run: cannot read {path}: {e.strerror}", file=err)
        return exits.BAD_INPUT
    except (PosesError, GrammarError) as e:  # each problem a line
        print(each_line("al5d run: ", f"nothing sent: {e}"), file=err)
        return exits.BAD_INPUT
    if not first.lines:  # an outside try: a file of nothing but comments ran without a word
        print(f"al5d run: {name}: no instruction in it: nothing sent", file=err)
        return exits.DONE
    started = connect("al5d run", namespace, wait_s, via, verbose, err)
    if started is None:
        return exits.NO_SERVER
    client, timing = started
    report = Report(out, timeout)
    sent: list[Instruction] = []
    background: list[Instruction] = []
    watch = LinkWatch(client, report, background)
    left = 0  # the steps after the one running: not sent after a Ctrl-C
    try:
        client.wait_for_server(wait_s)
        timing.discovered(client)
        try:
            steps = judged_steps(data, name, book, client.config())
        except GrammarError as e:
            print(each_line("al5d run: ", f"nothing sent: {e}"), file=err)
            return exits.BAD_INPUT
        for n, (item, in_background) in enumerate(steps):
            left = len(steps) - n - 1
            if isinstance(item, Instruction):
                sent.append(item)
            if not run_step(client, report, item, in_background, timeout, background, watch):
                # As the web view's Teach tab: a line waited for and not done (refused, or
                # cancelled: by a stop, say) ends the sequence, so that a release after a
                # stop does not take up the rest of it.
                if left:
                    report.line(f"not done: the {left} step{'s'[: left != 1]} after it not sent")
                    left = 0  # said: a Ctrl-C in the wait below says it not again
                break
        drain(client, report, background, timeout)
        return exits.DONE if report.all_done else exits.NOT_DONE
    except NoServer as e:
        print(f"al5d run: {e}", file=err)
        return exits.NO_SERVER
    except NoOutcome as e:
        report.line(str(e))
        return exits.NOT_DONE
    except KeyboardInterrupt:
        code = interrupted(client, report, sent, {i.id for i in background})
        if left:  # said even where nothing was running (an outside try: Ctrl-C in a `wait`)
            steps_left = f"{left} step{'s'[: left != 1]}"
            report.line(f"Ctrl-C: the sequence ends here: the {steps_left} after it not sent")
        return code
    finally:
        watch.close()
        client.close()
        timing.end()


def run_step(
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
    try:
        outcome = client.outcome(item.id, timeout + GIVE_UP_WORD_S)
    except (LostContact, LaneLost) as e:  # "[id]: ...": said with its name, as `Report.lost`
        raise type(e)(f"{item.name} {e}") from None
    report.outcome(outcome, instr=item)
    if outcome is not None and item.kind is Kind.RELEASE:
        return True  # refused where nothing is stopped: nothing to release, nothing lost
    return outcome is not None and outcome.result is Result.DONE


def drain(client: Client, report: Report, background: list[Instruction], timeout: float) -> None:
    """Wait for the outcomes of the lines run in the background (each printed as it came),
    every one said when this returns: its watcher's callback may run just after the wait
    ends, and what is said next would come above it."""
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
        report.outcome(outcome, instr=item)  # once: where its watcher said it, not again
    background.clear()
