"""The arm across a bad network: a cut, a delay, a loss and both on the cable between the
laptop and the arm's host (`al5d_rig.netfaults`; fifty of them in `make soak`), under a
client sending moves, straight-line moves and stops: every request has one outcome, no
request its sender gave up on moves the arm, and every stop is obeyed."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from al5d_rig import netfaults, netrig


@pytest.fixture
def hosts() -> Iterator[netrig.Hosts]:
    netrig.need()
    with netrig.Hosts(cable=True) as h:
        yield h


@pytest.mark.timeout(600)
def test_promises_hold_through_a_cut_a_delay_a_loss_and_both(hosts: netrig.Hosts) -> None:
    report = netfaults.run(hosts, 6, seed=44, kinds=("cut", "both", "delay", "loss", "cut"))
    print(netfaults.figures(report))
    assert report.requests and report.stops
    assert netfaults.check(report) == []
