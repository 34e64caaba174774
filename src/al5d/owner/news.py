"""What the owner tells of what its core did: to its listeners in this process (by its teller
thread) and to the lane's clients that watch it.

By the owner's thread alone, as `al5d.owner.conns` is: `al5d.owner.loop` carries each
effect of the core here once its own part (the bytes, the futures) is done. It also keeps
what a client that is not there yet is owed: the board's writes for a recorder that has not
connected, and the outcomes told while no ROS bridge heard them.
"""

from __future__ import annotations

import logging
import socket
from collections import deque
from collections.abc import Callable
from typing import Any

from al5d.arm.corestate import Announce, Posed
from al5d.arm.instruction import Instruction, Outcome
from al5d.arm.jobs import Sent
from al5d.arm.states import State
from al5d.clock import now
from al5d.owner import lane as ln
from al5d.owner.conns import Conn, Conns
from al5d.owner.teller import StateTold, Teller, tell

log = logging.getLogger("al5d")

#: The board's writes kept for a recorder that has not yet connected (`keep_wire`), at most:
#: its bridge connects within a second of the start, the park's writes are a handful.
WIRE_KEPT = 1000
#: The outcomes told while no ROS bridge heard them (one ended, the next not yet there),
#: kept for the next at most: so many, this long (s). Its clients' requests that the owner
#: halted as it went are answered on the result topic then, not never.
OUTCOMES_KEPT = 1000
OUTCOMES_KEPT_S = 120.0


class News:
    """The owner's news, told by `teller` to the listeners here and by `lanes` to the lane's
    watchers; with `keep_wire`, the board's writes are kept for the first recorder."""

    def __init__(self, teller: Teller, lanes: Conns, *, keep_wire: bool) -> None:
        self._teller = teller
        self._lanes = lanes
        self.outcome_listeners: list[Callable[[Outcome], None]] = []
        self.state_listeners: list[Callable[[State], None]] = []
        self.motion_listeners: list[Callable[[Sent], None]] = []
        self.pose_listeners: list[Callable[[Posed], None]] = []
        self.wire_listeners: list[Callable[[tuple[bytes, float, float]], None]] = []
        self.submit_listeners: list[Callable[[Instruction], None]] = []
        self.lapsed_listeners: list[Callable[[socket.socket], None]] = []
        #: The state told (logged, and to the state listeners), with its waits.
        self.announced = StateTold(State.INITIALIZING)
        #: With `keep_wire`, the board's writes until a recorder watches them (a lane client
        #: that says `recorder` in its hello), told to the first (`al5d serve --record` with
        #: ROS: the bridge records, and connects while the park may be on the wire
        #: already); None once told, or not kept.
        self._wire_kept: list[dict[str, Any]] | None = [] if keep_wire else None
        #: Outcomes told while no bridge heard them, once one has (`OUTCOMES_KEPT`).
        self._told_kept: deque[tuple[float, dict[str, Any]]] = deque(maxlen=OUTCOMES_KEPT)
        self._bridge_seen = False

    def submitted(self, instr: Instruction) -> None:
        """An instruction the owner has just taken, before it is judged."""
        if self.submit_listeners:
            self._teller.put(lambda: tell(self.submit_listeners, instr, "submit"))

    def wire(self, data: bytes, t: float, free_at: float) -> None:
        """Bytes written to the board at `t`, their last byte there at `free_at`."""
        if self.wire_listeners:
            self._teller.put(lambda: tell(self.wire_listeners, (data, t, free_at), "wire"))
        kept = self._wire_kept
        keep = kept is not None and len(kept) < WIRE_KEPT
        if keep or self._lanes.watching("wire"):
            message = {"op": "wire", "data": data.decode("latin-1"), "t": t, "free_at": free_at}
            self._lanes.news("wire", message)
            if keep and kept is not None:  # the recorder's, whoever else watches meanwhile
                kept.append(message)
                if len(kept) == WIRE_KEPT:
                    log.warning(
                        "no recorder has connected: the board's first %d writes are kept "
                        "for it, the later ones will be missing from the recording",
                        WIRE_KEPT,
                    )

    def outcome(self, outcome: Outcome) -> None:
        """An outcome for the outcome listeners and watchers (kept, while no bridge hears)."""
        if self.outcome_listeners:
            self._teller.put(lambda: tell(self.outcome_listeners, outcome, "outcome"))
        message = {"op": "told", "outcome": ln.outcome_out(outcome)}
        self._lanes.news("outcomes", message)
        if self._bridge_seen and not self._lanes.ros_watching("outcomes"):
            self._told_kept.append((now(), message))

    def state(self, effect: Announce, locked: bool) -> None:
        """An event of the state machine, and the state it left the arm in."""
        new, old, event = effect.new, effect.old, effect.event

        def told() -> None:
            log.debug("EVENT: %s", event.value)
            if new is not old:
                log.info("STATE: %s", new.value)
                tell(self.state_listeners, new, "state")
            self.announced.told(new)

        self._teller.put(told)
        if new is not old:
            message = {"op": "state", "state": new.value, "locked": locked}
            self._lanes.news("state", message)

    def moved(self, sent: Sent) -> None:
        """A step of a motion written to the board."""
        if self.motion_listeners:
            self._teller.put(lambda: tell(self.motion_listeners, sent, "motion"))
        if self._lanes.watching("motion"):
            message = {
                "op": "moved",
                "id": sent.instr.id,
                "name": sent.instr.name,
                "step": sent.step,
                "steps": sent.steps,
                "data": sent.data.decode("latin-1"),
                "t_submit": sent.t_submit,
                "t_write": sent.t_write,
                "motion": ln.motion_out(sent.motion),
            }
            self._lanes.news("motion", message)

    def posed(self, effect: Posed) -> None:
        """Where the arm is now known to be, or to be going."""
        if self.pose_listeners:
            self._teller.put(lambda: tell(self.pose_listeners, effect, "pose"))
        if self._lanes.watching("pose"):
            book = effect.book
            message = {
                "op": "posed",
                "pose": book.pose,
                "motion": None if book.motion is None else ln.motion_out(book.motion),
                "running": effect.running,
            }
            self._lanes.news("pose", message)

    def lapsed(self, sock: socket.socket) -> None:
        """A leased lane client lost for its silence: its socket, for the lapsed listeners."""
        self._teller.put(lambda: tell(self.lapsed_listeners, sock, "lapsed"))

    def welcomed(self, conn: Conn, recorder: bool) -> list[dict[str, Any]]:
        """What a client that said hello is owed beside its welcome: to the first `recorder`,
        the board's writes kept for it. A ROS bridge that watches the outcomes is seen."""
        kept: list[dict[str, Any]] = []
        if recorder and self._wire_kept is not None:  # told once, to the first recorder
            kept, self._wire_kept = self._wire_kept, None
        if conn.ros and "outcomes" in conn.watch:
            self._bridge_seen = True
        return kept

    def told_kept(self) -> list[dict[str, Any]]:
        """The outcomes told while no bridge heard them, newer than `OUTCOMES_KEPT_S`; each
        once (a new bridge asks, once its nodes publish what it is told)."""
        since = now() - OUTCOMES_KEPT_S
        kept = [message for t, message in self._told_kept if t >= since]
        self._told_kept.clear()
        return kept
