"""What can go wrong between the computer and the board, named for what the user must check.

    SerialFault                 the link to the board failed (catch this one for all)
    +-- PortUnavailable         the port cannot be opened: check the path and who holds it
    +-- NotAnSSC32U             the device does not answer like an SSC-32U: check the
    |                           port and the baud rate (the board's button)
    +-- LinkLost                the open port failed (unplugged, I/O error): check the
    |                           cable; the arm driver reconnects by itself
    +-- NoAnswer                a query got no answer in time: check the board's power
    +-- GarbageAnswer           an answer that is not the board's: check the baud rate
    +-- BoardReset              the board restarted (a brown-out): check the servos'
                                power supply; the arm driver locks the arm

Each says what to check in its `advice`.
"""

from __future__ import annotations


class SerialFault(Exception):
    """The serial link to the board failed; the message says which port and what happened."""

    #: What the user should check; the messages of the errors a user must act on end with it.
    advice = ""

    def __init__(self, port: str, what: str, received: bytes = b"") -> None:
        self.port = port
        self.what = what
        self.received = received
        super().__init__(f"{port}: {what}")


class PortUnavailable(SerialFault):
    """The port cannot be opened (no such device, no permission, held by another program)."""

    advice = "check the port's path, its permissions, and that no other program holds it"


class NotAnSSC32U(SerialFault):
    """The device at the port does not answer `VER` like an SSC-32U (or the baud is wrong)."""

    advice = (
        "check the port, the baud rate (the board's button; `al5d doctor --port PORT` finds "
        "it) and the board's power"
    )


class LinkLost(SerialFault):
    """Reading or writing the open port failed: the adapter was unplugged, or an I/O error."""

    advice = "check the USB cable; the driver reconnects when the board is back"


class NoAnswer(SerialFault):
    """A query got no answer by its deadline, twice."""

    advice = "check the board's power (the USB chip answers without it, the board does not)"


class GarbageAnswer(SerialFault):
    """A query was answered with bytes the board would never send."""

    advice = "check the baud rate and the cable"


class BoardReset(SerialFault):
    """The board restarted (a brown-out under heavy servo current, say): its pulses are gone
    and it has forgotten where the servos were, so its next move would run at full speed."""

    advice = "check the servos' power supply: it must hold its voltage at full servo current"
