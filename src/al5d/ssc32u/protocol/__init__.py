"""The SSC-32U serial protocol: pure encoding and parsing of commands and answers.

One place for the bytes of the board, used by both sides: the low-level driver
encodes commands and parses answers, the emulator parses commands and encodes
answers. Nothing here does I/O. Use it as one namespace
(`from al5d.ssc32u import protocol as p`; `p.GroupMove`, `p.parse_line`):

    commands.py   the commands as frozen dataclasses, CR and ESC, the wire time
    encode.py     the client's side: each command as its bytes, checked
    answers.py    the board's answers, encoded and parsed
    grammar.py    the board's side: a received line read into commands
"""

from __future__ import annotations

from al5d.ssc32u.facts import TIME_MAX_MS
from al5d.ssc32u.protocol.answers import (
    VERSION_ANSWER_BYTES,
    count_answers,
    encode_pulses,
    last_answer,
    parse_digital,
    parse_movement,
    parse_pulses,
    parse_register,
    parse_startup,
    parse_version,
)
from al5d.ssc32u.protocol.commands import (
    CANCEL,
    CR,
    ESC,
    AppendStartup,
    ByteOutput,
    ChannelTarget,
    Command,
    DefaultRegisters,
    DeleteStartup,
    DigitalOutput,
    GroupMove,
    ProtocolError,
    PulseOffset,
    Query,
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
    wire_time_s,
)
from al5d.ssc32u.protocol.encode import (
    encode,
    encode_byte_output,
    encode_digital_output,
    encode_group_move,
    encode_input_reads,
    encode_pulse_offset,
    encode_query_movement,
    encode_query_pulse,
    encode_register_read,
    encode_register_write,
    encode_startup_append,
    encode_startup_delete,
    encode_stop,
    encode_version,
    move_prefix,
    time_suffix,
)
from al5d.ssc32u.protocol.grammar import group_duration_s, parse_line

__all__ = [
    "CANCEL",
    "CR",
    "ESC",
    "TIME_MAX_MS",
    "VERSION_ANSWER_BYTES",
    "AppendStartup",
    "ByteOutput",
    "ChannelTarget",
    "Command",
    "DefaultRegisters",
    "DeleteStartup",
    "DigitalOutput",
    "GroupMove",
    "ProtocolError",
    "PulseOffset",
    "Query",
    "QueryMovement",
    "QueryPulse",
    "ReadAnalog",
    "ReadDigital",
    "ReadRegister",
    "ShowStartup",
    "Stop",
    "Unrecognized",
    "Version",
    "WriteRegister",
    "count_answers",
    "encode",
    "encode_byte_output",
    "encode_digital_output",
    "encode_group_move",
    "encode_input_reads",
    "encode_pulse_offset",
    "encode_pulses",
    "encode_query_movement",
    "encode_query_pulse",
    "encode_register_read",
    "encode_register_write",
    "encode_startup_append",
    "encode_startup_delete",
    "encode_stop",
    "encode_version",
    "group_duration_s",
    "last_answer",
    "move_prefix",
    "parse_digital",
    "parse_line",
    "parse_movement",
    "parse_pulses",
    "parse_register",
    "parse_startup",
    "parse_version",
    "time_suffix",
    "wire_time_s",
]
