"""`al5d replay`: the instructions of a recording (`al5d record`, `al5d serve --record`) sent
again, as `al5d run` sends a sequence file's, each with its outcome.

The instructions are the file's `al5d_interfaces/msg/ArmInstruction` messages on an arm's
instruction topic (`<ns>/al5d/instruction`; one arm's, when the file holds several),
decoded from the schema the file holds, and sent on the instruction topic by the client:
the server judges each as it judges any (a refused one writes nothing). `rate`:
`recorded` sends each at its recorded time after the first (when its sender sent it),
whatever the outcomes, with a gap longer than `max_gap_s` cut to it (and said); `fast`
sends each as soon as the one before has its outcome.

The file is read as a stream, twice: once whole, to check every instruction in it (a
damaged or foreign file, or a field that cannot be read, is an error naming the file and
the message, and nothing is sent), then again to send them. Memory does not grow with
the file. Each instruction is sent under an id of its own (its recorded id and its
place in the file), so that each gets its own outcome where the file repeats an id.
"""

from __future__ import annotations

import contextlib
import functools
import io
import itertools
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, TextIO

from mcap.reader import NonSeekingReader
from mcap.records import Channel, Message, Schema

from al5d.app.record import INSTRUCTION_TYPE
from al5d.arm.instruction import MAX_ID, MAX_QUOTE, TIME_FIELD_MAX_MS, Kind
from al5d.ros.names import NODE, PING

#: An arm's instruction topic ends so (`Names.instruction`: `<ns>/al5d/instruction`).
INSTRUCTION_TOPIC = f"/{NODE}/instruction"
RATES = ("recorded", "fast")
#: An MCAP file's first bytes (the format's magic: 0x89 `MCAP0` CR LF).
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: A gap between two instructions longer than this, at the recorded rate, is cut to it.
MAX_GAP_S = 10.0
#: The largest record the reader loads (a chunk of the recorder's is 1 MiB): a damaged
#: length is an error, not an allocation of gigabytes.
RECORD_LIMIT = 64 * 2**20
#: An instruction whose strings come to more than this is not sent: DDS would not carry
#: it whole to the server (a megabyte joint name never reached it), and no instruction of
#: the grammar is near it.
MAX_MESSAGE_BYTES = 64 * 2**10
#: What a damaged or foreign file raises in the reader, the schema's parser and the
#: decoder: anything. Their errors are many and undocumented (lz4's and zstandard's,
#: rosidl's parser's, struct's, a missing attribute of a foreign message), and whatever
#: they raise, the file is the cause: it is reported as the file's, with its type.
_DAMAGED = (Exception,)


class BadRecording(Exception):
    """The file is no recording that can be replayed: check its name, or record it again."""


class CutShort(BadRecording):
    """A recording damaged or cut short (its recorder killed): what comes before the
    damage can be replayed (`--partial`)."""


@dataclass(frozen=True)
class Fields:
    """One recorded instruction's fields, checked: what `ArmInstruction` holds."""

    instruction: str
    joints: tuple[str, ...]
    degrees: tuple[float, ...]
    time_ms: int
    id: str


@dataclass(frozen=True)
class Recorded:
    """One instruction message of a recording: its place among the arm's instructions, when
    it was sent (CLOCK_REALTIME ns), its topic and its fields."""

    index: int
    sent_ns: int
    topic: str
    fields: Fields


@dataclass
class Survey:
    """What the first reading found: every arm's instructions (topic -> how many), and the
    damage where the file stops being readable ("" none)."""

    instructions: Counter[str]
    damage: str = ""


def _after(channel: Channel | None, message: Message | None, n: int) -> str:
    """Where the reading of a file stopped: after its `n`th message, the one given."""
    if channel is None or message is None:
        return "before its first message"
    return f"after its message {n} (on {channel.topic}, log time {message.log_time})"


def _named(e: BaseException) -> str:
    """An error, by its type's name and its words (`struct.error`, not `error`)."""
    kind = type(e)
    name = kind.__name__ if kind.__name__ != "error" else f"{kind.__module__}.error"
    return f"{name}: {e}" if str(e) else name


def _checked(msg: Any) -> Fields:
    """The fields of a decoded message, or ValueError naming the one that is not what
    `ArmInstruction` says (a foreign message under its name)."""

    def text(name: str, value: Any) -> str:
        if not isinstance(value, str):
            raise ValueError(f"field {name}: {type(value).__name__}, not a string")
        return value

    def listed(name: str, value: Any) -> list[Any]:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
            raise ValueError(f"field {name}: {type(value).__name__}, not an array")
        return list(value)

    joints = [text("joints[]", j) for j in listed("joints", msg.joints)]
    degrees = []
    for d in listed("degrees", msg.degrees):
        if isinstance(d, bool) or not isinstance(d, (int, float)):
            raise ValueError(f"field degrees[]: {type(d).__name__}, not a number")
        degrees.append(float(d))
    time_ms = msg.time_ms
    if isinstance(time_ms, bool) or not isinstance(time_ms, int):
        raise ValueError(f"field time_ms: {type(time_ms).__name__}, not a whole number")
    if not 0 <= time_ms <= TIME_FIELD_MAX_MS:
        raise ValueError(f"field time_ms: {time_ms} is outside 0..{TIME_FIELD_MAX_MS}")
    return Fields(
        text("instruction", msg.instruction),
        tuple(joints),
        tuple(degrees),
        time_ms,
        text("id", msg.id),
    )


class _Reader:
    """The instruction messages of one file, read as a stream."""

    def __init__(self, path: str | Path) -> None:
        self.path = path
        self._decoders: dict[int, Callable[[bytes], Any]] = {}

    def _open(self) -> IO[bytes]:
        try:
            return open(self.path, "rb")
        except OSError as e:
            raise BadRecording(f"cannot read {self.path}: {e.strerror}") from e

    def _decoder(self, schema: Schema, channel: Channel) -> Callable[[bytes], Any]:
        decode = self._decoders.get(schema.id)
        if decode is None:
            if channel.message_encoding != "cdr" or schema.encoding != "ros2msg":
                raise BadRecording(
                    f"{self.path}: {channel.topic}: messages encoded as "
                    f"{channel.message_encoding!r} ({schema.encoding!r} schema), not CDR of a "
                    "ros2msg schema"
                )
            from mcap_ros2._dynamic import generate_dynamic

            # The schema's own decoder (mcap-ros2-support's, in Python), whatever the schema:
            # it reads a damaged message's lengths without trusting them, where rclpy's would
            # allocate what a damaged length asks for; and it is the faster here (6 us a
            # message against 8 us).
            try:
                # rosidl's parser prints its own words on a bad definition; ours say it.
                with contextlib.redirect_stderr(io.StringIO()):
                    decoders = generate_dynamic(schema.name, schema.data.decode())
                decode = decoders[schema.name]
            except _DAMAGED as e:
                raise BadRecording(
                    f"{self.path}: {channel.topic}: the schema {schema.name} cannot be read: "
                    f"{_named(e)}"
                ) from None
            self._decoders[schema.id] = decode
        return decode

    def messages(self) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Every message of the file in its order; BadRecording (naming where) when the
        file stops being an MCAP recording."""
        n = 0
        channel: Channel | None = None
        message: Message | None = None
        with self._open() as f:
            reader = NonSeekingReader(f, validate_crcs=True, record_size_limit=RECORD_LIMIT)
            try:
                # In the file's order: in log-time order this reader sorts the whole file in memory.
                for schema, channel, message in reader.iter_messages(log_time_order=False):
                    yield schema, channel, message
                    n += 1
            except BadRecording:
                raise
            except _DAMAGED as e:
                f.seek(0)
                mcap = f.read(len(MCAP_MAGIC)) == MCAP_MAGIC
                what = "is damaged or cut short" if mcap else "is not an MCAP recording"
                raise (CutShort if mcap else BadRecording)(
                    f"{self.path} {what} ({_after(channel, message, n)}: {_named(e)})"
                ) from None

    def instructions(self, topic: str | None = None) -> Iterator[Recorded]:
        """The instruction messages on `topic` (None: every arm's), checked, in the file's
        order; BadRecording naming the message that cannot be read."""
        count = 0
        for schema, channel, message in self.messages():
            if not channel.topic.endswith(INSTRUCTION_TOPIC) or (topic and channel.topic != topic):
                continue
            if schema is None or schema.name != INSTRUCTION_TYPE:
                raise BadRecording(
                    f"{self.path}: {channel.topic} holds "
                    f"{schema.name if schema else 'schemaless'} messages, not {INSTRUCTION_TYPE}"
                )
            decode = self._decoder(schema, channel)
            try:
                fields = _checked(decode(message.data))
            except _DAMAGED as e:
                raise BadRecording(
                    f"{self.path}: instruction {count + 1} (on {channel.topic}, log time "
                    f"{message.log_time}): cannot be read as {INSTRUCTION_TYPE}: {_named(e)}"
                ) from None
            count += 1
            if fields.instruction == PING:  # a client's handshake, no instruction
                continue
            yield Recorded(count, message.publish_time or message.log_time, channel.topic, fields)

    def survey(self, partial: bool) -> Survey:
        """Every instruction checked, counted by topic; with `partial`, damage ends the
        count instead (`Survey.damage` says where)."""
        found = Survey(Counter())
        try:
            for each in self.instructions():
                found.instructions[each.topic] += 1
        except CutShort as e:
            if not partial:
                raise
            found.damage = str(e)
        return found


def survey(path: str | Path, partial: bool = False) -> Survey:
    """Every instruction of a recording checked, counted by topic (`_Reader.survey`)."""
    return _Reader(path).survey(partial)


def read_instructions(path: str | Path, topic: str | None = None) -> list[Recorded]:
    """The checked instructions of a recording, in the file's order (every arm's, or those
    on `topic`). BadRecording when the file cannot be read whole."""
    return list(_Reader(path).instructions(topic))


def choose_topic(path: str, found: Counter[str], arm: str | None, namespace: str | None) -> str:
    """The instruction topic to replay: the recorded arm's (`arm`, a namespace), the one
    arm's the file holds, or the one of `namespace` (the server sent to); BadRecording
    when the file holds none, or several and neither says which."""
    from al5d.ros.names import Names

    if not found:
        raise BadRecording(f"{path} holds no instructions ({INSTRUCTION_TYPE})")
    if arm is not None:
        topic = Names.of(arm).instruction
        if topic not in found:
            held = ", ".join(sorted(found))
            raise BadRecording(f"{path} holds no instructions on {topic} (it holds {held})")
        return topic
    if len(found) == 1:
        return next(iter(found))
    mine = Names.of(namespace).instruction
    if mine in found:
        return mine
    arms = " and ".join(t.removesuffix(INSTRUCTION_TOPIC) or "/" for t in sorted(found))
    raise BadRecording(
        f"{path} holds the instructions of several arms ({arms}): choose one with --from NS"
    )


def _message(fields: Fields, ident: str) -> Any:
    from al5d_interfaces.msg import ArmInstruction

    msg = ArmInstruction()
    msg.instruction = fields.instruction
    msg.joints = list(fields.joints)
    msg.degrees = list(fields.degrees)
    msg.time_ms = fields.time_ms
    msg.id = ident
    return msg


def _unsendable(fields: Fields) -> str:
    """Why an instruction is not sent at all ("": it is): what the server would refuse
    without it reaching it whole."""
    size = len(fields.instruction) + len(fields.id) + sum(len(j) for j in fields.joints)
    size += 8 * len(fields.degrees)
    if size > MAX_MESSAGE_BYTES:
        return (
            f"the message holds {size} bytes of fields, more than the {MAX_MESSAGE_BYTES} an "
            "instruction is sent with"
        )
    if len(fields.id) > MAX_ID:
        return f"the id is {len(fields.id)} characters long; at most {MAX_ID}"
    return ""


def _sent_id(recorded: Recorded) -> str:
    """The id an instruction is sent under: its recorded id and its place in the file, so
    that a file that repeats an id has an outcome for each."""
    suffix = f"#{recorded.index}"
    return recorded.fields.id[: MAX_ID - len(suffix)] + suffix


class _Outcomes:
    """The outcomes of what the replay sent, by id, each handed to its waiter once; kept only
    while awaited (memory does not grow with the instructions sent)."""

    def __init__(self, client: Any) -> None:
        from al5d_interfaces.msg import InstructionResult

        from al5d.ros.qos import QOS_STREAM

        self._cv = threading.Condition()
        self._waiting: dict[str, Callable[[Any], None]] = {}
        #: The stops the replay sent, and the first stop it did not (an operator's, by any
        #: channel: every stop's outcome is told on the result topic, before those of what
        #: it cancelled), or why the arm was locked as the replay began.
        self.own_stops: set[str] = set()
        self.stopped_by: str | None = None
        self._sub = client.node.create_subscription(
            InstructionResult, client.names.result, self._on_result, QOS_STREAM
        )

    def handshake(self, client: Any, timeout: float) -> bool:
        """Until a ping of ours is answered on this reader: the server's writer of results
        has matched it (the client's own reader having matched says nothing of this one);
        False if none is within `timeout`."""
        from al5d_interfaces.msg import ArmInstruction

        from al5d.arm.instruction import new_id

        answered = threading.Event()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ping = new_id()
            self.expect(ping, lambda _: answered.set())
            client.pub.publish(ArmInstruction(instruction=PING, id=ping))
            if answered.wait(min(0.5, max(0.0, deadline - time.monotonic()))):
                return True
            self.forget(ping)
        return False

    def expect(self, ident: str, then: Callable[[Any], None]) -> None:
        with self._cv:
            self._waiting[ident] = then

    def _on_result(self, msg: Any) -> None:
        from al5d.ros.convert import outcome_from_message

        with self._cv:
            if msg.instruction == STOP_WORD and msg.id not in self.own_stops:
                self.stopped_by = self.stopped_by or msg.id  # before what it cancelled
            then = self._waiting.pop(msg.id, None)
            self._cv.notify_all()
        if then is not None:
            with contextlib.suppress(ValueError):  # an outcome word no server says
                then(outcome_from_message(msg))

    def wait(
        self, idents: Callable[[], bool], timeout: float, gone: Callable[[], str | None]
    ) -> bool:
        """Until `idents()` says the awaited outcomes have come, or `timeout` seconds.
        Raises `ServerGone` once `gone()` says why the server is gone (looked at each
        `GONE_EVERY_S`: an outside try's replay of a server shut down waited out its
        timeout for each instruction, 131.8 s)."""
        deadline = time.monotonic() + timeout
        with self._cv:
            while not idents():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                if why := gone():
                    raise ServerGone(why)
                self._cv.wait(min(left, GONE_EVERY_S))
            return True

    def pending(self) -> list[str]:
        with self._cv:
            return list(self._waiting)

    def arrived(self, ident: str) -> bool:
        """Whether the outcome of `ident` has come (or was never awaited)."""
        with self._cv:
            return ident not in self._waiting

    def forget(self, ident: str) -> None:
        with self._cv:
            self._waiting.pop(ident, None)


def replay(
    path: str,
    *,
    rate: str,
    wait_s: float,
    timeout: float,
    namespace: str | None = None,
    config: str | None = None,
    arm: str | None = None,
    max_gap_s: float = MAX_GAP_S,
    partial: bool = False,
    out: TextIO = sys.stdout,
    err: IO[str] = sys.stderr,
) -> int:
    """Send a recording's instructions again; the exit code (`al5d.exits`): done, not done
    (any one refused, cancelled or unanswered, or Ctrl-C), bad input (a file that cannot be
    replayed: nothing sent) or no server."""
    from al5d import exits

    reader = _Reader(path)
    try:
        survey = reader.survey(partial)
        topic = choose_topic(path, survey.instructions, arm, namespace)
    except BadRecording as e:
        # An outside try did not learn of --partial from the refusal of a file cut short.
        partial_hint = "; --partial replays the instructions before the damage"
        hint = partial_hint if isinstance(e, CutShort) else ""
        print(f"al5d replay: {e}{hint}", file=err)
        return exits.BAD_INPUT
    except KeyboardInterrupt:
        print(f"al5d replay: interrupted (Ctrl-C) while reading {path}: nothing sent", file=err)
        return exits.NOT_DONE
    total = survey.instructions[topic]
    if survey.damage:
        print(
            f"al5d replay: warning: {survey.damage}: replaying the {total} instructions before "
            "that (--partial)",
            file=err,
        )
    return _send(
        reader, topic, total, rate, wait_s, timeout, namespace, config, max_gap_s, out, err
    )


def _send(
    reader: _Reader,
    topic: str,
    total: int,
    rate: str,
    wait_s: float,
    timeout: float,
    namespace: str | None,
    config: str | None,
    max_gap_s: float,
    out: TextIO,
    err: IO[str],
) -> int:
    from al5d import exits
    from al5d.app.report import Report
    from al5d.arm.config import ConfigError, load_config
    from al5d.arm.instruction import Instruction
    from al5d.ros.answers import GIVE_UP_WORD_S, no_outcome, wait_ms
    from al5d.ros.client import Client, NoServer
    from al5d.ros.convert import from_message, to_message

    arm = load_config(config)
    presets = tuple(arm.presets)
    # Over ROS 2 always, wherever the server is: the instructions go on its topic as they
    # were recorded, the outcomes come from its result topic (`_Outcomes`).
    client = Client(namespace, local=False)
    report = Report(out, timeout)
    sent = 0
    try:
        outcomes = _Outcomes(client)
        client.wait_for_server(wait_s)
        if not outcomes.handshake(client, wait_s):
            raise NoServer(f"the server's results do not reach this replay within {wait_s:g} s")
        heard = _Heard()
        try:
            client.on_change(lambda r: heard.heard(r.state))  # its state topic, latched
        except ConfigError as e:  # a server of another version
            raise NoServer(f"the server's configuration cannot be read: {e}") from None
        if heard.came.wait(wait_s) and heard.state == "stopped":
            outcomes.stopped_by = "a stop before the replay began"

        def gone() -> str | None:
            if heard.shutting_down:
                return "the server is shutting down"
            return client.out_of_contact()

        started = time.monotonic()
        first: int | None = None
        before: int | None = None
        cut_s = 0.0  # the gaps cut so far
        last_sent = time.monotonic()
        # The first `total`: a --partial replay stops before the damage.
        for each in itertools.islice(reader.instructions(topic), total):
            fields = each.fields
            why = _unsendable(fields)
            instr: Instruction | str = why or from_message(
                _message(fields, _sent_id(each)), presets, arm.model
            )
            if isinstance(instr, str):  # as the server would refuse it: nothing is sent
                report.fail()
                # One line, as an outcome is told (the file's words escaped: they were
                # never judged), and no "> " line: a million of them would be two million.
                name = repr(fields.instruction[:MAX_QUOTE])[1:-1]
                said = f"{name} [{repr(_sent_id(each))[1:-1]}]: refused: {instr} (not sent)"
                # Out with the next line sent, or before a wait (a million: a write per thousand).
                report.line(said, flush=rate == "recorded")
                continue
            if rate == "recorded":
                first = each.sent_ns if first is None else first
                gap_s = (each.sent_ns - (before if before is not None else each.sent_ns)) / 1e9
                before = each.sent_ns
                if gap_s > max_gap_s:
                    cut_s += gap_s - max_gap_s
                    print(
                        f"al5d replay: a gap of {gap_s:.6g} s before instruction {each.index} "
                        f"is cut to {max_gap_s:g} s (--max-gap)",
                        file=err,
                        flush=True,
                    )
                due = started + (each.sent_ns - first) / 1e9 - cut_s
                # In slices: a server gone, or a stop, is heard in a gap of up to --max-gap.
                while (left := due - time.monotonic()) > 0 and outcomes.stopped_by is None:
                    if lost := gone():
                        raise ServerGone(lost)
                    time.sleep(min(left, GONE_EVERY_S))
            if lost := gone():
                raise ServerGone(lost)
            if (by := outcomes.stopped_by) is not None:
                said = by if by.startswith("a stop") else f"stop [{by}]"
                report.line(
                    f"the arm is stopped by {said}, which this replay did not send: the replay "
                    f"ends here: instruction {each.index} and those after it are not sent"
                )
                report.fail()
                break
            report.line(f"> {instr}")
            outcome_of = _reporter(report, instr)
            outcomes.expect(instr.id, outcome_of)
            msg = to_message(instr)
            msg.client = client.key  # a replay cut off or killed leaves nothing moving
            msg.wait_ms = wait_ms(timeout)  # nor does what it gives up on
            if instr.kind is Kind.STOP:  # before its outcome can come back
                outcomes.own_stops.add(instr.id)
            elif instr.kind is Kind.SHUTDOWN:
                heard.sent_shutdown = True
            client.pub.publish(msg)
            sent += 1
            last_sent = time.monotonic()
            arrived = functools.partial(outcomes.arrived, instr.id)
            if rate != "recorded" and not outcomes.wait(arrived, timeout + GIVE_UP_WORD_S, gone):
                outcomes.forget(instr.id)
                report.outcome(None, instr=instr)
        report.flush()  # the refusals after the last sent, before the wait for its outcome
        if not outcomes.wait(
            lambda: not outcomes.pending(),
            timeout + GIVE_UP_WORD_S - (time.monotonic() - last_sent),
            gone,
        ):
            for ident in outcomes.pending():
                outcomes.forget(ident)
                report.line(str(no_outcome(f"[{ident}]", timeout)))
            report.fail()
        return exits.DONE if report.all_done else exits.NOT_DONE
    except NoServer as e:
        print(f"al5d replay: {e}", file=err)
        return exits.NO_SERVER
    except ServerGone as e:
        report.flush()
        unknown = len(outcomes.pending())
        print(
            f"al5d replay: {e}: the replay ends here, after {sent} of {total} instructions "
            f"sent; {unknown} of them not told (whether they ran is unknown)",
            file=err,
        )
        return exits.NO_SERVER
    except BadRecording as e:  # the file changed since it was checked
        print(f"al5d replay: {e}", file=err)
        return exits.BAD_INPUT
    except KeyboardInterrupt:
        print(
            f"al5d replay: interrupted (Ctrl-C) after {sent} of {total} instructions sent; "
            "those sent go on (al5d send stop halts the arm)",
            file=err,
        )
        return exits.NOT_DONE
    finally:
        try:
            report.flush()  # the refusals held, whatever ended the replay
        finally:
            client.close()


#: How often a replay waiting for outcomes looks whether its server is gone.
GONE_EVERY_S = 0.25
#: The instruction word of a stop, as the result topic names it.
STOP_WORD = Kind.STOP.value


class ServerGone(Exception):
    """The server a replay sends to is gone (out of contact, or shutting down)."""


class _Heard:
    """What the server says of the arm that a replay heeds: its state (the first as the
    replay begins: an arm already stopped), and whether it is shutting down, not by the
    replay's own word."""

    def __init__(self) -> None:
        self.state = ""
        self.came = threading.Event()
        self.shutting_down = False
        self.sent_shutdown = False

    def heard(self, state: str) -> None:
        if state == "shutting_down" and not self.sent_shutdown:
            self.shutting_down = True
        if state:
            self.state = state
            self.came.set()


def _reporter(report: Any, instr: Any) -> Callable[[Any], None]:
    def told(outcome: Any) -> None:
        report.outcome(outcome, instr=instr)

    return told
