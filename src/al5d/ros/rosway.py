"""A client's way to a server over ROS 2: its node, the instruction topic and the outcomes
on the result topic, its lease, the server's silence, the stop and the release on the
topic (the stop's copies: `al5d.ros.rosstop`) and the shutdown by its service
(`al5d.ros.client.Client` takes this way where no lane of the server is on this machine).

Only `al5d.ros.client` imports this module, once the ROS 2 way is taken: a client of a
local server starts without rclpy and the messages (about half a second less).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from al5d_interfaces.msg import ArmInstruction, InstructionResult
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Trigger

from al5d.arm.instruction import SAFETY, Instruction, Kind, Outcome, new_id
from al5d.clock import Deadline
from al5d.interrupts import ctrl_c_after
from al5d.ros.answers import (
    ANSWER_S,
    GIVE_UP_WORD_S,
    SILENCE_SAID_S,
    Answer,
    LostContact,
    NoOutcome,
    NoServer,
    NotSent,
    elsewhere,
    no_outcome,
    others,
    wait_ms,
)
from al5d.ros.convert import outcome_from_message, to_message
from al5d.ros.dds import start_context
from al5d.ros.executors import Spinner
from al5d.ros.leasing import LEASE_EVERY_S, LOST_AFTER_LEASE_S, Leaser, new_key, said_lease
from al5d.ros.names import PING, Names, reaches_server, server_nodes
from al5d.ros.qos import QOS_INSTRUCTIONS, QOS_LATCHED, QOS_SAFETY, QOS_SERVICES, QOS_STREAM
from al5d.ros.reading import ArmView, follow_ros
from al5d.ros.rosstop import StopCall
from al5d.ros.workarounds import PublishFailed

if TYPE_CHECKING:
    from al5d.arm.config import ArmConfig

log = logging.getLogger("al5d")

#: The handshake's ping (`al5d.ros.names.PING`) is sent again this often until one is
#: answered: a ping the server answered before its result writer had matched our reader
#: reached nobody.
PING_EVERY_S = 0.25
#: How long the shutdown service may stay undiscovered once the server's topics are: after
#: that the shutdown goes on the instruction topic instead (and says so). The services are
#: on the stop path's DDS participant, discovered apart from the topics': beside two busy
#: loops once more than 2 s after them. (A stop waits for nothing: `rosstop.StopCall`.)
SERVICE_GRACE_S = 5.0
#: A shutdown waits this long after its service is found: rmw_fastrtps drops an answer
#: whose client it has not matched 100 ms after the request (ros2/rmw_fastrtps#390), which
#: on a loaded machine can befall a new client's first call.
SERVICE_SETTLE_S = 0.5
#: A client that has not found its server in this long names the servers it sees under other
#: namespaces at once (a WARNING), before it gives up.
OTHERS_SAID_AFTER_S = 1.0
#: A client takes the server for lost when it has heard nothing from it (its joint states,
#: 10 a second when idle) for the server's lease (`server.client_lease_s`, 1 s until the
#: client has heard the server's configuration) and `LOST_AFTER_LEASE_S` more
#: (`al5d.ros.leasing`): by then the server has halted what this client commanded.
LOST_S = 1.0 + LOST_AFTER_LEASE_S


def silence_warning(quiet: float, lost_after: float) -> str | None:
    """What a client waiting for the server says (once an outage, as a WARNING) when the
    server has been silent for `quiet` s and is taken for lost after `lost_after` s; None
    while the silence is short (`SILENCE_SAID_S`, or the lease's margin if shorter).

    Said also when the first look comes after `lost_after`: a thread that a loaded host
    held back past the whole window would otherwise give up without the warning."""
    said_after = min(SILENCE_SAID_S, lost_after - LOST_AFTER_LEASE_S)  # a short lease
    if quiet <= said_after:
        return None
    left = lost_after - quiet
    when = (
        f"in {left:.1f} s, once the server has halted what it commanded"
        if left > 0
        else "now: the server has halted what it commanded"
    )
    return (
        f"no sign of the server for {quiet:.1f} s: the link may be lost; this client gives "
        f"up on what it waits for {when}"
    )


class RosWay:
    """A client's node on the server's topics and services in `names`; `wait_s`: how long
    its first use waits for the server. What `al5d.ros.client.Client` asks of its way."""

    def __init__(self, names: Names, wait_s: float) -> None:
        self.names = names
        self.wait_s = wait_s
        self.via = "ROS 2"
        #: Seconds spent waiting for the server (its topics or services) to be discovered.
        self.discovery_s = 0.0
        #: Whether a ping of ours has been answered (`wait_for_server`).
        self.matched = False
        self._config: ArmConfig | None = None
        self.context = start_context()
        try:
            self.node = Node(
                f"al5d_client_{os.getpid()}", namespace=names.node_namespace, context=self.context
            )
        except BaseException:
            self.context.try_shutdown()
            raise
        self.pub = self.node.create_publisher(ArmInstruction, names.instruction, QOS_INSTRUCTIONS)
        #: Readers of our stops ever matched (the matched event's total): a stop is sent
        #: again the moment a new one matches (`al5d.ros.rosstop.StopCall`).
        self._readers_matched = 0
        #: The stop's copies, the release and the shutdown (where its service is not
        #: found), on a writer of their own (`QOS_SAFETY`): a flood of moves never holds
        #: them, and a release comes after this client's stops, in order.
        self.safety_pub = self.node.create_publisher(
            ArmInstruction,
            names.instruction,
            QOS_SAFETY,
            event_callbacks=PublisherEventCallbacks(matched=self._on_readers_matched),
        )
        self.results = self.node.create_subscription(
            InstructionResult, names.result, self._on_result, QOS_STREAM
        )
        #: This client's lease (`al5d.ros.leases`), named in what it sends.
        self.lease = Leaser(self.node, names, new_key())
        #: The server's configuration as it says it on its latched topic, heard from the
        #: start: its lease of this client is known before the first silence, whether or
        #: not the configuration is ever asked for (`al5d send` never does: with a 60 s
        #: lease it gave up after 1.5 s, saying the server had halted what it commanded).
        self._said: str | None = None
        self._said_lease_s: float | None = None
        self._config_came = threading.Event()
        self.node.create_subscription(String, names.config, self._on_config, QOS_LATCHED)
        self.key = self.lease.key
        #: The last sign of the server whose silence has been said (once an outage), until
        #: it is heard again (`_over`).
        self._silence_said: float | None = None
        self._said_lock = threading.Lock()  # the command's thread and `LinkWatch`'s look
        #: The shutdown's service (a stop and a release go on the topic: `StopCall`,
        #: `_release`).
        self._services: dict[Kind, tuple[str, Any]] = {
            kind: (name, self.node.create_client(Trigger, name, qos_profile=QOS_SERVICES))
            for name, kind in names.services.items()
            if kind is Kind.SHUTDOWN
        }
        #: Only the outcomes of what this client sent are kept: every client's come by.
        self._sent: set[str] = set()
        self._outcomes: dict[str, Outcome] = {}
        self._watchers: dict[str, Callable[[Outcome], None]] = {}
        self._cv = threading.Condition()
        #: Each service once found, and when its first call may go (`SERVICE_SETTLE_S`).
        self._settled: dict[Kind, Deadline] = {}
        # rclpy's Python executor: its events executor is now and then told of one message
        # too few, and the last one waits for the next; here that would be an outcome, or a
        # service's answer, waited for until the timeout (and the test peer's spin thread
        # crashed with it: `al5d_rig.rospeer.Peer`).
        self.spinner = Spinner(self.node, self.context, kind="single")

    # -- the lease and the server's silence --------------------------------------------

    def _on_readers_matched(self, info: Any) -> None:
        self._readers_matched = info.total_count

    def lost_contact(self) -> float | None:
        """Once the server has been heard: for how long it has not been, if more than
        `lost_after_s` (None: not lost). The silence is said once, as a WARNING, before that
        is returned (`silence_warning`), and so is its end (`_over`)."""
        lost_after = self.lost_after_s
        self.lease.say_held(lost_after - LOST_AFTER_LEASE_S)
        # Under the lock: a look that read the silence before another said it over would
        # say it again.
        with self._said_lock:
            since = self.lease.silent_since()
            if since is None:
                return None
            quiet = time.monotonic() - since
            over = self._over(lost_after)
            warning = silence_warning(quiet, lost_after) if self._silence_said != since else None
            if warning:
                self._silence_said = since
        if over:
            log.warning("%s", over)
        if warning:
            log.warning("%s", warning)
        return quiet if quiet > lost_after else None

    def _over(self, lost_after: float) -> str | None:
        """The silence said over, the server heard since: what to say of it (with a 60 s
        lease the warning stood alone until the outcome, a minute later), None where there
        is nothing to say: no silence said, or one that lasted past `lost_after`, taken for
        lost, whose end the command says (`al5d.app.report.LinkWatch`)."""
        said, heard = self._silence_said, self.lease.heard
        if said is None or heard is None or heard <= said:
            return None
        self._silence_said = None
        back = self.lease.back
        ended = back[1] if back is not None and back[0] <= said < back[1] else heard
        if ended - said > lost_after:
            return None
        return f"the server is heard again, after {ended - said:.1f} s of silence"

    def _silence_over(self) -> None:
        """A wait has ended with its outcome, a sign of the server: a silence said is over,
        and what follows it says so (no word of it later, under another line)."""
        with self._said_lock:
            self._silence_said = None

    def out_of_contact(self) -> str | None:
        quiet = self.lost_contact()
        if quiet is None:
            return None
        return f"lost contact with the server (nothing heard from it for {quiet:.1f} s)"

    @property
    def lost_after_s(self) -> float:
        """How long the server may go unheard before this client takes it for lost: the
        server's lease of this client and `LOST_AFTER_LEASE_S` (`LOST_S` until the server's
        configuration is heard), so that the server has halted what this client commanded
        before the client gives up on it."""
        # What the server said first: a configuration judged by the shipped one (none
        # said in time) must not hide a lease said later.
        if self._said_lease_s is not None:
            return self._said_lease_s + LOST_AFTER_LEASE_S
        if self._config is not None:
            return self._config.server.client_lease_s + LOST_AFTER_LEASE_S
        return LOST_S

    def _on_config(self, msg: String) -> None:
        self._said = msg.data
        # Only the lease here, in the executor's thread: the whole configuration is
        # validated when it is asked for (`config`).
        self._said_lease_s = said_lease(msg.data)
        self._config_came.set()

    def _lost(self, what: str, sent: bool = True) -> LostContact:
        quiet = self.lost_contact() or self.lost_after_s
        # One not sent is known not to run (an outside try: "not sent: ... whether it ran
        # is unknown").
        unknown = "; whether it ran is unknown" if sent else ""
        return LostContact(
            f"{what}: lost contact with the server (nothing heard from it for {quiet:.1f} s"
            f"{unknown}): once this client's lease runs out the server halts what it "
            "commanded, and never runs what it sent meanwhile"
        )

    # -- finding the server ------------------------------------------------------------

    def server_seen(self) -> bool:
        """Our writer of instructions has matched every reader of them that discovery lists,
        the server's node's among them, and our reader of results a writer of them.

        A server has more than one reader of instructions (its stop watcher's, best effort):
        one matched is not enough. An instruction published before our writer has matched
        the node's reader never reaches it (seen: 2 `al5d run`s in 30 on a loaded machine
        waited for ever for their first outcome, the server never told of it). The node is
        the one that both reads instructions and publishes results, whatever its name: `-r
        __node:=left_arm` renames it (looked for as `al5d`, no client over ROS found it)."""
        return (
            reaches_server(self.node, self.pub, self.names)
            and self.results.get_publisher_count() > 0
        )

    def no_server(self, name: str, timeout: float, seen: str = "") -> NoServer:
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        # A server seen that did not answer is no server absent, nor closed to the network
        # (an outside try, at 20 % loss: "is 'al5d serve' running?" of a server it reached).
        why = (
            ": something of it was found, but no answer came: a slow or lossy link, or its "
            "side has not found this client yet"
            if seen and server_nodes(self.node, self.names)
            else elsewhere(self.names, self.node)
        )
        return NoServer(
            f"no al5d server answers on {name} (ROS_DOMAIN_ID={domain}) "
            f"within {timeout:g} s{seen}{why}"
        )

    def others(self) -> str:
        """The servers seen under other namespaces (`al5d.ros.answers.others`)."""
        return others(self.names, self.node)

    def _found(self, pings: int) -> str:
        """What of a server this client found, where it found something (a server that
        runs, seen but not matched, is not one that is absent): its node, the readers of
        the instructions that the graph lists and how many of them ours reached, the
        writers of results ours heard, and the pings unanswered."""
        readers = self.node.get_subscriptions_info_by_topic(self.names.instruction)
        if not readers:
            return ""
        nodes = sorted(server_nodes(self.node, self.names))
        listed = ", ".join(sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in readers))
        return (
            f" (found: {'the server node ' + ', '.join(nodes) if nodes else 'no server node'}; "
            "this client's "
            f"instructions reach {self.pub.get_subscription_count()} of the "
            f"{len(readers)} readers listed ({listed}); its results come from "
            f"{self.results.get_publisher_count()} writer(s); {pings} ping(s) unanswered)"
        )

    def wait_for_server(self, timeout: float) -> None:
        """Until our instructions reach a server and its results reach us: a ping of ours
        answered. Each side of a topic matches the other when it hears of it, apart: our
        reader can have matched the server's result writer long before that writer has
        matched our reader, and a result published meanwhile reaches nobody (seen on a
        loaded host: discovery took 9.6 s, then an outcome waited for 80 s and more)."""
        deadline = Deadline(timeout)
        start = time.monotonic()
        pings: list[str] = []
        next_ping = 0.0
        warned = False
        try:
            while not deadline.expired:
                with self._cv:
                    if any(p in self._outcomes for p in pings):
                        self.matched = True
                        return
                if self.server_seen():
                    if time.monotonic() >= next_ping:
                        pings.append(self._ping())
                        next_ping = time.monotonic() + PING_EVERY_S
                elif not warned and time.monotonic() - start >= OTHERS_SAID_AFTER_S:
                    warned = True
                    self._say_others(timeout)
                time.sleep(0.02)
            raise self.no_server(self.names.instruction, timeout, self._found(len(pings)))
        finally:
            self.discovery_s += time.monotonic() - start
            with self._cv:  # an answer that comes later is not kept
                for ping in pings:
                    self._sent.discard(ping)
                    self._outcomes.pop(ping, None)

    def _say_others(self, timeout: float) -> None:
        """Servers under other namespaces said at once (a WARNING), where this client's is
        not found yet: a command meant for another arm need not wait out `timeout` to
        learn so (discovery over a network takes seconds: nothing is said without them)."""
        seen = self.others()
        if seen:
            log.warning(
                "no al5d server found at %s yet (still looking, up to %g s)%s",
                self.names.instruction,
                timeout,
                seen,
            )

    def _ping(self) -> str:
        """Send a ping; its id."""
        msg = ArmInstruction(instruction=PING, id=new_id())
        with self._cv:
            self._sent.add(msg.id)
        self.pub.publish(msg)
        return str(msg.id)

    # -- instructions and their outcomes -----------------------------------------------

    def send(self, instr: Instruction, wait_s: float) -> None:
        """Publish `instr` with this client's lease and `wait_s` (the server refuses it as
        stale if it comes later), once the server is found (`NoServer` if it is not within
        `self.wait_s`: one published before then reaches no server, or only its stop
        watcher, and was lost without a word). `LostContact` while the server is out of contact,
        `NotSent` while its writer is full of what the server has not acknowledged."""
        if not self.matched:
            self.wait_for_server(self.wait_s)
        if self.lost_contact() is not None:
            raise self._lost(f"{instr.name} [{instr.id}]: not sent", sent=False)
        msg = to_message(instr)
        msg.client = self.key
        msg.wait_ms = wait_ms(wait_s)
        with ctrl_c_after():
            with self._cv:
                self._sent.add(instr.id)
            try:
                (self.safety_pub if instr.kind in SAFETY else self.pub).publish(msg)
            except PublishFailed as e:  # its writer is full of what the server has not taken
                with self._cv:
                    self._sent.discard(instr.id)
                raise NotSent(
                    f"{instr.name} [{instr.id}]: not sent: the server has not acknowledged "
                    f"what this client sent before it ({e}); wait for outcomes before "
                    "sending more"
                ) from None

    def _on_result(self, msg: InstructionResult) -> None:
        self.lease.sign()
        with self._cv:
            if msg.id not in self._sent and msg.id not in self._watchers:
                return
            outcome = outcome_from_message(msg)
            self._outcomes[msg.id] = outcome
            watcher = self._watchers.pop(msg.id, None)
            self._cv.notify_all()
        if watcher is not None:
            watcher(outcome)

    def watch(self, ident: str, watcher: Callable[[Outcome], None]) -> None:
        with self._cv:
            outcome = self._outcomes.get(ident)
            if outcome is None:
                self._watchers[ident] = watcher
        if outcome is not None:
            watcher(outcome)

    def outcome(self, ident: str, timeout: float) -> Outcome | None:
        if not self.sent(ident):
            return None
        deadline = Deadline(timeout)
        with self._cv:
            while ident not in self._outcomes:
                if deadline.expired:
                    return None
                if self.lost_contact() is not None:
                    raise self._lost(f"[{ident}]")
                asked, within = time.monotonic(), min(deadline.left(), LEASE_EVERY_S)
                self._cv.wait(within)
                self.lease.woke(asked, within)
                self.lease.say_held(self.lost_after_s - LOST_AFTER_LEASE_S)
            self._silence_over()
            return self._outcomes[ident]

    def forget(self, ident: str) -> None:
        with self._cv:
            self._sent.discard(ident)
            self._outcomes.pop(ident, None)

    def sent(self, ident: str) -> bool:
        with self._cv:
            return ident in self._sent or ident in self._outcomes

    def pending(self) -> list[str]:
        return []  # not known over ROS 2: an outcome comes only to those who wait for it

    def cancel(self, ident: str, reason: str) -> bool:
        return False  # ROS 2 has no cancel by id: the stop is the way there

    def execute(self, instr: Instruction, timeout: float) -> Outcome:
        """Send `instr` (once the server is found: `NoServer` if it is not within `wait_s`);
        its outcome, the server's cancel once `timeout` s have passed (`Client.execute`).
        `NoOutcome` if none comes (`LostContact`: the server went out of contact first)."""
        self.send(instr, timeout)
        # The server gives up on a move with its sender, and says so: listened for a while
        # more. A release or a shutdown (sent here where their service is missing) it obeys.
        safety = instr.kind in SAFETY
        try:
            outcome = self.outcome(instr.id, timeout + (0.0 if safety else GIVE_UP_WORD_S))
        except LostContact:
            self.forget(instr.id)
            raise self._lost(f"{instr.name} [{instr.id}]") from None
        # Kept on Ctrl-C (KeyboardInterrupt), which cancels what is pending.
        self.forget(instr.id)
        if outcome is None and safety:
            # Its answer may be what was lost (an outside try at 20 % loss: a release said
            # "no outcome" had unlocked the arm 2.4 s before): said to be unknown.
            raise NoOutcome(
                f"{instr.name} [{instr.id}]: no outcome within {timeout:g} s (whether the "
                "server obeyed it is unknown: its answer may have been lost)"
            )
        if outcome is None:
            raise no_outcome(f"{instr.name} [{instr.id}]", timeout)
        return outcome

    # -- what the client hears of the arm ----------------------------------------------

    def config(self) -> ArmConfig:
        """The server's latched `al5d/config` (the parameters' values at its start
        included), read once (`al5d.ros.client.Client.config`)."""
        if self._config is None:
            self._config = self._served_config()
        return self._config

    def _served_config(self) -> ArmConfig:
        """Raises ConfigError if what the server says is no configuration this version
        reads."""
        from al5d.arm.config import load_config, parse_config

        if not self.matched:
            self.wait_for_server(self.wait_s)
        if not self._config_came.wait(ANSWER_S) or self._said is None:
            log.warning("the server did not say its configuration: judged by the shipped one")
            return load_config(None)
        return parse_config(json.loads(self._said), "the server's configuration")

    def view(self) -> ArmView:
        """The arm as the server's state and joint states say it, in its configuration's
        model."""
        config = self.config()
        prefix = config.server.joint_prefix_in(self.names.namespace)
        view = ArmView(config.model)
        follow_ros(self.node, self.names, prefix, view)
        return view

    # -- the stop, the release and the shutdown ----------------------------------------

    def ask(self, kind: Kind, timeout: float) -> Answer:
        """The stop (`al5d.ros.rosstop.StopCall`) and the release (`_release`) on the
        instruction topic, the shutdown by its service (the topic instead if the server is
        there but its service is not: `SERVICE_GRACE_S`)."""
        if kind is Kind.STOP:
            return StopCall(self, timeout).run()
        if kind is Kind.RELEASE:
            return self._release(timeout)
        name, service = self._services[kind]
        if not self._find_service(kind, name, service):
            log.warning(
                "%s: the service %s is not available; sent on the topic %s instead",
                kind.value,
                name,
                self.names.instruction,
            )
            outcome = self.execute(Instruction(kind), timeout)
            message = outcome.reason or f"{kind.value}: {outcome.result.value}"
            return Answer(
                kind.value, outcome.ok, message, self.names.instruction, False, outcome.id
            )
        # The server matches our reader of its answers a moment after we match its
        # service; an answer it cannot deliver 100 ms on is dropped (`SERVICE_SETTLE_S`).
        time.sleep(self._settled[kind].left())
        response = self._call(service, timeout)
        if response is None:
            raise NoOutcome(
                f"{kind.value}: no answer from {name} within {timeout:g} s "
                "(whether the server obeyed is unknown)"
            )
        return Answer(kind.value, bool(response.success), str(response.message), name)

    def _release(self, timeout: float) -> Answer:
        """The release on the instruction topic, with this client's lease. Not by the release
        service: a service request names no client, so the server could only take its time
        of sending on this machine's clock, seconds off on another machine; a request on
        the topic names its client, whose clock the server knows from its leases
        (`al5d.ros.leases`). On the writer of this client's stops, after them in order (a
        copy that the stop watcher, reading best effort, takes after the release is that
        stop, obeyed already: `al5d.ros.rosstop`)."""
        outcome = self.execute(Instruction(Kind.RELEASE), timeout)
        message = outcome.reason or f"release: {outcome.result.value}"
        return Answer("release", outcome.ok, message, self.names.instruction, False, outcome.id)

    @property
    def topic(self) -> str:
        return self.names.instruction

    @property
    def readers_matched(self) -> int:
        return self._readers_matched

    def send_copy(self, ident: str, heard: Callable[[Outcome], None]) -> None:
        msg = to_message(Instruction(Kind.STOP, id=ident))
        msg.client = self.key  # no deadline: a stop is obeyed however late
        self.watch(ident, heard)
        with self._cv:
            self._sent.add(ident)
        self.safety_pub.publish(msg)

    def drop_copies(self, idents: Iterable[str]) -> None:
        with self._cv:
            for ident in idents:
                self._watchers.pop(ident, None)
        for ident in idents:
            self.forget(ident)

    def _find_service(self, kind: Kind, name: str, service: Any) -> bool:
        """True once `service` is available; False if the server's topics are there and it is
        not, `SERVICE_GRACE_S` on. `NoServer` if neither comes within `wait_s`."""
        if service.service_is_ready():
            self._settled.setdefault(kind, Deadline(SERVICE_SETTLE_S))
            return True
        deadline = Deadline(self.wait_s)
        grace: Deadline | None = None
        start = time.monotonic()
        try:
            while not service.service_is_ready():
                if grace is None and self.server_seen():
                    grace = Deadline(SERVICE_GRACE_S)
                if grace is not None and grace.expired:
                    return False
                if deadline.expired:
                    raise self.no_server(name, self.wait_s)
                time.sleep(0.02)
        finally:
            self.discovery_s += time.monotonic() - start
        self._settled[kind] = Deadline(SERVICE_SETTLE_S)
        return True

    def _call(self, service: Any, timeout: float) -> Any:
        """The service's response, or None if none came within `timeout`."""
        future = service.call_async(Trigger.Request())
        answered = threading.Event()
        future.add_done_callback(lambda _: answered.set())
        answered.wait(timeout)
        if future.done():
            return future.result()
        service.remove_pending_request(future)
        return None

    def close(self, halt: str = "") -> None:
        """End the lease (its goodbye, if in contact, says this client left by `halt`,
        halting what it commanded: `Leaser.close`), and end the node and its ROS context."""
        self.lease.close([self.pub, self.safety_pub], left_by=halt)
        self.spinner.close()
