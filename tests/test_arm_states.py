"""The state machine as a table: every transition, every guard, every refusal, without a board."""

from __future__ import annotations

import pytest

from al5d.arm.states import (
    LOCKED_BY_RESET,
    MOVE_REFUSALS,
    TABLE,
    TAKES_MOVES,
    TRANSITIONS,
    Event,
    Guards,
    State,
    next_state,
    refusal,
)

S, E = State, Event
ALIVE = (S.INITIALIZING, S.READY, S.MOVING, S.STOPPED, S.FAULT)


def test_the_table_holds_the_design_transitions_and_no_others() -> None:
    # D6 plus the fault state, as the design document draws it (and as the driver did before
    # the table chose the states): the same set, transition for transition.
    d6 = {
        (S.INITIALIZING, E.MOVE_DONE, S.READY),
        # The start-up park is done with moves waiting that came meanwhile: `moving` is the
        # state while moves run or wait (D6).
        (S.INITIALIZING, E.MOVE_DONE, S.MOVING),
        (S.READY, E.MOVE, S.MOVING),
        (S.MOVING, E.MOVE, S.MOVING),
        (S.MOVING, E.MOVE_DONE, S.MOVING),
        (S.MOVING, E.MOVE_DONE, S.READY),
        (S.READY, E.STOP, S.STOPPED),
        (S.MOVING, E.STOP, S.STOPPED),
        (S.INITIALIZING, E.STOP, S.STOPPED),
        (S.STOPPED, E.STOP, S.STOPPED),
        (S.STOPPED, E.RELEASE, S.READY),
        (S.FAULT, E.STOP, S.FAULT),
        (S.FAULT, E.RELEASE, S.FAULT),
        (S.SHUTTING_DOWN, E.STOP, S.SHUTTING_DOWN),
        (S.FAULT, E.RECONNECTED, S.READY),
        (S.FAULT, E.RECONNECTED, S.STOPPED),
        # A server that started without its board parks once it is there, before ready.
        (S.FAULT, E.RECONNECTED, S.INITIALIZING),
        # A shutdown whose park fails shows the fault (it was SHUTTING_DOWN, silently).
        (S.SHUTTING_DOWN, E.SERIAL_FAULT, S.FAULT),
        *((s, E.SHUTDOWN, S.SHUTTING_DOWN) for s in ALIVE),
        *((s, E.SERIAL_FAULT, S.FAULT) for s in ALIVE if s is not S.FAULT),
    }
    assert d6 == TRANSITIONS


@pytest.mark.parametrize(("queue_empty", "expected"), [(True, S.READY), (False, S.MOVING)])
def test_a_move_ends_in_ready_only_when_the_move_list_is_empty(
    queue_empty: bool, expected: State
) -> None:
    assert next_state(S.MOVING, E.MOVE_DONE, Guards(queue_empty=queue_empty)) is expected


@pytest.mark.parametrize(
    ("locked", "parked", "expected"),
    [
        (True, True, S.STOPPED),
        (True, False, S.STOPPED),
        (False, True, S.READY),
        (False, False, S.INITIALIZING),
    ],
)
def test_a_reconnect_keeps_the_lock_and_parks_a_board_never_parked(
    locked: bool, parked: bool, expected: State
) -> None:
    assert next_state(S.FAULT, E.RECONNECTED, Guards(locked=locked, parked=parked)) is expected


def test_release_during_a_fault_only_takes_a_lock_off() -> None:
    assert next_state(S.FAULT, E.RELEASE, Guards(locked=True)) is S.FAULT
    assert next_state(S.FAULT, E.RELEASE, Guards(locked=False)) is None


@pytest.mark.parametrize("state", list(State))
def test_a_stop_is_taken_in_every_state(state: State) -> None:
    assert next_state(state, E.STOP) is not None


@pytest.mark.parametrize("state", ALIVE)
def test_shutdown_and_a_serial_fault_are_taken_in_every_live_state(state: State) -> None:
    assert next_state(state, E.SHUTDOWN) is S.SHUTTING_DOWN
    assert next_state(S.SHUTTING_DOWN, E.SERIAL_FAULT) is S.FAULT


@pytest.mark.parametrize(
    ("state", "event"),
    [
        (S.READY, E.RELEASE),
        (S.MOVING, E.RELEASE),
        (S.STOPPED, E.MOVE),
        (S.SHUTTING_DOWN, E.SHUTDOWN),
        (S.SHUTTING_DOWN, E.RELEASE),
        (S.READY, E.MOVE_DONE),
        (S.READY, E.RECONNECTED),
    ],
)
def test_events_a_state_does_not_take(state: State, event: Event) -> None:
    assert (state, event) not in TABLE
    assert next_state(state, event, Guards(queue_empty=False, locked=True)) is None


def test_a_move_is_refused_with_a_reason_in_exactly_the_states_that_do_not_take_moves() -> None:
    for state in State:
        assert (refusal(state) == "") == (state in TAKES_MOVES)
    assert refusal(S.STOPPED) == "the arm is stopped (emergency stop): send release first"
    assert (
        refusal(S.STOPPED, locked_by=LOCKED_BY_RESET)
        == "the arm is stopped (the board has reset): send release first"
    )
    assert (
        refusal(S.FAULT, "/dev/x: gone") == "the serial link is lost (/dev/x: gone); reconnecting"
    )
    assert set(MOVE_REFUSALS) | set(TAKES_MOVES) == set(State)
