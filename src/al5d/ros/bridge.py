"""The ROS 2 bridge: the server's nodes, in a process of their own, a client of the owner.

`al5d serve` (the owner of the board) starts it (`al5d.ros.processes`). It reads the
command line's ROS parameters and remaps (`RosStart`: the DDS profile, the context and
the node `al5d` with its parameters) and hands the owner the settings they make; then,
on the lane the owner gives it, it runs the nodes: `al5d` (the instruction, trajectory
and joint-command topics, the results and the state, the parameters), `al5d_robot`
(the description, joint states and transforms), `al5d_actions` (the move action and
MoveIt's controllers) and `al5d_safety` (the release and shutdown services, on a DDS
participant of its own). The stop service and the stop watcher are the stop's own
process (`al5d.ros.stopproc`); if that one cannot start or ends, this one serves the
stop too, and says so. It ends when the owner ends (its lane closes).

Its process is `al5d.app.bridgeproc`.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from typing import Any

from rclpy.context import Context
from rclpy.node import Node

from al5d.arm.config import ArmConfig, ConfigError
from al5d.owner.client import Remote
from al5d.priority import built_urgently
from al5d.ros import params
from al5d.ros.dds import acked, dds_profile, start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import NODE, SAFETY_NODE, Names
from al5d.ros.node import ActionsNode, ArmNode, RobotNode
from al5d.ros.params import Flags, Settings
from al5d.ros.safety import SafetyNode, StopNode

log = logging.getLogger("al5d")


#: The parameters rclpy declares on every node itself: not the user's.
RCLPY_OWN = ("use_sim_time", "start_type_description_service")


def parameter_overrides(context: Context, names: Names) -> dict[str, object]:
    """The parameter values the command line gives the node `al5d` (`-p`, `--params-file`,
    global and its own), as rcl resolves them for its name and namespace: declared from the
    overrides by a node of that name that lives only for this."""
    probe = Node(
        NODE,
        namespace=names.node_namespace,
        context=context,
        allow_undeclared_parameters=True,
        automatically_declare_parameters_from_overrides=True,
    )
    try:
        # rclpy 7.1 hands Parameter objects here, whatever its annotation says.
        found: dict[str, Any] = dict(probe.get_parameters_by_prefix(""))
        return {
            name: getattr(value, "value", value)
            for name, value in found.items()
            if name not in RCLPY_OWN
        }
    finally:
        probe.destroy_node()


class RosStart:
    """The bridge's ROS side before the arm: the DDS profile, the context and the node `al5d`
    with its parameters, from a command line's `--ros-args` (`args`, rclpy's argv: the
    program's name first), `al5d serve`'s flags, and the config file (or `base`, a config
    loaded already). `settings` is what the server then runs with; ConfigError with the
    config's message when a parameter cannot be taken (nothing is left running then)."""

    def __init__(
        self,
        args: Sequence[str] | None = None,
        flags: Flags | None = None,
        base: ArmConfig | None = None,
    ) -> None:
        flags = flags or Flags()
        self.args = list(args) if args else None
        given, remap = params.early_arguments(self.args, NODE)
        try:
            early = params.resolve(given, flags, remap, base)
        except ConfigError:
            # What rcl makes of the parameters is the word that counts: its refusal is
            # given below, once the node has them; the profile is then the file's.
            early = params.resolve({}, flags, remap, base)
        names = Names.of(early.namespace)
        backlog = early.config.server.instruction_backlog
        theirs = dds_profile((names.instruction, backlog))
        if theirs:
            log.warning(
                "Fast DDS profiles from %s: the instruction backlog and the transports are theirs",
                theirs,
            )
        self.context = start_context(self.args or [NODE])
        try:
            overrides = parameter_overrides(self.context, names)
            self.node = ArmNode(self.context, names)
            settings = params.resolve(overrides, flags, remap, base)
            self._same(early, settings)
            self.node.declare(settings)
        except BaseException:
            if hasattr(self, "node"):
                self.node.destroy_node()
            self.context.try_shutdown()
            raise
        self.settings = settings
        self.names = names

    def _same(self, early: Settings, settings: Settings) -> None:
        """What rcl made of the arguments is what `early_arguments` read of them, where the
        DDS profile depends on it (see `al5d.ros.params`)."""
        rcl = (self.node.get_namespace().strip("/"), settings.namespace.strip("/"))
        sized = (early.namespace.strip("/"), early.config.server.instruction_backlog)
        now = (settings.namespace.strip("/"), settings.config.server.instruction_backlog)
        if rcl[0] != rcl[1] or sized != now:
            raise ConfigError(
                f"{params.SOURCE}: the namespace and server.instruction_backlog were read as "
                f"{sized[0] or '/'!r} and {sized[1]} before DDS started (which sizes the "
                f"instruction reader then), but the node is in {rcl[0] or '/'!r} with "
                f"{now[1]}: give them as -r __ns:=/NS and -p NAME:=VALUE (or a params file's "
                "/** or al5d section), or in the config file"
            )

    def close(self) -> None:
        self.node.destroy_node()
        self.context.try_shutdown()


class Bridge:
    """The nodes with their executor threads, on the owner (`arm`, over the lane), under the
    names `start` resolved. `stop_here`: this process serves the stop service and the
    stop watcher too (the stop's own process is not there)."""

    def __init__(
        self, arm: Remote, start: RosStart, trace: str | None = None, stop_here: bool = False
    ) -> None:
        names = self.names = start.names
        self.arm = arm
        self.context = start.context
        self.node = start.node
        self.node.attach(arm)
        self.robot = RobotNode(arm, self.context, names)
        self.actions = ActionsNode(arm, self.context, names)
        self.node.appliers += [self.robot.set_rates, self.actions.set_rate]
        actions = self.actions
        for action in (actions.move_action, actions.trajectory_action, actions.gripper_action):
            action.refuse = self.node.refuse
            action.tell = self.node.results.put
        self.trace_path = trace
        if trace is not None:
            self.node.trace = events = []
            # ...and when each move's bytes were written: the server's share of the path.
            arm.motion_listeners.append(
                lambda sent: events.append((sent.instr.id, "write", int(sent.t_write * 1e9)))
            )
        # The release and shutdown services on a participant of their own, every thread of
        # it at the stop path's priority: the flood the node `al5d` takes, its results and
        # the actions' traffic never stand in the same queues as a safety request.
        args = start.args

        def build() -> tuple[Context, SafetyNode, Spinner, StopNode | None]:
            context = start_context(args or [SAFETY_NODE])
            safety = SafetyNode(arm, context, names)
            stop = StopNode(arm, context, names) if stop_here else None
            more: list[Node] = [stop] if stop is not None else []
            spinner = Spinner(safety, context, False, more, kind="single", urgent=True)
            return context, safety, spinner, stop

        self.safety_context, self.safety, self.safety_spinner, self.stop = built_urgently(
            "al5d-safety", build
        )
        self.node_spinner = Spinner(self.node, self.context, owns_context=False, kind="single")
        self.robot_spinner = Spinner(self.robot, self.context, owns_context=False)
        self.actions_spinner = Spinner(
            self.actions, self.context, owns_context=False, kind="single"
        )
        log.info(
            "ROS 2 node %s up (ROS_DOMAIN_ID=%s)",
            self.node.get_fully_qualified_name(),
            os.environ.get("ROS_DOMAIN_ID", "0"),
        )

    def close(self) -> None:
        # Let the last results (the shutdown's) reach their readers before the node goes.
        self.node.results.close()
        self.node.detach()
        self.robot.detach()
        acked([self.node.result_pub], 1.0)
        if self.stop is not None:
            self.stop.close()
        self.safety_spinner.close()
        self.safety_context.try_shutdown()
        self.node.reader.close()
        self.actions_spinner.close()
        self.robot_spinner.close()
        self.node_spinner.close()  # destroys the node `al5d`
        self.context.try_shutdown()
        if self.trace_path is not None and self.node.trace is not None:
            with open(self.trace_path, "w", encoding="utf-8") as f:
                # One JSON array a line: an id may hold any character.
                f.writelines(json.dumps(event) + "\n" for event in self.node.trace)
