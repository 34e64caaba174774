"""`al5d serve`: the owner of the board on a real port or on the embedded emulator, with its
ROS side beside it.

This process owns the board (`al5d.owner.Owner`: one thread writes to it) and serves
its local lane; the ROS side runs in processes of its own, clients of the owner
(`al5d.ros.processes`): the bridge, which also resolves the command line's ROS
parameters into the settings this process runs with, and the stop's own process.
Without `--port` it starts an emulated SSC-32U in this process, so anyone can run the
server without an arm. SIGINT and SIGTERM park the arm first (D2), then the process
exits 0.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from al5d import exits
from al5d.arm.config import ArmConfig, ConfigError, load_config, on_embedded_board
from al5d.arm.instruction import GrammarError, Instruction, Outcome, parse_instruction, shutdown
from al5d.owner import lane
from al5d.owner.loop import Owner
from al5d.owner.where import answers
from al5d.ssc32u.transport import SerialTransport

if TYPE_CHECKING:
    from al5d.app.record import ServerRecording
    from al5d.ros.processes import Child
    from al5d.ssc32u.emulator import Emulator

log = logging.getLogger("al5d")

SWITCH_INTERVAL_S = 0.0005
#: `al5d serve`'s exit code when the server ended without the arm in park.
EXIT_NOT_PARKED = exits.NOT_PARKED
#: How long the bridge may take to read the parameters (a busy host's imports and DDS).
SETTINGS_S = 120.0
#: How long the bridge may take to end once the owner has (its last results published, a
#: trace or a recording written, on a busy host).
CLOSE_S = 60.0
#: A bridge that ends is started again, unless it has been this many times in so long (one
#: that cannot run would otherwise halt its clients' motion every second or so).
RESTARTS_MAX = 3
RESTARTS_WITHIN_S = 60.0
#: A bridge the owner lost to its silence is killed if it has not ended in this long.
HUNG_KILL_S = 5.0


@dataclass
class ServerOptions:
    port: str | None = None
    baud: int | None = None
    config: str | None = None
    stdin: bool = False
    ros: bool = True
    trace: str | None = None
    #: The ROS namespace; None: the config's (server.namespace).
    namespace: str | None = None
    #: The command line for rclpy (the program's name first), whose `--ros-args` give the
    #: node `al5d` its parameters and remaps; None: none.
    ros_args: list[str] | None = None
    #: An MCAP file to record what happened in, the board's bytes too; None: none.
    record: str | None = None
    #: The embedded board drives a physical twin in this scene file ("": the shipped one);
    #: None: no twin (docs/physics.md).
    physics: str | None = None


@contextmanager
def arm(
    options: ServerOptions,
    config: ArmConfig | None = None,
    lane_path: Path | None = None,
    config_file: str | None = None,
    keep_wire: bool = False,
) -> Iterator[tuple[Owner, Emulator | None]]:
    """The owner on the given port, or on an embedded emulator; closed (parked) on exit. With
    `lane_path`, its local lane is there; `keep_wire`: the board's writes are kept for the
    recorder until it connects (the ROS bridge, where it records)."""
    config = config or load_config(options.config)
    baud = options.baud or config.server.baud
    emulator: Emulator | None = None
    twin = None
    port = options.port
    if port is None:
        from al5d.ssc32u.emulator import Emulator  # only where an emulated board is wanted

        config = on_embedded_board(config)  # what the bridge resolved holds it already
        emulator = Emulator(config, baud=baud).start()
        if options.physics is not None:  # the twin follows the board's pulses (al5d.twin)
            from al5d.twin.link import TwinLink

            twin = TwinLink(emulator, config, options.physics or None, options.namespace)
        port = emulator.port
        link = emulator.usb.describe()
        log.info("no --port: using the embedded SSC-32U emulator on %s, %s", port, link)
    given = config_file if config_file is not None else options.config
    source = Path(given).absolute() if given else None  # the lane says the whole path
    owner = Owner(
        config, SerialTransport(port, baud), lane=lane_path, config_file=source, keep_wire=keep_wire
    )
    try:
        owner.start()
        yield owner, emulator
    finally:
        owner.close()
        if twin is not None:
            twin.close()
        if emulator is not None:
            emulator.close()


def _read_instructions(owner: Owner, stream: TextIO, out: TextIO) -> None:
    """Instructions in the text grammar, one a line; each outcome printed when it comes."""
    presets = tuple(owner.config.presets)

    def show(outcome: Outcome) -> None:
        print(outcome, file=out, flush=True)

    for line in stream:
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            instr: Instruction = parse_instruction(text, presets)
        except GrammarError as e:
            print(f"error: {e}", file=out, flush=True)
            continue
        owner.submit(instr).add_done_callback(lambda f: show(f.result()))
    # An outside try: Ctrl-D left a server that said nothing, and a user who took it for
    # one that would end.
    print(
        "standard input ended: no more instructions are read from it; the server goes on "
        "(Ctrl-C ends it)",
        file=out,
        flush=True,
    )


class RosSide:
    """The ROS side's two processes, started at once (their imports and DDS start-up go on
    beside the board's): the bridge, which reads the parameters, and the stop's own.

    A bridge that ends while the server serves (killed, crashed) is a lost client to the
    owner (what its ROS clients commanded is halted) and is started again, said in the log:
    a server whose topics, actions and parameters had silently gone would look absent to
    every ROS client while its local lane still worked."""

    def __init__(self, options: ServerOptions) -> None:
        from al5d.ros.params import Flags
        from al5d.ros.processes import Child, Setup

        flags = Flags(options.config, options.port, options.baud, options.namespace, options.record)
        self._setup = Setup(tuple(options.ros_args or ()), flags, options.trace)
        self.stop: Child | None = Child("al5d.ros.stopproc", self._setup)
        self.bridge = Child("al5d.app.bridgeproc", self._setup)
        self._serving = False
        #: A bridge being started again, until its settings come.
        self._starting: Child | None = None
        # Held while a bridge is started again and swapped in, and by `close`, which closes
        # the one there is (and cuts short one starting).
        self._swap = threading.Lock()

    def settings(self) -> object:
        """What the bridge made of the parameters (`al5d.ros.params.Settings`), or the error."""
        got = self._settings(self.bridge)
        if isinstance(got, tuple):  # said as every bad configuration is (`al5d.app.cli`)
            raise ConfigError(got[0])
        return got

    @staticmethod
    def _settings(bridge: Child) -> object:
        """A bridge's settings; a str for an error, a 1-tuple for a configuration refused."""
        from al5d.ros.processes import receive

        got = receive(bridge.ctrl, SETTINGS_S)
        if got is None:
            return "the ROS bridge ended before it read the parameters (see its log above)"
        if got[0] == "config-error":
            return (str(got[1]),)
        if got[0] == "error":
            return str(got[1])
        return got[1]

    def serve(self, owner: Owner) -> None:
        """Both on the owner's lane; the stop is the bridge's if its own process is gone."""
        stop = self.stop
        alive = stop is not None and stop.proc.poll() is None
        if stop is not None:
            owner.adopt(stop.lane)
        self._go(owner)
        self._serving = True
        owner.lapsed_listeners.append(self._on_lapsed)
        threading.Thread(target=self._watch_bridge, args=(owner,), daemon=True).start()
        if alive and stop is not None:
            threading.Thread(target=self._watch_stop, args=(stop, owner), daemon=True).start()

    def _go(self, owner: Owner) -> None:
        from al5d.ros.processes import send

        owner.adopt(self.bridge.lane)
        stop = self.stop
        send(self.bridge.ctrl, "go", stop is None or stop.proc.poll() is not None)

    def _on_lapsed(self, sock: socket.socket) -> None:
        """The owner lost a lane client to its silence: if it is the bridge, it is killed
        unless it ends within `HUNG_KILL_S` (it may run again, find its lane closed and
        end; one that hangs for good would keep the ROS side dead), and started again."""
        bridge = self.bridge
        if sock is bridge.lane:
            threading.Thread(target=self._end_hung, args=(bridge,), daemon=True).start()

    def _end_hung(self, bridge: Child) -> None:
        try:
            bridge.proc.wait(HUNG_KILL_S)
        except subprocess.TimeoutExpired:
            if self._serving:
                log.error(
                    "the ROS 2 bridge was lost to its silence and has not ended in %g s: killed",
                    HUNG_KILL_S,
                )
                bridge.proc.kill()

    def _watch_stop(self, stop: Child, owner: Owner) -> None:
        """A stop process that ends while the server serves: the bridge serves the stop at
        once, and a new stop process is started, which takes it back once its node is up
        (an outside try: with the stop only in the bridge, a frozen bridge left no stop at
        all). Its bridge and it overlap for a moment; never is there neither."""
        from al5d.ros.processes import Child, receive, send

        restarts = _Restarts()
        while True:
            code = stop.proc.wait()
            # As the owner ends its lanes close, and the stop process ends as it should.
            if not self._serving or owner.ending.is_set():
                return
            with self._swap:
                send(self.bridge.ctrl, "serve-stop")
            if not restarts.allowed(
                f"the stop process ended (exit code {code})",
                again="the bridge serves the stop until it is started again",
                not_again="the bridge serves the stop, where a busy host delays it",
            ):
                return
            with self._swap:
                if not self._serving:
                    return
                stop = self.stop = Child("al5d.ros.stopproc", self._setup)
            owner.adopt(stop.lane)
            got = receive(stop.ctrl, SETTINGS_S)  # its node is up
            if got is None or got[0] != "ready":
                if self._serving and not owner.ending.is_set():
                    log.error("the stop process could not start again; the bridge serves the stop")
                return
            with self._swap:
                send(self.bridge.ctrl, "unserve-stop")
            log.warning("the stop process was started again; it serves the stop")

    def _watch_bridge(self, owner: Owner) -> None:
        from dataclasses import replace

        from al5d.ros.params import Settings
        from al5d.ros.processes import Child

        restarts = _Restarts()
        while True:
            code = self.bridge.proc.wait()
            # As the owner ends its lanes close, and the bridge ends as it should.
            if not self._serving or owner.ending.is_set():
                return
            if not restarts.allowed(
                f"the ROS 2 bridge ended (exit code {code})",
                again="what its clients commanded is halted; starting it again",
                not_again="the server goes on without it (its local lane and the stop "
                "service still work)",
            ):
                return
            with self._swap:
                if not self._serving:
                    return
                # Its recording, if any, ended with it: a new one would overwrite the file.
                self._starting = Child("al5d.app.bridgeproc", replace(self._setup, again=True))
            bridge = self._starting
            got = self._settings(bridge)  # outside the lock: `close` cuts it short
            with self._swap:
                self._starting = None
                if not self._serving or owner.ending.is_set() or not isinstance(got, Settings):
                    if self._serving and not owner.ending.is_set():
                        log.error("the ROS 2 bridge could not start again: %s", got)
                    bridge.close(5.0)
                    return
                # The old one's lane is the owner's, which closes it as it drops the client.
                self.bridge.ctrl.close()
                self.bridge = bridge
                self._go(owner)
            log.warning("the ROS 2 bridge was started again")

    def close(self) -> None:
        from socket import SHUT_RDWR

        self._serving = False
        with self._swap:
            if self._starting is not None:  # its settings are not waited for
                with contextlib.suppress(OSError):
                    self._starting.ctrl.shutdown(SHUT_RDWR)
            self.bridge.close(CLOSE_S)
        if self.stop is not None:
            self.stop.close()


class _Restarts:
    """How often one child of the server was started again: at most `RESTARTS_MAX` times
    in `RESTARTS_WITHIN_S`."""

    def __init__(self) -> None:
        self._times: list[float] = []

    def allowed(self, ended: str, *, again: str, not_again: str) -> bool:
        """Whether the child that `ended` (said) is started again; said as an error either
        way, with `again` or with `not_again` and the advice to restart the server."""
        now = time.monotonic()
        self._times = [t for t in self._times if t > now - RESTARTS_WITHIN_S]
        if len(self._times) >= RESTARTS_MAX:
            log.error(
                "%s, started again %d times in the last %.0f s already: not started again; "
                "%s: restart al5d serve",
                ended,
                len(self._times),
                RESTARTS_WITHIN_S,
                not_again,
            )
            return False
        log.error("%s: %s", ended, again)
        self._times.append(now)
        return True


def _recording(options: ServerOptions) -> ServerRecording | None:
    """`--record` without ROS: the board's bytes, written by this process (with ROS the
    bridge records, the topics too); None (said) where the file cannot be made."""
    from al5d.app.mcapfile import RecordingError
    from al5d.app.record import ServerRecording

    assert options.record is not None
    try:
        recording = ServerRecording(options.record)
    except RecordingError as e:
        log.error("%s", e)
        return None
    recording.tap(options.namespace)
    return recording


def serve(options: ServerOptions) -> int:
    """Run until shutdown (instruction or signal); the arm is parked before the end.

    Exit 0 once the arm is parked; EXIT_NOT_PARKED when the final park could not be
    done (the board was lost, or a stop came during it); 2 for settings that cannot be.
    """
    stop_requested = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop_requested.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    ros = RosSide(options) if options.ros else None
    recording: ServerRecording | None = None
    try:
        config = None
        config_file = options.config
        namespace = options.namespace or ""
        bridge_records = False  # with ROS the bridge records, the board's writes too
        if ros is not None:
            settings = ros.settings()
            if isinstance(settings, str):
                log.error("%s", settings)
                return 2
            from al5d.ros.params import Settings

            assert isinstance(settings, Settings)
            config, options.port = settings.config, settings.port
            namespace = settings.namespace
            config_file = settings.config_file
            bridge_records = settings.record is not None
        elif options.namespace is None:
            config = load_config(options.config)
            namespace = config.server.namespace
        if options.record and ros is None:
            recording = _recording(options)
            if recording is None:
                return 2
        if options.trace is not None:
            try:  # written as the server ends: a path that cannot be is said now
                open(options.trace, "a", encoding="utf-8").close()
            except OSError as e:
                log.error("--trace: cannot write %s: %s", options.trace, e.strerror)
                return 2
        where = lane.path(namespace)
        if answers(where):
            # One server per name, as on ROS: a second would answer ROS clients too (one of
            # them "refused: the serial link is lost" while the first moved the arm), and
            # could not be reached on this lane.
            log.error(
                "another al5d server serves the namespace %s on ROS domain %s on this machine "
                "(its lane %s): end it first, or give this one another namespace",
                namespace or "/",
                os.environ.get("ROS_DOMAIN_ID", "0"),
                where,
            )
            return 2
        with arm(options, config, where, config_file, bridge_records) as (owner, _):
            if recording is not None:
                tap = recording.file.board_tap
                owner.wire_listeners.append(lambda w: tap(*w))
            if ros is not None:
                ros.serve(owner)
            if options.stdin:
                threading.Thread(
                    target=_read_instructions, args=(owner, sys.stdin, sys.stdout), daemon=True
                ).start()
            while not owner.finished.is_set():
                if stop_requested.wait(0.1):
                    log.info("signal received: shutting down (park first)")
                    owner.submit(shutdown(id="signal"))
                    owner.finished.wait()
                    break
    finally:
        if ros is not None:
            ros.close()
        if recording is not None:
            recording.close()
    if owner.parked_at_end is False:
        log.error("the arm was not parked: exit %d", EXIT_NOT_PARKED)
        return EXIT_NOT_PARKED
    return 0
