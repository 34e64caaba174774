"""Recordings: `al5d serve --record` and `al5d record` write rosbag2's MCAP, read back here with
the `mcap` reader and mcap-ros2-support's decoder; `al5d replay` sends the instructions to a
fresh server on a fresh board, which then receives the same bytes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest
from al5d_interfaces.msg import ArmInstruction
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.serialization import serialize_message

from al5d import exits
from al5d.app.mcapfile import BOARD_WRITE_MSG, BOARD_WRITE_TYPE, RecordFile, board_write_cdr
from al5d.app.replay import BadRecording, read_instructions, survey
from al5d.arm.config import load_config
from al5d.arm.instruction import PRESET_NAMES, Wait, parse_sequence
from al5d.ros.client import Client
from al5d.ros.dds import start_context
from al5d.ros.names import PING, Names, reaches_server, server_nodes
from al5d.ros.qos import QOS_INSTRUCTIONS
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator
from al5d_rig.proc import Lines, Proc, patient_config, to_another_thread
from al5d_rig.rospeer import Peer, wait_future, wait_until

ROOT = Path(__file__).resolve().parents[1]

#: The sequence the client runs while the recordings are made: a refused move (nothing
#: written), a stop and a release on the topic, moves before and after.
SEQUENCE = """\
ready
move base=30 time=300
move elbow=200
stop
release
move shoulder=60 elbow=60 wrist=30 time=400
park
"""
SENT = [
    ("ready", [], []),
    ("move", ["base"], [30.0]),
    ("move", ["elbow"], [200.0]),
    ("stop", [], []),
    ("release", [], []),
    ("move", ["shoulder", "elbow", "wrist"], [60.0, 60.0, 30.0]),
    ("park", [], []),
]
OUTCOMES = ["done", "done", "refused", "done", "done", "done", "done"]
STATUS_SUCCEEDED = 4
TYPES = {
    "/al5d/instruction": "al5d_interfaces/msg/ArmInstruction",
    "/al5d/result": "al5d_interfaces/msg/InstructionResult",
    "/al5d/state": "std_msgs/msg/String",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/al5d/joint_trajectory": "trajectory_msgs/msg/JointTrajectory",
    "/joint_commands": "sensor_msgs/msg/JointState",
    "/al5d/move/_action/status": "action_msgs/msg/GoalStatusArray",
    "/arm_controller/follow_joint_trajectory/_action/status": "action_msgs/msg/GoalStatusArray",
    "/gripper_controller/gripper_cmd/_action/status": "action_msgs/msg/GoalStatusArray",
    "/robot_description": "std_msgs/msg/String",
    "/al5d/tool_pose": "geometry_msgs/msg/PoseStamped",
    "/al5d/goals/move": "al5d_interfaces/msg/ArmInstruction",
    "/al5d/goals/follow_joint_trajectory": "trajectory_msgs/msg/JointTrajectory",
    "/al5d/goals/gripper_cmd": "sensor_msgs/msg/JointState",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}


def motion_lines(chunks: list[bytes]) -> list[bytes]:
    """The group moves and STOPs among bytes written or received (ESC and queries left out:
    the link checks come when a timer says, not when an instruction does). A long line goes
    to the board in pieces, a write each: the bytes are read as one stream."""
    lines = []
    for line in b"".join(chunks).replace(b"\x1b", b"").split(b"\r"):
        if line.startswith((b"#", b"STOP")):
            lines.append(line)
    return lines


def without_holds(lines: list[bytes]) -> list[bytes]:
    """`lines` (of `motion_lines`) without the group moves that hold: no time, every pulse
    the one last written on its channel. The server writes one before a move after a stop
    that came while a joint may still have been on its way (`PoseBook.unsure`: within
    `SETTLE_GRACE_S` of its move's end), so whether there is one depends on how soon the
    stop followed the move (a CI run's replay had none where its recording had one)."""
    last: dict[int, int] = {}
    kept = []
    for line in lines:
        parsed = p.parse_line(line)
        moves = [] if isinstance(parsed, p.Unrecognized) else parsed
        targets = [t for c in moves if isinstance(c, p.GroupMove) for t in c.targets]
        untimed = all(isinstance(c, p.GroupMove) and c.time_ms is None for c in moves)
        if not (moves and untimed and all(last.get(t.channel) == t.pulse_us for t in targets)):
            kept.append(line)
        last.update((t.channel, t.pulse_us) for t in targets)
    return kept


def read_back(path: Path) -> tuple[Any, dict[str, list[tuple[Any, Any]]]]:
    """The file's summary and its decoded messages by topic, in the file's order."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        by_topic: dict[str, list[tuple[Any, Any]]] = defaultdict(list)
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert schema is not None
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            expected = BOARD_WRITE_TYPE if channel.topic.endswith("board_writes") else None
            assert schema.name == (expected or TYPES[channel.topic]), channel.topic
            by_topic[channel.topic].append((message, decoded))
    assert summary is not None
    total = sum(len(v) for v in by_topic.values())
    assert summary.statistics.message_count == total
    for topic, messages in by_topic.items():
        times = [m.log_time for m, _ in messages]
        assert times == sorted(times), f"{topic}: not in the order received"
    return summary, by_topic


def check_topics(by_topic: dict[str, list[tuple[Any, Any]]], goal_uuid: bytes) -> None:
    """Every instruction of the sequence, in order, each with one result; the states; the
    joint states; the goal's status. The client's handshake (its pings) is on the topic
    too, as many as it took; `al5d replay` passes them over."""
    instructions = [d for _, d in by_topic["/al5d/instruction"] if d.instruction != PING]
    assert len(instructions) < len(by_topic["/al5d/instruction"])
    assert [(d.instruction, list(d.joints), list(d.degrees)) for d in instructions] == SENT
    results: dict[str, list[str]] = defaultdict(list)
    for _, d in by_topic["/al5d/result"]:
        results[d.id].append(d.outcome)
    assert [results[d.id] for d in instructions] == [[o] for o in OUTCOMES]
    states = [d.data for _, d in by_topic["/al5d/state"]]
    assert {"ready", "moving", "stopped"} <= set(states)
    assert len(by_topic["/joint_states"]) > 10
    finished = [
        s
        for _, d in by_topic["/al5d/move/_action/status"]
        for s in d.status_list
        if bytes(s.goal_info.goal_id.uuid) == goal_uuid
    ]
    assert finished and finished[-1].status == STATUS_SUCCEEDED


def writers(lines: Lines, topic: str) -> int:
    """How many writers of `topic` a recorder last said it had matched."""
    said = [line for line in lines.drain(0.1) if f" {topic}: " in line and "writer" in line]
    return int(said[-1].split(f" {topic}: ")[1].split()[0]) if said else 0


def wait_for_recorders(client: Client, server: Lines, recorder: Lines) -> None:
    """Until both recorders have matched the server's writers, `al5d record`'s this client's
    too, and the client's writer of instructions every reader of them (the recorder's among
    them): a recorder, as rosbag2's, misses what was sent before it had matched the writer,
    and on a busy host a participant can be discovered seconds after another. (The server's
    own recording has the instructions its node read.)"""
    wait_until(
        lambda: any(
            i.node_name == "al5d_recorder"
            for i in client.node.get_subscriptions_info_by_topic("/al5d/instruction")
        ),
        30,
        "the recorder, seen by the client",
    )
    client.wait_for_server(30)
    needed = {"/al5d/result": 1, "/al5d/state": 1, "/joint_states": 1}
    needed["/al5d/move/_action/status"] = 1
    for lines, more in ((server, {}), (recorder, {"/al5d/instruction": 2})):
        for topic, n in {**needed, **more}.items():
            wait_until(
                lambda lines=lines, topic=topic, n=n: writers(lines, topic) >= n,
                30,
                f"{n} writer(s) of {topic}",
            )


def run_sequence(client: Client, text: str) -> list[str]:
    """Each line of `text`, in turn, each waited for; the outcomes."""
    outcomes = []
    for item, _ in parse_sequence(text.encode(), "sequence", PRESET_NAMES):
        if isinstance(item, Wait):
            time.sleep(item.ms / 1000)
        else:
            outcomes.append(client.execute(item, timeout=30).result.value)
    return outcomes


def test_record_then_replay_reproduces_the_boards_bytes(tmp_path: Path) -> None:
    config = load_config()
    served, recorded = tmp_path / "served.mcap", tmp_path / "recorded.mcap"
    link_a = tmp_path / "board-a"
    emu_a = Emulator(config, link=link_a).start()
    server = Proc(
        "serve", "--port", str(link_a), "--config", patient_config(), "--record", str(served)
    )
    recorder = Proc("record", str(recorded))
    peer = Peer(name="record_test_peer")
    try:
        server.err.wait_for("STATE: ready", 30)
        recorder.out.wait_for("recording to", 30)
        peer.wait_for_server()
        with Client(local=False) as client:
            wait_for_recorders(client, server.err, recorder.out)
            assert run_sequence(client, SEQUENCE) == OUTCOMES
        goal_sent = time.monotonic()
        handle = peer.goal(preset="ready")
        assert wait_future(handle.get_result_async(), 20).status == STATUS_SUCCEEDED
        goal_uuid = bytes(handle.goal_id.uuid)
        time.sleep(0.5)  # its last status reaches the recorders
        recorder.popen.send_signal(signal.SIGINT)
        assert recorder.wait(20) == 0
        assert "recorded.mcap: " in recorder.out.wait_for("recorded.mcap: ", 5)
        server.popen.send_signal(signal.SIGTERM)
        assert server.wait(30) == 0
    finally:
        peer.close()
        recorder.kill()
        server.kill()
        emu_a.close()

    # The server's recording: every topic, and the board's bytes as the board received them.
    _, by_topic = read_back(served)
    try:
        check_topics(by_topic, goal_uuid)
    except AssertionError as e:  # what the server's recorder said it matched, for the reader
        said = [x for x in server.err.drain(0) if "recording" in x or "recorded" in x]
        counts = {topic: len(messages) for topic, messages in by_topic.items()}
        raise AssertionError(f"{e}: recorded {counts}; the server said {said[-15:]}") from e
    writes = [d for _, d in by_topic["/al5d/board_writes"]]
    assert [m.sequence for m, _ in by_topic["/al5d/board_writes"]] == list(
        range(1, len(writes) + 1)
    )
    received = [r.raw + b"\r" for r in emu_a.records]  # each line the board took, its CR
    assert motion_lines([bytes(w.data) for w in writes]) == motion_lines(received)
    assert all((w.arrival.sec, w.arrival.nanosec) >= (w.stamp.sec, w.stamp.nanosec) for w in writes)
    # The client's recording: the same messages, and no bytes of the board.
    _, client_topics = read_back(recorded)
    check_topics(client_topics, goal_uuid)
    assert "/al5d/board_writes" not in client_topics

    # The replay, on a fresh server and board: the same bytes as the board received before
    # the goal (which the replay does not send: goals are no instructions).
    before_goal = motion_lines([r.raw + b"\r" for r in emu_a.records if r.t_effect < goal_sent])
    link_b = tmp_path / "board-b"
    emu_b = Emulator(config, link=link_b).start()
    server_b = Proc("serve", "--port", str(link_b), "--config", patient_config())
    try:
        server_b.err.wait_for("STATE: ready", 30)
        fast = Proc("replay", str(served), "--rate", "fast")
        assert fast.wait(60) == 1  # the refused move, refused again
        outcomes = [line.split("]: ")[1].split()[0] for line in fast.out.drain() if "]: " in line]
        assert [o.rstrip(":") for o in outcomes] == OUTCOMES
        time.sleep(0.5)  # the last move's bytes are in effect
        replayed = motion_lines([r.raw + b"\r" for r in emu_b.records])
        assert without_holds(replayed) == without_holds(before_goal), (replayed, before_goal)
        # As recorded: each sent at its recorded time, each with one outcome. Not always the
        # same outcomes: on a host slower now than when it was recorded, the stop sent at
        # its time can find the move before it still running, and cancel it.
        slow = Proc("replay", str(recorded))
        assert slow.wait(60) == 1
        outcomes = [line.split("]: ")[1].split()[0] for line in slow.out.drain() if "]: " in line]
        said = [o.rstrip(":") for o in outcomes]
        assert len(said) == len(OUTCOMES) and said.count("refused") == 1, said
        assert set(said) <= {"done", "refused", "cancelled"}, said
    finally:
        server_b.kill()
        emu_b.close()


def test_bad_files_are_clear_errors(tmp_path: Path) -> None:
    missing = Proc("replay", str(tmp_path / "none.mcap"))
    assert missing.wait(30) == exits.BAD_INPUT
    assert "cannot read" in missing.err.wait_for("al5d replay:", 5)

    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    bad = Proc("replay", str(text))
    assert bad.wait(30) == exits.BAD_INPUT
    assert "is not an MCAP recording" in bad.err.wait_for("al5d replay:", 5)

    # A recording without instructions (only a state, say).
    empty = tmp_path / "empty.mcap"
    file = RecordFile(empty)
    channel = file.channel("/al5d/state", "std_msgs/msg/String")
    file.put(channel, b"\x00\x01\x00\x00\x06\x00\x00\x00ready\x00", 1, 1)
    file.close()
    none = Proc("replay", str(empty))
    assert none.wait(30) == exits.BAD_INPUT
    assert "holds no instructions" in none.err.wait_for("al5d replay:", 5)

    unwritable = Proc("record", str(tmp_path / "no" / "such" / "dir.mcap"), "--duration", "1")
    assert unwritable.wait(30) == 2
    assert "cannot write the recording" in unwritable.err.wait_for("al5d record:", 5)
    server = Proc("serve", "--no-ros", "--record", str(tmp_path / "no" / "dir.mcap"))
    assert server.wait(30) == 2
    assert "cannot write the recording" in server.err.wait_for("ERROR", 10)
    # The same file as the node's parameter `record`.
    param = Proc("serve", "--ros-args", "-p", f"record:={tmp_path / 'no' / 'param.mcap'}")
    assert param.wait(30) == 2
    assert "param.mcap: No such file" in param.err.wait_for("ERROR", 10)
    # A trace (`--trace`, written as the server ends) that cannot be written is said at once:
    # it was taken, and the trace silently never written (an outside try).
    trace = Proc("serve", "--no-ros", "--trace", str(tmp_path / "no" / "trace.txt"))
    assert trace.wait(30) == 2
    assert "--trace: cannot write" in trace.err.wait_for("ERROR", 10)


def test_a_recording_cut_short_is_an_error_or_with_partial_what_it_holds(tmp_path: Path) -> None:
    """A recorder killed before it closed its file: an error naming the damage, nothing
    sent; with --partial, the instructions before the cut."""
    whole = tmp_path / "whole.mcap"
    file = RecordFile(whole)
    channel = file.channel("/al5d/instruction", "al5d_interfaces/msg/ArmInstruction")
    for i in range(200):
        msg = ArmInstruction(instruction="move", joints=["base"], degrees=[float(i % 60)])
        msg.id = f"m{i}"
        file.put(channel, serialize_message(msg), 1000 + i, 1000 + i, i)
    file.close()
    found = read_instructions(whole)
    assert [r.fields.id for r in found] == [f"m{i}" for i in range(200)]
    cut = tmp_path / "cut.mcap"
    data = whole.read_bytes()
    cut.write_bytes(data[: len(data) - 200])  # the summary and footer gone
    with pytest.raises(BadRecording, match="is damaged or cut short"):
        read_instructions(cut)
    partial = survey(cut, partial=True)
    assert "is damaged or cut short" in partial.damage
    assert 0 < partial.instructions["/al5d/instruction"] <= 200
    refused = Proc("replay", str(cut), "--wait", "1")
    assert refused.wait(30) == exits.BAD_INPUT
    said = refused.err.wait_for("al5d replay:", 5)
    assert "cut.mcap is damaged or cut short" in said, said
    assert said.endswith("; --partial replays the instructions before the damage"), said


def test_what_a_recording_is_handed_is_on_disk_a_moment_later(tmp_path: Path) -> None:
    """A process killed as it records (a bridge that crashed) leaves what is on disk: what it
    was handed up to `FLUSH_EVERY_S` before, readable with --partial. The chunk being filled
    stayed in memory until it was full (a megabyte): a killed bridge's short recording was
    0 bytes."""
    live = tmp_path / "live.mcap"
    file = RecordFile(live)
    try:
        channel = file.channel("/al5d/instruction", "al5d_interfaces/msg/ArmInstruction")
        for i in range(50):
            msg = ArmInstruction(instruction="move", joints=["base"], degrees=[float(i)])
            msg.id = f"m{i}"
            file.put(channel, serialize_message(msg), 1000 + i, 1000 + i, i)
        killed_now = tmp_path / "killed.mcap"

        def left() -> int:
            killed_now.write_bytes(live.read_bytes())  # what a kill -9 would leave now
            return survey(killed_now, partial=True).instructions["/al5d/instruction"]

        wait_until(lambda: left() == 50, 20, "the 50 instructions on disk")
    finally:
        file.close()
    assert len(read_instructions(live)) == 50  # and closed, the file is whole


#: A recorder whose disk refuses its chunk (the kernel's file size limit: EFBIG), in a
#: process of its own; it prints the failure and the CPU seconds its process then spent
#: in 3 s of doing nothing.
FAILING_DISK = """
import os, resource, signal, sys, time
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))
from al5d.app.mcapfile import RecordFile
file = RecordFile(sys.argv[1])
channel = file.channel("/al5d/instruction", "al5d_interfaces/msg/ArmInstruction")
for i in range(1500):  # a chunk's megabyte at once, random: compressed, still over the limit
    file.put(channel, b"\\x00\\x01\\x00\\x00" + os.urandom(1000), i, i, i)
deadline = time.monotonic() + 60
while not file.failed and time.monotonic() < deadline:
    time.sleep(0.05)
cpu = time.process_time()
time.sleep(3)
print(file.failed, time.process_time() - cpu, flush=True)
os._exit(0)
"""


def test_a_recording_whose_disk_fails_mid_chunk_waits_quietly(tmp_path: Path) -> None:
    """A write that failed within a second of the last flush left a flush due for ever: the
    file's thread spun (0.87 CPU s in 3 s here) until the recording was closed, beside
    the bridge's nodes. Once failed, it waits for the end and writes nothing."""
    done = subprocess.run(
        [sys.executable, "-c", FAILING_DISK, str(tmp_path / "full.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    failed, cpu = done.stdout.rsplit(" ", 1)
    assert "File too large" in failed, done.stdout + done.stderr
    assert float(cpu) < 0.1, done.stdout


def test_a_recording_that_fails_never_stops_the_arm(tmp_path: Path) -> None:
    """/dev/full takes the file but no byte of it: the arm works, the failure is logged."""
    server = Proc("serve", "--stdin", "--no-ros", "--record", "/dev/full", stdin=True)
    try:
        server.err.wait_for("STATE: ready", 30)
        server.send("move base=30 time=300")
        assert "done" in server.out.wait_for("move [", 20)
        server.send("shutdown")
        assert server.wait(30) == 0
        server.err.drain()
        assert any("recording /dev/full" in line and "ERROR" in line for line in server.err.all)
    finally:
        server.kill()


def test_the_board_write_type_is_the_interface_and_its_bytes_are_rosidls() -> None:
    """The schema written into recordings is al5d_interfaces/msg/BoardWrite as built, and a
    BoardWrite serialized by rclpy is the bytes the recording writes."""
    from al5d_interfaces.msg import BoardWrite

    source = ROOT / "interfaces" / "al5d_interfaces" / "msg" / "BoardWrite.msg"
    assert source.read_text() == BOARD_WRITE_MSG
    msg = BoardWrite(data=list(b"\x1bSTOP0\rSTOP1\r"))
    msg.stamp.sec, msg.stamp.nanosec = 1_790_000_000, 123_456_789
    msg.arrival.sec, msg.arrival.nanosec = 1_790_000_001, 5
    stamp, arrival = 1_790_000_000_123_456_789, 1_790_000_001_000_000_005
    assert serialize_message(msg) == board_write_cdr(b"\x1bSTOP0\rSTOP1\r", stamp, arrival)


def test_a_recorder_that_finds_no_arm_says_so(tmp_path: Path) -> None:
    """In a namespace no server has, nothing matches: said after a few seconds."""
    recorder = Proc("record", str(tmp_path / "none.mcap"), "--namespace", "nobody_here")
    try:
        warning = recorder.out.wait_for("warning: no writer matched", 30)
        assert "nobody_here" in warning
        # Ctrl-C, handed by the kernel to a thread that is not the main one (DDS's): the
        # main thread that waited for it still wakes to end the recording.
        to_another_thread(recorder.popen.pid, signal.SIGINT)
        assert recorder.wait(30) == 0
    finally:
        recorder.kill()


def test_a_servers_recording_holds_what_came_by_its_local_lane(tmp_path: Path) -> None:
    """`al5d send` reaches a server on this machine by its local lane, on no ROS topic: the
    server's recording holds it on the instruction topic all the same, once, and a replay
    reads it (an outside try: its bytes and its outcome were recorded, the instruction not,
    and a replay left it out without a word)."""
    config = load_config()
    served = tmp_path / "served.mcap"
    link = tmp_path / "board"
    emu = Emulator(config, link=link).start()
    server = Proc(
        "serve", "--port", str(link), "--config", patient_config(), "--record", str(served)
    )
    try:
        server.err.wait_for("STATE: ready", 30)
        for words in (["move", "base=30", "time=300"], ["park"]):
            send = Proc("send", *words)
            assert send.wait(60) == 0, send.err.drain(0.5)
        server.popen.send_signal(signal.SIGTERM)
        assert server.wait(30) == 0
    finally:
        server.kill()
        emu.close()
    _, by_topic = read_back(served)
    recorded = [d for _, d in by_topic["/al5d/instruction"]]
    assert [d.instruction for d in recorded] == ["move", "park"], recorded
    assert len({d.id for d in recorded}) == 2
    assert [r.fields.instruction for r in read_instructions(served)] == ["move", "park"]


def graph_seen(node: Node, pub: Any, names: Names) -> str:
    """What `reaches_server` judges by: the readers the graph lists, and how many matched."""
    readers = node.get_subscriptions_info_by_topic(names.instruction)
    listed = [f"{r.node_namespace.rstrip('/')}/{r.node_name}" for r in readers]
    return (
        f"readers listed {listed}, matched {pub.get_subscription_count()}, "
        f"server nodes {sorted(server_nodes(node, names))}"
    )


def test_a_servers_recording_holds_every_instruction_its_node_read(tmp_path: Path) -> None:
    """One-shot senders, each a participant of its own that publishes as soon as it has
    matched the server node's reader: the server answers each, and each is in its
    recording. A reader of the recording's own missed those sent before it had
    matched their writer (1 of 10 `al5d send --via ros` on a busy host), and a replay left
    out what the arm had obeyed."""
    served = tmp_path / "served.mcap"
    server = Proc("serve", "--config", patient_config(), "--record", str(served))
    peer = Peer(name="record_oneshot_peer")
    sent = [f"oneshot-{k}" for k in range(6)]
    try:
        server.err.wait_for("STATE: ready", 30)
        peer.wait_for_server()
        for ident in sent:
            context = start_context()
            node = Node("record_oneshot", context=context)
            try:
                pub = node.create_publisher(ArmInstruction, "/al5d/instruction", QOS_INSTRUCTIONS)
                # Any reader will not do: the stop process's is often matched first.
                wait_until(
                    lambda node=node, pub=pub: reaches_server(node, pub, Names()),
                    30,
                    "the server's reader",
                    lambda node=node, pub=pub: graph_seen(node, pub, Names()),
                )
                pub.publish(ArmInstruction(instruction="frobnicate", id=ident))
                assert pub.wait_for_all_acked(Duration(seconds=10))
            finally:
                node.destroy_node()
                context.try_shutdown()
        wait_until(lambda: all(i in peer.results_now() for i in sent), 30, "every answer")
        server.popen.send_signal(signal.SIGTERM)
        assert server.wait(30) == 0
    finally:
        peer.close()
        server.kill()
    _, by_topic = read_back(served)
    recorded = {d.id for _, d in by_topic["/al5d/instruction"]}
    assert set(sent) <= recorded, f"answered, not recorded: {sorted(set(sent) - recorded)}"
