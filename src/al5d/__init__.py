"""al5d: driver and ROS 2 server for the Lynxmotion AL5D arm on an SSC-32U.

The layers, each importing only those below it:

    al5d.app      the applications: `al5d` command line, server process, demo
    al5d.ros      ROS 2: node `al5d`, message mapping, the client
    al5d.arm      the arm: config, instructions, validation, state machine, driver
    al5d.ssc32u   the board: facts, protocol bytes, low-level driver, emulator
    al5d.clock    one clock and deadlines, for all of them
"""

__version__ = "0.1.0"
