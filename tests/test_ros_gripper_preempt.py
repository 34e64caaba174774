"""A gripper goal preempted while its line is on the board (issue 14's gripper controller).

Over real DDS against `al5d serve` in its own process, with a gripper slowed in its
configuration: a server of its own, which test_ros_controllers.py's module server (same
namespace and domain) would refuse to share.
"""

from __future__ import annotations

import threading
from pathlib import Path

from action_msgs.msg import GoalStatus
from control_msgs.action import GripperCommand

from al5d.arm.config import ArmConfig
from al5d_rig.proc import patient_config
from al5d_rig.rospeer import LockedActionClient, wait_future, wait_until
from al5d_rig.served import served


def gripper_goal(gap_m: float) -> GripperCommand.Goal:
    goal = GripperCommand.Goal()
    goal.command.position = gap_m
    return goal


def test_a_gripper_goal_preempted_on_the_board_halts_the_gripper_on_its_way(
    config: ArmConfig, tmp_path: Path
) -> None:
    """A gripper goal whose line is on the board when a newer one comes (test_ros_controllers.py
    tests one still waiting): it ends CANCELED, its one outcome on /al5d/result naming the newer
    goal; the gripper halts where it is, short of the first goal's gap, and then goes to
    the newer one's. A gripper slowed to 20 deg/s, so that its close is still running when
    the newer goal comes, however busy the host."""
    slow = patient_config((("gripper", 20.0),))
    done = threading.Event()
    with served(config, tmp_path, "al5d_gripper_preempt_peer", slow) as arm:
        name = "/gripper_controller/gripper_cmd"
        client = LockedActionClient(arm.peer.node, GripperCommand, name)
        try:
            assert client.wait_for_server(timeout_sec=10)
            wait_until(lambda: arm.states[-1] == "ready", 30, "ready")
            to_deg = config.model.from_urdf
            closed, between = 0.002, 0.020
            far = to_deg({"gripper": closed})["gripper"]  # about 4 s away from open
            seen: list[float] = []  # the gripper's degrees, every 10 ms from here to the end

            def watch() -> None:
                while not done.wait(0.01):
                    seen.append(arm.emu.servo_degrees()["gripper"])

            watcher = threading.Thread(target=watch, daemon=True)
            watcher.start()
            first = wait_future(client.send_goal_async(gripper_goal(closed)))
            wait_until(lambda: bool(seen) and seen[-1] > 15, 20, "the gripper closing")
            second = wait_future(client.send_goal_async(gripper_goal(between)))
            assert first.accepted and second.accepted
            old = wait_future(first.get_result_async(), 20)
            assert old.status == GoalStatus.STATUS_CANCELED, old.status
            by = bytes(second.goal_id.uuid).hex()
            told = arm.peer.result(bytes(first.goal_id.uuid).hex(), 20)
            assert told.outcome == "cancelled" and told.reason == f"preempted by gripper goal {by}"
            new = wait_future(second.get_result_async(), 20)
            assert new.status == GoalStatus.STATUS_SUCCEEDED and new.result.reached_goal
            assert abs(new.result.position - between) < 0.0005, new.result.position
            there = to_deg({"gripper": between})["gripper"]
            wait_until(lambda: abs(seen[-1] - there) < 0.5, 10, "the gripper at the newer gap")
            done.set()
            watcher.join()
            # Halted on its way: the servo never came near the first goal's end.
            assert max(seen) < far - 10, (max(seen), far)
        finally:
            done.set()
            arm.peer.destroy(client)
