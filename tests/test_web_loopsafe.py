"""viser's message buffers are woken on their own loop (web/loopsafe.py): a page drawn from
the ROS thread never touches the loop's waiters from that thread."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import viser
import viser._messages as vm
import websockets.sync.client
from viser.infra._async_message_buffer import AsyncMessageBuffer

from al5d.web import loopsafe

WAIT_S = 20.0  # generous: a busy host


@pytest.fixture
def debug_loop() -> Iterator[asyncio.AbstractEventLoop]:
    """A running event loop in a thread of its own, in debug mode: there, an asyncio call
    made off the loop's thread raises at once instead of racing."""
    loop = asyncio.new_event_loop()
    loop.set_debug(True)
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    yield loop
    loop.call_soon_threadsafe(loop.stop)
    thread.join(WAIT_S)
    loop.close()


def _consumer(loop: asyncio.AbstractEventLoop, buffer: AsyncMessageBuffer) -> list[Any]:
    """Messages the buffer's window generator hands out, once it waits for more."""
    got: list[Any] = []

    async def consume() -> None:
        async for window in buffer.window_generator(0):
            got.extend(window)

    asyncio.run_coroutine_threadsafe(consume(), loop)
    deadline = time.monotonic() + WAIT_S
    while not buffer.message_event._waiters and time.monotonic() < deadline:  # type: ignore[attr-defined]
        time.sleep(0.01)
    assert buffer.message_event._waiters, "the window generator never waited"  # type: ignore[attr-defined]
    return got


def test_a_push_from_another_thread_is_handed_to_the_buffers_loop(
    debug_loop: asyncio.AbstractEventLoop,
) -> None:
    # viser's own buffer, as pinned: the push resolves the waiting generator's future from
    # this thread, which a debug loop refuses (the race of a busy CI run, made certain).
    plain = AsyncMessageBuffer(debug_loop, persistent_messages=True)
    _consumer(debug_loop, plain)
    with pytest.raises(RuntimeError, match="Non-thread-safe operation"):
        plain.push(vm.SetCameraFovMessage(fov=0.5))

    safe = AsyncMessageBuffer(debug_loop, persistent_messages=True)
    got = _consumer(debug_loop, safe)
    loopsafe.make_loop_safe(safe)  # while the generator already waits, as a page may
    for fov in (0.5, 0.6, 0.7):
        safe.push(vm.SetCameraFovMessage(fov=fov))
    deadline = time.monotonic() + WAIT_S
    while not (got and got[-1].fov == 0.7) and time.monotonic() < deadline:
        time.sleep(0.01)
    # One message a kind: viser keeps only the newest of messages that replace each other.
    assert got and got[-1].fov == 0.7


def test_a_served_pages_buffers_are_loop_safe_and_still_deliver() -> None:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        loopsafe.install(server)
        ws: Any = server._websock_server
        assert type(ws.get_message_buffer().message_event) is loopsafe.LoopEvent
        url = f"ws://127.0.0.1:{server.get_port()}"
        with websockets.sync.client.connect(
            url,
            subprotocols=[f"viser-v{viser.__version__}"],
            open_timeout=WAIT_S,  # type: ignore[list-item]
        ) as conn:
            # viser keeps the connection's state, then runs the connect callbacks (ours
            # among them), then starts its sending: the class changes in between.
            def swapped() -> bool:
                states = list(ws._client_state_from_id.values())
                return bool(states) and all(
                    type(st.message_buffer.message_event) is loopsafe.LoopEvent for st in states
                )

            deadline = time.monotonic() + WAIT_S
            while not swapped() and time.monotonic() < deadline:
                time.sleep(0.01)
            assert swapped(), "the connection's buffer was not made loop-safe"
            while True:  # what the server sends at once on a connection
                try:
                    conn.recv(timeout=1.0)
                except TimeoutError:
                    break
            server.scene.add_frame("/pushed_from_this_thread")
            assert conn.recv(timeout=WAIT_S)
    finally:
        server.stop()
