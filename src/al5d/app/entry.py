"""The `al5d` command's entry: a plain `al5d send stop` goes by the local lane before anything
is imported (`al5d.owner.quick`); everything else is `al5d.app.cli`."""

from __future__ import annotations

import sys


def main() -> int:
    from al5d.owner.quick import LaneFull, parse, stop

    asked = parse(sys.argv[1:])
    argv = None
    if asked is not None:
        try:
            code = stop(*asked)
        except LaneFull:  # said: the way by ROS 2 alone
            argv = ["send", "--via", "ros", *sys.argv[2:]]
        else:
            if code is not None:
                return code
    try:
        from al5d.app.cli import main as full

        return full(argv)
    except KeyboardInterrupt:  # before anything was sent (the commands say what they sent)
        print("al5d: interrupted", file=sys.stderr)
        return 130
