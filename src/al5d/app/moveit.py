"""`al5d moveit`: a MoveIt 2 config package for an arm, or for several arms as one robot,
written from their configs.

The shipped copy (`config/moveit/`) is this function's output for the shipped
config; a test regenerates it and compares, so the two cannot drift.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from al5d.app import moveit_package as pkg
from al5d.app.moveit_arms import ServedArm, arms_launch_files
from al5d.arm.config import ArmConfig, namespace_problem
from al5d.model import Chain, build_chain, moveit_config, urdf_from_chain, urdf_of_arms
from al5d.model import moveit as mv
from al5d.model.errors import InvalidInput

ROBOT = "al5d"
DEFAULT_PACKAGE = pkg.DEFAULT_PACKAGE


def arm_chain(config: ArmConfig, namespace: str | None = None) -> Chain:
    """The arm's links and joints as the server names them: frames prefixed `NS/` and
    joints by the arm's joint prefix (`server.joint_prefix`, else `NS_`), by `namespace`,
    or (None) by the configuration's `server.namespace`, as `al5d serve` takes it."""
    ns = _namespace(config, namespace)
    return build_chain(
        config.model,
        config.speeds_deg_s,
        prefix=f"{ns}/" if ns else "",
        joint_prefix=config.server.joint_prefix_in(ns),
    )


def _namespace(config: ArmConfig, namespace: str | None) -> str:
    return (config.server.namespace if namespace is None else namespace).strip("/")


def _yaml(data: object) -> str:
    return yaml.safe_dump(data, sort_keys=False)


def moveit_files(
    config: ArmConfig, namespace: str | None = None, package: str = DEFAULT_PACKAGE
) -> dict[str, str]:
    """Path in the package -> text: the whole MoveIt config package `package` for the arm
    in `namespace` (by default the configuration's). With a mount (`server.mount`) the
    URDF's root is the mount's parent frame, which MoveIt then plans in (and RViz shows)."""
    problem = pkg.package_name_problem(package)
    if problem:
        raise ValueError(problem)
    ns = _namespace(config, namespace)
    chain = arm_chain(config, ns)
    model = config.model
    mount = config.server.mount
    arm = mv.MoveItArm(model, chain, config.presets)
    files = {
        "package.xml": pkg.package_xml(package, ROBOT),
        "CMakeLists.txt": pkg.cmakelists(package),
        ".setup_assistant": pkg.setup_assistant(package, ROBOT),
        f"config/{ROBOT}.urdf": urdf_from_chain(chain, ROBOT, mount.frame() if mount else None)
        + "\n",
    }
    for name, content in moveit_config(model, chain, config.presets, robot_name=ROBOT).items():
        files[f"config/{name}"] = content if isinstance(content, str) else _yaml(content)
    threshold = mv.command_threshold(
        model, {name: joint.us_per_deg for name, joint in config.joints.items()}
    )
    files |= {
        pkg.ROS2_CONTROL_CONTROLLERS: _yaml(mv.ros2_control_controllers(arm)),
        "config/pilz_cartesian_limits.yaml": _yaml(mv.pilz_cartesian_limits()),
        "config/initial_positions.yaml": _yaml(mv.initial_positions(model, chain, config.presets)),
        # The controllers run at the rate the server publishes the state they act on.
        "config/ros2_controllers.yaml": _yaml(
            mv.ros2_controllers(
                chain,
                update_rate_hz=max(1, round(config.server.joint_state_rate_hz)),
                namespace=ns,
            )
        ),
        f"config/{ROBOT}.ros2_control.xacro": mv.ros2_control_xacro(chain, robot_name=ROBOT),
        f"config/{ROBOT}.urdf.xacro": mv.robot_xacro(
            robot_name=ROBOT, namespace=ns, threshold=threshold
        ),
        "config/moveit.rviz": pkg.rviz_config(mount.parent if mount else chain.root),
    }
    files |= pkg.launch_files(robot=ROBOT, package=package, namespace=ns)
    return files


@dataclass(frozen=True)
class Arm:
    """One arm of `al5d moveit --arms`: its namespace and its configuration (its mount, its
    joints' prefix, as its server runs with them)."""

    namespace: str
    config: ArmConfig


def arms_problem(arms: Sequence[Arm]) -> str | None:
    """Why `arms` cannot be one robot, or None: two at least, each in a namespace of its
    own and mounted in one shared frame."""
    if len(arms) < 2:
        return "--arms: name two arms at least (one arm: --namespace)"
    seen: set[str] = set()
    for arm in arms:
        ns = arm.namespace.strip("/")
        problem = namespace_problem(arm.namespace) if ns else f"--arms: {arm.namespace!r}"
        if problem or not ns:
            return problem or "--arms: each arm needs a namespace"
        if ns in seen:
            return f"--arms: {ns} is named twice"
        seen.add(ns)
    parents = {arm.config.server.mount.parent for arm in arms if arm.config.server.mount}
    unmounted = [arm.namespace for arm in arms if arm.config.server.mount is None]
    if unmounted:
        return (
            f"--arms: {', '.join(unmounted)} has no server.mount in its configuration: give "
            "each arm its place in the frame they share (NS=FILE, a file with server.mount)"
        )
    if len(parents) > 1:
        return f"--arms: the mounts name several parent frames ({', '.join(sorted(parents))}): one"
    return None


def moveit_files_of_arms(arms: Sequence[Arm], package: str = DEFAULT_PACKAGE) -> dict[str, str]:
    """Path in the package -> text: one MoveIt config package for several arms, each served
    in its namespace: one URDF of them all on their mounts, a planning group for each
    (`left_arm`, `left_gripper`) and `arms` for all, their controllers (the servers' own
    actions), the configurations the servers run with, and launch files that start the
    servers, merge their joint states and run move_group and RViz. ValueError says why
    they cannot be one robot."""
    problem = pkg.package_name_problem(package) or arms_problem(arms)
    if problem:
        raise ValueError(problem)
    chains = [arm_chain(arm.config, arm.namespace) for arm in arms]
    moveit_arms = [
        mv.MoveItArm(arm.config.model, chain, arm.config.presets, chain.joint_prefix)
        for arm, chain in zip(arms, chains, strict=True)
    ]
    mounts = [arm.config.server.mount for arm in arms]
    try:
        urdf = urdf_of_arms(
            [(chain, m.frame() if m else None) for chain, m in zip(chains, mounts, strict=True)],
            ROBOT,
        )
        data = mv.moveit_config_of(moveit_arms, robot_name=ROBOT)
    except InvalidInput as e:
        raise ValueError(f"--arms: {e}") from None
    groups = [a.group_prefix for a in moveit_arms]
    if len(set(groups)) < len(groups):
        raise ValueError("--arms: two arms' joints share a prefix (server.joint_prefix)")
    root = mounts[0].parent if mounts[0] else chains[0].root
    files = {
        "package.xml": pkg.package_xml(package, ROBOT, arms=True),
        "CMakeLists.txt": pkg.cmakelists(package),
        ".setup_assistant": pkg.setup_assistant(package, ROBOT),
        f"config/{ROBOT}.urdf": urdf + "\n",
        "config/pilz_cartesian_limits.yaml": _yaml(mv.pilz_cartesian_limits()),
        "config/moveit.rviz": pkg.rviz_config(root, group=mv.ARMS_GROUP),
    }
    for name, content in data.items():
        files[f"config/{name}"] = content if isinstance(content, str) else _yaml(content)
    served = []
    for arm in arms:
        ns = arm.namespace.strip("/")
        # The configuration its server runs with (the namespace it is written for).
        config = arm.config.model_dump(mode="json")
        config["server"]["namespace"] = ns
        files[f"config/arms/{ns}.yaml"] = _yaml(config)
        served.append(
            ServedArm(
                ns,
                f"config/arms/{ns}.yaml",
                arm.config.server.joint_prefix_in(ns),
                arm.config.server.joint_state_rate_hz,
            )
        )
    files |= arms_launch_files(robot=ROBOT, package=package, arms=served)
    return files


def write_moveit_config(
    out: str | Path,
    config: ArmConfig,
    namespace: str | None = None,
    package: str = DEFAULT_PACKAGE,
) -> list[Path]:
    """Write the package into `out` (made if missing); the paths written."""
    return write_files(out, moveit_files(config, namespace, package))


def write_files(out: str | Path, files: dict[str, str]) -> list[Path]:
    """Write a package's files into `out` (made if missing); the paths written."""
    folder = Path(out)
    written = []
    for name, text in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written
