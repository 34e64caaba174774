"""What the emulated board received: one record per line, with its time of effect.

The records have a lock of their own: an observer that waits for a record (a
test, the demo) never holds up the board, whose answers are due within
milliseconds.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from dataclasses import dataclass

from al5d.clock import Deadline
from al5d.ssc32u import protocol as p

#: Where a record's line came from.
SERIAL = "serial"  # received on the serial link
STARTUP = "startup"  # a command of the startup string, run at power-up
RESET = "reset"  # not a line: the board restarted here


@dataclass(frozen=True, slots=True)
class Record:
    """One line as the board received it, with its time of effect (the CR's arrival)."""

    t_effect: float
    raw: bytes
    commands: tuple[p.Command, ...]
    ignored: str | None = None  # why the board did nothing with it
    source: str = SERIAL

    @property
    def accepted(self) -> bool:
        return self.ignored is None

    def to_json(self) -> str:
        """One line for a record stream (`al5d emulator --record`): time, bytes, why ignored,
        and where the line came from when not from the serial link."""
        data: dict[str, object] = {
            "t": round(self.t_effect, 6),
            "raw": self.raw.decode("latin-1"),
            "ignored": self.ignored,
        }
        if self.source != SERIAL:
            data["source"] = self.source
        return json.dumps(data)

    @classmethod
    def from_json(cls, line: str) -> Record:
        """A record read back from a stream; its commands parsed again from its bytes."""
        data = json.loads(line)
        raw = data["raw"].encode("latin-1")
        parsed = p.parse_line(raw)
        commands = () if isinstance(parsed, p.Unrecognized) else tuple(parsed)
        return cls(data["t"], raw, commands, data["ignored"], data.get("source", SERIAL))


Answer = tuple[float, bytes]  # (when its last byte is due at the client, the bytes)


class RecordLog:
    """Every line the board received, in order, and the listeners told of each."""

    def __init__(self) -> None:
        self._changed = threading.Condition(threading.Lock())
        self._records: list[Record] = []
        #: Called with each new record, in the board's thread: keep it short.
        self.record_listeners: list[Callable[[Record], None]] = []

    @property
    def records(self) -> list[Record]:
        with self._changed:
            return list(self._records)

    def clear_records(self) -> None:
        with self._changed:
            self._records.clear()

    def wait_for(
        self, predicate: Callable[[list[Record]], bool], timeout: float = 5.0
    ) -> list[Record]:
        """Wait until `predicate(records)` holds; return the records (raises TimeoutError).

        The predicate sees a copy, outside every lock of the board.
        """
        deadline = Deadline(timeout)
        while True:
            with self._changed:
                seen = len(self._records)
                records = list(self._records)
            if predicate(records):
                return records
            with self._changed:
                while len(self._records) == seen:
                    if deadline.expired:
                        raise TimeoutError(f"emulator: condition not met in {timeout} s")
                    self._changed.wait(deadline.left())

    def note(self, rec: Record) -> None:
        """Add a record (the link notes lines it cancelled or could not hear)."""
        with self._changed:
            self._records.append(rec)
            self._changed.notify_all()
        for listener in self.record_listeners:
            listener(rec)
