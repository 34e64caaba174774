"""The client application: sends instructions to the server over ROS 2 and reports their outcomes.

`al5d send` sends one instruction and waits for its outcome. `al5d run`
runs a sequence file: each instruction waits for its outcome before the next
line, unless the line ends with `&` (then the client goes on at once, so that,
say, a `stop` can land in the middle of a move); `wait <ms>` pauses.
Exit codes: 0 done, 1 refused or cancelled (or not an instruction), 2 no server.
"""

from __future__ import annotations

import functools
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

from al5d_interfaces.msg import ArmInstruction, InstructionResult

from al5d.arm.instruction import (
    PRESET_NAMES,
    GrammarError,
    Instruction,
    Outcome,
    Result,
    Wait,
    parse_instruction,
    parse_sequence,
)
from al5d.clock import Deadline
from al5d.ros.convert import outcome_from_message, to_message
from al5d.ros.runtime import (
    QOS_INSTRUCTIONS,
    QOS_STREAM,
    Names,
    Spinner,
    start_context,
)

EXIT_DONE, EXIT_NOT_DONE, EXIT_NO_SERVER = 0, 1, 2


class NoServer(Exception):
    """No `al5d serve` answers on this ROS domain."""


#: How long the server's side of the match is given after ours: each side matches when it
#: hears of the other, independently (a mitigation, not a proof: DDS offers none here).
MATCH_SETTLE_S = 0.1


class Client:
    """A ROS 2 node that publishes instructions and collects their outcomes by id, for the
    server in `namespace` (none by default)."""

    def __init__(self, namespace: str | None = None) -> None:
        from rclpy.node import Node

        self.names = names = Names.of(namespace)
        self.context = start_context()
        self.node = Node(
            f"al5d_client_{os.getpid()}", namespace=names.node_namespace, context=self.context
        )
        self.pub = self.node.create_publisher(ArmInstruction, names.instruction, QOS_INSTRUCTIONS)
        self.results = self.node.create_subscription(
            InstructionResult, names.result, self._on_result, QOS_STREAM
        )
        self._outcomes: dict[str, Outcome] = {}
        self._watchers: dict[str, Callable[[Outcome], None]] = {}
        self._cv = threading.Condition()
        self.spinner = Spinner(self.node, self.context)

    def _on_result(self, msg: InstructionResult) -> None:
        outcome = outcome_from_message(msg)
        with self._cv:
            self._outcomes[msg.id] = outcome
            watcher = self._watchers.pop(msg.id, None)
            self._cv.notify_all()
        if watcher is not None:
            watcher(outcome)

    def wait_for_server(self, timeout: float) -> None:
        """Until our instructions reach a server and its results reach us (both directions)."""
        deadline = Deadline(timeout)
        while not deadline.expired:
            if self.pub.get_subscription_count() > 0 and self.results.get_publisher_count() > 0:
                # Our reader has matched the server's result writer; that writer matches our
                # reader when the server hears of it, a moment apart, and a result published
                # before then would not reach us (it is not kept for late readers).
                time.sleep(MATCH_SETTLE_S)
                return
            time.sleep(0.02)
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        raise NoServer(
            f"no al5d server answers on {self.names.instruction} (ROS_DOMAIN_ID={domain}) "
            f"within {timeout:g} s: is 'al5d serve' running?"
        )

    def send(self, instr: Instruction) -> None:
        self.pub.publish(to_message(instr))

    def watch(self, ident: str, watcher: Callable[[Outcome], None]) -> None:
        """Call `watcher` with the outcome of `ident` as soon as it comes (at once if it has)."""
        with self._cv:
            outcome = self._outcomes.get(ident)
            if outcome is None:
                self._watchers[ident] = watcher
        if outcome is not None:
            watcher(outcome)

    def outcome(self, ident: str, timeout: float) -> Outcome | None:
        deadline = Deadline(timeout)
        with self._cv:
            while ident not in self._outcomes:
                if deadline.expired:
                    return None
                self._cv.wait(deadline.left())
            return self._outcomes[ident]

    def close(self) -> None:
        self.spinner.close()


class Report:
    """Prints each outcome when it comes, whichever thread it comes in; keeps the verdict."""

    def __init__(self, out: TextIO) -> None:
        self._out = out
        self._lock = threading.Lock()
        self.all_done = True

    def line(self, text: str) -> None:
        with self._lock:
            print(text, file=self._out, flush=True)

    def outcome(self, outcome: Outcome | None, *, instr: Instruction) -> None:
        if outcome is None:
            text = f"{instr.name} [{instr.id}]: no outcome (timed out)"
        else:
            text = str(outcome)
        with self._lock:
            self.all_done &= outcome is not None and outcome.result is Result.DONE
            print(text, file=self._out, flush=True)


def send(
    text: str,
    *,
    wait_s: float,
    timeout: float,
    out: TextIO = sys.stdout,
    namespace: str | None = None,
) -> int:
    try:
        instr = parse_instruction(text, PRESET_NAMES)
    except GrammarError as e:
        print(f"al5d send: {e}", file=sys.stderr)
        return EXIT_NOT_DONE
    client = Client(namespace)
    report = Report(out)
    try:
        client.wait_for_server(wait_s)
        client.send(instr)
        report.outcome(client.outcome(instr.id, timeout), instr=instr)
        return EXIT_DONE if report.all_done else EXIT_NOT_DONE
    except NoServer as e:
        print(f"al5d send: {e}", file=sys.stderr)
        return EXIT_NO_SERVER
    finally:
        client.close()


def run(
    path: str | Path,
    *,
    wait_s: float,
    timeout: float,
    out: TextIO = sys.stdout,
    namespace: str | None = None,
) -> int:
    """Run a sequence file; 0 if every instruction was done, 1 if any was not.

    The file is checked whole before its first line is sent. Each outcome is
    printed when it comes: a line run in the background (`&`) reports as soon
    as its outcome arrives, not after the next line's.
    """
    try:
        steps = parse_sequence(Path(path).read_bytes(), str(path), PRESET_NAMES)
    except OSError as e:
        print(f"al5d run: cannot read {path}: {e.strerror}", file=sys.stderr)
        return EXIT_NOT_DONE
    except GrammarError as e:
        print(f"al5d run: {e}", file=sys.stderr)
        return EXIT_NOT_DONE
    client = Client(namespace)
    report = Report(out)
    try:
        client.wait_for_server(wait_s)
        background: list[Instruction] = []
        for item, in_background in steps:
            if isinstance(item, Wait):
                report.line(f"wait {item.ms} ms")
                time.sleep(item.ms / 1000)
                continue
            report.line(f"> {item}{' &' if in_background else ''}")
            if in_background:
                background.append(item)
                client.watch(item.id, functools.partial(report.outcome, instr=item))
            client.send(item)
            if not in_background:
                report.outcome(client.outcome(item.id, timeout), instr=item)
        for item in background:
            if client.outcome(item.id, timeout) is None:
                report.outcome(None, instr=item)
        return EXIT_DONE if report.all_done else EXIT_NOT_DONE
    except NoServer as e:
        print(f"al5d run: {e}", file=sys.stderr)
        return EXIT_NO_SERVER
    finally:
        client.close()
