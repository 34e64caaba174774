"""The server's ROS side put together: `RosStart` (the DDS profile, the context and the node
`al5d` with its parameters, before the arm exists) and `RosServer` (every node of
`al5d serve` on the driver, each with its thread; the nodes are `al5d.ros.node`'s, the
stop path `al5d.ros.safety`'s)."""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence

import rclpy

from al5d.arm.config import ArmConfig, ConfigError
from al5d.arm.driver import ArmDriver
from al5d.ros import params
from al5d.ros.dds import dds_profile, start_context
from al5d.ros.executors import Spinner
from al5d.ros.names import NODE, Names
from al5d.ros.node import ActionsNode, ArmNode, RobotNode
from al5d.ros.params import Flags, Settings
from al5d.ros.safety import SafetyPath, StopSetup
from al5d.ros.stopproc import Setup, StopProcess
from al5d.ros.workarounds import parameter_overrides

log = logging.getLogger("al5d")


class RosStart:
    """The server's ROS side before the arm: the DDS profile, the context and the node `al5d`
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
        # A recording's participant reads the server's topics through the transport.
        theirs = dds_profile((names.instruction, backlog), in_process=early.record is None)
        if theirs:
            log.warning(
                "Fast DDS profiles from %s: the instruction backlog and the transports are theirs",
                theirs,
            )
        self.context = start_context(self.args or [NODE])
        try:
            self.node = ArmNode(self.context, names)
            settings = params.resolve(parameter_overrides(self.node), flags, remap, base)
            self._same(early, settings)
            self.node.declare(settings)
        except BaseException:
            if hasattr(self, "node"):
                self.node.destroy_node()
            self.context.try_shutdown()
            raise
        self.settings = settings
        self.names = names
        # Started now, so that its imports and DDS start-up go on beside the board's.
        stops = StopSetup.of(settings.config)
        self.stop = StopProcess(Setup(stops, names.namespace, tuple(self.args or ())))

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
        """When the server does not start after all (its board cannot be opened)."""
        self.stop.close()
        self.node.destroy_node()
        self.context.try_shutdown()


class RosServer:
    """The nodes with their executor threads, for `al5d serve`: `al5d` for the instructions,
    the outputs and the parameters, `al5d_safety` for the release and the shutdown,
    `al5d_stop` for the stop service and stops on the topic (in the stop process),
    `al5d_actions` for the actions. `start`: the node `al5d` made already with the command
    line's parameters (`RosStart`); without it, one for the driver's config, in
    `namespace` (None: the config's)."""

    def __init__(
        self,
        driver: ArmDriver,
        trace: str | None = None,
        namespace: str | None = None,
        start: RosStart | None = None,
    ) -> None:
        if start is None:
            start = RosStart(flags=Flags(namespace=namespace), base=driver.config)
        names = self.names = start.names
        self.context = start.context
        self.node = start.node
        self.node.attach(driver)
        self.robot = RobotNode(driver, self.context, names)
        # The stop path's participant takes the same arguments: remaps, and the namespace.
        self.safety = SafetyPath(driver, names, start.args, start.stop)
        self.actions = ActionsNode(driver, self.context, names)
        self.node.appliers += [self.robot.set_rates, self.actions.set_rate]
        self.trace_path = trace
        if trace is not None:
            self.node.trace = []
            events = self.node.trace
            # ...and when each move's bytes were written: the server's share of the path.
            driver.motion_listeners.append(
                lambda sent: events.append((sent.instr.id, "write", int(sent.t_write * 1e9)))
            )
        # The node `al5d` is read by its own thread (its `Reader`), and its parameter
        # services answered by an executor of its own; the others have an executor and a
        # thread each. The stop path has a participant of its own.
        self.node_spinner = Spinner(self.node, self.context, owns_context=False, kind="single")
        self.robot_spinner = Spinner(self.robot, self.context, owns_context=False)
        self.actions_spinner = Spinner(
            self.actions, self.context, owns_context=False, kind="single"
        )

    def close(self) -> None:
        # Let the last results (the shutdown's) reach their readers before the node goes.
        self.node.results.close()
        self.node.detach()
        self.robot.detach()
        self.node.result_pub.wait_for_all_acked(rclpy.duration.Duration(seconds=1))
        self.safety.close()
        self.node.reader.close()
        self.actions_spinner.close()
        self.robot_spinner.close()
        self.node_spinner.close()  # destroys the node `al5d`
        self.context.try_shutdown()
        if self.trace_path is not None and self.node.trace is not None:
            with open(self.trace_path, "w", encoding="utf-8") as f:
                # One JSON array a line: an id may hold any character.
                f.writelines(json.dumps(event) + "\n" for event in self.node.trace)
