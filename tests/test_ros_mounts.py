"""Several arms in one TF tree (issue 24, item 5): each server's mount (`server.mount`) puts
its base_link in the shared `world` frame, on /tf_static; the web view shows its arm there.

Two servers in one ROS domain, in two namespaces: the left one set up by `-p` and `-r`,
the right one by a params file, as a launch file gives parameters. The tree is composed
here from the messages on /tf_static and /tf (tf2 is not on PyPI).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import pytest
import viser
import yaml
from tf2_msgs.msg import TFMessage

from al5d.arm.config import ArmConfig
from al5d.arm.instruction import Instruction, Outcome
from al5d.model import forward
from al5d.model.transforms import Transform, Vec3, quat_from_rpy
from al5d.ros.names import Names
from al5d.ros.robot import QOS_TF_STATIC
from al5d.ssc32u.emulator import Emulator
from al5d.web.link import WebNode
from al5d.web.scene import ArmScene
from al5d_rig.proc import Proc, patient_config
from al5d_rig.rospeer import Peer, wait_until

MOUNTS: dict[str, tuple[Vec3, Vec3]] = {
    "left": ((0.0, 0.35, 0.0), (0.0, 0.0, -math.pi / 2)),
    "right": ((0.05, -0.35, 0.02), (0.0, 0.0, math.pi / 2)),
}


@dataclass
class Arm:
    name: str
    emu: Emulator
    proc: Proc
    peer: Peer

    @property
    def mount(self) -> Transform:
        xyz, rpy = MOUNTS[self.name]
        return Transform(xyz, quat_from_rpy(*rpy))


def _vector(v: Sequence[float]) -> str:
    return "[" + ",".join(repr(float(x)) for x in v) + "]"


@pytest.fixture(scope="module")
def arms(config: ArmConfig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[list[Arm]]:
    made: list[Arm] = []
    try:
        for name, (xyz, rpy) in MOUNTS.items():
            folder = tmp_path_factory.mktemp(name)
            link = folder / "ssc32u"
            emu = Emulator(config, link=link).start()
            if name == "left":
                ros = ["-p", f"port:={link}", "-p", f"config_file:={patient_config()}"]
                ros += [
                    "-p",
                    "server.mount.parent:=world",
                    "-p",
                    f"server.mount.xyz:={_vector(xyz)}",
                ]
                ros += ["-p", f"server.mount.rpy:={_vector(rpy)}", "-r", "__ns:=/left"]
            else:
                params = {
                    "port": str(link),
                    "config_file": patient_config(),
                    "server": {
                        "namespace": name,
                        "mount": {"parent": "world", "xyz": list(xyz), "rpy": list(rpy)},
                    },
                }
                path = folder / "params.yaml"
                path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
                ros = ["--params-file", str(path)]
            proc = Proc("serve", "--log-level", "INFO", "--ros-args", *ros)
            made.append(Arm(name, emu, proc, Peer(name=f"al5d_{name}_mount_peer", namespace=name)))
        for arm in made:
            arm.proc.err.wait_for("STATE: ready", 30)
            arm.peer.wait_for_server()
        yield made
    finally:
        for arm in made:
            arm.peer.close()
            arm.proc.kill()
            arm.emu.close()


def tree(peer: Peer, tools: Sequence[str]) -> dict[str, tuple[str, Transform]]:
    """child -> (parent, transform), from /tf_static and /tf, once each of `tools` has a
    path to a root that is no frame of its arm (or 20 s have passed)."""
    static: dict[str, tuple[str, Transform]] = {}
    moving: dict[str, tuple[str, Transform]] = {}

    def add(into: dict[str, tuple[str, Transform]], msg: TFMessage) -> None:
        for t in msg.transforms:
            p, q = t.transform.translation, t.transform.rotation
            into[t.child_frame_id] = (
                t.header.frame_id,
                Transform((p.x, p.y, p.z), (q.x, q.y, q.z, q.w)),
            )

    subs = [
        peer.node.create_subscription(
            TFMessage, "/tf_static", lambda m: add(static, m), QOS_TF_STATIC
        ),
        peer.node.create_subscription(TFMessage, "/tf", lambda m: add(moving, m), 100),
    ]
    try:

        def whole() -> bool:
            frames = {**static, **moving}
            return all("/" not in in_root(frames, tool)[0] for tool in tools)

        with contextlib.suppress(AssertionError):  # the test says what is missing
            wait_until(whole, 20, f"a tree for {tools}")
    finally:
        peer.destroy(*subs)
    return {**static, **moving}


def in_root(frames: dict[str, tuple[str, Transform]], frame: str) -> tuple[str, Transform]:
    """The root of `frame`'s tree and `frame`'s pose in it."""
    pose = Transform()
    while frame in frames:
        parent, t = frames[frame]
        pose = t * pose
        frame = parent
    return frame, pose


def test_two_mounted_arms_are_one_tree_from_the_world_to_both_tools(
    arms: list[Arm], config: ArmConfig
) -> None:
    left, right = arms
    left.peer.send("m-l", "move", base=30, shoulder=20, elbow=80, wrist=-10)
    right.peer.send("m-r", "move", base=-45, shoulder=40, elbow=70, wrist=10)
    assert left.peer.result("m-l").outcome == "done"
    assert right.peer.result("m-r").outcome == "done"
    frames = tree(left.peer, ["left/tool0", "right/tool0"])
    for arm in arms:
        root, pose = in_root(frames, f"{arm.name}/tool0")
        assert root == "world", f"{arm.name}/tool0 hangs from {root}, not world"
        parent, mount = frames[f"{arm.name}/base_link"]
        assert parent == "world"
        assert math.dist(mount.translation, arm.mount.translation) < 1e-9
        assert (
            max(abs(a - b) for a, b in zip(mount.rotation, arm.mount.rotation, strict=True)) < 1e-9
        )
        tip = forward(config.model.geometry, arm.emu.servo_degrees()).position
        assert math.dist(pose.translation, arm.mount.apply(tip)) < 0.002
    # Facing each other across the world's x axis, 70 cm apart: the tools are apart too.
    assert (
        math.dist(
            in_root(frames, "left/tool0")[1].translation,
            in_root(frames, "right/tool0")[1].translation,
        )
        > 0.1
    )


class Listener:
    """The web view's page, as its ROS link tells it things: only the mount is kept."""

    def __init__(self) -> None:
        self.mounts: list[tuple[str, Transform]] = []

    def on_description(self, urdf: str) -> None: ...

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None: ...

    def on_state(self, state: str) -> None: ...

    def on_outcome(self, outcome: Outcome) -> None: ...

    def on_instruction(self, instr: Instruction) -> None: ...

    def on_mount(self, parent: str, mount: Transform) -> None:
        self.mounts.append((parent, mount))

    def on_physical(self, degrees: dict[str, float]) -> None: ...

    def on_answer(self, text: str, ok: bool | None) -> None: ...


def test_the_web_view_shows_its_arm_where_its_mount_puts_it(
    arms: list[Arm], config: ArmConfig
) -> None:
    right = arms[1]
    listener = Listener()
    link = WebNode(Names.of("right"), listener, config.model, tuple(config.presets))
    try:
        wait_until(lambda: listener.mounts, 20, "the right arm's mount")
    finally:
        link.close()
    parent, mount = listener.mounts[-1]
    assert parent == "world"
    assert math.dist(mount.translation, right.mount.translation) < 1e-9
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        scene = ArmScene(server, config.model)
        scene.place_arm(mount)
        assert tuple(scene.mount.position) == pytest.approx(right.mount.translation)
        x, y, z, w = right.mount.rotation
        assert tuple(scene.mount.wxyz) == pytest.approx((w, x, y, z))
        # The gizmo is placed in base_link (as the page's targets are): in the world it is
        # where the mount puts that point.
        scene.place_target((0.2, 0.0, 0.1))
        assert scene.target.name.startswith(scene.mount.name + "/")
    finally:
        server.stop()
