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
- `core`: the protocol as one pure transition, `step(core, input) -> (core, effects)`:
  the lanes, the order across channels; read this first.
- `corestate`: the core's inputs and effects, its value, and the steps its inputs share.
- `running`: a job as it runs: its steps planned and written on the wire's pace, waited
  for, confirmed; a stream's set-points watched.
- `link`: the board's connection as the core keeps it: open, check, ask, judge the answers.
- `order`: the sending times the order across channels is judged by (a value).
- `pose`: what the core believes the board holds (the pose, the motion; a value).
- `jobs`: a move on its way (its steps, who asked) and the motion it makes.

The emergency stop's path is `core._stop` (the decision) -> `corestate.halt` (the bytes,
`al5d.ssc32u.protocol`); the owner (`al5d.owner`) writes them.

This layer imports `al5d.model`, `al5d.ssc32u` (never its emulator) and `al5d.clock`;
nothing here knows ROS, and nothing here does I/O but reading files (the configuration,
poses, calibrations).
"""
