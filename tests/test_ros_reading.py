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


def test_a_state_heard_without_joints_carries_the_live_joints(config: ArmConfig) -> None:
    """Over the lane the joints are estimated along the move the owner told (`live`). The
    end of a move is told as the state first, its pose after: the `ready` reading, as a
    wait for it and a listener have it, had the joints the move began with (an outside
    try: base 20 after a move to -20)."""
    here = {"base": 20.0}
    view = ArmView(config.model, live=lambda: dict(here))
    view.heard("moving", False, {"base": 20.0})
    heard: list[Reading] = []
    view.on_change(heard.append)
    here["base"] = -20.0  # where the move told has brought it
    view.heard("ready", False)
    ready = view.wait(lambda r: r.state == "ready", 1)
    assert ready is not None and ready.joints["base"] == -20.0, ready
    assert [(r.state, r.joints["base"]) for r in heard] == [("ready", -20.0)]
    # Without `live` (over ROS 2 the joints come on their own topic), the last told.
    told = ArmView(config.model)
    told.heard("moving", False, {"base": 20.0})
    told.heard("ready", False)
    assert told.reading.joints["base"] == 20.0
