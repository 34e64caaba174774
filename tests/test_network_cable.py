"""The cable of the network tests (`al5d_rig.cable`): it delays and loses frames as told and
keeps their order, and two hosts joined by it talk over the kernel's own sockets."""

from __future__ import annotations

import os
import random
import sys
import time
from collections.abc import Iterator

import pytest

from al5d_rig import netrig
from al5d_rig.cable import Fault, Wire, parse
from al5d_rig.proc import Lines

CMD_S = 60.0


def test_settings_are_read_and_a_bad_one_is_named() -> None:
    fault = parse("delay 250", Fault())
    assert fault == Fault(0.25, 0.0)
    assert parse("loss 30", fault) == Fault(0.25, 0.3)
    for line, said in (("delay -1", "from 0 to 60000"), ("loss 130", "from 0 to 100")):
        with pytest.raises(ValueError, match=said):
            parse(line, fault)
    with pytest.raises(ValueError, match="expected 'delay MS' or 'loss PERCENT'"):
        parse("jitter 5", fault)


def test_frames_arrive_the_delay_later_and_in_the_order_sent() -> None:
    (ra, a), (rb, b) = os.pipe(), os.pipe()  # what the cable writes "to a" is read at ra
    wire = Wire(a, b, random.Random(1))
    wire.fault = Fault(delay_s=0.5)
    wire.take(a, b"first", now=10.0)
    wire.fault = Fault(delay_s=0.1)  # shorter now: what is in flight keeps its order
    wire.take(a, b"second", now=10.1)
    assert wire.deliver(10.4) == 10.5  # nothing due yet
    assert wire.deliver(10.5) is None
    assert os.read(rb, 100) == b"firstsecond"
    wire.fault = Fault(loss=1.0)
    wire.take(b, b"lost", now=11.0)
    assert wire.deliver(99.0) is None
    os.set_blocking(ra, False)
    with pytest.raises(BlockingIOError):
        os.read(ra, 100)


@pytest.fixture(scope="module")
def hosts() -> Iterator[netrig.Hosts]:
    netrig.need()
    with netrig.Hosts(cable=True) as h:
        yield h


ECHO = f"""
import socket
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("{netrig.ARM_IP}", 9999))
print("ready", flush=True)
while True:
    data, peer = s.recvfrom(100)
    s.sendto(data, peer)
"""
#: Sends argv[1] datagrams 5 ms apart; prints each answer's number and round trip.
PINGS = f"""
import socket, sys, threading, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.settimeout(3.0)
sent = {{}}
def send():
    for k in range(int(sys.argv[1])):
        sent[k] = time.monotonic()
        s.sendto(str(k).encode(), ("{netrig.ARM_IP}", 9999))
        time.sleep(0.005)
threading.Thread(target=send).start()
try:
    while True:
        data, _ = s.recvfrom(100)
        k = int(data)
        print(k, time.monotonic() - sent[k], flush=True)
except socket.timeout:
    print("end", flush=True)
"""


def pings(hosts: netrig.Hosts, count: int) -> list[tuple[int, float]]:
    proc = hosts.popen(hosts.laptop, [sys.executable, "-c", PINGS, str(count)])
    out, err = proc.communicate(timeout=CMD_S)
    assert proc.returncode == 0 and out.endswith("end\n"), err
    return [(int(k), float(t)) for k, t in (line.split() for line in out.splitlines()[:-1])]


def test_two_hosts_on_the_cable_see_its_delay_and_its_loss(hosts: netrig.Hosts) -> None:
    echo = hosts.popen(hosts.arm, [sys.executable, "-c", ECHO])
    assert echo.stdout is not None
    try:
        Lines(echo.stdout).wait_for("ready", CMD_S)
        for _ in range(20):  # the first datagram may wait for ARP
            if pings(hosts, 1):
                break
        clear = pings(hosts, 50)
        hosts.impair(delay_ms=200)
        time.sleep(0.1)
        slow = pings(hosts, 50)
        hosts.impair(delay_ms=0, loss_percent=30)
        time.sleep(0.1)
        lossy = pings(hosts, 400)
        hosts.impair()
    finally:
        echo.kill()
        echo.wait(10)
    assert len(clear) == 50 and [k for k, _ in slow] == list(range(50))  # none lost, in order
    trips = sorted(t for _, t in slow)
    print(
        f"round trip clear: max {max(t for _, t in clear) * 1000:.1f} ms; with 200 ms each "
        f"way: min {trips[0] * 1000:.0f} ms; 30 % loss each way: {len(lossy)} of 400 back"
    )
    assert trips[0] >= 0.4  # both ways held
    # Both ways lose 30 %: 0.7 * 0.7 = 49 % come back (sd 2.5 % of 400); 4 sd either side.
    assert 0.39 < len(lossy) / 400 < 0.59, len(lossy)
