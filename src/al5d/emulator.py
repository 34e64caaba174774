"""An emulated SSC-32U on a pseudo terminal, faithful to the board's protocol and timing.

The client (our low-level driver, or anything that speaks to a serial port)
opens the pty's slave like a USB serial adapter. The emulator reads the master
side no faster than the wire would carry the bytes at the baud the client set
(10 bit times a byte), so bytes not yet "sent" stay in the pty and a client's
output flush really drops them. Each byte gets a virtual arrival time; a
command takes effect when its CR arrives. Each servo follows its commanded
pulse at the speed given in the arm configuration, in closed form, so the time
a servo reached its target is known exactly rather than polled.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import fcntl
import math
import os
import queue
import select
import struct
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import NamedTuple

from al5d import protocol as p
from al5d.config import ArmConfig

now = time.monotonic

#: A servo not named in the configuration: 60 deg / 0.19 s at about 10 us/deg.
DEFAULT_SPEED_US_S = 60 / 0.19 * 10
DEFAULT_VERSION = "SSC32-V2.50USB"
#: How long the board takes to start answering a query (manual: 50 us to 5 ms).
DEFAULT_ANSWER_DELAY_S = 0.0003
MAX_LINE = 1024
GARBAGE = b"\xfe?\x00\xff\r"
HISTORY = 100_000  # commands remembered per channel for reach_time

_BAUDS = {
    getattr(termios, f"B{b}"): b
    for b in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
}


class Fault(enum.Enum):
    """Faults the emulator can inject on demand."""

    DISCONNECT = "disconnect"  # the adapter is unplugged: the client's I/O fails
    NO_ANSWER = "no_answer"  # queries are not answered
    GARBAGE = "garbage"  # queries are answered with bytes that are not the board's


@dataclass(frozen=True, slots=True)
class Record:
    """One line as the board received it, with its time of effect (the CR's arrival)."""

    t_effect: float
    raw: bytes
    commands: tuple[p.Command, ...]
    ignored: str | None = None  # why the board did nothing with it

    @property
    def accepted(self) -> bool:
        return self.ignored is None


def _follow(x: float, c: float, r: float, v: float, d: float) -> float:
    """Where a servo at `x` is after `d` s, chasing a pulse at `c` moving at `r` us/s, at most `v`.

    The servo moves toward its pulse at its top speed `v`; once it has caught
    up it tracks the pulse if the pulse moves no faster than `v`.
    """
    while d > 0:
        g = c - x
        if abs(g) < 1e-9:
            if abs(r) <= v:
                return c + r * d
            return x + math.copysign(v, r) * d
        s = 1.0 if g > 0 else -1.0
        closing = v - s * r
        if closing <= 0:
            return x + s * v * d
        t_meet = abs(g) / closing
        if d <= t_meet:
            return x + s * v * d
        c += r * t_meet
        x = c
        d -= t_meet
    return x


@dataclass
class Servo:
    """One channel: its commanded pulse ramp and the physical servo following it."""

    speed_us_s: float
    position_us: float  # physical, at time `t_position`
    t_position: float
    known: bool = False  # has the board had a pulse command for it since power-up?
    on: bool = False  # is the channel putting out pulses?
    start_us: float = 0.0
    end_us: float = 0.0
    t0: float = 0.0
    t1: float = 0.0
    busy_until: float = 0.0  # Q answers '+' until then, even after a STOP
    offset_us: int = 0
    output_high: bool | None = None

    def pulse_at(self, t: float) -> float:
        if not self.on:
            return 0.0
        if t >= self.t1 or self.t1 <= self.t0:
            return self.end_us
        if t <= self.t0:
            return self.start_us
        return self.start_us + (self.end_us - self.start_us) * (t - self.t0) / (self.t1 - self.t0)

    def position_at(self, t: float) -> float:
        """The physical position at `t` >= the last update (pure)."""
        x, tx = self.position_us, self.t_position
        if not self.on or t <= tx:
            return x
        v, off = self.speed_us_s, self.offset_us
        if tx < self.t1:
            b = min(t, self.t1)
            slope = (self.end_us - self.start_us) / (self.t1 - self.t0)
            x = _follow(x, self.pulse_at(tx) + off, slope, v, b - tx)
            tx = b
        if t > tx:
            x = _follow(x, self.end_us + off, 0.0, v, t - tx)
        return x

    def advance(self, t: float) -> None:
        if t > self.t_position:
            self.position_us = self.position_at(t)
            self.t_position = t

    def settle_time(self, tol_us: float) -> float:
        """When the servo came (or will come) within `tol_us` of its final target, to stay."""
        target = self.end_us + self.offset_us
        if not self.on:
            return self.t_position
        t_lo = self.t_position
        # After the ramp the servo closes the rest at top speed: an upper bound.
        gap = abs(self.position_at(max(self.t1, t_lo)) - target)
        t_hi = max(self.t1, t_lo) + gap / self.speed_us_s
        step = 0.001
        t = t_hi
        while t - step > t_lo and abs(self.position_at(t - step) - target) <= tol_us:
            t -= step
        lo, hi = max(t_lo, t - step), t  # outside (or the start) at lo, inside at hi
        if abs(self.position_at(lo) - target) <= tol_us:
            return lo
        for _ in range(30):
            mid = (lo + hi) / 2
            if abs(self.position_at(mid) - target) <= tol_us:
                hi = mid
            else:
                lo = mid
        return hi


class _Slot(NamedTuple):
    """A byte on the virtual wire: when its first bit leaves the client, when its last arrives."""

    start: float
    arrival: float
    byte: int
    heard: bool  # sent at the board's baud; otherwise the board hears noise


class Emulator:
    """An SSC-32U on a pseudo terminal; use as a context manager or start()/close().

    `port` is the path a client opens (the `link` symlink when one is given,
    so that it survives a reconnect). `baud` is the board's own setting: a
    client at another baud is heard as noise, as with the real board.
    """

    def __init__(
        self,
        config: ArmConfig | None = None,
        *,
        baud: int = 9600,
        link: str | os.PathLike[str] | None = None,
        version: str = DEFAULT_VERSION,
        answer_delay_s: float = DEFAULT_ANSWER_DELAY_S,
        initial_pose: Mapping[str, float] | None = None,
    ) -> None:
        self.config = config
        self.baud = baud
        self.version = version
        self.answer_delay_s = answer_delay_s
        self._link = Path(link) if link is not None else None
        self._lock = threading.RLock()  # the board's model
        # The records have a lock of their own: an observer that waits for a record
        # never holds up the board (its answers have to come within milliseconds).
        self._changed = threading.Condition(threading.Lock())
        self._records: list[Record] = []
        self._faults: set[Fault] = set()
        self._servos: dict[int, Servo] = {}
        # Per channel: the servo as each command left it, to answer "when did that move arrive".
        self._history: dict[int, deque[Servo]] = {}
        t = now()
        if config is not None:
            pose = initial_pose if initial_pose is not None else config.presets["park"]
            for name, joint in config.joints.items():
                self._servos[joint.channel] = Servo(
                    speed_us_s=joint.speed_us_s,
                    position_us=joint.to_us(pose.get(name, 0.0)),
                    t_position=t,
                )
        self._master = -1
        self._slave = -1
        self._slave_name = ""
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self._answers: queue.Queue[tuple[float, bytes] | None] = queue.Queue()
        self._wake_r, self._wake_w = -1, -1

    # -- life cycle ------------------------------------------------------

    def start(self) -> Emulator:
        self._open_pty()
        self._running.set()
        self._threads = [
            threading.Thread(target=self._read_loop, name="ssc32u-rx", daemon=True),
            threading.Thread(target=self._answer_loop, name="ssc32u-tx", daemon=True),
        ]
        for th in self._threads:
            th.start()
        return self

    def close(self) -> None:
        self._shutdown_io()
        if self._link is not None and self._link.is_symlink():
            with contextlib.suppress(OSError):
                self._link.unlink()

    def __enter__(self) -> Emulator:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    @property
    def port(self) -> str:
        return str(self._link) if self._link is not None else self._slave_name

    @property
    def device(self) -> str:
        """The pty slave itself (changes on reconnect)."""
        return self._slave_name

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        # Raw before any client opens it, or the line discipline eats CR.
        tty.setraw(slave)
        attrs = termios.tcgetattr(slave)
        speed = getattr(termios, f"B{self.baud}")
        attrs[4] = attrs[5] = speed
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        os.set_blocking(master, False)
        # Packet mode: the master hears of the client's output flushes (TIOCPKT_FLUSHWRITE).
        fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
        self._master, self._slave = master, slave
        self._slave_name = os.ttyname(slave)
        self._wake_r, self._wake_w = os.pipe()
        if self._link is not None:
            tmp = self._link.with_name(self._link.name + ".tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self._slave_name)
            tmp.replace(self._link)

    def _shutdown_io(self) -> None:
        self._running.clear()
        self._answers.put(None)
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        for th in self._threads:
            if th is not threading.current_thread():
                th.join(timeout=2)
        self._threads = []
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = -1
        self._answers = queue.Queue()

    # -- faults ------------------------------------------------------------

    def inject(self, fault: Fault) -> None:
        """Start a fault. DISCONNECT closes the pty: the client's I/O fails until reconnect()."""
        with self._lock:
            self._faults.add(fault)
        if fault is Fault.DISCONNECT:
            self._shutdown_io()

    def clear(self, fault: Fault | None = None) -> None:
        with self._lock:
            if fault is None:
                self._faults.clear()
            else:
                self._faults.discard(fault)

    def reconnect(self) -> None:
        """Plug the adapter back in: a new pty behind the same link; the servos kept their state."""
        with self._lock:
            self._faults.discard(Fault.DISCONNECT)
        if self._running.is_set():
            self._shutdown_io()
        self.start()

    # -- observation (tests, benchmarks, the demo) ----------------------------

    @property
    def records(self) -> list[Record]:
        with self._changed:
            return list(self._records)

    def clear_records(self) -> None:
        with self._changed:
            self._records.clear()

    def wait_for(
        self, predicate: Callable[[list[Record]], bool], timeout: float = 5.0
    ) -> list[Record]:
        """Wait until `predicate(records)` holds; return the records (raises TimeoutError).

        The predicate sees a copy, outside every lock of the board.
        """
        deadline = now() + timeout
        while True:
            with self._changed:
                seen = len(self._records)
                records = list(self._records)
            if predicate(records):
                return records
            with self._changed:
                while len(self._records) == seen:
                    left = deadline - now()
                    if left <= 0:
                        raise TimeoutError(f"emulator: condition not met in {timeout} s")
                    self._changed.wait(left)

    def pulse_us(self, channel: int, t: float | None = None) -> float:
        """The pulse the board puts out on `channel` (0 when off)."""
        with self._lock:
            servo = self._servos.get(channel)
            return servo.pulse_at(now() if t is None else t) if servo else 0.0

    def servo_us(self, channel: int, t: float | None = None) -> float:
        """Where the physical servo on `channel` is, as a pulse width."""
        with self._lock:
            servo = self._servos.get(channel)
            if servo is None:
                return 0.0
            return servo.position_at(max(now() if t is None else t, servo.t_position))

    def servo_degrees(self, t: float | None = None) -> dict[str, float]:
        """Every configured joint's physical angle, through the calibration."""
        if self.config is None:
            return {}
        return {
            name: j.to_deg(self.servo_us(j.channel, t)) for name, j in self.config.joints.items()
        }

    def settle_time(self, tol_deg: float = 1.0, joints: Iterable[str] | None = None) -> float:
        """When every joint came (or will come) within `tol_deg` of its final target, to stay."""
        if self.config is None:
            raise ValueError("settle_time needs the arm configuration")
        names = list(joints) if joints is not None else list(self.config.joints)
        with self._lock:
            times = []
            for name in names:
                joint = self.config.joints[name]
                servo = self._servos[joint.channel]
                times.append(servo.settle_time(tol_deg * abs(joint.us_per_deg)))
            return max(times)

    def reach_time(
        self, t_effect: float, tol_deg: float = 1.0, joints: Iterable[str] | None = None
    ) -> float | None:
        """When the move that took effect at `t_effect` had every joint within `tol_deg`.

        None if a later command (a move or a STOP) changed one of those joints first:
        that move never arrived. Works after the fact, from the servos' history.
        """
        if self.config is None:
            raise ValueError("reach_time needs the arm configuration")
        names = list(joints) if joints is not None else list(self.config.joints)
        latest = t_effect
        with self._lock:
            for name in names:
                joint = self.config.joints[name]
                snap, later = self._snapshot(joint.channel, t_effect)
                if snap is None:
                    continue  # this joint was not part of that move
                settle = snap.settle_time(tol_deg * abs(joint.us_per_deg))
                if later is not None and later < settle:
                    return None
                latest = max(latest, settle)
        return latest

    def trajectory(
        self, t_effect: float, times: Iterable[float], joints: Iterable[str] | None = None
    ) -> dict[str, tuple[list[float], list[float]]]:
        """Per joint, the commanded pulse and the servo position (both in degrees) at `times`,
        as the move that took effect at `t_effect` left them (for plots)."""
        if self.config is None:
            raise ValueError("trajectory needs the arm configuration")
        ts = list(times)
        out: dict[str, tuple[list[float], list[float]]] = {}
        with self._lock:
            for name in joints if joints is not None else self.config.joints:
                joint = self.config.joints[name]
                snap, _ = self._snapshot(joint.channel, t_effect)
                if snap is None:
                    continue
                out[name] = (
                    [joint.to_deg(snap.pulse_at(t)) for t in ts],
                    [joint.to_deg(snap.position_at(t)) for t in ts],
                )
        return out

    def moving(self, t: float | None = None) -> bool:
        with self._lock:
            return self._busy(now() if t is None else t)

    # -- the board -------------------------------------------------------------

    def _client_baud(self) -> int:
        try:
            speed = termios.tcgetattr(self._master)[4]
        except (termios.error, OSError):
            return self.baud
        return _BAUDS.get(speed, 0)

    def _read_loop(self) -> None:
        """Put each byte on a virtual wire at the client's baud and act on each line at its CR.

        Bytes are read from the pty as soon as the client writes them and get
        a slot on the wire: byte after byte, 10 bit times each, starting when
        written or when the wire is free. The master runs in packet mode, so a
        client's output flush (TCOFLUSH) is reported here; it drops the bytes
        whose slot has not begun, as a USB adapter drops what it has not sent.
        """
        wire: deque[_Slot] = deque()
        ends: deque[float] = deque()  # arrival times of the CR/ESC bytes on the wire
        line = bytearray()
        line_free = 0.0  # when the wire has carried the last byte given to it
        master, wake = self._master, self._wake_r
        while self._running.is_set():
            timeout = max(0.0, ends[0] - now()) if ends else 0.5
            try:
                ready, _, _ = select.select([master, wake], [], [], timeout)
            except (OSError, ValueError):
                return
            if wake in ready or not self._running.is_set():
                return
            if master in ready:
                t_seen = now()
                try:
                    packet = os.read(master, 4096)
                except BlockingIOError:
                    packet = b""
                except OSError:
                    return
                if not packet:
                    continue
                if packet[0] != 0:  # a status packet: only a flush of the client's output matters
                    if packet[0] & termios.TIOCPKT_FLUSHWRITE:
                        line_free = self._flush(wire, ends, t_seen, line_free)
                    continue
                baud = self._client_baud()
                heard = baud == self.baud
                bt = p.BITS_PER_BYTE / (baud or self.baud)
                t = max(t_seen, line_free)
                for byte in packet[1:]:
                    wire.append(_Slot(t, t + bt, byte, heard))
                    t += bt
                    if byte in (0x0D, 0x1B):
                        ends.append(t)
                line_free = t
            t_now = now()
            while wire and wire[0].arrival <= t_now:
                _, arrival, byte, heard = wire.popleft()
                if byte in (0x0D, 0x1B):
                    ends.popleft()
                    if not heard:
                        self._record(Record(arrival, bytes(line), (), self._noise_reason()))
                    elif byte == 0x0D:
                        self._execute(bytes(line), arrival)
                    else:
                        self._record(Record(arrival, bytes(line), (), "cancelled by ESC"))
                    line.clear()
                elif len(line) < MAX_LINE:
                    line.append(byte)

    def _noise_reason(self) -> str:
        return f"noise: client at {self._client_baud()} baud, board at {self.baud}"

    @staticmethod
    def _flush(wire: deque[_Slot], ends: deque[float], t_flush: float, line_free: float) -> float:
        """Drop the bytes whose slot had not begun at `t_flush`; return when the wire is free.

        Limit: the kernel reports a flush before any data still unread in the
        master; bytes written a few microseconds before a flush, before this
        thread could read them, are taken as written after it and escape it.
        """
        while wire and wire[-1].start > t_flush:
            if wire.pop().byte in (0x0D, 0x1B):
                ends.pop()
        return wire[-1].arrival if wire else min(line_free, t_flush)

    @staticmethod
    def _sleep_until(t: float) -> None:
        wait = t - now()
        if wait > 0:
            time.sleep(wait)

    def _record(self, rec: Record) -> None:
        with self._changed:
            self._records.append(rec)
            self._changed.notify_all()

    def _busy(self, t: float) -> bool:
        return any(s.busy_until > t for s in self._servos.values())

    def _servo(self, channel: int, t: float) -> Servo:
        servo = self._servos.get(channel)
        if servo is None:
            servo = Servo(speed_us_s=DEFAULT_SPEED_US_S, position_us=1500.0, t_position=t)
            self._servos[channel] = servo
        return servo

    def _execute(self, raw: bytes, t: float) -> None:
        parsed = p.parse_line(raw)
        if isinstance(parsed, p.Unrecognized):
            self._record(Record(t, raw, (), parsed.why))
            return
        notes: list[str] = []
        with self._lock:
            for cmd in parsed:
                self._apply(cmd, t, notes)
        self._record(Record(t, raw, tuple(parsed), "; ".join(notes) if notes else None))

    def _apply(self, cmd: p.Command, t: float, notes: list[str]) -> None:
        match cmd:
            case p.GroupMove():
                self._group_move(cmd, t, notes)
            case p.Stop(channel):
                servo = self._servo(channel, t)
                servo.advance(t)
                held = servo.pulse_at(t)
                servo.start_us = servo.end_us = held
                servo.t0 = servo.t1 = t
                self._remember(channel, servo)
                # busy_until stays: the board keeps answering '+' until the move's time is over.
            case p.QueryMovement():
                self._answer(p.MOVING if self._busy(t) else p.DONE, t)
            case p.QueryPulse(channels):
                pulses = [round(self._servo(ch, t).pulse_at(t)) for ch in channels]
                self._answer(p.encode_pulses(pulses), t)
            case p.Version():
                self._answer(self.version.encode("ascii") + p.CR, t)
            case p.PulseOffset(offsets):
                for ch, off in offsets:
                    servo = self._servo(ch, t)
                    servo.advance(t)
                    servo.offset_us = max(-100, min(100, off))
            case p.DigitalOutput(levels):
                for ch, high in levels:
                    servo = self._servo(ch, t)
                    servo.advance(t)
                    servo.on = False
                    servo.output_high = high

    def _group_move(self, cmd: p.GroupMove, t: float, notes: list[str]) -> None:
        spans: dict[int, tuple[int, int, int | None]] = {}
        targets: dict[int, int] = {}
        for tgt in cmd.targets:
            pw = tgt.pulse_us
            if pw != p.PULSE_OFF and not p.PULSE_MIN_US <= pw <= p.PULSE_MAX_US:
                clipped = min(p.PULSE_MAX_US, max(p.PULSE_MIN_US, pw))
                notes.append(f"channel {tgt.channel}: P{pw} clipped to {clipped}")
                pw = clipped
            targets[tgt.channel] = pw
            servo = self._servo(tgt.channel, t)
            if servo.known and servo.on and pw != p.PULSE_OFF:
                spans[tgt.channel] = (int(servo.pulse_at(t)), pw, tgt.speed_us_s)
        duration = p.group_duration_s(spans, cmd.time_ms)
        first = [ch for ch, pw in targets.items() if pw and not self._servo(ch, t).known]
        if first:
            notes.append(
                "first command since power-up for channel(s) "
                + ",".join(map(str, first))
                + ": speed and time ignored"
            )
        for ch, pw in targets.items():
            servo = self._servo(ch, t)
            servo.advance(t)
            if pw == p.PULSE_OFF:
                servo.on = False
                servo.t1 = servo.busy_until = t
                continue
            servo.output_high = None
            if ch in spans:
                servo.start_us = servo.pulse_at(t)
                servo.t1 = servo.busy_until = t + duration
            else:
                servo.start_us = pw
                servo.t1 = servo.busy_until = t
            servo.on = servo.known = True
            servo.end_us = pw
            servo.t0 = t
            self._remember(ch, servo)

    def _snapshot(self, channel: int, t_effect: float) -> tuple[Servo | None, float | None]:
        """The servo as the command at `t_effect` left it, and when the next command came."""
        history = list(self._history.get(channel, ()))
        i = next((k for k, snap in enumerate(history) if snap.t0 == t_effect), None)
        if i is None:
            return None, None
        return history[i], (history[i + 1].t0 if i + 1 < len(history) else None)

    def _remember(self, channel: int, servo: Servo) -> None:
        history = self._history.setdefault(channel, deque(maxlen=HISTORY))
        history.append(dataclasses.replace(servo))

    def _answer(self, data: bytes, t: float) -> None:
        if Fault.NO_ANSWER in self._faults:
            return
        if Fault.GARBAGE in self._faults:
            data = GARBAGE
        bt = p.BITS_PER_BYTE / self.baud
        self._answers.put((t + self.answer_delay_s + len(data) * bt, data))

    def _answer_loop(self) -> None:
        answers, master = self._answers, self._master
        while True:
            item = answers.get()
            if item is None:
                return
            due, data = item
            self._sleep_until(due)
            try:
                os.write(master, data)
            except OSError:
                return


def serve_forever(emulator: Emulator, stop: threading.Event) -> None:
    """Run until `stop` is set (used by `al5d emulator`)."""
    with emulator:
        print(emulator.port, flush=True)
        stop.wait()
