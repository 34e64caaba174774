"""The board's side of the protocol: a received line read into commands, as the board does.

With the board's rule for how long a group move takes.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from al5d.ssc32u.facts import BLANKS, CHANNELS, REGISTERS
from al5d.ssc32u.protocol.commands import (
    AppendStartup,
    ByteOutput,
    ChannelTarget,
    Command,
    DefaultRegisters,
    DeleteStartup,
    DigitalOutput,
    GroupMove,
    PulseOffset,
    QueryMovement,
    QueryPulse,
    ReadAnalog,
    ReadDigital,
    ReadRegister,
    ShowStartup,
    Stop,
    Unrecognized,
    Version,
    WriteRegister,
)

# Order matters where one token starts another: STOP and SSDEL before SS, QP before Q,
# VER before VE, RDFLT before R<n>, AL before A.
_TOKEN = re.compile(
    rb"#(?P<ch>\d+)(?:PO(?P<off>[+-]?\d+)|P(?P<pw>\d+)(?:S(?P<spd>\d+))?|(?P<hl>[HL]))"
    rb"|#(?P<bank>\d+):(?P<byte>\d+)"
    rb"|T(?P<t>\d+)"
    rb"|STOP(?P<stop>\d+)"
    rb"|SSDEL(?P<ssdel>\d+)?"
    rb"|(?P<ss>SS)"
    rb"|QP(?P<qp>\d+)"
    rb"|(?P<q>Q)"
    rb"|(?P<ver>VER)"
    rb"|V(?P<analog>[A-H])"
    rb"|(?P<rdflt>RDFLT)"
    rb"|R(?P<reg>\d+)(?:=(?P<val>[+-]?\d+))?"
    rb"|(?P<digital>[A-F])(?P<latched>L)?"
)
_SSCAT = b"SSCAT"


def _startup_append(line: bytes) -> AppendStartup | None:
    """`SSCAT <text>` when the line is one: its text is everything after SSCAT and the one
    blank that follows it, spaces included (UG-39), so it cannot go through the blank-free
    tokens. Line feeds are dropped even there: a CR LF client puts one in every line."""
    line = line.replace(b"\n", b"")
    i = 0
    for letter in _SSCAT:
        while i < len(line) and line[i] in BLANKS:
            i += 1
        if i >= len(line) or line[i] & 0xDF != letter:
            return None
        i += 1
    if i < len(line) and line[i] in b" \t":
        i += 1
    return AppendStartup(line[i:].decode("latin-1"))


def parse_line(line: bytes) -> list[Command] | Unrecognized:
    """The commands of one line (without its CR), as the board reads them.

    Case, spaces, tabs and line feeds do not matter (UG-24). A line that does not
    parse as a whole is returned as `Unrecognized`: the board ignores it, and so
    does the emulator. Pulse widths outside 500..2500 are returned as sent;
    clipping is the board's business, not the grammar's.
    """
    text = line.translate(None, BLANKS).upper()
    shown = line.decode("ascii", "replace")
    if not text:
        return Unrecognized(shown, "empty line")
    if (append := _startup_append(line)) is not None:
        return [append]
    commands: list[Command] = []
    targets: list[ChannelTarget] = []
    offsets: list[tuple[int, int]] = []
    levels: list[tuple[int, bool]] = []
    time_ms: int | None = None
    group_at: int | None = None  # where the group move goes among the commands
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            return Unrecognized(shown, f"cannot read {text[pos : pos + 12]!r} at column {pos}")
        pos = m.end()
        g = m.groupdict()
        if g["ch"] is not None:
            ch = int(g["ch"])
            if ch not in CHANNELS:
                return Unrecognized(shown, f"channel {ch} is outside 0..31")
            if g["off"] is not None:
                offsets.append((ch, int(g["off"])))
            elif g["hl"] is not None:
                levels.append((ch, g["hl"] == b"H"))
            else:
                spd = int(g["spd"]) if g["spd"] is not None else None
                targets.append(ChannelTarget(ch, int(g["pw"]), spd))
                if group_at is None:
                    group_at = len(commands)
        elif g["bank"] is not None:
            bank, value = int(g["bank"]), int(g["byte"])
            if bank not in range(4) or value not in range(256):
                return Unrecognized(shown, f"byte output #{bank}:{value} is outside 0..3:0..255")
            commands.append(ByteOutput(bank, value))
        elif g["t"] is not None:
            time_ms = int(g["t"])
            if group_at is None:
                group_at = len(commands)
        elif g["stop"] is not None:
            commands.append(Stop(int(g["stop"])))
        elif g["qp"] is not None:
            ch = int(g["qp"])
            if commands and isinstance(commands[-1], QueryPulse):
                commands[-1] = QueryPulse((*commands[-1].channels, ch))
            else:
                commands.append(QueryPulse((ch,)))
        elif g["q"] is not None:
            commands.append(QueryMovement())
        elif g["ver"] is not None:
            commands.append(Version())
        elif m.group().startswith(b"SSDEL"):
            if g["ssdel"] is None:  # not SS, D, EL: a command word is read whole
                return Unrecognized(shown, "SSDEL without a count")
            commands.append(DeleteStartup(int(g["ssdel"])))
        elif g["ss"] is not None:
            commands.append(ShowStartup())
        elif g["analog"] is not None:
            commands.append(ReadAnalog(g["analog"].decode("ascii")))
        elif g["rdflt"] is not None:
            commands.append(DefaultRegisters())
        elif g["reg"] is not None:
            number = int(g["reg"])
            if number not in REGISTERS:
                return Unrecognized(shown, f"register {number} is outside 0..255")
            if g["val"] is None:
                commands.append(ReadRegister(number))
            else:
                commands.append(WriteRegister(number, int(g["val"])))
        else:
            commands.append(ReadDigital(g["digital"].decode("ascii"), g["latched"] is not None))
    if time_ms is not None and not targets:
        return Unrecognized(shown, "T without any channel to move")
    if targets and group_at is not None:
        commands.insert(group_at, GroupMove(tuple(targets), time_ms))
    if offsets:
        commands.append(PulseOffset(tuple(offsets)))
    if levels:
        commands.append(DigitalOutput(tuple(levels)))
    return commands


def group_duration_s(
    moves: Mapping[int, tuple[int, int, int | None]], time_ms: int | None
) -> float:
    """The board's duration rule: max(T, max over channels of |delta pw| / S).

    `moves` maps channel -> (from us, to us, speed us/s or None).
    """
    longest = (time_ms or 0) / 1000.0
    for start, end, speed in moves.values():
        if speed:
            longest = max(longest, abs(end - start) / speed)
    return longest
