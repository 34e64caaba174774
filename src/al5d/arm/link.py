"""The board's connection, kept by the worker: connect, watch the idle link, fault, reconnect.

Everything here runs in the worker's thread (`al5d.arm.worker`) and does board
I/O; what it learns it reports to the protocol (`al5d.arm.core`), which owns
the state. A lost link, a silent or babbling board, or a board that has reset
becomes the `fault` state: every pending move gets its outcome, and the link is
tried again every `reconnect_interval_s` until the board answers; then the pose
is read back and no cancelled move is replayed.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass

from al5d.arm.config import ArmConfig
from al5d.arm.core import Core
from al5d.arm.effects import LinkView
from al5d.arm.translate import Translator
from al5d.ssc32u.driver import SSC32U
from al5d.ssc32u.errors import BoardReset, Interrupted, NotAnSSC32U, SerialFault
from al5d.ssc32u.facts import QP_RESOLUTION_US

log = logging.getLogger("al5d")
RESET_LOCKED = "the arm is locked after the board's reset: send release to go on"
#: How far a pulse read back may be from the one expected at rest: `QP` answers in steps
#: of 10 us (rounded down), and a pose read back is itself one of those steps.
REST_MARGIN_US = 2 * QP_RESOLUTION_US
#: During a motion, how late (or early) the board may be on the driver's schedule: a
#: step of a trajectory goes out one wire time before the one before ends, and a few
#: bytes more or less on the wire are a few ms. The margin is this long at full speed.
MOTION_SLACK_S = 0.02


@dataclass(frozen=True, slots=True)
class Probe:
    """A link check's `QP`: the channel it reads, and the pulses (us) it expects there."""

    joint: str
    channel: int
    low_us: float
    high_us: float
    #: The core's token when the check began: the answer is judged only if no caller's
    #: write began until it came (`Core.untouched`).
    token: int | None


class LinkKeeper:
    """The worker's hold on the board: open it, check it, lose it, get it back."""

    def __init__(self, config: ArmConfig, core: Core, port: str, baud: int) -> None:
        self.config = config
        self.core = core
        self.port = port
        self.baud = baud
        self.settings = config.server
        self.translator = Translator(config)
        self.channels = config.channels

    def _open(self) -> SSC32U:
        return SSC32U(self.port, self.baud, read_timeout_s=self.settings.answer_timeout_s)

    def connect(self) -> None:
        try:
            board = self._open()
        except SerialFault as e:
            log.error("serial fault: %s", e)
            self.core.unreachable(e)
            self.core.announce()
            return
        log.info("connected to %s on %s at %d baud", board.firmware, self.port, self.baud)
        self.core.connected(board)

    def check(self) -> None:
        """An idle arm's link is checked too (`QP` of one channel and its answer are 5 bytes:
        every 0.5 s is 1 % of the wire at 9600 baud), so that a pulled cable, a silent board
        or a reset is a fault at once, not at the next move. A stop never waits for it (the
        query lock is not the stop's)."""
        board = self.core.board
        if board is not None:
            with contextlib.suppress(Interrupted):  # a stop flushed the answer: the link lives
                self.watch(board)

    def watch(self, board: SSC32U) -> None:
        """Check the link, and that the board has not reset: `QP` of one channel (4 bytes,
        as cheap as `Q`), the one of the joint written least recently (a move after a reset
        restores only its own channels). A pulse other than the driver expects there is a
        reset (the pulses of a board with none at power-up are 0, of one with power-up
        pulses those), or something else has moved the servo: either way the board no
        longer holds what the driver believes, and its next move would run at full speed.

        A write from a caller's thread (the fast path, a stop, a cancel) that races the
        query changes the pulse under it: such a check is a link check only."""
        view = self.core.link_view()
        if view is None:  # nothing known to have been lost: the link alone
            board.is_done()
            return
        probe = self._probe(view)
        pulse = board.read_pulses([probe.channel])[probe.channel]
        if self.core.untouched(probe.token) and not probe.low_us <= pulse <= probe.high_us:
            raise self._reset(board, probe.joint, pulse, probe)

    def _probe(self, view: LinkView) -> Probe:
        """The pulses the driver expects on the joint's channel: at rest the known pose's
        pulse, during a motion (or just after one) anything on its way, with margins."""
        joint = view.joint
        config = self.config.joints[joint]
        ends = [view.pose]
        margin = float(REST_MARGIN_US)
        motion = view.motion
        if motion is not None and joint in motion.target:
            ends += [motion.start.get(joint, view.pose), motion.target[joint]]
        if view.way is not None:
            ends += view.way
        if len(ends) > 1:
            margin += MOTION_SLACK_S * config.speed_us_s
        pulses = [config.to_us(deg) for deg in ends]
        return Probe(joint, config.channel, min(pulses) - margin, max(pulses) + margin, view.token)

    def _reset(
        self, board: SSC32U, joint: str, pulse: int = 0, probe: Probe | None = None
    ) -> BoardReset:
        channel = self.config.joints[joint].channel
        if pulse == 0:
            what = "has no pulse any more"
        else:
            assert probe is not None
            expected = f"{probe.low_us:.0f}..{probe.high_us:.0f}"
            what = f"puts out {pulse} us where the driver expects {expected} us"
        return BoardReset(
            board.port,
            f"the board has reset: {joint} (channel {channel}) {what}, and the board has "
            f"forgotten where every servo was; {BoardReset.advice}",
        )

    def read_pose(self, board: SSC32U) -> dict[str, float | None] | None:
        """Where the servos are, from the board; None if stops kept interrupting the read.
        A joint of known pose with no pulse now is a reset (BoardReset)."""
        for _ in range(3):
            try:
                pulses = board.read_pulses(self.channels)
                break
            except Interrupted:
                continue  # another stop flushed the query: ask again
        else:
            return None
        pose = self.translator.degrees(pulses)
        known = self.core.pose()
        lost = [j for j, v in pose.items() if v is None and known.get(j) is not None]
        if lost:  # a reset between the last check and this read (during a stop, say)
            raise self._reset(board, lost[0])
        log.debug(
            "read back: %s", {j: (None if v is None else round(v, 1)) for j, v in pose.items()}
        )
        return pose

    def read_back(self, board: SSC32U | None = None) -> bool:
        """Learn where the servos are (after a stop, at start); False if a stop came while
        reading (the pose is then still a guess: read it again)."""
        board = board or self.core.board
        if board is None:
            return False
        token = self.core.write_token()
        pose = self.read_pose(board)
        return pose is not None and self.core.read_back(pose, token)

    def enter_fault(self, error: SerialFault) -> None:
        """A serial fault (any thread may have seen it): everything pending ends."""
        log.error("serial fault: %s", error)
        ended = self.core.lose(error)
        self.core.announce()
        if isinstance(error, BoardReset):
            log.warning(RESET_LOCKED)
        ended.settle()

    def recover(self) -> None:
        """Reconnect every few tenths of a second; re-learn the positions; no stale move replays."""
        interval = self.settings.reconnect_interval_s
        while self.core.wait_unless_shutdown(interval):
            try:
                board = self._open()
            except SerialFault as e:
                self._reconnect_failed(e)
                continue
            reset = False
            try:
                self.halt_what_was_cancelled(board, "reconnect")
                try:
                    pose = self.read_pose(board)
                except BoardReset as e:  # it restarted while the link was down
                    log.error("serial fault: %s", e)
                    log.warning(RESET_LOCKED)
                    reset = True
                    pose = self.translator.degrees(board.read_pulses(self.channels))
                if pose is None:
                    raise Interrupted("the read-back was interrupted")
            except (SerialFault, Interrupted) as e:
                log.debug("reconnect failed: %s", e)
                board.close()  # it holds the port exclusively: the next try must open it
                continue
            self.core.reconnected(board, pose, reset)
            self.core.announce()
            log.info("reconnected to %s on %s", board.firmware, self.port)
            return

    def halt_what_was_cancelled(self, board: SSC32U, why: str) -> None:
        """A board may still be running a move that was cancelled without a halt (when the
        link went, or by a shutdown), and its client told so: it is halted here, and the pose
        read back is where the arm stopped, not a snapshot of it on its way."""
        if not self.core.q_believed() or not board.is_done():
            board.stop(self.channels)
            log.warning("%s: halted the move the board was still running (cancelled)", why)

    def _reconnect_failed(self, error: SerialFault) -> None:
        """Keep trying; but a device that is not a board is said clearly, once, and becomes
        the fault's reason (a missing port is the usual unplugged cable: quiet)."""
        known = self.core.fault
        if not isinstance(error, NotAnSSC32U):
            log.debug("reconnect failed: %s", error)
            return
        if isinstance(known, NotAnSSC32U) and known.received == error.received:
            log.debug("reconnect failed: %s", error)
            return
        log.warning("reconnect: %s", error)
        self.core.unreachable(error)
