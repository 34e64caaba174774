"""A ROS client's side of its lease (`al5d.ros.leases` is the server's): the key it names in
what it sends, the lease sent a few times a second while it hears the server, and its
goodbye. The Python client's way (`al5d.ros.rosway`) and the web view's node
(`al5d.web.link`) both hold one, so that the server halts what either commanded once it
has lost them.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import secrets
import socket
import threading
import time
from collections.abc import Sequence
from typing import Any

from al5d_interfaces.msg import ClientLease
from rclpy.node import Node
from sensor_msgs.msg import JointState

from al5d.arm.config import MAX_CLIENT_LEASE_S
from al5d.ros.dds import acked
from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATEST, QOS_LEASES

#: A client over ROS 2 sends its lease this often (`al5d.ros.leases`), and takes the server
#: for lost when it has heard nothing from it (its joint states, 10 a second when idle)
#: for the server's lease (`server.client_lease_s`, 1 s unless the client has read the
#: server's configuration) and `LOST_AFTER_LEASE_S` more: by then the server, which
#: checks its leases every tenth of a second, has halted what this client commanded. With
#: equal times a move was done 80 ms after its sender had given up on it (a CI run).
LEASE_EVERY_S = 0.1
LOST_AFTER_LEASE_S = 0.5
#: How long a closing client waits for the server to have its last lease.
BYE_S = 0.5
#: A thread of a client that wakes this much later than it asked to was held, and the
#: process with it (stopped by Ctrl-Z or SIGSTOP, or starved by a busy host): what it
#: did not hear meanwhile is no silence of the server's.
HELD_S = LOST_AFTER_LEASE_S
#: A silence of the server's longer than this is kept (`Leaser.back`): shorter than one a
#: client says with the shipped lease (1 s), longer than the joint states' period (10 a
#: second at rest), so that those that follow it do not take its place.
GAP_S = 0.5

log = logging.getLogger("al5d")


def said_lease(config_json: str) -> float | None:
    """The lease (`server.client_lease_s`, s) in a server's configuration as it says it
    (JSON); None where it says none, or one its configuration's own check refuses (NaN or
    infinity: never lost)."""
    try:
        lease = float(json.loads(config_json)["server"]["client_lease_s"])
    except Exception:  # whatever the text: no lease said (an executor's callback)
        return None
    return lease if 0 < lease <= MAX_CLIENT_LEASE_S else None


def new_key(kind: str = "") -> str:
    """A client's key: its host, its process and a few random bytes (`kind` before them)."""
    return f"{kind}{socket.gethostname()[:40]}-{os.getpid()}-{secrets.token_hex(3)}"


class Leaser:
    """The lease of the client with key `key` on `names.clients`, sent by a thread of its own
    every `LEASE_EVERY_S` from creation until `close`, while the client hears the server.

    It hears the server's joint states on `node` (its holder may say it heard the server
    otherwise too: `sign`), whose executor must run no callback that waits long: one that
    did would hold the joint states back, and the lease with them, for a silence of the
    server that is not one. Silent for more than `LOST_AFTER_LEASE_S`, the lease is held
    back, so that where the link fails one way only (the server's frames lost, the
    client's still arriving) the server halts what this client commanded after its lease,
    as the client, giving up then, says it does. (An outside try: the client gave up and
    said so, its leases still came, and the move ran on to `done`.)"""

    def __init__(self, node: Node, names: Names, key: str) -> None:
        self.key = key
        #: When the server was last heard (monotonic s; None: not yet).
        self.heard: float | None = None
        #: The last silence of the server's longer than `GAP_S`: when it was heard before
        #: it and after it (monotonic s).
        self.back: tuple[float, float] | None = None
        #: When this client last found itself held (`woke`), for how long (s), and how many
        #: holds it has found.
        self.held_until: float | None = None
        self.held_for = 0.0
        self.holds = 0
        self._held_said = 0  # the last hold said (`say_held`)
        #: When the lease's thread last ran (monotonic s): see `silent_since`.
        self.looked = time.monotonic()
        self._holding = threading.Lock()  # the threads that wake together after a hold
        self._pub = node.create_publisher(ClientLease, names.clients, QOS_LEASES)
        node.create_subscription(JointState, names.joint_states, self.sign, QOS_LATEST)
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name="al5d-lease", daemon=True)
        self._thread.start()

    def sign(self, *_: object) -> None:
        """The server was heard now (a callback of any of its topics)."""
        t, heard = time.monotonic(), self.heard
        if heard is not None and t - heard > GAP_S:
            self.back = (heard, t)
        self.heard = t

    def deaf(self) -> bool:
        """The server heard once, and not for more than `LOST_AFTER_LEASE_S` since."""
        heard = self.heard
        return heard is not None and time.monotonic() - heard > LOST_AFTER_LEASE_S

    def silent_since(self) -> float | None:
        """Since when the server has been silent for this client (monotonic s): when it was
        last heard, or when this client was last held, whichever is later; None before
        it is first heard, or while this client may be held without knowing it yet (the
        lease's thread, which finds a hold, has not run for `HELD_S`: the threads of a
        process stopped and resumed wake in no set order, and the first to look would
        take its own stop for the server's silence)."""
        heard = self.heard
        if heard is None:
            return None
        if time.monotonic() - self.looked > HELD_S and self._thread.is_alive():
            return None  # (a thread that has ended finds no hold: judged by `heard` alone)
        return max(heard, self.held_until or heard)

    def woke(self, asked_at: float, within: float) -> None:
        """A thread of this client that asked at `asked_at` (monotonic s) to wake within
        `within` s has woken: if later than that by more than `HELD_S`, the client was held
        until now."""
        t = time.monotonic()
        if t - asked_at - within <= HELD_S:
            return
        with self._holding:
            if self.held_until is None or self.held_until < asked_at:
                self.holds += 1  # not one another thread has found already
                self.held_for = t - asked_at - within
            self.held_until = max(t, self.held_until or t)

    def say_held(self, lease_s: float) -> None:
        """Once a hold of this client longer than the server's lease of it (`lease_s`): the
        server took it for lost (an outside try: a client stopped for 4 s by Ctrl-Z said,
        resumed, 'lost contact with the server ... the link may be lost')."""
        with self._holding:
            if self.holds == self._held_said or self.held_for <= lease_s:
                return
            self._held_said, held_for = self.holds, self.held_for
        log.warning(
            "this client was held for %.1f s (its process stopped, by Ctrl-Z or SIGSTOP, or "
            "starved by a busy host): longer than the server's lease of it (%g s), so the "
            "server, if it is there, has taken it for lost, and halted what of this client's "
            "was still running",
            held_for,
            lease_s,
        )

    def _run(self) -> None:
        every_ms = round(LEASE_EVERY_S * 1000)
        asked = time.monotonic()
        while not self._closing.wait(LEASE_EVERY_S):
            self.woke(asked, LEASE_EVERY_S)
            asked = self.looked = time.monotonic()
            if not self.deaf():
                self._pub.publish(
                    ClientLease(client=self.key, sent_ns=time.time_ns(), every_ms=every_ms)
                )

    def close(self, sent_by: Sequence[Any] = (), left_by: str = "") -> None:
        """End the lease. Still in contact, say goodbye and wait a moment for what it sent
        (on `sent_by`, its writers) and that word to reach the server: a client it never
        hears close, it takes for lost. The goodbye names `left_by` where the client leaves
        without seeing what it commanded through (what made it leave: KeyboardInterrupt),
        and the server halts that at once; else what it commanded goes on. Out of contact,
        none: the server takes this client for lost once its lease has run out, and halts
        what it commanded, as this client said when it gave up."""
        # What it sent is received before its last word is sent: topics keep no order
        # between them, and a move come after the goodbye would run under a lease of its
        # own, halted (or not, after a `left_by`) only when that had run out. Its lease
        # goes on meanwhile: stopped first, a wait of a second for readers' acknowledgements
        # on a busy host let the lease run out before the goodbye (a CI run).
        if not self.deaf():
            with contextlib.suppress(Exception):
                acked(sent_by, BYE_S * len(sent_by))
        self._closing.set()
        self._thread.join()
        if self.deaf():
            return
        self._pub.publish(
            ClientLease(client=self.key, sent_ns=time.time_ns(), every_ms=0, left_by=left_by)
        )
        with contextlib.suppress(Exception):
            acked([self._pub], BYE_S)
