"""What is typed at `al5d shell`'s terminal while a line of it runs: a stop goes at once,
the rest waits its turn at the prompt (`TypedAhead`)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import struct
import termios
import threading
from collections.abc import Callable, Iterator

from al5d.arm.instruction import is_stop

#: How long the prompt waits for the answer of a stop typed as its line ended (the answer
#: is said when it comes, all the same).
TYPED_STOP_SAID_S = 1.0


class TypedAhead:
    """At a terminal, the lines typed while a line of the shell runs (the terminal's own
    line discipline has them whole, echoed): a stop among them goes at once, as Ctrl-C's
    does; the others wait their turn at the prompt, as typed ahead in a shell. (An outside
    try: `stop`, typed 1 s into a 5 s move, was read when the move had ended: the arm was
    never stopped, and locked 4 s later.)

    Only what the terminal holds is read (`FIONREAD`): the terminal drops what it holds at
    a Ctrl-C, and a read of more would wait for the next line (but for a Ctrl-C between
    the count and the read, microseconds). The reader ends before the prompt reads again
    (`watching`), but for one sending a stop, which reads nothing more."""

    def __init__(self, fd: int, say: Callable[[str], None]) -> None:
        self.fd = fd
        self.say = say  # a line typed ahead, drawn after a prompt when its turn comes
        self.lines: list[str] = []
        #: Text the terminal gave without its line's end (typed before a Ctrl-D, or the
        #: rest of a paste): put back after the next prompt, to be ended there.
        self.unfinished = ""
        self.ended = False  # Ctrl-D typed meanwhile: the input ends after `lines`

    @contextlib.contextmanager
    def watching(self, stop: Callable[[], None]) -> Iterator[None]:
        """While the body runs, typed lines are read: `stop` is called (in the reader's
        thread) for a stop, the rest kept. A stop's answer is waited for a moment after."""
        done = threading.Event()
        reader = threading.Thread(
            target=self._read, args=(done, stop), name="al5d-typed-ahead", daemon=True
        )
        reader.start()
        try:
            yield
        finally:
            done.set()
            reader.join(TYPED_STOP_SAID_S)

    def _read(self, done: threading.Event, stop: Callable[[], None]) -> None:
        while not done.is_set():
            # The wait only bounds how long `done` goes unseen: a line typed wakes it.
            if not select.select([self.fd], [], [], 0.05)[0] or done.is_set():
                continue
            held = struct.unpack("i", fcntl.ioctl(self.fd, termios.FIONREAD, b"\0" * 4))[0]
            # Nothing held, yet readable: a Ctrl-D at the start of a line, read at once
            # (or, just after the select, a line: whole in one read).
            data = os.read(self.fd, held or 4096)
            if not data:
                self.ended = True  # stops typed after it are still read
                continue
            # The last piece, unless empty, is text without its line's end. Each read's is
            # its own: joined to the next read, a `stop` typed later would be no stop.
            *whole, rest = data.decode(errors="replace").split("\n")
            for line, ended in [(w, True) for w in whole] + ([(rest, False)] if rest else []):
                words = line.split("#", 1)[0].split()
                if words and is_stop(words[0]):
                    stop()
                elif ended:
                    self.lines.append(line)
                else:
                    self.unfinished += line

    def drop(self) -> None:
        """A Ctrl-C drops what was typed ahead, as the terminal drops what it holds."""
        self.lines.clear()
        self.unfinished = ""
        self.ended = False
