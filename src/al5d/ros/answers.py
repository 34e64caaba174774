"""What a client of the server is told, or why it is not: the errors `Client` raises, the
answer to a stop, a release or a shutdown, and what a client that finds no server says.

Their public home is `al5d.ros.client` (as tracebacks name them); they are here so that
both of the client's ways (`al5d.ros.client`'s lane, `al5d.ros.rosway`'s ROS 2, whose stop is
`al5d.ros.rosstop`'s) raise them.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from typing import Any

from al5d.owner import where
from al5d.ros.names import Names, server_namespaces

log = logging.getLogger("al5d")

#: A stop, a release or a shutdown is answered at once.
ANSWER_S = 10.0
#: The least wait for the answer to a stop, release or shutdown, whatever the timeout asked
#: (a stop is never refused for its timeout: 0 waits this; on a lane, from its opening).
ANSWER_MIN_S = 1.0
#: A silence of the server this long is said at once (a WARNING) by a client that waits
#: for it, before it gives up.
SILENCE_SAID_S = 1.0
#: How long a client waits past its timeout for the server's word on what it gave up on:
#: the server cancels it, or halts it, at the same deadline (`Instruction.wait_ms`), and
#: says so.
GIVE_UP_WORD_S = 1.0


#: `math.inf` seconds as a client waits them (a thread's wait takes no more), and what an
#: instruction carries as waited for for ever.
FOR_EVER_S = 1e9


def wait_ms(wait_s: float) -> int:
    """`wait_s` as an instruction carries it: ms, within a message's uint32 (0: for ever,
    as is `FOR_EVER_S` or more)."""
    if wait_s >= FOR_EVER_S:
        return 0
    return min(math.ceil(max(wait_s, 0.0) * 1000), 2**32 - 1)


class NoServer(Exception):
    """No `al5d serve` answers on this ROS domain."""


class NoOutcome(TimeoutError):
    """The server took too long to report an instruction's outcome, or to answer a service
    call: what became of the instruction is unknown."""


class LostContact(NoOutcome):
    """Nothing has been heard from the server for longer than its lease of this client (and
    a margin: `Client.lost_contact`): the link (or the server) is
    gone. The client has given up on what it waited for; the server, once this client's
    lease runs out, halts what it commanded and never runs what it sent meanwhile."""


class NotSent(Exception):
    """An instruction not sent: the server has not acknowledged what this client sent
    before it (as many instructions as DDS keeps for it wait: a link that holds them, a
    server that does not take them). Wait for outcomes before sending more (`execute`
    does), or for the server; a stop still goes (`Client.stop`)."""


class LaneLost(NoOutcome):
    """The server's local lane closed while an outcome was waited for (the server ended, or
    was killed): whether the instruction ran is unknown."""


def no_outcome(what: str, timeout: float) -> NoOutcome:
    """No outcome of `what` (an instruction's name and `[id]`) within `timeout` s, nor the
    server's word on it since."""
    return NoOutcome(
        f"{what}: no outcome within {timeout:g} s, nor word of it "
        f"{GIVE_UP_WORD_S:g} s later (the server halts what its sender gave up on: "
        "whether it ran is unknown)"
    )


@dataclass(frozen=True)
class Answer:
    """The server's answer to a stop, a release or a shutdown: whether it was obeyed, the
    server's message, the id it went under, and `via` what took it: the local lane, the
    instruction topic (a stop or a release over ROS 2, `by_service` False), or the
    shutdown's service (the topic where that is not found)."""

    instruction: str
    success: bool
    message: str
    via: str
    by_service: bool = True
    #: The id it went under, which the client's warnings while it waited named ("": a
    #: service's request, which names none).
    ident: str = ""

    @property
    def ok(self) -> bool:
        return self.success

    def __str__(self) -> str:
        result = "done" if self.success else "refused"
        text = f"{self.instruction} [{self.ident}]" if self.ident else self.instruction
        text += f": {result}"
        if self.message and self.message != f"{self.instruction}: {result}":
            text += f": {self.message}"
        return f"{text} (by {self.via})"


def elsewhere(names: Names, node: Any) -> str:
    """The end of a message that no server answers at `names`: the servers seen under other
    namespaces (on this machine's lanes, and on the ROS graph as `node` sees it), or the
    question whether one runs."""
    found = others(names, node)
    if found:
        return found
    if node is None:
        return ": is 'al5d serve' running?"
    return ": is 'al5d serve' running?" + closed_hint()


def others(names: Names, node: Any) -> str:
    """The servers seen under other namespaces than `names`' (on this machine's lanes, and
    on the ROS graph as `node`, if any, sees it), said as the end of a message with the one
    meant where it is likely: "; found /left: --namespace left?". Empty where none is."""
    seen = set(where.namespaces())
    if node is not None:
        seen |= server_namespaces(node)
    seen.discard(names.node_namespace)
    if not seen:
        return ""
    found = sorted(seen)
    listed = " and ".join([", ".join(found[:-1]), found[-1]] if len(found) > 1 else found)
    return f"; found {listed}{_which(names.node_namespace, found)}"


def _which(asked: str, found: list[str]) -> str:
    """The one of `found` that `asked` likely meant, said as an option; where none is likely
    (two servers and no namespace asked, or a namespace asked that is none of them: the
    arm it names may be down), the namespace is left to the user: a hint to command
    another arm than the one asked for could move, or stop, the wrong one."""

    def said(namespace: str) -> str:
        bare = namespace.strip("/")
        return f"--namespace {bare}?" if bare else "no --namespace?"

    if asked == "/":
        return f": {said(found[0])}" if len(found) == 1 else ": name one with --namespace"
    typos = [f for f in found if _typo(asked, f)]
    return f": {said(typos[0])}" if len(typos) == 1 else ""


def _typo(asked: str, found: str) -> bool:
    """Whether `asked` is `found` mistyped: the same but for case, or two letters side by
    side swapped (`rigth`). Never a name a letter or digit apart (`arm1`, `arm2`): that is
    another arm, and so is `lab_left` for `lab/left`."""
    a, f = asked.lower(), found.lower()
    if a == f:
        return True
    if len(a) != len(f):
        return False
    apart = [k for k in range(len(a)) if a[k] != f[k]]
    return (
        len(apart) == 2
        and apart[1] == apart[0] + 1
        and a[apart[0]] == f[apart[1]]
        and a[apart[1]] == f[apart[0]]
    )


def closed_hint() -> str:
    """What a client over ROS 2 that finds no server says of a server on another machine."""
    given = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "")
    here = (given or "LOCALHOST").upper()
    if here == "LOCALHOST":
        return (
            " This client looks on this machine only (ROS_AUTOMATIC_DISCOVERY_RANGE="
            f"LOCALHOST{'' if given else ', the default'}); for a server on another machine, set "
            "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET here and where it runs, with the same "
            "ROS_DOMAIN_ID (docs/ros.md, 'Reaching the node from another machine')."
        )
    return (
        " A server on another machine is closed to the network unless it was started with "
        "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET (its default keeps it to its own machine) and "
        "this ROS_DOMAIN_ID (docs/ros.md, 'Reaching the node from another machine'); one "
        "that is open is not found while the network to it is down: run this again once "
        "it is up."
    )


for _public in (NoServer, NoOutcome, LostContact, LaneLost, Answer):
    _public.__module__ = "al5d.ros.client"


def said_late(stop: str, after_s: float, ok: bool, result: str, reason: str) -> None:
    """The answer to the stop `stop` that its client had given up on, `after_s` after it
    was asked, said as a WARNING (over ROS 2 and the local lane alike): a stop is obeyed
    however late, and whoever asked must hear that it locked the arm."""
    if ok:
        # The server obeyed it when it came (or before, its answer lost), which locked
        # the arm; a release sent since may have unlocked it: not said locked now.
        log.warning(
            "stop [%s]: answered after this client gave up on it (%.1f s after it was "
            "asked): the server obeyed it, which locked the arm until a release sent "
            "after it",
            stop,
            after_s,
        )
    else:
        log.warning(
            "stop [%s]: answered after this client gave up on it (%.1f s after it was asked): %s%s",
            stop,
            after_s,
            result,
            f": {reason}" if reason else "",
        )
