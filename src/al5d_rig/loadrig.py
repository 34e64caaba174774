"""Floods over real DDS, and the emergency stop measured under them (issue 9's load suite).

The server is `al5d serve` in its own process on an emulated board in this
process (so the board's record is at hand); the flood comes from a third
process (`flood_client.py`); this process also calls the stop service and
counts every outcome on `/al5d/result`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Record
from al5d_rig.proc import dies_with_parent, said
from al5d_rig.rospeer import Peer, wait_future, wait_until

#: How the board's record notes an ESC (the first byte of every stop's write).
ESC_NOTE = "cancelled by ESC"


class Board(Protocol):
    """What the suite reads of a board: the in-process emulator or `BoardProcess`."""

    baud: int

    @property
    def records(self) -> list[Record]: ...

    def wait_for(
        self, predicate: Callable[[list[Record]], bool], timeout: float = ...
    ) -> list[Record]: ...


#: A reader that keeps every result it has not handed over: what we count must not be
#: lost on our side of the wire.
QOS_ALL = QoSProfile(
    history=HistoryPolicy.KEEP_ALL, depth=1, reliability=ReliabilityPolicy.RELIABLE
)


def proc_status(pid: int) -> dict[str, int]:
    """Resident memory (kB) and threads of a process, from /proc."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "Threads"):
            out[key] = int(value.split()[0])
    return out


class Outcomes(Protocol):
    """What a flood asks of the results it brings (`Counter`, `ResultCounter`)."""

    def heard(self, prefix: str) -> bool: ...

    def count(self, ids: list[str]) -> tuple[int, int]: ...


class Counter:
    """Every result on /al5d/result, by id: how many came for each."""

    def __init__(self, peer: Peer) -> None:
        self.lock = threading.Lock()
        self.seen: dict[str, int] = {}
        #: The ids with more than one outcome.
        self.repeated: set[str] = set()
        self.reasons: dict[str, str] = {}
        peer.read(InstructionResult, "/al5d/result", self._on, QOS_ALL)

    def _on(self, msg: InstructionResult) -> None:
        with self.lock:
            times = self.seen[msg.id] = self.seen.get(msg.id, 0) + 1
            if times == 2:
                self.repeated.add(msg.id)
            self.reasons[msg.id] = f"{msg.outcome}: {msg.reason}"

    def heard(self, prefix: str) -> bool:
        """Has an outcome come for an id that begins with `prefix`?"""
        with self.lock:
            return any(i.startswith(prefix) for i in self.seen)

    def count(self, ids: list[str]) -> tuple[int, int]:
        """(ids with an outcome, ids with more than one)."""
        with self.lock:
            got = sum(i in self.seen for i in ids)
        return got, self.repeated_among(set(ids))

    def repeated_among(self, ids: set[str]) -> int:
        """How many of `ids` had more than one outcome."""
        with self.lock:
            return sum(i in ids for i in self.repeated)

    def missing(self, ids: Iterable[str]) -> list[str]:
        """The ids with no outcome."""
        with self.lock:
            return [i for i in ids if i not in self.seen]


@dataclass
class FloodResult:
    rate: float
    seconds: float
    sent: int = 0
    failed_publishes: int = 0
    #: Publishes the writer refused (its history full of samples not acked) and that the
    #: client sent again.
    publish_retries: int = 0
    outcomes: int = 0
    duplicates: int = 0
    drained_s: float = 0.0
    stop_service_ms: list[float] = field(default_factory=list)
    stop_topic_ms: list[float] = field(default_factory=list)
    #: Every measured stop as (via, when it was sent on the monotonic clock, ms).
    stop_at: list[tuple[str, float, float]] = field(default_factory=list)
    stops_missed: int = 0
    #: The stops sent on the topic, and how many of them got one outcome, and more than one.
    stop_ids: list[str] = field(default_factory=list)
    stop_outcomes: int = 0
    stop_duplicates: int = 0
    notes: list[str] = field(default_factory=list)
    before: dict[str, int] = field(default_factory=dict)
    after: dict[str, int] = field(default_factory=dict)

    @property
    def lost(self) -> int:
        return self.sent - self.outcomes

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "lost": self.lost}


def first_stop_after(emu: Board, t: float, timeout: float = 10.0) -> Record:
    """The first STOP of the first stop whose ESC took effect after `t` (raises TimeoutError).

    Bound to the ESC that begins the stop's write: a STOP of an earlier stop still on
    the wire at `t` (six take 38.5 ms at 9600 baud) is not this one's."""

    def find(records: list[Record]) -> Record | None:
        esc = next(
            (i for i, r in enumerate(records) if r.t_effect > t and r.ignored == ESC_NOTE), None
        )
        if esc is None:
            return None
        return next((r for r in records[esc + 1 :] if r.raw.startswith(b"STOP")), None)

    found = find(emu.wait_for(lambda rs: find(rs) is not None, timeout))
    assert found is not None
    return found


#: What the board received around each stop that `stop_latency_ms` did not find.
MISSED: list[str] = []


def board_after(emu: Board, t: float) -> str:
    """The lines the board received from just before `t` on, as the note of a missed stop."""
    records = emu.records
    late = [i for i, r in enumerate(records) if r.t_effect > t - 0.05]
    first = late[0] if late else len(records)
    shown = records[max(0, first - 3) : first + 40]
    return "\n".join(f"{r.t_effect - t:+.4f} {r.raw!r} {r.ignored or ''}" for r in shown)


def stop_latency_ms(emu: Board, peer: Peer, via: str, baud: int, ident: str = "") -> float | None:
    """Stop by service or topic (with `ident`); ms until the first STOP is in effect, minus
    ESC and its wire."""
    t0 = time.monotonic()
    if via == "service":
        future = peer.services["stop"].call_async(Trigger.Request())
    else:
        peer.pub.publish(ArmInstruction(instruction="stop", id=ident or f"stop-{t0}"))
    try:
        rec = first_stop_after(emu, t0)
    except TimeoutError:
        MISSED.append(board_after(emu, t0))
        return None
    if via == "service":
        wait_future(future, 10)
    wire = p.wire_time_s(len(p.CANCEL) + len(rec.raw) + len(p.CR), baud)
    return (rec.t_effect - t0 - wire) * 1000


def quiet_stops(emu: Board, peer: Peer, trials: int) -> dict[str, list[float]]:
    """`trials` stops by service and as many by topic, each released, with nothing else
    going on: the figure the stops under a flood are judged against."""
    quiet: dict[str, list[float]] = {"service": [], "topic": []}
    time.sleep(0.5)  # what came before (a stop, its read-back) off the wire
    for via in ("service", "topic") * trials:
        ms = stop_latency_ms(emu, peer, via, emu.baud)
        assert ms is not None, f"a stop via {via} never reached the board"
        quiet[via].append(ms)
        peer.trigger("release")
        time.sleep(0.1)  # the stop's six STOPs off the wire before the next stop
    return quiet


#: A stop slower than this gets a note with what the server said (what made it slow).
SLOW_STOP_MS = 250.0


def default_priority() -> None:
    """In a child before it runs: the default priority (nice 0), whatever its parent's,
    and killed with its parent (`dies_with_parent`)."""
    os.setpriority(os.PRIO_PROCESS, 0, 0)
    dies_with_parent()


def flood(
    emu: Board,
    peer: Peer,
    counter: Outcomes,
    server_pid: int,
    rate: float,
    seconds: float,
    prefix: str,
    stops_every_s: float = 0.5,
    client_flags: tuple[str, ...] = (),
    diagnose: Callable[[], str] = lambda: "",
    drain_s: float = 120.0,
) -> FloodResult:
    """Flood at `rate` for `seconds`; meanwhile stop (service and topic in turn) and release
    every `stops_every_s`, measuring each stop on the board."""
    result = FloodResult(rate, seconds, before=proc_status(server_pid))
    client = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "al5d_rig.flood_client",
            str(rate),
            str(seconds),
            prefix,
            "--ack-s",
            str(drain_s),
            *client_flags,
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),
        # A client (MoveIt, a script) runs at the default priority, whatever this process's.
        preexec_fn=default_priority,
    )
    assert client.stdin is not None and client.stdout is not None
    try:
        assert json.loads(said(client.stdout)).get("ready")
        # Both directions matched: the server answered one of the client's probes.
        probe = f"{prefix}-probe-"
        wait_until(lambda: counter.heard(probe), 60, "a probe of the flood client answered")
        client.stdin.write("go\n")
        client.stdin.flush()
        t_go = time.monotonic()
        t_end = t_go + seconds
        via = "service"
        tried = 0
        # At least two stops each way, however long a stop and its release take on a busy
        # machine (then the last may come as the sender ends, its moves still queued): a
        # median of two is the mean, which one slow stop moves (beside two busy loops, one
        # of 1,976 ms with one of 0.5 ms, the only two of a flood).
        while time.monotonic() < t_end - stops_every_s or tried < 4:
            tried += 1
            time.sleep(stops_every_s)
            ident = f"{prefix}-stop-{len(result.stop_ids)}" if via == "topic" else ""
            if ident:
                result.stop_ids.append(ident)
            t_stop = time.monotonic()
            ms = stop_latency_ms(emu, peer, via, emu.baud, ident)
            if ms is None:
                result.stops_missed += 1
                sent = time.strftime("%H:%M:%S", time.localtime(time.time() - 10))
                result.notes.append(
                    f"a stop via {via} sent at {sent} never reached the board:\n{diagnose()}"
                    f"\nthe board from 50 ms before it:\n{MISSED[-1]}"
                )
            else:
                (result.stop_service_ms if via == "service" else result.stop_topic_ms).append(ms)
                result.stop_at.append((via, t_stop, ms))
                if ms > SLOW_STOP_MS:
                    result.notes.append(f"a stop via {via} took {ms:.0f} ms:\n{diagnose()}")
            wait_future(peer.services["release"].call_async(Trigger.Request()), 10)
            via = "topic" if via == "service" else "service"
        done = json.loads(said(client.stdout))
        result.sent, result.failed_publishes = done["sent"], done["failed"]
        result.publish_retries = done["retried"]
        if not done.get("acked", True):
            result.notes.append(
                "the flood's client ended before the server acknowledged all it sent: "
                "what it had not is lost with it, on the sender's side"
            )
        t_sent = t_go + done["seconds"]  # its last publish; its wait for acks is in the drain
        # The moves still queued get their outcomes from more stops, not a minute of moving:
        # the server may not have taken the whole flood yet (the sender was slowed).
        ids = [f"{prefix}-{i}" for i in range(result.sent)]
        deadline = t_sent + drain_s
        while counter.count(ids)[0] < len(ids) and time.monotonic() < deadline:
            wait_future(peer.services["stop"].call_async(Trigger.Request()), 10)
            wait_future(peer.services["release"].call_async(Trigger.Request()), 10)
            time.sleep(0.5)
        result.drained_s = time.monotonic() - t_sent
        result.outcomes, result.duplicates = counter.count(ids)
        result.stop_outcomes, result.stop_duplicates = counter.count(result.stop_ids)
        time.sleep(0.5)
        result.after = proc_status(server_pid)
    finally:
        client.kill()
        client.wait(10)
    return result
