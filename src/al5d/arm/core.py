"""The arm's protocol: the one owner of the driver's state, and every event that changes it.

Threads
-------
Callers (a ROS executor, the command line, a Python program) submit, stop,
release, cancel and shut down. One worker thread (`worker.Worker`) parks, runs
the moves that wait, watches the link, reads the pose back and reconnects. None
of them owns a field of the arm's state: `Core` does. Each public method of it
is one event, handled whole under one lock: it asks the state table
(`states.TABLE`) for the next state, updates the fields, and returns what its
caller must do outside the lock (write a STOP, write a step, hand out outcomes).
The lock is never held during serial I/O, and nothing outside this module
writes a field of it. The fields and the small steps the events share are in
`corestate`; what the events hand back, in `effects`; the sending times the order
across channels is judged by, in `order`. The decisions are all here.

The lanes
---------
- **The stop** is taken first, whoever is doing what. `stop` ends the epoch
  (every job of an older epoch is dropped and never written), locks the arm and
  returns the STOP to write; its caller writes it at once, with no hand-over to
  the worker: it waits only for this lock and for the board's write lock, each
  held for microseconds. A step is written only if its job's epoch still holds
  when the step has the board's write lock (`SSC32U.write_command`'s `unless`,
  which reads `epoch` without this lock). So either a step goes out before the
  STOP, which halts it, or it does not go out at all.
- **Moves** are admitted (`admit`) in the order they come. An idle arm's move
  is written at once by its caller (the fast path: no thread hand-over), which
  then hands the job to the worker to see it through (`first_written`). Others
  wait in the queue; the worker takes them one at a time (`next_task`), and a
  job is the current one from the moment it is taken until it ends. Only the
  current job's steps are written; whoever ends it (done, stop, cancel, fault,
  shutdown) makes it not current, in one event.
- **Set-points** (a stream such as ros2_control's joint commands, or the web
  view's jog) are moves whose latest wins: a new one replaces the one of its
  stream that waits (it ends cancelled, never written), and one where the arm
  is heading already (within half a pulse microsecond) is done at once with
  nothing written. One that finds the arm idle is written at once, like any
  move. One that comes while a set-point of its stream runs, and nothing waits,
  supersedes it (`_supersede`): in the same event the running one is cancelled
  (none of its bytes still to go is written: its `cancel` is checked under the
  write lock) and the new one becomes the current job, for the worker to write
  (`Runner.NEXT`) once no caller's write is under way, so that what the
  superseded one wrote is in the pose before the new one is planned from it.
  The worker writes it when the wire is free (until then a newer one may still
  take its place) and the board retargets mid-move. A set-point is done when
  its time is over, without `Q`. The watchdog (`watchdog`, run by the worker
  while a set-point's time runs): when no set-point of its stream has come for
  `server.stream_timeout_s`, the arm is halted where it is as a cancelled move
  is (no lock). A stop, a fault or a shutdown holds the streams: their
  set-points are refused until one comes that is where the arm is (its source
  has let go of the target it had before), so a target sent again and again is
  not driven to after a release.
- **The worker's own work** (`next_task`, in this order): the shutdown, the
  recovery from a fault, the start-up park, a job the caller wrote, the
  read-back of the pose after a halt, the next queued move, and a check of
  the idle link. While a caller writes (a fast-path step, a STOP), the worker
  waits for it: what comes next depends on what the write did.

The order across channels
-------------------------
Stops, releases and moves come by several channels (the instruction topic, in
order behind a flood; the services; the stop watcher; actions; Python calls),
so a message can arrive after one sent later. Each instruction carries when it
was sent (`Instruction.sent_ns`: a DDS message's source timestamp, on this
host's CLOCK_REALTIME; when the driver took it, where the channel does not
say). The order of sending, not of arriving, decides:

1. A release unlocks only if it was sent after every stop that holds the lock;
   an older one is refused with a reason naming that stop. So a stop is never
   undone by a release sent before it, whatever the channels.
2. A move sent before the last event that dropped every pending move (a stop,
   a fault, the shutdown) is cancelled by that event, as it would have been had
   it waited in the queue; a move sent between a stop and the release that
   unlocked the arm is refused, as it would have been had it arrived then.
3. A stop that two readers of one topic both see (the node, in order; the stop
   watcher, at once) is one stop: it is known by its message's identity
   (`key`), obeyed once and answered once.

A fault, a board's reset and the shutdown are the driver's own events: they
count as sent when the driver takes them. Clients on other machines are judged
on their own clocks (the server is closed to the network by default).
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from concurrent.futures import Future

from al5d.arm.corestate import CoreState, Runner
from al5d.arm.effects import Admission, Ended, Halt, Verdict, Work
from al5d.arm.instruction import Outcome
from al5d.arm.jobs import Job, Mode, Motion, Written
from al5d.arm.states import (
    Event,
    State,
    Task,
    next_state,
    refusal,
    release_refusal,
    stream_held,
)
from al5d.clock import Deadline, now, wall_ns
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import BoardReset, SerialFault


class Core(CoreState):
    """One arm's protocol: every event that changes its state (the fields and the steps the
    events are made of: `corestate.CoreState`)."""

    # -- callers' events ----------------------------------------------------------------

    def admit(self, job: Job) -> Admission:
        """A validated move comes: it is cancelled, refused, queued, or written now. A
        set-point of a stream (`Job.stream`) replaces the one of its stream that waits, and
        is not written at all where the arm is heading already (the lane of set-points)."""
        with self._lock:
            cancelled = self._order.cancelled(job.sent_ns)
            if cancelled:
                return Admission(Verdict.CANCELLED, cancelled)
            reason = (
                "the server is shutting down"
                if self._shutdown is not None
                else refusal(self._state, self._fault)
            ) or self._order.sent_while_locked(job.sent_ns)
            if reason:
                return Admission(Verdict.REFUSED, reason)
            replaced = None
            if job.stream:
                self._stream_seen[job.stream] = now()
                unchanged = self._unchanged(job)
                if self._streams_held:
                    if not unchanged:
                        return Admission(Verdict.REFUSED, stream_held(self._streams_held))
                    self._streams_held = ""  # the source holds where the arm is: it resumes
                # The latest set-point wins: one that waits is replaced, never queued behind.
                replaced = next((j for j in self._queue if j.stream == job.stream), None)
                if replaced is not None:
                    self._queue.remove(replaced)
                if unchanged:
                    if self._current is None and not self._queue and self._state is State.MOVING:
                        self._fire(Event.MOVE_DONE)
                    return Admission(Verdict.UNCHANGED, replaced=replaced)
            job.epoch = self._epoch
            superseded = self._supersede(job)
            if superseded is not None:
                return Admission(Verdict.SUPERSEDES, replaced=replaced, superseded=superseded)
            if self._idle():
                self._current, self._runner = job, Runner.CALLER
                self._writes += 1
                self._writing += 1
                self._fire(Event.MOVE)
                return Admission(Verdict.WRITE, board=self._board, replaced=replaced)
            if len(self._queue) >= self._capacity:
                return Admission(
                    Verdict.REFUSED,
                    f"the queue is full ({self._capacity} moves wait)",
                    replaced=replaced,
                )
            self._queue.append(job)
            if self._state is State.READY:
                self._fire(Event.MOVE)
            if len(self._queue) == 1:  # the worker may wait for one; it takes the rest in turn
                self._cv.notify_all()
            return Admission(Verdict.QUEUED, replaced=replaced)

    def first_written(
        self, job: Job, written: Written | None, error: SerialFault | None = None
    ) -> tuple[Motion | None, Ended]:
        """The caller has written (or not) the first step of the job `admit` gave it: the
        worker sees it through from here. The motion on the board, and what ended: a
        fault's jobs, or this one, withheld for a stop another process wrote."""
        with self._cv:
            self._writing -= 1
            self._cv.notify_all()
            if error is not None:
                return None, self._lose(error)
            motion = self._written(job, written) if written is not None else None
            if job is self._current:
                if motion is not None:
                    self._runner = Runner.HANDED
                elif self._end_current(job) and written is None:
                    # Nothing of it went out and nothing here ended it: the write was
                    # withheld for a STOP the stop process wrote, which this server has not
                    # obeyed yet; that stop would cancel it, so it ends so (its outcome is
                    # the caller's to set, as an event's).
                    return None, Ended((job,), "cancelled by stop")
            return motion, Ended()

    def stop(
        self, future: Future[Outcome], sent_ns: int, key: Hashable | None = None
    ) -> Halt | Future[Outcome]:
        """The emergency stop (sent at `sent_ns`): drop everything, lock, and the STOP to write
        at once. A stop already obeyed under the same `key` is not obeyed again: its future
        comes back."""
        with self._lock:
            known = self._order.obeyed(key, future) if key is not None else None
            if known is not None:
                return known
            ended = self._drop("cancelled by stop", sent_ns)
            self._lock_arm("the stop", sent_ns)
            halt = self._halt(ended)
            self._fire(Event.STOP)
            return halt

    def halt_written(self, error: SerialFault | None) -> Ended:
        """A STOP (a stop's or a cancel's) has been written, or could not be: a fault then."""
        with self._cv:
            self._writing -= 1
            self._cv.notify_all()
            if error is None or self._board is None:
                return Ended()
            return self._lose(error)

    def release(self, sent_ns: int) -> str:
        """Unlock (a release sent at `sent_ns`); the reason it cannot, or ""."""
        with self._lock:
            state = self._state
            if next_state(state, Event.RELEASE, self._guards()) is None:
                return release_refusal(state)
            too_old = self._order.release_too_old(sent_ns)
            if too_old:
                return too_old
            self._fire(Event.RELEASE)
            self._locked = False
            self._order.released(sent_ns)
            return ""

    def cancel(self, ident: str) -> Job | Halt | None:
        """Cancel one move: a waiting one is dropped (it comes back); a running one is halted
        where it is, without the lock (its STOP comes back). None if it is not here."""
        with self._lock:
            job = next((j for j in self._queue if j.instr.id == ident), None)
            if job is not None:
                self._queue.remove(job)
                if self._current is None and not self._queue and self._state is State.MOVING:
                    self._fire(Event.MOVE_DONE)
                return job
            job = self._current
            if job is None or job.instr.id != ident or job.mode is not Mode.QUEUE:
                return None
            job.cancel.set()
            halt = self._halt(Ended((job,)), urgent=False)
            self._end_current(job)
            return halt

    def shutdown(self, job: Job) -> Ended | None:
        """Park and end: everything pending ends; None if a shutdown is under way already."""
        with self._lock:
            if self._shutdown is not None:
                return None
            ended = self._drop("cancelled by shutdown", job.sent_ns)
            job.epoch = self._epoch
            self._shutdown = job
            self._fire(Event.SHUTDOWN)
            return ended

    # -- the worker's events ------------------------------------------------------------

    def next_task(self, watch_every: float) -> Work:
        """The worker's next task (waits for one), in the order of the module's docstring;
        WATCH when the arm has been idle on a board for `watch_every` seconds."""
        idle = Deadline(watch_every)
        with self._cv:
            while True:
                work = self._choose(idle.expired)
                if work is not None:
                    return work
                if idle.expired:
                    idle = Deadline(watch_every)
                self._cv.wait(idle.left())

    def _choose(self, idle: bool) -> Work | None:
        if self._shutdown is not None and not self._shutdown_taken:
            self._shutdown_taken = True
            return Work(Task.SHUTDOWN, self._shutdown)
        if self._state is State.FAULT:
            return Work(Task.RECOVER)
        if self._writing:
            return None  # a caller writes: what it did decides what comes next
        if self._current is not None:
            if self._runner is Runner.NEXT:  # a set-point that took a running one's place
                self._runner = Runner.WORKER
                return Work(Task.MOVE, self._current)
            if self._runner is not Runner.HANDED:
                return None
            self._runner = Runner.WORKER
            return Work(Task.FOLLOW, self._current)
        if self._state is State.INITIALIZING and not self._parked:
            return Work(Task.STARTUP)
        if self._readback:
            return Work(Task.READBACK)
        if self._queue and self._state is not State.INITIALIZING:
            job = self._queue.popleft()
            self._current, self._runner = job, Runner.WORKER
            return Work(Task.MOVE, job)
        if idle and self._board is not None:
            return Work(Task.WATCH)
        return None

    def start(self, job: Job) -> SSC32U | None:
        """The worker's own park (at start-up or shutdown) becomes the current job: the
        board to run it on, or None if an event since it was made has ended it."""
        with self._lock:
            board = self._board
            if job.epoch != self._epoch or job.cancel.is_set() or board is None:
                return None
            if self._state not in job.mode.states or self._current is not None:
                return None
            self._current, self._runner = job, Runner.WORKER
            return board

    def watchdog(self, job: Job, timeout: float, reason: str) -> Halt | None:
        """No set-point of the running job's stream has come for `timeout` s: the arm is held
        where it is, as a cancelled move is (its STOP comes back; no lock), and the job ends
        with `reason`. None if it has ended, or a set-point came meanwhile."""
        with self._lock:
            if not job.stream or not self._holds(job) or self._quiet(job) < timeout:
                return None
            job.cancel.set()
            halt = self._halt(Ended((job,), reason), urgent=False)
            self._end_current(job)
            return halt

    def board_for(self, job: Job) -> SSC32U | None:
        """The board to write the job's next step on; None if the job has been ended."""
        with self._lock:
            return self._board if self._holds(job) else None

    def step_written(self, job: Job, written: Written) -> Motion | None:
        """A step's bytes went out: the motion on the board, or None if the job was ended
        meanwhile (then a STOP came after the bytes and halted them)."""
        with self._lock:
            return self._written(job, written)

    def reached(self, job: Job, target: Mapping[str, float]) -> bool:
        """A step's time is over (and, for the last, `Q` said done); False if ended meanwhile."""
        with self._lock:
            if job is not self._current or job.epoch != self._epoch:
                return False
            self._book.reached(target)
            return True

    def done(self, job: Job) -> bool:
        """The job has completed (its outcome is DONE); False if it was ended meanwhile."""
        with self._lock:
            if not self._holds(job):
                return False
            self._book.at_rest()
            return self._end_current(job, completed=True)

    def let_go(self, job: Job) -> bool:
        """The job ends without completing (refused at its start, or its runner found it
        ended): no longer current. True if it still was (its outcome is then the caller's)."""
        with self._lock:
            return self._end_current(job)

    def lose(self, error: SerialFault) -> Ended:
        """A serial fault, seen by any thread: everything pending ends; the board is let go
        (the caller closes it). Nothing more if the fault is known already."""
        with self._lock:
            if self._state is State.FAULT and self._board is None:
                if isinstance(error, BoardReset) and not isinstance(self._fault, BoardReset):
                    self._fault = error
                return Ended()
            return self._lose(error)

    def connected(self, board: SSC32U) -> None:
        with self._lock:
            self._board = board

    def unreachable(self, error: SerialFault) -> None:
        """The board could not be reached (at start, or a device that is not a board at a
        reconnect): the fault's reason, and the state `fault`."""
        with self._lock:
            self._fault = error
            if self._state is not State.FAULT:
                self._fire(Event.SERIAL_FAULT)

    def reconnected(self, board: SSC32U, pose: Mapping[str, float | None], reset: bool) -> None:
        """The board is back, its pose read; `reset`: it restarted while the link was down."""
        with self._lock:
            if reset:
                self._lock_arm("the board's reset", wall_ns())
                self._book.forget()
            self._book.read_back(pose)
            self._board = board
            self._fault = None
            self._readback = False
            if self._state is State.FAULT:  # not if a shutdown came meanwhile: it parks now
                self._fire(Event.RECONNECTED)

    def read_back(self, pose: Mapping[str, float | None], token: int | None) -> bool:
        """The pose read from the board, `token` taken by `write_token` before the read: it
        stands only if no caller's write was under way then or began since (else read again)."""
        with self._cv:
            if not self._untouched(token):
                return False
            self._book.read_back(pose)
            if self._current is None:
                self._readback = False
            self._cv.notify_all()
            return True

    def wait_unless_shutdown(self, timeout: float) -> bool:
        """Sleep `timeout` (a reconnect's interval); False if a shutdown came."""
        with self._cv:
            if self._shutdown is None:
                self._cv.wait(timeout)
            return self._shutdown is None

    def worker_failed(self, error: SerialFault) -> Ended:
        """The worker has died of a bug: everything pending ends (the shutdown too), so that
        nothing waits for an outcome that would never come."""
        with self._lock:
            ended = self._lose(error)
            shutdown = self._shutdown
            if shutdown is not None and shutdown not in ended.jobs:
                ended = Ended((*ended.jobs, shutdown), ended.reason, ended.board)
            return ended

    def worker_ended(self) -> None:
        self.finished.set()
        with self._cv:
            self._cv.notify_all()
