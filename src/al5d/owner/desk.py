"""What the lane's clients ask of the owner: each message read into the owner's inbox, and
each answer routed back to the connection and the reference it came with.

By the owner's thread alone, as `al5d.owner.conns` (the bytes) is. The owner (`Inbox`)
takes the requests in its turns; here they are only checked, named with the owner's own
references and queued, so that `al5d.owner.loop` reads as the owner's inputs and effects.
A bad message is answered with an `error` and changes nothing.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass, replace
from typing import Any, Protocol

from al5d.arm.instruction import Instruction, Outcome
from al5d.arm.resample import Follow
from al5d.arm.validate import Ticket
from al5d.clock import now, wall_ns
from al5d.owner import lane as ln
from al5d.owner.conns import Conn, Conns

#: Tickets judged for one connection and never asked, kept at most (the oldest go).
TICKETS_KEPT = 10_000


@dataclass(frozen=True, slots=True)
class Request:
    """A request for the core, as the owner's inbox holds it until its turn: the owner's
    reference, the instruction (or its `ticket`), the `stream` of set-points it belongs to,
    the `key` of a stop two readers may see, the `client` it counts for, and whether the
    outcome listeners are told (`tell`)."""

    ref: int
    instr: Instruction
    ticket: Ticket | None
    stream: str
    key: Hashable | None
    client: int
    tell: bool


class Inbox(Protocol):
    """What the desk needs of the owner (`al5d.owner.loop.Owner`)."""

    def new_ref(self) -> int:
        """A reference of the owner's own, for a request whose answer is routed back."""
        ...

    def put(self, request: Request) -> None:
        """A request for the core (a stop on the stops' lane)."""
        ...

    def later(self, what: str, ref: int, payload: Any) -> None:
        """An entry for the owner's next turns, behind the requests before it."""
        ...

    def judge(self, instr: Instruction, follow: Follow | None = None) -> Ticket | str:
        """The one judgement of a motion instruction: its ticket, or why it is refused."""
        ...

    def welcome(self, conn: Conn, recorder: bool) -> list[dict[str, Any]]:
        """What a client that said hello is told: the welcome, then (to a `recorder` that
        watches the wire) the board's writes kept for it."""
        ...

    def told_kept(self) -> list[dict[str, Any]]:
        """The outcomes told while no bridge heard them (each once)."""
        ...


class Desk:
    """The lane's requests for the owner `inbox`, from the clients of `lanes`; a leased
    client (its hello asks for it) is lost when not heard for `lease_s`."""

    def __init__(self, lanes: Conns, inbox: Inbox, lease_s: float) -> None:
        self._lanes = lanes
        self._inbox = inbox
        self._lease_s = lease_s
        #: The owner's reference -> the connection and the client's reference it came with.
        self._routes: dict[int, tuple[Conn, Any]] = {}

    def read(self, conn: Conn, stalled: float) -> None:
        """Every whole message `conn` has sent (the owner's stalls so far: `stalled`)."""
        for message in self._lanes.read(conn, stalled):
            if isinstance(message, ln.LaneError):
                self._send(conn, {"op": "error", "error": str(message)})
            else:
                self._message(conn, message)

    def judge(self, conn: Conn, ref: Any, m: dict[str, Any]) -> None:
        """A `judge` request, in its turn: a ticket kept for `conn`, or the reason."""
        try:
            instr = ln.instruction_in(m.get("instr"))
            follow = ln.follow_in(m.get("follow"))
        except ln.LaneError as e:
            self._send(conn, {"op": "error", "ref": ref, "error": str(e)})
            return
        got = self._inbox.judge(instr, follow)
        if isinstance(got, str):
            self._send(conn, {"op": "judged", "ref": ref, "reason": got})
            return
        name = f"{conn.ident}-{ref}"
        conn.tickets[name] = got
        while len(conn.tickets) > TICKETS_KEPT:
            del conn.tickets[next(iter(conn.tickets))]
        knots = [step.point for step in got.steps]
        self._send(conn, {"op": "judged", "ref": ref, "ticket": name, "knots": knots})

    def outcome(self, ref: int, outcome: Outcome) -> bool:
        """The outcome of the owner's request `ref` to the client that asked it; False when
        no lane client did."""
        return self._answer(ref, "outcome", outcome=ln.outcome_out(outcome))

    def reply(self, ref: int, ok: bool) -> bool:
        """The reply to the owner's request `ref` (a cancel) to the client that asked it;
        False when no lane client did."""
        return self._answer(ref, "reply", ok=ok)

    def dropped(self, conn: Conn, why: str) -> None:
        """`conn` has been dropped (`Conns.drop`): its requests' answers go nowhere; and, when
        it was lost (`why`), what it and the clients it speaks for commanded does not go on."""
        for ref, (c, _) in list(self._routes.items()):
            if c is conn:
                del self._routes[ref]
        if why:
            self._inbox.later("gone", 0, (conn.ident, f"{conn.name}: {why}"))
            for who, client in conn.subs.items():
                self._inbox.later("gone", 0, (client, f"{who} by {conn.name}: {why}"))

    # -- one message ------------------------------------------------------------------------

    def _send(self, conn: Conn, message: dict[str, Any]) -> None:
        self._lanes.write(conn, ln.dumps(message))

    def _answer(self, ref: int, op: str, **fields: Any) -> bool:
        routed = self._routes.pop(ref, None)
        if routed is None:
            return False
        conn, their = routed
        self._send(conn, {"op": op, "ref": their, **fields})
        return True

    def _route(self, conn: Conn, ref: Any) -> int:
        ours = self._inbox.new_ref()
        self._routes[ours] = (conn, ref)
        return ours

    def _message(self, conn: Conn, m: dict[str, Any]) -> None:
        """One request of a lane client; a bad one is answered with an `error`."""
        op = m["op"]
        ref = m.get("ref")
        if not (ref is None or isinstance(ref, int | str)) or isinstance(ref, bool):
            # Echoed in the answer: a ref nested near the interpreter's depth failed the
            # owner's writing of it (a second reading).
            self._send(conn, {"op": "error", "error": f"{op[:40]}: ref must be a number or text"})
            return
        try:
            if op == "ask":
                self._ask(conn, ref, m)
            elif op == "judge":
                # Judged in its turn among the requests, not as the connection is read: a
                # trajectory's judgement takes milliseconds, and a stop read in the same turn
                # from another connection is taken first (a client asks with a ticket only
                # once it has the answer, so no ask can come before its judgement).
                self._inbox.later("judge", 0, (conn, ref, m))
            elif op == "drop":  # a ticket its client will not ask with (a goal cancelled)
                conn.tickets.pop(str(m.get("ticket")), None)
            elif op == "cancel":
                ident, reason = m.get("id"), m.get("reason") or "cancelled by the client"
                if not isinstance(ident, str) or not isinstance(reason, str):
                    raise ln.LaneError("cancel: id and reason must be text")
                self._inbox.later("cancel", self._route(conn, ref), (ident, reason[:200]))
            elif op == "hello":
                self._hello(conn, m)
            elif op == "kept":  # a new bridge: what its clients were told while none was
                for message in self._inbox.told_kept():
                    self._send(conn, message)
                self._send(conn, {"op": "reply", "ref": ref, "ok": True})
            elif op == "ping":
                self._send(conn, {"op": "pong", "ref": ref, "t": now()})
            elif op == "sign":  # a leased client is there (`Conn.heard`, set as it was read)
                # Answered by the owner's thread: the client's sign that the owner turns (a
                # frozen owner's lane stays open and says nothing: `Remote.quiet`).
                self._send(conn, {"op": "signed"})
            elif op == "bye":  # `left_by`: it leaves by an error, and what it commanded halts
                left_by = m.get("left_by", "")
                if not isinstance(left_by, str):
                    raise ln.LaneError("bye: left_by must be text")
                conn.left_by, conn.bye = left_by[:200], not left_by
            elif op == "gone":
                self._gone(conn, m)
            else:
                raise ln.LaneError(f"no op {op[:40]!r}")
        except ln.LaneError as e:
            self._send(conn, {"op": "error", "ref": ref, "error": str(e)})
        except RecursionError:  # a value nested deep, read by Python's recursion
            self._send(conn, {"op": "error", "ref": ref, "error": f"{op[:40]}: nested too deep"})

    def _hello(self, conn: Conn, m: dict[str, Any]) -> None:
        if conn.welcomed:  # each is answered with the whole welcome, read before any stop
            raise ln.LaneError("hello: once a connection")
        watch = m.get("watch") or []
        if not isinstance(watch, list) or not all(w in ln.WATCHES for w in watch):
            raise ln.LaneError(f"hello: watch is a list of {', '.join(ln.WATCHES)}")
        conn.name = str(m.get("name", "?"))[:80]
        conn.watch = frozenset(watch)
        if m.get("lease") is True:
            conn.lease_s = self._lease_s
        conn.ros = m.get("ros") is True
        recorder = m.get("recorder") is True and "wire" in conn.watch
        # Once: a flood of hellos on one connection, each welcomed, held the other lanes'
        # stops 0.3 to 0.9 s (an outside try).
        conn.welcomed = True
        for message in self._inbox.welcome(conn, recorder):
            self._send(conn, message)

    def _ask(self, conn: Conn, ref: Any, m: dict[str, Any]) -> None:
        ticket = None
        if "ticket" in m:
            ticket = conn.tickets.pop(str(m["ticket"]), None)
            if ticket is None:
                raise ln.LaneError(f"ask: no ticket {str(m['ticket'])[:40]!r} (judged once each)")
            instr = ticket.instr
        else:
            instr = ln.instruction_in(m.get("instr"))
        if instr.sent_ns is not None and instr.sent_ns > (came := wall_ns()):
            # Sent no later than it came (this machine's clock on both sides): a stop stamped
            # in the future held every release refused until the server ended (an outside
            # try), as a stop over ROS 2 is held to when it came (`convert.stop_time`).
            instr = replace(instr, sent_ns=came)
            if ticket is not None:
                ticket = replace(ticket, instr=instr)
        stream = m.get("stream", "")
        if not isinstance(stream, str):
            raise ln.LaneError("ask: stream must be text")
        key = _hashable(m.get("key"))
        client = conn.ident
        if "for" in m:
            who = m["for"]
            if not isinstance(who, str) or not who or len(who) > 200:
                raise ln.LaneError("ask: for must be a client's key (text, 1 to 200 characters)")
            client = conn.subs.get(who) or conn.subs.setdefault(who, self._lanes.new_ident())
        tell = bool(m.get("tell", True))
        self._inbox.put(Request(self._route(conn, ref), instr, ticket, stream, key, client, tell))
        if not conn.ros and self._lanes.watching("asked"):  # a recording's: no ROS topic has it
            asked = {"op": "asked", "instr": ln.instruction_out(instr), "wall": wall_ns()}
            self._lanes.news("asked", asked)

    def _gone(self, conn: Conn, m: dict[str, Any]) -> None:
        """A client `conn` speaks for is lost (`why`): what it commanded does not go on; or
        closed (`why` empty): it is forgotten, what it commanded goes on."""
        who, why = m.get("for"), m.get("why", "")
        if not isinstance(who, str) or not isinstance(why, str):
            raise ln.LaneError("gone: for and why must be text")
        client = conn.subs.pop(who, None)
        if client is not None and why:
            self._inbox.later("gone", 0, (client, f"{who}: {why[:200]}"))


#: How deep a stop's key may nest (a client's own; the bridge's is a flat list).
KEY_DEPTH = 8


def _hashable(value: Any, depth: int = 0) -> Hashable | None:
    if isinstance(value, list):
        if depth >= KEY_DEPTH:  # 500 deep ended the owner's thread (a second reading)
            raise ln.LaneError(f"key: nested deeper than {KEY_DEPTH}")
        return tuple(_hashable(v, depth + 1) for v in value)
    if value is None or isinstance(value, str | int | float | bool):
        return value
    raise ln.LaneError("key: not a JSON value")
