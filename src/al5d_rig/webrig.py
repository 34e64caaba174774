"""The web view's test rig: `al5d web` in its own process, and a real headless Chromium.

Shared by tests/test_web.py and bench/webbench.py. The browser is Debian's
`chromium` (the Makefile installs it), driven by playwright, which cannot download
a browser of its own here. WebGL runs on SwiftShader, Chromium's CPU renderer.
"""

from __future__ import annotations

import contextlib
import io
import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from std_msgs.msg import String

from al5d.ros.names import Names
from al5d.ros.qos import QOS_LATCHED
from al5d_rig.proc import Proc

CHROMIUM = os.environ.get("AL5D_CHROMIUM", "/usr/bin/chromium")
#: Software WebGL: a headless machine has no GPU. The page is composited in software too:
#: through SwiftShader's GL, Chromium's GPU process took 1.35 cores while the arm moved
#: on the page, 0.94 with Skia's software compositor (the WebGL canvas is drawn the same).
CHROMIUM_ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-gpu-compositing",
]
VIEWPORT = {"width": 1280, "height": 800}


class BrowserUnavailable(RuntimeError):
    """Chromium could not be started; the message says why and what to do."""


def launch(playwright: Any) -> Any:
    """Headless Chromium, or BrowserUnavailable with the reason."""
    if not Path(CHROMIUM).exists():
        raise BrowserUnavailable(
            f"no browser at {CHROMIUM}: `make install` installs Debian's chromium"
        )
    try:
        return playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
    except Exception as e:
        raise BrowserUnavailable(f"headless Chromium at {CHROMIUM} did not start: {e}") from e


@contextlib.contextmanager
def chromium() -> Iterator[Any]:
    """Headless Chromium for a test, closed after it; one that cannot start fails the test
    with the reason (never a skip)."""
    import pytest
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        try:
            browser = launch(playwright)
        except BrowserUnavailable as e:
            pytest.fail(str(e))
        try:
            yield browser
        finally:
            browser.close()


class WebProc:
    """`al5d web --port 0` (any free port) in its own process; `url` once it serves."""

    def __init__(self, *args: str) -> None:
        self.proc = Proc("web", "--port", "0", *args)
        line = self.proc.out.wait_for("al5d web: http", 30)
        self.url = line.split(": ", 1)[1].strip()
        self.port = int(self.url.rstrip("/").rsplit(":", 1)[1])

    def close(self) -> None:
        if self.proc.popen.poll() is None:
            self.proc.popen.terminate()
            try:
                self.proc.wait(10)
            except Exception:
                self.proc.kill()


#: How long a page may take to load and show the arm's joint states: viser's client is
#: megabytes of script, and a CI run of six test processes on two cores (four browsers among
#: them) once took over 30 s for it.
PAGE_LOAD_S = 90.0


#: A browser in a process of its own (on another host: `ip netns exec`), the page at
#: argv[1]. It prints "open"; then for each line read (the link cut), "lost EPOCH_S" once
#: the page says it lost contact (when it said so, by the page's clock), the page's words,
#: and "back EPOCH_S" once it is live again.
REMOTE_PAGE = """
import sys, time
from playwright.sync_api import sync_playwright
from al5d_rig.webrig import launch, open_page
with sync_playwright() as playwright:
    browser = launch(playwright)
    page = open_page(browser, sys.argv[1])
    print("open", flush=True)
    for _ in sys.stdin:
        layer = page.wait_for_selector("#al5d-page-lost", timeout=60_000)
        print("lost", int(layer.get_attribute("data-at")) / 1000, flush=True)
        print("text", layer.inner_text().replace(chr(10), " "), flush=True)
        page.wait_for_selector("#al5d-page-lost", state="detached", timeout=120_000)
        print("back", time.time(), flush=True)
    browser.close()
"""


def open_page(browser: Any, url: str, timeout_s: float = PAGE_LOAD_S) -> Any:
    """The page, once the arm's joint states have reached it (the tool readout is there)."""
    page = browser.new_page(viewport=VIEWPORT)
    page.goto(url)
    page.wait_for_selector("#al5d-tool", timeout=timeout_s * 1000)
    return page


def dismiss_notifications(page: Any) -> None:
    """Close viser's toasts (software WebGL, here): they would hide part of the view."""
    for button in page.locator(".mantine-Notification-closeButton").all():
        button.click()


def arm_pixels(png: bytes) -> int:
    """How many pixels of the canvas show the arm's dark parts (base, turntable, wrist).

    The page is white with a light grey grid; only the arm is dark, so a
    canvas where this is 0 did not render the arm (blank, or only the grid)."""
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
    return int(np.count_nonzero(rgb.max(axis=2) < 100))


def arm_box(png: bytes) -> tuple[int, int, int, int] | None:
    """Where the arm's dark parts are in a screenshot: (left, top, right, bottom) in pixels,
    None if none is drawn. Every link has some (its servos, the base, the fingers), so the
    box is the whole arm's."""
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
    ys, xs = np.nonzero(rgb.max(axis=2) < 100)
    if len(xs) == 0:
        return None
    return int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())


def wait_for_arm(page: Any, timeout_s: float = 20.0, at_least: int = 300) -> bytes:
    """A screenshot of the 3D view once the arm is drawn in it."""
    canvas = page.locator("canvas").first
    deadline = time.monotonic() + timeout_s
    while True:
        png: bytes = canvas.screenshot()
        if arm_pixels(png) >= at_least:
            return png
        if time.monotonic() > deadline:
            raise AssertionError(f"the arm was not drawn in {timeout_s} s")
        time.sleep(0.3)


class StateWatch:
    """The server's latched state (/NS/al5d/state), as a ROS client sees it."""

    def __init__(self, node: Any, names: Names) -> None:
        self.states: list[str] = []
        #: When each state came (CLOCK_MONOTONIC), as `states`.
        self.times: list[float] = []
        self._changed = threading.Condition()
        node.create_subscription(String, names.state, self._on, QOS_LATCHED)

    def _on(self, msg: String) -> None:
        t = time.monotonic()
        with self._changed:
            self.states.append(str(msg.data))
            self.times.append(t)
            self._changed.notify_all()

    @property
    def now(self) -> str | None:
        with self._changed:
            return self.states[-1] if self.states else None

    def wait_for(self, state: str, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        with self._changed:
            while not self.states or self.states[-1] != state:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"state {state!r} not reached; states: {self.states}")
                self._changed.wait(left)


def wait_text(
    page: Any, selector: str, want: Callable[[str], bool], timeout_s: float = 10.0
) -> str:
    """The text of `selector` once `want` holds for it."""
    deadline = time.monotonic() + timeout_s
    text = ""
    while time.monotonic() < deadline:
        found = page.locator(selector)
        text = found.first.inner_text() if found.count() else ""  # hidden: not in the page
        if want(text):
            return str(text)
        time.sleep(0.05)
    raise AssertionError(f"{selector}: {text!r} after {timeout_s} s")


def watch_texts(
    page: Any, selector: str, index: int = 0, attribute: str = ""
) -> Callable[[], list[str]]:
    """Every text the `index`th element `selector` finds shows from now on (or every value
    of its `attribute`), as the browser renders them: a text shown for less than a poll of
    `wait_text` takes on a busy machine is kept too."""
    key = "__texts_" + "".join(c if c.isalnum() else "_" for c in f"{selector}{index}{attribute}")
    page.evaluate(
        """([selector, key, index, attribute]) => {
        const seen = (window[key] = []);
        const look = () => {
          const found = document.querySelectorAll(selector)[index];
          const text = !found ? "" : attribute ? found.getAttribute(attribute) : found.innerText;
          if (text && seen[seen.length - 1] !== text) seen.push(text);
        };
        look();
        new MutationObserver(look).observe(document.body, {
          subtree: true, childList: true, characterData: true, attributes: true,
        });
      }""",
        [selector, key, index, attribute],
    )
    return lambda: [str(t) for t in page.evaluate(f"window.{key}")]


def clickable(page: Any, locator: Any) -> bool:
    """Whether `locator` is in the viewport and is what a click at its centre would hit
    (not scrolled away, not under the panel's header, not hidden or unmounted)."""
    if locator.count() != 1:
        return False
    box = locator.bounding_box()
    size = page.viewport_size
    if box is None or box["width"] < 1 or box["height"] < 1:
        return False
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    if not (0 <= x < size["width"] and 0 <= y < size["height"]):
        return False
    return bool(
        locator.evaluate("(e, [x, y]) => e.contains(document.elementFromPoint(x, y))", [x, y])
    )


#: Every control in the side panel, by what it is and its label, and whether a user can
#: still work it: buttons, inputs and slider thumbs shown, not disabled (attribute or
#: aria) and that the pointer reaches (CSS pointer-events). The panel's own chrome (its
#: header) is not ours.
CONTROLS = r"""() => {
  const panel = document.querySelector("#al5d-state").closest("[data-dock-group]");
  const out = [];
  // A slider is its root: Mantine draws no thumb on a disabled one.
  for (const e of panel.querySelectorAll("button, input, .mantine-Slider-root")) {
    if (e.closest("[data-dock-header]") || (e.type || "") === "hidden") continue;
    if (!e.getClientRects().length) continue;  // not shown (another tab's)
    const slider = e.classList.contains("mantine-Slider-root");
    const off = e.disabled || e.getAttribute("aria-disabled") === "true"
      || e.closest("[data-disabled]") !== null || getComputedStyle(e).pointerEvents === "none"
      || (slider && e.querySelector("[data-disabled]") !== null);
    let name = e.innerText || "";  // a button's own text, else the row's label
    for (let n = e.parentElement; !/[a-z]/.test(name) && n && n !== panel; n = n.parentElement)
      name = n.innerText || "";
    out.push([`${slider ? "slider" : e.type || e.tagName} `
      + name.replace(/\s+/g, " ").trim().slice(0, 30), !off]);
  }
  return out;
}"""


def controls(page: Any) -> dict[str, bool]:
    """The side panel's controls over all its tabs (each opened in turn), each with whether
    it works."""
    found: dict[str, bool] = {}
    for tab in ("Joints", "Target", "History"):
        page.get_by_role("tab", name=tab).click()
        for i, (name, works) in enumerate(page.evaluate(CONTROLS)):
            found[f"{tab} {i}: {name}"] = works
    return found
