"""The rig's reading of its processes' words (`al5d_rig.proc.said`, `own_lines`): Fast DDS
prints its own log on the same stdout, and a line of it is not the process's word (a CI run read
"... [RTPS_TRANSPORT_SHM Error] Failed init_port ..." where it waited for "reading")."""

from __future__ import annotations

import io

import pytest

from al5d_rig.host import Shortage
from al5d_rig.netfaults import Restart, restart_problems
from al5d_rig.proc import Lines, own_lines, said

SHM_ERROR = (
    "\x1b[37;1m2026-11-28 16:18:09.319 \x1b[31;1m[\x1b[37;1mRTPS_TRANSPORT_SHM\x1b[31;1m Error]"
    " \x1b[37mFailed init_port fastrtps_port7005: open_and_lock_file failed\x1b[34;1m"
    " -> Function \x1b[36mopen_port_internal\x1b[m\n"
)


def test_fast_dds_log_lines_are_passed_over_coloured_or_not() -> None:
    plain = "2026-11-28 16:18:09.319 [RTPS_TRANSPORT_SHM Warning] a port\n"
    stream = io.StringIO(SHM_ERROR + plain + "reading\n" + '{"ready": true}\n')
    assert said(stream) == "reading"
    assert said(stream) == '{"ready": true}'
    assert said(stream) == ""


def test_a_line_that_only_starts_with_a_date_is_the_process_s_own() -> None:
    assert said(io.StringIO("2026-11-28 16:18:09.319 moved\n")) == "2026-11-28 16:18:09.319 moved"


def test_a_whole_stdout_keeps_the_process_s_own_lines_in_order() -> None:
    """A user's script read whole (a CI-like run of tests/test_ros_client.py read the SHM
    error as the script's first line)."""
    text = SHM_ERROR + "ROS 2\n" + SHM_ERROR + "move [1]: done (300 ms)\n"
    assert own_lines(text) == ["ROS 2", "move [1]: done (300 ms)"]


def test_lines_of_two_processes_are_waited_for_in_whichever_order_they_came() -> None:
    """A server logs, then tells its child, which logs: each by a logging thread of its own,
    the child's line may come first (a CI run waited for the server's, then the child's,
    and never saw the child's: it had come before)."""
    lines = Lines(io.StringIO("start\nthe effect\nthe cause\nlater\n"))
    assert lines.wait_for_each(["the cause", "the effect"], 5) == ["the cause", "the effect"]
    assert lines.wait_for("later", 5) == "later"
    with pytest.raises(AssertionError, match="'never'"):
        lines.wait_for_each(["later", "never"], 0.5)


def test_a_late_trajectory_is_excused_only_by_the_servers_word_and_the_hosts() -> None:
    short = Shortage()
    late = "point 3 took effect {} ms late: base was 1.53 deg off its path, tolerance 1 deg "
    host = "(the host did not run the owner in time)"
    assert short.excuses(late.format(0) + host)  # nothing to excuse: any host
    assert not short.excuses(late.format(10**9) + host)  # more than the host was short
    assert not short.excuses(late.format(0))  # not the server's word that the host was late
    assert not short.excuses("point 3 is below the table")


def test_a_restarts_stop_is_obeyed_in_time_or_said_unanswered_by_its_client() -> None:
    def problems(obeyed: float | None, said: str = "ok", unanswered: float | None = None) -> int:
        done = Restart(100.0, 100.0 + (obeyed or 10.0), said, obeyed, (), unanswered)
        return len(restart_problems([done]))

    assert problems(0.01) == 0
    assert problems(2.15) == 1  # late, and nobody told
    assert problems(2.15, unanswered=1.02) == 0  # told at once, obeyed later
    assert problems(None, unanswered=1.02) == 1  # told, and never obeyed
    assert problems(None, said="raised NoOutcome") == 0  # the client's call said so
