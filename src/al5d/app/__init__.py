"""The applications: the command line, the server process, and the tools around them.

- `entry`: the `al5d` command's entry: a plain `al5d send stop` by the local lane before
  anything is imported; everything else by `cli`.
- `cli`: `al5d serve | emulator | send | run | shell | doctor | demo | urdf | moveit | web |
  record | replay | calibrate`, and the exit codes' table in `--help`; `commands`: what each
  command does with its parsed arguments.
- `emulator`: `al5d emulator`, a standalone emulated SSC-32U on a pseudo terminal.
- `terminal`: `al5d send` and `al5d run`, the client's commands at the terminal; `shell`:
  `al5d shell`, a line at a time (its `help`, its Ctrl-C; `typed`: what is typed while a
  line runs, a stop at once); `report`: how they report (outcomes, the link watched, where
  the time went).
- `server`: `al5d serve`, the owner of the board on a port or on the embedded emulator,
  with the ROS side's processes beside it; `bridgeproc`: the ROS 2 bridge's process (it
  records, for `serve --record`).
- `demo`: DE01 on the embedded emulator, with the DE02 table of `reach`.
- `reach`: how soon each move reached its target (the demo's and the benchmarks' table).
- `doctor`: `al5d doctor`, what stands between this computer and its SSC-32U.
- `moveit`, `moveit_package`, `moveit_arms`: `al5d moveit`, a MoveIt 2 config package for
  the arm (`moveit_arms`: the launch files of a package of several).
- `record`, `replay`: recordings in rosbag2's MCAP (`al5d record`, `serve --record`) and
  `al5d replay`; `mcapfile`: a recording's file (schemas, CDR, its writing thread).
- `calibrate`: `al5d calibrate`, the guided calibration at the terminal (through the server).

The top layer: it may import every other part of al5d.
"""

import os

# Our processes multiply 4x4 matrices at most: OpenBLAS's thread pool (a thread a core,
# started when numpy is imported) is no use to them, and starting it cost 0.16 CPU s of
# each `al5d` command's 0.83 (median of 12 `al5d --help`, 2 cores). Before numpy's import
# (al5d.arm.config below this package imports it); a value the user set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
