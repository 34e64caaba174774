"""Two hosts on a network for the tests: the arm's computer and a laptop, each a network
namespace, joined by a veth pair, or by a cable that delays and loses frames
(`al5d_rig.cable`); the link cut and mended with `ip link`.

Each host has a lane folder of its own (`AL5D_RUNTIME_DIR`), so that a client on the laptop
cannot reach the server's local lane through the shared file system: it goes over the
network, by ROS 2, as on two machines. DDS is opened to the network on both
(`ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`, docs/ros.md).

Delay and loss come from the cable rather than `tc netem`: this machine's kernel has no
netem ("Error: Specified qdisc kind is unknown." for `tc qdisc add dev X root netem delay
10ms`).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from types import TracebackType

from al5d.ros.dds import OURS_VAR, PROFILES_VAR
from al5d_rig.proc import Lines, dies_with_parent

#: The two hosts' addresses on their link.
ARM_IP = "10.231.0.1"
LAPTOP_IP = "10.231.0.2"


def unavailable() -> str | None:
    """Why this process cannot make hosts (None: it can)."""
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN); CI runs as root"
    probe = f"al5d-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"`ip netns add` failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def need() -> None:
    """Skips the calling test where hosts cannot be made, saying why; fails it instead in CI
    (which runs as root): the network tests never go quietly unrun there."""
    why = unavailable()
    if why is None:
        return
    import pytest

    message = f"the network tests cannot run here: {why}"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


class Hosts:
    """The arm's host and the laptop, joined by one link, for as long as the `with` block.

    `cable`: the link is `al5d_rig.cable`'s (delay and loss set by `impair`), not a veth
    pair."""

    def __init__(self, tag: str | None = None, cable: bool = False) -> None:
        tag = tag or f"{os.getpid() % 100_000}"
        self.arm = f"al5d-arm-{tag}"
        self.laptop = f"al5d-lap-{tag}"
        self._veth = (f"a5a{tag}"[:15], f"a5l{tag}"[:15])
        self._dirs = {h: Path(tempfile.mkdtemp(prefix=f"{h}-")) for h in (self.arm, self.laptop)}
        self._cable_wanted = cable
        self._cable: subprocess.Popen[str] | None = None

    def __enter__(self) -> Hosts:
        a, b = self._veth
        for ns in (self.arm, self.laptop):
            _ip("netns", "add", ns)
        try:
            if self._cable_wanted:
                self._cable = subprocess.Popen(
                    [sys.executable, "-m", "al5d_rig.cable", a, b],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                    preexec_fn=dies_with_parent,
                )
                assert self._cable.stdout is not None
                Lines(self._cable.stdout).wait_for("ready", 30)
            else:
                _ip("link", "add", a, "type", "veth", "peer", "name", b)
            _ip("link", "set", a, "netns", self.arm)
            _ip("link", "set", b, "netns", self.laptop)
            for ns, dev, addr in ((self.arm, a, ARM_IP), (self.laptop, b, LAPTOP_IP)):
                _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
                _ip("-n", ns, "link", "set", "lo", "up")
                _ip("-n", ns, "link", "set", dev, "up")
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        if self._cable is not None:
            self._cable.kill()
            self._cable.wait(10)
            self._cable = None
        for ns in (self.arm, self.laptop):  # the veth pair goes with its namespaces
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        for d in self._dirs.values():
            shutil.rmtree(d, ignore_errors=True)

    def env(self, host: str) -> dict[str, str]:
        """The environment of a process on `host`: DDS open to the network, its own lanes.
        A Fast DDS profile this process wrote is not passed on: made for a machine's own
        DDS, it binds every socket to the loopback interface."""
        env = {k: v for k, v in os.environ.items() if k not in (PROFILES_VAR, OURS_VAR)}
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        env["AL5D_RUNTIME_DIR"] = str(self._dirs[host])
        return env

    def popen(
        self, host: str, argv: list[str], env: dict[str, str] | None = None
    ) -> subprocess.Popen[str]:
        """`argv` started on `host`, its input and output text through pipes."""
        return subprocess.Popen(
            ["ip", "netns", "exec", host, *argv],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env if env is not None else self.env(host),
            preexec_fn=dies_with_parent,
        )

    def cut(self) -> None:
        """The link goes down (as a cable pulled at the laptop)."""
        _ip("-n", self.laptop, "link", "set", self._veth[1], "down")

    def mend(self) -> None:
        _ip("-n", self.laptop, "link", "set", self._veth[1], "up")

    def one_way(self, on: bool) -> None:
        """The arm's frames to the laptop dropped (`on`) or not, the laptop's to the arm still
        arriving: a link that fails one way (a route on the arm's host that drops them)."""
        _ip("-n", self.arm, "route", "add" if on else "del", "blackhole", f"{LAPTOP_IP}/32")

    def impair(self, delay_ms: float = 0.0, loss_percent: float = 0.0) -> None:
        """Each frame, both ways, lost with `loss_percent` and the others `delay_ms` late
        (from now on; frames in flight keep their delay). Needs `cable`."""
        if self._cable is None or self._cable.stdin is None:
            raise RuntimeError("impair needs Hosts(cable=True)")
        self._cable.stdin.write(f"delay {delay_ms:g}\nloss {loss_percent:g}\n")
        self._cable.stdin.flush()


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")
