"""What each `al5d` command does with its parsed arguments (`al5d.app.cli` parses them):
the part of al5d it needs, imported then, and its call; its exit code back."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

from al5d import exits
from al5d.arm.config import load_config


class Default(float):
    """--timeout's default, told from a value given on the command line: argparse keeps a
    default that is no string as it is. A stop's or a release's answer is waited for its own
    default (`answer_s`), as `al5d send stop`'s quick path waits, unless --timeout is given."""


def answer_s(timeout: float) -> float:
    """How long a stop's or a release's answer is waited for, by --timeout's value."""
    from al5d.ros.answers import ANSWER_S

    return ANSWER_S if isinstance(timeout, Default) else timeout


def cmd_serve(args: argparse.Namespace) -> int:
    from al5d.app.server import ServerOptions, serve
    from al5d.logs import setup_logging

    setup_logging(args.log_level)
    options = ServerOptions(
        port=args.port,
        baud=args.baud,
        config=args.config,
        stdin=args.stdin,
        ros=not args.no_ros,
        trace=args.trace,
        namespace=args.namespace,
        ros_args=args.ros_args,
        record=args.record,
        physics=args.physics,
    )
    if args.physics is not None:
        if args.port is not None:  # the twin follows an emulated board's pulses
            print(
                "al5d serve: --physics runs the twin of the embedded emulated board; with "
                "--port the board is real (for a twin beside an emulated board on a pty: al5d "
                "emulator --physics, then al5d serve --port on it)",
                file=sys.stderr,
            )
            return exits.USAGE
        return with_twin(lambda: serve(options))
    return serve(options)


def with_twin(run: Callable[[], int]) -> int:
    """`run()`; a physical twin that cannot start is said in a line (exit 2), not a traceback."""
    from al5d.twin.link import TwinFailed

    try:
        return run()
    except TwinFailed as e:
        print(f"al5d: {e}", file=sys.stderr)
        return exits.USAGE


def cmd_demo(args: argparse.Namespace) -> int:
    from al5d.app.demo import run_demo
    from al5d.logs import setup_logging

    setup_logging(args.log_level)

    def demo() -> int:
        if args.physics is not None:
            return with_twin(lambda: run_demo(baud=args.baud, physics=args.physics))
        return run_demo(baud=args.baud)

    if args.web:
        import random

        from al5d.web.app import web_beside

        # One domain for the demo's server and the web view's process.
        os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(100, 199)))
        with web_beside(args.web_port):
            return demo()
    return demo()


def cmd_web(args: argparse.Namespace) -> int:
    from al5d.logs import setup_logging
    from al5d.web.app import WebOptions, serve_web

    setup_logging(args.log_level)
    options = WebOptions(args.port, args.host, args.namespace, args.config, args.poses)
    return serve_web(options)


def cmd_urdf(args: argparse.Namespace) -> int:
    from al5d.app.moveit import ROBOT, arm_chain
    from al5d.model import urdf_from_chain

    print(urdf_from_chain(arm_chain(load_config(args.config), args.namespace), ROBOT))
    return exits.DONE


def cmd_moveit(args: argparse.Namespace) -> int:
    from al5d.app.moveit import Arm, moveit_files_of_arms, write_files, write_moveit_config

    if args.arms is None:
        config = load_config(args.config)
        for path in write_moveit_config(args.out, config, args.namespace, args.name):
            print(path)
        return exits.DONE
    if args.namespace is not None:
        print("al5d moveit: --arms names each arm's namespace: no --namespace", file=sys.stderr)
        return exits.USAGE
    arms = [Arm(ns, load_config(file or args.config)) for ns, file in args.arms]
    try:
        files = moveit_files_of_arms(arms, args.name)
    except ValueError as e:
        print(f"al5d moveit: {e}", file=sys.stderr)
        return exits.USAGE
    for path in write_files(args.out, files):
        print(path)
    return exits.DONE


def cmd_send(args: argparse.Namespace) -> int:
    from al5d.app.terminal import send
    from al5d.interrupts import cancelling

    with cancelling():  # a second Ctrl-C does not cut the cancel the first one started
        return send(
            " ".join(args.instruction),
            wait_s=args.wait,
            timeout=args.timeout,
            answer_s=answer_s(args.timeout),
            namespace=args.namespace,
            verbose=args.verbose,
            via=args.via,
        )


def cmd_run(args: argparse.Namespace) -> int:
    from al5d.app.terminal import run
    from al5d.interrupts import cancelling

    if args.check:
        return check(args.file, args.poses, args.namespace, args.wait)
    with cancelling():  # as in `cmd_send`
        return run(
            args.file,
            wait_s=args.wait,
            timeout=args.timeout,
            namespace=args.namespace,
            verbose=args.verbose,
            poses=args.poses,
            via=args.via,
        )


def check(path: str, poses: str | None, namespace: str | None, wait_s: float) -> int:
    """`al5d run --check`: the file judged whole as `al5d run` judges it, against the
    configuration of the server on this machine's lane (waited for up to `wait_s`), else
    the shipped one; nothing sent."""
    from al5d.app.report import each_line
    from al5d.arm.poses import PosesError, beside, load_poses
    from al5d.arm.sequence import judge_sequence, read_sequence
    from al5d.owner import where
    from al5d.owner.client import LaneStalled, local_config
    from al5d.ros.answers import others
    from al5d.ros.names import Names

    names = Names.of(namespace)
    whose = "the server"
    try:
        config = local_config(where.path(names.namespace), max(wait_s, 1.0))
    except LaneStalled as e:
        config = None
        whose = f"a server with the shipped configuration ({e})"
    else:
        if config is None:
            # Another arm's server here is named: its configuration may be the one meant.
            whose = (
                "a server with the shipped configuration (none on this machine's lane"
                f"{others(names, None)})"
            )
    if config is None:
        config = load_config()
    try:
        book = load_poses(beside(path) if poses is None else poses, required=poses is not None)
        judged = judge_sequence(read_sequence(path), config, path, book)
    except OSError as e:
        print(f"al5d run: cannot read {path}: {e.strerror}", file=sys.stderr)
        return exits.BAD_INPUT
    except PosesError as e:
        print(each_line("al5d run: ", str(e)), file=sys.stderr)
        return exits.BAD_INPUT
    if not judged.ok:
        # As `al5d run` says them: the first MAX_SEQUENCE_ERRORS, then how many more.
        print(each_line("al5d run: ", str(judged.error())), file=sys.stderr)
        return exits.BAD_INPUT
    steps = len(judged.lines)
    said = f"{path}: {steps} step{'s'[: steps != 1]}, none {whose} would refuse"
    unknown = [str(line.number) for line in judged.lines if not line.known]
    if unknown:
        # Where the arm starts is not known here: those lines' paths (the table) and starts
        # are the server's to judge as they start (seen: "none would refuse" of a move the
        # server then refused as below the table).
        which = unknown[0] if len(unknown) == 1 else ", ".join(unknown[:-1]) + " and " + unknown[-1]
        one = len(unknown) == 1
        said += (
            " from where the lines before leave the arm; where it starts is not known, so "
            f"the table is judged for line{'' if one else 's'} {which} only by the server, "
            f"as {'it starts' if one else 'they start'} (from a preset, or a move naming "
            "every joint, on it is known)"
        )
    print(f"{said}; nothing sent")
    return exits.DONE


def cmd_shell(args: argparse.Namespace) -> int:
    from al5d.app.shell import shell

    return shell(
        wait_s=args.wait,
        timeout=args.timeout,
        answer_s=answer_s(args.timeout),
        namespace=args.namespace,
        verbose=args.verbose,
        poses=args.poses,
        via=args.via,
    )


def cmd_calibrate(args: argparse.Namespace) -> int:
    from al5d.app.calibrate import calibrate_command

    return calibrate_command(
        config_path=args.config,
        joints=tuple(args.joints.split(",")) if args.joints else (),
        step_us=args.step,
        namespace=args.namespace,
        wait_s=args.wait,
        timeout=args.timeout,
        yes=args.yes,
        reference_ms=args.time,
    )


def cmd_doctor(args: argparse.Namespace) -> int:
    from al5d.app.doctor import doctor

    return doctor(args.port, args.config)


def cmd_record(args: argparse.Namespace) -> int:
    from al5d.app.record import record

    return record(args.file, args.namespace, args.duration)


def cmd_replay(args: argparse.Namespace) -> int:
    from al5d.app.replay import replay

    return replay(
        args.file,
        rate=args.rate,
        wait_s=args.wait,
        timeout=args.timeout,
        namespace=args.namespace,
        config=args.config,
        arm=args.arm,
        max_gap_s=args.max_gap,
        partial=args.partial,
    )
