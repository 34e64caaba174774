"""`al5d moveit`: the MoveIt configuration files of an arm, written from its config.

The shipped copy (`config/moveit/`) is this function's output for the shipped
config; a test regenerates it and compares, so the two cannot drift.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from al5d.arm.config import ArmConfig
from al5d.model import Chain, build_chain, moveit_config, urdf_from_chain

ROBOT = "al5d"


def arm_chain(config: ArmConfig, namespace: str | None = None) -> Chain:
    """The arm's links and joints, its frames prefixed `NS/` as the server's TF frames
    are: by `namespace`, or (None) by the configuration's `server.namespace`, as
    `al5d serve` takes it."""
    ns = (config.server.namespace if namespace is None else namespace).strip("/")
    return build_chain(config.model, config.speeds_deg_s, prefix=f"{ns}/" if ns else "")


def moveit_files(config: ArmConfig, namespace: str | None = None) -> dict[str, str]:
    """File name -> text: the URDF and the four MoveIt files, for the arm in `namespace`
    (by default the configuration's). With a mount (`server.mount`) the URDF's root is the
    mount's parent frame, which MoveIt then plans in."""
    chain = arm_chain(config, namespace)
    mount = config.server.mount
    files = {
        f"{ROBOT}.urdf": urdf_from_chain(chain, ROBOT, mount.frame() if mount else None) + "\n"
    }
    for name, content in moveit_config(
        config.model, chain, config.presets, robot_name=ROBOT
    ).items():
        files[name] = (
            content if isinstance(content, str) else yaml.safe_dump(content, sort_keys=False)
        )
    return files


def write_moveit_config(
    out: str | Path, config: ArmConfig, namespace: str | None = None
) -> list[Path]:
    """Write the files into `out` (made if missing); the paths written."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in moveit_files(config, namespace).items():
        path = folder / name
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written
