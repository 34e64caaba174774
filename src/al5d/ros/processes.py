"""The ROS side's processes, as the owner starts them: the bridge (`al5d.app.bridgeproc`,
`al5d.ros.bridge`'s nodes) and the stop's own bridge (`al5d.ros.stopproc`).

The owner of the board takes no ROS 2 callback: on a busy host a flood's callbacks held
its interpreter while a stop waited. So each ROS side runs in a process of its own, a
client of the owner over a lane socket it is handed at its start (a socket pair: no
path, no discovery), and a control socket that carries its setup and, for the bridge,
the settings it resolves from the command line's ROS parameters. Both end when the
owner ends (their lane closes), or with it (`PR_SET_PDEATHSIG`). This module imports
no rclpy: the owner's process uses it.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import pickle
import signal
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from typing import Any

from al5d.ros.params import Flags

_MESSAGE_MAX = 1 << 22
_PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class Setup:
    """What a ROS side is given: the command line (rclpy's argv: the program's name first,
    its `--ros-args`), `al5d serve`'s flags, where to write a trace of the instruction
    topic (`al5d serve --trace`), and whether it is a bridge started again."""

    args: tuple[str, ...] = ()
    flags: Flags = field(default_factory=Flags)
    trace: str | None = None
    #: A bridge started again after one ended: it does not record (the file is the first
    #: one's, kept as it was).
    again: bool = False


def send(sock: socket.socket, *message: Any) -> None:
    with contextlib.suppress(OSError):  # the other side has ended: its own end says so
        sock.send(pickle.dumps(message))


def receive(sock: socket.socket, timeout: float | None = None) -> tuple[Any, ...] | None:
    """The next message; None when the other side has ended (or said nothing in time)."""
    sock.settimeout(timeout)
    try:
        data = sock.recv(_MESSAGE_MAX)
    except OSError:
        return None
    finally:
        sock.settimeout(None)
    # Pickled by the process that started this one (or that it started): trusted.
    return pickle.loads(data) if data else None


class Child:
    """A ROS side's process: `python -m MODULE CTRL LANE`, with its two sockets."""

    def __init__(self, module: str, setup: Setup) -> None:
        self.ctrl, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.lane, their_lane = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        fds = (theirs.fileno(), their_lane.fileno())
        self.proc = subprocess.Popen(
            [sys.executable, "-m", module, *map(str, fds)],
            pass_fds=fds,
            stdin=subprocess.DEVNULL,
        )
        theirs.close()
        their_lane.close()
        send(self.ctrl, setup)

    def close(self, timeout: float = 10.0) -> int | None:
        """Wait for it to end (it ends when its lane closes), killing it past `timeout`."""
        with contextlib.suppress(OSError):
            self.ctrl.shutdown(socket.SHUT_RDWR)
        # The owner closes the lanes it serves as it ends; one no owner ever served (the
        # configuration refused) is closed here, or the child would wait out `timeout`
        # (a refused `al5d serve` took 12.5 s, 10 of them here).
        with contextlib.suppress(OSError):
            self.lane.shutdown(socket.SHUT_RDWR)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait(5)
        self.ctrl.close()
        self.lane.close()
        return code


def child_start(argv: list[str]) -> tuple[socket.socket, socket.socket, Setup]:
    """In the child: its control and lane sockets and its setup. It ends with its parent,
    and leaves Ctrl-C and SIGTERM to the owner (which parks, then closes the lane): a
    SIGTERM to the server's whole process group (`timeout`, systemd) ended both children
    in the middle of the park, logged as errors and a bridge started again. A SIGTERM
    ends it only once the owner has gone (`PR_SET_PDEATHSIG` sends one then)."""
    parent = os.getppid()
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)

    def on_term(signum: int, frame: object) -> None:
        if os.getppid() != parent:  # the owner has gone: end as SIGTERM ends a process
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)

    signal.signal(signal.SIGTERM, on_term)
    if os.getppid() != parent:  # it went before the handler was set
        os._exit(0)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ctrl = socket.socket(fileno=int(argv[0]))
    lane = socket.socket(fileno=int(argv[1]))
    got = receive(ctrl)
    if got is None:
        os._exit(0)  # the owner ended before it said anything
    (setup,) = got
    assert isinstance(setup, Setup)
    return ctrl, lane, setup
