"""Starting DDS as this project needs it: the environment's defaults, the Fast DDS profile
(loopback only unless the user opens it, a deeper shared-memory port, the instruction
reader's bound, Fast DDS's log on stderr) and the ROS context (a DDS participant)."""

from __future__ import annotations

import atexit
import contextlib
import os
import tempfile
import time
from collections.abc import Sequence
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.signals import SignalHandlerOptions

from al5d.ros.workarounds import discovery_on_our_transports


def ros_environment() -> None:
    """Defaults that must be set before rclpy starts: local discovery, a writable log dir."""
    # Nobody on the network drives the arm unless the user opens it on purpose.
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not any(os.path.isdir(os.environ.get(v, "")) for v in ("ROS_LOG_DIR", "ROS_HOME", "HOME")):
        os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="al5d-ros-log-")


#: Fast DDS reads its XML profiles from this file, named at its start.
PROFILES_VAR = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: The profiles file this project wrote (a child process may write its own over it); any
#: other file in PROFILES_VAR is the user's, and kept.
OURS_VAR = "AL5D_DDS_PROFILES_FILE"
#: Messages a process's shared-memory port holds before Fast DDS drops what comes next (its
#: default is 512: about 50 ms of a 10,000/s flood, or half of the outcomes one stop gives
#: a full queue).
SHM_PORT_QUEUE = 8192
#: The largest RTPS message a writer fills with a fragment of a large sample (bytes), below
#: the 65,500 of the UDP transport that sizes the participant's send buffers.
#:
#: Fast DDS 2.14 sizes a writer's fragments for the whole message and only then adds, to
#: each sample, the inline QoS that tells filtered readers which filters it passed
#: (ContentFilterInfo: 36 bytes for one filter, 16 more for each further one; the stop
#: watcher's reader is filtered, `workarounds.filter_content`). One filter just fits; with
#: two (a restarted server's watcher beside the one of the server before it, whose stop
#: process ended without saying goodbye and stays matched until its lease ends) every
#: fragment overflowed its message ("Cannot add RTPS submesage to the CDRMessage. Buffer
#: too small", over and over), and the writer never delivered a sample larger than a
#: fragment (eProsima/Fast-DDS#6017). 600 bytes less holds the inline QoS of the 32 filters
#: a writer tracks (Fast DDS's default `reader_filters_allocation`: 532 bytes) however Fast
#: DDS packs a fragment, and costs a 1 MB sample no fragment more (16 either way).
WRITER_MESSAGE = 64_900
#: How often a reliable writer asks its readers what they lack (Fast DDS's heartbeat, 3 s
#: by default; in ns, below a second). A reader says what it has when asked: with the
#: default, a sample lost on a lossy link went again up to 3 s later, and a writer waiting
#: for its readers to have what it sent (`Publisher.wait_for_all_acked`: a closing client's
#: last words, `al5d.ros.leasing.Leaser.close`) waited for the heartbeat, 1.0 to 2.9 s
#: here, where the closing client waits 0.5 s at most and so waited that long every time
#: (`al5d replay`, the Python client over ROS 2). With 100 ms: 0.1 s.
HEARTBEAT_NS = 100_000_000
_PROFILES = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">{library}
  <profiles>
    <!-- al5d: Fast DDS's own transports (shared memory, UDPv4){udp_note}. -->
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>al5d_shm</transport_id>
        <type>SHM</type>{port_queue}
      </transport_descriptor>
      <transport_descriptor>
        <transport_id>al5d_udp</transport_id>
        <type>UDPv4</type>{loopback}
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="al5d" is_default_profile="true">
      <rtps>
        <userTransports>
          <transport_id>al5d_shm</transport_id>
          <transport_id>al5d_udp</transport_id>
        </userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
      </rtps>
    </participant>
    <!-- al5d: every writer's fragments leave room for the content filters' inline QoS,
         and it asks its readers what they lack more often than every 3 s. -->
    <data_writer profile_name="al5d_writer" is_default_profile="true">
      <times>
        <heartbeatPeriod>
          <sec>0</sec>
          <nanosec>{heartbeat_ns}</nanosec>
        </heartbeatPeriod>
      </times>
      <propertiesPolicy>
        <properties>
          <property>
            <name>fastdds.max_message_size</name>
            <value>{writer_message}</value>
          </property>
        </properties>
      </propertiesPolicy>
    </data_writer>{reader}
  </profiles>
  <!-- al5d: Fast DDS's own log on stderr, where a process's stdout stays its own. -->
  <log>
    <use_default>FALSE</use_default>
    <consumer>
      <class>StdoutErrConsumer</class>
      <property>
        <name>stderr_threshold</name>
        <value>Log::Kind::Info</value>
      </property>
    </consumer>
  </log>
</dds>
"""
_LOOPBACK = """
        <interfaceWhiteList>
          <address>127.0.0.1</address>
        </interfaceWhiteList>"""
_PORT_QUEUE = """
        <port_queue_capacity>{n}</port_queue_capacity>"""
_READER = """
    <!-- al5d serve: at most {limit} instructions wait in DDS for the server to take them. -->
    <data_reader profile_name="{topic}">
      <topic>
        <resourceLimitsQos>
          <max_samples>{limit}</max_samples>
          <max_instances>1</max_instances>
          <max_samples_per_instance>{limit}</max_samples_per_instance>
          <allocated_samples>{allocated}</allocated_samples>
        </resourceLimitsQos>
      </topic>
    </data_reader>"""


#: Fast DDS hands a message from a writer to a reader of the same process directly (its
#: intra-process delivery) unless told not to.
_NOT_IN_PROCESS = """
  <library_settings>
    <intraprocess_delivery>OFF</intraprocess_delivery>
  </library_settings>"""


def local_only() -> bool:
    """Is DDS kept to this machine? Yes unless the user opened discovery to the network
    (`ROS_AUTOMATIC_DISCOVERY_RANGE` SUBNET or SYSTEM_DEFAULT; README, "Reaching the node
    from another machine")."""
    ros_environment()
    return os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"].strip().upper() in ("LOCALHOST", "OFF")


def dds_profile(instructions: tuple[str, int] | None = None, in_process: bool = True) -> str | None:
    """Write this process's Fast DDS profile and name it in FASTRTPS_DEFAULT_PROFILES_FILE;
    the user's own file, if one is named there (then it applies, not ours).

    Every process of the project (the server, the clients, the web view) binds its UDP
    sockets to the loopback interface unless the user opened DDS to the network
    (`local_only`): discovery kept to this machine is not enough, since a participant
    still listens on every interface for anyone who knows its port. Every process's
    shared-memory port is deeper than Fast DDS's default (below), and every writer's
    fragments leave room for the content filters' inline QoS (`WRITER_MESSAGE`), and Fast
    DDS logs on stderr: its default prints on stdout, where its lines ("Failed init_port
    fastrtps_port7002: open_and_lock_file failed" when other processes hold shared-memory
    ports) fell among a script's own output and spoiled what read it. The server's
    (`instructions`: the topic and its backlog) also bounds that topic's reader:

    With KEEP_ALL and no bound, a flood faster than the server piles up in its reader,
    and a stop sent on the topic waits behind the pile (seconds). With the bound, the
    reader refuses what it cannot hold, and reliable delivery holds it at the sender,
    slowing it.

    The port: under a 10,000/s flood Fast DDS's default of 512 messages overflowed now
    and then. What it dropped was lost to the stop watcher (best effort), and a stop
    request, a stop on the topic or an outcome came 1 to 3 s late, when DDS repaired
    the loss (6 stops in 4 floods of 30 s, and once an outcome lost for good, its
    reader 10,000 results behind by then); with 8192, none in 5 floods. A client's port
    overflows as well: a stop that cancels a full queue sends 1,025 outcomes at once,
    and three servers flooded beside busy loops lost 19 to 12,839 outcomes a flood on
    their way to their readers, whose ports held 512.

    Without `in_process`, a reader and a writer of the same process exchange messages
    through the shared-memory transport, as those of two processes do, not Fast DDS's
    intra-process delivery. `al5d serve --record` asks for that: its recorder is a
    participant in the server's process, and twice in the suite's runs (one of them CI's)
    it matched the server's `/joint_states` writer and then recorded none of its messages
    for the whole run, while it recorded every other topic of that same participant and
    `al5d record`, in a process of its own, held 133 of them. Not reproduced in 40 runs of
    a server recording beside two busy loops, so the cause is not proven: the lost topic
    is the one written while the two participants match (10 a second), and Fast DDS 2.14
    tells a matched in-process reader what to skip with a single message (a GAP when the
    writer matches it), which a reader that has not matched the writer yet ignores. Over
    the transport the recorder is matched, and repaired, as every other reader is.

    Must run before the process's first ROS context starts (Fast DDS reads the file
    once).
    """
    named = os.environ.get(PROFILES_VAR)
    if named and named != os.environ.get(OURS_VAR):
        return named
    local = local_only()
    reader = ""
    if instructions is not None:
        topic, limit = instructions
        reader = _READER.format(topic=topic, limit=limit, allocated=min(limit, 100))
    profile = _PROFILES.format(
        udp_note=", UDP on the loopback interface only" if local else "",
        port_queue=_PORT_QUEUE.format(n=SHM_PORT_QUEUE),
        loopback=_LOOPBACK if local else "",
        reader=reader,
        writer_message=WRITER_MESSAGE,
        heartbeat_ns=HEARTBEAT_NS,
        library="" if in_process else _NOT_IN_PROCESS,
    )
    fd, path = tempfile.mkstemp(prefix="al5d-dds-", suffix=".xml")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(profile)
    # Fast DDS has read it by the time the process ends; a process this one starts that
    # uses DDS writes a file of its own (above: ours is not the user's).
    atexit.register(_remove, path)
    os.environ[PROFILES_VAR] = os.environ[OURS_VAR] = path
    return None


def _remove(path: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def start_context(args: Sequence[str] | None = None) -> Context:
    """A ROS context (a DDS participant); the process's DDS profile first, if none is named.
    `args`: a command line whose `--ros-args` (remaps, parameters) apply to its nodes."""
    ros_environment()
    if not os.environ.get(PROFILES_VAR):
        dds_profile()
    context = Context()
    ours = os.environ.get(PROFILES_VAR) == os.environ.get(OURS_VAR)
    with discovery_on_our_transports(ours and local_only()):
        # Our own SIGINT/SIGTERM handling parks the arm first; rclpy's would just stop.
        rclpy.init(
            args=list(args) if args else None,
            context=context,
            signal_handler_options=SignalHandlerOptions.NO,
        )
    return context


#: How often `acked` looks again.
ACK_POLL_S = 0.005


def acked(publishers: Sequence[Any], within_s: float) -> bool:
    """Whether every reader of each of `publishers` has acknowledged all it was sent, looked
    at until `within_s` seconds have passed. rclpy's `wait_for_all_acked` holds the GIL
    for as long as it waits (measured: a thread of the same process counted 0.8 to 2 % of
    its pace during a wait of 1 s), which starved everything else of the process, the lease's
    thread and an emulated board among them (a CI run's board went unanswered): here each
    look waits for nothing, and the GIL is let go between looks."""
    deadline = time.monotonic() + within_s
    for pub in publishers:
        while not pub.wait_for_all_acked(Duration()):
            if time.monotonic() >= deadline:
                return False
            time.sleep(ACK_POLL_S)
    return True
