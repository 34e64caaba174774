"""The physical twin: the emulated board's pulses drive a MuJoCo arm, with gravity, its
servos' torques, a table, objects to pick up, and a camera.

`al5d emulator --physics` and `al5d serve --physics` (docs/physics.md). What the board
answers is unchanged (a real SSC-32U cannot sense its servos); what the arm does is the
physics. The modules:

- `scene`: the scene file (table, objects, camera, the physics' step), validated.
- `mjcf`: the MuJoCo model, made from the robot model (`al5d.model`'s chain, as the URDF)
  and the servo table (`al5d.arm.servos`: speeds, stall torques, masses).
- `physics`: `Twin`, the model following the board's pulses frame by frame, and what it
  finds (objects' poses, a joint held short of its target: `Held`).
- `camera`: the offscreen camera, rendered in software.
- `node`: its ROS node `al5d_twin` (joints, objects, words, pictures).
- `run`: the twin's process, in real time, fed on its stdin.
- `link`: the board's side: `TwinLink` starts the process and feeds it the pulses.

Imports al5d.model, al5d.arm, al5d.ssc32u (the emulator's `Pulse` and `Board`), al5d.ros
(names, QoS, DDS), MuJoCo and numpy; nothing imports it but al5d.app and the rig.
"""

from __future__ import annotations

import os

# MuJoCo picks its GL when it is first imported: rendered offscreen, without a display,
# by Debian's Mesa on the CPU, unless the environment chose (osmesa, or a GPU's egl).
os.environ.setdefault("MUJOCO_GL", "egl")
