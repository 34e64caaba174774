"""`al5d moveit`: a MoveIt 2 config package for an arm, written from its config.

The shipped copy (`config/moveit/`) is this function's output for the shipped
config; a test regenerates it and compares, so the two cannot drift.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from al5d.app import moveit_package as pkg
from al5d.arm.config import ArmConfig
from al5d.model import Chain, build_chain, moveit_config, urdf_from_chain
from al5d.model import moveit as mv

ROBOT = "al5d"
DEFAULT_PACKAGE = pkg.DEFAULT_PACKAGE


def arm_chain(config: ArmConfig, namespace: str | None = None) -> Chain:
    """The arm's links and joints, its frames prefixed `NS/` as the server's TF frames
    are: by `namespace`, or (None) by the configuration's `server.namespace`, as
    `al5d serve` takes it."""
    ns = _namespace(config, namespace)
    return build_chain(config.model, config.speeds_deg_s, prefix=f"{ns}/" if ns else "")


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
        pkg.ROS2_CONTROL_CONTROLLERS: _yaml(mv.ros2_control_controllers()),
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


def write_moveit_config(
    out: str | Path,
    config: ArmConfig,
    namespace: str | None = None,
    package: str = DEFAULT_PACKAGE,
) -> list[Path]:
    """Write the package into `out` (made if missing); the paths written."""
    folder = Path(out)
    written = []
    for name, text in moveit_files(config, namespace, package).items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written
