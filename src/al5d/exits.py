"""The exit codes of the `al5d` command line: one table, for every subcommand and `--help`.

It lives at the top of the package, beside `clock.py`, so that the clients (`ros`) and
the applications (`app`) share it without either importing the other, nor rclpy.
"""

from __future__ import annotations

from typing import Final

#: Every instruction done; `al5d doctor`: every check passed.
DONE: Final = 0
#: An instruction refused or cancelled, or no outcome in time; `al5d doctor`: a problem.
NOT_DONE: Final = 1
#: The command line or the configuration is wrong: argparse's own code, kept for it.
USAGE: Final = 2
#: `al5d serve`: the arm could not be parked at the end.
NOT_PARKED: Final = 3
#: An instruction, or a sequence file, that is not in the grammar (or cannot be read):
#: nothing was sent.
BAD_INPUT: Final = 4
#: No al5d server was found within `--wait` seconds: nothing was sent.
NO_SERVER: Final = 5
#: Ctrl-C: what the command sent was cancelled, or (`al5d shell`) stopped; as a shell's
#: 128 + SIGINT.
INTERRUPTED: Final = 130

TABLE: Final = (
    (DONE, "done (doctor: every check passed)"),
    (NOT_DONE, "refused, cancelled or no outcome in time (doctor: a problem found)"),
    (USAGE, "usage: a wrong option or argument, or a bad configuration file"),
    (NOT_PARKED, "serve: the arm could not be parked at the end"),
    (BAD_INPUT, "bad input: an instruction or sequence file not in the grammar; nothing sent"),
    (
        NO_SERVER,
        "no server found within --wait seconds, or the one on this machine not answering; "
        "nothing sent",
    ),
    (
        INTERRUPTED,
        "Ctrl-C: what send or run sent is cancelled (over ROS 2 said not); shell, piped: "
        "a stop asked where its lines ran, the input ended",
    ),
)


def describe() -> str:
    """The table as `--help` shows it."""
    return "exit codes:\n" + "\n".join(f"  {code}  {what}" for code, what in TABLE)
