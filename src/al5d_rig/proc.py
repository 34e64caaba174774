"""Running `al5d` commands as separate processes, and reading their output as it comes."""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import errno
import functools
import os
import platform
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import yaml

from al5d.arm.config import DEFAULT_CONFIG

AL5D = str(Path(sys.executable).with_name("al5d"))

_PR_SET_PDEATHSIG = 1
_prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up before any fork


#: A line of Fast DDS's own log (its default consumer prints on stdout, coloured or not:
#: "2026-11-28 16:18:09.319 [RTPS_TRANSPORT_SHM Error] Failed init_port ...", seen when a
#: shared-memory port's lock file was held), not a word of the process that printed it.
#: The project's profile sends that log to stderr; a profile of the user's may not.
_FASTDDS_LOG = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d+ \[\w+ (Error|Warning|Info)\]")
_ESCAPES = re.compile(r"\x1b\[[0-9;]*m")


def _own(line: str) -> bool:
    """Whether a line of a process's stdout is its own (not one of Fast DDS's log lines)."""
    return not _FASTDDS_LOG.match(_ESCAPES.sub("", line))


def said(stream: IO[str]) -> str:
    """The next line of `stream` printed by its process itself, stripped: Fast DDS's log
    lines on the same stdout are passed over. "" at the stream's end."""
    return next((line.strip() for line in stream if _own(line)), "")


def own_lines(text: str) -> list[str]:
    """The lines of `text` (a process's whole stdout) that the process printed itself:
    Fast DDS's log lines on the same stdout are left out."""
    return [line for line in text.splitlines() if _own(line)]


def dies_with_parent() -> None:
    """`preexec_fn` of the rig's processes: killed when the test process dies.

    A pytest worker that crashed left its servers running, with its ROS domain's lock
    released: the worker started in its place claimed the same domain and met them (a CI
    run's tests then failed one after another until the run's time ran out). Linux sends
    the signal when the thread that forked ends: the rig starts processes from the main
    thread only. One foreign call, nothing else, between fork and exec."""
    _prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)


#: The answer timeout of a server whose emulated board is a thread of the busy test
#: process. The board answers within 5 ms; this emulator, on two loaded cores, once missed
#: the 0.15 s of two asks during a CI run, and once 0.5 s (four workers and two busy loops
#: beside them), and the server rightly took it for a lost link (the test's move ended
#: `cancelled`). Tests that are about faults keep the default.
PATIENT_ANSWER_S = 1.0


def patient_config_text() -> str:
    """The packaged configuration file, comments and all, with `PATIENT_ANSWER_S`."""
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    shipped = "answer_timeout_s: 0.05 "
    assert shipped in text, "the packaged answer timeout moved"
    return text.replace(shipped, f"answer_timeout_s: {PATIENT_ANSWER_S:<4} ")


@functools.cache
def patient_config(speeds: tuple[tuple[str, float], ...] = (), **server: float) -> str:
    """The packaged configuration with `server.answer_timeout_s` at `PATIENT_ANSWER_S`, for
    a server whose emulated board is a thread of the busy test process. `speeds`: joints'
    speeds (deg/s); `server`: other settings of the `server` section."""
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["server"]["answer_timeout_s"] = PATIENT_ANSWER_S
    data["server"].update(server)
    for joint, speed in speeds:
        data["joints"][joint].pop("servo", None)
        data["joints"][joint]["speed_deg_s"] = speed
    path = Path(tempfile.mkdtemp(prefix="al5d-test-")) / "al5d.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


class Lines:
    """The lines of a stream, collected by a thread so that a test can wait for one."""

    def __init__(self, stream: IO[str]) -> None:
        self.all: list[str] = []
        self._cursor = 0  # wait_for looks after the line it matched last
        self._q: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._pump, args=(stream,), daemon=True).start()

    def _pump(self, stream: IO[str]) -> None:
        for line in stream:
            self._q.put(line.rstrip("\n"))
        self._q.put(None)

    def _next(self, deadline: float) -> str | None:
        """The next line that comes before `deadline` (None: none came, or the stream ended)."""
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        try:
            line = self._q.get(timeout=left)
        except queue.Empty:
            return None
        if line is not None:
            self.all.append(line)
        return line

    def wait_for(self, text: str, timeout: float = 20.0) -> str:
        """The next line (after the last one matched) that contains `text`; if none comes,
        the error holds every line since the last match (up to 200: a process's start-up
        log, where a child process said why it ended, is often longer than 30)."""
        start = self._cursor
        for i in range(self._cursor, len(self.all)):
            if text in self.all[i]:
                self._cursor = i + 1
                return self.all[i]
        deadline = time.monotonic() + timeout
        while (line := self._next(deadline)) is not None:
            if text in line:
                self._cursor = len(self.all)
                return line
        self._cursor = len(self.all)
        got = self.all[max(start, len(self.all) - 200) :]
        raise AssertionError(f"no line with {text!r} in {timeout} s; got:\n" + "\n".join(got))

    def wait_for_each(self, texts: Sequence[str], timeout: float = 20.0) -> list[str]:
        """The lines (after the last one matched) that hold each of `texts`, in whichever
        order they come: two processes writing to one stream (a server and its child) each
        through a logging thread of its own may have their lines cross, the effect's line
        before its cause's. Each of `texts` is looked for once (give each once)."""
        if not texts:
            return []
        start = seen = self._cursor
        found: dict[str, int] = {}
        deadline = time.monotonic() + timeout
        while True:
            for i in range(seen, len(self.all)):
                for text in texts:
                    if text not in found and text in self.all[i]:
                        found[text] = i
            seen = len(self.all)
            if len(found) == len(texts):
                self._cursor = max(found.values()) + 1
                return [self.all[found[text]] for text in texts]
            if self._next(deadline) is None:
                missing = [t for t in texts if t not in found]
                got = self.all[max(start, len(self.all) - 200) :]
                raise AssertionError(
                    f"no line with {missing!r} in {timeout} s; got:\n" + "\n".join(got)
                )

    def drain(self, timeout: float = 2.0) -> list[str]:
        """Every line so far, after waiting up to `timeout` for more (or for the end)."""
        deadline = time.monotonic() + timeout
        while self._next(deadline) is not None:
            pass
        # And every line read from the stream by then (`_next` takes none past its deadline:
        # drain(0) would return no line that came since the last call).
        with contextlib.suppress(queue.Empty):
            while (line := self._q.get_nowait()) is not None:
                self.all.append(line)
        return self.all


#: Every `Proc` still running, killed when this process ends: a server a test failed to end
#: (its teardown raised first) would live on in the ROS domain that this run held, and the
#: next run to claim that domain would take its answers for its own server's.
_LIVE: weakref.WeakSet[Proc] = weakref.WeakSet()


#: Every `Tty` still referenced (closed or not: what it drew is kept), for a failure's
#: report (`said_so_far`).
_TTYS: weakref.WeakSet[Tty] = weakref.WeakSet()


@atexit.register
def _kill_live() -> None:
    for proc in list(_LIVE):
        with contextlib.suppress(Exception):
            proc.kill()


def stacks(pid: int, timeout: float = 60.0) -> str:
    """Every thread's stack in the Python process `pid` and its children now (py-spy, with
    the native frames of C extensions such as rclpy's), for a failure's reader: where a
    process that went silent is waiting (a server waits on its bridge and its stop
    process)."""
    spy = str(Path(sys.executable).with_name("py-spy"))
    said = ""
    for native in (["--native"], []):  # the Python frames alone where native ones fail
        try:
            done = subprocess.run(
                [spy, "dump", *native, "--subprocesses", "--pid", str(pid)],
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        except (OSError, subprocess.TimeoutExpired) as e:
            said += f"(no stacks: {e})\n"
            continue
        said += done.stdout + done.stderr
        if done.returncode == 0:
            break
    return said


class Proc:
    """An `al5d` subcommand in its own process (or, with `program`, another program: the
    venv's Python running a user's script), with its stdout and stderr lines."""

    def __init__(
        self,
        *args: str,
        env: dict[str, str] | None = None,
        stdin: bool = False,
        program: str = AL5D,
        cwd: Path | None = None,
        group: bool = False,
    ) -> None:
        """`group`: in a process group of its own (its children too), as a shell or systemd
        starts a service, for a signal to the whole group."""
        _LIVE.add(self)
        self.started = time.monotonic()
        self.command = " ".join(("al5d" if program == AL5D else Path(program).name, *args))
        self.popen = subprocess.Popen(
            [program, *args],
            stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **(env or {})},
            preexec_fn=dies_with_parent,
            cwd=cwd,
            process_group=0 if group else None,
        )
        assert self.popen.stdout is not None and self.popen.stderr is not None
        self.out = Lines(self.popen.stdout)
        self.err = Lines(self.popen.stderr)

    def stacks(self) -> str:
        """Every thread's stack in the process now (py-spy), for a failure's reader: where a
        server that went silent is waiting."""
        return stacks(self.popen.pid)

    def send(self, line: str) -> None:
        assert self.popen.stdin is not None
        self.popen.stdin.write(line + "\n")
        self.popen.stdin.flush()

    def wait(self, timeout: float = 30.0) -> int:
        """Its exit code; still running after `timeout`, a failure that shows what it said
        and where it waits."""
        try:
            return self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            said = "\n".join(self.err.drain(0.5)[-30:])
            raise AssertionError(
                f"{self.command} still running after {timeout} s; "
                f"its stderr:\n{said}\n{self.stacks()}"
            ) from None

    def kill(self) -> None:
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait(5)


def family(pid: int) -> list[int]:
    """Process `pid` and every process it started, and theirs (`al5d serve`: the owner, the
    ROS bridge and the stop's process)."""
    found = [pid]
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            for child in (task / "children").read_text().split():
                found += family(int(child))
    return found


def kill_all(pids: list[int]) -> None:
    """SIGKILL each of `pids` (a `family`), its children before their parent. One already
    gone is not an error (seen: a CI run beside two busy loops found the bridge gone by the
    time the test came to kill it). Children first: killed after their parent, they died
    with it (`dies_with_parent`) and were reaped at once, and their pids could already
    belong to another process (pids wrap, at 32,768 on the CI machine): a CI run's worker
    was once killed outright, with nothing said, as its test killed a server this way."""
    for pid in reversed(pids):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def freeze(pid: int, timeout: float = 30.0) -> None:
    """SIGSTOP process `pid` and wait until it is stopped: the signal stops a process only
    once each of its threads is scheduled again (an idle CI run read the bridge as running
    after the stop it was to miss had been written)."""
    os.kill(pid, signal.SIGSTOP)
    deadline = time.monotonic() + timeout
    while (now := run_state(pid)) != "T":
        if time.monotonic() > deadline:
            raise AssertionError(f"process {pid} not stopped in {timeout:g} s (state {now})")
        time.sleep(0.01)


def run_state(pid: int) -> str:
    """`T` where every thread of process `pid` is stopped, else the state letter of one that
    is not (/proc/PID/task/TID/stat)."""
    states = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):  # a thread that ended meanwhile
            states.add((task / "stat").read_text().rsplit(")", 1)[1].split()[0])
    return "T" if states == {"T"} else min(states - {"T"}, default="?")


def thread_nices(pid: int) -> list[int]:
    """The nice value of every thread of process `pid` (/proc/PID/task/TID/stat, field 19)."""
    nices = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            stat = (task / "stat").read_text()
            nices.append(int(stat.rsplit(")", 1)[1].split()[16]))
    return nices


#: tgkill(2)'s number, by the machine (`platform.machine()`).
SYS_TGKILL = {"x86_64": 234, "aarch64": 131}


def to_another_thread(pid: int, sig: int) -> None:
    """`sig` to a thread of the process `pid` other than its main one that does not block
    it (tgkill(2)), as the kernel may hand a process's signal to any such thread; Python
    then runs the handler only when the main thread next runs. A thread that ends on the
    way is passed over (an idle CI run: its /proc status gone as it was read). Raises
    OSError where that fails or there is no such thread."""
    others = [
        int(task.name)
        for task in sorted(Path(f"/proc/{pid}/task").iterdir())
        if int(task.name) != pid and not _blocked(task / "status", sig)
    ]
    number = SYS_TGKILL.get(platform.machine())
    if number is None:
        raise OSError(f"tgkill: its system call's number on {platform.machine()} is not known")
    libc = ctypes.CDLL(None, use_errno=True)
    for tid in others:
        if libc.syscall(number, pid, tid, sig) == 0:
            return
        if ctypes.get_errno() != errno.ESRCH:
            raise OSError(ctypes.get_errno(), f"tgkill({pid}, {tid}, {sig})")
    raise OSError(f"process {pid} has no thread but its main one that takes signal {sig}")


def _blocked(status: Path, sig: int) -> bool:
    """Whether the thread whose /proc status is `status` blocks `sig` (or has ended)."""
    try:
        text = status.read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True  # it has ended: it takes no signal
    for line in text.splitlines():
        if line.startswith("SigBlk:"):
            return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    return False


class Tty:
    """A process of `args` at a terminal of its own (a pseudo terminal): what it draws,
    read whole (a prompt is no line), and what the test types."""

    def __init__(self, args: list[str]) -> None:
        self.master, slave = os.openpty()
        env = {**os.environ, "TERM": "dumb"}  # no terminal's escapes but the shell's own
        self.command = " ".join(args)
        self.proc = subprocess.Popen(
            args, stdin=slave, stdout=slave, stderr=slave, env=env, preexec_fn=dies_with_parent
        )
        os.close(slave)
        _TTYS.add(self)
        self.started = time.monotonic()
        self.drawn = ""
        self._cursor = 0
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self.master, 4096)
            except OSError:  # EIO: the process's end of the terminal closed
                return
            if not data:
                return
            with self._lock:
                self.drawn += data.decode(errors="replace")

    def type(self, text: str) -> None:
        os.write(self.master, text.encode())

    def wait_for(self, pattern: str, timeout: float) -> re.Match[str]:
        """The first match of `pattern` drawn after the last match."""
        deadline = time.monotonic() + timeout
        while True:
            with self._lock:
                found = re.compile(pattern).search(self.drawn, self._cursor)
                if found is not None:
                    self._cursor = found.end()
                    return found
                if time.monotonic() > deadline:
                    drawn = self.drawn[self._cursor :]
                    break
            time.sleep(0.05)
        # Where it waits, taken now: the test's cleanup ends it before the report is made.
        where = stacks(self.proc.pid) if self.proc.poll() is None else "(it has ended)"
        raise AssertionError(
            f"nothing drawn matches {pattern!r} in {timeout} s; drawn since the last "
            f"match:\n{drawn!r}\n{where}"
        )

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait(10)
        os.close(self.master)


def said_so_far(since: float, lines: int = 120) -> str:
    """What each `Proc` and `Tty` started at or after `since` (monotonic) said, its last
    `lines` lines, and where each still running waits (`stacks`): for the report of a test
    that failed. A failure seen once in a CI run (a server's stderr with one "Traceback"
    line; a shell that drew nothing for 90 s) left nothing else to find its cause by."""
    parts: list[str] = []
    procs = sorted((p for p in list(_LIVE) if p.started >= since), key=lambda p: p.started)
    ttys = sorted((t for t in list(_TTYS) if t.started >= since), key=lambda t: t.started)
    for proc in procs:
        try:
            parts += _said_by(proc, lines)
        except Exception as error:  # one process's report must not lose the others'
            parts.append(f"--- {proc.command}: not read: {error!r}")
    for tty in ttys:
        running = tty.proc.poll() is None
        state = "running" if running else f"ended with {tty.proc.returncode}"
        with tty._lock:
            drawn = tty.drawn.splitlines()[-lines:]
        parts.append(f"--- {tty.command} at a terminal ({state}); drawn:")
        parts += [repr(line) for line in drawn]
        if running:
            parts.append(stacks(tty.proc.pid, REPORT_STACKS_S))
    return "\n".join(parts)


#: py-spy's limit for each process's stacks in a failure's report: within the test's own
#: timeout, which ends the worker, report and all, when it passes.
REPORT_STACKS_S = 15.0


def _said_by(proc: Proc, lines: int) -> list[str]:
    running = proc.popen.poll() is None
    state = "running" if running else f"ended with {proc.popen.returncode}"
    # One that ended: its last lines (a traceback, often) may still be on their way in.
    wait = 0.0 if running else 0.5
    err = proc.err.drain(wait)[-lines:]
    out = proc.out.drain(wait)[-lines:]
    parts = [f"--- {proc.command} ({state}); its stderr, last {len(err)} lines:", *err]
    parts += [f"--- its stdout, last {len(out)} lines:", *out]
    if running:
        parts.append(stacks(proc.popen.pid, REPORT_STACKS_S))
    return parts
