"""The page's ROS side: a client node of the server, by the public names of one namespace
(and its STOP by the server's local lane too, where the server is on this machine).

It reads what any client may read and sends what any client may send; the server
does not know it is a web page. Nothing it does can hold the server up: the
joint states come best effort (a page that falls behind loses samples, it never
makes the server resend them), the instruction and trajectory topics are read
best effort too (to show the target of a move sent by anyone: a reliable reader
could hold up a sender's KEEP_ALL writer), and the server's writers of the state
and the results keep their last samples whatever a reader does.

The goals of the actions (al5d's Move, FollowJointTrajectory, GripperCommand)
are on no topic: the page shows no ghost for them, only their outcomes.
"""

from __future__ import annotations

import itertools
import logging
import os
import queue
import socket
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Protocol

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory

from al5d.arm.instruction import FRESH_MARK, Instruction, Kind, Outcome, Result, new_id
from al5d.model import ArmModel
from al5d.model.chain import BASE_LINK
from al5d.model.transforms import Transform
from al5d.owner import quick, where
from al5d.ros.convert import (
    COPY_MARK,
    from_message,
    outcome_from_message,
    to_message,
    trajectory_from_message,
)
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.leasing import Leaser, new_key
from al5d.ros.names import PING, Names
from al5d.ros.physical import PhysicalReader
from al5d.ros.qos import (
    QOS_COMMANDS,
    QOS_INSTRUCTIONS,
    QOS_LATCHED,
    QOS_LATEST,
    profile,
)
from al5d.ros.robot import QOS_TF_STATIC

#: Outcomes: reliable (a refusal's reason must reach the page) but shallow; the server's
#: writer keeps its own history and is never slowed by a reader's.
QOS_OUTCOMES = profile(100)

log = logging.getLogger("al5d.web")

#: How long a STOP by the local lane may take to be handed over (a socket whose owner has
#: not read its backlog), and how long its answer is waited for, in a thread of its own.
LANE_HAND_S = 0.05
LANE_STOP_S = 10.0
#: STOPs said unanswered that are kept for a late answer, at most (the newest).
LATE_KEPT = 64
#: A STOP on the topic (no lane of the server here) is sent again this often in its first
#: second, then every second, until a copy is answered or `LANE_STOP_S` has passed: a
#: server just found may not have matched this writer yet, and a lossy link loses copies.
STOP_FIRST_COPIES_S = 0.25
STOP_COPIES_S = 1.0
#: How long a RELEASE's answer is waited for before the page says none came.
RELEASE_ANSWER_S = 10.0


#: The state: latched as the server writes it, and every change kept until this page takes
#: it (a reader of depth 1 whose executor lagged a short move behind showed READY, READY:
#: the MOVING between them was overwritten before it was taken).
QOS_STATES = profile(20, latched=True)


#: What the page says of a STOP or a RELEASE sent, until its answer comes.
AWAITED = "sent, the server's answer awaited"


def _answered(what: str, result: object, reason: object) -> str:
    """`what`'s answer (its result and reason), as the page says it."""
    return f"{what}: {result or 'an answer with no result'}{f': {reason}' if reason else ''}"


class Listener(Protocol):
    """What the link hands over, in its executor's thread."""

    def on_description(self, urdf: str) -> None: ...

    def on_joints(self, names: Sequence[str], positions: Sequence[float], t: float) -> None: ...

    def on_state(self, state: str) -> None: ...

    def on_outcome(self, outcome: Outcome) -> None: ...

    def on_instruction(self, instr: Instruction) -> None: ...

    def on_mount(self, parent: str, mount: Transform) -> None: ...

    def on_physical(self, degrees: dict[str, float]) -> None: ...

    def on_answer(self, text: str, ok: bool | None) -> None:
        """What became of the page's last STOP or RELEASE: sent and its answer awaited
        (`ok` None), answered (whether done), or no answer in time (False). Called in a
        thread of the link's own, in order; never of a STOP or RELEASE older than the
        last."""


class WebNode:
    """The web process's node: subscriptions to the server's outputs, the instruction topic
    (the page's moves, STOP and RELEASE, each naming its lease), and its lease: a client
    of the server as the Python client is, whose moves the server halts once it has lost
    it (`al5d.ros.leasing`)."""

    def __init__(
        self,
        names: Names,
        listener: Listener,
        model: ArmModel,
        presets: tuple[str, ...],
        joint_prefix: str = "",
    ) -> None:
        self.names = names
        #: Before the URDF's joint names on the server's topics (`server.joint_prefix`).
        self.joint_prefix = joint_prefix
        self.listener = listener
        self.model = model
        self.presets = presets
        self.context = start_context()
        self.node = node = Node(
            f"al5d_web_{os.getpid()}", namespace=names.node_namespace, context=self.context
        )
        self.pub = node.create_publisher(ArmInstruction, names.instruction, QOS_INSTRUCTIONS)
        # The lease on a node of its own, which its own thread spins: this node's callbacks
        # wait for the page's lock, and a lease that waited with them would be held back
        # for a silence of the server that is the page's.
        self.lease_node = Node(
            f"al5d_web_lease_{os.getpid()}", namespace=names.node_namespace, context=self.context
        )
        #: Named in what the page sends, and sent while the page hears the server.
        self.lease = Leaser(self.lease_node, names, new_key("web-"))
        # rclpy's Python executor: two of its events executors in one process are what
        # `al5d_rig.rospeer.Peer` saw crash.
        self.lease_spinner = Spinner(
            self.lease_node, self.context, owns_context=False, kind="single"
        )
        #: The STOPs on the topic still sent again: each one's id, what its answer sets and
        #: its number (`_begin`).
        self._stops: dict[str, tuple[threading.Event, int]] = {}
        #: The STOPs said unanswered (by the lane or on the topic), with their numbers: an
        #: answer that comes on the result topic later (a server that stalled past
        #: `LANE_STOP_S` obeyed them after) is said then. Held with `_late_lock` while an
        #: answer is matched, or a STOP said unanswered, so that neither is said after the other.
        self._late: dict[str, int] = {}
        self._late_lock = threading.Lock()
        #: Held while a copy of a STOP or a RELEASE is published: no copy follows a release.
        self._sending = threading.Lock()
        #: The RELEASEs whose answers are awaited, with their numbers; each one's popped
        #: once: by its answer or by its timer (`RELEASE_ANSWER_S`).
        self._releases: dict[str, tuple[threading.Timer, int]] = {}
        # What the page says of its STOPs and RELEASEs goes through a queue to a thread of
        # its own: a STOP hands it over and waits for nothing (the page's widgets take
        # viser's locks), and it is said in the order it was handed over, of the newest
        # STOP or RELEASE only (an old one's late answer would hide the newer's).
        self._numbers = itertools.count(1)
        self._newest = 0
        self._numbering = threading.Lock()  # held for a number and its assignment alone
        self._answers: queue.SimpleQueue[tuple[int, str, bool | None] | None] = queue.SimpleQueue()
        threading.Thread(target=self._say_answers, name="al5d-web-answers", daemon=True).start()
        #: The ids of this page's set-points start with it.
        self.jog_prefix = f"web-jog-{os.getpid():x}-"
        self._jog_ids = itertools.count(1)
        # Readers of the jog ever matched and ever gone (the matched event's counts), and
        # both when the page last lost the server (`server_lost`).
        self._jog_seen = self._jog_mark = (0, 0)
        self.jog_pub = node.create_publisher(
            JointState,
            names.joint_commands,
            QOS_COMMANDS,
            event_callbacks=PublisherEventCallbacks(matched=self._on_jog_matched),
        )
        node.create_subscription(String, names.robot_description, self._on_description, QOS_LATCHED)
        node.create_subscription(JointState, names.joint_states, self._on_joints, QOS_LATEST)
        node.create_subscription(String, names.state, self._on_state, QOS_STATES)
        node.create_subscription(InstructionResult, names.result, self._on_result, QOS_OUTCOMES)
        node.create_subscription(
            ArmInstruction, names.instruction, self._on_instruction, QOS_LATEST
        )
        node.create_subscription(JointTrajectory, names.trajectory, self._on_trajectory, QOS_LATEST)
        node.create_subscription(TFMessage, "/tf_static", self._on_static, QOS_TF_STATIC)
        # Where an emulated arm truly stands, if one says (`al5d emulator --misalign`).
        PhysicalReader(node, names, model, listener.on_physical)
        #: The local lane of a server of these names on this machine, where the STOP goes
        #: first (no discovery: `al5d.owner.quick`), if a server is there.
        self.lane = where.path(names.namespace)
        self.spinner = Spinner(node, self.context)

    # -- from the server ------------------------------------------------------------

    def _on_description(self, msg: String) -> None:
        self.listener.on_description(str(msg.data))

    def _on_joints(self, msg: JointState) -> None:
        prefix = len(self.joint_prefix)
        names = [n[prefix:] if n.startswith(self.joint_prefix) else n for n in msg.name]
        self.listener.on_joints(names, list(msg.position), time.monotonic())

    def _on_state(self, msg: String) -> None:
        self.listener.on_state(str(msg.data))

    def _on_result(self, msg: InstructionResult) -> None:
        if msg.instruction == PING:  # a client's handshake: no news of the arm
            return
        try:
            outcome = outcome_from_message(msg)
        except ValueError:  # an outcome word this page does not know: not the server's
            return
        stop, mark, _ = outcome.id.partition(COPY_MARK)
        done = outcome.result is Result.DONE
        with self._late_lock:
            stopping = self._stops.pop(stop, None) if mark else None
            late = self._late.pop(stop if mark else outcome.id, None)
            if stopping is not None:
                answered, number = stopping
                answered.set()
                log.info("web: STOP on the topic: %s", outcome.reason or outcome.result.value)
                self._say(number, _answered("STOP", outcome.result.value, outcome.reason), done)
            elif late is not None:
                log.info("web: STOP %s answered late: %s", stop, outcome.result.value)
                self._say(late, _answered("STOP", outcome.result.value, outcome.reason), done)
        releasing = self._releases.pop(outcome.id, None)
        if releasing is not None:
            timer, number = releasing
            timer.cancel()
            self._say(number, _answered("RELEASE", outcome.result.value, outcome.reason), done)
        self.listener.on_outcome(outcome)

    def _on_instruction(self, msg: ArmInstruction) -> None:
        instr = from_message(msg, self.presets, self.model)
        if not isinstance(instr, str):  # the server refuses it; its outcome will say why
            self.listener.on_instruction(instr)

    def _on_static(self, msg: TFMessage) -> None:
        """The arm's mount: base_link in a frame shared with other arms (`server.mount`)."""
        base = self.names.frame_prefix + BASE_LINK
        for t in msg.transforms:
            if t.child_frame_id == base:
                p, q = t.transform.translation, t.transform.rotation
                mount = Transform((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))
                self.listener.on_mount(str(t.header.frame_id), mount)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        instr = trajectory_from_message(msg, self.model, prefix=self.joint_prefix)
        if not isinstance(instr, str):
            self.listener.on_instruction(instr)

    # -- to the server ---------------------------------------------------------------

    def send(self, instr: Instruction) -> None:
        msg = to_message(instr)
        msg.client = self.lease.key
        self.pub.publish(msg)

    def jog(self, degrees: Mapping[str, float]) -> bool:
        """A set-point of the jog (the arm's degrees) on the server's stream of set-points,
        in the URDF's values as ros2_control's hardware sends them. False when no server
        reads the stream yet: a server just (re)started can send its joint states to this
        page before DDS has matched this writer to its reader, and the set-point is lost.
        After the page lost the server, a reader counts once one has matched or gone since:
        a killed server's reader stays matched until DDS notices it has gone (its lease,
        seconds), and a set-point sent to it alone reaches nobody; the new server's may have
        matched before the page noticed the loss (a busy host), and then counts once the
        killed one's has gone."""
        values = self.model.to_urdf(dict(degrees))
        msg = JointState(position=[float(v) for v in values.values()])
        msg.name = [self.joint_prefix + n for n in values]
        msg.header.stamp = self.node.get_clock().now().to_msg()
        # The set-point's id on the result topic (`convert.trajectory_id`): the page knows
        # its own jog's refusals by it. Marked new since any stop (the page lets its jog go
        # at one; a hand on a slider sent this), so that it resumes the server's stream of
        # set-points, held since a stop (`FRESH_MARK`; a set-point where the arm stands
        # would do too, but the newest set-point of the stream overwrites it, unread, on
        # a busy host: a CI run).
        msg.header.frame_id = f"{self.jog_prefix}{next(self._jog_ids)}{FRESH_MARK}"
        self.jog_pub.publish(msg)
        (matched, gone), (matched_then, gone_then) = self._jog_seen, self._jog_mark
        changed = matched > matched_then or gone > gone_then
        return self.jog_pub.get_subscription_count() > 0 and changed

    def server_lost(self) -> None:
        self._jog_mark = self._jog_seen

    def _on_jog_matched(self, info: QoSPublisherMatchedInfo) -> None:
        # One assignment: `jog`, on another thread, reads both counts of one event.
        self._jog_seen = (info.total_count, info.total_count - info.current_count)

    def stop(self) -> str:
        """The emergency stop: by the local lane where a server's is on this machine (no
        discovery, no DDS: the owner has it as the socket is read), else on the instruction
        topic, where the server's stop watcher obeys it at once. Only one way: a copy that
        came by the other after a release would lock the arm again (seen in a CI run: a
        STOPPED after the release). For the same reason there is no stop service call here
        (`std_srvs/Trigger` names no stop: the server cannot know it for this one): the
        copies sent again on the topic until one is answered name this page's lease and
        one stop (`<stop>~<n>`, `al5d.ros.convert.stop_key`), which the server obeys once,
        however many of them come, and before or after whichever release. Returns which
        way it went."""
        by_lane = f"web-stop-{new_id()}"
        try:
            # Handed over here (a Unix socket takes it at once); only its answer is waited
            # for, in a thread of its own.
            sock = quick.hand_stop(self.lane, by_lane, LANE_HAND_S)
        except OSError as e:
            log.warning("web: STOP by the local lane %s failed: %s", self.lane, e)
            sock = None
        number = self._begin()
        if sock is not None:
            self._say(number, f"STOP by the local lane: {AWAITED}", None)
            threading.Thread(
                target=self._lane_answer, args=(sock, by_lane, number), daemon=True
            ).start()
            return "the local lane"
        stop, answered = f"web-stop-{new_id()}", threading.Event()
        self._stops[stop] = answered, number
        # Handed over before the first copy goes, so that it is never said after the answer.
        self._say(number, f"STOP on the topic: {AWAITED} (sent again until it comes)", None)
        self._stop_copy(stop, 1)  # the first at once, in the click's own thread
        # Then the thread of the copies after it (starting one waits for it to run).
        threading.Thread(
            target=self._stop_again, args=(stop, answered, number), name=stop, daemon=True
        ).start()
        return "the topic"

    def _begin(self) -> int:
        """A new STOP or RELEASE: its number; what is said of those before it is not."""
        with self._numbering:
            number = self._newest = next(self._numbers)
        return number

    def _say(self, number: int, text: str, ok: bool | None) -> None:
        """Hand over what to say of the STOP or RELEASE `number` (a queue's put: no wait)."""
        self._answers.put((number, text, ok))

    def _say_answers(self) -> None:
        while (item := self._answers.get()) is not None:
            number, text, ok = item
            if number == self._newest:
                try:
                    self.listener.on_answer(text, ok)
                except Exception:  # the next one is said all the same
                    log.exception("web: %s: not shown", text)

    def _stop_copy(self, stop: str, n: int) -> bool:
        """Copy `n` of `stop`, unless it has ended (answered, or a release sent since);
        whether it went."""
        msg = to_message(Instruction(Kind.STOP, id=f"{stop}{COPY_MARK}{n}"))
        msg.client = self.lease.key  # no deadline: a stop is obeyed however late
        with self._sending:
            if stop not in self._stops:
                return False
            self.pub.publish(msg)
        return True

    def _stop_again(self, stop: str, answered: threading.Event, number: int) -> None:
        """The copies of `stop` after the first, until one is answered, a release is sent,
        or `LANE_STOP_S` has passed."""
        start = time.monotonic()
        n = 1
        while True:
            elapsed = time.monotonic() - start
            every = STOP_FIRST_COPIES_S if elapsed < 1.0 else STOP_COPIES_S
            if answered.wait(every) or time.monotonic() - start >= LANE_STOP_S:
                break
            n += 1
            try:
                if not self._stop_copy(stop, n):
                    break
            except Exception:  # the next copy may go: only the context's end stops them
                log.exception("web: STOP on the topic: copy %d not sent", n)
        with self._late_lock:
            ended = self._stops.pop(stop, None) is not None
            if not ended or answered.is_set():
                return
            self._unanswered(
                stop,
                number,
                f"STOP on the topic: no answer in {LANE_STOP_S:g} s (sent {n} times): "
                "whether the arm has stopped is unknown",
            )

    def _unanswered(self, stop: str, number: int, text: str) -> None:
        """The STOP `stop` (number `number`) said unanswered, with `text`; its answer, if
        one comes later, said then (under `_late_lock`)."""
        log.warning("web: %s", text)
        self._late[stop] = number
        while len(self._late) > LATE_KEPT:
            del self._late[next(iter(self._late))]
        self._say(number, text, False)

    def _lane_answer(self, sock: socket.socket, stop: str, number: int) -> None:
        try:
            answer = quick.answer(sock, LANE_STOP_S)
        except (OSError, EOFError) as e:
            with self._late_lock:
                self._unanswered(
                    stop,
                    number,
                    f"STOP by the local lane: no answer ({e}): whether the arm has stopped is "
                    "unknown",
                )
            return
        log.info("web: STOP by the local lane: %s", answer.get("result"))
        result = answer.get("result")
        self._say(
            number, _answered("STOP", result, answer.get("reason")), result == Result.DONE.value
        )

    def release(self) -> None:
        """On the topic with the page's lease, as the Python client's: judged on the server's
        clock, and after the page's own stops, which went before it on the same writer (the
        release service takes no lease, and is judged on its sender's clock). A STOP still
        sent again is not sent after it: a copy sent after the release, which the stop
        watcher may read before the node has read an earlier one (a lossy link), would be
        a stop sent after the release, and lock the arm again."""
        release, number = Instruction(Kind.RELEASE), self._begin()
        # Out of the lock a STOP's copy takes: starting a timer waits for its thread to run.
        timer = threading.Timer(RELEASE_ANSWER_S, self._release_unanswered, (release.id,))
        timer.daemon = True
        self._releases[release.id] = timer, number
        self._say(number, f"RELEASE on the topic: {AWAITED}", None)
        timer.start()
        try:
            with self._sending:
                for stop in list(self._stops):
                    unanswered = self._stops.pop(stop, None)
                    if unanswered is not None:
                        log.info("web: STOP on the topic: no more copies (a release was sent)")
                        unanswered[0].set()
                self.send(release)
        except Exception as e:
            if self._releases.pop(release.id, None) is not None:
                timer.cancel()
                self._say(number, f"RELEASE: not sent ({e})", False)
            raise

    def _release_unanswered(self, ident: str) -> None:
        releasing = self._releases.pop(ident, None)
        if releasing is not None:
            log.warning("web: RELEASE on the topic: no answer in %g s", RELEASE_ANSWER_S)
            self._say(
                releasing[1],
                f"RELEASE on the topic: no answer in {RELEASE_ANSWER_S:g} s: whether the arm "
                "was released is unknown (its state shows it)",
                False,
            )

    def close(self) -> None:
        for timer, _ in list(self._releases.values()):
            timer.cancel()
        self._answers.put(None)
        self.lease.close([self.pub])
        self.lease_spinner.close()
        self.spinner.close()
