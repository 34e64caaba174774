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

#: Ignored anywhere in a command (UG-24), so clients that end lines with CR LF work.
BLANKS: Final = b" \t\n"

# -- inputs (UG-33, UG-34) ----------------------------------------------------

#: Pins read as digital inputs (`A`..`F`, latched `AL`..`FL`); G and H are analog only.
DIGITAL_PINS: Final = "ABCDEF"
#: Pins read as analog inputs (`VA`..`VH`).
ANALOG_PINS: Final = "ABCDEFGH"
#: A digital read answers one ASCII byte per pin, no CR.
LOW: Final = b"0"
HIGH: Final = b"1"
#: An analog read answers one byte per pin: 0 = 0 V, 255 = 4.98 V.
ANALOG_MAX: Final = 255
#: A digital read changes only once the pin has held its new level this long.
DEBOUNCE_S: Final = 0.015
#: Where the emulator puts a digital input's threshold on the analog scale. Our choice:
#: an AVR input switches somewhere between 0.3 and 0.6 of its supply; this is the middle.
DIGITAL_THRESHOLD: Final = 128
#: The first `V*` read of a pin since power-up "will not return valid data" (UG-34);
#: the emulator answers this (our choice: the filter of a pin just made analog starts at 0).
ANALOG_FIRST_READ: Final = 0

# -- registers (UG-34, UG-36..37) ---------------------------------------------

#: `R<n>` and `R<n>=<v>`: n is 0..255; values are 16 bits, read back as written
#: (`R0=1023`, `R32=-50` in the guide).
REGISTERS: Final = range(256)
REGISTER_VALUES: Final = range(-32768, 65536)
#: R0, the enable register: which stored settings the board applies at power-up.
R_ENABLE: Final = 0
ENABLE_STARTUP_STRING: Final = 1 << 0
ENABLE_TX_PACING: Final = 1 << 1
ENABLE_PULSE_OFFSET: Final = 1 << 2
ENABLE_PULSE_WIDTH: Final = 1 << 3
ENABLE_GLOBAL_DISABLE: Final = 1 << 15
#: R4 holds the baud divided by 10 (UG-34).
R_BAUD: Final = 4
#: R32..R63: each channel's pulse offset at power-up (R32 is channel 0: the guide's
#: `R32 = -50` and RobotShop's support answers).
R_PULSE_OFFSET: Final = 32
#: R64..R95: each channel's pulse width at power-up, 0 for none. An inference: the block
#: after the offsets; the guide's register table was not at hand to confirm the number.
R_PULSE_WIDTH: Final = 64
#: `RDFLT` sets every register to its default, "may take over a second", then answers this.
DEFAULTS_TIME_S: Final = 1.0
DEFAULTS_DONE: Final = b"OK\r"

# -- the startup string (UG-39) -------------------------------------------------

#: Its longest; characters beyond are ignored.
STARTUP_MAX_CHARS: Final = 100
#: Ends every command in the startup string, the last one included.
STARTUP_END: Final = ";"
#: `SS` answers the string between these, then CR.
STARTUP_QUOTE: Final = b'"'

# -- the USB link: the SSC-32U's FTDI USB serial chip (AN232B-04) -------------------

#: A short answer waits in the chip until its latency timer runs out (16 ms by default).
LATENCY_TIMER_MS: Final = 16
LATENCY_TIMER_RANGE_MS: Final = range(1, 256)
#: What Linux sets the timer to when the host asks for low latency (ASYNC_LOW_LATENCY).
LOW_LATENCY_TIMER_MS: Final = 1
#: A full packet goes at once: 64 bytes, of which 2 are the chip's status.
USB_PACKET_PAYLOAD: Final = 62
