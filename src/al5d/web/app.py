"""`al5d web`: the page on a port and its ROS link, until SIGINT or SIGTERM.

The first line on stdout is `al5d web: http://HOST:PORT/` (the port viser bound:
with --port 0 the system picks one, and a busy port makes viser take the next).
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass

from al5d.arm.config import ArmConfig, load_config

log = logging.getLogger("al5d.web")

DEFAULT_PORT = 8080
DEFAULT_HOST = "127.0.0.1"


@dataclass
class WebOptions:
    port: int = DEFAULT_PORT
    host: str = DEFAULT_HOST
    #: The server's ROS namespace; None: the config's (server.namespace), as `al5d serve`.
    namespace: str | None = None
    config: str | None = None


class WebView:
    """The page, its guard and its ROS link, started together and closed together."""

    def __init__(self, options: WebOptions, config: ArmConfig | None = None) -> None:
        import viser

        from al5d.ros.runtime import Names
        from al5d.web import guard
        from al5d.web.link import Link
        from al5d.web.page import Page

        # The websocket library's INFO lines (each connection) would drown the page's own.
        logging.getLogger("websockets").setLevel(logging.WARNING)
        config = config or load_config(options.config)
        ns = config.server.namespace if options.namespace is None else options.namespace
        self.names = Names.of(ns)
        if not guard.is_loopback(options.host):
            log.warning(
                "al5d web listens on %s: anyone who can reach port %d there can move the arm",
                options.host,
                options.port,
            )
        # viser prints a banner of its own; stdout's first line is ours (the URL).
        with contextlib.redirect_stdout(sys.stderr):
            self.server = viser.ViserServer(host=options.host, port=options.port, verbose=False)
        guard.install(self.server, options.host)
        host = options.host if ":" not in options.host else f"[{options.host}]"
        self.url = f"http://{host}:{self.server.get_port()}/"
        self.page = Page(self.server, config, f"al5d {self.names.namespace or ''}".strip())
        self.link = Link(self.names, self.page, config.model, tuple(config.presets))
        self.page.commands = self.link
        self.server.on_client_connect(lambda client: print("al5d web: a page opened", flush=True))

    def close(self) -> None:
        self.link.close()
        self.page.close()
        with contextlib.redirect_stdout(sys.stderr):
            self.server.stop()


def serve_web(options: WebOptions) -> int:
    done = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        done.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    view = WebView(options)
    print(f"al5d web: {view.url}", flush=True)
    log.info(
        "web: ROS 2 client of the server at %s (ROS_DOMAIN_ID=%s)",
        view.names.instruction,
        os.environ.get("ROS_DOMAIN_ID", "0"),
    )
    try:
        done.wait()
    finally:
        view.close()
    return 0


@contextlib.contextmanager
def web_beside(port: int = DEFAULT_PORT, wait_page_s: float = 30.0) -> Iterator[str]:
    """`al5d web` in a process of its own (it must never share the server's GIL), for
    `al5d demo --web`: yields its URL once it serves, after a page opened it or
    `wait_page_s` passed; ended with SIGINT afterwards."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "al5d", "web", "--port", str(port)],
        stdout=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),
    )
    assert proc.stdout is not None
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)

    try:
        first = proc.stdout.readline().strip()
        if not first.startswith("al5d web: http"):
            raise RuntimeError(f"al5d web did not start: {first!r}")
        url = first.split(": ", 1)[1]
        threading.Thread(target=pump, daemon=True).start()
        print(f"al5d demo: the web view is at {url}", flush=True)
        if wait_page_s > 0:
            print(
                f"al5d demo: open it; the demo starts when a page connects "
                f"(or in {wait_page_s:.0f} s)",
                flush=True,
            )
            with contextlib.suppress(queue.Empty):
                while "page opened" not in lines.get(timeout=wait_page_s):
                    pass
        yield url
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
