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
    ROS_DOMAIN_ID, 0 by default): one server per name, as on ROS. `d0.sock` for no
    namespace, `d0-lab.left.sock` for `/lab/left`: a '.' is in no ROS name, so two
    namespaces never share a lane (with '_' for '/', `/lab_left`'s clients reached
    `/lab/left`'s arm)."""
    domain = domain if domain is not None else os.environ.get("ROS_DOMAIN_ID", "0")
    name = namespace.strip("/").replace("/", ".")
    return folder() / (f"d{domain or 0}-{name}.sock" if name else f"d{domain or 0}.sock")


def answers(lane: Path) -> bool:
    """Whether a server listens on `lane` (a lane left behind by a server that was killed
    takes no connection; one whose queue of untaken connections is full, a frozen
    server's, is there all the same)."""
    return probe(lane) is not None


def probe(lane: Path) -> bool | None:
    """Whether the server on `lane` takes a new connection now (a connection asked, closed
    at once): True, False where its queue of untaken connections is full (busy or
    stalled: a frozen process), None where no server is there."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(0.5)
        try:
            sock.connect(str(lane))
        except BlockingIOError:  # a full queue, at once: a Unix socket does not wait
            return False
        except OSError:
            return None
    return True


def namespaces(domain: str | None = None) -> list[str]:
    """The namespaces ("/" for none) of the servers on ROS domain `domain` whose lanes are
    here and take a connection (a lane left behind by a server that was killed does not)."""
    domain = domain if domain is not None else os.environ.get("ROS_DOMAIN_ID", "0")
    root = path("", domain)
    found = ["/"] if answers(root) else []
    named = [lane for lane in folder().glob(f"{root.stem}-*.sock") if answers(lane)]
    return found + sorted("/" + lane.stem.split("-", 1)[1].replace(".", "/") for lane in named)
