"""The arm: joints in degrees, limits, presets, the move queue and the safety states.

- `config`: the arm's configuration file (joints, calibration, servos, presets), validated.
- `servos`: the servo models an AL5D is built with, as a table.
- `instruction`: instructions and outcomes as data, and their text grammar.
- `validate`: whether an instruction can run, judged whole (pure).
- `translate`: degrees to pulse widths, move times and the bytes of a group move.
- `states`: the state machine as a table (state, event) -> next state.
- `driver`: `ArmDriver`, the caller's side: submit, stop, release, cancel, shutdown.
- `worker`: the thread that parks, runs each move until done, and parks at the end.
- `writer`: one step of a move onto the wire, by the same rule from either thread.
- `link`: the worker's hold on the board: connect, watch the idle link, fault, reconnect.
- `shared`, `jobs`: what the two sides share, behind one lock.

The emergency stop's path is `driver.ArmDriver._stop` -> `ssc32u.driver.SSC32U.stop`.
This layer imports `al5d.model`, `al5d.ssc32u` (never its emulator) and `al5d.clock`;
nothing here knows ROS.
"""
