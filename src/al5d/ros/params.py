"""`al5d serve`'s settings as ROS parameters of the node `al5d`, named after the config file's
keys and validated by the config's own code.

- `config_file`, `port`, `baud`, `record`: what `al5d serve`'s `--config`, `--port`,
  `--baud` and `--record` give (`baud` is the config's `server.baud`).
- `server.<key>` for every key of the config's `server` section, `server.mount.parent`,
  `server.mount.xyz` and `server.mount.rpy` for its mount, `geometry.<key>` for the arm's
  lengths. Joints and presets (calibration pairs, poses) stay in the file.

Precedence: the config file < the parameters (`-p`, `--params-file`, a launch file's
`parameters`) < `al5d serve`'s own flags. The namespace also comes from `-r __ns:=`, the
ROS way: a parameter `server.namespace` that disagrees with it is an error, as is a
`--namespace` that does.

Every parameter is read at start and read-only after, but the joint-state rates, which a
running server applies (`RUNTIME`). A value the config would refuse is refused with the
config's message, at start (the server exits 2) and at run time (set_parameters fails
with it as the reason).

Fast DDS reads its profile once, when the process's first node is made, and the profile
sizes the instruction topic's reader by its name (namespace) and the config's
`server.instruction_backlog` (`dds.dds_profile`). So those two, and the config file
that may hold them, are read from the command line before any node exists
(`early_arguments`, the forms rcl documents), and checked against what rcl makes of the
same arguments once the node `al5d` exists: a form read otherwise is an error, never a
reader sized for another topic.
"""

from __future__ import annotations

import os
import re
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from al5d.arm.config import (
    DEFAULT_CONFIG,
    ArmConfig,
    ConfigError,
    GeometrySettings,
    ServerSettings,
    load_config,
    on_embedded_board,
)
from al5d.arm.config import with_changes as config_with
from al5d.clock import Deadline
from al5d.ros.names import server_nodes

if TYPE_CHECKING:
    from rclpy.node import Node

    from al5d.ros.names import Names

#: Where a parameter's error comes from, in the config's messages.
SOURCE = "ROS parameters"
#: The parameters a running server applies; every other one is read-only.
RUNTIME = ("server.joint_state_rate_hz", "server.idle_joint_state_rate_hz")
TOP = ("config_file", "port", "baud", "record")
MOUNT = ("server.mount.parent", "server.mount.xyz", "server.mount.rpy")
#: Config keys that are not parameters of their own (`baud` gives `server.baud`; the
#: mount is three parameters).
_NOT_SERVER = ("baud", "mount")
#: Config keys a user knows by a parameter's name, in the config's messages.
RENAMED = {"server.baud": "baud"}
#: The sections whose names are the al5d's: a parameter under one that al5d does not
#: declare is a mistake (a typo), not another node's.
_OURS = ("server", "geometry", "joints", "presets")
#: rcl's flags that take a value, which is not a flag of their own.
_VALUE_FLAGS = ("--log-level", "--log-config-file", "-e", "--enclave")

PARAMETERS: tuple[str, ...] = (
    *TOP,
    *(f"server.{k}" for k in ServerSettings.model_fields if k not in _NOT_SERVER),
    *MOUNT,
    *(f"geometry.{k}" for k in GeometrySettings.model_fields),
)

_NS_RULE = re.compile(r"(?:([^:=]+):)?__ns:=(.*)")
_PARAM_RULE = re.compile(r"(?:([^:=]+):)?([^:=]+):=(.*)", re.DOTALL)


@dataclass(frozen=True)
class Flags:
    """`al5d serve`'s own options that a parameter may also give (None: not given)."""

    config: str | None = None
    port: str | None = None
    baud: int | None = None
    namespace: str | None = None
    record: str | None = None


@dataclass(frozen=True)
class Settings:
    """What the server runs with, every source resolved."""

    config: ArmConfig
    #: The serial device; None: the embedded emulator.
    port: str | None
    #: The config file read ("": the shipped one).
    config_file: str
    #: The MCAP file `al5d serve --record` writes; None: no recording.
    record: str | None = None

    @property
    def namespace(self) -> str:
        return self.config.server.namespace

    def values(self) -> dict[str, Any]:
        """Every parameter's value (what `ros2 param get` shows)."""
        server = self.config.server
        mount = server.mount
        out: dict[str, Any] = {
            "config_file": self.config_file,
            "port": self.port or "",
            "baud": server.baud,
            "record": self.record or "",
        }
        for key, value in server:
            if key not in _NOT_SERVER:
                out[f"server.{key}"] = value
        # What the arm's joints carry, the namespace's when none was given (a parameter
        # holds no None).
        out["server.joint_prefix"] = server.joint_name_prefix
        out["server.mount.parent"] = mount.parent if mount else ""
        out["server.mount.xyz"] = [float(v) for v in (mount.xyz if mount else (0, 0, 0))]
        out["server.mount.rpy"] = [float(v) for v in (mount.rpy if mount else (0, 0, 0))]
        for key, value in self.config.geometry:
            out[f"geometry.{key}"] = value
        return out


def _same_namespace(a: str, b: str) -> bool:
    return a.strip("/") == b.strip("/")


def _text(name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"{SOURCE}: {name}: must be a string (value: {value!r})")
    return value


def _unknown(names: Sequence[str]) -> list[str]:
    problems = []
    for name in names:
        if name in PARAMETERS or name.split(".", 1)[0] not in _OURS:
            continue
        if name.startswith(("joints.", "presets.")):
            why = "joints and presets are set in the config file only"
        elif name == "server.baud":
            why = "the baud rate is the parameter baud"
        else:
            why = "not a parameter of al5d (`ros2 param list` names them)"
        problems.append(f"{SOURCE}: {name}: {why}")
    return problems


def resolve(
    given: Mapping[str, Any],
    flags: Flags,
    remapped_ns: str | None = None,
    base: ArmConfig | None = None,
) -> Settings:
    """The settings from the parameters `given` (name -> value, those set), the flags, the
    namespace of a `__ns` remap, over the config file (`base`, or the file they name);
    ConfigError with the config's message, naming the parameter, when they cannot be."""
    problems = _unknown(list(given))
    if problems:
        raise ConfigError("\n".join(problems))
    config_file = flags.config or _text("config_file", given.get("config_file", "")) or ""
    # Said to clients as the whole path: a name relative to the server's directory, read
    # in a client's own, named another file there (`al5d calibrate` wrote that one).
    config_file = os.path.abspath(config_file) if config_file else ""
    port = flags.port or _text("port", given.get("port", "")) or None
    record = flags.record or _text("record", given.get("record", "")) or None
    if base is None:
        base = load_config(config_file or None)  # the file's own errors name the file
    # Typed as at run time (`wrong_type`): "40" for a rate was taken at the start, and
    # refused when set later; an integer for a number is that number, as there.
    declared = Settings(base, port, config_file, record).values()
    given = {k: float(v) if widened(declared.get(k), v) else v for k, v in given.items()}
    wrong = wrong_type(declared, given)
    if wrong:
        raise ConfigError(f"{SOURCE}: {wrong}")
    changes: dict[str, Any] = {}
    for name, value in given.items():
        if name in ("config_file", "port", "record") or name in MOUNT:
            continue
        changes["server.baud" if name == "baud" else name] = value
    mount = {k.rsplit(".", 1)[1]: v for k, v in given.items() if k in MOUNT}
    if mount:
        before = base.server.mount.model_dump() if base.server.mount else {}
        merged = {**before, **mount}
        changes["server.mount"] = merged if merged.get("parent", "world") != "" else None
    namespace = _namespace(given.get("server.namespace"), flags.namespace, remapped_ns)
    if namespace is not None:
        changes["server.namespace"] = namespace
    if flags.baud is not None:
        changes["server.baud"] = flags.baud
    config = config_with(base, changes, SOURCE, RENAMED) if changes else base
    if port is None:  # the parameters say what the server runs with
        config = on_embedded_board(config)
    return Settings(config, port, config_file, record)


def _namespace(param: Any, flag: str | None, remap: str | None) -> str | None:
    """The namespace the parameter, the flag and a remap give together (None: none of
    them: the file's); one that contradicts another is an error."""
    given = [
        (f"the remap __ns:={remap}", remap),
        (f"--namespace {flag}", flag),
        (f"server.namespace {param!r}", param if isinstance(param, str) else None),
    ]
    said = [(what, ns) for what, ns in given if ns is not None]
    for what, ns in said[1:]:
        if not _same_namespace(ns, said[0][1]):
            raise ConfigError(
                f"{SOURCE}: server.namespace: {said[0][0]} and {what} disagree; give one"
            )
    if flag is not None:
        return flag
    if remap is not None:
        return remap.strip("/")
    return None  # a parameter's (validated as a change) or the file's


def early_arguments(args: Sequence[str] | None, node: str) -> tuple[dict[str, Any], str | None]:
    """The parameters (name -> value) that a command line's `--ros-args` give the node named
    `node`, and the namespace a `__ns` remap gives it, read as rcl reads the usual forms
    (`-p [node:]name:=value`, `--params-file FILE` with `/**`, `node` or `/node` keys,
    `-r [node:]__ns:=/ns`), before any node exists. What rcl makes of them is checked once
    the node exists (`RosStart`)."""
    params: dict[str, Any] = {}
    namespace: str | None = None
    ros = False
    words = iter(args or ())
    for word in words:
        if word == "--ros-args":
            ros = True
        elif word == "--":
            ros = False
        elif not ros:
            continue
        elif word in ("-r", "--remap"):
            m = _NS_RULE.fullmatch(next(words, ""))
            if m and m[1] in (None, node) and namespace is None:  # rcl: the first rule wins
                namespace = m[2]
        elif word in ("-p", "--param"):
            m = _PARAM_RULE.fullmatch(next(words, ""))
            if m and m[1] in (None, node):
                params[m[2]] = _yaml_value(m[3])
        elif word == "--params-file":
            params.update(_params_file(next(words, ""), node))
        elif word in _VALUE_FLAGS:
            next(words, None)
    return params, namespace


def _yaml_value(text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text  # rcl refuses it, and says why, when the context starts


def _params_file(path: str, node: str) -> dict[str, Any]:
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except (OSError, yaml.YAMLError):
        return {}  # rcl says what is wrong with it when the context starts
    out: dict[str, Any] = {}
    if not isinstance(data, dict):
        return out
    for key in ("/**", node, f"/{node}"):
        body = data.get(key)
        if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict):
            out.update(_flat(body["ros__parameters"]))
    return out


def _flat(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


#: What a parameter's value is, by its type, as a refusal says it.
_KINDS = {bool: "true or false", int: "an integer", float: "a number", str: "text"}


def widened(was: Any, value: Any) -> bool:
    """Whether `value` is an integer given for a parameter of numbers (now `was`), taken as
    that number (`ros2 param set ... 40` for 40.0), at the start as at run time."""
    return type(was) is float and type(value) is int


def wrong_type(values: Mapping[str, Any], changes: Mapping[str, Any]) -> str:
    """Why a change (name -> value) is not of its parameter's type, its value now in
    `values` (`Settings.values`), or "". The parameters are declared with dynamic typing,
    so that rclpy takes 50 for 50.0 (the node sets it as the double:
    `ArmNode._as_declared`): it would also take "40" or true, and change the parameter's
    type (true set a rate to 1 Hz, `ros2 param get` then saying a boolean)."""
    for name, value in changes.items():
        was = values.get(name)
        if type(was) in _KINDS and type(value) is not type(was):
            got = "no value" if value is None else f"{_KINDS.get(type(value), 'a list')} {value!r}"
            return f"{name}: expected {_KINDS[type(was)]}, got {got}"
    return ""


def with_changes(settings: Settings, changes: Mapping[str, Any]) -> Settings | str:
    """The settings with parameters changed at run time (name -> value), or the config's
    reason to refuse them."""
    try:
        config = config_with(settings.config, changes, SOURCE, RENAMED)
    except ConfigError as e:
        return str(e)
    return Settings(config, settings.port, settings.config_file, settings.record)


DESCRIPTIONS = {
    "config_file": "the arm's configuration file ('': the shipped one)",
    "port": "the SSC-32U's serial device ('': the embedded emulator)",
    "baud": "the serial link's baud rate (the config's server.baud)",
    "record": "the MCAP file to record in, the board's bytes too ('': none)",
    "server.mount.parent": "the frame the arm's base_link is mounted in ('': no mount)",
    "server.mount.xyz": "base_link's origin in the mount's parent frame, metres",
    "server.mount.rpy": "base_link's roll, pitch, yaw in the mount's parent frame, radians",
}


def description(name: str) -> str:
    """What `ros2 param describe` says of a parameter."""
    what = DESCRIPTIONS.get(name, f"the config file's {name}")
    when = "changes apply at once" if name in RUNTIME else "read at start: restart to change"
    return f"{what}; {when}"


def served_config_file(node: Node, names: Names, timeout: float) -> Path | None:
    """The configuration file a running server was started with (its node's `config_file`;
    the shipped one for ""), asked by a client's `node`; None if that node does not answer
    within `timeout` (gone). The node is asked by the name the graph shows for it
    (`server_nodes`): a remap may have renamed it, and the file asked of a node `al5d`
    that is not there went unanswered, so the calibration was written unchecked."""
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import GetParameters

    deadline = Deadline(timeout)
    while not (found := server_nodes(node, names)) and not deadline.expired:
        time.sleep(0.05)
    if not found:
        return None
    timeout = deadline.left()
    # Kept until the node ends, and asked again the next time (the web view asks at each
    # calibration it writes).
    name = names.private("get_parameters", min(found))
    service = next((c for c in node.clients if c.srv_name == name), None)
    if service is None:
        service = node.create_client(GetParameters, name)
    if not service.wait_for_service(timeout_sec=timeout):
        return None
    done = threading.Event()
    future = service.call_async(GetParameters.Request(names=["config_file"]))
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout) or future.result() is None:
        service.remove_pending_request(future)
        return None
    values = future.result().values
    if not values or values[0].type != ParameterType.PARAMETER_STRING:
        return None
    served = str(values[0].string_value)
    return Path(served) if served else DEFAULT_CONFIG
