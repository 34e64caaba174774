"""Several servers flooded at once on one machine, busy loops beside them (issue 23's rig).

    python -m al5d_rig.contention [--servers 3] [--seconds 20] [--rate 5000] [--busy 2]
    python -m al5d_rig.contention --goals [--seconds 20] [--rate 100] [--busy 2]

Each server is `al5d serve` in its own process on its own board (an emulator
process on a pty) and its own ROS domain, flooded by its own client process
(`flood_client.py`); one process per server (this module with `--arm I`) stops
and releases it every quarter second, by service and by topic in turn, as a
non-flooding peer (`loadrig.flood`), while `result_counter` counts every outcome
at the default priority. Busy loops (`python3 -c 'while True: pass'`) take what
CPU is left, and `stallprobe` notes the host's own stalls, matched to the slow
stops. Prints one line of JSON per server and, from the main process, the whole
as one JSON document.

With `--goals`: one server at 9600 baud, a MoveIt-like client sending
FollowJointTrajectory goals at `rate` a second, each preempting the last
(`goal_flood_client.py`), and stops by service and by topic every half second:
every stop must reach the board, and every goal must be answered.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from al5d_rig.proc import Proc, dies_with_parent, said
from al5d_rig.result_counter import ResultCounter
from al5d_rig.stallprobe import Stalls

#: A stop slower than this is listed with the host's stalls around it.
SLOW_MS = 40.0

MODULE = "al5d_rig.contention"  # its arms run it: python -m MODULE --arm I
BUSY_LOOP = "while True: pass"


def busy_loops(n: int) -> list[subprocess.Popen[bytes]]:
    """`n` processes that take a core each, as long as they are let (`ended` ends them)."""
    return [
        subprocess.Popen([sys.executable, "-c", BUSY_LOOP], preexec_fn=dies_with_parent)
        for _ in range(n)
    ]


def ended(procs: list[subprocess.Popen[Any]]) -> None:
    """Kill what still runs of `procs`, and reap them."""
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait(10)


def arm(index: int, seconds: float, rate: float, stops_every_s: float) -> dict[str, Any]:
    """One server under its flood, measured by this process (in the server's ROS domain)."""
    from al5d_rig.boardproc import BoardProcess
    from al5d_rig.loadrig import flood
    from al5d_rig.proc import Proc, patient_config
    from al5d_rig.rospeer import Peer

    link = Path(tempfile.mkdtemp(prefix=f"al5d-contention-{index}-")) / "ssc32u"
    board = BoardProcess(link)
    # A patient link check: this rig measures the stop; the false faults of a board in a
    # starved process are `link_check`'s to count.
    trace = link.with_name("trace.jsonl")
    # Started as a user starts it, at the default priority (its stop path raises its own).
    server = Proc("serve", "--port", str(link), "--config", patient_config(), "--trace", str(trace))
    # This process stands for the board's record (the emulator's, read here) and for an
    # operator's stop button: it runs ahead of the load where the OS allows, so that what
    # is measured is the server's share, not this process's own wait for a core. (The
    # flood's client it starts runs at the default priority: `loadrig.flood`.)
    with contextlib.suppress(OSError):
        if not os.environ.get("AL5D_NONICE"):
            os.nice(-10)
    peer = Peer(results=False, name=f"al5d_contention_peer_{index}")
    # The flood's results are counted at the default priority, as its client would count
    # them; this process only stops, releases and reads the board.
    counter = ResultCounter()
    try:
        server.err.wait_for("STATE: ready", 60)
        peer.wait_for_server()
        for name in ("stop", "release"):  # unmeasured: the services' first answers
            peer.trigger(name)
        print(json.dumps({"ready": index}), flush=True)
        sys.stdin.readline()  # go: every server is ready
        result = flood(
            board,
            peer,
            counter,
            server.popen.pid,
            rate,
            seconds,
            f"c{index}",
            stops_every_s=stops_every_s,
            diagnose=lambda: "\n".join(server.err.drain(0.5)[-15:]),
        )
        out = result.as_dict()
        ids = [f"c{index}-{i}" for i in range(result.sent)]
        unanswered = set(counter.missing(ids))
        missing = [i for i, ident in enumerate(ids) if ident in unanswered]
        out["missing"] = ranges(missing)
        if missing:  # did they reach the server? (its trace is written when it ends)
            server.popen.terminate()
            server.popen.wait(60)
            got = {json.loads(line)[0] for line in trace.read_text().splitlines()}
            out["missing_received"] = sum(f"c{index}-{i}" in got for i in missing)
        out["server_alive"] = server.popen.poll() is None
        # What the server said besides refusing moves (a flood's refusals are most of it).
        said = [line for line in server.err.drain(0.5) if "refused" not in line]
        out["server_said"] = said[-40:]
        # The stop process's own account of its slow stops (when DDS handed it over).
        out["late_stops"] = [line for line in said if "a stop written" in line][-20:]
        return out
    finally:
        counter.close()
        peer.close()
        server.kill()
        board.close()


def goals(seconds: float, rate: float, busy: int, stops_every_s: float = 0.5) -> dict[str, Any]:
    """The goal flood at 9600 baud (one server, in this process's ROS domain)."""
    from std_srvs.srv import Trigger

    from al5d_rig.boardproc import BoardProcess
    from al5d_rig.loadrig import stop_latency_ms
    from al5d_rig.proc import Proc, patient_config
    from al5d_rig.rospeer import Peer, wait_future

    link = Path(tempfile.mkdtemp(prefix="al5d-goals-")) / "ssc32u"
    board = BoardProcess(link)
    server = Proc("serve", "--port", str(link), "--config", patient_config())
    peer = Peer(results=False, name="al5d_goals_peer")
    loops: list[subprocess.Popen[bytes]] = []
    client = subprocess.Popen(
        [sys.executable, "-m", "al5d_rig.goal_flood_client", str(rate), str(seconds)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=dies_with_parent,
    )
    assert client.stdin is not None and client.stdout is not None
    out: dict[str, Any] = {"rate": rate, "seconds": seconds, "busy": busy}
    stops: dict[str, list[float]] = {"service": [], "topic": []}
    missed: list[str] = []
    try:
        server.err.wait_for("STATE: ready", 60)
        peer.wait_for_server()
        for name in ("stop", "release"):
            peer.trigger(name)
        assert json.loads(said(client.stdout)).get("ready")
        loops = busy_loops(busy)
        client.stdin.write("go\n")
        client.stdin.flush()
        t_end = time.monotonic() + seconds
        via = "service"
        while time.monotonic() < t_end - stops_every_s:
            time.sleep(stops_every_s)
            ms = stop_latency_ms(
                board, peer, via, board.baud, f"goals-stop-{len(missed)}-{time.monotonic()}"
            )
            if ms is None:
                missed.append(via)
            else:
                stops[via].append(ms)
            wait_future(peer.services["release"].call_async(Trigger.Request()), 10)
            via = "topic" if via == "service" else "service"
        out.update(json.loads(said(client.stdout)))
        log = server.err.drain(0.5)
        out["stop_service_ms"], out["stop_topic_ms"] = stops["service"], stops["topic"]
        out["stops_missed"] = missed
        out["stop_write_failures"] = [line for line in log if "stop could not be written" in line]
        out["faults"] = [line for line in log if "serial fault" in line][:5]
        out["server_alive"] = server.popen.poll() is None
        out["load1"] = os.getloadavg()[0]
        out["writers"] = board_writers(server)
        return out
    finally:
        ended([client, *loops])
        peer.close()
        server.kill()
        board.close()


def board_writers(server: Proc) -> int | None:
    """How many threads wrote to the board, as the server says when it ends (SIGINT: it
    parks, then ends); None if it did not say."""
    server.popen.send_signal(signal.SIGINT)
    try:
        server.popen.wait(60)
    except subprocess.TimeoutExpired:
        return None
    said = [line for line in server.err.drain(0.5) if "board: " in line and "writes, by" in line]
    if not said:
        said = [line for line in server.err.all if "board: " in line and "writes, by" in line]
    return int(said[-1].rsplit("by ", 1)[1].split()[0]) if said else None


def host_stalls(stalls: Stalls, results: list[dict[str, Any]]) -> dict[str, Any]:
    """What the stall probe saw, and each stop slower than `SLOW_MS` with the longest stall
    of the host that overlapped it."""
    slow = []
    for i, r in enumerate(results):
        for via, t, ms in r.get("stop_at", []):
            if ms > SLOW_MS:
                worst = stalls.during(t, ms / 1000)
                slow.append(
                    {
                        "server": i,
                        "via": via,
                        "ms": round(ms, 1),
                        "host_stall_ms": round(1000 * worst, 1),
                    }
                )
    gaps = sorted(late for _, late in stalls.gaps)
    return {
        "scheduling": stalls.scheduling,
        "steal_s": round(stalls.steal_s, 3),
        "stalls_over_10_ms": sum(g >= 0.010 for g in gaps),
        "longest_stalls_ms": [round(1000 * g, 1) for g in gaps[-5:]],
        "slow_stops": slow,
    }


def ranges(xs: list[int]) -> list[tuple[int, int]]:
    """Consecutive runs of sorted numbers, as (first, last)."""
    out: list[tuple[int, int]] = []
    for x in xs:
        if out and out[-1][1] == x - 1:
            out[-1] = (out[-1][0], x)
        else:
            out.append((x, x))
    return out


def run(
    servers: int, seconds: float, rate: float, busy: int, stops_every_s: float = 0.25
) -> dict[str, Any]:
    """The whole rig: `servers` arms each in a domain of its own, `busy` busy loops."""
    base = random.randint(20, 80) * 2
    loops = busy_loops(busy)
    arms: list[subprocess.Popen[str]] = []
    probe: list[subprocess.Popen[str]] = []  # started once the arms are ready
    try:
        for i in range(servers):
            env = {**os.environ, "ROS_DOMAIN_ID": str(base + i)}
            cmd = [sys.executable, "-m", MODULE, "--arm", str(i), "--seconds", str(seconds)]
            cmd += ["--rate", str(rate), "--stops-every", str(stops_every_s)]
            arms.append(
                subprocess.Popen(
                    cmd,
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                    env=env,
                    preexec_fn=dies_with_parent,
                )
            )
        for each in arms:
            assert each.stdout is not None
            line = said(each.stdout)
            if not line:
                raise RuntimeError(f"an arm of the rig ended before it was ready: {each.args!r}")
        probe.append(
            subprocess.Popen(
                [sys.executable, "-m", "al5d_rig.stallprobe"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                preexec_fn=dies_with_parent,
            )
        )
        t0 = time.monotonic()
        for each in arms:
            assert each.stdin is not None
            each.stdin.write("go\n")
            each.stdin.flush()
        results = []
        for each in arms:
            assert each.stdout is not None
            line = said(each.stdout)
            results.append(json.loads(line) if line else {"error": "ended without a result"})
            each.wait(60)
        load = os.getloadavg()[0]
        stalls = Stalls.of(probe[0].communicate(timeout=60)[0])
        return {
            "servers": results,
            "seconds": time.monotonic() - t0,
            "load1": load,
            "host": host_stalls(stalls, results),
        }
    finally:
        ended([*arms, *probe, *loops])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--servers", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--rate", type=float, default=5000.0)
    parser.add_argument("--busy", type=int, default=2)
    parser.add_argument("--stops-every", type=float, default=0.25)
    parser.add_argument("--goals", action="store_true", help="the trajectory-goal flood")
    parser.add_argument("--arm", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.goals:
        os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(20, 80) * 2))
        print(json.dumps(goals(args.seconds, args.rate, args.busy)), flush=True)
        return 0
    if args.arm is not None:
        print(json.dumps(arm(args.arm, args.seconds, args.rate, args.stops_every)), flush=True)
        return 0
    print(json.dumps(run(args.servers, args.seconds, args.rate, args.busy, args.stops_every)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
