"""How the client commands report (`al5d send`, `run`, `shell`, `replay`): each outcome as
it comes and the verdict (`Report`), the lines running in the background watched while
nothing waits (`LinkWatch`), and where a command's time went (`Timing`)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import TextIO

from al5d.arm.instruction import Instruction, Outcome, Result
from al5d.ros.answers import no_outcome
from al5d.ros.client import Client, NoOutcome

#: Finding the server slower than this is said (where the time went), even without
#: `--verbose`: a user waiting seconds for a command should know it was discovery.
SLOW_DISCOVERY_S = 1.0


def each_line(prefix: str, text: str) -> str:
    """`text` with `prefix` before each of its lines: a command's error of several lines
    (every bad line of a file) said as its one-line errors are."""
    return prefix + text.replace("\n", "\n" + prefix)


#: Lines held at the most before they are written (a bounded memory, a write per thousand).
HELD_MAX = 1000


class Report:
    """Prints each outcome when it comes, whichever thread it comes in; keeps the verdict."""

    def __init__(self, out: TextIO, timeout: float) -> None:
        self._out = out
        self.timeout = timeout
        self._lock = threading.Lock()
        self.all_done = True
        #: The instructions whose fate has been said: once each.
        self.said: set[str] = set()
        # While a prompt at a terminal waits for a line: the prompt and what is typed after
        # it, drawn again below a line said meanwhile (an outcome of a line run in the
        # background, a lost server), as a shell draws its prompt again below a job's news.
        self._prompt: Callable[[], str] | None = None
        #: Lines said without `flush`, not yet written: held here, not in `out`'s buffer,
        #: which an unbuffered interpreter (PYTHONUNBUFFERED) has not (a write each: a
        #: million refusals of a replay took 49 s, not 41).
        self._held: list[str] = []

    def line(self, text: str, flush: bool = True) -> None:
        """`text` on a line of its own; without `flush`, it may wait for the next line
        flushed, or `flush()` (a replay's refusals, a million of them, a write each)."""
        with self._lock:
            if flush or self._prompt is not None:
                self._print(text)
                return
            self._held.append(text)
            if len(self._held) >= HELD_MAX:
                self._write_held()

    def flush(self) -> None:
        """Every line held written out."""
        with self._lock:
            self._write_held()
            self._out.flush()

    def _write_held(self) -> None:
        if self._held:
            self._out.write("\n".join(self._held) + "\n")
            self._held.clear()

    def at_prompt(self, prompt: Callable[[], str] | None) -> None:
        """A prompt at a terminal is drawn (`prompt`: it and what is typed after it), or is
        no more (None)."""
        with self._lock:
            self._prompt = prompt

    def _print(self, text: str) -> None:
        """`text` on a line of its own, after the lines held (the lock held)."""
        self._write_held()
        if self._prompt is None:
            print(text, file=self._out, flush=True)
            return
        # Over the prompt's line (carriage return, erase to its end), then the prompt again.
        self._out.write(f"\r\x1b[K{text}\n{self._prompt()}")
        self._out.flush()

    def fail(self) -> None:
        """The command is not done, whatever outcomes come (a `wait` cut short)."""
        with self._lock:
            self.all_done = False

    def not_sent(self, instr: Instruction) -> None:
        """`instr` was never sent: a Ctrl-C came first."""
        self.line(f"{instr.name} [{instr.id}]: not sent (Ctrl-C)")
        self.fail()

    def outcome(self, outcome: Outcome | None, *, instr: Instruction) -> None:
        if outcome is None:
            text = str(no_outcome(f"{instr.name} [{instr.id}]", self.timeout))
        else:
            text = str(outcome)
        self._say(instr, text, outcome is not None and outcome.result is Result.DONE)

    def lost(self, instr: Instruction, error: NoOutcome) -> None:
        """Contact with the server was lost (`LostContact`, `LaneLost`) while `instr` ran."""
        self._say(instr, f"{instr.name} {error}", False)

    def _say(self, instr: Instruction, text: str, done: bool) -> None:
        with self._lock:
            if instr.id in self.said:
                return
            self.said.add(instr.id)
            self.all_done &= done
            self._print(text)


#: How often `LinkWatch` looks: the silence is said at 1 s, lost contact at 1.5 s.
WATCH_EVERY_S = 0.1


class LinkWatch:
    """The lines running in the background, watched as a wait for an outcome watches its
    line, also while nothing waits (a `wait` line, the shell's prompt): a silence of the
    server is said, and lost contact (a closed lane) is said at once for each of them, not
    when the command next waits for something; with none running, once, while the command
    waits (`waiting`: a `wait` line, the shell's next line). `lost` is set then. Contact
    that comes back after a loss was said is said too (`al5d shell` goes on after one)."""

    def __init__(self, client: Client, report: Report, background: list[Instruction]) -> None:
        self.client, self.report, self.background = client, report, background
        self.lost = threading.Event()
        #: When this loss of the server was said (monotonic), None while in contact; the
        #: command's thread says a loss too (what it waited for), hence the lock.
        self._gone_said: float | None = None
        self._gone_lock = threading.Lock()
        self._waiting = threading.Event()  # in a `wait` line, at the shell's prompt
        self._ending = threading.Event()
        self._thread = threading.Thread(target=self._run, name="al5d-link-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._ending.wait(WATCH_EVERY_S):
            said, client = self.report.said, self.client
            pending = [i for i in list(self.background) if i.id not in said and client.sent(i.id)]
            for n, item in enumerate(pending):
                try:
                    outcome = client.outcome(item.id, 0.01)  # said by its watcher if it came
                except NoOutcome as e:
                    self.report.lost(item, e)
                    self.said_lost()
                    continue
                if n == 0 and outcome is None:
                    break  # one waiting on a link that holds: so are the others
            if self._gone_said is not None or (not pending and self._waiting.is_set()):
                self._watch_server()

    def said_lost(self) -> None:
        """A loss of the server was said (by this watch, or by the command for what it
        waited for): said again only once contact has come back."""
        self.lost.set()
        with self._gone_lock:
            if self._gone_said is None:
                self._gone_said = time.monotonic()

    def _watch_server(self) -> None:
        """A loss said: contact back is said. The command waits, and nothing of it runs: a
        server lost (a lane closed) is said all the same, once (seen: `al5d run` in a
        ten-minute `wait` said nothing of a server gone until the wait was over)."""
        gone = self.client.out_of_contact()
        if gone is None:
            with self._gone_lock:
                said, self._gone_said = self._gone_said, None
            if said is not None:
                since = time.monotonic() - said
                self.report.line(
                    f"contact with the server again ({since:.1f} s after it was said lost)"
                )
        elif self._gone_said is None and self._waiting.is_set():
            self.said_lost()
            self.report.line(f"{gone}: nothing this command sent is running")

    @contextlib.contextmanager
    def waiting(self) -> Iterator[None]:
        """The command waits (for its next line, in a `wait`): the server is watched."""
        self._waiting.set()
        try:
            yield
        finally:
            self._waiting.clear()

    def sleep(self, seconds: float) -> None:
        """A `wait` line: `seconds`, or less if contact is lost meanwhile (then not done)."""
        with self.waiting():
            if self.lost.wait(seconds):
                self.report.fail()

    def close(self) -> None:
        self._ending.set()
        self._thread.join(1.0)


class Timing:
    """Where a command's time went: ROS's start, the server's discovery, the rest. Said on
    stderr: all of it with `--verbose`, the discovery alone whenever it was slow."""

    def __init__(self, prog: str, verbose: bool, err: TextIO) -> None:
        self.prog = prog
        self.verbose = verbose
        self.err = err
        self.start = time.monotonic()
        self.ros_s = 0.0
        self._told = 0.0

    def ros_started(self) -> None:
        self.ros_s = time.monotonic() - self.start
        if self.verbose:
            self._say(f"ROS started in {self.ros_s:.2f} s")

    def discovered(self, client: Client) -> None:
        """Once the server is found (or not): how long that took, if slow or asked for."""
        waited = client.discovery_s - self._told
        self._told = client.discovery_s
        if self.verbose:
            self._say(f"waited {waited:.2f} s for the server to be discovered")
        elif waited > SLOW_DISCOVERY_S:
            self._say(
                f"waited {waited:.1f} s for the server to be discovered (ROS 2 discovery, "
                "which each new client pays: `al5d shell` pays it once for many instructions)"
            )

    def end(self) -> None:
        if self.verbose:
            self._say(f"{time.monotonic() - self.start:.2f} s in all")

    def _say(self, text: str) -> None:
        print(f"{self.prog}: {text}", file=self.err, flush=True)
