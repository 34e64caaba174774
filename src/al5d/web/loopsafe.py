"""viser's message buffers woken on their own event loop, whichever thread sends to the page.

viser 1.1.1's `AsyncMessageBuffer.push` sets its `message_event` (an `asyncio.Event`)
directly from the caller's thread before it hands the same `set` to the loop with
`call_soon_threadsafe`. `asyncio.Event` is not thread-safe: that direct `set` walks the
event's waiters while the loop's thread adds and removes them, and resolves their futures
off the loop. The page is drawn from the ROS thread (joint states, 25 a second), so under
load this once raised `RuntimeError: deque mutated during iteration` in the web view (a busy
CI run); on a debug loop every such push raises. Here each buffer's event is made one whose
`set` from another thread is only handed to the loop, as the next line of `push` does anyway.

It can go when viser's `push` no longer sets the event off its loop (pinned 1.1.1).
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

import viser


class LoopEvent(asyncio.Event):
    """An `asyncio.Event` that any thread may set: off the loop's thread, `set` goes to it."""

    home: asyncio.AbstractEventLoop

    def set(self) -> None:
        try:
            here = asyncio.get_running_loop()
        except RuntimeError:
            here = None
        if here is self.home:
            super().set()
            return
        # A closed loop raises: nothing waits on this event any more.
        with contextlib.suppress(RuntimeError):
            self.home.call_soon_threadsafe(super().set)


def make_loop_safe(buffer: Any) -> None:
    """Make a viser `AsyncMessageBuffer`'s `message_event` a `LoopEvent` of the buffer's loop.

    The event object stays the same (its class changes), so a window generator already
    waiting on it, a page that connected before this ran, is still woken.
    """
    event = buffer.message_event
    event.home = buffer.event_loop
    event.__class__ = LoopEvent


def install(server: viser.ViserServer) -> None:
    """Make the server's broadcast buffer and each connection's own buffer loop-safe.

    A connection's buffer is made so by an infra connect callback: viser 1.1.1 runs those
    before it starts the connection's sending (infra `ws_handler`).
    """
    ws: Any = server._websock_server
    make_loop_safe(ws.get_message_buffer())
    ws.on_client_connect(lambda conn: make_loop_safe(conn.get_message_buffer()))
