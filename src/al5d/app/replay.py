"""`al5d replay`: the instructions of a recording (`al5d record`, `al5d serve --record`) sent
again, as `al5d run` sends a sequence file's, each with its outcome.

The instructions are read from the file's `al5d_interfaces/msg/ArmInstruction` messages,
decoded with mcap-ros2-support from the schema the file holds, and sent on the instruction
topic by the client (`al5d.ros.client.Client`): the server judges each as it judges any
(a refused one writes nothing). `rate`: `recorded` sends each at its recorded time after
the first (when its sender sent it), whatever the outcomes; `fast` sends each as soon as the
one before has its outcome.
"""

from __future__ import annotations

import functools
import struct
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, TextIO

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, SeekingReader
from mcap_ros2.decoder import DecoderFactory

from al5d.ros.names import PING

INSTRUCTION_TYPE = "al5d_interfaces/msg/ArmInstruction"
RATES = ("recorded", "fast")
#: What a damaged file raises in the readers besides their own errors.
_DAMAGED = (McapError, struct.error, ValueError, EOFError, UnicodeDecodeError)


class BadRecording(Exception):
    """The file is no recording that can be replayed: check its name, or record it again."""


@dataclass(frozen=True)
class Recorded:
    """One instruction message of a recording, and when it was sent (CLOCK_REALTIME ns)."""

    sent_ns: int
    topic: str
    msg: Any  # the decoded message: instruction, joints, degrees, time_ms, id


def read_instructions(path: str | Path) -> tuple[list[Recorded], str]:
    """The instruction messages of a recording in the order they were sent, and a warning
    ("" when none) if the file ends early (a recorder killed before it closed it): those
    read before the damage are replayed. BadRecording when none can be read."""
    try:
        f = open(path, "rb")  # noqa: SIM115 (closed below)
    except OSError as e:
        raise BadRecording(f"cannot read {path}: {e.strerror}") from e
    with f:
        found: list[Recorded] = []
        try:
            _read(SeekingReader(f), found)
            warning = ""
        except _DAMAGED as e:
            found.clear()
            f.seek(0)
            try:
                _read(NonSeekingReader(f), found)
            except _DAMAGED as again:
                if not found:
                    raise BadRecording(f"{path} is not a readable MCAP recording: {e}") from again
                warning = (
                    f"{path} is damaged or cut short ({again}): replaying the {len(found)} "
                    "instructions read before that"
                )
            else:
                warning = ""
    found.sort(key=lambda r: r.sent_ns)
    return found, warning


def _read(reader: SeekingReader | NonSeekingReader, found: list[Recorded]) -> None:
    factory = DecoderFactory()
    decoders: dict[int, Any] = {}
    order = isinstance(reader, SeekingReader)
    for schema, channel, message in reader.iter_messages(log_time_order=order):
        if schema is None or schema.name != INSTRUCTION_TYPE:
            continue
        decode = decoders.get(schema.id)
        if decode is None:
            decode = factory.decoder_for(channel.message_encoding, schema)
            if decode is None:
                raise BadRecording(
                    f"{channel.topic}: messages encoded as {channel.message_encoding!r}, not CDR"
                )
            decoders[schema.id] = decode
        msg = decode(message.data)
        if msg.instruction == PING:  # a client's handshake with the server, no instruction
            continue
        found.append(Recorded(message.publish_time or message.log_time, channel.topic, msg))


def _message(recorded: Recorded) -> Any:
    from al5d_interfaces.msg import ArmInstruction

    msg = ArmInstruction()
    msg.instruction = recorded.msg.instruction
    msg.joints = list(recorded.msg.joints)
    msg.degrees = [float(d) for d in recorded.msg.degrees]
    msg.time_ms = int(recorded.msg.time_ms)
    msg.id = recorded.msg.id
    return msg


def replay(
    path: str,
    *,
    rate: str,
    wait_s: float,
    timeout: float,
    namespace: str | None = None,
    config: str | None = None,
    out: TextIO = sys.stdout,
    err: IO[str] = sys.stderr,
) -> int:
    """Send a recording's instructions again; the exit code (`al5d.exits`): done, not done
    (any one refused, cancelled or unanswered), bad input (a file that cannot be replayed:
    nothing sent) or no server."""
    from al5d import exits
    from al5d.app.terminal import Report
    from al5d.arm.config import load_config
    from al5d.arm.instruction import Instruction
    from al5d.ros.client import Client, NoServer
    from al5d.ros.convert import from_message

    try:
        recorded, warning = read_instructions(path)
    except BadRecording as e:
        print(f"al5d replay: {e}", file=err)
        return exits.BAD_INPUT
    if warning:
        print(f"al5d replay: warning: {warning}", file=err)
    if not recorded:
        print(f"al5d replay: {path} holds no instructions ({INSTRUCTION_TYPE})", file=err)
        return exits.BAD_INPUT
    arm = load_config(config)
    presets = tuple(arm.presets)
    client = Client(namespace)
    report = Report(out)
    try:
        client.wait_for_server(wait_s)
        started = time.monotonic()
        first = recorded[0].sent_ns
        sent: list[Instruction] = []
        for each in recorded:
            instr = from_message(_message(each), presets, arm.model)
            if isinstance(instr, str):  # as the server would refuse it: nothing is sent
                report.all_done = False
                report.line(f"> {each.msg.instruction!r} [{each.msg.id}]: refused: {instr}")
                continue
            if rate == "recorded":
                time.sleep(max(0.0, started + (each.sent_ns - first) / 1e9 - time.monotonic()))
            report.line(f"> {instr}")
            if rate == "recorded":
                client.watch(instr.id, functools.partial(report.outcome, instr=instr))
                sent.append(instr)
            client.send(instr)
            if rate != "recorded":
                report.outcome(client.outcome(instr.id, timeout), instr=instr)
        for instr in sent:
            if client.outcome(instr.id, timeout) is None:
                report.outcome(None, instr=instr)
        return exits.DONE if report.all_done else exits.NOT_DONE
    except NoServer as e:
        print(f"al5d replay: {e}", file=err)
        return exits.NO_SERVER
    finally:
        client.close()
