"""`al5d send stop` by the local lane, from a bare interpreter: the stop within a few tens of
milliseconds of the command's start.

A user who types `al5d send stop` in a new terminal must not wait for imports and ROS 2
discovery (0.7 to 3.5 s, measured): the command line hands a plain `send stop` here
before it imports anything else, and this needs the standard library alone. Where no
local server answers, it says so and the full command line goes on (over ROS 2).
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

from al5d.owner import where

#: The options of `al5d send` this path knows; anything else goes the full way.
_FLAGS = ("--namespace", "--timeout", "--wait")
#: `al5d.arm.instruction.STOP_MARKS`, which this path does not import (a test holds the two
#: alike): what may end the word `stop` typed in a hurry.
_STOP_MARKS = "!.,;:"
#: A stop unanswered this long is said to be so at once, while it is still awaited, by
#: the local lane as over ROS 2 (`al5d.ros.rosstop`): whoever asked must not believe the arm
#: stopped meanwhile. Under a second, so that a stop not obeyed within one is said before
#: the second is up.
UNANSWERED_S = 0.8


class LaneFull(ConnectionError):
    """A server is on the lane, but its queue of connections not yet taken is full: it is
    busy or stalled (a frozen process). A stop goes by a connection already open to it,
    which it reads, stops first, as it turns again."""


#: Where a stop goes when the lane takes no new connection (`LaneFull`), as said.
BY_ROS = "it goes by ROS 2, whose stop node holds a connection to the server"


def parse(argv: list[str]) -> tuple[str, float] | None:
    """`send stop [words]` with the options `_FLAGS` (each with its value) anywhere among its
    words: the namespace and the timeout; None for any other command line. A stop is read
    whatever words follow it, as the grammar reads it (`al5d send stop now`)."""
    if len(argv) < 2 or argv[0] != "send":
        return None
    namespace, timeout = "", 10.0
    words: list[str] = []
    rest = iter(argv[1:])
    for word in rest:
        if word.startswith("-"):
            value = next(rest, None)
            if word not in _FLAGS or value is None:
                return None  # --help, --via, -v, an option without its value: the full way
            if word == "--namespace":
                namespace = value
            elif word == "--timeout":
                try:
                    timeout = float(value)
                except ValueError:
                    return None
        else:
            words.append(word)
    if not words or words[0].lower().rstrip(_STOP_MARKS) != "stop":
        return None
    return namespace, timeout


def stop(namespace: str, timeout: float) -> int | None:
    """Ask the local server for the stop and print its answer as `al5d send` does; the exit
    code, or None where no server's lane answers here (then ROS 2 is the way). Raises
    LaneFull, said, where the server's lane takes no new connection: the stop then goes
    by ROS 2 alone, whose stop node holds a connection to the server (by the lane, the
    full command line would wait for one, and end with nothing sent)."""
    ident = f"{os.getpid():x}-stop"

    def unanswered() -> None:
        print(
            f"stop [{ident}]: no answer in {UNANSWERED_S:g} s by the local lane (the server "
            f"busy or stalled); still waiting, up to {timeout:g} s: whether the arm has "
            "stopped is unknown",
            file=sys.stderr,
            flush=True,
        )

    unknown = "whether the arm has stopped is unknown"
    try:
        outcome = ask_stop(where.path(namespace), ident, timeout, unanswered)
    except LaneFull as e:
        print(f"stop: {e}; {BY_ROS}", file=sys.stderr, flush=True)
        raise
    except TimeoutError:
        # The stop waits in the server's lane: one that comes back obeys it then.
        print(
            f"stop [{ident}]: no answer within {timeout:g} s by the local lane: {unknown}; the "
            "server obeys a stop however late it takes it (the arm then stays locked until a "
            "release)"
        )
        return 1
    except OSError as e:
        print(f"stop [{ident}]: no answer from the server ({e.strerror or e}): {unknown}")
        return 1
    except EOFError:
        print(f"stop [{ident}]: the server closed the lane without answering: {unknown}")
        return 1
    except KeyboardInterrupt:
        print(
            f"stop [{ident}]: Ctrl-C: left before its answer: {unknown} (the server obeys it "
            "when it takes it)"
        )
        return 130  # `al5d.exits.INTERRUPTED`, which this path does not import
    if outcome is None:
        return None
    ok = outcome.get("result") == "done"
    reason = outcome.get("reason") or ""
    text = f"stop [{outcome.get('id', ident)}]: {outcome.get('result')}"
    print(f"{text}: {reason} (by the local lane)" if reason else f"{text} (by the local lane)")
    return 0 if ok else 1


def ask_stop(
    lane: Path, ident: str, timeout: float, unanswered: Callable[[], None] | None = None
) -> dict[str, object] | None:
    """The stop `ident` asked of the server whose lane is `lane`, and its outcome as the lane
    carries it; None where no server's lane takes a connection there. `unanswered` as
    `answer` says. Raises OSError where the lane failed or no answer came within `timeout`
    s (the stop may have been obeyed), LaneFull (`hand_stop`), EOFError where the server
    closed it without answering."""
    sock = hand_stop(lane, ident, timeout)
    return None if sock is None else answer(sock, timeout, unanswered)


def full(lane: Path) -> LaneFull | None:
    """Why the server on `lane` takes no new connection now (`LaneFull`), or None: it takes
    one, or no server is there (`where.probe`)."""
    return _full(lane) if where.probe(lane) is False else None


def _full(lane: Path) -> LaneFull:
    return LaneFull(
        f"the al5d server on this machine's lane ({lane}) takes no new connection (too many "
        "wait for it): it is busy or stalled"
    )


def hand_stop(lane: Path, ident: str, timeout: float) -> socket.socket | None:
    """The stop `ident` handed to the server whose lane is `lane` (within `timeout` s: a
    Unix socket takes a line at once, unless the owner has not read a backlog of them);
    the socket its answer comes on (`answer`), or None where no server's lane takes a
    connection there. Raises LaneFull where one is there but takes no new connection now,
    OSError where the lane failed."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        sock.connect(str(lane))
    except BlockingIOError:  # at once, whatever the timeout: a Unix socket does not wait
        sock.close()
        raise _full(lane) from None
    except OSError:
        sock.close()
        return None
    ask = {
        "op": "ask",
        "ref": 1,
        "instr": {"kind": "stop", "id": ident, "sent_ns": time.time_ns()},
    }
    try:
        sock.sendall(json.dumps(ask).encode() + b"\n")
    except OSError:
        sock.close()
        raise
    return sock


def answer(
    sock: socket.socket,
    timeout: float,
    unanswered: Callable[[], None] | None = None,
    late: Callable[[dict[str, object]], None] | None = None,
) -> dict[str, object]:
    """The outcome of the stop handed over on `sock` (`hand_stop`), which is then closed;
    `unanswered` is called once, on this thread, where none has come within `UNANSWERED_S`
    (the wait goes on). Where none came within `timeout` s, the answer is still listened
    for with `late`, which a thread of its own calls with it if it comes (a stop waits in
    the lane of a stalled server, which obeys it when it can). Raises OSError
    (TimeoutError) where none came within `timeout` s, EOFError where the server closed
    the lane without answering."""
    try:
        outcome = _answer(sock, timeout, unanswered)
    except TimeoutError:
        if late is None:
            sock.close()
        else:
            import threading  # here: `al5d send stop`'s path imports as little as it can

            threading.Thread(
                target=_listen_late, args=(sock, late), name="al5d-stop-late", daemon=True
            ).start()
        raise
    except BaseException:
        sock.close()
        raise
    sock.close()
    if outcome is None:
        raise EOFError("the server closed the lane without answering")
    return outcome


def _listen_late(sock: socket.socket, late: Callable[[dict[str, object]], None]) -> None:
    """The answer that came after its asker gave up, given to `late` (none: nothing)."""
    try:
        sock.settimeout(None)
        outcome = _answer(sock, None, None)
    except (OSError, ValueError):  # the lane closed or garbled: nothing came to tell
        return
    finally:
        sock.close()
    if outcome is not None:
        late(outcome)


def _answer(
    sock: socket.socket, timeout: float | None, unanswered: Callable[[], None] | None
) -> dict[str, object] | None:
    """The outcome of our request (ref 1): the first line that is one, within `timeout` s."""
    end = None if timeout is None else time.monotonic() + timeout
    warn_at = (
        time.monotonic() + UNANSWERED_S
        if unanswered and (timeout is None or timeout > UNANSWERED_S)
        else None
    )
    data = b""
    while True:
        until = warn_at or end
        # A positive timeout: zero would make the socket non-blocking.
        sock.settimeout(None if until is None else max(until - time.monotonic(), 0.001))
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            if warn_at is None or unanswered is None:
                raise
            warn_at = None
            unanswered()
            continue
        if not chunk:
            return None
        data += chunk
        while b"\n" in data:
            line, data = data.split(b"\n", 1)
            message = json.loads(line)
            if message.get("op") == "outcome" and message.get("ref") == 1:
                outcome: dict[str, object] = message["outcome"]
                return outcome
