"""The server process: the arm driver on a real port or on the embedded emulator.

`al5d serve` builds it. Without `--port` it starts an emulated SSC-32U in the
same process, so anyone can run the server without an arm. SIGINT and SIGTERM
park the arm first (D2), then the process exits 0.
"""

from __future__ import annotations

import atexit
import logging
import logging.handlers
import os
import queue
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, TextIO

from al5d import exits
from al5d.arm.config import ArmConfig, load_config
from al5d.arm.driver import ArmDriver
from al5d.arm.instruction import GrammarError, Instruction, Outcome, parse_instruction, shutdown

if TYPE_CHECKING:
    from al5d.app.record import ServerRecording
    from al5d.ros.server import RosStart
    from al5d.ssc32u.emulator import Emulator
    from al5d.ssc32u.wire import WriteTap

log = logging.getLogger("al5d")

SWITCH_INTERVAL_S = 0.0005
#: `al5d serve`'s exit code when the server ended without the arm in park.
EXIT_NOT_PARKED = exits.NOT_PARKED
LOG_FORMAT = "%(asctime)s.%(msecs)03d %(levelname)s %(message)s"


def setup_logging(level: str) -> None:
    """Log lines to stderr, written by a thread of their own: a thousand refusals logged in a
    flood cost their callers a hand-over each, not a write to the terminal each."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(LOG_FORMAT, datefmt="%H:%M:%S"))
    lines: queue.SimpleQueue[logging.LogRecord] = queue.SimpleQueue()
    listener = logging.handlers.QueueListener(lines, handler)
    listener.start()
    atexit.register(listener.stop)  # the last lines are written before the process ends
    hand_over = logging.handlers.QueueHandler(lines)
    hand_over.setFormatter(logging.Formatter("%(message)s"))  # the listener's handler formats
    logging.basicConfig(level=level.upper(), handlers=[hand_over])


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
    options: ServerOptions, config: ArmConfig | None = None, tap: WriteTap | None = None
) -> Iterator[tuple[ArmDriver, Emulator | None]]:
    """The driver on the given port, or on an embedded emulator; closed (parked) on exit.
    `tap`: told of every write to the board (`al5d.ssc32u.wire.tap_writes`)."""
    config = config or load_config(options.config)
    baud = options.baud or config.server.baud
    emulator: Emulator | None = None
    twin = None
    port = options.port
    if port is None:
        from al5d.ssc32u.emulator import Emulator  # only where an emulated board is wanted

        emulator = Emulator(config, baud=baud).start()
        if options.physics is not None:  # the twin follows the board's pulses (al5d.twin)
            from al5d.twin.link import TwinLink

            twin = TwinLink(emulator, config, options.physics or None, options.namespace)
        port = emulator.port
        link = emulator.usb.describe()
        log.info("no --port: using the embedded SSC-32U emulator on %s, %s", port, link)
    if tap is not None:
        from al5d.ssc32u.wire import tap_writes

        tap_writes(port, tap)
    driver = ArmDriver(config, port, baud)
    try:
        driver.start()
        yield driver, emulator
    finally:
        driver.close()
        if twin is not None:
            twin.close()
        if emulator is not None:
            emulator.close()
        if tap is not None:
            tap_writes(port, None)


def _read_instructions(driver: ArmDriver, stream: TextIO, out: TextIO) -> None:
    """Instructions in the text grammar, one a line; each outcome printed when it comes."""
    presets = tuple(driver.config.presets)

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
        driver.submit(instr).add_done_callback(lambda f: show(f.result()))


def serve(options: ServerOptions) -> int:
    """Run until shutdown (instruction or signal); the arm is parked before the end.

    Exit 0 once the arm is parked; EXIT_NOT_PARKED when the final park could not be
    done (the board was lost, or a stop came during it).
    """
    stop_requested = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop_requested.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    # Threads here answer within milliseconds (the stop service, the move worker, the
    # embedded board) while others may be busy (handing out a thousand outcomes): hand
    # the GIL over every 0.5 ms, not every 5 ms, so that a busy one cannot hold up the rest.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    # The parameters (and remaps) come before the arm: they may name its port and config.
    start = _ros_start(options) if options.ros else None
    config = None
    if start is not None:
        config = start.settings.config
        options = replace(options, port=start.settings.port, record=start.settings.record)
    recording = None
    try:
        if options.record is not None:
            recording = _recording(options.record)
            if recording is None:
                return 2
        return _serve(options, config, start, stop_requested, recording)
    finally:
        if start is not None and start.context.ok():  # the server never took it over
            start.close()
        if recording is not None:
            recording.close()


def _recording(path: str) -> ServerRecording | None:
    """The recording `--record` asks for; None (said at ERROR) when its file cannot be made."""
    from al5d.app.record import RecordingError, ServerRecording

    try:
        return ServerRecording(path)
    except RecordingError as e:
        log.error("%s", e)
        return None


def _ros_start(options: ServerOptions) -> RosStart:
    from al5d.ros.params import Flags
    from al5d.ros.server import RosStart

    flags = Flags(options.config, options.port, options.baud, options.namespace, options.record)
    return RosStart(options.ros_args, flags)


def _serve(
    options: ServerOptions,
    config: ArmConfig | None,
    start: RosStart | None,
    stop_requested: threading.Event,
    recording: ServerRecording | None = None,
) -> int:
    namespace = start.names.namespace if start is not None else options.namespace
    tap = recording.tap(namespace) if recording is not None else None
    with arm(options, config, tap) as (driver, _):
        ros_server = None
        if start is not None:
            from al5d.ros.server import RosServer

            ros_server = RosServer(driver, trace=options.trace, start=start)
            if recording is not None:
                recording.follow(start.names, driver.config.server.instruction_backlog)
            log.info(
                "ROS 2 node %s up (ROS_DOMAIN_ID=%s)",
                ros_server.node.get_fully_qualified_name(),
                os.environ.get("ROS_DOMAIN_ID", "0"),
            )
        try:
            if options.stdin:
                threading.Thread(
                    target=_read_instructions, args=(driver, sys.stdin, sys.stdout), daemon=True
                ).start()
            while not driver.finished.is_set():
                if stop_requested.wait(0.1):
                    log.info("signal received: shutting down (park first)")
                    driver.submit(shutdown(id="signal"))
                    driver.finished.wait()
                    break
        finally:
            if ros_server is not None:
                ros_server.close()
            if recording is not None:
                recording.close_ros()  # after the server's last messages reached it
    if driver.parked_at_end is False:
        log.error("the arm was not parked: exit %d", EXIT_NOT_PARKED)
        return EXIT_NOT_PARKED
    return 0
