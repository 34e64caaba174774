"""What a client knows of the arm (`al5d.ros.reading.ArmView`): its waits."""

from __future__ import annotations

import threading

from al5d.arm.config import ArmConfig
from al5d.ros.reading import ArmView, Reading


def test_a_wait_sees_a_state_that_came_and_went_before_its_thread_ran(config: ArmConfig) -> None:
    """Waiting for `stopped`, the view hears it and then `ready` back to back (a stop and
    another client's release; a reset's fault, then locked) before the waiting thread runs
    again: the wait ends with the stopped reading, not at its timeout. (It looked only at
    the reading of the moment.)"""
    view = ArmView(config.model)
    view.heard("ready", False)
    looked = threading.Event()
    got: list[Reading | None] = []

    def stopped(r: Reading) -> bool:
        looked.set()  # called with the view's lock held, which the wait then lets go
        return r.state == "stopped"

    waiter = threading.Thread(target=lambda: got.append(view.wait(stopped, 30)))
    waiter.start()
    assert looked.wait(30)
    with view._cv:  # the waiter waits now; it runs again once both are heard
        view.heard("stopped", True)
        view.heard("ready", False)
    waiter.join(30)
    assert len(got) == 1 and got[0] is not None, got
    assert (got[0].state, got[0].locked) == ("stopped", True)
    assert view.reading.state == "ready"
    # A state heard before the wait began is not one it waits for.
    assert view.wait(lambda r: r.state == "stopped", 0.1) is None
