"""The core's vocabulary and its state: what comes in (inputs), what goes out (effects), and
the value the protocol (`core.step`) turns one into the next.

Data only (frozen). Times are CLOCK_MONOTONIC seconds (`al5d.clock.now`), sending times
CLOCK_REALTIME ns (`al5d.clock.wall_ns`); every input carries both, as the owner read
them when it took the input, and nothing here reads a clock.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Hashable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from enum import Enum

from al5d.arm import jobs
from al5d.arm.config import ArmConfig, ServerSettings
from al5d.arm.instruction import Instruction, Outcome, Result
from al5d.arm.jobs import NO_JOBS, Job, Jobs, Mode, Sent, Written, stop_order
from al5d.arm.order import Order
from al5d.arm.pose import PoseBook
from al5d.arm.states import LOCKED_BY_RESET, Event, Guards, State, TransitionError, next_state
from al5d.arm.translate import Translator
from al5d.arm.validate import Limits, Steps, Ticket
from al5d.ssc32u import protocol as p
from al5d.ssc32u.errors import BoardReset, SerialFault
from al5d.ssc32u.facts import LATENCY_TIMER_MS, LOW_LATENCY_TIMER_MS

# -- inputs -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Input:
    """Something the owner hands the core, at `t` (monotonic s) and `wall` (realtime ns)."""

    t: float
    wall: int


@dataclass(frozen=True, slots=True)
class Ask(Input):
    """A request: an instruction (or a ticket judged already), from client `client`, its
    outcome to go to `ref`. `stream`: a set-point of that stream; `key`: a stop message's
    identity where two readers may both see it (rule 3); `tell`: the outcome listeners
    hear of its outcome too."""

    ref: int
    instr: Instruction
    ticket: Ticket | None = None
    stream: str = ""
    key: Hashable | None = None
    client: int = 0
    tell: bool = True


@dataclass(frozen=True, slots=True)
class Cancel(Input):
    """Cancel the move `ident`; whether it was there goes to `ref` (`Reply`)."""

    ref: int
    ident: str
    reason: str = "cancelled by the client"


@dataclass(frozen=True, slots=True)
class Tick(Input):
    """Time has passed. `stalled`: the seconds, so far, the owner's thread was not running
    when it should have been, or the host was short of cores (a board's answer that came
    that much late was late because of the host, not the board)."""

    stalled: float = 0.0


@dataclass(frozen=True, slots=True)
class Received(Input):
    """Bytes from the board."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Opened(Input):
    """The port asked for by `Open`: opened (`error` None; `low_latency`: the USB chip
    passes short answers on at once), or not."""

    error: SerialFault | None = None
    low_latency: bool = False


@dataclass(frozen=True, slots=True)
class Failed(Input):
    """Reading or writing the open port failed."""

    error: SerialFault


@dataclass(frozen=True, slots=True)
class Gone(Input):
    """Client `client` has gone (closed, ended, or lost: `why`)."""

    client: int
    why: str = ""


# -- effects ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Send:
    """Bytes for the board, to write now."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Open:
    """Open the port (the owner answers with `Opened`)."""


@dataclass(frozen=True, slots=True)
class Close:
    """Close the port."""


@dataclass(frozen=True, slots=True)
class Resolve:
    """The one outcome of request `ref`; `tell`: the outcome listeners hear of it too."""

    ref: int
    outcome: Outcome
    tell: bool = True


@dataclass(frozen=True, slots=True)
class Cancelled:
    """Every job of `jobs` cancelled (`why`, at `t`): one effect, whose outcomes are made by
    whoever carries it (`resolves`), after the effects before it. A stop drops every
    waiting job, and a thousand outcomes made within its step held its STOP 2.4 ms."""

    jobs: tuple[Job, ...]
    why: str
    t: float

    def resolves(self) -> Iterator[Resolve]:
        for job in self.jobs:
            told = jobs.outcome(job.instr, Result.CANCELLED, self.why, job.t_submit, self.t)
            yield Resolve(job.ref, told, job.tell)


@dataclass(frozen=True, slots=True)
class Reply:
    """The answer to a `Cancel`: whether the move was there to cancel."""

    ref: int
    ok: bool


@dataclass(frozen=True, slots=True)
class Announce:
    """A transition of the state machine (logged, and told to the state listeners)."""

    event: Event
    old: State
    new: State


@dataclass(frozen=True, slots=True)
class Moved:
    """A step's bytes are all out: the board runs its motion."""

    sent: Sent


@dataclass(frozen=True, slots=True)
class Posed:
    """What the core believes of the arm changed: where it is, where it goes, which step of
    which instruction runs (for the clients that show or follow the arm)."""

    book: PoseBook
    running: tuple[str, int, int] | None  # (instruction id, step, steps)


@dataclass(frozen=True, slots=True)
class Say:
    """A log line (logging's level)."""

    level: int
    text: str


@dataclass(frozen=True, slots=True)
class End:
    """The core has ended (after the shutdown); `parked`: the arm reached park."""

    parked: bool


Effect = Send | Open | Close | Resolve | Cancelled | Reply | Announce | Moved | Posed | Say | End


# -- the state --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Arm:
    """What the core knows of the arm and its board, which no input changes."""

    config: ArmConfig
    port: str
    baud: int
    limits: Limits
    translator: Translator
    channels: Mapping[str, int]
    #: Half a pulse microsecond per joint, in degrees: a set-point closer than this to
    #: where a joint is going writes the same pulse, so it changes nothing.
    same_deg: Mapping[str, float]

    @classmethod
    def of(cls, config: ArmConfig, port: str, baud: int | None = None) -> Arm:
        baud = baud or config.server.baud
        return cls(
            config,
            port,
            baud,
            Limits.of(config, baud),
            Translator(config),
            {n: j.channel for n, j in config.joints.items()},
            {n: 0.5 / abs(j.us_per_deg) for n, j in config.joints.items()},
        )

    @property
    def settings(self) -> ServerSettings:
        return self.config.server


class Purpose(Enum):
    """What a query is asked for."""

    VERSION = "VER: is it an SSC-32U"
    POSE = "QP of every channel: where the servos are"
    PROBE = "QP of one channel: the link, and that the board has not reset"
    ALIVE = "Q: the link (no pose is known to probe)"
    DONE = "Q: the last step has ended"
    HALTED = "Q: is the board still running a move that was cancelled"


@dataclass(frozen=True, slots=True)
class Probe:
    """A link check's `QP`: the channel it reads, and the pulses (us) it expects there."""

    joint: str
    channel: int
    low_us: float
    high_us: float


@dataclass(frozen=True, slots=True)
class Query:
    """A query on its way: its bytes, how its answer ends (bytes each, or None: a CR), when
    it is due, how often it was asked, and what had been written when it was asked."""

    purpose: Purpose
    data: bytes
    n_answer: int | None
    due: float
    asks: int
    writes: int
    stalled: float
    probe: Probe | None = None


class Next(Enum):
    """What comes after the pose is read from a board just opened (or at the shutdown)."""

    STARTUP = "the start-up park"
    RECONNECT = "back from a fault"
    SHUTDOWN = "the shutdown's park"


@dataclass(frozen=True, slots=True)
class Link:
    """The board's connection, the account of its wire, and the line and query on it."""

    #: The port is open (it may still be checked); False: `Open` is due at `open_at`.
    open: bool = False
    opening: bool = False  # `Open` is out, `Opened` not back yet
    checked: bool = False  # VER said SSC-32U
    open_at: float = 0.0
    #: The margin an answer may take beyond its wire time (the read timeout and the USB
    #: chip's latency timer).
    margin_s: float = 0.0
    #: When the wire will have carried every byte written so far.
    free_at: float = 0.0
    #: A line going out in pieces: the bytes still to write, and what it is (a step of the
    #: current run, or a halt).
    rest: bytes = b""
    rest_is_halt: bool = False
    #: A line was cut short (its rest not written): the next bytes begin with ESC.
    cut: bool = False
    query: Query | None = None
    received: bytes = b""
    #: Answers still owed to a query asked twice and taken on its first answer: how each
    #: ends (bytes each, or None: a CR), and how many. The board answers in order, so they
    #: come before any later query's, and are dropped as they come, until `owed_until`
    #: (a board that answered one ask of two must not cost every later query its answer).
    owed: tuple[int | None, int] = (None, 0)
    owed_until: float = 0.0
    writes: int = 0  # lines (and stops) written so far: a QP's answer is judged if none since
    watched: float = 0.0  # when the link was last checked
    #: After the pose is read from a board just opened: what comes next; `halt_checked`:
    #: a move the board may still run (cancelled without a halt) has been halted.
    next: Next | None = None
    halt_checked: bool = False
    #: The host's stalls so far, as the last `Tick` said (queries' deadlines excuse them).
    stalled: float = 0.0


@dataclass(frozen=True, slots=True)
class Run:
    """The current job as it runs: its steps, the step now, and the step's write."""

    job: Job
    steps: Steps
    k: int = 0
    #: Step `k`'s write (None: it waits for the wire). Its time is over at `written.t_end`.
    written: Written | None = None
    #: When the step written last is due to end by the schedule: the timed steps after the
    #: first keep to the schedule of the first, so that a late wake-up, or a point faster
    #: than the servos, does not make every later point late too.
    t_due: float = 0.0
    expected_ms: float = 0.0
    #: The last step's time is over: `Q` is asked (every `POLL_S`) until it says done.
    confirming: bool = False
    poll_at: float = 0.0
    #: A `Q` after the last step's time said the board still moves it.
    still_moving: bool = False
    #: The step's line, planned: its bytes and its time (sent with the line's first piece).
    line: bytes = b""
    #: Of `line`, the bytes of the line before the step's own that puts the joints of
    #: unsure pose where the core believes them (`PoseBook.unsure`).
    held_bytes: int = 0
    line_ms: int = 0
    line_start: Mapping[str, float] = field(default_factory=dict)
    t_write: float = 0.0
    #: What the owner changed of what was asked (a time raised to what the servos can do),
    #: said in the outcome.
    notes: tuple[str, ...] = ()
    #: A set-point that took a running one's place: planned from where that one has the
    #: arm when its bytes take effect.
    retarget: bool = False
    #: When step `k` (after the first) was due to be written: a wire time before the step
    #: ahead of it ended. Written later than that, the board holds the point before while
    #: the path moves on (a host that did not run the owner in time).
    write_due: float = 0.0
    #: When step `k`'s line would take effect had every piece of it gone out when due (the
    #: wire's pace allowing): the yardstick of a point's lateness.
    due_effect: float = 0.0
    #: The time of the step that planned or checked the run as it started (a Cartesian
    #: move: about 10 ms of IK; a trajectory of 200 points: about 10 ms of its path against
    #: the table): its first line goes out in a later step, whose time is read after that
    #: work, or the wire's account starts that long before its bytes do: the next hop of a
    #: line takes effect before this one has ended (its corner cut), and every point of a
    #: trajectory is written that much early (its schedule counts from the first line).
    #: Or its job's start, where that is later (`Job.start_at`: a trajectory's stamp).
    not_before: float = -math.inf


@dataclass(frozen=True, slots=True)
class Core:
    """Everything the arm's protocol knows; `core.step` makes the next one from an input."""

    arm: Arm
    book: PoseBook
    state: State = State.INITIALIZING
    locked: bool = False  # a stop (or a board's reset) and no release since
    epoch: int = 0  # counts the events that dropped every pending move
    #: Why the streams of set-points are held (empty: they are not). A stream's source
    #: (ros2_control's hardware) sends its last target again and again while the arm is
    #: off it: after a stop, that target must not drive the arm once it is released.
    streams_held: str = ""
    #: When a set-point of each stream last came: the watchdog holds the arm where it is
    #: once none has come for `server.stream_timeout_s`.
    stream_seen: Mapping[str, float] = field(default_factory=dict)
    queue: Jobs = NO_JOBS
    #: When the sender of a waiting job gives up on it, at the earliest (an earlier time, of
    #: a job gone meanwhile, only wakes the core for nothing).
    give_up_at: float = math.inf
    run: Run | None = None
    link: Link = field(default_factory=Link)
    fault: SerialFault | None = None
    #: The pose is to be read back from the board (after a halt): nothing is written until
    #: it has been, or the pose read would be a snapshot of a motion.
    readback: bool = False
    #: A stop came while the port was closed (a fault): its STOP goes out as soon as the
    #: board is reached again, whatever the board then says of motion.
    halt_owed: bool = False
    shutdown: Job | None = None
    shutdown_taken: bool = False
    parked: bool = False  # the start-up park has been done
    order: Order = field(default_factory=Order)
    ended: bool = False
    firmware: str = ""  # what the board said to VER
    #: The time of the latest input taken: all that was due until then is done, and what
    #: falls due after it wants a wake (`al5d.arm.core.wake_at`), however late the owner
    #: comes back to ask.
    t: float = -math.inf

    @classmethod
    def start(cls, arm: Arm, t: float = 0.0) -> Core:
        """A core for `arm`, its port to open at `t`."""
        return cls(arm, PoseBook.unknown(arm.config.joints), link=Link(open_at=t), t=t)

    # -- reading -------------------------------------------------------------------------

    def positions(self, t: float) -> dict[str, float]:
        """Estimated joint angles at `t` (degrees; NaN where unknown since power-up)."""
        return self.book.positions(t)

    @property
    def idle(self) -> bool:
        """At rest on a board: nothing runs, is written, waits or is to be read back."""
        return (
            self.state is State.READY
            and self.link.checked
            and self.run is None
            and not self.queue
            and not self.readback
            and not self.link.rest
        )


def margin_s(settings: ServerSettings, low_latency: bool) -> float:
    """How long an answer may take beyond its wire time: the read timeout, and the time a
    short answer waits in the board's USB chip."""
    timer_ms = LOW_LATENCY_TIMER_MS if low_latency else LATENCY_TIMER_MS
    return settings.answer_timeout_s + timer_ms / 1000.0


# -- the steps the inputs share ---------------------------------------------------------
#
# Each takes the core and what it needs, adds what is to be done to `out` (in order), and
# returns the new core.

Out = list[Effect]


def guards(c: Core) -> Guards:
    running = c.run is not None and c.run.job.mode is Mode.QUEUE
    return Guards(queue_empty=not c.queue and not running, locked=c.locked, parked=c.parked)


def fire(c: Core, event: Event, out: Out) -> Core:
    """The state machine's transition on `event` (`states.TABLE`); announced."""
    new = next_state(c.state, event, guards(c))
    if new is None:
        raise TransitionError(f"no transition from {c.state.value} on {event.value}")
    out.append(Announce(event, c.state, new))
    return replace(c, state=new)


def say(out: Out, level: int, text: str) -> None:
    out.append(Say(level, text))


def finish(
    job: Job, result: Result, reason: str, t: float, out: Out, expected: float = 0.0
) -> None:
    """The job's one outcome."""
    outcome = jobs.outcome(job.instr, result, reason, job.t_submit, t, expected)
    out.append(Resolve(job.ref, outcome, job.tell))


def posed(c: Core, out: Out) -> None:
    """Tell the clients that follow the arm what the core now believes."""
    run = c.run
    running = (run.job.instr.id, run.k, len(run.steps)) if run is not None and run.steps else None
    out.append(Posed(c.book, running))


def send(c: Core, data: bytes, t: float, out: Out, *, pulses: bool = True) -> Core:
    """Bytes to the board now, on the wire's account; `pulses`: they may change what the
    board puts out (a line, a STOP: not a query). After a line cut short, ESC first."""
    link = c.link
    if link.cut and not data.startswith(p.CANCEL):
        data = p.CANCEL + data
    out.append(Send(data))
    free = max(t, link.free_at) + p.wire_time_s(len(data), c.arm.baud)
    link = replace(link, free_at=free, cut=False, writes=link.writes + pulses)
    return replace(c, link=link)


def lock_arm(c: Core, by: str, sent_ns: int, key: Hashable | None = None) -> Core:
    """Lock (or keep locked), by an event sent at `sent_ns` (a stop known by `key`): a
    release must be sent later."""
    return replace(c, locked=True, order=c.order.locked(by, sent_ns, c.locked, key))


def drop(c: Core, why: str, sent_ns: int) -> tuple[Core, list[Job]]:
    """End the epoch: the current job and every waiting one are never to be written (their
    outcomes are the caller's to set). A step's line still going out is cut; the shutdown's
    own park is not among them. `sent_ns`: when the event that drops them was sent."""
    jobs = list(c.queue)
    run = c.run
    if run is not None and run.job is not c.shutdown:
        jobs.insert(0, run.job)
    link = c.link
    if link.rest and not link.rest_is_halt:
        link = replace(link, rest=b"", cut=True)
    c = replace(
        c,
        epoch=c.epoch + 1,
        order=c.order.dropped(why, sent_ns),
        streams_held=why,
        queue=NO_JOBS,
        run=None,
        link=link,
    )
    return c, jobs


#: A stop that finds the port closed (a fault) has it opened this long after its answer.
STOP_OPENS_AFTER_S = 0.001


def halt(c: Core, t: float, out: Out, urgent: bool = True) -> Core:
    """A STOP of every channel, the moving joints first: an emergency stop's at once; a
    cancelled move's (`urgent` False) on the wire's pace, in place of a line going out. The
    pose is where the motion is now, until it is read back."""
    order = stop_order(c.book.motion, t, c.arm.channels)
    c = replace(c, book=c.book.halted(t), readback=True)
    link = c.link
    if not link.open:
        if urgent:
            c = replace(c, halt_owed=True)
            if not link.opening:
                # Tried now, not at the reconnect's interval; in a turn of the owner's own,
                # so that the stop's answer does not wait for the port to open. (A board
                # that did not answer VER is told apart from another device by nothing but
                # its answer: both are tried, as every reconnect tries them.)
                when = min(link.open_at, t + STOP_OPENS_AFTER_S)
                c = replace(c, link=replace(link, open_at=when))
        return c
    c = replace(c, halt_owed=False)
    data = p.CANCEL + p.encode_stop(order)
    if urgent:
        # Its ESC cancels on the board whatever part of a line went out before it.
        c = replace(c, link=replace(c.link, rest=b"", cut=False))
        return send(c, data, t, out)
    return replace(c, link=replace(c.link, rest=data, rest_is_halt=True, cut=False))


def cancel_all(dropped: list[Job], why: str, t: float, out: Out) -> None:
    if dropped:
        out.append(Cancelled(tuple(dropped), why, t))


#: Said when a reset has locked the arm.
RESET_LOCKED = "the arm is locked after the board's reset: send release to go on"


def lose(c: Core, error: SerialFault, t: float, wall: int, out: Out) -> Core:
    """The fault: the link is gone (or the board reset); everything pending ends, the port is
    closed and opened again every `server.reconnect_interval_s`."""
    reset = isinstance(error, BoardReset)
    say(out, logging.ERROR, f"serial fault: {error}")
    if reset:
        # A safety event: nothing moves again until a person has looked at the arm.
        c = replace(lock_arm(c, LOCKED_BY_RESET, wall), book=c.book.forget())
        say(out, logging.WARNING, RESET_LOCKED)
    why = str(error) if reset else f"the serial link is lost: {error}"
    c, jobs = drop(c, why, wall)
    if c.link.open or c.link.opening:
        out.append(Close())
    interval = c.arm.settings.reconnect_interval_s
    c = replace(
        c,
        fault=error,
        book=c.book.lost(),
        readback=False,
        link=Link(open_at=t + interval, watched=t),
    )
    if c.state is not State.FAULT:
        c = fire(c, Event.SERIAL_FAULT, out)
    cancel_all(jobs, why, t, out)
    posed(c, out)
    if c.shutdown is not None and not c.ended:
        c = end_shutdown(c, f"the serial link is lost ({error}): the arm is not parked", t, out)
    return c


def end_shutdown(c: Core, why: str, t: float, out: Out) -> Core:
    """The shutdown ends: parked (`why` empty) or not; the core has ended."""
    job = c.shutdown
    assert job is not None
    if why:
        say(out, logging.ERROR, f"shutdown: {why}")
        finish(job, Result.CANCELLED, why, t, out)
    else:
        say(out, logging.INFO, "shutdown: parked")
        finish(job, Result.DONE, "", t, out)
    if c.link.open or c.link.opening:
        out.append(Close())
    out.append(End(parked=not why))
    return replace(c, ended=True, run=None, link=replace(c.link, open=False, opening=False))


def complete(c: Core, t: float, out: Out) -> Core:
    """The current job has completed: its joints are where it sent them, its outcome is
    done (with what the owner changed of what was asked), and the next may start."""
    run = c.run
    assert run is not None
    job = run.job
    c = replace(c, run=None, book=c.book.reached(run.steps[-1].target).at_rest())
    if job.mode is Mode.STARTUP:
        c = fire(replace(c, parked=True), Event.MOVE_DONE, out)
    elif job.mode is Mode.SHUTDOWN:
        return end_shutdown(c, "", t, out)
    else:
        finish(job, Result.DONE, "; ".join(run.notes), t, out, run.expected_ms)
        if c.state is State.MOVING:
            c = fire(c, Event.MOVE_DONE, out)
    posed(c, out)
    return c
