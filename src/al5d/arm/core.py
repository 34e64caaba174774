"""The arm's protocol as one transition: `step(core, input) -> (core, effects)`.

The core is a value (`corestate.Core`, frozen) and `step` a function: no I/O, no
thread, no lock, no clock inside. The owner (`al5d.owner`) is the one thread that
holds the core: it hands it every input (a request, a cancel, the board's bytes, the
port opened or failed, the time passing) with the time it took it, and carries out
the effects in order (bytes to the board, outcomes to their requesters, the state's
changes, log lines). This module holds the rules; `running` (a job as it runs) and
`link` (the board's connection and its queries) hold the steps they are made of.

The lanes
---------
- **The stop** is taken first by the owner, whatever else waits, and here it ends the
  epoch (every job of an older epoch is dropped and none of its bytes still to go is
  written), locks the arm, and puts its STOP (ESC, then every channel, the moving
  joints first) on the wire in the same step: nothing of a move that predates it
  follows it to the board.
- **Moves** are admitted in the order they come: refused, cancelled, queued, or, on an
  idle arm, started at once (its first line in the same step). One job runs at a time
  (`Core.run`); only its steps are written; whoever ends it (done, stop, cancel, fault,
  shutdown) makes it not current, in one step. One whose last line's time was over by
  the board's lag (`running.over`), no `Q` saying it still moves, when a stop, a cancel,
  its client's loss, its sender's giving up, the shutdown or its stream's next set-point
  comes is done: the board ran it to its end while the owner did not look.
  A move whose sender waits for its outcome only so long (`Instruction.wait_ms`, from
  when it was sent) is refused as stale if that has passed when it comes, cancelled if
  it passes while the move waits, and halted where it is (as a cancel does) if it
  passes while the move runs: its sender has given up on it, and what nobody waits for
  does not go on.
- **Set-points** (a stream such as ros2_control's joint commands, or the web view's jog)
  are moves whose latest wins: a new one replaces the one of its stream that waits (it
  ends cancelled, never written), and one where the arm is heading already (within half
  a pulse microsecond) is done at once with nothing written. One that comes while a
  set-point of its stream runs, and nothing waits, supersedes it: the running one is
  cancelled and the new one runs, written when the wire is free, from where the
  superseded one has the arm then. A line of the running one still going out is
  finished first (the new one waits for it, as the newest): no set-point cuts a line,
  else a stream faster than the wire would have each line cut by the next (the board
  retargets a group move mid-move; the superseded move's joints that it does not name
  go along to their target in its line, judged whole with it). A set-point is done when its
  time is over, without `Q`. The watchdog: when no set-point of its stream has come for
  `server.stream_timeout_s` during its time, the arm is held where it is, as a cancelled
  move is (no lock). A stop, a fault or a shutdown holds the streams: their set-points
  are refused until one comes that is where the arm is (its source has let go of the
  target it had before), so a target sent again and again is not driven to after a
  release.
- **The core's own work**, in this order: the waiting moves whose senders have given
  up on them cancelled, the port opened and checked (and after a fault, a move the
  board may still run halted and the pose read back), the shutdown (halt, read back,
  park, end), the current run, the read-back of the pose after a halt, the start-up
  park, the next queued move, and a check of the idle link.

The order across channels
-------------------------
Stops, releases and moves come by several channels (the instruction topic, in order
behind a flood; the services; the stop watcher; actions; the local lane; Python
calls), so a request can arrive after one sent later. Each instruction carries when it
was sent (`Instruction.sent_ns`, CLOCK_REALTIME, this machine's: the ROS side puts a
client's times on it, and a stop's no later than when it came, `al5d.ros.leases`; when the
owner took it, where the channel does not say), and the order of sending, not of arriving, decides:

1. A release unlocks only if it was sent after every stop that holds the lock; an
   older one is refused with a reason naming that stop. So a stop is never undone by a
   release sent before it, whatever the channels.
2. A move sent before the last event that dropped every pending move (a stop, a fault,
   the shutdown) is cancelled by that event, as it would have been had it waited in
   the queue; a move sent between a stop and the release that unlocked the arm is
   refused, as it would have been had it arrived then.
3. A stop that two readers of one topic both see (the bridge's node, in order; the stop
   watcher, at once) is one stop: it is known by its identity (`Ask.key`: its message's,
   or, for a copy `<stop>~<n>` that names its client, its client's and the stop's id,
   which every copy its client sends again shares), obeyed once and answered once; a copy
   (an id of its own) that comes later, even after a release, is that stop: answered,
   not obeyed again. Its lock counts from the earlier of the two readers' times for it
   (each measures its client's clock on its own: `Order.seen_earlier`).

A fault, a board's reset and the shutdown are the owner's own events: they count as
sent when the owner takes them.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

from al5d.arm import link as board
from al5d.arm import running
from al5d.arm.corestate import (
    Ask,
    Cancel,
    Cancelled,
    Close,
    Core,
    Effect,
    Failed,
    Gone,
    Input,
    Next,
    Open,
    Opened,
    Out,
    Received,
    Reply,
    Resolve,
    Run,
    Send,
    Tick,
    cancel_all,
    drop,
    end_shutdown,
    finish,
    fire,
    guards,
    halt,
    lock_arm,
    lose,
    posed,
    say,
)
from al5d.arm.instruction import (
    FRESH_MARK,
    NOT_RUN,
    Instruction,
    Kind,
    Result,
    beyond_its_word,
    start_too_far,
)
from al5d.arm.jobs import NO_JOBS, Job, Mode, outcome
from al5d.arm.states import (
    LOCKED_BY_STOP,
    Event,
    State,
    next_state,
    refusal,
    release_refusal,
    stream_held,
)
from al5d.arm.validate import Step, from_start, judge


def step(c: Core, ev: Input) -> tuple[Core, tuple[Effect, ...]]:
    """The core after `ev`, and what is to be done, in order."""
    out: Out = []
    if isinstance(ev, Ask):
        c = _ask(c, ev, out)
    elif isinstance(ev, Tick):
        if ev.stalled != c.link.stalled:
            c = replace(c, link=replace(c.link, stalled=ev.stalled))
    elif isinstance(ev, Received):
        c = board.received(c, ev, out)
    elif isinstance(ev, Cancel):
        c = _cancel(c, ev, out)
    elif isinstance(ev, Opened):
        c = board.opened(c, ev, out)
    elif isinstance(ev, Failed):
        if c.link.open:
            c = lose(c, ev.error, ev.t, ev.wall, out)
    elif isinstance(ev, Gone):
        c = _gone(c, ev, out)
    c = _advance(c, ev.t, ev.wall, out)
    if ev.t > c.t:
        c = replace(c, t=ev.t)
    # The board's effects first, in their order: what is told of a step (its state, its
    # motion, its log lines) must not hold its bytes (a state's news woke the teller
    # thread, which took the interpreter before the write). The outcomes and answers last:
    # a client told that its move is done finds the state that follows it (ready) already
    # said, as it would expect.
    wire = tuple(e for e in out if isinstance(e, Send | Open | Close))
    told = tuple(e for e in out if isinstance(e, Resolve | Cancelled | Reply))
    news = tuple(
        e for e in out if not isinstance(e, Send | Open | Close | Resolve | Cancelled | Reply)
    )
    return c, wire + news + told


# -- requests ---------------------------------------------------------------------------


def _ask(c: Core, ev: Ask, out: Out) -> Core:
    kind = ev.instr.kind
    if kind is Kind.STOP:
        return _stop(c, ev, out)
    ambiguous = beyond_its_word(ev.instr)
    if ambiguous:
        _refuse(ev, ambiguous, out)
        return c
    if kind is Kind.RELEASE:
        return _release(c, ev, out)
    if kind is Kind.SHUTDOWN:
        return _shutdown(c, ev, out)
    return _admit(c, ev, out)


def _sent(ev: Ask) -> int:
    """When the request was sent: where its channel does not say, when the owner took it."""
    sent = ev.instr.sent_ns
    return sent if sent is not None else ev.wall


def _refuse(ev: Ask, reason: str, out: Out, result: Result = Result.REFUSED) -> None:
    out.append(Resolve(ev.ref, outcome(ev.instr, result, reason, ev.t, ev.t), ev.tell))


def _stop(c: Core, ev: Ask, out: Out) -> Core:
    """VE01/D4: halt at once, drop everything, lock. A stop obeyed already under the same
    key is answered as it was, and nobody else hears of it again; a copy of it (the same
    key, an id of its own) is answered so under its id, and told: it asked too."""
    if ev.key is not None:
        known = c.order.stops.get(ev.key)
        if known is not None:
            answer = replace(known, id=ev.instr.id)
            copy = (ev.key, ev.instr.id)
            if known.id == ev.instr.id:  # the stop, seen by the other reader
                out.append(Resolve(ev.ref, answer, tell=False))
                return replace(c, order=c.order.seen_earlier(ev.key, _sent(ev)))
            if copy in c.order.stops:  # a copy, seen by the other reader
                out.append(Resolve(ev.ref, answer, tell=False))
                return c
            # A copy of its own id: answered under it, and told, once.
            out.append(Resolve(ev.ref, answer, ev.tell))
            return replace(c, order=c.order.obeyed(copy, answer))
    sent = _sent(ev)
    c = running.over(c, ev.t, out)
    c, jobs = drop(c, "cancelled by stop", sent)
    c = lock_arm(c, LOCKED_BY_STOP, sent, ev.key)
    board_open = c.link.open
    c = fire(halt(c, ev.t, out), Event.STOP, out)
    note = (
        ""
        if board_open
        else f"the serial link is lost ({c.fault or 'the board not reached yet'}); the arm "
        "is locked, and STOP is written as soon as the board is reached again"
    )
    done = outcome(ev.instr, Result.DONE, note, ev.t, ev.t)
    out.append(Resolve(ev.ref, done, ev.tell))
    if ev.key is not None:
        c = replace(c, order=c.order.obeyed(ev.key, done))
    cancel_all(jobs, "cancelled by stop", ev.t, out)
    if jobs:
        say(out, logging.INFO, f"stop: {len(jobs)} move(s) cancelled")
    posed(c, out)  # halted where it is: a shutdown's park cut short too
    if c.shutdown is not None and not c.ended:
        return end_shutdown(
            c, "stopped before the arm reached park: the arm is not parked", ev.t, out
        )
    return c


def _release(c: Core, ev: Ask, out: Out) -> Core:
    """Unlock, if the arm is locked and the release was sent after the stop that locked it."""
    sent = _sent(ev)
    if next_state(c.state, Event.RELEASE, guards(c)) is None:
        _refuse(ev, release_refusal(c.state), out)
        return c
    too_old = c.order.release_too_old(sent)
    if too_old:
        _refuse(ev, too_old, out)
        return c
    c = fire(c, Event.RELEASE, out)
    c = replace(c, locked=False, order=c.order.released(sent))
    note = "unlocked; the serial link is still lost" if c.state is State.FAULT else ""
    out.append(Resolve(ev.ref, outcome(ev.instr, Result.DONE, note, ev.t, ev.t), ev.tell))
    return c


def _shutdown(c: Core, ev: Ask, out: Out) -> Core:
    """Park and end (D2): everything pending ends; the move the board may still run is
    halted, the pose read back, then the arm parks."""
    if c.shutdown is not None:
        _refuse(ev, "the server is already shutting down", out)
        return c
    sent = _sent(ev)
    c = running.over(c, ev.t, out)
    # Only a move cut short here may still run on the board: with none, there is nothing
    # to halt (and no way to ask while `Q` counts a stopped move down).
    cut = c.run is not None
    c, jobs = drop(c, "cancelled by shutdown", sent)
    park = (Step(dict(c.arm.config.presets["park"]), None),)
    fraction = c.arm.settings.startup_speed_fraction
    job = Job(ev.ref, ev.instr, park, ev.t, sent, c.epoch, fraction, Mode.SHUTDOWN, tell=ev.tell)
    c = fire(replace(c, shutdown=job), Event.SHUTDOWN, out)
    if c.link.checked:
        c = replace(c, link=replace(c.link, next=Next.SHUTDOWN, halt_checked=not cut))
    cancel_all(jobs, "cancelled by shutdown", ev.t, out)
    return c


def takes_no_moves(c: Core) -> str:
    """Why the arm takes no move now (stopped, faulted, shutting down), or ""."""
    if c.shutdown is not None:
        return "the server is shutting down"
    return refusal(c.state, c.fault, c.order.locked_by)


def _start_at(instr: Instruction, ev: Ask) -> tuple[float, str]:
    """When (the owner's clock) `instr` may be written, from its `start_ns`, and why it is
    refused for it ("")."""
    if instr.start_ns is None or instr.start_ns <= ev.wall:
        return -math.inf, ""
    return ev.t + (instr.start_ns - ev.wall) / 1e9, start_too_far(instr.start_ns, ev.wall)


def _admit(c: Core, ev: Ask, out: Out) -> Core:
    """A motion instruction comes: judged whole (unless its ticket was), then cancelled,
    refused, queued, or started now."""
    instr = ev.instr
    ticket = ev.ticket if ev.ticket is not None else judge(instr, c.arm.limits)
    if isinstance(ticket, str):
        _refuse(ev, ticket, out)
        return c
    sent = _sent(ev)
    cancelled = c.order.cancelled(sent)
    if cancelled:
        _refuse(ev, cancelled, out, Result.CANCELLED)
        return c
    reason = takes_no_moves(c) or c.order.sent_while_locked(sent)
    give_up_at = math.inf
    if instr.wait_ms:
        # Counted from when it was sent: the time on its way is part of the sender's wait.
        give_up_at = ev.t + instr.wait_ms / 1000 - max(0, ev.wall - sent) / 1e9
        if give_up_at <= ev.t:
            reason = f"{given_up(instr)}: stale, not run"
    start_at, late_start = _start_at(instr, ev)
    if start_at >= give_up_at:
        late_start = f"it would start after its sender gives up on it ({instr.wait_ms} ms)"
    reason = reason or late_start
    if reason:
        _refuse(ev, reason, out)
        return c
    job = Job(
        ev.ref,
        instr,
        ticket.steps,
        ev.t,
        sent,
        c.epoch,
        stream=ev.stream,
        client=ev.client,
        tell=ev.tell,
        follow=ticket.follow,
        give_up_at=give_up_at,
        start_at=start_at,
    )
    replaced = None
    if job.stream:
        c = replace(c, stream_seen={**c.stream_seen, job.stream: ev.t})
        unchanged = _unchanged(c, job)
        if c.streams_held:
            if not (unchanged or instr.id.endswith(FRESH_MARK)):
                _refuse(ev, stream_held(c.streams_held), out)
                return c
            # The source holds where the arm is, or says it is new since the stop: it resumes.
            c = replace(c, streams_held="")
        # The latest set-point wins: one that waits is replaced, never queued behind.
        replaced = next((j for j in c.queue if j.stream == job.stream), None)
        if replaced is not None:
            c = replace(c, queue=c.queue.where(lambda j: j is not replaced))
            finish(replaced, Result.CANCELLED, f"replaced by set-point {instr.id}", ev.t, out)
        if unchanged:
            if c.run is None and not c.queue and c.state is State.MOVING:
                c = fire(c, Event.MOVE_DONE, out)
            finish(job, Result.DONE, "at this set-point, or on its way: nothing written", ev.t, out)
            return c
        # A running set-point the board has run to its end while the owner did not look is
        # done, not superseded (`running.over`).
        c = running.over(c, ev.t, out)
        if _supersedes(c, job):
            if c.link.rest and not c.link.rest_is_halt:
                # The running set-point's line is going out. Cutting it would make the
                # board drop it whole, and a stream faster than the wire would never move
                # the arm (each line cut by the next: seen at 50 Hz and 9600 baud). The
                # newest waits for the line and takes its place then (`_next`).
                return _enqueue(c, job)
            return _supersede(c, job, ev.t, out)
    if c.idle:
        # Started before the state is told: one refused as it starts (its path below the
        # table from where the arm is) leaves the arm `ready`, never `moving` for an instant.
        started = running.start(c, job, ev.t, out)
        return started if started.run is None else fire(started, Event.MOVE, out)
    capacity = c.arm.settings.queue_capacity
    if len(c.queue) >= capacity:
        finish(job, Result.REFUSED, f"the queue is full ({capacity} moves wait)", ev.t, out)
        return c
    c = _enqueue(c, job)
    return fire(c, Event.MOVE, out) if c.state is State.READY else c


def _enqueue(c: Core, job: Job) -> Core:
    return replace(c, queue=c.queue.add(job), give_up_at=min(c.give_up_at, job.give_up_at))


def given_up(instr: Instruction) -> str:
    """Why an instruction whose sender no longer waits for it does not go on."""
    return f"its sender waited {instr.wait_ms} ms for an outcome and has given up on it"


def _given_up(c: Core, t: float, out: Out) -> Core:
    """The waiting jobs whose senders have given up on them are cancelled, unrun."""
    gone = [j for j in c.queue if j.give_up_at <= t]
    queue = c.queue.where(lambda j: j.give_up_at > t) if gone else c.queue
    c = replace(c, queue=queue, give_up_at=min((j.give_up_at for j in queue), default=math.inf))
    for job in gone:
        finish(job, Result.CANCELLED, f"{given_up(job.instr)}: not run", t, out)
    if gone and c.run is None and not c.queue and c.state is State.MOVING:
        c = fire(c, Event.MOVE_DONE, out)
    return c


def _heading(c: Core) -> dict[str, float | None] | None:
    """Where the arm rests once the current job is done (the pose at rest when none runs);
    None when that is not known yet: moves wait (a Cartesian one is planned from where the
    arm is when it starts), or the pose is to be read back."""
    if c.queue or c.readback:
        return None
    run = c.run
    if run is None:
        return dict(c.book.pose)
    if run.job.mode is not Mode.QUEUE or not run.steps:
        return None
    return c.book.heading(run.steps[-1].target)


def _unchanged(c: Core, job: Job) -> bool:
    """A one-step job whose target is where the arm is heading already."""
    heading = _heading(c)
    if heading is None or len(job.steps) != 1:
        return False
    for name, deg in job.steps[0].target.items():
        there = heading.get(name)
        if there is None or abs(deg - there) > c.arm.same_deg[name]:
            return False
    return True


def _supersede(c: Core, job: Job, t: float, out: Out) -> Core:
    """The set-point `job` takes the running one's place (`_supersedes`), judged from where
    that one has the arm at `t`; refused where that path would leave the table. Never while
    a line of the running one is going out: no set-point cuts a line."""
    assert c.run is not None and not (c.link.rest and not c.link.rest_is_halt)
    if running.stale_set_point(c, job, t, out):
        return c  # the running one's watchdog holds the arm
    superseded = c.run.job
    # Judged against the table from where the running one has the arm now (again
    # when its bytes go: `running`).
    motion = c.book.motion
    here = {**c.book.pose, **(motion.at(t) if motion is not None else {})}
    if motion is not None and len(job.steps) == 1:
        # The board retargets only the joints a line names: the others still moving
        # would go on to the running move's target at its pace, on a path nobody
        # judged (seen: 15.9 mm under the table). The set-point takes the running
        # move's joints along to that target: one group move, judged whole, whose
        # end is where the arm then rests (the superseded one, cancelled, never
        # says where it took them).
        step = job.steps[0]
        job = replace(job, steps=(replace(step, target={**motion.target, **step.target}),))
    reason = from_start(job.instr, job.steps, here, c.arm.limits)
    if reason:
        finish(job, Result.REFUSED, reason, t, out)
        return c
    c = replace(c, run=Run(job, job.steps, retarget=True))
    why = f"superseded by set-point {job.instr.id}"
    finish(superseded, Result.CANCELLED, why, t, out)
    return c


def _supersedes(c: Core, job: Job) -> bool:
    """A set-point may take the place of the running one of its stream: nothing waits,
    nothing is to be read back, a board is there and the arm moves."""
    run = c.run
    return (
        run is not None
        and run.job.stream == job.stream
        and run.job.mode is Mode.QUEUE
        and not c.queue
        and not c.readback
        and c.link.checked
        and c.state is State.MOVING
    )


def _cancel(c: Core, ev: Cancel, out: Out) -> Core:
    """Cancel one move: a waiting one is dropped; a running one is halted where it is,
    without the lock. Whether it was there is the answer."""
    job = next((j for j in c.queue if j.instr.id == ev.ident), None)
    if job is not None:
        c = replace(c, queue=c.queue.where(lambda j: j is not job))
        if c.run is None and not c.queue and c.state is State.MOVING:
            c = fire(c, Event.MOVE_DONE, out)
        # Said as a goal cancelled before the bridge handed it over is (`NOT_RUN`): one
        # outcome's words whichever side of the owner it waited on.
        finish(job, Result.CANCELLED, f"{ev.reason}{NOT_RUN}", ev.t, out)
        out.append(Reply(ev.ref, True))
        return c
    c = running.over(c, ev.t, out)
    run = c.run
    if run is None or run.job.instr.id != ev.ident or run.job.mode is not Mode.QUEUE:
        out.append(Reply(ev.ref, False))
        return c
    c = running.end_run(c, ev.reason, ev.t, out)
    out.append(Reply(ev.ref, True))
    return c


def _gone(c: Core, ev: Gone, out: Out) -> Core:
    """A client has gone without saying goodbye: what it commanded does not go on (its
    waiting moves are cancelled, its running one is halted where it is)."""
    why = f"lost contact with the client{f' ({ev.why})' if ev.why else ''}"
    c = running.over(c, ev.t, out)  # done before what waited behind it is cancelled
    mine = [j for j in c.queue if j.client == ev.client]
    if mine:
        c = replace(c, queue=c.queue.where(lambda j: j.client != ev.client))
        cancel_all(mine, why, ev.t, out)
        if c.run is None and not c.queue and c.state is State.MOVING:
            c = fire(c, Event.MOVE_DONE, out)
    run = c.run
    if run is not None and run.job.client == ev.client and run.job.mode is Mode.QUEUE:
        c = running.end_run(c, why, ev.t, out, warn=True)
    return c


# -- the core's own work ----------------------------------------------------------------


def _advance(c: Core, t: float, wall: int, out: Out) -> Core:
    """Do what can be done now, in the order of the module's docstring, until nothing more."""
    for _ in range(64):
        after = _next(c, t, wall, out)
        if after is c:
            return c
        c = after
    return c


def _next(c: Core, t: float, wall: int, out: Out) -> Core:
    """One thing that can be done now; the core as it was if none."""
    if c.ended:
        return c
    if t >= c.give_up_at:  # a waiting move needs no board to be cancelled
        return _given_up(c, t, out)
    link = c.link
    if not link.open:
        if link.opening:
            return c
        if c.shutdown is not None:
            why = f"the serial link is lost ({c.fault}): the arm is not parked"
            return end_shutdown(c, why, t, out)
        if t >= link.open_at:
            out.append(Open())
            return replace(c, link=replace(link, opening=True))
        return c
    if link.query is not None and t >= board.due(link.query, link.stalled):
        return board.overdue(c, t, wall, out)
    if link.rest:
        after = running.pieces(c, t, out)
        if after is not c:
            return after
    if not link.checked:
        return c
    if link.next is not None:
        return board.settle(c, t, out)
    if c.state is State.FAULT:
        return c
    if c.run is not None:
        job = c.run.job
        given = t >= job.give_up_at and job.mode is Mode.QUEUE
        # A set-point that waited for the running one's line takes its place once it is out,
        # ahead of what came after it.
        waiting = c.queue.first() if c.queue and not c.link.rest else None
        if waiting is not None and not (
            waiting.stream and _supersedes(replace(c, queue=NO_JOBS), waiting)
        ):
            waiting = None
        if given or waiting is not None:
            # Either ends the run: done instead if the board ran it to its end meanwhile
            # (`running.over`); then what waits starts as any next one does.
            done = running.over(c, t, out)
            if done is not c:
                return done
        if given:
            return running.end_run(c, given_up(job.instr), t, out, halted=": halted", warn=True)
        if waiting is not None:
            return _supersede(replace(c, queue=c.queue.rest()), waiting, t, out)
        return running.progress(c, t, out)
    if c.shutdown is not None:
        if c.shutdown_taken:
            return c
        park = c.shutdown
        return replace(c, shutdown_taken=True, run=Run(park, park.steps))
    if c.readback:
        return board.read_pose(c, t, out) if board.can_ask(c, t) else c
    if c.state is State.INITIALIZING and not c.parked:
        return running.start(c, _startup_park(c, t, wall), t, out)
    if c.queue and c.state is not State.INITIALIZING:
        return running.start(replace(c, queue=c.queue.rest()), c.queue.first(), t, out)
    if t >= link.watched + c.arm.settings.idle_check_interval_s and board.can_ask(c, t):
        return board.watch(c, t, out)
    return c


def _startup_park(c: Core, t: float, wall: int) -> Job:
    """D1, VE03: park once, at half speed where the board allows it, before `ready`."""
    park = (Step(dict(c.arm.config.presets["park"]), None),)
    fraction = c.arm.settings.startup_speed_fraction
    instr = Instruction(Kind.PRESET, preset="park", id="startup")
    return Job(0, instr, park, t, wall, c.epoch, fraction, Mode.STARTUP, tell=False)


def wake_at(c: Core) -> float:
    """When the core wants a `Tick` at the latest, whatever else comes (inf: only an input
    wakes it). An early one is harmless: nothing is due, nothing is done; what is due
    already but waits for something else (the wire, a query's answer) is woken by that.

    It counts from the core's own latest input (`Core.t`), not from when the owner asks: a
    time that fell due between the two (the owner's thread did not run meanwhile) is a
    time already past, which wakes it at once, not a time skipped until the next wake."""
    t = c.t
    if c.ended:
        return math.inf
    link = c.link
    if not link.open:
        return min(math.inf if link.opening else max(link.open_at, t), c.give_up_at)
    times = [link.watched + c.arm.settings.idle_check_interval_s, link.free_at]
    if link.query is not None:
        times.append(board.due(link.query, link.stalled))
    if link.rest:
        times.append(link.free_at - running.WIRE_HORIZON_S)
    times.append(c.give_up_at)
    if c.run is not None:
        times += [*running.wakes(c, c.run), c.run.job.give_up_at]
    return min((x for x in times if x > t), default=math.inf)
