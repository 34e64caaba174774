"""The SSC-32U servo controller: its facts, its protocol, a driver and an emulator.

- `facts`: the board's numbers as data (bauds, pulse limits, timings, firmware name).
- `protocol`: the bytes of every command and answer, as pure functions.
- `errors`: what can go wrong on the serial link, named for what the user must check.
- `driver`: `SSC32U`, one method per board function; serial I/O stays inside.
- `wire`: the port's writes: one at a time, a stop's never waiting, moves paced to the
  wire (no more than a short horizon ahead of a stop), a recording's tap.
- `stopline`: the emergency stop written by another process: the port handed over, and
  both processes' writes kept in order.
- `emulator`: an SSC-32U on a pseudo terminal (a pure board model and its pty link).

This layer knows channels and pulse widths, never joints or degrees of an arm.
It imports nothing of al5d but `al5d.clock`; the emulator is imported only where
an emulated board is wanted (the server's embedded default, tests, the demo,
the benchmarks).
"""
