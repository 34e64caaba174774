"""An emulated SSC-32U on a pseudo terminal, faithful to the board's protocol and timing.

`Emulator` is the board's model (`board.Board`: commands, servos, inputs,
registers, answers, records) on its serial link (`pty.PtyLink`: a pty at the
client's baud, through the USB chip or a plain UART, `usb.LinkModel`). The modules:
`board` (the board's logic), `servo` (each servo's travel), `inputs` (the input
pins), `records` (every line received) and `measure` (what observers read of the
servos), `pty` and `usb` (the link), `virtual` (the board in this process on a virtual wire, for
the owner's core in virtual time, and `VirtualTransport`), `settings` (`al5d emulator`'s
values as text).
Use it as a context manager, or `start()` and `close()`:

    with Emulator(config, baud=9600) as emu:
        print(emu.port)          # open this with SSC32U or any serial program
        emu.records              # every line received, with its time of effect
        emu.servo_degrees()      # where the emulated servos are
        emu.set_input("A", 0)    # a switch on input A closes
        emu.inject(Fault.RESET)  # a brown-out
        emu.joint_degrees()      # the joints' true angles (`mechanics=`: a misaligned arm)
        emu.observe_pulses(f)    # f(channel, Pulse) at each change of what the servos get
"""

from __future__ import annotations

import os
import queue
import signal
import threading
from typing import TYPE_CHECKING, TextIO

from al5d.interrupts import wait_set
from al5d.ssc32u.emulator import settings
from al5d.ssc32u.emulator.board import (
    Answer,
    ArmDescription,
    Board,
    BoardSettings,
    Fault,
    Mechanics,
    Pulse,
    Record,
    ServoJoint,
)
from al5d.ssc32u.emulator.pty import PtyLink
from al5d.ssc32u.emulator.usb import UART, USB, LinkModel, Transport

if TYPE_CHECKING:
    from typing import Unpack  # Python 3.11; only read by the type checker

__all__ = [
    "UART",
    "USB",
    "ArmDescription",
    "BoardSettings",
    "Emulator",
    "Fault",
    "LinkModel",
    "Mechanics",
    "Pulse",
    "Record",
    "ServoJoint",
    "Transport",
    "serve_forever",
    "settings",
]


class Emulator(Board):
    """An SSC-32U on a pseudo terminal.

    `port` is the path a client opens (the `link` symlink when one is given,
    so that it survives a reconnect). `baud` is the board's own setting: a
    client at another baud is heard as noise, as with the real board.
    `usb` is the link's model: the board's USB port as it is by default
    (`USB`: an output flush drops nothing, a 16 ms latency timer), or `UART`
    for a plain serial line to the board's TTL header.
    The other keywords are the board's settings (`BoardSettings`, see `board.Board`).
    """

    def __init__(
        self,
        config: ArmDescription | None = None,
        *,
        link: str | os.PathLike[str] | None = None,
        usb: LinkModel = USB,
        **board: Unpack[BoardSettings],
    ) -> None:
        super().__init__(config, **board)
        self.usb = usb
        self._link = PtyLink(self, link, usb)

    # -- life cycle ------------------------------------------------------

    def start(self) -> Emulator:
        self._link.open()
        return self

    def close(self) -> None:
        self._link.remove_link()  # first: see inject
        self._link.close()

    def __enter__(self) -> Emulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def port(self) -> str:
        return str(self._link.link) if self._link.link is not None else self._link.device

    @property
    def device(self) -> str:
        """The pty slave itself (changes on reconnect)."""
        return self._link.device

    @property
    def bytes_heard(self) -> int:
        """How many bytes the client wrote that the link has read (since it was opened)."""
        return self._link.bytes_heard

    # -- faults on the link ---------------------------------------------------

    def inject(self, fault: Fault) -> None:
        """Start a fault. DISCONNECT closes the pty and takes its link away, as an unplugged
        adapter's device path goes: the client's I/O and opens fail until reconnect() (a
        board with no link has only its pty's path, which the next pty opened may take).
        RESET restarts the board now (see `reset`)."""
        super().inject(fault)
        if fault is Fault.DISCONNECT:
            # The link goes first: left to the closed pty's number, which the system gives
            # the next pty opened anywhere, a client reopening it opened that (a CI run: a
            # server reconnecting wrote VER and STOP to another test's terminal, and its
            # serial settings took the terminal's line ends away).
            self._link.remove_link()
            self._link.close()

    def reset(self, t: float | None = None, announce: bool | None = None) -> list[Answer]:
        """A brown-out and restart (see `Board.reset`); whatever the board sends, goes out."""
        answers = super().reset(t, announce)
        self._link.send(answers)
        return answers

    def reconnect(self) -> None:
        """Plug the adapter back in: a new pty behind the same link; the servos kept their state."""
        self.clear(Fault.DISCONNECT)
        if self._link.is_open:
            self._link.remove_link()  # first: see inject
            self._link.close()
        self._link.open()


def serve_forever(emulator: Emulator, stop: threading.Event, record: TextIO | None = None) -> None:
    """Run until `stop` is set (used by `al5d emulator`); the device path is the first line
    of stdout. With `record`, every line the board receives is written there as JSON, with
    its time of effect (CLOCK_MONOTONIC), by a thread of its own so the board never waits.
    In the main thread, SIGUSR1 resets the board (a brown-out), for programs under test."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGUSR1, lambda signum, frame: emulator.inject(Fault.RESET))
    lines: queue.SimpleQueue[Record | None] = queue.SimpleQueue()
    writer = None
    if record is not None:
        out = record

        def write() -> None:
            while (rec := lines.get()) is not None:
                out.write(rec.to_json() + "\n")
                if lines.empty():
                    out.flush()

        writer = threading.Thread(target=write, name="ssc32u-record", daemon=True)
        writer.start()
        for rec in emulator.records:  # the power-up's (its startup string), before the link
            lines.put(rec)
        emulator.record_listeners.append(lines.put)
    with emulator:
        print(emulator.port, flush=True)
        wait_set(stop)  # set by a signal's handler, which this main thread must run
    if writer is not None:
        lines.put(None)
        writer.join(5)
