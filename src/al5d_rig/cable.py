"""A cable with a bad day: two TAP devices joined by this process, which delays and loses the
Ethernet frames between them as told (what `tc netem` does where a kernel has it).

This machine's kernel has no netem ("Error: Specified qdisc kind is unknown." for `tc
qdisc add dev X root netem delay 10ms`), so the fault sits on the wire instead of in the
kernel's queue: the two hosts' network stacks, their sockets, ARP and multicast are the
kernel's own, only the cable between them is this process. A frame is lost with the loss
given, and the others arrive the delay later, in the order they were sent (netem's order
without jitter).

Run by `al5d_rig.netrig.Hosts(cable=True)`:
`python -m al5d_rig.cable TAP_A TAP_B`. It makes both devices (in the namespace it runs
in: the caller moves them to their hosts), prints "ready", then reads settings from its
input, a line each: `delay MS`, `loss PERCENT`; it ends when its input does.
"""

from __future__ import annotations

import contextlib
import fcntl
import heapq
import itertools
import os
import random
import select
import struct
import sys
import threading
import time
from dataclasses import dataclass

#: <linux/if_tun.h>
TUNSETIFF = 0x400454CA
IFF_TAP = 0x0002
IFF_NO_PI = 0x1000
#: Larger than any frame of a 1500-byte MTU.
FRAME_MAX = 65536
#: The longest the loop sleeps with nothing due (its input and settings are read meanwhile).
IDLE_S = 0.05


@dataclass(frozen=True)
class Fault:
    """What the cable does to each frame: held `delay_s`, lost with probability `loss`."""

    delay_s: float = 0.0
    loss: float = 0.0


def parse(line: str, fault: Fault) -> Fault:
    """`fault` with the setting of `line` (`delay MS` or `loss PERCENT`) applied.

    Raises:
        ValueError: not one of those, or a value out of range (the message says which).
    """
    words = line.split()
    if len(words) != 2 or words[0] not in ("delay", "loss"):
        raise ValueError(f"{line.strip()!r}: expected 'delay MS' or 'loss PERCENT'")
    value = float(words[1])
    if words[0] == "delay":
        if not 0 <= value <= 60_000:
            raise ValueError(f"delay {value:g} ms: from 0 to 60000")
        return Fault(value / 1000, fault.loss)
    if not 0 <= value <= 100:
        raise ValueError(f"loss {value:g} %: from 0 to 100")
    return Fault(fault.delay_s, value / 100)


def open_tap(name: str) -> int:
    """A TAP device `name`, made in this process's network namespace; its descriptor."""
    fd = os.open("/dev/net/tun", os.O_RDWR)
    fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TAP | IFF_NO_PI))
    os.set_blocking(fd, False)
    return fd


class Wire:
    """The frames in flight between two devices, each way in the order it was sent."""

    def __init__(self, a: int, b: int, rng: random.Random) -> None:
        self.peer = {a: b, b: a}
        self.rng = rng
        self.fault = Fault()
        self._due: list[tuple[float, int, int, bytes]] = []  # (due, order, to, frame)
        self._order = itertools.count()
        self._last_due = {a: 0.0, b: 0.0}

    def take(self, source: int, frame: bytes, now: float) -> None:
        """A frame read from `source`: lost, or held for the peer."""
        fault = self.fault
        if fault.loss > 0 and self.rng.random() < fault.loss:
            return
        to = self.peer[source]
        # Never before a frame sent earlier the same way: a delay made shorter meanwhile
        # must not reorder what is in flight.
        due = max(now + fault.delay_s, self._last_due[to])
        self._last_due[to] = due
        heapq.heappush(self._due, (due, next(self._order), to, frame))

    def deliver(self, now: float) -> float | None:
        """Writes every frame due by `now`; when the next is due (None: none held)."""
        while self._due and self._due[0][0] <= now:
            _, _, to, frame = heapq.heappop(self._due)
            # The device down (a cut) or full: the frame is lost, as on a wire.
            with contextlib.suppress(OSError):
                os.write(to, frame)
        return self._due[0][0] if self._due else None


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m al5d_rig.cable TAP_A TAP_B", file=sys.stderr)
        return 2
    a, b = (open_tap(name) for name in argv)
    wire = Wire(a, b, random.Random())
    ended = threading.Event()

    def settings() -> None:
        for line in sys.stdin:
            try:
                wire.fault = parse(line, wire.fault)  # one assignment: the loop sees it whole
            except ValueError as e:
                print(f"cable: {e}", file=sys.stderr, flush=True)
        ended.set()

    threading.Thread(target=settings, name="al5d-cable-settings", daemon=True).start()
    print("ready", flush=True)
    next_due: float | None = None
    while not ended.is_set():
        now = time.monotonic()
        wait = IDLE_S if next_due is None else min(IDLE_S, max(0.0, next_due - now))
        readable, _, _ = select.select([a, b], [], [], wait)
        now = time.monotonic()
        for fd in readable:
            try:
                frame = os.read(fd, FRAME_MAX)
            except OSError:
                continue  # a device taken down reads nothing
            wire.take(fd, frame, now)
        next_due = wire.deliver(now)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
