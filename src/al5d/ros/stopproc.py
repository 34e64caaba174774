"""The stop's own process: the node `al5d_stop` (the stop service and the stop watcher), a
client of the owner, ahead of the rest.

On a busy host a thread of the bridge waits for its interpreter lock behind the thread
that takes a flood of instructions; a stop served there reached the board late. This
process takes nothing but the stop service and the watcher's filtered copy of the
instruction topic, at the urgent priority (`al5d.priority`), and hands each stop to
the owner on a lane of its own; the owner writes it before anything else it has
waiting, and the answer goes back when it has.

`al5d serve` starts it at once (`al5d.ros.processes`), so that its imports and DDS
start-up go on beside the board's; it waits for its lane's welcome (the owner and its
configuration), and ends when the owner ends. If it cannot start, or ends, the bridge
serves the stop (`al5d.ros.bridge`, in `al5d.app.bridgeproc`), and one log line says so;
one that ends is started again (`al5d.app.server.RosSide`) and takes the stop back.

Run as `python -m al5d.ros.stopproc CTRL LANE` by the owner; nothing else starts it.
"""

from __future__ import annotations

import logging
import os
import sys

from al5d.priority import make_urgent


def main(argv: list[str]) -> int:
    from al5d.ros.processes import child_start, send

    ctrl, lane, setup = child_start(argv)
    # Every thread started from here (the DDS participant's among them) inherits it.
    make_urgent("al5d-stop")
    from al5d.logs import setup_logging

    setup_logging(os.environ.get("AL5D_LOG_LEVEL", "INFO"))
    from al5d.owner.client import LaneClosed, Remote
    from al5d.ros.dds import start_context
    from al5d.ros.executors import Spinner
    from al5d.ros.names import STOP_NODE, Names
    from al5d.ros.safety import StopNode

    # DDS starts while the owner opens its board; the node waits for the owner's welcome
    # (its configuration).
    context = start_context(list(setup.args) or [STOP_NODE])
    try:
        arm = Remote(lane, name="al5d-stop", watch=(), timeout=120.0, ros=True)
    except LaneClosed:  # the owner ended before it welcomed this one (a SIGTERM at start)
        os._exit(0)
    node = StopNode(arm, context, Names.of(arm.settings.namespace))
    Spinner(node, context, owns_context=False, kind="single", urgent=True)
    logging.getLogger("al5d").info("ROS 2 stop node %s up", node.get_fully_qualified_name())
    send(ctrl, "ready")
    # The lane's own event: the owner may have ended (and the lane closed) while the node
    # was being made, before any listener added now could hear it.
    arm.closed.wait()
    os._exit(0)  # the owner has ended; DDS's threads need no goodbye


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
