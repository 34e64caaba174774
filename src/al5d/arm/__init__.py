"""The arm: joints in degrees, limits, presets, the move queue and the safety states.

- `config`: the arm's configuration file (joints, calibration, servos, presets), validated.
- `servos`: the servo models an AL5D is built with, as a table.
- `calibration`: the guided calibration's logic: reference poses, nudges, the points found,
  the direction and limits checked.
- `calfile`: the calibrations found written into the configuration file, checked first,
  with a backup and a diff.
- `instruction`: instructions and outcomes as data, and their text grammar.
- `poses`: the named poses file (`pose <name>` in sequence files), and sequence files.
- `validate`: whether an instruction can run, judged whole (pure).
- `sequence`: a sequence judged whole before its first instruction is sent (pure): the
  grammar, then each step as the server will judge it (`al5d run`, `al5d shell`, the Teach tab).
- `resample`: a trajectory at the link's budget: the points thinned to what the wire
  carries within the path tolerance, or the limit it meets (pure).
- `translate`: degrees to pulse widths, move times and the bytes of a group move.
- `cartesian`: `move_to`'s target checked, and planned into group moves by the model.
- `states`: the state machine as a table (state, event) -> next state.
- `core`: the protocol: the one owner of the arm's state, its events and their rules
  (the lanes, the order across channels); read this first.
- `corestate`: the core's fields and the steps its events share.
- `effects`: what the core's events hand back to do outside its lock; the announcements.
- `order`: the sending times the order across channels is judged by.
- `pose`: what the driver believes the board holds (the pose, the motion), the core's.
- `jobs`: a move on its way (its steps, its outcome) and the motion it makes.
- `driver`: `ArmDriver`, the caller's side: submit, stop, release, cancel, shutdown.
- `worker`: the thread that parks, runs each move until done, and parks at the end.
- `writer`: one step of a move onto the wire, by the same rule from either thread.
- `link`: the worker's hold on the board: connect, watch the idle link, fault, reconnect.

The emergency stop's path is `driver.ArmDriver._stop` -> `core.Core.stop` (the decision)
-> `ssc32u.driver.SSC32U.stop` (the bytes).
This layer imports `al5d.model`, `al5d.ssc32u` (never its emulator) and `al5d.clock`;
nothing here knows ROS.
"""
