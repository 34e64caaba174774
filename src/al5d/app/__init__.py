"""The applications: the command line, the server process, the demo, MoveIt files, recordings.

- `cli`: `al5d serve | emulator | send | run | shell | doctor | urdf | moveit | demo | web |
  record | replay`, the one entry point.
- `doctor`: `al5d doctor`, what stands between this computer and its SSC-32U.
- `server`: `al5d serve`, the arm driver on a port or on the embedded emulator, with ROS.
- `demo`: DE01 on the embedded emulator, with the DE02 table of `qos`.
- `qos`: the measured quality of service per move, against SA03 (the demo's, the bench's).
- `moveit`: `al5d moveit`, a MoveIt 2 config package written from the configuration;
  `moveit_package`: its frame (package.xml, CMakeLists.txt, RViz, launch files).
- `record`: recordings in rosbag2's MCAP (`al5d record`, `al5d serve --record`).
- `replay`: `al5d replay`, a recording's instructions sent again.

The top layer: it may import every other part of al5d.
"""
