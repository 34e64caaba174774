"""Ctrl-C held off while a step that must be whole runs (a send and its record).

Python raises KeyboardInterrupt between any two bytecodes of the main thread: in the
middle of a send, after the request went out and before the sender kept it, so that
whoever catches it cannot cancel what was sent.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


@contextlib.contextmanager
def ctrl_c_after() -> Iterator[None]:
    """Ctrl-C (SIGINT) that comes inside is raised as the block ends, not in its middle: an
    instruction is sent and kept as sent whole, or not sent, so that whoever catches the
    KeyboardInterrupt can cancel what was sent (seen: Ctrl-C in `al5d shell` as a move had
    just gone on the lane, before the client kept it: its outcome was never heard, and
    `al5d send` would not have cancelled it). A second Ctrl-C inside is raised at once.
    Where Python's own handler is not the one in place (another thread, a program's own
    handler), the block runs as it is."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield
        return
    came: list[int] = []

    def pressed(signum: int, frame: object) -> None:
        if came:  # a second Ctrl-C: a send that hangs (a lane's owner not reading) is left
            raise KeyboardInterrupt
        came.append(signum)

    signal.signal(signal.SIGINT, pressed)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if came:  # over any error of the block's: the user's Ctrl-C comes first
            raise KeyboardInterrupt
