"""Where the local lanes are: one Unix socket for each server, in a folder that is the user's
alone. The standard library only: `al5d send stop` imports it first."""

from __future__ import annotations

import os
import socket
from pathlib import Path


def folder() -> Path:
    """Where the lanes of this user's servers are: `$AL5D_RUNTIME_DIR`, else
    `$XDG_RUNTIME_DIR/al5d`, else `/tmp/al5d-<uid>`."""
    given = os.environ.get("AL5D_RUNTIME_DIR")
    if given:
        return Path(given)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "al5d"
    return Path(f"/tmp/al5d-{os.getuid()}")


def path(namespace: str = "", domain: str | None = None) -> Path:
    """The lane of the server of `namespace` on ROS domain `domain` (the environment's
    ROS_DOMAIN_ID, 0 by default): one server per name, as on ROS."""
    domain = domain if domain is not None else os.environ.get("ROS_DOMAIN_ID", "0")
    name = namespace.strip("/").replace("/", "_") or "_"
    return folder() / f"d{domain or 0}-{name}.sock"


def answers(lane: Path) -> bool:
    """Whether a server listens on `lane` (a lane left behind by a server that was killed
    takes no connection)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(0.5)
        try:
            sock.connect(str(lane))
        except OSError:
            return False
    return True


def namespaces(domain: str | None = None) -> list[str]:
    """The namespaces ("/" for none) of the servers on ROS domain `domain` whose lanes are
    here and take a connection (a lane left behind by a server that was killed does not)."""
    domain = domain if domain is not None else os.environ.get("ROS_DOMAIN_ID", "0")
    found = []
    for lane in sorted(folder().glob(f"d{domain or 0}-*.sock")):
        if answers(lane):
            name = lane.stem.split("-", 1)[1]
            found.append("/" if name == "_" else "/" + name.replace("_", "/"))
    return found
