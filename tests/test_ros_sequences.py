"""Issue 22's sequences over real DDS: `al5d serve` in its own process, this process a client.

Each broke the arm's promises before the core was one protocol: a queue that wedged
after a stop and a release; a release sent before a stop (queued on the topic behind
a flood) that undid it; a URDF finger joint that crashed a goal check; an absurd angle
that wrapped round. Each runs a few times in `make test` and ten times more in `make
soak`; the in-process twins are in `test_arm_sequences.py`.
"""

from __future__ import annotations

import random
import time
from collections.abc import Iterator

import pytest
from builtin_interfaces.msg import Duration
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from al5d.arm.config import ArmConfig
from al5d.ssc32u import protocol as p
from al5d_rig.armrig import group_moves
from al5d_rig.fuzzcount import examples
from al5d_rig.rospeer import wait_until
from al5d_rig.served import Served, StopBursts, served

JOINTS = ("base", "shoulder", "elbow", "wrist")
#: Generous: an outcome on a loaded machine (timing is `bench/`'s, not a test's).
OUTCOME_S = 30.0


class Arm(Served):
    """The served arm, and what these sequences read of it."""

    def moves_after(self, index: int) -> list[p.GroupMove]:
        return group_moves(self.emu.records[index:])

    def outcomes(self, ids: list[str]) -> dict[str, str]:
        try:
            wait_until(
                lambda: all(i in self.peer.results for i in ids), OUTCOME_S, f"{len(ids)} outcomes"
            )
        except AssertionError as e:  # which, and what the server said, for the next reader
            missing = [i for i in ids if i not in self.peer.results]
            said = self.proc.err.drain(0)[-25:]
            raise AssertionError(
                f"{e}: missing {missing}; states {self.states[-8:]}; {said}"
            ) from e
        results = self.peer.results_now()
        return {i: results[i].outcome for i in ids}


@pytest.fixture(scope="module")
def arm(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Arm]:
    workdir = tmp_path_factory.mktemp("sequences")
    with served(config, workdir, "al5d_sequences_peer") as s:
        # At ready first: a move of one to three joints near ready, from the park pose, can
        # put the fingers under the table, and is refused.
        s.peer.send("sequences-ready", "ready")
        assert s.peer.result("sequences-ready").outcome == "done"
        yield Arm(s.proc, s.emu, s.config, s.peer, s.states)


def near_ready(rng: random.Random, config: ArmConfig) -> dict[str, float]:
    ready = config.presets["ready"]
    return {j: ready[j] + rng.uniform(-3, 3) for j in rng.sample(JOINTS, rng.randint(1, 3))}


def test_the_queue_never_wedges_after_a_stop_and_a_release(arm: Arm) -> None:
    """Defect 1: 30 moves, a stop on the topic, a release by the service 50 ms later, then
    probe moves: they were accepted and never written, in `ready`, for ever."""
    rng = random.Random(1)
    peer = arm.peer
    for rep in range(examples(3)):
        arm.ready()
        flood = [f"wedge{rep}-{i}" for i in range(30)]
        for ident in flood:
            peer.send(ident, "move", **near_ready(rng, arm.config))
        peer.send(f"wedge{rep}-stop", "stop")
        time.sleep(0.05)
        assert peer.result(f"wedge{rep}-stop", OUTCOME_S).outcome == "done"
        assert peer.trigger("release").success
        n = len(arm.emu.records)
        probes = [f"wedge{rep}-probe{i}" for i in range(3)]
        for ident in probes:
            peer.send(ident, "move", **near_ready(rng, arm.config))
        outcomes = arm.outcomes(flood + probes)
        assert [outcomes[i] for i in probes] == ["done"] * 3, (rep, outcomes)
        assert len(arm.moves_after(n)) >= 3, rep
        wait_until(lambda: arm.states[-1] == "ready", 10, "ready after the probes")
    # Stop, release and a quiet second: a lone move is done, and a park goal finishes.
    assert peer.trigger("stop").success
    assert peer.trigger("release").success
    time.sleep(1.0)
    peer.send("wedge-lone", "move", base=5)
    assert peer.result("wedge-lone", OUTCOME_S).outcome == "done"
    handle = peer.goal(preset="park")
    result = handle.get_result_async()
    wait_until(result.done, OUTCOME_S, "the park goal")
    assert result.result().result.outcome == "done"


def test_a_release_sent_before_a_stop_never_undoes_it(arm: Arm) -> None:
    """Defect 2: stop (service); 3,000 moves on the topic; release on the topic; 20 moves on
    the topic; stop (service). The last stop overtakes the release queued on the topic,
    which arrived after it and unlocked the arm: the 20 moves ran."""
    rng = random.Random(2)
    peer = arm.peer
    overtaken = 0
    for rep in range(examples(2)):
        arm.ready()
        assert peer.trigger("stop").success
        flood = [f"under{rep}-{i}" for i in range(3000)]
        for ident in flood:
            peer.send(ident, "move", **near_ready(rng, arm.config))
        release = f"under{rep}-release"
        peer.send(release, "release")
        after = [f"under{rep}-after{i}" for i in range(20)]
        for ident in after:
            peer.send(ident, "move", **near_ready(rng, arm.config))
        stops = arm.stops()
        bursts = StopBursts(peer, arm.proc)
        assert peer.trigger("stop").success
        outcomes = arm.outcomes([*flood, release, *after])
        wait_until(lambda: arm.states[-1] == "stopped", 10, "stopped at the end")
        # The last stop's STOPs may still be on the wire, behind the move they halt.
        wait_until(lambda n=stops: arm.stops() - n >= 6, 10, "the last stop's STOPs")
        time.sleep(0.2)
        last = max(
            i
            for i, r in enumerate(arm.emu.records)
            if any(isinstance(c, p.Stop) for c in r.commands)
        )
        assert not arm.moves_after(last), "a move reached the board after the last stop"
        reason = peer.results_now()[release].reason
        if outcomes[release] == "refused":  # it came after the last stop: that one holds
            overtaken += 1
            assert reason.startswith("this release was sent before the stop"), reason
            assert all(outcomes[i] != "done" for i in after), outcomes
        # One burst of STOPs per stop obeyed: none obeyed twice (defect 5's extra burst).
        bursts.check(lambda stops=stops: arm.stops() - stops)
    print(f"the last stop overtook the release in {overtaken} of {examples(2)} runs")


def test_a_finger_joint_on_the_trajectory_topic_is_refused(arm: Arm) -> None:
    """Defect 3: the URDF's finger joints on /al5d/joint_trajectory got no outcome at all."""
    arm.ready()
    pub = arm.peer.trajectory_writer()
    n = len(arm.emu.records)
    for finger in ("gripper_left", "gripper_right"):
        msg = JointTrajectory(joint_names=["elbow", finger])
        msg.header.frame_id = f"finger-{finger}"
        msg.points.append(
            JointTrajectoryPoint(positions=[1.0, 0.01], time_from_start=Duration(sec=1))
        )
        pub.publish(msg)
        result = arm.peer.result(f"finger-{finger}", OUTCOME_S)
        assert result.outcome == "refused" and "is a finger of the URDF's gripper" in (
            result.reason
        )
    assert not arm.moves_after(n)
    arm.peer.destroy(pub)


@pytest.mark.parametrize("pitch", [1e300, -1e300, 1e18])
def test_an_absurd_angle_is_refused_not_wrapped(arm: Arm, pitch: float) -> None:
    """Defect 4: pitch 1e300, -1e300 or 1e18 (radians over ROS) moved the arm to some pitch
    between -180 and 180 degrees."""
    arm.ready()
    n = len(arm.emu.records)
    ident = f"absurd-{pitch:g}"
    arm.peer.send(ident, "move_to", x=0.25, y=0.0, z=0.12, pitch=pitch)
    result = arm.peer.result(ident, OUTCOME_S)
    assert result.outcome == "refused" and "is beyond one turn" in result.reason, result.reason
    assert not arm.moves_after(n)
