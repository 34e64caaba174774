"""`al5d web`: the page on a port and its ROS link, until SIGINT or SIGTERM.

The first line on stdout is `al5d web: http://HOST:PORT/` (the port viser bound:
with --port 0 the system picks one, and a busy port makes viser take the next).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from al5d.arm.config import DEFAULT_CONFIG, ArmConfig, load_config
from al5d.interrupts import wait_set

log = logging.getLogger("al5d.web")

DEFAULT_PORT = 8080
#: How long the Calibrate tab waits for the server to say its config file.
SERVED_WAIT_S = 5.0
DEFAULT_HOST = "127.0.0.1"


@dataclass
class WebOptions:
    port: int = DEFAULT_PORT
    host: str = DEFAULT_HOST
    #: The server's ROS namespace; None: the config's (server.namespace), as `al5d serve`.
    namespace: str | None = None
    config: str | None = None
    #: The poses file of the Teach tab; None: `poses.yaml` beside the config (or here).
    poses: str | None = None


class WebView:
    """The page, its guard and its ROS link, started together and closed together."""

    def __init__(self, options: WebOptions, config: ArmConfig | None = None) -> None:
        import viser

        from al5d.arm.poses import beside, load_poses
        from al5d.ros.names import Names
        from al5d.ros.params import served_config_file
        from al5d.web import calibrate, guard, loopsafe
        from al5d.web.link import WebNode
        from al5d.web.page import Page
        from al5d.web.teach import Listeners, Teach
        from al5d.web.twin import TwinView

        # The websocket library's INFO lines (each connection) would drown the page's own.
        logging.getLogger("websockets").setLevel(logging.WARNING)
        # The server's configuration, as a client judges what it sends (`al5d run` too): the
        # file as `al5d serve` reads it (its `--config`).
        config = config or load_config(options.config)
        poses = (Path(options.poses) if options.poses else beside(options.config)).absolute()
        load_poses(poses, required=False)  # a bad file stops here, before the port is taken
        ns = config.server.namespace if options.namespace is None else options.namespace
        self.names = Names.of(ns)
        # viser prints a banner of its own; stdout's first line is ours (the URL).
        with contextlib.redirect_stdout(sys.stderr):
            self.server = viser.ViserServer(host=options.host, port=options.port, verbose=False)
        accepted = guard.install(self.server, options.host)
        loopsafe.install(self.server)
        port = self.server.get_port()
        if not guard.is_loopback(options.host):
            # The port bound, not the one asked for (0, or a busy one viser skipped).
            log.warning(
                "al5d web listens on %s: anyone who can reach port %d there can move the arm",
                options.host,
                port,
            )
        host = options.host if ":" not in options.host else f"[{options.host}]"
        self.url = f"http://{host}:{port}/"
        prefix = config.server.joint_prefix_in(ns)
        title = f"al5d {self.names.namespace or ''}".strip()
        self.page = Page(self.server, config, title, prefix)
        self.teach = Teach(self.page, poses)
        listeners = Listeners(self.page, self.teach)
        self.link = WebNode(self.names, listeners, config.model, tuple(config.presets), prefix)
        self.page.commands = self.link
        self.twin = TwinView(self.page, self.link.context, self.names)  # a twin's, when one runs
        calibrate.attach(
            self.page,
            Path(options.config) if options.config else DEFAULT_CONFIG,
            lambda: served_config_file(self.link.node, self.names, SERVED_WAIT_S),
        )

        def on_client(client: viser.ClientHandle) -> None:
            # Only a page the guard let in counts as opened (`al5d demo --web` waits for one).
            if accepted(client.client_id):
                print("al5d web: a page opened", flush=True)

        self.server.on_client_connect(on_client)

    def close(self) -> None:
        self.teach.player.halt("the web view's end")
        self.twin.close()
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
    threading.Thread(target=_say_where, args=(view, done), daemon=True).start()
    try:
        wait_set(done)  # set by a signal's handler, which this main thread must run
    finally:
        view.close()
    return 0


#: A web view that has not heard its server in this long says which servers it can see.
FIND_SERVER_S = 5.0


def _say_where(view: WebView, done: threading.Event) -> None:
    """Where the server has not been heard in `FIND_SERVER_S`, the servers seen under other
    namespaces, said once (an outside try: with only /left and /right, the page waited
    with no word of them, where `al5d send` names them)."""
    from al5d.ros.answers import elsewhere

    if view.link.heard.wait(FIND_SERVER_S) or done.is_set():
        return
    try:
        seen = elsewhere(view.names, view.link.node)
    except Exception:  # the view ending meanwhile (its node destroyed): nothing to say
        return
    log.warning(
        "web: no al5d server heard at %s yet (%g s; the page shows it once one is)%s",
        view.names.instruction,
        FIND_SERVER_S,
        seen,
    )


#: prctl(2): the signal a child gets when its parent ends.
PR_SET_PDEATHSIG = 1


def _end_with_parent() -> None:
    """In the child, before it runs: SIGTERM when the demo ends, even killed outright (its
    `finally` never runs then), so that no web view is left holding the port. Linux."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


@contextlib.contextmanager
def web_beside(port: int = DEFAULT_PORT, wait_page_s: float = 30.0) -> Iterator[str]:
    """`al5d web` in a process of its own (it must never share the server's GIL), for
    `al5d demo --web`: yields its URL once it serves, after a page opened it or
    `wait_page_s` passed; ended with SIGINT afterwards. `port` 0: any free one."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "al5d", "web", "--port", str(port)],
        stdout=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),
        preexec_fn=_end_with_parent,
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
            deadline = time.monotonic() + wait_page_s
            why = f"no page opened in {wait_page_s:.0f} s"
            with contextlib.suppress(queue.Empty, ValueError):
                # Only a page the guard let in prints this (a refused one never starts it).
                while "page opened" not in lines.get(timeout=deadline - time.monotonic()):
                    pass
                why = "a page opened"
            print(f"al5d demo: {why}; the demo starts", flush=True)
        yield url
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
