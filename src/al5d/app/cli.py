"""The `al5d` command line: its parser (serve, emulator, send, run, shell, doctor, demo,
web, record, replay, calibrate), each argument checked as it is read; `commands` runs them."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from al5d import exits
from al5d.app import commands
from al5d.app.emulator import add_emulator
from al5d.arm.config import ConfigError
from al5d.ssc32u.facts import BAUDS

#: `--log-level`, in any case (ROS users type `--log-level debug`).
LOG_LEVEL: dict[str, Any] = {
    "default": "INFO",
    "type": str.upper,
    "choices": ("DEBUG", "INFO", "WARNING", "ERROR"),
    "help": "DEBUG, INFO, WARNING or ERROR, in any case",
}


NAMESPACE_HELP = "ROS namespace of the arm (several arms: one each), e.g. left"


def _namespace(text: str) -> str:
    """A ROS namespace, or argparse's error naming why not."""
    from al5d.arm.config import namespace_problem

    problem = namespace_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


#: `--physics [SCENE]`: the physical twin (docs/physics.md).
PHYSICS: dict[str, Any] = {
    "nargs": "?",
    "const": "",
    "metavar": "SCENE",
    "help": "drive a physical twin (MuJoCo) in SCENE, a scene file; default: the shipped "
    "scene (a cup on the table); docs/physics.md",
}


def _package_name(text: str) -> str:
    """A ROS package name (REP 144), or argparse's error naming why not."""
    from al5d.app.moveit_package import package_name_problem

    problem = package_name_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def _arms(text: str) -> list[tuple[str, str | None]]:
    """`left,right` or `left=left.yaml,right=right.yaml`: each arm's namespace and its
    configuration file (None: --config's), or argparse's error naming why not."""
    from al5d.arm.config import namespace_problem

    arms: list[tuple[str, str | None]] = []
    for item in text.split(","):
        ns, _, file = item.strip().partition("=")
        problem = namespace_problem(ns) if ns.strip("/") else f"{item!r}: a namespace first"
        if problem:
            raise argparse.ArgumentTypeError(problem)
        arms.append((ns.strip("/"), file or None))
    return arms


def _within(lo: int, hi: int, unit: str) -> Callable[[str], int]:
    """A whole number of `unit` within lo..hi, or argparse's error saying so."""

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number of {unit}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} {unit}: give {lo}..{hi}")
        return value

    convert.__name__ = unit
    return convert


def _add_calibrate(sub: Any) -> None:
    """`al5d calibrate` (README, Calibration)."""
    cal = sub.add_parser(
        "calibrate",
        help="find each joint's calibration on the arm (through al5d serve) and write it",
        description=(
            "Per joint, the arm goes to two reference poses (through al5d serve); nudge the\n"
            "pulse until the real joint stands where the model says, and accept. The\n"
            "calibrations found are written into the server's config file, with a backup\n"
            "beside it and the diff printed.\n"
            "At a terminal: + - one step, ] [ ten, Enter accepts, s skips, q quits.\n"
            "Piped: a line each, + - +N -N ok skip quit, then y or n to write."
        ),
        epilog=exits.describe(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    cal.add_argument(
        "--config", help="the file to write: the one al5d serve runs with (default: the server's)"
    )
    cal.add_argument("--joints", help="comma-separated, e.g. base,elbow; default: every joint")
    cal.add_argument(
        "--step",
        type=_within(1, 100, "us"),
        default=5,
        help="a nudge, in us (1..100); default %(default)s",
    )
    cal.add_argument(
        "--time",
        type=_within(0, 60_000, "ms"),
        default=1500,
        help="ms for a move to a reference pose (the servos' speed allowing); default %(default)s",
    )
    cal.add_argument("--yes", action="store_true", help="write without asking")
    cal.add_argument("--namespace", type=_namespace, help=NAMESPACE_HELP + "; default: none")
    _add_waits(cal, 30.0, "a move")
    cal.set_defaults(func=commands.cmd_calibrate)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="al5d",
        description="Lynxmotion AL5D arm on an SSC-32U: server, client and emulator.",
        epilog=exits.describe(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True)

    srv = sub.add_parser(
        "serve",
        help="the arm server (embedded emulator without --port)",
        epilog="ROS arguments follow --ros-args, as for any ROS node: -p NAME:=VALUE (the "
        "parameters: docs/ros.md), --params-file FILE, -r __ns:=/NS, "
        "-r __node:=NAME. These flags win over parameters, which win over the config file.",
    )
    srv.add_argument("--port", help="serial device of the SSC-32U; default: embedded emulator")
    srv.add_argument("--baud", type=int, choices=BAUDS, help="default: config")
    srv.add_argument("--config", help="arm configuration file; default: the shipped one")
    srv.add_argument("--log-level", **LOG_LEVEL)
    srv.add_argument("--stdin", action="store_true", help="also read instructions from stdin")
    srv.add_argument("--no-ros", action="store_true", help="no ROS node (use with --stdin)")
    srv.add_argument("--trace", help="write when each instruction message arrived (benchmarks)")
    srv.add_argument("--namespace", type=_namespace, help=NAMESPACE_HELP + "; default: config")
    srv.add_argument(
        "--record", metavar="FILE.mcap", help="record what happens, the board's bytes too (MCAP)"
    )
    srv.add_argument("--physics", **PHYSICS)
    srv.set_defaults(func=commands.cmd_serve)

    add_emulator(sub)

    for name, func, what in (
        ("send", commands.cmd_send, "send one instruction and print its outcome"),
        ("run", commands.cmd_run, "run a sequence file (the client application)"),
        (
            "shell",
            commands.cmd_shell,
            "instructions a line at a time over one connection (discovery paid once); "
            "Ctrl-C while one runs stops the arm",
        ),
    ):
        cmd = sub.add_parser(
            name,
            help=what,
            epilog=exits.describe(),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        if name == "send":
            cmd.add_argument("instruction", nargs="+", help="e.g. move base=30 elbow=90 time=800")
        elif name == "run":
            cmd.add_argument(
                "file",
                help="one instruction a line; wait <ms>; # comments; & = go on "
                "(-: standard input, read to its end first)",
            )
            cmd.add_argument(
                "--check",
                action="store_true",
                help="judge the whole file as the server would, say every problem, send nothing",
            )
        if name in ("run", "shell"):
            where = "beside the sequence file" if name == "run" else "in this directory"
            cmd.add_argument(
                "--poses",
                help=f"the poses file that `pose <name>` lines name; default: poses.yaml {where}",
            )
        cmd.add_argument("--namespace", type=_namespace, help=NAMESPACE_HELP + "; default: none")
        _add_waits(cmd, 120.0, stops=name != "run")
        cmd.add_argument(
            "--verbose",
            action="store_true",
            help="say where the time went: ROS's start, the server's discovery (said anyway "
            "when over 1 s), in all",
        )
        cmd.add_argument(
            "--via",
            choices=("auto", "lane", "ros"),
            default="auto",
            help="auto: a server on this machine by its local lane, else ROS 2; lane or ros: "
            "only that way",
        )
        cmd.set_defaults(func=func)

    doc = sub.add_parser(
        "doctor",
        help="check the way to the SSC-32U: USB, permission, latency timer, baud, channels",
        epilog=exits.describe(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    doc.add_argument("--port", help="the board's serial device; default: every SSC-32U on USB")
    doc.add_argument("--config", help="arm configuration file; default: the shipped one")
    doc.set_defaults(func=commands.cmd_doctor)

    urdf = sub.add_parser("urdf", help="print the URDF of the arm, made from the configuration")
    urdf.add_argument("--config", help="arm configuration file; default: the shipped one")
    urdf.add_argument(
        "--namespace", type=_namespace, help=NAMESPACE_HELP + " (frames NS/...); default: config"
    )
    urdf.set_defaults(func=commands.cmd_urdf)

    moveit = sub.add_parser(
        "moveit", help="write a MoveIt 2 config package (URDF, SRDF, controllers, launch files)"
    )
    moveit.add_argument(
        "out", help="directory of the package, e.g. ~/ws/src/al5d_moveit_config (made if missing)"
    )
    moveit.add_argument("--config", help="arm configuration file; default: the shipped one")
    moveit.add_argument("--namespace", type=_namespace, help=NAMESPACE_HELP + "; default: config")
    moveit.add_argument(
        "--arms",
        type=_arms,
        metavar="NS[=FILE],NS[=FILE]...",
        help="several arms as one robot, each by its namespace and its configuration (default: "
        "--config's), each with its server.mount",
    )
    moveit.add_argument(
        "--name",
        type=_package_name,
        default="al5d_moveit_config",
        help="the package's name; default: %(default)s",
    )
    moveit.set_defaults(func=commands.cmd_moveit)

    demo = sub.add_parser("demo", help="the DE01 demo on the embedded emulator, with a QoS table")
    demo.add_argument("--baud", type=int, choices=BAUDS, help="default: config")
    demo.add_argument("--log-level", **LOG_LEVEL)
    demo.add_argument("--web", action="store_true", help="with the web view open (al5d web)")
    demo.add_argument(
        "--web-port", type=int, default=8080, help="the web view's port; default 8080 (0: any)"
    )
    demo.add_argument(
        "--physics",
        **{
            **PHYSICS,
            "help": "the pick-and-place demo on a physical twin in SCENE (default: "
            "the shipped scene): the QoS table, then where the cup ended against its goal",
        },
    )
    demo.set_defaults(func=commands.cmd_demo)

    web = sub.add_parser("web", help="the live web view and control panel (a ROS 2 client)")
    web.add_argument("--port", type=int, default=8080, help="default 8080 (0: any free port)")
    web.add_argument(
        "--host", default="127.0.0.1", help="default 127.0.0.1; any other lets others move the arm"
    )
    web.add_argument("--namespace", type=_namespace, help=NAMESPACE_HELP + "; default: config")
    web.add_argument("--config", help="arm configuration file; default: the shipped one")
    web.add_argument(
        "--poses",
        help="the Teach tab's poses file (its sequences beside it); default: poses.yaml beside "
        "--config, else in this directory",
    )
    web.add_argument("--log-level", **LOG_LEVEL)
    web.set_defaults(func=commands.cmd_web)
    _add_recordings(sub)
    _add_calibrate(sub)
    for each in sub.choices.values():
        # Its own usage with a mistake on its line, not the top level's (`parse`).
        each.set_defaults(command_parser=each)
    return parser


def _add_waits(
    cmd: argparse.ArgumentParser, timeout: float, what: str = "an outcome", stops: bool = False
) -> None:
    """A client command's --wait and --timeout, their defaults said in --help (an outside
    try: `al5d send stop` with no server took 10.9 s, and --help did not say why); `stops`:
    the command sends a stop and a release as `Client.stop` and `release` (`answer_s`)."""
    cmd.add_argument(
        "--wait",
        type=_seconds,
        default=10.0,
        help="seconds to find the server; default %(default)g",
    )
    cmd.add_argument(
        "--timeout",
        type=_seconds,
        default=commands.Default(timeout),
        help=f"seconds to wait for {what}; default %(default)g"
        # `al5d.ros.answers.ANSWER_S`, not imported here: it imports the configuration.
        + (" (a stop's or release's answer: 10)" if stops else ""),
    )


def _add_recordings(sub: Any) -> None:
    """`al5d record` and `al5d replay` (docs/ros.md, Recordings)."""
    rec = sub.add_parser(
        "record",
        help="record the arms and their transforms in an MCAP file (rosbag2's format) until Ctrl-C",
        epilog=exits.describe(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rec.add_argument("file", help="the MCAP file to write, e.g. run.mcap (replaced if there)")
    rec.add_argument(
        "--namespace",
        type=_namespace,
        action="append",
        help="the arm to record, by its ROS namespace (again for more); default: every arm "
        "found, as it is found",
    )
    rec.add_argument("--duration", type=_seconds, help="seconds to record; default: until Ctrl-C")
    rec.set_defaults(func=commands.cmd_record)

    rep = sub.add_parser(
        "replay",
        help="send a recording's instructions again",
        epilog=exits.describe(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rep.add_argument("file", help="an MCAP file of al5d record or al5d serve --record")
    rep.add_argument(
        "--rate",
        choices=("recorded", "fast"),
        default="recorded",
        help="recorded (default): each at its recorded time after the first; fast: each as "
        "soon as the one before has its outcome",
    )
    rep.add_argument(
        "--namespace",
        type=_namespace,
        help="the arm to send to: " + NAMESPACE_HELP + "; default: none",
    )
    rep.add_argument(
        "--from",
        dest="arm",
        type=_namespace,
        metavar="NS",
        help="the recorded arm whose instructions are sent (a file of several arms); default: "
        "the file's one arm, or --namespace's",
    )
    rep.add_argument(
        "--max-gap",
        type=_seconds,
        default=10.0,
        help="at the recorded rate, a longer gap between two instructions is cut to this "
        "(and said); default %(default)g s",
    )
    rep.add_argument(
        "--partial",
        action="store_true",
        help="a file cut short (its recorder killed): replay the instructions before the cut",
    )
    rep.add_argument("--config", help="arm configuration (presets, geometry); default: shipped")
    _add_waits(rep, 120.0)
    rep.set_defaults(func=commands.cmd_replay)


#: The longest a command's wait may be (a week): longer ones are a mistake, and past about
#: 9e9 s the standard library's waits fail (`threading.TIMEOUT_MAX`).
SECONDS_MAX = 7 * 24 * 3600.0


def _seconds(text: str) -> float:
    """A number of seconds above 0 and at most `SECONDS_MAX`, or argparse's error saying so
    (before anything is sent: NaN, 0 or -1 sent a move and then waited for none of it)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 < value <= SECONDS_MAX:
        raise argparse.ArgumentTypeError(
            f"{text}: give a number of seconds above 0, at most {SECONDS_MAX:.0f}"
        )
    return value


def _split_ros_args(argv: list[str]) -> tuple[list[str], list[str] | None]:
    """The command line without its `--ros-args` (for argparse), and the whole of it for
    rclpy (None when it has none), as rcl reads them: `--ros-args ... [--]`, anywhere."""
    if "--ros-args" not in argv:
        return argv, None
    from rclpy.utilities import remove_ros_args

    whole = ["al5d", *argv]
    return remove_ros_args(whole)[1:], whole


def parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """`argv` read by `parser`, as argparse does but for `al5d send`'s instruction: its words
    after an option are its words too (`send move base=30 --timeout 1 time=800`: argparse
    takes the words before the option only, and said `time=800` was unknown to `al5d`).
    Exits with argparse's usage error (2) for anything else it does not know."""
    args, extra = parser.parse_known_args(argv)
    if extra and getattr(args, "instruction", None) and not any(e.startswith("-") for e in extra):
        args.instruction += extra
    elif extra:
        command: argparse.ArgumentParser = getattr(args, "command_parser", parser)
        first = next((i for i, word in enumerate(argv) if word in extra), len(argv))
        if args.command not in argv[:first]:  # `al5d --frob send`: the top level's mistake
            command = parser
        command.error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        rest, ros_args = _split_ros_args(list(sys.argv[1:] if argv is None else argv))
    except Exception as e:  # rcl's own words for what it cannot parse
        print(f"al5d: ROS arguments: {e}", file=sys.stderr)
        return exits.USAGE
    args = parse(parser, rest)
    args.ros_args = ros_args
    if ros_args is not None and args.command != "serve":
        parser.error("--ros-args: `al5d serve` is the ROS node that takes them")
    try:
        code: int = args.func(args)
    except ConfigError as e:
        print(f"al5d: configuration error:\n{e}", file=sys.stderr)
        return exits.USAGE
    except BrokenPipeError:  # `al5d urdf | head`: the reader has had enough
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return exits.DONE
    return code


if __name__ == "__main__":
    sys.exit(main())
