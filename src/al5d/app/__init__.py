"""The applications: the command line, the server process, the demo and its QoS table.

- `cli`: `al5d serve | emulator | send | run | shell | doctor | demo | ...`.
- `doctor`: `al5d doctor`, what stands between this computer and its SSC-32U.
- `server`: `al5d serve`, the arm driver on a port or on the embedded emulator, with ROS.
- `demo`: DE01 on the embedded emulator, with the DE02 table of `qos`.
- `calibrate`: `al5d calibrate`, the guided calibration at the terminal (through the server).

The top layer: it may import every other part of al5d.
"""
