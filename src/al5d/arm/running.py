"""A job as it runs, on the core's value: its steps planned, written on the wire's pace,
waited for, confirmed; a stream's set-points watched.

Pure steps (`corestate`'s conventions). The wire is not a queue: a step's line is
written only when at most `WIRE_HORIZON_S` of earlier bytes are still on their way (a
stream's set-point only when the wire is free, where a newer one may still take its
place), and a line longer than `WIRE_PIECE_S` on the wire goes out in pieces, each
when the horizon allows it, cut only between whole commands. So a stop finds at most
the horizon and one piece ahead of it in the port, and a line it cuts short holds no
partial number: its ESC cancels the whole commands the board has of it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import replace

from al5d.arm.corestate import (
    Core,
    Moved,
    Out,
    Purpose,
    Run,
    complete,
    finish,
    fire,
    halt,
    posed,
    say,
    send,
)
from al5d.arm.instruction import NOT_RUN, Kind, Result
from al5d.arm.jobs import Job, Mode, Motion, Sent, Written
from al5d.arm.link import ask, can_ask, watch
from al5d.arm.pose import SETTLE_GRACE_S
from al5d.arm.states import Event, State
from al5d.arm.validate import from_start, planned
from al5d.ssc32u import protocol as p
from al5d.ssc32u.facts import BITS_PER_BYTE

#: How much of earlier bytes' wire time a step may find still to go when it is written (the
#: horizon a stop can find ahead of it, with the one piece written last).
WIRE_HORIZON_S = 0.02
#: A line longer than this on the wire goes out in pieces of about it (9 bytes at 9600
#: baud, 115 at 115200: only the slow bauds' long lines are cut).
WIRE_PIECE_S = 0.01
#: A run that waits longer than this for its start (`Job.start_at`) says so: the arm stands
#: still while `moving`, and what comes after waits behind it.
SAID_WAIT_S = 0.5
#: A point of a trajectory whose line takes effect later than its schedule by more than
#: this is judged against the path tolerance (less is the wire's and the host's jitter).
LATE_JUDGED_S = 0.005


def horizon(job: Job) -> float:
    """How much of earlier bytes a job's line may find still on the wire: a stream's
    set-point waits until the wire is free (at 9600 baud a line is 32 ms of wire, and a
    50 Hz stream sends a newer one every 20 ms: one written behind the line on the wire
    could no longer be superseded)."""
    return 0.0 if job.stream else WIRE_HORIZON_S


def piece(data: bytes, baud: int) -> int:
    """How many bytes of `data` go in the next piece: about `WIRE_PIECE_S` of wire, ended
    between two whole commands (before a `#` or a `T`, after a CR), or all of it."""
    limit = max(1, int(baud / BITS_PER_BYTE * WIRE_PIECE_S))
    if len(data) <= limit:
        return len(data)
    cut = 0
    for i in range(1, len(data)):
        if data[i] in b"#T" or data[i - 1] == p.CR[0]:
            if i > limit and cut:
                break
            cut = i
            if i > limit:
                break
    return cut or len(data)


# -- starting ---------------------------------------------------------------------------


def start(c: Core, job: Job, t: float, out: Out) -> Core:
    """The job becomes the current run. A Cartesian move is planned when it starts, from where
    the arm is then; any other move's path is judged against the table from there (the
    owner's own parks are not: they are how the server makes the arm safe). Refused as
    it starts if that fails: its outcome, and the next may start."""
    steps = job.steps
    reason = ""
    pose = c.book.pose
    limits = c.arm.limits
    if stale_set_point(c, job, t, out):
        if c.state is State.MOVING and not c.queue:
            c = fire(c, Event.MOVE_DONE, out)
        return c
    if not steps:
        got = planned(job.instr, pose, limits, c.arm.translator)
        if isinstance(got, str):
            reason = got
        else:
            steps = got
    elif job.mode is Mode.QUEUE:
        reason = from_start(job.instr, steps, pose, limits)
    if reason:
        finish(job, Result.REFUSED, reason, t, out)
        if c.state is State.MOVING and not c.queue:
            c = fire(c, Event.MOVE_DONE, out)
        return c
    # A run of one step checked in this step is written in it: its check took microseconds.
    worked = not job.steps or len(steps) > 1
    not_before = max(t if worked else -math.inf, job.start_at)
    if job.start_at - t > SAID_WAIT_S:
        wait = f"waits {job.start_at - t:.2f} s for its start (header.stamp)"
        say(out, logging.INFO, f"{job.instr.name} [{job.instr.id}]: {wait}")
    return replace(c, run=Run(job, steps, not_before=not_before))


# -- planning a step --------------------------------------------------------------------


def plan(c: Core, run: Run, t: float) -> Run:
    """Step `k`'s line and time (ms), from where the arm is. A step after the first is timed
    to end when the schedule says, its `time_ms` after the one before was due to end,
    however early or late it takes effect; what the servos cannot do is said (INF03) and
    noted for the outcome."""
    job, k = run.job, run.k
    step = run.steps[k]
    tr = c.arm.translator
    pose = dict(c.book.pose)
    motion = c.book.motion
    if k == 0 and run.retarget and motion is not None:
        # It retargets the set-point it superseded mid-move: planned from where that one
        # has the arm when these bytes take effect.
        pose.update(motion.at(_arrival(c, len(tr.encode(step.target, 0)), t)))
    notes = list(run.notes)
    unknown = [j for j in step.target if pose.get(j) is None]
    if unknown:
        say_later = (
            f"D1: {job.instr.name} [{job.instr.id}]: first command for {', '.join(unknown)} "
            "since the board powered up (or reset): the board ignores speed and time for it, "
            "so they go at full servo speed"
        )
        notes.append(say_later)
    minimum = tr.minimum_ms(pose, step.target, job.speed_fraction)
    min_ms = math.ceil(minimum - 1e-9)
    requested = step.time_ms or 0
    if requested and k > 0:
        due = run.t_due + requested / 1000.0
        length = len(tr.encode(step.target, requested))
        requested = max(1, round((due - _arrival(c, length, t)) * 1000.0))
    time_ms = max(requested, min_ms)
    if job.instr.kind is Kind.MOVE_TO and len(run.steps) > 1:
        if k == 0:
            notes += _line_note(c, run, pose)
    elif step.time_ms and requested < min_ms:
        point = f" point {k}" if len(run.steps) > 1 else ""
        left = "" if requested == step.time_ms else f" ({requested} ms left of its schedule)"
        notes.append(
            f"INF03: {job.instr.name} [{job.instr.id}]{point} cannot be done in the requested "
            f"{step.time_ms} ms{left}; expected {time_ms} ms"
        )
    start = {j: v for j, v in pose.items() if v is not None}
    line = tr.encode(step.target, time_ms)
    unsure = {j: start[j] for j in c.book.unsure if j in start}
    held = b""
    if k == 0 and job.mode is Mode.QUEUE and unsure:
        # Joints known to within a step of `QP` only are put where the core believes them
        # first, at once (no time: a jump of less than 10 us), so that the path the board
        # takes is the one judged from `start` (the owner's parks are not judged).
        held = tr.encode(unsure, 0)
    return replace(
        run,
        line=held + line,
        held_bytes=len(held),
        line_ms=time_ms,
        line_start=start,
        notes=tuple(notes),
    )


def _line_note(c: Core, run: Run, pose: Mapping[str, float | None]) -> list[str]:
    """INF03 once for a straight line whose `time` the servos cannot hold (not once per hop)."""
    job = run.job
    asked = job.instr.time_ms
    if not asked:
        return []
    here: Mapping[str, float | None] = pose
    expected = 0
    for step in run.steps:
        need = c.arm.translator.minimum_ms(here, step.target, job.speed_fraction)
        expected += max(step.time_ms or 0, math.ceil(need - 1e-9))
        here = {**here, **step.target}
    if expected <= asked:
        return []
    return [
        f"INF03: {job.instr.name} [{job.instr.id}] cannot be done in the requested "
        f"{asked} ms; expected {expected} ms"
    ]


def _arrival(c: Core, n_bytes: int, t: float) -> float:
    """When a line of `n_bytes` written now would have reached the board."""
    return max(t, c.link.free_at) + p.wire_time_s(n_bytes, c.arm.baud)


# -- writing a step ---------------------------------------------------------------------


def _write(c: Core, run: Run, t: float, out: Out) -> Core:
    """Step `k`'s line when the wire allows: its first piece now (the rest, piece by piece,
    by `pieces`); once all of it is out, the step is written."""
    if run.line or not c.link.checked or c.link.rest:
        return c  # its pieces are going out, or a halt's are
    if t <= run.not_before:
        return c  # planned in this step: its time is stale (`Run.not_before`)
    if c.link.free_at - horizon(run.job) > t:
        return c
    told = len(run.notes)
    run = plan(c, run, t)
    if run.retarget and run.k == 0:
        # It takes a running set-point's place mid-move: its path is judged against the
        # table from where that one has the arm when these bytes take effect.
        reason = from_start(run.job.instr, run.steps, run.line_start, c.arm.limits)
        if reason:
            return end_run(c, reason, t, out, Result.REFUSED)
    for note in run.notes[told:]:
        say(out, logging.WARNING, note)
    # Where the host ran the owner in time, the line took effect at `due_effect`: written
    # when due, or when the wire's pace first allowed it.
    free = c.link.free_at
    due = max(run.write_due, free - horizon(run.job))
    due_effect = max(due, free) + p.wire_time_s(len(run.line), c.arm.baud)
    size = piece(run.line, c.arm.baud)
    c = send(c, run.line[:size], t, out)
    link = replace(c.link, rest=run.line[size:], rest_is_halt=False)
    c = replace(c, link=link, run=replace(run, t_write=t, due_effect=due_effect))
    return _written(c, t, out) if not link.rest else c


def pieces(c: Core, t: float, out: Out) -> Core:
    """The next piece of a line going out, when the horizon allows it; a step's line whose
    last piece went is written."""
    link = c.link
    if not link.rest or link.free_at - WIRE_HORIZON_S > t:
        return c
    size = piece(link.rest, c.arm.baud)
    was_halt = link.rest_is_halt
    c = send(c, link.rest[:size], t, out)
    c = replace(c, link=replace(c.link, rest=link.rest[size:]))
    if not c.link.rest and not was_halt and c.run is not None:
        return _written(c, t, out)
    return c


def _written(c: Core, t: float, out: Out) -> Core:
    """A step's line is all out: the motion it makes on the board, when its time is over,
    and the schedule; a trajectory's point that took effect too late for its path
    tolerance ends the job."""
    run = c.run
    assert run is not None
    job, k, step = run.job, run.k, run.steps[run.k]
    t_sent = c.link.free_at  # the CR's arrival: the move starts then
    t_end = t_sent + run.line_ms / 1000.0
    if not step.time_ms:
        t_due = t_end
    elif k:
        t_due = run.t_due + step.time_ms / 1000.0
    else:
        t_due = t_sent + step.time_ms / 1000.0
    motion = Motion(run.line_start, step.target, t_sent, run.line_ms / 1000.0)
    # The step's own line: the next step goes that wire time before this one ends.
    wire = p.wire_time_s(len(run.line) - run.held_bytes, c.arm.baud)
    book = c.book.moving(motion, run.t_write, t_end)
    if run.held_bytes:
        book = book.held()
    late = _off_path(c, run, t_sent) if k and step.time_ms else ""
    run = replace(
        run,
        written=Written(motion, t_end, wire, run.line, run.t_write),
        t_due=t_due,
        expected_ms=run.expected_ms + run.line_ms,
    )
    c = replace(c, run=run, book=book)
    steps = len(run.steps)
    on_board = book.motion or motion
    out.append(Moved(Sent(job.instr, run.line, job.t_submit, run.t_write, on_board, k, steps)))
    if late:
        return end_run(c, late, t, out)
    posed(c, out)
    return c


def _off_path(c: Core, run: Run, t_sent: float) -> str:
    """Why a trajectory's point `k`, whose line took effect at `t_sent`, leaves the path
    beyond its tolerance (""): later than it would have had the host run the owner in time
    (`Run.due_effect`), the board holds the point before while the path moves on. (A point
    the servos cannot reach in its time slips the schedule, not the path: that is the
    trajectory's lateness, which its result reports: so a joint is behind by at most its
    servo's speed times the lateness, however fast its point asked it to go.)"""
    late = t_sent - run.due_effect
    if run.job.instr.kind is not Kind.TRAJECTORY or late <= LATE_JUDGED_S:
        return ""
    step, before = run.steps[run.k], run.steps[run.k - 1]
    span = (step.time_ms or 1) / 1000.0
    follow = run.job.follow
    joints = c.arm.config.joints
    for joint, target in step.target.items():
        travel = abs(target - before.target.get(joint, target))
        rate = min(travel / span, joints[joint].speed_deg_s)
        off = min(travel, rate * late)
        tolerance = c.arm.limits.path_tolerance_deg
        if follow is not None:
            tolerance = follow.tolerance.get(joint, tolerance)
        if off > tolerance:
            return (
                f"point {step.point if step.point >= 0 else run.k} took effect "
                f"{late * 1000.0:.0f} ms late: {joint} was {off:.2f} deg off its path, "
                f"tolerance {tolerance:g} deg (the host did not run the owner in time)"
            )
    return ""


def wakes(c: Core, run: Run) -> list[float]:
    """When the run has something to do next (`core.wake_at`)."""
    written = run.written
    if written is None:
        write_at = max(c.link.free_at - horizon(run.job), math.nextafter(run.not_before, math.inf))
        return [write_at, _watch_at(c, run.job.start_at)]
    if run.confirming:
        return [run.poll_at]
    times = [_until(run, written), _watch_at(c, written.t_end)]
    if run.job.stream:
        times.append(_quiet_at(c, run, written))
    return times


def _until(run: Run, written: Written) -> float:
    """When the run moves on from its step: a wire time before its end (so that the next
    takes effect as this one ends), or at its end for the last."""
    last = run.k == len(run.steps) - 1
    return written.t_end if last else written.t_end - written.wire_s


def _watch_at(c: Core, until: float) -> float:
    """When the link is next checked before `until` (a step's end, or a run's start:
    `Job.start_at`): every `moving_check_interval_s`, while at least half of that is left,
    so that the check's answer is in by then (inf: not before it)."""
    every = c.arm.settings.moving_check_interval_s
    at = c.link.watched + every
    return at if until - at > every / 2 else math.inf


def _quiet_at(c: Core, run: Run, written: Written) -> float:
    """When a running set-point's stream has been quiet for `server.stream_timeout_s`."""
    return _quiet_since(c, run.job.stream, written.t_write)


def _quiet_since(c: Core, stream: str, t: float) -> float:
    """When `stream` has been quiet for `server.stream_timeout_s` (counted from `t` where it
    has not been seen)."""
    return c.stream_seen.get(stream, t) + c.arm.settings.stream_timeout_s


def stale_set_point(c: Core, job: Job, t: float, out: Out) -> bool:
    """A set-point about to be written whose stream went quiet while it waited (behind a
    move, for the wire) is cancelled, not written: the target of a source that stopped or
    lost its link is not driven to (an outside try: a killed stream's last set-point
    swung the base 69 degrees 2.8 s after the kill). Whether it was."""
    if not job.stream or _quiet_since(c, job.stream, t) > t:
        return False
    why = f"{went_quiet(c, job.stream)} before it was written: not written"
    say(out, logging.WARNING, f"watchdog: {job.instr.name} [{job.instr.id}]: {why}")
    finish(job, Result.CANCELLED, why, t, out)
    return True


def went_quiet(c: Core, stream: str) -> str:
    """Why the watchdog holds `stream`'s set-point."""
    timeout = c.arm.settings.stream_timeout_s
    return (
        f"the stream {stream} went quiet (no set-point for {timeout:g} s, server.stream_timeout_s)"
    )


# -- waiting for a step -----------------------------------------------------------------


def progress(c: Core, t: float, out: Out) -> Core:
    """Drive the current run: write its step when the wire allows, move on to the next one a
    wire time before this one ends (so that it takes effect as this one ends), confirm the
    last with `Q`, check the link during long steps, and watch a stream's set-point."""
    run = c.run
    assert run is not None
    written = run.written
    if written is None:
        if t >= _watch_at(c, run.job.start_at) and can_ask(c, t):
            c = watch(c, t, out)
        return _write(c, run, t, out)
    settings = c.arm.settings
    if run.job.stream and _quiet_at(c, run, written) <= t < written.t_end:
        return _hold(c, t, out)
    last = run.k == len(run.steps) - 1
    if t < _until(run, written):
        if t >= _watch_at(c, written.t_end) and can_ask(c, t):
            c = watch(c, t, out)
        return c
    if not last:
        book = c.book.reached(run.steps[run.k].target)
        after = Run(
            run.job,
            run.steps,
            run.k + 1,
            t_due=run.t_due,
            expected_ms=run.expected_ms,
            notes=run.notes,
            write_due=_until(run, written),
        )
        return replace(c, book=book, run=after)
    if run.job.stream:
        # A set-point is done when its time is over, without `Q`: its stream's next one,
        # due any moment, must not wait for a query's answer. The link is still checked
        # every `moving_check_interval_s` of a stream.
        if t >= c.link.watched + settings.moving_check_interval_s and can_ask(c, t):
            c = watch(c, t, out)
        return complete(c, t, out)
    if not run.confirming:
        if not c.book.q_believed(t):
            return complete(c, t, out)  # Q still counts a stopped move down: time alone
        run = replace(run, confirming=True, poll_at=t)
        c = replace(c, run=run)
    if t >= run.poll_at and can_ask(c, t):
        c = ask(c, Purpose.DONE, p.encode_query_movement(), 1, t, out)
        c = replace(c, run=replace(run, poll_at=math.inf))
    return c


#: A run whose last line (all its pieces: `Run.written`) has been over this long is one the
#: board has run to its end: the board's own timing lags the owner's estimate by its link
#: and its host (`pose.SETTLE_GRACE_S`), unless a `Q` since said otherwise.
OVER_BY_S = SETTLE_GRACE_S


def over(c: Core, t: float, out: Out) -> Core:
    """The current run completed, if the board has run it to its end by `t`: what ends it
    now (a stop, a cancel, its client lost, its sender's giving up, the shutdown or its
    stream's next set-point) came after the arm got there, though before the owner looked
    (its thread frozen or starved), and must not report as cut short a move the arm
    finished. The core as it was if not, and for the owner's own parks (at start-up, at
    the shutdown), which a stop cuts short as before. A `Q` of this run's still on its way
    says only that the link lives when its answer comes: the next run must not take it
    for its own."""
    run = c.run
    written = run.written if run is not None else None
    if run is None or written is None or run.k < len(run.steps) - 1:
        return c
    if run.job.mode is not Mode.QUEUE or run.still_moving or t < written.t_end + OVER_BY_S:
        return c
    query = c.link.query
    if query is not None and query.purpose is Purpose.DONE:
        c = replace(c, link=replace(c.link, query=replace(query, purpose=Purpose.ALIVE)))
    return complete(c, t, out)


def _hold(c: Core, t: float, out: Out) -> Core:
    """The watchdog: the stream of the running set-point has gone quiet mid-move (its source
    stopped, or lost its link): the arm is held where it is, as a cancelled move is halted
    (no lock: the next set-point moves it again)."""
    run = c.run
    assert run is not None
    reason = f"{went_quiet(c, run.job.stream)}: the arm is held where it is"
    say(out, logging.WARNING, f"watchdog: {run.job.instr.name} [{run.job.instr.id}]: {reason}")
    return end_run(c, reason, t, out)


def unwritten(c: Core, t: float) -> bool:
    """Nothing of the current run has gone out, and the arm is still (no motion, no joint
    on its way): its end writes nothing (`end_run`)."""
    run, book = c.run, c.book
    if run is None:
        return False
    return (
        run.k == 0
        and run.written is None
        and not run.line
        and book.motion is None
        and all(book.way(joint, t) is None for joint in book.ways)
    )


def end_run(
    c: Core,
    reason: str,
    t: float,
    out: Out,
    result: Result = Result.CANCELLED,
    *,
    halted: str = "",
    warn: bool = False,
) -> Core:
    """The current run ends (cancelled, or refused as it was to be written: `reason`), the
    arm halted where it is on the wire's pace (no lock); the next may start once the pose
    is read back. A run that wrote nothing, the arm still, ends with nothing written, its
    outcome's reason followed by `NOT_RUN` (else by `halted`); `warn`: the log says so."""
    run = c.run
    assert run is not None
    still = unwritten(c, t)
    if warn:
        said = f"{reason}{NOT_RUN if still else ': halted'}"
        say(out, logging.WARNING, f"{run.job.instr.name} [{run.job.instr.id}]: {said}")
    reason += NOT_RUN if still else halted
    # Nothing to halt, nor to read back, when still: the next may start at once (a preempting
    # goal waited for a STOP and the pose's read-back after a trajectory that waited for its
    # start and had written nothing).
    c = replace(c, run=None)
    c = c if still else halt(c, t, out, urgent=False)
    finish(run.job, result, reason, t, out)
    if c.state is State.MOVING and run.job.mode is Mode.QUEUE:
        c = fire(c, Event.MOVE_DONE, out)
    posed(c, out)
    return c
