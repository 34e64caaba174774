"""The board's link, as the core keeps it: open, check, ask, judge the answers, lose it.

Pure steps on the core's value (`corestate.Core`): the owner opens the port when told
(`Open`), hands over what comes (`Opened`, `Received`, `Failed`), and writes what it is
given (`Send`). A lost link, a silent or babbling board, or a board that has reset
becomes the `fault` state: every pending move gets its outcome, and the port is opened
again every `server.reconnect_interval_s` (and at once for a stop) until the board
answers; then a move the board may still run is halted (every servo, if a stop came
meanwhile), the pose is read back, and no cancelled move is replayed.

One query is on its way at a time; it is written only when no line is going out and the
wire is free (it cannot be cut), asked once more before a missing answer is a fault, and
its deadline is the board's: the time the owner's thread was not running, or the host
short of cores, is excused up to `EXCUSE_MAX_S`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import replace

from al5d.arm.corestate import (
    RESET_LOCKED,
    Close,
    Core,
    Link,
    Next,
    Opened,
    Out,
    Probe,
    Purpose,
    Query,
    Received,
    complete,
    fire,
    halt,
    lock_arm,
    lose,
    margin_s,
    posed,
    say,
    send,
)
from al5d.arm.states import LOCKED_BY_RESET, Event, State
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import BoardReset, GarbageAnswer, NoAnswer, NotAnSSC32U, SerialFault
from al5d.ssc32u.facts import FIRMWARE_PREFIX, QP_RESOLUTION_US

#: At most this much is excused to one ask of a query: a silent board on a busy host is
#: found that much later, at worst; on an idle one, not later at all. Beside two busy
#: loops and a flood, a board's answer (an emulator at nice -10 in its own process) came
#: 75 ms late twice in a row: the kernel's work that carries a pty's bytes waited for a core.
EXCUSE_MAX_S = 0.15
#: How far a pulse read back may be from the one expected at rest: `QP` answers in steps
#: of 10 us (rounded down), and a pose read back is itself one of those steps.
REST_MARGIN_US = 2 * QP_RESOLUTION_US
#: During a motion, how late (or early) the board may be on the owner's schedule: a step of
#: a trajectory goes out one wire time before the one before ends, and a few bytes more or
#: less on the wire are a few ms. The margin is this long at full speed.
MOTION_SLACK_S = 0.02


# -- opening ----------------------------------------------------------------------------


def opened(c: Core, ev: Opened, out: Out) -> Core:
    """The port asked for is open (then ESC, and VER: is it an SSC-32U), or it is not."""
    link = replace(c.link, opening=False)
    if ev.error is not None:
        return not_reached(replace(c, link=link), ev.error, ev.t, out)
    settings = c.arm.settings
    link = replace(link, open=True, margin_s=margin_s(settings, ev.low_latency), free_at=ev.t)
    c = send(replace(c, link=link), p.CANCEL, ev.t, out, pulses=False)
    return ask(c, Purpose.VERSION, p.encode_version(), None, ev.t, out)


def not_reached(c: Core, error: SerialFault, t: float, out: Out) -> Core:
    """The board could not be reached (at start, or a device that is not a board at a
    reconnect): tried again after the interval. At start, and for a device that is not a
    board, said (once for the same answer) and the fault's reason."""
    link = replace(c.link, open=False, open_at=t + c.arm.settings.reconnect_interval_s)
    c = replace(c, link=link)
    known = c.fault
    first = c.state is not State.FAULT
    if not first and not isinstance(error, NotAnSSC32U):
        say(out, logging.DEBUG, f"reconnect failed: {error}")
        return c
    if isinstance(known, NotAnSSC32U) and getattr(error, "received", None) == known.received:
        say(out, logging.DEBUG, f"reconnect failed: {error}")
        return c
    if first:
        say(out, logging.ERROR, f"serial fault: {error}")
    else:
        say(out, logging.WARNING, f"reconnect: {error}")
    c = replace(c, fault=error)
    return fire(c, Event.SERIAL_FAULT, out) if first else c


def _checked(c: Core, answer: bytes, t: float, wall: int, out: Out) -> Core:
    """VER's answer: an SSC-32U, or not (closed and tried again)."""
    port = c.arm.port
    start = answer.upper().find(FIRMWARE_PREFIX.encode())
    if 0 < start <= 2 * (len(c.arm.channels) + 1):
        # Answers to queries asked before the fault, held up on their way (a busy host's
        # pty): they come first, and are not the board's. At most a `QP` of every channel
        # and a `Q`, each asked twice.
        say(out, logging.DEBUG, f"late answers before VER's, dropped: {answer[:start]!r}")
        answer = answer[start:]
    try:
        firmware = p.parse_version(answer)
    except p.ProtocolError:
        firmware = ""
    if not firmware.upper().startswith(FIRMWARE_PREFIX):
        what = f"answered VER with {firmware!r}" if firmware else f"answered VER with {answer!r}"
        error = NotAnSSC32U(port, f"{what}, which is not an SSC-32U; {NotAnSSC32U.advice}", answer)
        return _close(c, error, t, out)
    if c.state is State.FAULT:
        following = Next.RECONNECT
    elif c.state is State.SHUTTING_DOWN:
        following = Next.SHUTDOWN
    else:
        following = Next.STARTUP
        say(out, logging.INFO, f"connected to {firmware} on {port} at {c.arm.baud} baud")
    checked = following is Next.STARTUP and not c.halt_owed
    link = replace(c.link, checked=True, next=following, halt_checked=checked)
    return replace(c, link=link, firmware=firmware)


def _close(c: Core, error: SerialFault, t: float, out: Out) -> Core:
    """A port that is open but no board (or no board we can use): closed, tried again."""
    out.append(Close())
    c = replace(c, link=Link(watched=t))
    return not_reached(c, error, t, out)


# -- queries ----------------------------------------------------------------------------


def can_ask(c: Core, t: float) -> bool:
    """A query may be written now: none on its way, no line going out, the wire free."""
    link = c.link
    return link.open and link.query is None and not link.rest and link.free_at <= t


def ask(
    c: Core,
    purpose: Purpose,
    data: bytes,
    n_answer: int | None,
    t: float,
    out: Out,
    probe: Probe | None = None,
    asks: int = 1,
) -> Core:
    """Write a query; its answer is due after our bytes on the wire (behind any before them),
    the answer's own bytes back, and the margin."""
    c = send(c, data, t, out, pulses=False)
    link = c.link
    back = p.wire_time_s(n_answer or p.VERSION_ANSWER_BYTES, c.arm.baud)
    due = link.free_at + back + link.margin_s
    writes = link.writes if asks == 1 or link.query is None else link.query.writes
    query = Query(purpose, data, n_answer, due, asks, writes, link.stalled, probe)
    # A late first answer may still come, and so may an owed one (kept whole to be dropped).
    keep = link.received if asks > 1 or link.owed[1] else b""
    return replace(c, link=replace(link, query=query, received=keep))


def _skip_owed(data: bytes, owed: tuple[int | None, int]) -> tuple[bytes, tuple[int | None, int]]:
    """`data` without the whole answers owed to a query taken already, and what is still owed
    (an answer owed that has come in part is kept whole until the rest comes)."""
    n_answer, count = owed
    while count and data:
        if n_answer is None:
            end = data.find(p.CR) + 1
            if not end:
                break
        else:
            end = n_answer
            if len(data) < end:
                break
        data, count = data[end:], count - 1
    return data, (n_answer, count)


def received(c: Core, ev: Received, out: Out) -> Core:
    """Bytes from the board: the answer of the query on its way, once whole (both answers
    after a second ask: the board answers in order, so a late first answer comes before
    the second, and is never left for the next query to take as its own). A query taken on
    its first answer is owed the second: that is dropped when it comes (seen beside busy
    loops: a reconnect's VER, asked twice, taken on the first; the second's 15 bytes came
    while the next Q waited, which took the last of them as its answer, "Q answered
    b'\\r'", and the link was lost again, for 2 s)."""
    link = c.link
    data = link.received + ev.data
    if link.owed[1] and ev.t > link.owed_until:
        link = replace(link, owed=(None, 0))
    if link.owed[1]:
        data, owed = _skip_owed(data, link.owed)
        link = replace(link, owed=owed)
        if owed[1]:  # an owed answer in part: kept until it is whole
            return replace(c, link=replace(link, received=data))
    query = link.query
    if query is None:  # nothing asked: not an answer of ours
        return replace(c, link=replace(link, received=b""))
    c = replace(c, link=replace(link, received=data))
    if p.count_answers(data, query.n_answer) >= query.asks:
        return _answered(c, query, p.last_answer(data, query.n_answer), ev.t, ev.wall, out)
    return c


def due(query: Query, stalled: float) -> float:
    """When the query's answer is late: its deadline, moved on by the host's stalls since
    it was asked, up to `EXCUSE_MAX_S`."""
    return query.due + min(EXCUSE_MAX_S, max(0.0, stalled - query.stalled))


def overdue(c: Core, t: float, wall: int, out: Out) -> Core:
    """The query's deadline has passed: asked again once; then what came is taken (the
    last answer), or no answer is the fault."""
    query = c.link.query
    assert query is not None
    data = c.link.received
    if answers := p.count_answers(data, query.n_answer):
        owed = (query.n_answer, max(0, query.asks - answers))
        back = p.wire_time_s(query.n_answer or p.VERSION_ANSWER_BYTES, c.arm.baud)
        until = t + back + c.link.margin_s + EXCUSE_MAX_S
        c = replace(c, link=replace(c.link, owed=owed, owed_until=until))
        return _answered(c, query, p.last_answer(data, query.n_answer), t, wall, out)
    if query.asks == 1:
        c = replace(c, link=replace(c.link, query=None))
        return ask(c, query.purpose, query.data, query.n_answer, t, out, query.probe, asks=2)
    name = query.data.rstrip(p.CR).decode("ascii", "replace")[:8]
    waited = (t - query.due) * 1000.0
    got = f", got {data!r}" if data else ""
    error = NoAnswer(c.arm.port, f"no answer to {name}, asked twice, {waited:.0f} ms late{got}")
    if query.purpose is Purpose.VERSION:
        received = f"received {data!r}" if data else "received nothing"
        bad = NotAnSSC32U(
            c.arm.port,
            f"does not answer like an SSC-32U at {c.arm.baud} baud ({error.what}); "
            f"{received}; {NotAnSSC32U.advice}",
            data,
        )
        return _close(replace(c, link=replace(c.link, query=None)), bad, t, out)
    return lose(c, error, t, wall, out)


def _garbage(c: Core, answer: bytes, e: Exception, t: float, wall: int, out: Out) -> Core:
    error = GarbageAnswer(c.arm.port, f"not an SSC-32U answer: {e}", answer)
    return lose(c, error, t, wall, out)


def _answered(c: Core, query: Query, answer: bytes, t: float, wall: int, out: Out) -> Core:
    """A whole answer to the query on its way, judged by what it was asked for."""
    c = replace(c, link=replace(c.link, query=None, received=b"", watched=t))
    purpose = query.purpose
    if purpose is Purpose.VERSION:
        return _checked(c, answer, t, wall, out)
    if purpose is Purpose.POSE:
        channels = list(c.arm.channels.values())
        try:
            pulses = p.parse_pulses(answer, channels)
        except p.ProtocolError as e:
            return _garbage(c, answer, e, t, wall, out)
        if c.link.writes != query.writes:
            return c  # a line or a STOP went out meanwhile: the pose is asked again
        return _pose(c, c.arm.translator.degrees(pulses), t, wall, out)
    if purpose is Purpose.PROBE:
        assert query.probe is not None
        try:
            pulse = p.parse_pulses(answer, [query.probe.channel])[query.probe.channel]
        except p.ProtocolError as e:
            return _garbage(c, answer, e, t, wall, out)
        probe = query.probe
        if c.link.writes == query.writes and not probe.low_us <= pulse <= probe.high_us:
            return lose(c, _reset(c, probe.joint, pulse, probe), t, wall, out)
        return c
    try:
        moving = p.parse_movement(answer)
    except p.ProtocolError as e:
        return _garbage(c, answer, e, t, wall, out)
    if purpose is Purpose.HALTED:
        if moving:
            c = _halt_cancelled(c, t, out)
        return replace(c, link=replace(c.link, halt_checked=True))
    if purpose is Purpose.DONE:
        return _confirmed(c, moving, t, wall, out)
    return c  # ALIVE: the link lives


#: A move whose `Q` still says moving this long after its time is taken as a fault.
COMPLETION_GRACE_S = 2.0
#: How often `Q` is asked once a move's time is over.
POLL_S = 0.002


def _confirmed(c: Core, moving: bool, t: float, wall: int, out: Out) -> Core:
    """`Q` after the last step's time: done, asked again, or (too long after) the fault."""
    run = c.run
    if run is None or not run.confirming:
        return c  # ended meanwhile (a stop, a cancel)
    if not moving:
        return complete(c, t, out)
    written = run.written
    assert written is not None
    if t - written.t_end > COMPLETION_GRACE_S:
        error = SerialFault(
            c.arm.port, f"Q still says moving {COMPLETION_GRACE_S} s after the move's time"
        )
        return lose(c, error, t, wall, out)
    return replace(c, run=replace(run, poll_at=t + POLL_S, still_moving=True))


def _halt_cancelled(c: Core, t: float, out: Out) -> Core:
    c = halt(c, t, out)
    what = c.link.next.value if c.link.next is not None else "the link"
    say(out, logging.WARNING, f"{what}: halted the move the board was still running (cancelled)")
    return c


def _reset(c: Core, joint: str, pulse: int = 0, probe: Probe | None = None) -> BoardReset:
    channel = c.arm.channels[joint]
    if pulse == 0:
        what = "has no pulse any more"
    else:
        assert probe is not None
        what = (
            f"puts out {pulse} us where the driver expects "
            f"{probe.low_us:.0f}..{probe.high_us:.0f} us"
        )
    return BoardReset(
        c.arm.port,
        f"the board has reset: {joint} (channel {channel}) {what}, and the board has "
        f"forgotten where every servo was; {BoardReset.advice}",
    )


# -- the pose ---------------------------------------------------------------------------


def _pose(c: Core, pose: Mapping[str, float | None], t: float, wall: int, out: Out) -> Core:
    """The pose read back: after a halt, at start, at a reconnect or at the shutdown. A joint
    of known pose with no pulse now is a reset (at a reconnect, the arm is locked)."""
    known = c.book.pose
    lost = [j for j, v in pose.items() if v is None and known.get(j) is not None]
    following = c.link.next
    if lost and following is not Next.RECONNECT:
        return lose(c, _reset(c, lost[0]), t, wall, out)
    if following is Next.RECONNECT:
        c = _reconnected(c, pose, bool(lost), wall, out)
    else:
        c = replace(c, book=c.book.read_back(pose, _exact(c, pose)))
        if c.run is None:
            c = replace(c, readback=False)
    read = ", ".join(f"{j} {'?' if v is None else round(v, 1)}" for j, v in pose.items())
    if following in (None, Next.RECONNECT) and c.state is State.STOPPED:
        # Where a stop left the arm (also one asked while the board was away, written when
        # it came back) is what its user asks next (an outside try: said at DEBUG only).
        say(out, logging.INFO, f"stopped at: {read} (read back from the board)")
    else:
        say(out, logging.DEBUG, f"read back: {read}")
    c = replace(c, link=replace(c.link, next=None))
    posed(c, out)
    return c


def _exact(c: Core, pose: Mapping[str, float | None]) -> frozenset[str]:
    """The joints read back whose pulse the core knows to the microsecond: at rest where
    its own line put them, and in the step of `QP` the board answered."""
    book, tr = c.book, c.arm.translator
    exact = set()
    for joint, deg in pose.items():
        known = book.pose.get(joint)
        if deg is None or known is None or joint in book.unsure:
            continue
        if (
            tr.pulse_us(joint, known) // QP_RESOLUTION_US
            == tr.pulse_us(joint, deg) // QP_RESOLUTION_US
        ):
            exact.add(joint)
    return frozenset(exact)


def _reconnected(
    c: Core, pose: Mapping[str, float | None], reset: bool, wall: int, out: Out
) -> Core:
    """The board is back, its pose read; `reset`: it restarted while the link was down."""
    book = c.book
    if reset:
        say(out, logging.ERROR, f"serial fault: {_reset(c, next(iter(book.pose)))}")
        say(out, logging.WARNING, RESET_LOCKED)
        c = lock_arm(c, LOCKED_BY_RESET, wall)
        book = book.forget()
    exact = frozenset() if reset else _exact(c, pose)
    c = replace(c, book=book.read_back(pose, exact), fault=None, readback=False)
    if c.state is State.FAULT:  # not if a shutdown came meanwhile: it parks now
        c = fire(c, Event.RECONNECTED, out)
    say(out, logging.INFO, f"reconnected to {c.firmware} on {c.arm.port}")
    return c


def settle(c: Core, t: float, out: Out) -> Core:
    """A board just opened (or the shutdown's): a move it may still run (cancelled without a
    halt, when the link went or by the shutdown) is halted, and so is every servo if a stop
    came while the port was closed; then the pose is read back, so that it is where the
    arm stopped, not a snapshot of it on its way."""
    if not can_ask(c, t):
        return c
    if not c.link.halt_checked:
        if c.halt_owed:
            c = halt(c, t, out)
            say(out, logging.WARNING, "the board is back: STOP for the stop asked meanwhile")
        elif c.book.q_believed(t):
            return ask(c, Purpose.HALTED, p.encode_query_movement(), 1, t, out)
        else:
            c = _halt_cancelled(c, t, out)
        return replace(c, link=replace(c.link, halt_checked=True))
    return read_pose(c, t, out)


def read_pose(c: Core, t: float, out: Out) -> Core:
    """Ask where the servos are (`QP` of every channel)."""
    channels = list(c.arm.channels.values())
    return ask(c, Purpose.POSE, p.encode_query_pulse(channels), len(channels), t, out)


# -- the link checks --------------------------------------------------------------------


def watch(c: Core, t: float, out: Out) -> Core:
    """Check the link, and that the board has not reset: `QP` of one channel (4 bytes, as
    cheap as `Q`), the one of the joint written least recently (a move after a reset
    restores only its own channels). A pulse other than the core expects there is a reset
    (the pulses of a board with none at power-up are 0, of one with power-up pulses
    those), or something else has moved the servo: either way the board no longer holds
    what the core believes, and its next move would run at full speed. A line written
    while the query is on its way changes the pulse under it: such a check is a link
    check only."""
    joint = c.book.stalest()
    if joint is None:  # nothing known to have been lost: the link alone
        return ask(c, Purpose.ALIVE, p.encode_query_movement(), 1, t, out)
    probe = _probe(c, joint, t)
    data = p.encode_query_pulse([probe.channel])
    return ask(c, Purpose.PROBE, data, 1, t, out, probe)


def _probe(c: Core, joint: str, t: float) -> Probe:
    """The pulses the core expects on the joint's channel: at rest the known pose's pulse,
    during a motion (or just after one) anything on its way, with margins."""
    config = c.arm.config.joints[joint]
    pose = c.book.pose[joint]
    assert pose is not None
    ends = [pose]
    margin = float(REST_MARGIN_US)
    motion = c.book.motion
    if motion is not None and joint in motion.target:
        ends += [motion.start.get(joint, pose), motion.target[joint]]
    way = c.book.way(joint, t)
    if way is not None:
        ends += way
    if len(ends) > 1:
        margin += MOTION_SLACK_S * config.speed_us_s
    pulses = [config.to_us(deg) for deg in ends]
    return Probe(joint, config.channel, min(pulses) - margin, max(pulses) + margin)
