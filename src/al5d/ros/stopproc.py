"""The stop process: the node `al5d_stop` in a process of its own that writes the STOP itself.

On a busy host the server's own threads wait for its interpreter lock behind the
thread that takes a flood of instructions; a stop served there reached the board
65-210 ms late at p99 (three flooded servers beside two busy loops). This process
takes nothing but the stop service and the watcher's copy of the instruction topic,
at the urgent priority (`al5d.priority`), and holds a duplicate of the board's port
(`al5d.ssc32u.stopline`): a stop is counted in the shared gate (no move of the
server's goes out after that), written, answered, and then told to the server, whose
driver obeys it as any stop (drop, lock, outcomes; the same stop seen on the topic by
the node `al5d` too is one stop, as in the server).

`StopProcess` is the server's side: it starts the process early (`RosStart`, beside
the board's start-up), hands it the config's few facts, gates the board's port once
the arm is there (`serve`), and obeys what it is told. The process ends when the
server does (its socket closes), or with it (`PR_SET_PDEATHSIG`). If it cannot
start, or ends while the server runs, the server serves the stop itself
(`al5d.ros.safety.SafetyPath.take_over`) and one log line says so.

Run as `python -m al5d.ros.stopproc SHARED PORT_SOCKET MESSAGES` (descriptors the
server leaves open for it); nothing else starts it.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import Instruction, Kind
from al5d.clock import wall_ns
from al5d.priority import make_urgent
from al5d.ros.convert import stop_key
from al5d.ros.names import STOP_NODE, Names
from al5d.ros.safety import StopSetup, stop_instruction
from al5d.ssc32u.stopline import StopEnd, StopGate
from al5d.ssc32u.wire import gate_port

log = logging.getLogger("al5d")

#: How long the server waits for the process to say it is ready (a busy host's imports
#: and DDS start-up take seconds).
READY_S = 60.0
#: How long a stop the process could not write waits for the server's answer.
ANSWER_S = 2.0
_MESSAGE_MAX = 1 << 20
SWITCH_INTERVAL_S = 0.0005
#: A stop written this late after it was sent is said (on the host's clock).
LATE_MS = 50.0
_PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class Setup:
    """What the process is given: the config's facts, the names, the ROS arguments."""

    stops: StopSetup
    namespace: str
    args: tuple[str, ...]


def _send(sock: socket.socket, *message: Any) -> None:
    with contextlib.suppress(OSError):  # the other side has ended: its own end says so
        sock.send(pickle.dumps(message))


def _receive(sock: socket.socket) -> tuple[Any, ...] | None:
    """The next message; None when the other side has ended."""
    try:
        data = sock.recv(_MESSAGE_MAX)
    except OSError:
        return None
    return pickle.loads(data) if data else None


class StopProcess:
    """The server's side of the stop process, started at once (`setup`); `serve` waits for
    it and puts it to work for a driver."""

    def __init__(self, setup: Setup) -> None:
        self.gate = StopGate()
        self._sock, peer = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        shared, port = self.gate.peer_fds
        fds = (shared, port, peer.fileno())
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "al5d.ros.stopproc", *map(str, fds)],
            pass_fds=fds,
            stdin=subprocess.DEVNULL,
        )
        peer.close()
        self.gate.peer_started()
        _send(self._sock, setup)
        self._driver: ArmDriver | None = None
        self._closing = False
        self._thread: threading.Thread | None = None

    def serve(self, driver: ArmDriver, lost: Callable[[], None]) -> bool:
        """Wait for the process, then gate the driver's port and obey what it tells; `lost`
        is called if it ends while the server runs. False (said) if it is not ready."""
        self._sock.settimeout(READY_S)
        ready = _receive(self._sock)
        self._sock.settimeout(None)
        if ready != ("ready",):
            log.error(
                "the stop process did not start (%s); the stop is served in the server, "
                "where a busy host delays it",
                "it ended" if ready is None else f"it said {ready!r}",
            )
            self.close()
            return False
        self._driver = driver
        gate_port(driver.port, self.gate)
        self._thread = threading.Thread(
            target=self._listen, args=(driver, lost), name="al5d-stop-told", daemon=True
        )
        self._thread.start()
        return True

    def _listen(self, driver: ArmDriver, lost: Callable[[], None]) -> None:
        make_urgent("al5d-stop-told")
        stops = StopSetup.of(driver.config)
        while (message := _receive(self._sock)) is not None:
            try:
                self._obey(driver, stops, message)
            except Exception:  # the next stop must still be obeyed
                log.exception("a stop from the stop process could not be obeyed")
        gate_port(driver.port, None)
        self.gate.acknowledge(self.gate.stops)  # no move waits for a stop nobody will obey
        if not self._closing:
            log.error(
                "the stop process ended (exit code %s); the stop is served in the server "
                "from now on, where a busy host delays it",
                self._proc.poll(),
            )
            lost()

    def _obey(self, driver: ArmDriver, stops: StopSetup, message: tuple[Any, ...]) -> None:
        _, count, written, raw, info, sent = message
        if raw is None:
            future = driver.submit(Instruction(Kind.STOP, sent_ns=sent), written=written)
        else:
            instr = stop_instruction(raw, info, stops.presets, stops.model)
            assert instr is not None  # the process judged it as the node `al5d` does
            future = driver.submit(instr, key=stop_key(info), written=written)
        self.gate.acknowledge(count)

        def answer(done: Future[Any]) -> None:
            outcome = done.result()
            reason = outcome.reason or f"stop: {outcome.result.value}"
            _send(self._sock, "answer", count, outcome.ok, reason)

        future.add_done_callback(answer)

    def close(self) -> None:
        self._closing = True
        if self._driver is not None:
            gate_port(self._driver.port, None)
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        try:
            self._proc.wait(5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(5)
        if self._thread is not None:
            self._thread.join(5)
        self._sock.close()
        self.gate.close()


# -- the process ----------------------------------------------------------------------


def late(sent: int | None, taken: int) -> None:
    """Say a stop written `LATE_MS` or more after it was sent, and where the time went."""
    if sent is None:
        return
    written = wall_ns()
    if (written - sent) / 1e6 >= LATE_MS:
        log.warning(
            "a stop written %.0f ms after it was sent: taken %.0f ms after, written in %.1f ms",
            (written - sent) / 1e6,
            (taken - sent) / 1e6,
            (written - taken) / 1e6,
        )


class _Answers:
    """The server's answers to the stops this process told it of, by stop number."""

    def __init__(self) -> None:
        self._waiting: dict[int, Future[tuple[bool, str]]] = {}
        self._lock = threading.Lock()

    def expect(self, count: int) -> Future[tuple[bool, str]]:
        with self._lock:
            return self._waiting.setdefault(count, Future())

    def came(self, count: int, ok: bool, reason: str) -> None:
        with self._lock:
            future = self._waiting.pop(count, None)
        if future is not None:
            future.set_result((ok, reason))


def main(argv: Sequence[str]) -> int:
    shared, port, messages = (int(a) for a in argv)
    # Before any thread: every thread of this process (DDS's too) inherits the priority.
    make_urgent("al5d stop process")
    # The service's thread must not wait 5 ms (the default) for the watcher's to let go of
    # the interpreter while it reads a flood.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    with contextlib.suppress(OSError, AttributeError):  # ends with the server, however it ends
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    # A terminal's ^C, and a SIGTERM to the server's process group, are the server's to
    # handle: it parks the arm first, and the stop must hold until it has ended.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s al5d stop: %(message)s"
    )
    sock = socket.socket(fileno=messages)
    setup = _receive(sock)
    if setup is None:
        return 0
    (config,) = setup
    assert isinstance(config, Setup)
    stops = config.stops
    end = StopEnd(shared, port, stops.channels, lambda: os._exit(0))
    answers = _Answers()

    def on_service(sent: int | None) -> tuple[bool, str]:
        taken = wall_ns()
        count, error, data = end.stop()
        late(sent, taken)
        waiting = answers.expect(count) if error else None
        _send(sock, "stop", count, None if error else data, None, None, sent)
        if waiting is None:
            return True, "stop: done"
        try:
            return waiting.result(ANSWER_S)
        except TimeoutError:
            return False, f"{error}; the server did not answer within {ANSWER_S:g} s"

    def on_topic(raw: bytes, info: dict[str, int], instr: Instruction) -> None:
        taken = wall_ns()
        count, error, data = end.stop(stop_key(info))
        late(instr.sent_ns, taken)
        _send(sock, "stop", count, None if error else data, raw, info, None)

    from al5d.ros.dds import start_context
    from al5d.ros.executors import Spinner
    from al5d.ros.safety import StopNode

    context = start_context(list(config.args) or [STOP_NODE])
    node = StopNode(context, Names.of(config.namespace), stops, on_service, on_topic)
    Spinner(node, context, owns_context=False, kind="single", urgent=True)
    _send(sock, "ready")
    while (message := _receive(sock)) is not None:
        if message[0] == "answer":
            answers.came(*message[1:])
    os._exit(0)  # the server has ended; DDS's threads need no goodbye


if __name__ == "__main__":
    # The module's own names, not __main__'s: the server's pickled `Setup` is the module's.
    from al5d.ros import stopproc

    sys.exit(stopproc.main(sys.argv[1:]))
