"""A bad network under a working client: random cuts, delays and losses on the cable between
the laptop and the arm's host while a client on the laptop sends moves and straight-line
moves and, now and then, a stop; then what each side saw, checked against the promises.

Shared by tests/test_network_faults.py (a few faults) and bench/network_faults.py (50,
`make soak`). The promises (issue 44's):

- every request has exactly one outcome at the server (an observer on the arm's host reads
  them all, beside the server, where the cable cannot lose them);
- no request its sender gave up on (the client said it lost contact, or had no outcome)
  moves the arm: the server refused it, cancelled it, or it never came; it may have been
  done only before the fault began;
- a stop asked while the link is up is obeyed (the server's state says STOPPED).
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime

from al5d_rig.netrig import Hosts
from al5d_rig.proc import AL5D, Lines, patient_config

CMD_S = 60.0
#: How long a fault lasts: a cut is short or long against the lease (1 s).
CUT_S = (0.4, 3.0)
IMPAIRED_S = (2.0, 5.0)
CLEAR_S = (1.0, 2.5)
#: The worst the issue asks for.
DELAY_MS = (50, 500)
LOSS_PERCENT = (5, 30)
#: A stop asked while the link is up is obeyed within this (the delay both ways, lost
#: frames sent again, the client's retries); the figure is printed.
STOP_OBEYED_S = 5.0

#: The laptop's client: argv[1] the seed. Prints `req ID EPOCH TIMEOUT TEXT` before each
#: request and `res ID RESULT EPOCH` after (RESULT: done, refused, cancelled, lost,
#: nooutcome); for each line read, a stop (`stop ASKED ANSWERED OK|raised`) and a release.
LAPTOP = """
import random, sys, threading, time
from al5d.arm.instruction import PRESET_NAMES, parse_instruction
from al5d.ros.client import Client, LostContact, NoOutcome
c = Client(wait_s=60)
c.wait_for_server(60)
c.execute("ready", timeout=60)
lock = threading.Lock()
def say(*words):
    with lock:
        print(*words, flush=True)
import logging
class Unanswered(logging.Handler):  # the client's word that a stop has had no answer yet
    def emit(self, record):
        said = record.getMessage()
        if said.startswith("stop [") and "]: no answer in" in said:
            say("unanswered", time.time())
logging.getLogger("al5d").addHandler(Unanswered())
quiet = threading.Event()  # set from a stop to its release: no move asked meanwhile
def stops():
    for _ in sys.stdin:
        quiet.set()
        asked = time.time()
        try:
            ok = c.stop(timeout=10).success
            say("stop", asked, time.time(), "ok" if ok else "refused")
        except Exception as e:
            say("stop", asked, time.time(), "raised", type(e).__name__)
        time.sleep(0.3)
        try:
            c.release(timeout=10)
        except Exception:
            pass
        quiet.clear()
threading.Thread(target=stops, daemon=True).start()
say("ready")
rng = random.Random(int(sys.argv[1]))
while True:
    if c.lost_contact() is not None or quiet.is_set():
        time.sleep(0.05)
        continue
    ms = rng.choice((300, 800, 1500))
    if rng.random() < 0.3:
        x, z = rng.uniform(180, 260), rng.uniform(80, 160)
        text = f"move_to x={x:.0f} y=0 z={z:.0f} pitch=-30 path=line time={ms}"
    else:
        text = f"move base={rng.uniform(-60, 60):.0f} elbow={rng.uniform(60, 100):.0f} time={ms}"
    instr = parse_instruction(text, PRESET_NAMES)
    timeout = ms / 1000 + 8
    say("req", instr.id, time.time(), timeout, text)
    try:
        result = c.execute(instr, timeout=timeout).result.value
    except LostContact:
        result = "lost"
    except NoOutcome:
        result = "nooutcome"
    say("res", instr.id, result, time.time())
"""

#: Beside the server: every outcome (`out ID RESULT EPOCH REASON`) and state (`state S EPOCH`);
#: `ready` once its reader of outcomes has matched the server's writer and the server's
#: latched state has come (the server has found it: what it publishes from then reaches it).
OBSERVER = """
import threading, time
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, HistoryPolicy, ReliabilityPolicy, DurabilityPolicy
from al5d_interfaces.msg import InstructionResult
from std_msgs.msg import String
from al5d.ros.dds import start_context
from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATCHED, QOS_STREAM
import rclpy
context = start_context()
node = Node("al5d_fault_observer", context=context)
names = Names()
def outcome(msg):
    reason = msg.reason.replace(chr(10), " ")
    print("out", msg.id, msg.outcome, time.time(), reason, flush=True)
matched, stated = threading.Event(), threading.Event()
def state(msg):
    print("state", msg.data, time.time(), flush=True)
    stated.set()
def ready():
    if matched.wait(60) and stated.wait(60):
        print("ready", flush=True)
threading.Thread(target=ready, daemon=True).start()
events = SubscriptionEventCallbacks(matched=lambda info: matched.set())
node.create_subscription(
    InstructionResult, names.result, outcome, QOS_STREAM, event_callbacks=events
)
node.create_subscription(String, names.state, state, QOS_LATCHED)
executor = rclpy.executors.SingleThreadedExecutor(context=context)
executor.add_node(node)
executor.spin()
"""


@dataclass(frozen=True)
class Fault:
    """One fault on the cable: `kind` cut, delay or loss (a delay may come with a loss),
    from `start` (epoch s) for `seconds`."""

    kind: str
    start: float
    seconds: float
    delay_ms: float = 0.0
    loss_percent: float = 0.0

    @property
    def end(self) -> float:
        return self.start + self.seconds


@dataclass
class Report:
    """What each side saw."""

    faults: list[Fault] = field(default_factory=list)
    #: By id: (sent epoch, text).
    requests: dict[str, tuple[float, str]] = field(default_factory=dict)
    #: By id: (the client's result, epoch).
    results: dict[str, tuple[str, float]] = field(default_factory=dict)
    #: The server's outcomes as the observer read them: (id, result, epoch, reason).
    outcomes: list[tuple[str, str, float, str]] = field(default_factory=list)
    states: list[tuple[str, float]] = field(default_factory=list)
    #: (asked, answered, how) of each stop asked while the link was up.
    stops: list[tuple[float, float, str]] = field(default_factory=list)


def run(hosts: Hosts, count: int, seed: int, kinds: tuple[str, ...] = ()) -> Report:
    """`count` random faults on `hosts`' cable (`Hosts(cable=True)`) under the laptop's client,
    every third followed by a stop while the link is up; what each side saw. `kinds`: the
    faults' kinds in turn (cut, delay, loss, both), else each picked at random."""
    rng = random.Random(seed)
    server = hosts.popen(hosts.arm, [AL5D, "serve", "--config", patient_config()])
    observer = hosts.popen(hosts.arm, [sys.executable, "-c", OBSERVER])
    assert server.stderr is not None and observer.stdout is not None
    log, seen = Lines(server.stderr), Lines(observer.stdout)
    laptop: subprocess.Popen[str] | None = None
    report = Report()
    try:
        log.wait_for("STATE: ready", CMD_S)
        seen.wait_for("ready", CMD_S)  # before the first request: it sees every outcome
        laptop = hosts.popen(hosts.laptop, [sys.executable, "-c", LAPTOP, str(seed)])
        assert laptop.stdout is not None and laptop.stdin is not None
        out = Lines(laptop.stdout)
        out.wait_for("ready", CMD_S)
        for k in range(count):
            time.sleep(rng.uniform(*CLEAR_S))
            fault = _fault(rng, kinds[k % len(kinds)] if kinds else None)
            report.faults.append(fault)
            if fault.kind == "cut":
                hosts.cut()
            else:
                hosts.impair(fault.delay_ms, fault.loss_percent)
            time.sleep(fault.seconds)
            if fault.kind == "cut":
                hosts.mend()
            if k % 3 == 2:  # a stop while the link is up, the fault still on for a delay
                laptop.stdin.write("stop\n")
                laptop.stdin.flush()
                _, asked, answered, how = out.wait_for("stop ", CMD_S).split(maxsplit=3)
                report.stops.append((float(asked), float(answered), how))
            hosts.impair()
            print(f"fault {k + 1}: {_said(fault)}", flush=True)
        time.sleep(12.0)  # the last request's outcome (its timeout at most)
    finally:
        hosts.mend()
        hosts.impair()
        for proc in (laptop, observer):
            if proc is not None:
                proc.kill()
                proc.wait(10)
        server.kill()
        server.wait(10)
    for line in out.drain(0.5):
        words = line.split(maxsplit=4)
        if words[0] == "req":
            report.requests[words[1]] = (float(words[2]), words[4])
        elif words[0] == "res":
            report.results[words[1]] = (words[2], float(words[3]))
    for line in seen.drain(0.5):
        words = line.split(maxsplit=4)
        if words[0] == "out":
            report.outcomes.append((words[1], words[2], float(words[3]), "".join(words[4:])))
        elif words[0] == "state":
            report.states.append((words[1], float(words[2])))
    return report


def _fault(rng: random.Random, kind: str | None) -> Fault:
    kind = kind or rng.choice(("cut", "delay", "loss", "both"))
    if kind == "cut":
        return Fault("cut", time.time(), rng.uniform(*CUT_S))
    seconds = rng.uniform(*IMPAIRED_S)
    delay = rng.uniform(*DELAY_MS) if kind in ("delay", "both") else 0.0
    loss = rng.uniform(*LOSS_PERCENT) if kind in ("loss", "both") else 0.0
    return Fault("delay" if delay else "loss", time.time(), seconds, delay, loss)


def _said(fault: Fault) -> str:
    if fault.kind == "cut":
        return f"cut for {fault.seconds:.1f} s"
    return (
        f"{fault.delay_ms:.0f} ms delay, {fault.loss_percent:.0f} % loss for {fault.seconds:.1f} s"
    )


def check(report: Report) -> list[str]:
    """What broke a promise (empty: none did)."""
    problems: list[str] = []
    counts = Counter(ident for ident, *_ in report.outcomes)
    problems += [f"[{i}]: {n} outcomes at the server" for i, n in counts.items() if n > 1]
    at_server = {ident: (result, t, why) for ident, result, t, why in report.outcomes}
    for ident in report.requests:
        given_up = report.results.get(ident, ("", 0.0))
        outcome = at_server.get(ident)
        if given_up[0] in ("done", "refused", "cancelled"):
            if outcome is None or outcome[0] != given_up[0]:
                problems.append(f"[{ident}]: the client heard {given_up[0]}, the server {outcome}")
        elif given_up[0] in ("lost", "nooutcome") and outcome is not None:
            # Done before its sender gave up is a move that ran while it waited (a cut
            # near a move's end: the server finishes it within the lease); done after is
            # a request that moved the arm for nobody.
            result, t, _ = outcome
            if result == "done" and t > given_up[1]:
                began = _fault_before(report.faults, given_up[1])
                problems.append(
                    f"[{ident}]: its sender gave up ({given_up[0]}) at {given_up[1]:.2f} and "
                    f"it was done at {t:.2f} (the fault began at {began})"
                )
    for asked, _, how in report.stops:
        obeyed = _obeyed_after(report, asked)
        if how != "ok" and obeyed is None:
            problems.append(f"a stop asked at {asked:.2f} was not obeyed ({how})")
        elif obeyed is None or obeyed > STOP_OBEYED_S:
            problems.append(f"a stop asked at {asked:.2f}: STOPPED after {obeyed} s")
    return problems


def _obeyed_after(report: Report, asked: float) -> float | None:
    """How long after `asked` the server's state first said STOPPED (None: never)."""
    stopped = [t for s, t in report.states if s == "stopped" and t >= asked - 0.05]
    return stopped[0] - asked if stopped else None


def _fault_before(faults: list[Fault], t: float) -> float | None:
    """When the last fault that began before `t` began."""
    began = [f.start for f in faults if f.start <= t]
    return began[-1] if began else None


def figures(report: Report) -> str:
    """The run in a few numbers."""
    results = Counter(r for r, _ in report.results.values())
    after = (_obeyed_after(report, asked) for asked, _, _ in report.stops)
    obeyed = [s for s in after if s is not None]
    kinds = Counter(f.kind for f in report.faults)
    reasons = Counter(why[:60] for _, result, _, why in report.outcomes if result == "refused")
    return (
        f"{len(report.faults)} faults ({dict(kinds)}); {len(report.requests)} requests, "
        f"the client heard {dict(results)}; {len(report.outcomes)} outcomes at the server; "
        f"{len(report.stops)} stops, obeyed after "
        f"{', '.join(f'{s:.2f}' for s in sorted(obeyed))} s; refused most for "
        f"{reasons.most_common(3)}"
    )


@dataclass(frozen=True)
class Restart:
    """A stop asked of a server just restarted, by a client that ran before: when it was
    asked and answered (epoch s), the client's word (ok, refused, raised ...), and how long
    after it was asked the server's state said STOPPED (None: it did not within 5 s)."""

    asked: float
    answered: float
    said: str
    obeyed_s: float | None
    #: When the server's ROS nodes said they were up, from when the stop was asked (s;
    #: negative: before it).
    up_s: tuple[float, ...] = ()
    #: When the client said the stop had had no answer yet, from when it was asked (s;
    #: None: it did not).
    unanswered_s: float | None = None


#: What a server's bridge and its stop's own process say when their ROS 2 node is up.
NODES_UP = ("ROS 2 node", "ROS 2 stop node")


def restarts(hosts: Hosts, count: int, seed: int) -> list[Restart]:
    """The server on `hosts.arm` restarted `count` times (SIGTERM, then started again) under
    the laptop's client, which sends moves all along; a stop asked of each new server at a
    random moment in its first second up (its arm ready, and its ROS nodes)."""
    rng = random.Random(seed)
    laptop: subprocess.Popen[str] | None = None
    out: Lines | None = None
    done: list[Restart] = []
    for _ in range(count + 1):
        server = hosts.popen(hosts.arm, [AL5D, "serve", "--config", patient_config()])
        assert server.stderr is not None
        log = Lines(server.stderr)
        try:
            # Restarted once the arm is ready and its ROS side has said it is up: a stop
            # asked before reaches no node, and is obeyed when one is up (the client keeps
            # sending it; in a CI run beside busy loops, one asked 0.24 s after the arm was
            # ready was obeyed 2.15 s after it was asked).
            log.wait_for_each(["STATE: ready", *NODES_UP], CMD_S)
            if laptop is None:  # the client, from before the first restart on
                laptop = hosts.popen(hosts.laptop, [sys.executable, "-c", LAPTOP, str(seed)])
                assert laptop.stdout is not None
                out = Lines(laptop.stdout)
                out.wait_for("ready", CMD_S)
                continue
            time.sleep(rng.uniform(0.0, 1.0))
            assert laptop.stdin is not None and out is not None
            laptop.stdin.write("stop\n")
            laptop.stdin.flush()
            _, asked, answered, said = out.wait_for("stop ", CMD_S).split(maxsplit=3)
            try:
                stopped = log_clock(log.wait_for("STATE: stopped", 5.0), float(asked))
                obeyed: float | None = stopped - float(asked)
            except AssertionError:
                obeyed = None
            up = tuple(
                round(log_clock(line, float(asked)) - float(asked), 3)
                for line in log.drain(0)
                if any(node in line for node in NODES_UP) and " up" in line
            )
            unanswered = [
                float(line.split()[1]) - float(asked)
                for line in out.all
                if line.startswith("unanswered ") and float(line.split()[1]) >= float(asked)
            ]
            done.append(
                Restart(
                    float(asked), float(answered), said, obeyed, up, min(unanswered, default=None)
                )
            )
            print(f"restart {len(done)}: {done[-1]}", flush=True)
        finally:
            server.send_signal(signal.SIGTERM)
            try:
                server.wait(60)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait(10)
    if laptop is not None:
        laptop.kill()
        laptop.wait(10)
    return done


#: A stop asked of a server is obeyed within this, or its client says it was not.
RESTART_STOP_S = 1.0
#: How much later than `RESTART_STOP_S` a busy host may let the client say a stop has had
#: no answer yet (its loop looks every 20 ms; its thread waits its turn for a core).
UNANSWERED_SLACK_S = 0.5


def restart_problems(done: list[Restart], timeout_s: float = 10.0) -> list[str]:
    """The stops that were neither obeyed within `RESTART_STOP_S` nor said by their client
    not to have been answered: by raising within its timeout (`timeout_s`), or at once
    (within `RESTART_STOP_S` and its slack) while it still sent a stop obeyed later."""
    problems = []
    for r in done:
        obeyed = r.obeyed_s is not None and r.obeyed_s <= RESTART_STOP_S
        said = r.said.startswith("raised") and r.answered - r.asked <= timeout_s + 1.0
        # Or the client said at once that the stop had had no answer yet, and it was
        # obeyed later all the same.
        unanswered = (
            r.unanswered_s is not None
            and r.unanswered_s <= RESTART_STOP_S + UNANSWERED_SLACK_S
            and r.obeyed_s is not None
        )
        if not (obeyed or said or unanswered):
            problems.append(f"a stop asked at {r.asked:.2f}: {r}")
    return problems


def log_clock(line: str, near: float) -> float:
    """The time (epoch s) of a server's log line `HH:MM:SS.mmm ...` of the day of `near`."""
    at = datetime.strptime(line.split()[0], "%H:%M:%S.%f").time()
    return datetime.combine(datetime.fromtimestamp(near).date(), at).timestamp()
