"""The load suite: floods over real DDS with stops and releases mixed in (issue 9).

`al5d serve` in its own process on a board in its own process; the flood from a
third; this process stops and releases every half second and counts every
outcome. Every instruction must get exactly one outcome, every stop must reach
the board, and the server's threads and memory must stay flat. The stop's
latency under each flood is written to `build/reliability/load.json` (its
target, checked in `make soak`: within 50 ms of the quiet figure at p99).
"""

from __future__ import annotations

import json
import signal
import statistics
from collections.abc import Iterator
from pathlib import Path

import pytest

from al5d_rig.boardproc import BoardProcess
from al5d_rig.loadrig import Counter, FloodResult, flood, quiet_stops
from al5d_rig.proc import Proc
from al5d_rig.rospeer import Peer

pytestmark = pytest.mark.solo  # load suites: alone (see pyproject.toml)

OUT = Path(__file__).resolve().parents[1] / "build" / "reliability"
RATES = (2000, 5000, 10000)
SECONDS = 3.0
#: Bounds that only a stop queued behind instruction traffic breaks, far above what is
#: measured (`make soak` prints the figures): the defect moved the median (1.13 s by
#: service, 2.35 s by topic at 10,000/s before the safety node and the stop watcher); a
#: busy machine moves the tail alone (one stop of 12 took 985 ms beside two busy loops,
#: and one of two 512 ms): the median is of a flood's stops both ways together.
MEDIAN_BOUND_MS = 500
BOUND_MS = 5000


@pytest.fixture(scope="module")
def loaded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[BoardProcess, Proc, Peer]]:
    link = tmp_path_factory.mktemp("load") / "ssc32u"
    board = BoardProcess(link)
    # The trace (written when the server ends) tells an instruction that never reached the
    # server from an outcome that never reached this process.
    trace = link.with_name("trace.jsonl")
    server = Proc("serve", "--port", str(link), "--log-level", "INFO", "--trace", str(trace))
    peer = Peer(results=False, name="al5d_load_peer")
    try:
        server.err.wait_for("STATE: ready", 30)
        peer.wait_for_server()
        # Unmeasured: the first answer of a service may wait for its reader to be discovered.
        for name in ("stop", "release"):
            peer.trigger(name)
        yield board, server, peer
    finally:
        peer.close()
        if MISSING:
            server.popen.terminate()
            server.popen.wait(60)
            received = {json.loads(line)[0] for line in trace.read_text().splitlines()}
            OUT.mkdir(parents=True, exist_ok=True)
            (OUT / "missing.json").write_text(
                json.dumps({i: i in received for i in MISSING}, indent=0)
            )
        server.kill()
        board.close()


RESULTS: dict[str, object] = {}
#: Instructions of a flood with no outcome (build/reliability/missing.json says, at the end,
#: whether each reached the server).
MISSING: list[str] = []


def test_quiet_stops(loaded: tuple[BoardProcess, Proc, Peer]) -> None:
    board, _, peer = loaded
    quiet = quiet_stops(board, peer, 10)
    # The software's share: after the request, never before (a STOP of an earlier stop
    # still on the wire once passed for this one's), and not behind anything.
    assert all(0 < ms < BOUND_MS for ms in quiet["service"] + quiet["topic"]), quiet
    RESULTS["quiet"] = quiet


@pytest.mark.parametrize("rate", RATES)
def test_a_flood_loses_nothing_and_the_stop_gets_through(
    loaded: tuple[BoardProcess, Proc, Peer], rate: int
) -> None:
    board, server, peer = loaded
    counter = RESULTS.setdefault("counter", Counter(peer))
    assert isinstance(counter, Counter)
    result: FloodResult = flood(
        board,
        peer,
        counter,
        server.popen.pid,
        rate,
        SECONDS,
        f"f{rate}",
        diagnose=lambda: "\n".join(server.err.drain(0.5)[-15:]),
        drain_s=60,  # within the test's timeout, so that what is missing is said
    )
    ids = (f"f{rate}-{n}" for n in range(result.sent))
    MISSING.extend(i for i in ids if i not in counter.seen)
    RESULTS[str(rate)] = result.as_dict()
    if result.notes:  # whole, where pytest's report would shorten them
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / f"notes-{rate}.txt").write_text("\n\n".join(result.notes))
    assert result.sent == int(rate * SECONDS)
    assert result.failed_publishes == 0
    assert result.lost == 0 and result.duplicates == 0, (result.lost, MISSING[:10])
    assert result.stops_missed == 0, result.notes
    assert result.stop_service_ms and result.stop_topic_ms
    stops = result.stop_service_ms + result.stop_topic_ms
    assert statistics.median(stops) < MEDIAN_BOUND_MS and max(stops) < BOUND_MS, (
        stops,
        result.notes,
    )
    assert (result.stop_outcomes, result.stop_duplicates) == (len(result.stop_ids), 0)
    assert result.after["Threads"] == result.before["Threads"]
    assert result.after["VmRSS"] - result.before["VmRSS"] < 30_000  # kB: flat, not growing
    assert server.popen.poll() is None


def test_one_thread_wrote_every_byte_of_the_floods(
    loaded: tuple[BoardProcess, Proc, Peer],
) -> None:
    """The owner's transport records the threads that write to it; the server says so as it
    ends: every write of the floods, stops and all, came from one thread."""
    _, server, _ = loaded
    server.popen.send_signal(signal.SIGINT)  # parks, then ends
    assert server.wait(60) == 0
    lines = server.err.drain(5.0)  # every line it said, to its end
    said = [line for line in lines if "board: " in line and "writes, by" in line]
    assert len(said) == 1, lines[-20:]
    writes = int(said[0].split("board: ")[1].split()[0])
    # Hundreds of writes, so that "by 1 thread" says something: how many the floods get
    # written varies with how long each stop holds the arm (871 in a CI run on an idle
    # host, over 1,000 in others; 650 where a serial fault cut a flood short; 486 in a
    # CI run beside two busy loops).
    assert writes > 200 and said[0].endswith("by 1 thread"), said


def test_write_the_figures() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    figures = {k: v for k, v in RESULTS.items() if k != "counter"}
    if not figures:
        pytest.fail("no flood ran before this one")
    (OUT / "load.json").write_text(json.dumps(figures, indent=1))
