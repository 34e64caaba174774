"""`al5d web` in a real headless browser, on a real server, over real DDS.

Four processes: the emulated board lives in this one behind a pty link (so that
the test reads exactly what reached the board), `al5d serve --port LINK`, `al5d
web`, and Chromium, driven by playwright, which clicks and drags like a person.
A browser that cannot start fails the test with the reason: it is never skipped.
"""

from __future__ import annotations

import itertools
import shutil
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import viser
from playwright.sync_api import sync_playwright
from proc import Proc
from rospeer import Peer, wait_until
from webrig import (
    BrowserUnavailable,
    StateWatch,
    WebProc,
    arm_pixels,
    dismiss_notifications,
    launch,
    open_page,
    wait_for_arm,
    wait_text,
)
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from al5d.arm.config import ArmConfig, load_config
from al5d.ros.runtime import Names
from al5d.ssc32u import protocol as p
from al5d.ssc32u.emulator import Emulator
from al5d.web.page import QUIET_S

DOCS = Path(__file__).resolve().parents[1] / "docs"


@dataclass
class Rig:
    config: ArmConfig
    emu: Emulator
    server: Proc
    web: WebProc
    peer: Peer
    state: StateWatch
    page: Any

    def group_moves(self, since: int) -> list[p.GroupMove]:
        return [
            c for r in self.emu.records[since:] for c in r.commands if isinstance(c, p.GroupMove)
        ]

    def stops(self, since: int) -> list[p.Stop]:
        return [c for r in self.emu.records[since:] for c in r.commands if isinstance(c, p.Stop)]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    config = load_config()
    link = tmp_path_factory.mktemp("web") / "ssc32u"
    emu = Emulator(config, link=link).start()
    server = Proc("serve", "--port", str(link), "--log-level", "DEBUG")
    web: WebProc | None = None
    peer: Peer | None = None
    try:
        server.err.wait_for("STATE: ready", 30)
        web = WebProc()
        peer = Peer(name="al5d_test_web_peer")
        state = StateWatch(peer.node, Names())
        peer.wait_for_server()
        with sync_playwright() as playwright:
            try:
                browser = launch(playwright)
            except BrowserUnavailable as e:
                pytest.fail(str(e))
            try:
                page = open_page(browser, web.url)
                yield Rig(config, emu, server, web, peer, state, page)
            finally:
                browser.close()
    finally:
        if peer is not None:
            peer.close()
        if web is not None:
            web.close()
        if server.popen.poll() is None:
            server.popen.send_signal(signal.SIGTERM)
            server.wait(30)
        emu.close()


def test_the_page_draws_the_arm(rig: Rig, tmp_path: Path) -> None:
    rig.peer.send("web-ready", "ready")
    assert rig.peer.result("web-ready").outcome == "done"
    dismiss_notifications(rig.page)
    wait_text(rig.page, "#al5d-state", lambda t: t == "READY")
    assert arm_pixels(wait_for_arm(rig.page)) >= 300
    time.sleep(0.5)  # the last joint states of the move drawn
    shot = tmp_path / "web.png"
    rig.page.screenshot(path=str(shot))
    DOCS.mkdir(exist_ok=True)
    shutil.copyfile(shot, DOCS / "web.png")
    tool = rig.page.inner_text("#al5d-tool")
    assert "tool (mm)" in tool and "joint states" in tool


def test_a_slider_drag_is_one_move(rig: Rig) -> None:
    page = rig.page
    page.get_by_role("tab", name="Joints").click()
    thumb = page.get_by_role("slider").nth(0)  # base, the first joint
    assert thumb.get_attribute("aria-valuenow") == "0"
    box = thumb.bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    n0 = len(rig.emu.records)
    page.mouse.move(x, y)
    page.mouse.down()
    stamps = []
    for i in range(1, 16):  # 15 steps: viser reports a value for each
        page.mouse.move(x + 4 * i, y)
        stamps.append(time.monotonic())
    page.mouse.up()
    degrees = float(thumb.get_attribute("aria-valuenow") or "nan")
    assert 20 <= degrees <= 90
    wait_until(lambda: rig.group_moves(n0), 5, "the slider's move on the board")
    time.sleep(QUIET_S + 0.5)  # a second move would have come by now
    moves = rig.group_moves(n0)
    # One drag, one move; a drag held still longer than QUIET_S (a slow machine) is two.
    pauses = sum(b - a >= QUIET_S for a, b in itertools.pairwise(stamps))
    assert 1 <= len(moves) <= 1 + pauses, moves
    pulse = round(rig.config.joints["base"].to_us(degrees))
    assert {(t.channel, t.pulse_us) for t in moves[-1].targets} == {(0, pulse)}
    rig.state.wait_for("ready", 10)


def test_stop_and_release_from_the_page(rig: Rig) -> None:
    page = rig.page
    rig.peer.send("web-slow", "move", time_ms=5000, base=-60)
    rig.state.wait_for("moving", 5)
    n0 = len(rig.emu.records)
    page.get_by_role("button", name="STOP").click()
    rig.state.wait_for("stopped", 5)
    wait_until(lambda: len(rig.stops(n0)) == 6, 5, "a STOP for every channel on the board")
    assert rig.peer.result("web-slow").outcome == "cancelled"
    wait_text(page, "#al5d-state", lambda t: t == "STOPPED")
    page.get_by_role("button", name="release").click()
    rig.state.wait_for("ready", 5)
    wait_text(page, "#al5d-state", lambda t: t == "READY")


def test_an_unreachable_target_shows_the_servers_reason(rig: Rig) -> None:
    page = rig.page
    page.get_by_role("tab", name="Target").click()
    for axis, mm in (("x", "500"), ("y", "0"), ("z", "100")):
        page.get_by_label(f"{axis} (mm)").fill(mm)
    # The page's server has the typed point, and its own check says why it cannot be.
    typed = wait_text(page, "#al5d-target-status", lambda t: "x 500 y 0 z 100 mm" in t)
    assert "unreachable: " in typed and "out of reach" in typed, typed
    n0 = len(rig.emu.records)
    page.get_by_role("button", name="move to").click()
    text = wait_text(page, "#al5d-target-status", lambda t: t.startswith("server:"))
    assert "refused" in text and "out of reach" in text, text
    assert "x=500 y=0 z=100" in text
    time.sleep(0.2)
    assert rig.group_moves(n0) == []


def test_only_the_page_itself_may_connect(rig: Rig) -> None:
    """Another web site open in the same browser must not reach the arm (no CSWSH)."""
    url = f"ws://127.0.0.1:{rig.web.port}"
    protocol: Any = f"viser-v{viser.__version__}"
    foreign: Any = "http://evil.example"
    with (
        connect(url, origin=foreign, subprotocols=[protocol]) as ws,
        pytest.raises(ConnectionClosed) as closed,
    ):
        ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
    origin: Any = f"http://127.0.0.1:{rig.web.port}"
    with connect(url, origin=origin, subprotocols=[protocol]) as ws:
        assert ws.recv(timeout=5)  # the page's state, as for the page


def test_the_page_says_when_it_lost_the_server(rig: Rig) -> None:
    page = rig.page
    page.get_by_role("tab", name="Joints").click()
    rig.server.popen.send_signal(signal.SIGTERM)  # parks, then ends
    assert rig.server.wait(30) == 0
    text = wait_text(page, "#al5d-banner", lambda t: "No contact with the server" in t, 10)
    assert "STOP still works" in text
    assert page.get_by_role("button", name="release").is_disabled()
    assert page.get_by_role("button", name="STOP").is_enabled()
    page.get_by_role("button", name="STOP").click()  # with no server: on the topic, harmless
    rig.web.proc.err.wait_for("STOP clicked (sent by topic)", 5)
