"""The web page's jog rules (`al5d.web.jog`), on a clock of the test's own: when a
set-point is due, sent again, given up, and what the user is told."""

from __future__ import annotations

import itertools

from al5d.web.jog import FOLLOW_AFTER_S, JOG_KEPT_LOST_S, JOG_RESEND_S, QUIET_S, Jog

SPEEDS = {"base": 100.0, "shoulder": 50.0}
ARM = {"base": 0.0, "shoulder": 0.0}


def take(jog: Jog, joint: str, degrees: float, now: float, refused: str = "") -> dict[str, float]:
    """`joint` to `degrees` on the slider, judged as the sliders' thread judges it."""
    target = jog.take(joint, degrees, now)
    assert jog.judge(target, refused)
    return target


def test_a_new_target_is_due_at_once_and_again_while_the_user_is_at_the_slider() -> None:
    jog = Jog(SPEEDS)
    assert jog.due(0.0, False, ARM) == (None, "")
    assert take(jog, "base", 10.0, 0.0) == {"base": 10.0}
    assert take(jog, "shoulder", 5.0, 0.01) == {"base": 10.0, "shoulder": 5.0}
    assert jog.due(0.02, False, ARM) == ({"base": 10.0, "shoulder": 5.0}, "")
    # Still at it: the same set-point again, which keeps the server's watchdog content.
    assert jog.due(0.02 + QUIET_S / 2, False, ARM) == ({"base": 10.0, "shoulder": 5.0}, "")


def test_a_jog_ends_once_let_go_and_the_arm_is_there() -> None:
    jog = Jog(SPEEDS)
    take(jog, "base", 10.0, 0.0)
    assert jog.due(0.0, False, ARM)[0] is not None
    there = {"base": 10.0, "shoulder": 0.0}
    assert jog.due(QUIET_S + 0.1, False, there) == (None, "")
    assert jog.target is None
    assert not jog.quiet(QUIET_S + 0.1)  # the sliders were let go only just now
    assert jog.quiet(FOLLOW_AFTER_S + 0.1)


def test_a_jog_that_arrived_does_not_undo_the_next_move_of_another_client() -> None:
    """Let go and there: another client's move then (the arm moving, then idle elsewhere)
    is not fought: nothing is sent again, neither while it runs nor after it."""
    jog = Jog(SPEEDS)
    take(jog, "base", 10.0, 0.0)
    jog.due(0.0, False, ARM)
    assert jog.due(QUIET_S + 0.1, False, {"base": 10.0, "shoulder": 0.0}) == (None, "")
    elsewhere = {"base": -20.0, "shoulder": 30.0}
    for k, t in enumerate(itertools.count(QUIET_S + 0.2, 0.05)):
        if t > FOLLOW_AFTER_S * 3:
            break
        assert jog.due(t, k < 10, elsewhere) == (None, ""), t


def test_a_moving_arm_keeps_the_jog_alive_for_its_way_and_no_longer() -> None:
    jog = Jog(SPEEDS)
    take(jog, "base", 100.0, 0.0)  # 1 s of way at 100 deg/s
    jog.due(0.0, True, ARM)
    assert jog.due(QUIET_S + 0.1, True, ARM)[0] == {"base": 100.0}
    assert jog.due(1.0 + FOLLOW_AFTER_S + 0.1, True, ARM) == (None, "")  # another's move


def test_a_jog_is_kept_alive_all_its_way_as_the_arm_goes() -> None:
    """A slow way (100 deg at 20 deg/s: 5 s), the arm on it at its speed: the set-point is
    sent at every tick until the arm is there. A window of the way left, measured anew at
    each tick, ended halfway (at 3.25 s): the server's watchdog held the arm short of the
    slider, again and again (a CI run of the browser's jog beside two busy loops)."""
    jog = Jog({"base": 20.0, "shoulder": 50.0})
    take(jog, "base", 100.0, 0.0)
    assert jog.due(0.0, False, ARM)[0] == {"base": 100.0}
    for t in (u / 20 for u in range(int(QUIET_S * 20) + 1, 100)):
        here = {"base": 20.0 * t, "shoulder": 0.0}
        assert jog.due(t, True, here)[0] == {"base": 100.0}, t


def test_slower_speeds_that_come_on_its_way_keep_the_jog_alive_longer() -> None:
    """The server's speeds come (its robot description) while a jog is on its way: it is
    kept alive for its way at them, from where the arm is then."""
    jog = Jog({"base": 100.0, "shoulder": 50.0})
    take(jog, "base", 100.0, 0.0)
    assert jog.due(0.0, False, ARM)[0] == {"base": 100.0}
    jog.new_speeds({"base": 10.0}, 0.5, {"base": 5.0})
    assert jog.speeds == {"base": 10.0, "shoulder": 50.0}
    t = 0.5 + 95 / 10 + FOLLOW_AFTER_S - 0.1  # at 100 deg/s, over at 2.5 s
    assert jog.due(t, True, {"base": 99.0, "shoulder": 0.0})[0] == {"base": 100.0}
    assert jog.due(t + 0.2, True, {"base": 99.0, "shoulder": 0.0}) == (None, "")


def test_a_target_the_server_would_refuse_is_not_sent_and_said_once_let_go() -> None:
    jog = Jog(SPEEDS)
    take(jog, "base", 500.0, 0.0, "base 500 deg is outside its range")
    assert jog.due(0.05, False, ARM) == (None, "")  # while at it: the handler says why
    assert jog.due(QUIET_S + 0.1, False, ARM) == (
        None,
        "not sent: base 500 deg is outside its range",
    )
    assert jog.target is None and jog.refused == ""
    assert jog.quiet(QUIET_S + 0.2)  # the sliders go back to the arm at once


def test_a_jog_stopped_short_is_sent_again_then_given_up() -> None:
    jog = Jog(SPEEDS)
    take(jog, "base", 10.0, 0.0)
    jog.due(0.0, False, ARM)
    # Let go, and the arm idle short of the target (the server's watchdog held it).
    ticks = [u / 100 for u in range(int(QUIET_S * 100) + 1, 400)]
    resent = [t for t in ticks if jog.due(t, False, ARM)[0] is not None]
    assert len(resent) >= 3, resent
    assert all(b - a >= JOG_RESEND_S - 1e-9 for a, b in itertools.pairwise(resent))
    assert resent[-1] <= resent[0] + FOLLOW_AFTER_S + 1e-9
    assert jog.target is None  # given up: the sliders go back to the arm


def test_a_set_point_nobody_read_is_due_again() -> None:
    jog = Jog(SPEEDS)
    take(jog, "base", 10.0, 0.0)
    t = QUIET_S + 0.1
    assert jog.due(t, False, ARM)[0] == {"base": 10.0}  # the first
    assert jog.due(t, False, ARM)[0] == {"base": 10.0}  # short of it: sent again at once
    assert jog.due(t + 0.05, False, ARM) == (None, "")  # ... and not again that soon
    jog.unread()
    assert jog.due(t + 0.06, False, ARM)[0] == {"base": 10.0}


def test_a_jog_survives_a_short_loss_of_the_server_not_a_long_one() -> None:
    jog = Jog(SPEEDS)
    take(jog, "base", 10.0, 0.0)
    jog.contact_back(JOG_KEPT_LOST_S - 1)
    assert jog.target == {"base": 10.0}
    jog.contact_back(JOG_KEPT_LOST_S + 1)
    assert jog.target is None


def test_a_target_is_not_sent_before_its_judgement() -> None:
    """The sliders' thread takes a value, then judges it outside the page's lock: the page's
    loop, due to send, found the new target with the judgement of the one before ("" where
    that one was fine) and sent it: a set-point below the table reached the server, which
    refused it, while the page said it would not be sent (a CI run of the browser's test)."""
    jog = Jog(SPEEDS)
    take(jog, "base", 10.0, 0.0)
    assert jog.due(0.01, False, ARM)[0] == {"base": 10.0}
    below = jog.take("base", 80.0, 0.02)  # not judged yet
    assert jog.due(0.03, False, ARM) == (None, "")
    assert jog.judge(below, "below the table")
    assert jog.due(0.04, False, ARM) == (None, "")  # at it: the sliders' thread says why
    assert jog.due(0.02 + QUIET_S + 0.1, False, ARM) == (None, "not sent: below the table")
    # Judged fine, it goes at the next tick.
    fine = jog.take("base", 20.0, 1.0)
    assert jog.due(1.0, False, ARM) == (None, "")
    assert jog.judge(fine, "")
    assert jog.due(1.01, False, ARM) == ({"base": 20.0}, "")


def test_a_judgement_that_comes_after_a_stop_sends_nothing() -> None:
    """A STOP ends the jog without waiting for the page's lock, between a value's taking
    and its judgement: the judgement that comes then sends nothing."""
    jog = Jog(SPEEDS)
    target = jog.take("base", 10.0, 0.0)
    jog.end()
    assert not jog.judge(target, "")
    assert jog.due(0.01, False, ARM) == (None, "")
    assert jog.target is None
