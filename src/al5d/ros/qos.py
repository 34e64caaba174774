"""The QoS profiles of the arm's topics and services, and why each is what it is."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def profile(
    depth: int, *, reliable: bool = True, keep_all: bool = False, latched: bool = False
) -> QoSProfile:
    """A profile `depth` deep (KEEP_LAST, or KEEP_ALL), reliable or best effort, volatile or
    latched (TRANSIENT_LOCAL, for late joiners)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if keep_all else HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


#: Instructions: reliable, and kept until taken (KEEP_ALL), so that a flood faster than
#: the server slows its sender instead of overwriting what it sent (back-pressure).
QOS_INSTRUCTIONS = profile(1, keep_all=True)


#: A client's stops (their copies), releases and shutdowns, on a writer of their own:
#: reliable, in order among themselves, and never waiting for what the server has not
#: taken (KEEP_LAST). On the instruction writer, whose history a flood fills while the
#: server does not acknowledge it (a link cut, a frozen bridge), the stop failed with the
#: moves ("Failed to publish" after 0.1 s; measured: 4,999 moves waiting unacknowledged)
#: and never went out.
QOS_SAFETY = profile(100)


def qos_watch(backlog: int) -> QoSProfile:
    """The stop watcher's reader of the instruction topic: it never slows a sender (best
    effort) and never waits: a flood it cannot keep up with overwrites the oldest.

    As deep as the server's instruction backlog, and no deeper: Fast DDS gives the
    backlog's bound (`dds_profile`) to every reader of the topic in the process, the
    watcher's too, and a KEEP_LAST reader deeper than its bound, once full, refuses the
    newest message instead of dropping the oldest (measured: 5,000 sent to a reader 10,000
    deep bounded at 1,000 kept the first 1,000): a stop that came last would be lost."""
    return profile(backlog, reliable=False)


#: Samples that may be dropped (joint states, a pose): the latest is all a reader wants, a
#: late one is replaced, never sent again.
QOS_LATEST = profile(1, reliable=False)
#: Results: reliable and deep; a reader more than 10,000 results behind loses the oldest,
#: and never slows the server (KEEP_ALL here would let a stuck reader block it).
QOS_STREAM = profile(10_000)
#: The services' requests and answers (the safety services', the actions' goal, result and
#: cancel): deep enough that a request waits rather than is lost. 100 preempting trajectory
#: goals a second beside two busy loops outran the server's 1,000-deep goal queue (306 of
#: 3,000 goals in 30 s never answered); 10,000 deep, every one was (docs/reliability.md).
QOS_SERVICES = profile(10_000)
#: The stream of set-points (`joint_commands`): the newest is all that matters (ros2_control's
#: hardware writer keeps one too, and so does the web view's jog).
QOS_COMMANDS = profile(1)
#: The state: latched, so that a late joiner gets the current one.
QOS_LATCHED = profile(1, latched=True)
#: The clients' leases (`al5d.ros.leases`): reliable, so that a client's last word (it is
#: closing) reaches the server, and one deep, so that after an outage a writer sends again
#: only its newest lease, not the ones of the outage, which would say it had been there.
#: (Several clients' leases share the reader's one place: one overwritten before it is
#: taken is one of the ten or so a lease's time holds.)
QOS_LEASES = profile(1)
