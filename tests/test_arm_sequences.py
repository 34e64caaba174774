"""Issue 22's sequences in-process, 20 times each: the driver on an emulated board, the
channels played by the test (which instruction arrives when, and when it was sent).

The twins over real DDS are in `test_ros_sequences.py`.
"""

from __future__ import annotations

import dataclasses
import random
import threading
import time
from concurrent.futures import Future

import pytest

from al5d.arm import instruction as ins
from al5d.arm.instruction import Instruction, Outcome, Result
from al5d.arm.states import State
from al5d.clock import wall_ns
from al5d.ssc32u import protocol as p
from al5d_rig.armrig import Rig, group_moves

REPEATS = 20
JOINTS = ("base", "shoulder", "elbow", "wrist")


@pytest.fixture(autouse=True)
def at_ready(rig: Rig) -> None:
    """The arm at ready first: a move of one to three joints near ready, from the park pose
    (or a move stopped on its way), can put the fingers under the table, and is refused."""
    assert rig.driver.execute(ins.preset("ready"), 15).ok


def near_ready(rig: Rig, rng: random.Random) -> Instruction:
    ready = rig.config.presets["ready"]
    joints = rng.sample(JOINTS, rng.randint(1, 3))
    return ins.move(**{j: ready[j] + rng.uniform(-3, 3) for j in joints})


def sent(instr: Instruction, t_ns: int) -> Instruction:
    return dataclasses.replace(instr, sent_ns=t_ns)


def moves_since(rig: Rig, index: int) -> int:
    return len(group_moves(rig.emu.records[index:]))


def test_a_stop_on_the_topic_and_a_release_never_wedge_the_queue(rig: Rig) -> None:
    """30 moves from one thread (the node, in order); the stop among them seen at once by
    the stop watcher and later by the node (one message: one key); a release 50 ms later;
    probes: every one done, the state honest, 20 times."""
    rng = random.Random(22)

    def node(stop: Instruction, key: object, futures: list[Future[Outcome]]) -> None:
        for _ in range(30):
            futures.append(rig.driver.submit(near_ready(rig, rng)))
        rig.driver.submit(stop, key=key)  # the node reaches the stop, in order

    for rep in range(REPEATS):
        stop = ins.stop()
        key = ("seq1", rep)
        futures: list[Future[Outcome]] = []
        reader = threading.Thread(target=node, args=(stop, key, futures))
        reader.start()
        time.sleep(rng.uniform(0, 0.01))
        assert rig.driver.submit(stop, key=key).result(1).ok  # the watcher, at once
        reader.join(10)
        time.sleep(0.05)
        assert rig.driver.execute(ins.release(), 30).ok, rep
        n = len(rig.emu.records)
        probes = [rig.driver.submit(near_ready(rig, rng)) for _ in range(3)]
        for f in futures:
            assert f.result(10).result in (Result.DONE, Result.CANCELLED, Result.REFUSED)
        assert all(f.result(10).ok for f in probes), rep
        assert moves_since(rig, n) >= 3
        rig.driver.wait_for_state(State.READY, 5)
        stops = sum(isinstance(c, p.Stop) for r in rig.emu.records for c in r.commands)
        assert stops == 6 * (rep + 1), "a stop seen by both readers was obeyed twice"


def test_a_release_sent_before_a_stop_is_refused_and_the_arm_stays_locked(rig: Rig) -> None:
    """Stop (service); 3,000 moves, a release and 20 moves sent on the topic, where they
    wait behind each other; stop (service) last, obeyed before the topic's backlog
    arrives: the release is refused, the 20 moves never run, 20 times."""
    rng = random.Random(23)
    for rep in range(REPEATS):
        assert rig.driver.execute(ins.stop(), 30).ok
        topic = [sent(near_ready(rig, rng), wall_ns()) for _ in range(3000)]
        release = sent(ins.release(), wall_ns())
        after = [sent(near_ready(rig, rng), wall_ns()) for _ in range(20)]
        assert rig.driver.execute(ins.stop(), 30).ok  # the service overtakes the topic
        n = len(rig.emu.records)
        outcomes = [rig.driver.submit(i) for i in topic]
        refused = rig.driver.execute(release, 30)
        late = [rig.driver.submit(i) for i in after]
        assert refused.result is Result.REFUSED, (rep, refused)
        assert refused.reason.startswith("this release was sent before the stop"), refused
        assert all(f.result(5).result is not Result.DONE for f in (*outcomes, *late))
        assert rig.driver.state is State.STOPPED
        time.sleep(0.05)
        assert moves_since(rig, n) == 0, rep
        assert rig.driver.execute(ins.release(), 30).ok  # sent now: after the stop
