"""A server on this machine frozen mid-move (`make soak`): how long until a client over ROS 2
says it has no sign of the server, where only the owner is frozen (its ROS side runs on and
must tell, `al5d.ros.node`'s owner silence) against where the whole server is (the floor:
the client's own measure of a silence, nothing between).

A Python client's `al5d send --via ros` of an 8 s move; 3 s into it the owner (or every
process of the server) is stopped with SIGSTOP for 4 s; the time is from the stop to the
client's WARNING `no sign of the server`. The target: the owner alone within the floor and
a sign's round of the lane (`SIGN_EVERY_MAX_S`) and its silence (`SILENCE_KEPT_S`) more.

Then a web page (`al5d web`, headless Chromium) with the owner alone frozen: how long until
it shows `No contact with the server`, against the 2 s a page has to say so after a cut
link (bench/network_cut.py).
"""

from __future__ import annotations

import os
import signal
import statistics
import subprocess
import sys
import time

from al5d.owner.client import SIGN_EVERY_MAX_S, SILENCE_KEPT_S
from al5d_rig import domains, webrig
from al5d_rig.proc import AL5D, Lines, family, freeze, patient_config

if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())

TRIES = int(os.environ.get("AL5D_FREEZES", "6"))
CMD_S = 60.0
FROZEN_S = 4.0
#: A page says it has lost contact within this of a cut link (bench/network_cut.py).
PAGE_LOST_S = 2.0


def _said_after(server: subprocess.Popen[str], alone: bool, k: int) -> float:
    """One freeze 3 s into a move: seconds from it to the client's word."""
    send = subprocess.Popen(
        [AL5D, "send", "--via", "ros", "move", f"base={60 if k % 2 else -60}", "time=8000"],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    assert send.stderr is not None
    err = Lines(send.stderr)
    try:
        time.sleep(3.0)
        pids = [server.pid] if alone else family(server.pid)
        frozen = time.monotonic()
        for pid in pids:
            freeze(pid)
        try:
            err.wait_for("no sign of the server", CMD_S)
            said = time.monotonic() - frozen
            time.sleep(max(0.0, FROZEN_S - (time.monotonic() - frozen)))
        finally:
            for pid in pids:
                os.kill(pid, signal.SIGCONT)
    finally:
        send.kill()
        send.wait(CMD_S)
    subprocess.run([AL5D, "send", "release"], capture_output=True, timeout=CMD_S, check=False)
    time.sleep(1.0)
    return said


def _page_freezes(server: subprocess.Popen[str]) -> list[float]:
    """A page of `al5d web` in headless Chromium; the owner alone frozen TRIES times: how
    long until the page shows that it has no contact with the server, each time."""
    from playwright.sync_api import sync_playwright

    web = subprocess.Popen(
        [AL5D, "web", "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )
    assert web.stdout is not None
    shown: list[float] = []
    try:
        url = Lines(web.stdout).wait_for("al5d web: http", CMD_S).split(": ", 1)[1].strip()
        with sync_playwright() as playwright:
            browser = webrig.launch(playwright)
            page = webrig.open_page(browser, url)
            for k in range(TRIES):
                time.sleep(2.0)
                frozen = time.monotonic()
                freeze(server.pid)
                try:
                    page.wait_for_selector("#al5d-banner", timeout=CMD_S * 1000)
                    shown.append(time.monotonic() - frozen)
                    time.sleep(max(0.0, FROZEN_S - (time.monotonic() - frozen)))
                finally:
                    os.kill(server.pid, signal.SIGCONT)
                page.wait_for_selector("#al5d-banner", state="detached", timeout=CMD_S * 1000)
                print(f"page freeze {k + 1}: no contact shown after {shown[-1]:.2f} s", flush=True)
            browser.close()
    finally:
        web.kill()
        web.wait(CMD_S)
    return shown


def main() -> int:
    server = subprocess.Popen(
        [AL5D, "serve", "--config", patient_config()], stderr=subprocess.PIPE, text=True
    )
    assert server.stderr is not None
    times: dict[bool, list[float]] = {True: [], False: []}
    try:
        Lines(server.stderr).wait_for("STATE: ready", CMD_S)
        for k in range(2 * TRIES):
            alone = k % 2 == 0  # interleaved: a busy spell weighs on both
            times[alone].append(_said_after(server, alone, k))
            print(
                f"freeze {k + 1}: {'owner alone' if alone else 'whole server'}: "
                f"said after {times[alone][-1]:.2f} s",
                flush=True,
            )
        pages = _page_freezes(server)
    finally:
        server.send_signal(signal.SIGINT)
        server.wait(CMD_S)
    owner, whole = times[True], times[False]
    limit = max(whole) + SIGN_EVERY_MAX_S + SILENCE_KEPT_S
    held = max(owner) <= limit
    print(
        f"{TRIES} freezes of the owner alone: the ROS client said no sign of the server after "
        f"p50 {statistics.median(owner):.2f} s, max {max(owner):.2f} s; floor, the whole "
        f"server frozen: p50 {statistics.median(whole):.2f} s, max {max(whole):.2f} s "
        f"(target: the owner alone within the floor's max + {SIGN_EVERY_MAX_S:g} + "
        f"{SILENCE_KEPT_S:g} s = {limit:.2f} s: {'held' if held else 'NOT held'})"
    )
    page_held = max(pages) <= PAGE_LOST_S
    print(
        f"{TRIES} freezes of the owner alone under a page: it showed no contact with the "
        f"server after p50 {statistics.median(pages):.2f} s, max {max(pages):.2f} s (target: "
        f"{PAGE_LOST_S:g} s, as after a cut link: {'held' if page_held else 'NOT held'})"
    )
    return 0 if held and page_held else 1


if __name__ == "__main__":
    sys.exit(main())
