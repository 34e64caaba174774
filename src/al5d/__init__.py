"""al5d: driver and ROS 2 server for the Lynxmotion AL5D arm on an SSC-32U.

The layers, each importing only those below it:

    al5d.app      the applications: `al5d` command line, server process, demo, MoveIt files
    al5d.web      `al5d web`: the live view, a ROS 2 client serving one page
    al5d.twin     the physical twin (`--physics`): a MuJoCo arm the emulated board drives
    al5d.ros      ROS 2: the bridges (nodes, message mapping, the control actions), the client
    al5d.owner    the board's one owner: its thread, its inbox, the local lane and its clients
    al5d.arm      the arm: config, instructions, validation, state machine, the core (pure)
    al5d.model    the robot model: geometry, kinematics, URDF, straight lines (pure)
    al5d.ssc32u   the board: facts, protocol bytes, the transport, a tool driver, emulator
    al5d.clock    one clock and deadlines, for all of them
    al5d.exits    the command line's exit codes, one table, for all of them
    al5d.priority threads ahead of the rest (the stop path), where the OS allows it
    al5d.interrupts Ctrl-C held off while a send is made whole
    al5d.logs     the processes' log lines: one format, written by a thread of their own
    al5d.__main__ `python -m al5d`: the command line

The model and the board do not know each other: the arm joins them.
"""

__version__ = "0.1.0"
