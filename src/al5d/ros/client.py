"""The client application: sends instructions to the server over ROS 2 and reports their outcomes.

`al5d send` sends one instruction and waits for its outcome. `al5d run`
runs a sequence file: each instruction waits for its outcome before the next
line, unless the line ends with `&` (then the client goes on at once, so that,
say, a `stop` can land in the middle of a move); `wait <ms>` pauses.
Exit codes: 0 done, 1 refused or cancelled (or not an instruction), 2 no server.
"""

from __future__ import annotations

import os
import sys
import threading
import time
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
    parse_sequence_step,
)
from al5d.clock import Deadline
from al5d.ros.convert import outcome_from_message, to_message
from al5d.ros.runtime import INSTRUCTION_TOPIC, QOS_STREAM, RESULT_TOPIC, Spinner, start_context

EXIT_DONE, EXIT_NOT_DONE, EXIT_NO_SERVER = 0, 1, 2


class NoServer(Exception):
    """No `al5d serve` answers on this ROS domain."""


class Client:
    """A ROS 2 node that publishes instructions and collects their outcomes by id."""

    def __init__(self) -> None:
        from rclpy.node import Node

        self.context = start_context()
        self.node = Node(f"al5d_client_{os.getpid()}", context=self.context)
        self.pub = self.node.create_publisher(ArmInstruction, INSTRUCTION_TOPIC, QOS_STREAM)
        self.node.create_subscription(InstructionResult, RESULT_TOPIC, self._on_result, QOS_STREAM)
        self._outcomes: dict[str, Outcome] = {}
        self._cv = threading.Condition()
        self.spinner = Spinner(self.node, self.context)

    def _on_result(self, msg: InstructionResult) -> None:
        with self._cv:
            self._outcomes[msg.id] = outcome_from_message(msg)
            self._cv.notify_all()

    def wait_for_server(self, timeout: float) -> None:
        """Until our instructions reach a server and its results reach us (both directions)."""
        deadline = Deadline(timeout)
        while not deadline.expired:
            if (
                self.pub.get_subscription_count() > 0
                and self.node.count_publishers(RESULT_TOPIC) > 0
            ):
                return
            time.sleep(0.02)
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        raise NoServer(
            f"no al5d server answers on {INSTRUCTION_TOPIC} (ROS_DOMAIN_ID={domain}) "
            f"within {timeout:g} s: is 'al5d serve' running?"
        )

    def send(self, instr: Instruction) -> None:
        self.pub.publish(to_message(instr))

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


def _report(outcome: Outcome | None, instr: Instruction, out: TextIO) -> bool:
    if outcome is None:
        print(f"{instr.name} [{instr.id}]: no outcome (timed out)", file=out, flush=True)
        return False
    print(outcome, file=out, flush=True)
    return outcome.result is Result.DONE


def send(text: str, *, wait_s: float, timeout: float, out: TextIO = sys.stdout) -> int:
    try:
        instr = parse_instruction(text, PRESET_NAMES)
    except GrammarError as e:
        print(f"al5d send: {e}", file=sys.stderr)
        return EXIT_NOT_DONE
    client = Client()
    try:
        client.wait_for_server(wait_s)
        client.send(instr)
        return (
            EXIT_DONE if _report(client.outcome(instr.id, timeout), instr, out) else EXIT_NOT_DONE
        )
    except NoServer as e:
        print(f"al5d send: {e}", file=sys.stderr)
        return EXIT_NO_SERVER
    finally:
        client.close()


def run(path: str | Path, *, wait_s: float, timeout: float, out: TextIO = sys.stdout) -> int:
    """Run a sequence file; 0 if every instruction was done, 1 if any was not."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as e:
        print(f"al5d run: cannot read {path}: {e.strerror}", file=sys.stderr)
        return EXIT_NOT_DONE
    steps = []
    for number, line in enumerate(lines, start=1):
        try:
            step = parse_sequence_step(line, PRESET_NAMES)
        except GrammarError as e:
            print(f"al5d run: {path}:{number}: {e}", file=sys.stderr)
            return EXIT_NOT_DONE
        if step is not None:
            steps.append(step)
    client = Client()
    try:
        client.wait_for_server(wait_s)
        all_done = True
        pending: list[Instruction] = []
        for item, background in steps:
            if isinstance(item, Wait):
                print(f"wait {item.ms} ms", file=out, flush=True)
                time.sleep(item.ms / 1000)
                continue
            print(f"> {item}{' &' if background else ''}", file=out, flush=True)
            client.send(item)
            if background:
                pending.append(item)
                continue
            all_done &= _report(client.outcome(item.id, timeout), item, out)
            # Outcomes of background lines that have come meanwhile, in order.
            while pending and (o := client.outcome(pending[0].id, 0)) is not None:
                all_done &= _report(o, pending.pop(0), out)
        for item in pending:
            all_done &= _report(client.outcome(item.id, timeout), item, out)
        return EXIT_DONE if all_done else EXIT_NOT_DONE
    except NoServer as e:
        print(f"al5d run: {e}", file=sys.stderr)
        return EXIT_NO_SERVER
    finally:
        client.close()
