"""`al5d emulator`: a standalone emulated SSC-32U on a pseudo terminal, its arguments and
its run until SIGINT or SIGTERM.

The emulator itself (`al5d.ssc32u.emulator`) is imported when the command runs or an
argument is read: the other commands never load it.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from al5d import exits
from al5d.arm.config import ArmConfig, load_config
from al5d.ssc32u.facts import BAUDS, FACTORY_BAUD, LATENCY_TIMER_MS

if TYPE_CHECKING:
    from al5d.ros.physical import PhysicalPublisher
    from al5d.ssc32u.emulator import Emulator
    from al5d.twin.link import TwinLink


def add_emulator(sub: Any) -> None:
    """The `emulator` subcommand on `sub` (argparse's subparsers)."""
    emu = sub.add_parser("emulator", help="a standalone emulated SSC-32U on a pseudo terminal")
    emu.add_argument("--baud", type=int, default=FACTORY_BAUD, choices=BAUDS)
    emu.add_argument("--link", help="also make this path a symlink to the device")
    emu.add_argument("--config", help="arm configuration (servo speeds); default: shipped")
    emu.add_argument(
        "--record",
        metavar="FILE",
        help="write every line the board receives as JSON (time of effect, bytes); - = stdout",
    )
    emu.add_argument(
        "--transport",
        choices=("usb", "uart"),
        default="usb",
        help="usb (default): the board's USB port, an output flush drops nothing written and "
        "short answers wait for the latency timer; uart: a plain serial line, a flush drops "
        "unsent bytes",
    )
    emu.add_argument(
        "--latency-timer",
        metavar="MS",
        type=_emulator_setting("latency_ms"),
        default=LATENCY_TIMER_MS,
        help="the USB chip's latency timer, 1..255 ms (default %(default)s)",
    )
    emu.add_argument(
        "--low-latency",
        action="store_true",
        help="as if the host had set the port's low-latency mode (the timer at 1 ms)",
    )
    emu.add_argument(
        "--input",
        metavar="PIN=LEVEL",
        action="append",
        default=[],
        type=_emulator_setting("input_setting"),
        help="an input pin: A..H=0|1|open, VA..VH=0..255|open (repeat; default all open)",
    )
    emu.add_argument(
        "--register",
        metavar="N=VALUE",
        action="append",
        default=[],
        type=_emulator_setting("register_setting"),
        help="a register at power-up, e.g. 0=8 (repeat); R4 is the baud / 10",
    )
    emu.add_argument(
        "--startup",
        metavar="TEXT",
        default="",
        help="the startup string, run at power-up (R0 bit 0 is set), e.g. '#0P1500;#1P1500;'",
    )
    emu.add_argument(
        "--power-up",
        metavar="CH=US",
        action="append",
        default=[],
        type=_emulator_setting("pulse_setting"),
        help="a channel's pulse at power-up (the initial pulse width registers; repeat)",
    )
    emu.add_argument(
        "--announce-reset",
        action="store_true",
        help="a reset (SIGUSR1) sends what SS answers, unasked",
    )
    emu.add_argument(
        "--misalign",
        metavar="JOINT=US[,reversed]",
        action="append",
        default=[],
        type=_emulator_setting("misalign_setting"),
        help="an arm other than its config says (to try `al5d calibrate` on): the joint "
        "stands US off its calibration, or turns the other way (repeat); where it truly "
        "stands goes on ROS (physical_joint_states), for al5d web and al5d calibrate to show",
    )
    emu.add_argument(
        "--namespace",
        help="the ROS namespace of the arm's server, for physical_joint_states; default: config",
    )
    emu.add_argument(
        "--physics",
        nargs="?",
        const="",
        metavar="SCENE",
        help="the board's pulses drive a physical twin (MuJoCo) in SCENE, a scene file; "
        "default: the shipped scene (a cup on the table); docs/physics.md",
    )
    emu.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from al5d.priority import make_urgent
    from al5d.ssc32u.emulator import Emulator, LinkModel, Transport, serve_forever

    config = load_config(args.config)
    if args.physics:  # a bad scene file is said before the board starts
        from al5d.twin.scene import load_scene

        load_scene(args.physics)
    usb = LinkModel(Transport(args.transport), args.latency_timer, args.low_latency)
    unknown = [name for name, _ in args.misalign if name not in config.joints]
    if unknown:
        print(
            f"al5d emulator: --misalign {unknown[0]}: no such joint; joints: "
            + ", ".join(config.joints),
            file=sys.stderr,
        )
        return exits.USAGE
    if args.link is not None:
        from pathlib import Path

        from al5d.ssc32u.emulator.pty import link_problem

        taken = link_problem(Path(args.link))
        if taken is not None:
            print(f"al5d emulator: --link: {taken}", file=sys.stderr)
            return exits.USAGE
    if args.record not in (None, "-"):
        try:  # made now: a path that cannot be written is said before the board starts
            open(args.record, "w", encoding="utf-8").close()
        except OSError as e:
            print(
                f"al5d emulator: --record: cannot write {args.record}: {e.strerror}",
                file=sys.stderr,
            )
            return exits.USAGE
    from al5d.arm.config import namespace_problem

    # The arm's namespace: where the misaligned arm's true angles and the twin go.
    ns = config.server.namespace if args.namespace is None else args.namespace
    problem = namespace_problem(ns)
    if problem:
        print(f"al5d emulator: --namespace: {problem}", file=sys.stderr)
        return exits.USAGE
    physical = None
    if args.misalign:
        # Before the board is made urgent: the publisher's threads (and DDS's) keep the
        # default priority, behind the board's.
        physical = _physical(config, ns)
    # A board answers in its own time whatever the computer does: the emulated one runs
    # ahead of the host's load (every thread it starts inherits this), where the OS allows.
    # Once its arguments are good: a caller's thread (`main` in a test) keeps its own.
    make_urgent("al5d emulator")
    emulator = Emulator(
        config,
        baud=args.baud,
        link=args.link,
        usb=usb,
        inputs=dict(args.input),
        registers=dict(args.register),
        startup=args.startup,
        power_up=dict(args.power_up),
        announce_reset=args.announce_reset,
        mechanics=dict(args.misalign),
    )
    print(f"al5d emulator: SSC-32U at {args.baud} baud, {usb.describe()}", file=sys.stderr)
    twin = None
    if args.physics is not None:
        from al5d.twin.link import TwinFailed

        try:
            twin = _twin(emulator, config, args.physics, ns)
        except TwinFailed as e:
            print(f"al5d emulator: {e}", file=sys.stderr)
            return exits.USAGE
    if physical is not None:
        physical.start(emulator.joint_degrees)
    try:
        if args.record is None:
            serve_forever(emulator, _until_signal())
        elif args.record == "-":
            serve_forever(emulator, _until_signal(), sys.stdout)
        else:
            with open(args.record, "w", encoding="utf-8") as record:
                serve_forever(emulator, _until_signal(), record)
    finally:
        if twin is not None:
            twin.close()
        if physical is not None:
            physical.close()
    return exits.DONE


def _twin(emulator: Emulator, config: ArmConfig, scene: str, namespace: str) -> TwinLink:
    """The physical twin of the board (`al5d.twin`) on ROS under `namespace`, its words on
    stderr."""
    import logging

    from al5d.twin.link import TwinLink

    logging.basicConfig(level=logging.INFO, format="al5d emulator: %(message)s", stream=sys.stderr)
    return TwinLink(emulator, config, scene or None, namespace)


def _physical(config: ArmConfig, namespace: str) -> PhysicalPublisher:
    """The publisher of where the misaligned arm truly stands (ROS is imported only here)."""
    from al5d.ros.names import Names
    from al5d.ros.physical import PhysicalPublisher

    names = Names.of(namespace)
    print(
        f"al5d emulator: where the arm truly stands goes on {names.physical_joint_states}",
        file=sys.stderr,
    )
    prefix = config.server.joint_prefix_in(names.namespace)
    return PhysicalPublisher(names, config.model, prefix=prefix)


def _until_signal() -> threading.Event:
    """An event set by SIGINT or SIGTERM (so that both end the program the same clean way)."""
    done = threading.Event()

    def handler(signum: int, frame: object) -> None:
        done.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return done


def _emulator_setting(name: str) -> Callable[[str], Any]:
    """`al5d.ssc32u.emulator.settings.<name>`, imported when a value is first read: only
    `al5d emulator` loads the emulator, not `al5d serve --port` nor the clients."""

    def convert(text: str) -> Any:
        from al5d.ssc32u.emulator import settings

        return getattr(settings, name)(text)

    convert.__name__ = name  # argparse names the type in its errors
    return convert
