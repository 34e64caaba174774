"""The web view's figures: STOP clicked in a real browser until STOP on the board, the view's
update rate while a move runs, the page's state lag (the server's state change until the
page shows it), and the web process's CPU while idle. The STOP and the state lag are judged
against floors measured in the same run (`floors.ratio_row`): a bare viser page whose
button writes the same STOP bytes to an emulated board of its own, and a bare viser page's
element set from Python until the browser's DOM has it.

Five processes: the emulated board (`al5d emulator --record -`, its times not held up
by this process's GIL), `al5d serve --port LINK`, `al5d web`, headless Chromium, and
this one (playwright and a ROS peer). Every time is CLOCK_MONOTONIC, which the
processes share, except the click's: the browser stamps it with the wall clock
(`performance.timeOrigin + performance.now()`), and the bench maps it onto the
monotonic clock with an offset measured against the page (the uncertainty is
printed: half the best round trip of the calibration).

    .venv/bin/python bench/webbench.py          # prints the figures, writes bench/out/web.json
    .venv/bin/python bench/webbench.py --state-lag   # the page's state lag alone
    .venv/bin/python bench/webbench.py --trials 20    # fewer trials of each (default 50 and 40)
"""

from __future__ import annotations

import json
import os
import random
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from al5d_rig import domains

HERE = Path(__file__).resolve().parent
# A pair of domains claimed as a test run claims them: a random one met a running
# suite's servers (their states reached its page).
if "ROS_DOMAIN_ID" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import floors  # noqa: E402
from playwright.sync_api import sync_playwright  # noqa: E402
from rosbench import STOP_BYTES, proc_stat  # noqa: E402
from stats import figure  # noqa: E402
from tables import table as run_table  # noqa: E402

from al5d.arm.config import load_config  # noqa: E402
from al5d.ros.names import Names  # noqa: E402
from al5d.ssc32u import protocol as p  # noqa: E402
from al5d.ssc32u.emulator import Record  # noqa: E402
from al5d_rig.boardproc import BoardProcess  # noqa: E402
from al5d_rig.proc import Proc  # noqa: E402
from al5d_rig.rospeer import Peer, wait_until  # noqa: E402
from al5d_rig.webrig import StateWatch, WebProc, dismiss_notifications, launch, open_page  # noqa: E402

OUT = HERE / "out"
BAUD = 9600
#: The page stamps a click on STOP as the browser dispatches it (capture phase, before
#: viser's own handler sends the message).
STAMP_CLICKS = """() => {
  window.__stops = [];
  document.addEventListener("click", (e) => {
    const b = e.target.closest("button");
    const now = performance.timeOrigin + performance.now();
    if (b && b.innerText.includes("STOP")) window.__stops.push(now);
  }, true);
}"""
#: Each change of the tool readout as the page's DOM takes it (a MutationObserver: headless
#: Chromium runs no animation frames unless something asks for a picture).
COUNT_UPDATES = """() => {
  window.__updates = [];
  let last = null;
  new MutationObserver(() => {
    const el = document.getElementById("al5d-tool");
    const text = el ? el.textContent : null;
    if (text !== last) { window.__updates.push(performance.now()); last = text; }
  }).observe(document.body, { childList: true, subtree: true, characterData: true });
}"""


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def clock_offset(page: Any, rounds: int = 30) -> tuple[float, float]:
    """(page wall-clock ms minus our monotonic ms, uncertainty ms): the tightest round trip."""
    best = (float("inf"), 0.0)
    for _ in range(rounds):
        t0 = time.monotonic()
        wall_ms = page.evaluate("performance.timeOrigin + performance.now()")
        t1 = time.monotonic()
        rtt = (t1 - t0) * 1000
        if rtt < best[0]:
            best = (rtt, wall_ms - (t0 + t1) / 2 * 1000)
    return best[1], best[0] / 2


def stops_after(records: list[Record], n0: int) -> list[Record]:
    return [r for r in records[n0:] if any(isinstance(c, p.Stop) for c in r.commands)]


def click_to_stops(page: Any, button: Any, board: BoardProcess) -> tuple[float, float, float]:
    """`button` clicked in `page` until the first and the sixth STOP in effect on `board`
    (ms), and the clock's uncertainty (ms). The page stamps its clicks (STAMP_CLICKS)."""
    offset, err = clock_offset(page, 5)
    n1 = len(board.records)
    button.click()
    records = board.wait_for(lambda rs, n1=n1: len(stops_after(rs, n1)) >= 6, 10)
    clicked_ms = page.evaluate("window.__stops[window.__stops.length - 1]") - offset
    stops = stops_after(records, n1)
    return stops[0].t_effect * 1000 - clicked_ms, stops[5].t_effect * 1000 - clicked_ms, err


def stop_clicks(
    page: Any, board: BoardProcess, peer: Peer, state: StateWatch, trials: int = 50
) -> dict[str, Any]:
    """STOP clicked in the page while a long move runs, until the STOPs take effect."""
    page.evaluate(STAMP_CLICKS)
    stop = page.get_by_role("button", name="STOP")
    wire_all = p.wire_time_s(STOP_BYTES, BAUD) * 1000
    first_line = len(p.CANCEL) + len(b"STOP0\r")
    wire_first = p.wire_time_s(first_line, BAUD) * 1000
    to_all: list[float] = []
    to_first: list[float] = []
    offsets: list[float] = []
    for trial in range(trials):
        n0 = len(board.records)
        peer.send(f"web-long-{trial}", "move", 5000, base=60 if trial % 2 else -60)
        board.wait_for(
            lambda rs, n0=n0: any(b"T5000" in r.raw for r in rs[n0:]), 10
        )  # the move runs on the board
        time.sleep(0.05 + random.random() * 0.1)
        first, every, err = click_to_stops(page, stop, board)
        to_first.append(first)
        to_all.append(every)
        offsets.append(err)
        state.wait_for("stopped", 5)
        assert peer.trigger("release").success
        state.wait_for("ready", 5)
    return {
        "click_to_all_stops": figure(
            "STOP click -> every STOP in effect", to_all, wire_ms=wire_all
        ),
        "software": figure("STOP click -> every STOP, minus wire", [x - wire_all for x in to_all]),
        "click_to_first_stop": figure(
            "STOP click -> first STOP in effect", to_first, wire_ms=wire_first
        ),
        "clock_uncertainty_ms": max(offsets),
    }


def bare_viser_stop(browser: Any, workdir: Path, trials: int = 50) -> dict[str, Any]:
    """The web STOP's floor: a bare viser page on a server in this process, whose one button
    writes ESC and STOP for every channel (the bytes our server writes for a stop) to an
    emulated board of its own (`al5d emulator` in its own process, on a pty, at the same
    baud) from viser's event loop as the click comes: no ROS, no server, no state."""
    import serial
    import viser

    config = load_config()
    link = workdir / "floor-stop"
    board = BoardProcess(link, BAUD, config)
    port = serial.Serial(str(link), BAUD, timeout=0)
    stop_bytes = p.CANCEL + p.encode_stop(sorted(j.channel for j in config.joints.values()))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        button = server.gui.add_button("STOP")

        async def on_click(_: Any) -> None:
            os.write(port.fileno(), stop_bytes)

        button.on_click(on_click)
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{server.get_port()}/")
        stop = page.get_by_role("button", name="STOP")
        stop.wait_for(timeout=30_000)
        page.evaluate(STAMP_CLICKS)
        wire_all = p.wire_time_s(STOP_BYTES, BAUD) * 1000
        to_all: list[float] = []
        for _ in range(trials):
            _, every, _ = click_to_stops(page, stop, board)
            to_all.append(every)
            time.sleep(wire_all / 1000 + 0.05 + random.random() * 0.1)
        page.close()
        return {
            "click_to_all_stops": figure(
                "bare viser page: STOP click -> every STOP in effect", to_all, wire_ms=wire_all
            ),
            "software": figure(
                "bare viser page: STOP click -> every STOP, minus wire",
                [x - wire_all for x in to_all],
            ),
        }
    finally:
        server.stop()
        port.close()
        board.close()


#: viser's client reads its websocket in a Web Worker (which playwright's websocket events
#: do not see) and posts each batch of messages to the page: counted here, before the page
#: loads, the batches that move a frame of the scene (the arm's links follow joint states).
COUNT_SCENE_BATCHES = """
window.__scene = [];
const ViserWorker = window.Worker;
window.Worker = class extends ViserWorker {
  constructor(...args) {
    super(...args);
    this.addEventListener("message", (event) => {
      const batch = event.data && event.data.messages;
      if (batch && batch.some((m) => /^SetOrientation|^SetPosition/.test(m.type || ""))) {
        window.__scene.push(performance.now());
      }
    });
  }
};
"""


def update_rate(page: Any, peer: Peer, state: StateWatch, move_ms: int = 3000) -> dict[str, Any]:
    """Per second over the middle of a move: the batches of scene updates the page received
    (the arm drawn anew), and the redraws of its tool readout (a text that viser's GUI
    sends at most every 50 ms)."""
    page.add_init_script(COUNT_SCENE_BATCHES)
    page.reload()
    page.wait_for_selector("#al5d-tool", timeout=30_000)
    dismiss_notifications(page)
    time.sleep(1.0)
    page.evaluate(COUNT_UPDATES)
    t_page0 = page.evaluate("performance.now()")
    peer.send("web-rate", "move", move_ms, base=-60 if random.random() < 0.5 else 60)
    assert peer.result("web-rate", 30).outcome == "done"
    state.wait_for("ready", 5)
    updates = page.evaluate("window.__updates")
    scene = page.evaluate("window.__scene")
    # The middle of the move: away from its start (the instruction's trip) and its end.
    lo, hi = 0.5, move_ms / 1000 - 0.3
    span = hi - lo

    def rate(times: list[float]) -> float:
        return sum(1 for u in times if lo <= (u - t_page0) / 1000 <= hi) / span

    return {
        "scene_updates_per_s": rate(scene),
        "page_updates_per_s": rate(updates),
        "window_s": span,
    }


#: Each text the state element shows, stamped (wall clock) as the page's DOM takes it.
WATCH_STATE = """() => {
  window.__states = [];
  let last = null;
  new MutationObserver(() => {
    const el = document.getElementById(window.__stateId || "al5d-state");
    const text = el ? el.textContent : null;
    if (text !== last) {
      window.__states.push([performance.timeOrigin + performance.now(), text]);
      last = text;
    }
  }).observe(document.body, { childList: true, subtree: true, characterData: true });
}"""


def shown_so_far(page: Any) -> int:
    """How many texts the watched element has shown (`WATCH_STATE`): where to look from for
    what the next change shows."""
    return int(page.evaluate("window.__states.length"))


def shown_at(page: Any, text: str, since: int, timeout_s: float = 5.0) -> float | None:
    """The page's wall-clock ms when its watched element first showed `text` among what it
    showed after its first `since` texts (`shown_so_far`); None if it did not within
    `timeout_s`. By the page's own order, not by the time: a time mapped from this process's
    clock is only as good as the offset (half a round trip to a busy browser: 18 ms), and a
    state shown within it of the send was taken for one shown before it, never shown."""
    deadline = time.monotonic() + timeout_s
    while True:
        for t, shown in page.evaluate("window.__states")[since:]:
            if shown == text:
                return float(t)
        if time.monotonic() > deadline:
            return None
        time.sleep(0.02)


def state_lag(
    page: Any, peer: Peer, state: StateWatch, trials: int = 40
) -> tuple[list[float], int, float]:
    """The server's state changes (moving, then ready: a 300 ms move), as a ROS client hears
    them, until the page shows them, in ms; how many the page never showed (within 5 s);
    and the clock's uncertainty."""
    page.evaluate(WATCH_STATE)
    lags: list[float] = []
    missed = 0
    worst = 0.0
    for trial in range(trials):
        offset, err = clock_offset(page, 5)
        worst = max(worst, err)
        n0 = len(state.times)
        since = shown_so_far(page)
        peer.send(f"web-lag-{trial}", "move", 300, base=20 if trial % 2 else -20)
        assert peer.result(f"web-lag-{trial}", 30).outcome == "done"
        state.wait_for("ready", 5)
        for word in ("moving", "ready"):
            i = state.states.index(word, n0)
            heard_ms = state.times[i] * 1000 + offset
            shown = shown_at(page, word.upper(), since)
            if shown is None:
                missed += 1
            else:
                lags.append(shown - heard_ms)
        time.sleep(0.1 + random.random() * 0.1)
    return lags, missed, worst


def bare_viser_lag(browser: Any, trials: int = 40) -> tuple[list[float], float]:
    """The floor: a bare viser page (one HTML element, nothing else) on a server in this
    process: its content set here (and flushed, as the page does a state) until the
    browser's DOM has it, in ms."""
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        element = server.gui.add_html('<div id="bare">0</div>')
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{server.get_port()}/")
        page.wait_for_selector("#bare", timeout=30_000)
        page.evaluate("window.__stateId = 'bare'")
        page.evaluate(WATCH_STATE)
        lags: list[float] = []
        worst = 0.0
        for trial in range(1, trials + 1):
            offset, err = clock_offset(page, 5)
            worst = max(worst, err)
            since = shown_so_far(page)
            t0 = time.monotonic() * 1000 + offset
            element.content = f'<div id="bare">{trial}</div>'
            server.flush()  # at once, as the page sends a state (not in viser's next window)
            shown = shown_at(page, str(trial), since)
            assert shown is not None, "the bare page did not show its content in 5 s"
            lags.append(shown - t0)
            time.sleep(0.1 + random.random() * 0.1)
        page.close()
        return lags, worst
    finally:
        server.stop()


def state_lags(
    page: Any, peer: Peer, state: StateWatch, browser: Any, trials: int = 40
) -> dict[str, Any]:
    log(f"the page's state lag, then a bare viser page's, {trials} + {trials} times")
    lags, missed, err_page = state_lag(page, peer, state, trials)
    floor, err_floor = bare_viser_lag(browser, trials)
    return {
        "page": figure("server state heard -> shown in the page", lags, missed=missed),
        "floor": figure("bare viser page: content set -> in its DOM", floor),
        "clock_uncertainty_ms": max(err_page, err_floor),
    }


def idle_cpu(pid: int, seconds: float = 10.0) -> float:
    cpu0, _ = proc_stat(pid)
    time.sleep(seconds)
    cpu1, _ = proc_stat(pid)
    return (cpu1 - cpu0) / seconds * 100


def run(
    log: Any = log, trials: int = 50, only_state_lag: bool = False, lag_trials: int = 40
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    workdir = Path(tempfile.mkdtemp(prefix="al5d-webbench-"))
    config = load_config()
    board = BoardProcess(workdir / "ssc32u", BAUD, config)
    server = Proc("serve", "--port", str(workdir / "ssc32u"), "--log-level", "INFO")
    web: WebProc | None = None
    peer: Peer | None = None
    try:
        server.err.wait_for("STATE: ready", 30)
        web = WebProc()
        peer = Peer(name="al5d_webbench_peer")
        state = StateWatch(peer.node, Names())
        peer.wait_for_server()
        if not only_state_lag:
            log("web process CPU while idle, no page open (10 s)")
            out["web_idle_cpu_no_page_percent"] = idle_cpu(web.proc.popen.pid)
        with sync_playwright() as playwright:
            browser = launch(playwright)
            try:
                page = open_page(browser, web.url)
                dismiss_notifications(page)
                time.sleep(2.0)
                if only_state_lag:
                    out["state_lag"] = state_lags(page, peer, state, browser, lag_trials)
                    return out
                log("web process and server CPU while idle, the page open (10 s)")
                cpu0 = proc_stat(server.popen.pid)[0]
                out["web_idle_cpu_percent"] = idle_cpu(web.proc.popen.pid)
                out["server_idle_cpu_with_page_percent"] = (
                    (proc_stat(server.popen.pid)[0] - cpu0) / 10 * 100
                )
                log(f"STOP clicked in the page, {trials} times, each during a 5 s move")
                out["stop"] = stop_clicks(page, board, peer, state, trials)
                log(f"the floor: STOP clicked in a bare viser page, {trials} times")
                out["stop_floor"] = bare_viser_stop(browser, workdir, trials)
                log("the view's update rate during a 3 s move")
                out["updates"] = update_rate(page, peer, state)
                out["state_lag"] = state_lags(page, peer, state, browser, lag_trials)
            finally:
                browser.close()
        wait_until(lambda: state.now == "ready", 5, "ready")
    finally:
        if peer is not None:
            peer.close()
        if web is not None:
            web.close()
        if server.popen.poll() is None:
            server.popen.send_signal(signal.SIGTERM)
            server.wait(60)
        board.close()
    return out


#: The issue's targets for the web view's figures (the STOP and the state lag are judged as
#: ratios to their floors, `floors.ratio_row`).
UPDATES_PER_S = 20.0
STATE_LAG_P99_MS = 100.0


def state_lag_rows(lag: dict[str, Any]) -> list[tuple[str, str, str, str, bool | None]]:
    page, floor = lag["page"], lag["floor"]
    return [
        floors.ratio_row(
            f"web: the page's state lag (state heard -> shown, n={page['n']}; "
            "floor: a bare viser page's element)",
            page,
            floor,
        ),
        (
            "web: the page's state lag, p99 (state heard by a ROS client -> shown)",
            f"p50 {page['p50_ms']:.1f} ms, p99 {page['p99_ms']:.1f} ms, "
            f"never shown {page['missed']} (clock within {lag['clock_uncertainty_ms']:.2f} ms)",
            "-",
            f"p99 <= {STATE_LAG_P99_MS:.0f} ms",
            page["p99_ms"] <= STATE_LAG_P99_MS and not page["missed"],
        ),
    ]


def rows(r: dict[str, Any]) -> list[tuple[str, str, str, str, bool | None]]:
    """The web view's figures as rows of bench/run.py's table (figure, ours, design doc,
    target, held), so that they count in its tally of targets held."""
    stop, floor, u = r["stop"], r["stop_floor"], r["updates"]
    return [
        floors.ratio_row(
            f"web: STOP click -> every STOP in effect (wire "
            f"{stop['click_to_all_stops']['wire_ms']:.1f} ms, n={stop['click_to_all_stops']['n']}; "
            "floor: a bare viser page's button)",
            stop["click_to_all_stops"],
            floor["click_to_all_stops"],
        ),
        (
            "  ... the same minus the wire: ours / the floor's",
            f"p50 {stop['software']['p50_ms']:.1f} / {floor['software']['p50_ms']:.1f} ms, "
            f"p99 {stop['software']['p99_ms']:.1f} / {floor['software']['p99_ms']:.1f} ms",
            "-",
            "(information)",
            None,
        ),
        (
            "web: view updates in the page during a move",
            f"{u['scene_updates_per_s']:.1f}/s scene updates "
            f"({u['page_updates_per_s']:.1f}/s redraws of the tool readout)",
            "-",
            f">= {UPDATES_PER_S:.0f}/s",
            u["scene_updates_per_s"] >= UPDATES_PER_S,
        ),
        *state_lag_rows(r["state_lag"]),
        (
            "web: web process CPU while idle, page open / no page; server's, page open",
            f"{r['web_idle_cpu_percent']:.1f} % / {r['web_idle_cpu_no_page_percent']:.1f} %; "
            f"{r['server_idle_cpu_with_page_percent']:.1f} %",
            "-",
            "-",
            None,
        ),
    ]


def main() -> int:
    t0 = time.monotonic()
    trials = int(sys.argv[sys.argv.index("--trials") + 1]) if "--trials" in sys.argv else None
    load0 = os.getloadavg()
    if "--state-lag" in sys.argv:  # that figure alone (a minute)
        r = run(only_state_lag=True, lag_trials=trials or 40)
        lines = state_lag_rows(r["state_lag"])
    else:
        r = run(trials=trials or 50, lag_trials=trials or 40)
        lines = rows(r)
        OUT.mkdir(exist_ok=True)
        (OUT / "web.json").write_text(json.dumps(r, indent=1))
    print(run_table(lines))
    load1 = os.getloadavg()
    print(
        f"({time.monotonic() - t0:.0f} s; load average {load0[0]:.1f} at the start, "
        f"{load1[0]:.1f} at the end)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
