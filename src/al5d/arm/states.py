"""The arm's state machine as data: which state each event leads to, and why a move is refused.

D6 of the design document plus the fault state. `TABLE` maps (state, event)
to the next state, or to a rule that chooses it from `Guards` (the few facts
a choice depends on). An event that is not in the table is not allowed in
that state: the caller refuses it (`refusal`) or it is a bug (`TransitionError`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum


class State(Enum):
    INITIALIZING = "initializing"
    READY = "ready"
    MOVING = "moving"
    STOPPED = "stopped"
    SHUTTING_DOWN = "shutting_down"
    FAULT = "fault"


class Event(Enum):
    START = "start"
    MOVE = "move"
    MOVE_DONE = "move_done"
    STOP = "stop"
    RELEASE = "release"
    SHUTDOWN = "shutdown"
    REFUSED = "refused"
    SERIAL_FAULT = "serial_fault"
    RECONNECTED = "reconnected"


@dataclass(frozen=True, slots=True)
class Guards:
    """The facts a transition may depend on."""

    queue_empty: bool = True  # no move runs or waits (besides the one that ends)
    locked: bool = False  # an emergency stop has not been released
    parked: bool = True  # the start-up park has been done (D1, VE03)


def more_moves_or_ready(g: Guards) -> State:
    """A move ended: `moving` while the move list is not empty, then `ready` (D6)."""
    return State.READY if g.queue_empty else State.MOVING


def locked_or_ready(g: Guards) -> State:
    """The board is back: still `stopped` if a stop came during the fault; `initializing`
    if the start-up park has yet to be done (a server that started without its board)."""
    if g.locked:
        return State.STOPPED
    return State.READY if g.parked else State.INITIALIZING


def unlock_only_if_locked(g: Guards) -> State | None:
    """A release during a fault only takes the lock off; without a lock there is nothing to do."""
    return State.FAULT if g.locked else None


S, E = State, Event
Rule = State | Callable[[Guards], State | None]
_ALIVE = (S.INITIALIZING, S.READY, S.MOVING, S.STOPPED, S.FAULT)

#: The protocol state machine (D6), plus the fault state. Nothing else may happen.
TABLE: dict[tuple[State, Event], Rule] = {
    # The start-up park is done: moves that came meanwhile wait.
    (S.INITIALIZING, E.MOVE_DONE): more_moves_or_ready,
    (S.READY, E.MOVE): S.MOVING,
    (S.MOVING, E.MOVE): S.MOVING,
    (S.MOVING, E.MOVE_DONE): more_moves_or_ready,
    # A stop always works: while parking at start and at shutdown too.
    (S.INITIALIZING, E.STOP): S.STOPPED,
    (S.READY, E.STOP): S.STOPPED,
    (S.MOVING, E.STOP): S.STOPPED,
    (S.STOPPED, E.STOP): S.STOPPED,
    (S.FAULT, E.STOP): S.FAULT,  # locks; the arm stays locked after reconnecting
    (S.SHUTTING_DOWN, E.STOP): S.SHUTTING_DOWN,
    (S.STOPPED, E.RELEASE): S.READY,
    (S.FAULT, E.RELEASE): unlock_only_if_locked,
    (S.FAULT, E.RECONNECTED): locked_or_ready,
    # The shutdown ends all the same, but the state says the arm could not be parked.
    (S.SHUTTING_DOWN, E.SERIAL_FAULT): S.FAULT,
    **{(s, E.SHUTDOWN): S.SHUTTING_DOWN for s in _ALIVE},
    **{(s, E.SERIAL_FAULT): S.FAULT for s in _ALIVE if s is not S.FAULT},
}


class TransitionError(RuntimeError):
    """A transition the state machine does not have: a bug, never a user error."""


def next_state(state: State, event: Event, guards: Guards = Guards()) -> State | None:
    """The state `event` leads to from `state`, or None where the event is not allowed."""
    rule = TABLE.get((state, event))
    if rule is None or isinstance(rule, State):
        return rule
    return rule(guards)


def _outcomes(rule: Rule) -> set[State]:
    if isinstance(rule, State):
        return {rule}
    both = (True, False)
    seen = {
        rule(Guards(queue_empty=q, locked=lock, parked=park))
        for q in both
        for lock in both
        for park in both
    }
    return {s for s in seen if s is not None}


#: Every (state, event, next state) the table can produce: for checks of logs and plots.
TRANSITIONS: frozenset[tuple[State, Event, State]] = frozenset(
    (s, e, n) for (s, e), rule in TABLE.items() for n in _outcomes(rule)
)

#: What locks the arm (`al5d.arm.order.Order.locked_by`), and how a refused move says it.
LOCKED_BY_STOP = "the stop"
LOCKED_BY_RESET = "the board's reset"
LOCK_SAID = {LOCKED_BY_STOP: "emergency stop", LOCKED_BY_RESET: "the board has reset"}

#: Why a move (or preset) is refused in a state that does not take moves.
MOVE_REFUSALS: dict[State, str] = {
    S.STOPPED: "the arm is stopped ({locked}): send release first",
    S.FAULT: "the serial link is lost ({fault}); reconnecting",
    S.SHUTTING_DOWN: "the server is shutting down",
}
#: The states in which a move is taken into the queue.
TAKES_MOVES = (S.INITIALIZING, S.READY, S.MOVING)


def refusal(state: State, fault: object = None, locked_by: str = LOCKED_BY_STOP) -> str:
    """Why a move is refused in `state` (empty where moves are taken): with the link's
    `fault`, or what locked the arm (`locked_by`: a stop, or the board's reset)."""
    locked = LOCK_SAID.get(locked_by, LOCK_SAID[LOCKED_BY_STOP])
    return MOVE_REFUSALS.get(state, "").format(fault=fault, locked=locked)


def release_refusal(state: State) -> str:
    return f"the arm is not stopped (state {state.value}): nothing to release"


def stream_held(why: str) -> str:
    """Why a set-point of a stream is refused after a stop, a fault or a shutdown (`why`)."""
    return (
        f"the stream of set-points is held since a stop, fault or shutdown ({why}): a "
        "set-point where the arm is now resumes it (with ros2_control: re-activate the "
        "controllers, or start a new trajectory from where the arm stands)"
    )
