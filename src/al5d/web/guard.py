"""Who may open the page's websocket: the page itself, reached by a name we listen on.

A websocket is not bound by the browser's same-origin policy: any web site open
in the user's browser could connect to ws://127.0.0.1:8080 and move the arm
(cross-site WebSocket hijacking), and a site whose name is made to resolve to
127.0.0.1 could even load the page itself (DNS rebinding). viser checks neither,
so every connection is checked before its first message is read: its Origin must
be the page's own (the Host it asked for), and that host must be a name of this
machine that we listen on: a loopback name when listening on loopback.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
from collections.abc import Callable, Iterable
from typing import Any
from urllib.parse import urlsplit

import viser

log = logging.getLogger("al5d.web")

LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})


def is_loopback(host: str) -> bool:
    """Whether `host` (a name or an address, as --host takes it) is this machine only."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _hostname(authority: str) -> str:
    """`name` of `name:port`, `[::1]:8080` -> `::1`, lower case."""
    parsed = urlsplit(f"//{authority}")
    return (parsed.hostname or "").lower()


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def allowed_hosts(listen_host: str) -> frozenset[str] | None:
    """The host names a page may be reached by; None: any IP address or this machine's name
    (listening on every interface, we cannot know the names the network gives us)."""
    if is_loopback(listen_host):
        return frozenset({*LOOPBACK_NAMES, "127.0.0.1", "::1"})
    if listen_host in ("0.0.0.0", "::", ""):
        return None
    return frozenset({listen_host.lower().strip("[]"), *LOOPBACK_NAMES, "127.0.0.1", "::1"})


def connection_problem(
    origin: str | None, host: str | None, hosts: Iterable[str] | None
) -> str | None:
    """Why a websocket with these Origin and Host headers may not drive the arm, or None."""
    if not origin or not host:
        return "no Origin or Host header"
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or parts.netloc.lower() != host.lower():
        return f"origin {origin[:80]!r} is not this page ({host[:80]!r})"
    name = _hostname(host)
    if hosts is None:
        ok = _is_ip(name) or is_loopback(name) or name in _machine_names()
    else:
        ok = name in hosts or (name.startswith("127.") and _is_ip(name))
    return None if ok else f"host name {name[:80]!r} is not one this page listens on"


def _machine_names() -> set[str]:
    return {socket.gethostname().lower(), socket.getfqdn().lower()}


def install(server: viser.ViserServer, listen_host: str) -> Callable[[int], bool]:
    """Close every websocket that fails `connection_problem`, before its first message.
    Returns whether a client id is one let in (and still connected): viser's own connect
    callbacks come later (at a client's first camera message), and count a page only if
    this says so, whatever the order of the two.

    viser 1.1.1 runs its infra connect callbacks before it reads a connection's messages
    (infra `ws_handler`); the connection object with the request's headers is the
    one it keeps in `_live_connections` (pinned version: tests/test_web.py checks it).
    """
    ws: Any = server._websock_server
    hosts = allowed_hosts(listen_host)
    accepted: set[int] = set()

    async def check(conn: Any) -> None:
        connection = ws._live_connections.get(conn.client_id)
        if connection is None:
            return
        headers = connection.request.headers
        problem = connection_problem(headers.get("Origin"), headers.get("Host"), hosts)
        if problem is not None:
            log.warning("web: refused a connection from %s: %s", connection.remote_address, problem)
            await connection.close(1008, "al5d web: not this page")
        else:
            accepted.add(conn.client_id)

    async def gone(conn: Any) -> None:
        accepted.discard(conn.client_id)

    ws.on_client_connect(check)
    ws.on_client_disconnect(gone)
    return accepted.__contains__
