"""Signals in the main thread: Ctrl-C held off while a step that must be whole runs (a send
and its record), and, in a command that cancels what it sent on Ctrl-C, while it cancels;
and a wait for what a signal's handler sets, which that handler always ends (`wait_set`).

Python raises KeyboardInterrupt between any two bytecodes of the main thread: in the
middle of a send, after the request went out and before the sender kept it, so that
whoever catches it cannot cancel what was sent; and, on a second Ctrl-C, in the middle
of the cancel the first one started (seen: two quick presses on `al5d run`, its moves
queued on the server ran on while it said only that it was interrupted).
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator

#: The press that leaves a command's cancel at once (the first asked for the cancel, the
#: ones after it up to this are counted and let be).
LEAVE_AT_PRESS = 3


class Presses:
    """SIGINT's handler for a command that cancels what it sent on Ctrl-C (`cancelling`): the
    first press raises KeyboardInterrupt (at the end of a `ctrl_c_after` block, inside one);
    the ones after it are counted, not raised, so that the cancel it started goes out
    whole, up to the `LEAVE_AT_PRESS`-th, which is raised at once (a cancel that waits on
    a server that does not answer can be left)."""

    def __init__(self) -> None:
        self.count = 0
        self.raised = False
        self._holding = 0
        self._held = False

    def __call__(self, signum: int, frame: object) -> None:
        self.count += 1
        if self.raised:
            if self.count >= LEAVE_AT_PRESS:
                raise KeyboardInterrupt
        elif self._holding and not self._held:
            self._held = True
        else:  # the first, or a second inside a hold (a send that hangs is left)
            self.raised = True
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def hold(self) -> Iterator[None]:
        self._holding += 1
        try:
            yield
        finally:
            self._holding -= 1
            if self._held and not self._holding and not self.raised:
                self.raised = True
                raise KeyboardInterrupt


@contextlib.contextmanager
def cancelling() -> Iterator[Presses | None]:
    """Ctrl-C inside, for a command that cancels what it sent (`al5d send`, `al5d run`): as
    `Presses` says; once one has come, Ctrl-C is ignored after the block, as the process
    ends. None where Python's own handler is not the one in place."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield None
        return
    presses = Presses()
    signal.signal(signal.SIGINT, presses)
    try:
        yield presses
    finally:
        # After a press the command has cancelled and said so, and ends: a press as it ends
        # would end the process by the signal (Python's finalization puts SIGINT's default
        # action back) instead of with the command's exit code.
        signal.signal(
            signal.SIGINT, signal.SIG_IGN if presses.raised else signal.default_int_handler
        )


@contextlib.contextmanager
def ctrl_c_after() -> Iterator[None]:
    """Ctrl-C (SIGINT) that comes inside is raised as the block ends, not in its middle: an
    instruction is sent and kept as sent whole, or not sent, so that whoever catches the
    KeyboardInterrupt can cancel what was sent (seen: Ctrl-C in `al5d shell` as a move had
    just gone on the lane, before the client kept it: its outcome was never heard, and
    `al5d send` would not have cancelled it). A second Ctrl-C inside is raised at once.
    Inside `cancelling`, its `Presses` hold; where neither Python's own handler nor that
    one is in place (another thread, a program's own handler), the block runs as it is."""
    handler = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is threading.main_thread() and isinstance(handler, Presses):
        with handler.hold():
            yield
        return
    if (
        threading.current_thread() is not threading.main_thread()
        or handler is not signal.default_int_handler
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


#: How often `wait_set` looks again: at most this late, a signal's handler runs.
SIGNAL_LOOK_S = 0.1


def wait_set(event: threading.Event, timeout: float | None = None) -> bool:
    """In the main thread, wait until `event` is set (by a signal's handler too) or
    `timeout` s have passed (None: no end); whether it was set.

    Python runs a signal's handler in the main thread, when that thread next runs. The
    kernel hands a process's signal to any of its threads, and where it is not the main
    thread, a main thread asleep in `Event.wait()` is not woken (seen: `al5d emulator`,
    stopped and continued beside two busy loops, left 2 SIGTERMs in 8 unheard until it
    was killed 10 s later, its main thread in `Event.wait()`). So the wait wakes each
    `SIGNAL_LOOK_S`."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        left = (
            SIGNAL_LOOK_S if deadline is None else min(SIGNAL_LOOK_S, deadline - time.monotonic())
        )
        if event.wait(max(0.0, left)):
            return True
        if deadline is not None and time.monotonic() >= deadline:
            return False
