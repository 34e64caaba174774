"""`al5d serve` in its own process on an emulated board in this one, with a ROS peer that
follows the arm's state: the rig of the tests that talk to a server over real DDS.

`served` gives the peer the arm's states; `commanded` gives it a writer on the server's
`joint_commands`, as ros2_control's topic-based hardware has."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from al5d.arm.config import ArmConfig
from al5d.ros.qos import QOS_LATCHED
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator, Record
from al5d_rig.proc import Proc, patient_config
from al5d_rig.rospeer import Peer, wait_until


class StopBursts:
    """The bursts of STOPs the board should get for the stops `peer` asks of the server in
    `proc` from now on: one per stop request sent (`Peer.trigger` asks again after a second
    unanswered)."""

    def __init__(self, peer: Peer, proc: Proc) -> None:
        self.peer, self.proc = peer, proc
        self.asked = peer.stops_asked

    def expected(self, on_topic: int = 0) -> int:
        """The bursts due so far with `on_topic` stops sent on the instruction topic."""
        return self.peer.stops_asked - self.asked + on_topic

    def check(self, stops: Callable[[], int], on_topic: int = 0, timeout_s: float = 5.0) -> None:
        """`stops()` (the STOP commands on the board since the first of these stops) is six
        to each burst due, no more, no fewer: compared again for a while, as a burst may
        still be on its way to the board."""
        deadline = time.monotonic() + timeout_s
        while True:
            due = self.expected(on_topic)
            got = stops()
            if got == 6 * due:
                return
            if time.monotonic() > deadline:
                said = self.proc.err.drain(0)
                raise AssertionError(
                    f"{got} STOPs on the board, {6 * due} due ({due} stop(s) sent); the "
                    "server said:\n" + "\n".join(said[-20:])
                )
            time.sleep(0.2)


@dataclass
class Served:
    proc: Proc
    emu: Emulator
    config: ArmConfig
    peer: Peer
    #: Every state `/al5d/state` said, the last one last.
    states: list[str]

    def ready(self, timeout: float = 30.0) -> Served:
        """The arm released and at rest, whatever the last test left: the reset between the
        tests of a module that shares one server (a restart costs seconds of discovery)."""
        wait_until(lambda: self.states and self.states[-1] in ("ready", "stopped"), timeout, "rest")
        if self.states[-1] == "stopped":
            assert self.peer.trigger("release").success
        wait_until(lambda: self.states[-1] == "ready", timeout, "ready")
        return self

    def stops(self) -> int:
        """STOP commands the board has received (six to a stop of the arm)."""
        return sum(isinstance(c, p.Stop) for r in self.emu.records for c in r.commands)


@contextmanager
def _serving(
    config: ArmConfig, workdir: Path, name: str, config_file: str, *args: str, namespace: str = ""
) -> Iterator[tuple[Emulator, Proc, Peer]]:
    """A board behind a link in `workdir`, `al5d serve` on it (not yet ready) with
    `config_file` and `args`, and a peer named `name` in `namespace`; all closed after."""
    link = workdir / "ssc32u"
    emu = Emulator(config, link=link).start()
    proc = Proc(
        "serve", "--port", str(link), "--config", config_file, "--log-level", "INFO", *args
    )  # fmt: skip
    peer = Peer(name=name, namespace=namespace)
    try:
        yield emu, proc, peer
    finally:
        peer.close()
        proc.kill()
        emu.close()


@contextmanager
def served(
    config: ArmConfig, workdir: Path, name: str, config_file: str | None = None
) -> Iterator[Served]:
    """A server on a board behind a link in `workdir`, ready, and a peer named `name` that
    has matched it; its configuration `config_file` (`patient_config()` unless given)."""
    config_file = config_file or patient_config()
    with _serving(config, workdir, name, config_file) as (emu, proc, peer):
        states: list[str] = []

        def on_state(msg: String) -> None:
            states.append(msg.data)

        peer.node.create_subscription(String, "/al5d/state", on_state, QOS_LATCHED)
        proc.err.wait_for("STATE: ready", 30)
        peer.wait_for_server()
        wait_until(lambda: states, 10, "the state")
        yield Served(proc, emu, config, peer, states)


@dataclass
class Commanded:
    """A server in a namespace, and a peer that publishes on its `joint_commands` as
    ros-controls' topic-based hardware (`JointStateTopicSystem`) or a teleoperation node
    does."""

    emu: Emulator
    proc: Proc
    peer: Peer
    config: ArmConfig
    commands: Publisher

    def command(
        self, degrees: Mapping[str, float], ident: str = "", **raw: list[Any]
    ) -> JointState:
        """Publish a command for `degrees` (the arm's) as the hardware would: the URDF's
        joint names and values, stamped; `raw` sets fields of the message as given."""
        values = self.config.model.to_urdf(dict(degrees))
        msg = JointState()
        msg.header.stamp = self.peer.node.get_clock().now().to_msg()
        msg.header.frame_id = ident
        msg.name = list(values)
        msg.position = [float(v) for v in values.values()]
        for name, value in raw.items():
            setattr(msg, name, value)
        self.commands.publish(msg)
        return msg

    def records(self, since: int = 0) -> list[Record]:
        return self.emu.records[since:]


@contextmanager
def commanded(
    config: ArmConfig, workdir: Path, name: str, namespace: str, config_file: str, *ros: str
) -> Iterator[Commanded]:
    """`al5d serve` with `config_file` in `namespace` (and the ROS arguments `ros`) on a
    board behind a link in `workdir`, ready, and a peer named `name` whose commands' writer
    has matched the server's reader."""
    ros_args = ("--ros-args", "-r", f"__ns:=/{namespace}", *ros)
    with _serving(config, workdir, name, config_file, *ros_args, namespace=namespace) as (
        emu,
        proc,
        peer,
    ):
        # JointStateTopicSystem's publisher: rclcpp::QoS(1), reliable, volatile.
        commands = peer.node.create_publisher(
            JointState, peer.names.joint_commands, QoSProfile(depth=1)
        )
        proc.err.wait_for("STATE: ready", 30)
        peer.wait_for_server()
        # Commands of 2 positions for 6 joints, which the server refuses, until one is answered.
        peer.until_answered(commands, lambda ident: _short_command(peer, ident))
        yield Commanded(emu, proc, peer, config, commands)


def _short_command(peer: Peer, ident: str) -> JointState:
    msg = JointState(position=[0.0, 0.0])
    msg.header.stamp = peer.node.get_clock().now().to_msg()
    msg.header.frame_id = ident
    return msg
