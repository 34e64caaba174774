"""The SSC-32U's facts as data: bauds, channels, pulse limits, timings and its firmware name.

Sources: the Lynxmotion SSC-32U user guide ("UG-n" pages) and the board's USB
link; where a number is our choice rather than the board's, it says so.
"""

from __future__ import annotations

from typing import Final

#: The bauds the board can be set to (a button on the board, kept in EEPROM).
BAUDS: Final = (9600, 38400, 115200)
FACTORY_BAUD: Final = 9600
#: 8N1: a start bit, 8 data bits and a stop bit.
BITS_PER_BYTE: Final = 10

CHANNELS: Final = range(32)
PULSE_MIN_US: Final = 500
PULSE_MAX_US: Final = 2500
PULSE_CENTRE_US: Final = 1500
#: `P0` switches a channel's pulses off (the servo goes limp).
PULSE_OFF: Final = 0
#: `QP` answers pulse width / 10: a read-back has 10 us resolution.
QP_RESOLUTION_US: Final = 10
#: `#<ch>PO<offset>`: the volatile trim, in us.
OFFSET_RANGE: Final = range(-100, 101)
#: The largest `T` of a group move (UG-25).
TIME_MAX_MS: Final = 65535

#: The board answers a query after 50 us to 5 ms (UG-33).
ANSWER_DELAY_MIN_S: Final = 50e-6
ANSWER_DELAY_MAX_S: Final = 5e-3
#: What `VER` answers starts with this on every SSC-32 firmware.
FIRMWARE_PREFIX: Final = "SSC32"
#: The firmware string of the board we model (what a USB SSC-32U answers to VER).
FIRMWARE: Final = "SSC32-V2.50USB"

#: Answers of `Q` (UG-33): one byte, no CR.
MOVING: Final = b"+"
DONE: Final = b"."
