"""The stop process (`al5d.ros.stopproc`, `al5d.ssc32u.stopline`): the STOP is written by a
process of its own, whatever the server's threads are doing; the server then obeys the
stop as any other, and no move of its own reaches the board after that STOP.

The server is frozen with SIGSTOP to stand for the worst a busy host can do to it (its
threads never scheduled): the stop must reach the board all the same."""

from __future__ import annotations

import contextlib
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Record
from al5d_rig.proc import Proc, patient_config
from al5d_rig.rospeer import Peer, wait_until
from al5d_rig.served import StopBursts


@dataclass
class Served:
    emu: Emulator
    proc: Proc
    peer: Peer

    @property
    def pid(self) -> int:
        return self.proc.popen.pid

    def stop_process(self) -> int:
        """The pid of the server's stop process."""
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            with contextlib.suppress(OSError):
                cmdline = (entry / "cmdline").read_bytes().split(b"\0")
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                if ppid == self.pid and b"al5d.ros.stopproc" in cmdline:
                    return int(entry.name)
        raise AssertionError("the server has no stop process")

    def stops_since(self, n: int) -> list[bytes]:
        return [r.raw for r in self.emu.records[n:] if r.raw.startswith(b"STOP")]

    def moves_after_first_stop(self, n: int) -> list[bytes]:
        records = self.emu.records[n:]
        first = next(i for i, r in enumerate(records) if r.raw.startswith(b"STOP"))
        return [
            r.raw for r in records[first:] if any(isinstance(c, p.GroupMove) for c in r.commands)
        ]

    def wait_stopped(self) -> None:
        self.proc.err.wait_for("STATE: stopped", 20)


@pytest.fixture
def served(config: ArmConfig, tmp_path: Path) -> Iterator[Served]:
    link = tmp_path / "ssc32u"
    emu = Emulator(config, link=link).start()
    proc = Proc("serve", "--port", str(link), "--config", patient_config(), "--log-level", "INFO")
    peer = Peer()
    try:
        proc.err.wait_for("STATE: ready", 60)
        peer.wait_for_server()
        peer.first_stop_answer()
        yield Served(emu, proc, peer)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.popen.pid, signal.SIGCONT)
        peer.close()
        proc.kill()
        emu.close()


def long_move_running(served: Served, ident: str) -> int:
    """A 6 s move under way on the board; the index of the record after it (a stop's STOPs
    before it may still be on their way when this is sent)."""
    n = len(served.emu.records)
    served.peer.send(ident, "move", time_ms=6000, base=80, shoulder=60, elbow=30)

    def index(records: list[Record]) -> int | None:
        return next((i for i in range(n, len(records)) if b"T6000" in records[i].raw), None)

    records = served.emu.wait_for(lambda rs: index(rs) is not None, 10)
    at = index(records)
    assert at is not None
    return at + 1


def test_a_frozen_server_is_stopped_by_its_stop_process(served: Served) -> None:
    """SIGSTOP the server mid-move: the stop service is answered, and the STOP written, by
    the stop process alone; once the server runs again it has obeyed that stop: the move
    cancelled by it, the arm locked, no move of its own after the STOP, one burst of STOPs."""
    n = long_move_running(served, "long")
    os.kill(served.pid, signal.SIGSTOP)
    try:
        # Moves sent while it is frozen wait in DDS for it; sent before the stop, they are
        # cancelled by it (rule 2) once the server reads them.
        for i in range(5):
            served.peer.send(f"behind-{i}", "move", base=-40 + i)
        bursts = StopBursts(served.peer, served.proc)
        answer = served.peer.trigger("stop")
        assert answer.success, answer.message
        served.emu.wait_for(lambda rs: any(r.raw.startswith(b"STOP") for r in rs[n:]), 10)
        # Still frozen: nothing but the stop process can have written that.
        assert Path(f"/proc/{served.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "T"
    finally:
        os.kill(served.pid, signal.SIGCONT)
    assert served.peer.result("long").reason == "cancelled by stop"
    served.wait_stopped()
    for i in range(5):
        outcome = served.peer.result(f"behind-{i}")
        assert outcome.outcome in ("cancelled", "refused"), outcome
    served.peer.send("locked", "move", base=0)
    assert "send release first" in served.peer.result("locked").reason
    time.sleep(0.5)  # whatever the server might still write, it has written by now
    assert served.moves_after_first_stop(n) == []
    # One burst a stop: the server did not write it again.
    bursts.check(lambda: len(served.stops_since(n)))


def test_a_stop_on_the_topic_is_written_once_whoever_sees_it_first(served: Served) -> None:
    """A stop on the instruction topic is seen by the node `al5d` (in order) and the stop
    process's watcher (at once): written once, answered once."""
    for rep in range(5):
        n = long_move_running(served, f"move-{rep}")
        bursts = StopBursts(served.peer, served.proc)
        served.peer.send(f"stop-{rep}", "stop")
        assert served.peer.result(f"stop-{rep}").outcome == "done"
        assert served.peer.result(f"move-{rep}").reason == "cancelled by stop"
        wait_until(lambda n=n: len(served.stops_since(n)) >= 6, 10, "the STOPs")
        time.sleep(0.3)
        bursts.check(lambda n=n: len(served.stops_since(n)), on_topic=1)
        assert served.peer.trigger("release").success


def test_when_the_stop_process_ends_the_server_serves_the_stop_itself(served: Served) -> None:
    os.kill(served.stop_process(), signal.SIGKILL)
    served.proc.err.wait_for("the stop process ended", 20)
    n = long_move_running(served, "after")
    deadline = time.monotonic() + 20
    while True:  # the server's own stop service may take a moment to be found
        try:
            answer = served.peer.trigger("stop")
            break
        except AssertionError:
            if time.monotonic() > deadline:
                raise
    assert answer.success, answer.message
    assert served.peer.result("after").reason == "cancelled by stop"
    wait_until(lambda: len(served.stops_since(n)) >= 6, 10, "the STOPs")


def test_a_release_sent_after_the_stop_is_judged_after_it(served: Served) -> None:
    """The stop process answers a stop before the server has obeyed it. A release (or a move)
    the server takes in that moment waits for that stop: the release unlocks the arm (it
    is not refused as "nothing to release" and then undone by the stop), a move sent in
    between is refused. Frozen, the server takes them all at once when it runs again."""
    from std_srvs.srv import Trigger

    os.kill(served.pid, signal.SIGSTOP)
    try:
        assert served.peer.trigger("stop").success
        served.peer.send("between", "move", base=10)
        release = served.peer.services["release"].call_async(Trigger.Request())
        time.sleep(0.5)  # the release is in the server's socket before it runs again
    finally:
        os.kill(served.pid, signal.SIGCONT)
    wait_until(release.done, 20, "the release's answer")
    answer = release.result()
    assert answer.success, answer.message
    assert served.peer.result("between").outcome == "refused"  # locked, whichever came first
    served.peer.send("after", "move", base=-10)
    assert served.peer.result("after").outcome == "done"
