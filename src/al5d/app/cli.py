"""The `al5d` command line: serve, emulator, send, run, demo."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

from al5d.arm.config import ConfigError, load_config
from al5d.ssc32u.facts import BAUDS, FACTORY_BAUD

#: `--log-level`, in any case (ROS users type `--log-level debug`).
LOG_LEVEL: dict[str, Any] = {
    "default": "INFO",
    "type": str.upper,
    "choices": ("DEBUG", "INFO", "WARNING", "ERROR"),
    "help": "DEBUG, INFO, WARNING or ERROR, in any case",
}


def _until_signal() -> threading.Event:
    """An event set by SIGINT or SIGTERM (so that both end the program the same clean way)."""
    done = threading.Event()

    def handler(signum: int, frame: object) -> None:
        done.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return done


def _cmd_emulator(args: argparse.Namespace) -> int:
    from al5d.ssc32u.emulator import Emulator, serve_forever

    config = load_config(args.config)
    emulator = Emulator(config, baud=args.baud, link=args.link)
    if args.record is None:
        serve_forever(emulator, _until_signal())
    elif args.record == "-":
        serve_forever(emulator, _until_signal(), sys.stdout)
    else:
        with open(args.record, "w", encoding="utf-8") as record:
            serve_forever(emulator, _until_signal(), record)
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    from al5d.app.server import ServerOptions, serve, setup_logging

    setup_logging(args.log_level)
    options = ServerOptions(
        port=args.port,
        baud=args.baud,
        config=args.config,
        stdin=args.stdin,
        ros=not args.no_ros,
        trace=args.trace,
    )
    return serve(options)


def _cmd_demo(args: argparse.Namespace) -> int:
    from al5d.app.demo import run_demo
    from al5d.app.server import setup_logging

    setup_logging(args.log_level)
    return run_demo(baud=args.baud)


def _cmd_send(args: argparse.Namespace) -> int:
    from al5d.ros.client import send

    return send(" ".join(args.instruction), wait_s=args.wait, timeout=args.timeout)


def _cmd_run(args: argparse.Namespace) -> int:
    from al5d.ros.client import run

    return run(args.file, wait_s=args.wait, timeout=args.timeout)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="al5d", description="Lynxmotion AL5D arm on an SSC-32U: server, client and emulator."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    srv = sub.add_parser("serve", help="the arm server (embedded emulator without --port)")
    srv.add_argument("--port", help="serial device of the SSC-32U; default: embedded emulator")
    srv.add_argument("--baud", type=int, choices=BAUDS, help="default: config")
    srv.add_argument("--config", help="arm configuration file; default: the shipped one")
    srv.add_argument("--log-level", **LOG_LEVEL)
    srv.add_argument("--stdin", action="store_true", help="also read instructions from stdin")
    srv.add_argument("--no-ros", action="store_true", help="no ROS node (use with --stdin)")
    srv.add_argument("--trace", help="write when each instruction message arrived (benchmarks)")
    srv.set_defaults(func=_cmd_serve)

    emu = sub.add_parser("emulator", help="a standalone emulated SSC-32U on a pseudo terminal")
    emu.add_argument("--baud", type=int, default=FACTORY_BAUD, choices=BAUDS)
    emu.add_argument("--link", help="also make this path a symlink to the device")
    emu.add_argument("--config", help="arm configuration (servo speeds); default: shipped")
    emu.add_argument(
        "--record",
        metavar="FILE",
        help="write every line the board receives as JSON (time of effect, bytes); - = stdout",
    )
    emu.set_defaults(func=_cmd_emulator)

    for name, func, what in (
        ("send", _cmd_send, "send one instruction and print its outcome"),
        ("run", _cmd_run, "run a sequence file (the client application)"),
    ):
        cmd = sub.add_parser(name, help=what)
        if name == "send":
            cmd.add_argument("instruction", nargs="+", help="e.g. move base=30 elbow=90 time=800")
        else:
            cmd.add_argument(
                "file", help="one instruction a line; wait <ms>; # comments; & = go on"
            )
        cmd.add_argument("--wait", type=float, default=10.0, help="seconds to find the server")
        cmd.add_argument(
            "--timeout", type=float, default=120.0, help="seconds to wait for an outcome"
        )
        cmd.set_defaults(func=func)

    demo = sub.add_parser("demo", help="the DE01 demo on the embedded emulator, with a QoS table")
    demo.add_argument("--baud", type=int, choices=BAUDS, help="default: config")
    demo.add_argument("--log-level", **LOG_LEVEL)
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except ConfigError as e:
        print(f"al5d: configuration error:\n{e}", file=sys.stderr)
        return 2
    return code


if __name__ == "__main__":
    sys.exit(main())
