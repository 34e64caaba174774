"""The SSC-32U servo controller: its facts, its protocol, its transport, a driver and an
emulator.

- `facts`: the board's numbers as data (bauds, pulse limits, timings, firmware name).
- `protocol`: the bytes of every command and answer, as pure functions.
- `errors`: what can go wrong on the serial link, named for what the user must check.
- `transport`: the board behind one small interface (`Transport`: bytes in, bytes out,
  who wrote them); `SerialTransport`, a port through pyserial.
- `driver`: `SSC32U`, one method per board function, for tools (`al5d doctor`, tests);
  the arm's server writes through its owner instead.
- `emulator`: an SSC-32U on a pseudo terminal, or in process on a virtual wire (a pure
  board model and its links).

This layer knows channels and pulse widths, never joints or degrees of an arm.
It imports nothing of al5d but `al5d.clock`; the emulator is imported only where
an emulated board is wanted (the server's embedded default, tests, the demo,
the benchmarks).
"""
