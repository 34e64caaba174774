"""A recording's file: MCAP of rosbag2's `ros2` profile, each type's schema, the board's
writes as CDR, written by a thread of its own.

Whoever hands a message over (the DDS reader, the board's write, the emergency stop's among
them) only puts it in a queue. A recording that fails (a full disk) is logged and given up;
the arm goes on. What is recorded, and when: `al5d.app.record`.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import queue
import re
import struct
import threading
import time
from collections import Counter
from pathlib import Path
from typing import IO

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer

log = logging.getLogger("al5d")

BOARD_WRITE_TYPE = "al5d_interfaces/msg/BoardWrite"
#: The type's definition, as interfaces/al5d_interfaces/msg/BoardWrite.msg has it (a test
#: checks that they are the same): it is written into every server's recording.
BOARD_WRITE_MSG = """\
# Bytes that al5d serve wrote to the SSC-32U, one write each (its recordings:
# al5d serve --record, on the topic /al5d/board_writes).
# When the write returned (CLOCK_REALTIME, as a header's stamp).
builtin_interfaces/Time stamp
# When its last byte reaches the board, by the driver's account of the wire (same clock).
builtin_interfaces/Time arrival
# The bytes, as written: group moves, stops (ESC first), queries.
uint8[] data
"""
#: Little-endian CDR: its encapsulation header, then two Times (sec, nanosec) and the
#: length of `data` (every field 4-byte aligned, so no padding).
_CDR_HEADER = b"\x00\x01\x00\x00"
_BOARD_WRITE_HEAD = struct.Struct("<iIiII")
#: At most this many messages wait for the file: a disk slower than the messages for long
#: loses the newest (counted), not the server's memory.
BACKLOG = 100_000
#: What the file's thread has taken is written out this long after, at most (the chunk
#: being filled is ended and written; behind a disk that falls behind, later): a process
#: killed, or a bridge that crashed, leaves a file cut short that `al5d replay --partial`
#: reads up to then. In memory until the chunk was full (a megabyte), a short recording of
#: a killed bridge was 0 bytes.
FLUSH_EVERY_S = 1.0
_SEPARATOR = "=" * 80
_PRIMITIVES = frozenset(
    [
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    ]
)


class RecordingError(Exception):
    """A recording cannot be made: choose a file that can be written."""


def _share_dir(package: str) -> Path:
    """Where a message package's `.msg` files are: the ament index's word (a ROS install's
    `AMENT_PREFIX_PATH`), else beside its Python package (the venv's prefix, where the
    wheels and the Makefile put them)."""
    with contextlib.suppress(Exception):
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(package))
    module = importlib.import_module(package)
    # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py
    return Path(str(module.__file__)).parents[4] / "share" / package


def _msg_text(type_name: str) -> str:
    if type_name == BOARD_WRITE_TYPE:
        return BOARD_WRITE_MSG
    package, name = type_name.split("/")[0], type_name.split("/")[-1]
    path = _share_dir(package) / "msg" / f"{name}.msg"
    try:
        return path.read_text(encoding="utf-8")
    except OSError as e:
        raise RecordingError(f"the definition of {type_name} is not at {path}: {e}") from e


def _used_types(package: str, text: str) -> list[str]:
    """The message types (`pkg/Type`) the fields of a `.msg` text use, in order."""
    used = []
    for line in text.splitlines():
        words = line.split("#", 1)[0].split()
        if len(words) < 2:
            continue  # blank
        base = re.sub(r"\[.*\]$", "", words[0]).split("<=")[0]
        if base in _PRIMITIVES:
            continue  # constants too: theirs are primitive
        parts = base.split("/")
        used.append(f"{parts[0]}/{parts[-1]}" if len(parts) > 1 else f"{package}/{base}")
    return used


def message_definition(type_name: str) -> str:
    """The `ros2msg` schema of a type (`pkg/msg/Type`), as rosbag2 writes it: its `.msg`
    text, then each type it uses, once, after a line of `=` and `MSG: pkg/Type`."""
    package = type_name.split("/")[0]
    main = _msg_text(type_name)
    parts = [main.rstrip("\n")]
    seen = {f"{package}/{type_name.split('/')[-1]}"}
    todo = _used_types(package, main)
    while todo:
        dep = todo.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        text = _msg_text(dep)
        parts.append(f"{_SEPARATOR}\nMSG: {dep}\n{text.rstrip(chr(10))}")
        todo += _used_types(dep.split("/")[0], text)
    return "\n".join(parts) + "\n"


def board_write_cdr(data: bytes, stamp_ns: int, arrival_ns: int) -> bytes:
    """A BoardWrite message, serialized as DDS would (little-endian CDR)."""
    stamp = divmod(stamp_ns, 1_000_000_000)
    arrival = divmod(arrival_ns, 1_000_000_000)
    head = _BOARD_WRITE_HEAD.pack(stamp[0], stamp[1], arrival[0], arrival[1], len(data))
    return _CDR_HEADER + head + data


#: What the file's thread is handed: a message (channel, bytes, log ns, publish ns,
#: sequence), a board write (bytes, written and arrival, CLOCK_MONOTONIC s), or None: the end.
_Message = tuple[int, bytes, int, int, int]
_BoardWrite = tuple[bytes, float, float]


class RecordFile:
    """An MCAP file being written by a thread of its own; `put` and `board_tap` hand it
    messages and never wait. RecordingError when the file cannot be made."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 (closed by close)
        except OSError as e:
            raise RecordingError(f"cannot write the recording {self.path}: {e.strerror}") from e
        self._writer = Writer(self._file)
        self._writer.start(profile="ros2", library="al5d")
        self._lock = threading.Lock()  # the writer: its channels (any thread), its messages
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._topic_of: dict[int, str] = {}
        self._items: queue.SimpleQueue[_Message | _BoardWrite | None] = queue.SimpleQueue()
        # CLOCK_MONOTONIC -> CLOCK_REALTIME for the board's times (DDS stamps are realtime).
        self._wall_offset_ns = time.time_ns() - time.monotonic_ns()
        self._board_channel: int | None = None
        self._board_seq = 0
        self.counts: Counter[str] = Counter()
        self.dropped = 0
        self.failed: str | None = None
        self._closed = False
        try:  # killed before its first message, it is still an MCAP file (cut short)
            self._file.flush()
        except OSError as e:  # a full disk: the arm goes on
            self._failed(e)
        self._thread = threading.Thread(target=self._run, name="al5d-record", daemon=True)
        self._thread.start()

    def channel(self, topic: str, type_name: str) -> int:
        """The channel of `topic` (registered with its type's schema the first time)."""
        with self._lock:
            if topic in self._channels:
                return self._channels[topic]
            schema = self._schemas.get(type_name)
            if schema is None:
                data = message_definition(type_name).encode()
                schema = self._writer.register_schema(type_name, SchemaEncoding.ROS2, data)
                self._schemas[type_name] = schema
            channel = self._writer.register_channel(topic, MessageEncoding.CDR, schema)
            self._channels[topic] = channel
            self._topic_of[channel] = topic
            return channel

    def record_board(self, topic: str) -> None:
        """Record the bytes `board_tap` is told of on `topic`."""
        self._board_channel = self.channel(topic, BOARD_WRITE_TYPE)

    def put(self, channel: int, data: bytes, log_ns: int, publish_ns: int, seq: int = 0) -> None:
        """Hand a serialized message over (times: CLOCK_REALTIME ns)."""
        if self._items.qsize() >= BACKLOG or self.failed:
            self.dropped += 1
            return
        self._items.put((channel, data, log_ns, publish_ns, seq))

    def board_tap(self, data: bytes, written: float, arrival: float) -> None:
        """One write to the board, as the owner's wire news tells it (only a queue's put)."""
        if self._items.qsize() >= BACKLOG or self.failed:
            self.dropped += 1
            return
        self._items.put((data, written, arrival))

    def _run(self) -> None:
        unflushed = 0.0  # when the first message not yet on disk was written (0: none)
        while True:
            due = unflushed + FLUSH_EVERY_S - time.monotonic() if unflushed else None
            item: _Message | _BoardWrite | None = None
            try:
                item = self._items.get(timeout=None if due is None else max(0.0, due))
                if item is None:
                    return
            except queue.Empty:
                pass  # time to flush
            if self.failed:
                unflushed = 0.0  # nothing more is written: no flush is due
                continue
            try:
                if item is not None:
                    self._write(item)
                    unflushed = unflushed or time.monotonic()
                # Also in a steady stream, which never leaves the queue empty for long.
                if unflushed and time.monotonic() - unflushed >= FLUSH_EVERY_S:
                    unflushed = 0.0
                    with self._lock:
                        self._writer.flush()  # type: ignore[no-untyped-call]
            except Exception as e:  # a full disk, a removed file: the arm goes on
                self._failed(e)

    def _failed(self, e: Exception) -> None:
        self.failed = f"{type(e).__name__}: {e}"
        log.error(
            "recording %s failed (%s): nothing more is recorded; the arm goes on",
            self.path,
            self.failed,
        )

    def _write(self, item: _Message | _BoardWrite) -> None:
        if len(item) == 3:
            data, written, arrival = item
            channel = self._board_channel
            if channel is None:
                return
            stamp = int(written * 1e9) + self._wall_offset_ns
            cdr = board_write_cdr(data, stamp, int(arrival * 1e9) + self._wall_offset_ns)
            self._board_seq += 1
            message: _Message = (channel, cdr, stamp, stamp, self._board_seq)
        else:
            message = item
        channel, cdr, log_ns, publish_ns, seq = message
        with self._lock:
            self._writer.add_message(
                channel_id=channel,
                log_time=log_ns,
                data=cdr,
                publish_time=publish_ns,
                sequence=seq & 0xFFFFFFFF,
            )
        self.counts[self._topic_of[channel]] += 1

    def close(self) -> None:
        """Write what was handed over, the summary, and close the file (again: nothing)."""
        if self._closed:
            return
        self._closed = True
        self._items.put(None)
        self._thread.join()
        try:
            with self._lock:
                self._writer.finish()  # type: ignore[no-untyped-call]
            self._file.close()
        except Exception as e:
            self.failed = self.failed or f"{type(e).__name__}: {e}"
            log.error("recording %s: its end could not be written (%s)", self.path, e)
            with contextlib.suppress(OSError):
                self._file.close()  # what is left in its buffer cannot be written either
        if self.dropped:
            log.warning("recording %s: %d messages were not recorded", self.path, self.dropped)

    def summary(self) -> str:
        """One line: how many messages of which topic are in the file."""
        each = ", ".join(f"{topic} {n}" for topic, n in sorted(self.counts.items()))
        total = sum(self.counts.values())
        return f"{self.path}: {total} messages ({each or 'none'})"
