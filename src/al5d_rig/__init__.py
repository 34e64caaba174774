"""The test and benchmark rig: the arm's parts started for real, and what reads them back.

Installed with the project (`pip install -e .`, as `make install` does), so that the
tests (tests/) and the benchmarks (bench/) import it as any package, and the scripts
among its modules run as `python -m al5d_rig.NAME`. It sits above every subpackage of
`al5d` and may import any of them; nothing in `al5d` imports it. The modules:

- `proc`: `al5d` commands as processes of their own (at a terminal of their own too:
  `Tty`), their output read as it comes.
- `shm`: Fast DDS's shared-memory files of processes gone, removed before a run.
- `boardproc`: `al5d emulator` in a process of its own, its records streamed back.
- `armrig`: an owner on an emulated board in this process, and what tests read of the
  board's records (`group_moves`, `written`, `group_pulses`).
- `sim`: the arm's core against an emulated board in virtual time: no pty, no process,
  no thread, no sleep.
- `served`: `al5d serve` on an emulated board, with a peer that follows its state.
- `rospeer`: a ROS 2 peer of the server: publishes, calls, listens.
- `domains`: the ROS domains of a test run, a pair claimed by each pytest process.
- `loadrig`: floods over DDS, and the stop measured under them; `flood_client` floods
  (a process: `python -m al5d_rig.flood_client`).
- `contention` and `falsefaults`: several servers beside busy loops, and false link
  faults on a busy host (both also run as processes); `goal_flood_client` floods with
  trajectory goals (a process); `result_counter` counts a flood's results at the
  default priority, and `stallprobe` notes the host's own stalls (both processes).
- `faultrig`: faults injected at chosen moments into a driver, and what it made of them.
- `watch_backlog`: a reader of the instruction topic that a flood outruns (a process).
- `late_results`: a server's topics alone, whose answers reach a new client late (a
  process).
- `trajectories`: dense trajectories as MoveIt times them, and their goals.
- `webrig`: `al5d web` in its own process, and a headless Chromium.
- `calibuser`: the user of a calibration, who sees where a joint truly stands.
- `model_support`: the shipped arm's ranges, speeds and presets for the model's tests.
- `twinrig`: a board and its physical twin (`al5d.twin`) in this process, on a clock of
  the test's own.
- `fuzzcount`: how many cases each fuzz suite ran.
- `host`: how short of cores the host was over a stretch of a test (its timing excused).
- `netrig`: two hosts (network namespaces joined by a veth pair, or by `cable`) and their
  link, cut and mended; `cable`: a link that delays and loses frames (a process: `python
  -m al5d_rig.cable`), where the kernel has no netem; `netfaults`: random faults on it
  under a client, server restarts, and the promises checked.
- `actionclient`: a client of FollowJointTrajectory as MoveIt is (a process), which leaves
  with its goal running; and docs/ros.md's Fast DDS profile of a short lease.

The pytest fixtures stay in tests/conftest.py, not here as a plugin: they claim the run's
ROS domain when pytest loads them, which only the test suite must do (a benchmark
claims its own as it starts), and pytest finds conftest.py without any registration.
"""
