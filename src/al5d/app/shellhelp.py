"""What `help` says at `al5d shell`'s prompt (`al5d.app.terminal`): the grammar of a line."""

from __future__ import annotations

from collections.abc import Iterable


def shell_help(presets: Iterable[str], joints: Iterable[str]) -> list[str]:
    """What `help` says at `al5d shell`'s prompt: its grammar (docs/server.md, Instructions),
    with the server's presets and joints."""
    return [
        f"{' | '.join(presets)}  [time=<ms>]",
        "move <joint>=<degrees> [...]  [time=<ms>]",
        "move_to x=<mm> y=<mm> z=<mm> [pitch=<deg>] [roll=<deg>] [gripper=<deg>] [time=<ms>] "
        "[path=joint|line]",
        "stop | release | shutdown",
        "pose <name>  [time=<ms>]  (a pose of the poses file)",
        "wait <ms>  (the shell pauses)",
        "<instruction> &  (runs in the background)    # a comment",
        "exit | quit | Ctrl-D ends the shell; Ctrl-C while a move runs stops the arm",
        f"joints: {' '.join(joints)}",
    ]
