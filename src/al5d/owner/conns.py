"""The owner's side of the local lane's sockets: its clients' connections accepted, read,
written and dropped, and their leases kept, by the owner's thread alone.

What the clients ask is the owner's (`al5d.owner.loop`): here only bytes and lines come
and go, so that the owner reads as its inputs and its effects. Every socket is in the
owner's selector, the listening one with `"listen"` as its data, each client's with its
`Conn`.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import selectors
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from math import inf
from pathlib import Path
from typing import Any

from al5d.arm.validate import Ticket
from al5d.clock import now
from al5d.owner import lane as ln
from al5d.owner.where import answers

log = logging.getLogger("al5d")

#: A client's socket read at most this much in one turn (the stops in it are found first).
READ_BYTES = 32 * 1024
#: A client that reads nothing while this much waits for it is let go (a lost client).
OUT_MAX = 64 * 1024 * 1024


@dataclass(eq=False)
class Conn:
    """One client of the local lane."""

    sock: socket.socket
    ident: int
    name: str = "?"
    lines: ln.Lines = field(default_factory=ln.Lines)
    out: bytearray = field(default_factory=bytearray)
    watch: frozenset[str] = frozenset()
    tickets: dict[str, Ticket] = field(default_factory=dict)
    #: The clients this one speaks for (a bridge's ROS clients), by their keys: each a
    #: client of the core of its own, lost on its own (`gone`).
    subs: dict[str, int] = field(default_factory=dict)
    bye: bool = False
    #: It left by an error (its `bye` named it: `left_by`): what it commanded is halted,
    #: and the loss says why.
    left_by: str = ""
    #: It said hello, and was welcomed (once a connection).
    welcomed: bool = False
    #: It asks what came over ROS 2 (the bridge, the stop process; its hello says so): a
    #: recording has it from ROS, and is not told it again (`asked`).
    ros: bool = False
    writing: bool = False
    #: A write to it failed: its peer has closed (or failed). Nothing more is written, and
    #: what it sent before is still read, to its end (a `bye` among it, or not).
    broken: bool = False
    #: A leased client (its hello asked for it) not heard for this long is lost: a hung
    #: process's lane stays open and says nothing (0: not leased).
    lease_s: float = 0.0
    #: When it was last heard (the owner's clock), and the owner's stalls then (`Owner`'s
    #: `_stalled`): a host that stalled held the client's signs too, and the owner wakes
    #: first.
    heard: float = 0.0
    stalled: float = 0.0


class Conns:
    """The lane's connections, in the owner's `selector`: listening at `lane` (where no
    other server holds it), or only those adopted. `lost(conn, why)` is called for each
    connection dropped (`why` empty: it said goodbye) once it is closed; the client
    numbers (`new_ident`) are also those of the clients a connection speaks for."""

    def __init__(
        self,
        selector: selectors.BaseSelector,
        lost: Callable[[Conn, str], None],
        lane: Path | None = None,
    ) -> None:
        self.conns: dict[int, Conn] = {}
        self._selector = selector
        self._lost = lost
        self._idents = itertools.count(1)
        self._lane = lane
        self._inode: int | None = None
        self._listener = None if lane is None else _listen(lane)
        if lane is not None and self._listener is not None:
            self._inode = lane.stat().st_ino
            selector.register(self._listener, selectors.EVENT_READ, "listen")

    @property
    def path(self) -> Path | None:
        """The lane's socket, where it could be made."""
        return self._lane if self._listener is not None else None

    def new_ident(self) -> int:
        return next(self._idents)

    def watching(self, what: str) -> bool:
        return any(what in conn.watch for conn in self.conns.values())

    def ros_watching(self, what: str) -> bool:
        """Whether a client that speaks for ROS 2 (the bridge) watches `what`."""
        return any(conn.ros and what in conn.watch for conn in self.conns.values())

    def news(self, what: str, message: dict[str, Any]) -> None:
        """`message` to every connection that watches `what`."""
        line = b""
        for conn in list(self.conns.values()):
            if what in conn.watch:
                line = line or ln.dumps(message)
                self.write(conn, line)

    def accept(self) -> list[Conn]:
        """The clients waiting to connect (16 at most a turn), now connected."""
        assert self._listener is not None
        accepted: list[Conn] = []
        for _ in range(16):
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, OSError):
                break
            sock.setblocking(False)
            accepted.append(self.connect(sock))
        return accepted

    def connect(self, sock: socket.socket) -> Conn:
        """A client on `sock` (non-blocking)."""
        conn = Conn(sock, self.new_ident())
        self.conns[conn.ident] = conn
        self._selector.register(sock, selectors.EVENT_READ, conn)
        return conn

    def read(self, conn: Conn, stalled: float) -> list[dict[str, Any] | ln.LaneError]:
        """The lines `conn` has sent, each a message or what is wrong with it; none when it
        has closed (it is dropped). `stalled`: the owner's stalls so far, kept with when
        it was heard (its lease)."""
        try:
            data = conn.sock.recv(READ_BYTES)
        except BlockingIOError:
            return []
        except OSError:
            data = b""
        if not data:
            left = f"it left by {conn.left_by}" if conn.left_by else "its connection closed"
            self.drop(conn, "" if conn.bye else left)
            return []
        conn.heard, conn.stalled = now(), stalled
        return list(conn.lines.feed(data))

    def write(self, conn: Conn, line: bytes) -> None:
        if conn.ident not in self.conns or conn.broken:
            return
        conn.out += line
        if not conn.writing:
            self.flush(conn)

    def flush(self, conn: Conn) -> None:
        """What waits for `conn`, as much as its socket takes now (the rest when it is
        writable again)."""
        try:
            sent = conn.sock.send(conn.out)
        except BlockingIOError:
            sent = 0
        except OSError:
            # Not dropped here: a client that said `bye` and closed at once (`Remote.close`)
            # fails a write of news it was sent meanwhile before its `bye` is read, and it is
            # not lost (seen: a move halted as `with Client() as arm: arm.send(...)` ended).
            # Its socket is read to its end, which drops it as it went.
            conn.broken = True
            conn.out.clear()
            with contextlib.suppress(OSError):  # a peer that is still there reads its end
                conn.sock.shutdown(socket.SHUT_WR)
            if conn.writing:
                conn.writing = False
                self._selector.modify(conn.sock, selectors.EVENT_READ, conn)
            return
        del conn.out[:sent]
        waiting = bool(conn.out)
        if waiting != conn.writing:
            conn.writing = waiting
            events = selectors.EVENT_READ | (selectors.EVENT_WRITE if waiting else 0)
            self._selector.modify(conn.sock, events, conn)
        if len(conn.out) > OUT_MAX:
            self.drop(conn, f"it read nothing while {OUT_MAX} bytes waited for it")

    def lease_due(self, stalled: float) -> float:
        """When the first leased client's lease runs out (inf: none is leased)."""
        return min((_lease_end(c, stalled) for c in self.conns.values() if c.lease_s), default=inf)

    def lapsed(self, t: float, stalled: float) -> list[socket.socket]:
        """Each leased client not heard for its lease at `t`, the owner's own stalls since
        not counted (`stalled`: those so far), is lost (dropped); their sockets."""
        gone = []
        for conn in list(self.conns.values()):
            if conn.lease_s and t > _lease_end(conn, stalled):
                why = f"nothing heard from it for {conn.lease_s:g} s (hung or stopped)"
                # Told, where its socket takes it now: a client stopped and resumed (Ctrl-Z)
                # said its server had ended (an outside try), which was there all along.
                self.write(conn, ln.dumps({"op": "lost", "why": why}))
                self.drop(conn, why)
                gone.append(conn.sock)
        return gone

    def drop(self, conn: Conn, why: str) -> None:
        """A client has gone: said goodbye (`why` empty), or lost."""
        if self.conns.pop(conn.ident, None) is None:
            return
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(conn.sock)
        conn.sock.close()
        self._lost(conn, why)

    def close(self) -> None:
        """The owner's end: what waits for each client is sent (a second each at most), every
        socket closed, and the lane's path removed where it is still ours."""
        for conn in list(self.conns.values()):
            with contextlib.suppress(OSError):
                conn.sock.setblocking(True)
                conn.sock.settimeout(1.0)
                conn.sock.sendall(conn.out)
            conn.sock.close()
        self.conns.clear()
        if self._listener is not None:
            self._listener.close()
            # Only our own: a server started meanwhile on the same name may have taken the
            # path (it found no one listening), and its lane must stay.
            if self._lane is not None and self._inode is not None:
                with contextlib.suppress(OSError):
                    if self._lane.stat().st_ino == self._inode:
                        self._lane.unlink()


def _lease_end(conn: Conn, stalled: float) -> float:
    """When leased `conn`'s lease runs out: its lease from when it was last heard, the
    owner's own stalls since (`stalled` less those then) not counted."""
    return conn.heard + conn.lease_s + stalled - conn.stalled


def _listen(lane: Path) -> socket.socket | None:
    """The lane's socket, in a folder that is the user's alone; None (said) where another
    server holds it already."""
    lane.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    with contextlib.suppress(OSError):
        os.chmod(lane.parent, 0o700)
    if lane.exists():
        if answers(lane):
            log.warning(
                "another al5d server holds the local lane %s: this one is reached over ROS only",
                lane,
            )
            return None
        lane.unlink(missing_ok=True)  # a server that ended without removing it
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(lane))
    os.chmod(lane, 0o600)
    sock.listen(64)
    sock.setblocking(False)
    log.info("local lane: %s", lane)
    return sock
