"""The link cut mid-move, 20 times (`make soak`): how long after each cut the server halts
what the lost client commanded, against `server.client_lease_s` + 0.5 s; then the link cut
10 times under a browser on the laptop whose web view is beside the server: how long until
the page says it lost contact, against 2 s.

Two hosts (`al5d_rig.netrig`: network namespaces joined by a veth pair), the server on
one, a Python client on the other sending 6 s moves; 1.5 s into each the link is cut.
The halt's time is that of the server's log line `...: halted`, which the owner says in
the step that writes the halt to the board; the client must give up only after it. Needs
root (CI runs as root).
"""

from __future__ import annotations

import os
import statistics
import sys
import time

from al5d_rig import domains, netfaults, netrig, webrig
from al5d_rig.proc import AL5D, Lines, patient_config

if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())

CUTS = int(os.environ.get("AL5D_CUTS", "20"))
PAGE_CUTS = int(os.environ.get("AL5D_PAGE_CUTS", "10"))
LEASE_S = 1.0
#: The remote page's promise: it says it lost contact within this of a cut.
PAGE_LOST_S = 2.0
CMD_S = 60.0

LAPTOP = """
import logging, sys, time
from al5d.ros.client import Client, LostContact
logging.basicConfig(stream=sys.stdout, format="%(created).6f %(message)s", level=logging.WARNING)
c = Client(wait_s=60)
c.wait_for_server(60)
print("ready", flush=True)
for k, line in enumerate(sys.stdin):
    while c.lost_contact() is not None:
        time.sleep(0.05)
    try:
        print("outcome", c.execute(f"move base={-60 if k % 2 else 60} time=6000", 60), flush=True)
    except LostContact:
        print("lost", time.time(), flush=True)
"""


def main() -> int:
    why = netrig.unavailable()
    if why is not None:
        print(f"network_cut: cannot run here: {why}", file=sys.stderr)
        return 1
    halts: list[float] = []
    told: list[float] = []
    noticed: list[float] = []
    with netrig.Hosts() as hosts:
        server = hosts.popen(hosts.arm, [AL5D, "serve", "--config", patient_config()])
        laptop = hosts.popen(hosts.laptop, [sys.executable, "-c", LAPTOP])
        assert server.stderr is not None and laptop.stdout is not None
        assert laptop.stdin is not None
        log, out = Lines(server.stderr), Lines(laptop.stdout)
        try:
            log.wait_for("STATE: ready", CMD_S)
            out.wait_for("ready", CMD_S)
            for k in range(CUTS):
                laptop.stdin.write("go\n")
                laptop.stdin.flush()
                log.wait_for("STATE: moving", CMD_S)
                time.sleep(1.5)
                cut = time.time()
                hosts.cut()
                halted = log.wait_for(": halted", CMD_S)
                # When the client said each, by its own clock (the hosts share the machine's).
                silence = out.wait_for("no sign of the server", CMD_S)
                noticed.append(float(silence.split()[0]) - cut)
                told.append(float(out.wait_for("lost ", CMD_S).split()[1]) - cut)
                halts.append(netfaults.log_clock(halted, cut) - cut)
                hosts.mend()
                print(
                    f"cut {k + 1}: halt {halts[-1]:.3f} s, the client said the silence "
                    f"{noticed[-1]:.2f} s, gave up {told[-1]:.2f} s"
                )
            pages = _page_cuts(hosts)
        finally:
            laptop.kill()
            server.kill()
    limit = LEASE_S + 0.5
    held = max(halts) <= limit
    # The client gives up only once the server has halted (`Client.lost_after_s`): nothing it
    # gave up on is done after it said so.
    first = sum(h < t for h, t in zip(halts, told, strict=True))
    print(
        f"{CUTS} cuts mid-move: halt after the cut p50 {statistics.median(halts):.3f} s, "
        f"max {max(halts):.3f} s (target: every one within lease {LEASE_S:g} s + 0.5 s = "
        f"{limit:g} s: {'held' if held else 'NOT held'}); the client said it lost contact "
        f"after p50 {statistics.median(told):.2f} s, max {max(told):.2f} s, having said the "
        f"silence after p50 {statistics.median(noticed):.2f} s, max {max(noticed):.2f} s; "
        f"the halt came "
        f"before the client gave up in {first} of {CUTS} (target: all)"
    )
    page_held = max(pages) <= PAGE_LOST_S
    print(
        f"{PAGE_CUTS} cuts under a remote browser: the page said it lost contact after "
        f"p50 {statistics.median(pages):.2f} s, max {max(pages):.2f} s (target: "
        f"{PAGE_LOST_S:g} s: {'held' if page_held else 'NOT held'})"
    )
    return 0 if held and page_held and first == CUTS else 1


def _page_cuts(hosts: netrig.Hosts) -> list[float]:
    """`al5d web` on the arm's host, a browser on the laptop, the link cut PAGE_CUTS times:
    how long after each cut the page said it lost contact."""
    web = hosts.popen(hosts.arm, [AL5D, "web", "--host", netrig.ARM_IP, "--port", "0"])
    assert web.stdout is not None
    url = Lines(web.stdout).wait_for("al5d web: http", CMD_S).split(": ", 1)[1].strip()
    browser = hosts.popen(hosts.laptop, [sys.executable, "-c", webrig.REMOTE_PAGE, url])
    assert browser.stdout is not None and browser.stdin is not None
    out = Lines(browser.stdout)
    shown: list[float] = []
    try:
        out.wait_for("open", 120)
        for k in range(PAGE_CUTS):
            time.sleep(2.0)
            hosts.cut()
            cut = time.time()
            browser.stdin.write("cut\n")
            browser.stdin.flush()
            shown.append(float(out.wait_for("lost ", CMD_S).split()[1]) - cut)
            time.sleep(1.0)
            hosts.mend()
            out.wait_for("back ", 120)
            print(f"page cut {k + 1}: the page said it lost contact after {shown[-1]:.2f} s")
    finally:
        hosts.mend()
        browser.kill()
        web.kill()
    return shown


if __name__ == "__main__":
    sys.exit(main())
