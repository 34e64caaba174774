"""When the page's 3D view may change: it waits while the server's state goes to the
browsers alone, and holds the arm's arrival at its target until the state it brings.

Why: viser's client applies a batch of GUI updates at once when nothing waits before
it, but one that moves something in the 3D view waits for the next frame the browser
draws (in software, on a machine without a GPU, 100 ms and more), and holds up every
batch behind it. A state that changes while the view is held reaches the browser at
once. Called by the page (page.py) under its lock.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import viser

#: After a change of the server's state the 3D view (the arm, the ghost) waits this long,
#: then shows the newest pose: the state goes to the browser at once, in a batch of viser's
#: of its own. An instruction seen and an outcome hold the 3D view as well: a state comes
#: with them (the ghost they change would go just before it).
STATE_ALONE_S = 0.04
#: ... and at most this long for viser to send the state's batch (a busy host can keep its
#: event loop waiting longer than STATE_ALONE_S): a browser that takes nothing is not
#: left without its 3D view.
STATE_SENT_WITHIN_S = 0.5
#: The arm's arrival at its last target (within ARRIVED_DEG on every joint) comes 0-35 ms
#: before the server's READY: a pose sent then would wait for the browser's next frame with
#: READY behind it. The view holds the arrival until the state changes, for at most this long.
ARRIVED_DEG = 0.5
ARRIVAL_HELD_S = 0.15


def arrived(degrees: Mapping[str, float], target: Mapping[str, float]) -> bool:
    """Every joint of `target` within ARRIVED_DEG of it."""
    return all(abs(degrees.get(j, math.inf) - v) <= ARRIVED_DEG for j, v in target.items())


class ViewHold:
    """The 3D view's hold on one viser server."""

    def __init__(self, server: viser.ViserServer) -> None:
        self._server = server
        #: Until when the view waits (STATE_ALONE_S), and until when the arrival waits for
        #: the state (ARRIVAL_HELD_S).
        self._until = -math.inf
        self._arrival_until = -math.inf
        #: The state's message in viser's outgoing buffer, until viser has taken it into a
        #: batch for every browser (None: taken), and until when the view waits for that.
        self._state_message: int | None = None
        self._state_sent_by = -math.inf

    def hold(self) -> None:
        """A state is coming (an outcome, an instruction seen): the view waits a moment."""
        self._until = max(self._until, time.monotonic() + STATE_ALONE_S)

    def arrival(self) -> None:
        """The arm has arrived at its last target: the view waits for the state it brings."""
        self._arrival_until = time.monotonic() + ARRIVAL_HELD_S

    def state_sent(self) -> None:
        """A state has gone into viser's buffer: the view waits until viser has taken it
        into a batch for every browser (at most STATE_SENT_WITHIN_S), and a moment more."""
        self._arrival_until = -math.inf  # what it waited for has come
        self.hold()
        self._state_message = self.outgoing().message_counter - 1
        self._state_sent_by = time.monotonic() + STATE_SENT_WITHIN_S

    def held(self) -> bool:
        now = time.monotonic()
        if self._state_message is not None:
            cursors = list(self.outgoing().generator_cursors.values())
            if now < self._state_sent_by and any(c < self._state_message for c in cursors):
                return True
            self._state_message = None
        return now < max(self._until, self._arrival_until)

    def outgoing(self) -> Any:
        """viser's buffer of the messages for every browser (viser 1.1.1's, not public):
        its `message_counter` numbers them, its `generator_cursors` say, for each browser,
        up to which one it has taken them into a batch."""
        return self._server._websock_server.get_message_buffer()
