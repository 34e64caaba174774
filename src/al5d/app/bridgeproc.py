"""The ROS 2 bridge's process: `al5d.ros.bridge`'s nodes on the owner's lane, and the
recording of `al5d serve --record`.

`al5d serve` starts it (`al5d.ros.processes`): it hands the owner the settings the ROS
parameters make (`RosStart`), and, once the owner says go, runs the nodes (`Bridge`) on
the lane until the lane closes. Here, in the applications' layer, because it records
(`al5d.app.record`), which the ROS layer below may not import.

Run as `python -m al5d.app.bridgeproc CTRL LANE` by the owner; nothing else starts it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

from al5d.arm.config import ConfigError
from al5d.logs import setup_logging
from al5d.owner.client import LaneClosed, Remote
from al5d.priority import built_urgently
from al5d.ros.bridge import Bridge, RosStart
from al5d.ros.processes import Setup, child_start, receive, send
from al5d.ros.safety import StopNode

if TYPE_CHECKING:
    from al5d.app.record import ServerRecording

log = logging.getLogger("al5d")


def main(argv: list[str]) -> int:
    """The bridge's process: settings for the owner, then the nodes until the lane closes."""
    ctrl, lane, setup = child_start(argv)
    setup_logging(os.environ.get("AL5D_LOG_LEVEL", "INFO"))
    try:
        start = RosStart(setup.args, setup.flags)
    except ConfigError as e:
        send(ctrl, "config-error", str(e))
        return 2
    recording = None
    if start.settings.record is not None and setup.again:
        log.warning(
            "%s was recorded by the ROS 2 bridge that ended, and is kept as that one left it "
            "(what it had not written out is lost); this one does not record",
            start.settings.record,
        )
    elif start.settings.record is not None:
        from al5d.app.mcapfile import RecordingError  # mcap: only to record
        from al5d.app.record import ServerRecording

        try:
            recording = ServerRecording(start.settings.record)
        except RecordingError as e:
            send(ctrl, "error", str(e))
            start.close()
            return 2
    try:
        send(ctrl, "settings", start.settings)
        return _serve(ctrl, lane, setup, start, recording)
    finally:
        if recording is not None:
            recording.close()


#: A new bridge waits until its results have a reader, and the number of readers has held
#: this long (s), and no longer than `SETTLE_MOST_S`, before it says the last one's outcomes:
#: a busy host's discovery takes seconds.
SETTLE_QUIET_S = 1.0
SETTLE_MOST_S = 10.0


def settled(pub: Any) -> None:
    """Until `pub` has matched a reader and their number has held for `SETTLE_QUIET_S`."""
    deadline = time.monotonic() + SETTLE_MOST_S
    count, since = pub.get_subscription_count(), time.monotonic()
    while time.monotonic() < deadline and (not count or time.monotonic() < since + SETTLE_QUIET_S):
        time.sleep(0.05)
        now_count = pub.get_subscription_count()
        if now_count != count:
            count, since = now_count, time.monotonic()


def _serve(
    ctrl: socket.socket,
    lane: socket.socket,
    setup: Setup,
    start: RosStart,
    recording: ServerRecording | None,
) -> int:
    """The nodes on the owner's lane once it says go, until the lane closes."""
    go = receive(ctrl)
    if go is None or go[0] != "go":
        start.close()
        return 0
    stop_here = bool(go[1]) if len(go) > 1 else False
    watch = ("state", "outcomes", "motion", "pose") + (("wire", "asked") if recording else ())
    tap = recording.tap(start.names.namespace) if recording is not None else None
    on_wire = None if tap is None else (lambda w: tap(*w))
    try:
        # Leased: the leases of its ROS clients are kept here, so a bridge that hangs is
        # lost to the owner, and what they commanded halted.
        arm = Remote(
            lane,
            name="al5d-ros",
            watch=watch,
            on_wire=on_wire,
            recorder=tap is not None,
            lease=True,
            ros=True,
        )
    except LaneClosed:  # the owner ended before it welcomed this one (a SIGTERM at start)
        start.close()
        return 0
    if recording is not None:
        recording.follow(start.names)
        start.node.heard = recording.heard(start.names)  # before `Bridge` reads the topics
        on_asked = recording.asked(start.names)
        arm.asked_listeners.append(lambda a: on_asked(*a))
    bridge = Bridge(arm, start, setup.trace, stop_here)

    def on_ctrl() -> None:
        # The owner says its stop process has ended: the stop is served here until it says
        # that a new one serves it.
        while (message := receive(ctrl)) is not None:
            if message[0] == "serve-stop" and bridge.stop is None and not arm.closed.is_set():
                log.error(
                    "the stop process has ended; the stop is served by the bridge from now "
                    "on, where a busy host delays it"
                )
                bridge.stop = built_urgently(
                    "al5d-stop-here", lambda: StopNode(arm, bridge.safety_context, bridge.names)
                )
                bridge.safety_spinner.add(bridge.stop)
            elif message[0] == "unserve-stop" and bridge.stop is not None:
                here = bridge.stop
                here.close()  # its watcher's thread
                try:
                    bridge.safety_spinner.remove(here)
                except RuntimeError as e:  # a callback held the executor: it serves on too
                    log.warning("the bridge's stop service stays beside the process's: %s", e)
                    continue
                bridge.stop = None
                log.info("the stop is served by the stop process again")

    threading.Thread(target=on_ctrl, name="al5d-bridge-ctrl", daemon=True).start()
    if setup.again:
        # The outcomes of what the last bridge's clients asked, halted as it ended, go on
        # the result topic (an outside try: none ever came), once the clients that were
        # there have matched this one's writer (the topic keeps nothing for a late reader).
        settled(bridge.node.result_pub)
        with contextlib.suppress(LaneClosed, TimeoutError):
            arm.kept_outcomes()
    # The lane's own event, not a listener added now: a lane that closed before this line
    # (a SIGTERM as the server started) has told its listeners already.
    arm.closed.wait()
    bridge.close()
    if recording is not None:
        recording.close_ros()  # after the server's last messages reached it
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
