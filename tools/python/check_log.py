#!/usr/bin/env python3
"""Checks a strand MCAP log by decoding it with two independent readers and asserting the values.

    python3 tools/python/check_log.py LOG.mcap [--expect-job]

Opening a log proves little: a writer can produce a well-formed MCAP file whose CDR payloads are
misaligned, whose schema text disagrees with the bytes, or whose channels disagree with each other,
and every tool that merely lists the file will still be happy. This script decodes every message and
checks what the values say.

Why two readers. strand writes its CDR by hand (``src/log/cdr.rs``) and its schema texts too
(``src/log/messages.rs``), so a reader built from those same schema texts can share a mistake with
the writer: a schema that is wrong in the same way as the encoder still decodes "fine". So:

* ``mcap`` + ``mcap-ros2-support`` (``make_reader(..., decoder_factories=[DecoderFactory()])``,
  ``iter_decoded_messages``) is the main reader: the file structure (summary statistics, channels,
  metadata, attachments) and every decoded value, including the cross-checks between channels (each
  tick's ``/joint_command``, ``/status``, ``/extruder``, poses and segments must equal what its
  ``/strand/tick`` record says it decided, exactly, float for float).
* ``rosbags`` is the second reader, with its own schema parser and CDR implementation. The standard
  ROS types (``sensor_msgs/msg/JointState``, ``geometry_msgs/msg/PoseStamped``) are decoded with
  rosbags' built-in ROS 2 Humble definitions, not the log's schema text, and the log's schema texts
  for them must equal those definitions (rosbags refuses to register a different one). The strand
  types are registered from the log's own schema texts. Every message must decode and re-encode to
  the identical bytes (so the padding and lengths are canonical CDR), and sampled messages (first,
  middle and last of each channel, plus ticks carrying segments, controls, base poses or events) must
  decode to exactly the same values, field by field, as with mcap_ros2.

Each check is one ``check_*`` function returning ``None`` when it holds or a description of the
first problem. Checks applied to every message or tick count how many items failed and keep the
first few details. All checks run even after a failure; the last line is
``check_log: P passed, F failed`` and the exit status is 0 only if nothing failed. The scan keeps
only running state and a few samples, so memory does not grow with the length of the log.

Needs only ``mcap``, ``mcap-ros2-support`` and ``rosbags`` (and ``strand_ipc.py`` beside this file,
for the enumerations).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import struct
import sys
import tomllib
import xml.etree.ElementTree as ElementTree
from collections import Counter
from importlib.metadata import PackageNotFoundError, version
from typing import Any, Callable, Optional

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from strand_ipc import JobOutcome, LogState, RunState, enum_name  # noqa: E402

# Topics (src/log/mod.rs, `topics`) and the type each carries.
TICK = "/strand/tick"
JOINT_STATES = "/joint_states"
JOINT_COMMAND = "/joint_command"
TCP_TARGET = "/tcp/target"
TCP_ACTUAL = "/tcp/actual"
BASE_MEASURED = "/base/measured"
BASE_ESTIMATED = "/base/estimated"
EXTRUDER = "/extruder"
STATUS = "/status"
SEGMENTS = "/segments"
BASE_COMMAND = "/base/command"

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
POSE_STAMPED_TYPE = "geometry_msgs/msg/PoseStamped"
TOPIC_TYPES = {
    TICK: "strand_msgs/msg/Tick",
    JOINT_STATES: JOINT_STATE_TYPE,
    JOINT_COMMAND: JOINT_STATE_TYPE,
    TCP_TARGET: POSE_STAMPED_TYPE,
    TCP_ACTUAL: POSE_STAMPED_TYPE,
    BASE_MEASURED: POSE_STAMPED_TYPE,
    BASE_ESTIMATED: POSE_STAMPED_TYPE,
    EXTRUDER: "strand_msgs/msg/ExtruderCommand",
    STATUS: "strand_msgs/msg/Status",
    SEGMENTS: "strand_msgs/msg/Segment",
    BASE_COMMAND: POSE_STAMPED_TYPE,
}

# Topics that must hold messages in every log, and in a log of a job.
ALWAYS_PRESENT = (TICK, JOINT_COMMAND, STATUS, EXTRUDER, TCP_TARGET, BASE_ESTIMATED)
JOB_PRESENT = (SEGMENTS, JOINT_STATES)
# Written once on every tick.
EVERY_TICK = (STATUS, EXTRUDER, TCP_TARGET, BASE_ESTIMATED)
# Written any number of times on one tick (so their log times need not strictly increase).
MANY_PER_TICK = {SEGMENTS, BASE_MEASURED}

METADATA_NAME = "strand"
METADATA_KEYS = (
    "version", "contract_version", "robot", "rate_hz", "dof", "joint_names", "part", "first_tick", "clock_offset_ns",
)
CONFIG_ATTACHMENT = "effective-config.toml"
URDF_ATTACHMENT = "robot.urdf"
SCHEMA_SEPARATOR = "=" * 80

# Event kinds in TickOutput.events (src/log/messages.rs, EVENT_DEFINITION).
EVENT_JOB_ENDED = 7

# How many extra /strand/tick and /segments messages the two readers compare (beyond first, middle, last).
MAX_EXTRA_SAMPLES = 20
# Tolerances (everything else is compared exactly).
QUATERNION_NORM_TOLERANCE = 1e-6
PERIOD_TOLERANCE = 0.05


# --------------------------------------------------------------------------------------------------
# Results


@dataclasses.dataclass
class Outcome:
    """The result of one named check, over however many items it was applied to."""

    name: str
    runs: int = 0
    failures: int = 0
    details: list[str] = dataclasses.field(default_factory=list)


class Results:
    """Collects the outcome of every named check (a check's name is its function's name without ``check_``)."""

    MAX_DETAILS = 3

    def __init__(self) -> None:
        self.outcomes: dict[str, Outcome] = {}

    @staticmethod
    def name(check: Callable[..., Optional[str]]) -> str:
        return check.__name__.removeprefix("check_")

    def declare(self, checks: list[Callable[..., Optional[str]]]) -> None:
        for c in checks:
            self.outcomes.setdefault(self.name(c), Outcome(self.name(c)))

    def record(self, check: Callable[..., Optional[str]], failure: Optional[str]) -> None:
        o = self.outcomes.setdefault(self.name(check), Outcome(self.name(check)))
        o.runs += 1
        if failure is not None:
            o.failures += 1
            if len(o.details) < self.MAX_DETAILS:
                o.details.append(failure)

    def run(self, check: Callable[..., Optional[str]], *args: Any) -> None:
        """Runs a check on one item and records it (a check that raises fails with the exception; the run goes on)."""
        try:
            failure = check(*args)
        except Exception as e:  # noqa: BLE001 (unexpected data: report it as this check's failure)
            failure = f"raised {type(e).__name__}: {e}"
        self.record(check, failure)

    def not_run(self, checks: list[Callable[..., Optional[str]]], why: str) -> None:
        for c in checks:
            o = self.outcomes.setdefault(self.name(c), Outcome(self.name(c)))
            if o.runs == 0:
                self.record(c, f"not run: {why}")

    def passed(self) -> int:
        return sum(1 for o in self.outcomes.values() if o.failures == 0)

    def failed(self) -> int:
        return sum(1 for o in self.outcomes.values() if o.failures > 0)


# --------------------------------------------------------------------------------------------------
# The log and what the scans learn about it


@dataclasses.dataclass
class TickGroup:
    """One tick: its /strand/tick record and the messages written with the same log time."""

    log_time: int
    tick: Any
    messages: dict[str, list[Any]] = dataclasses.field(default_factory=dict)

    def on(self, topic: str) -> list[Any]:
        return self.messages.get(topic, [])


@dataclasses.dataclass
class Log:
    """The file, its summary and metadata, and the facts and running state of the scans."""

    path: str
    expect_job: bool
    header: Any = None
    summary: Any = None
    metadata: Optional[dict[str, str]] = None
    metadata_records: int = 0
    attachments: dict[str, Any] = dataclasses.field(default_factory=dict)
    # From the "strand" metadata (None when it is missing or unreadable).
    joint_names: Optional[list[str]] = None
    dof: Optional[int] = None
    clock_offset_ns: Optional[int] = None
    first_tick: Optional[int] = None
    rate_hz: Optional[float] = None
    contract_version: Optional[int] = None
    # Facts gathered by the mcap_ros2 scan.
    counts: Counter = dataclasses.field(default_factory=Counter)
    first_log_time: Optional[int] = None
    last_log_time: Optional[int] = None
    first_tick_msg: Any = None
    last_tick_msg: Any = None
    last_status: Any = None
    tick_steps_ns: Counter = dataclasses.field(default_factory=Counter)
    max_filament_rate: float = -math.inf
    job_end_outcomes: list[int] = dataclasses.field(default_factory=list)
    scan_error: Optional[str] = None
    # Running state of the scan.
    group: Optional[TickGroup] = None
    prev_log_time: Optional[int] = None
    prev_log_time_by_topic: dict[str, int] = dataclasses.field(default_factory=dict)
    prev_tick: Optional[int] = None
    prev_status_tick: Optional[int] = None
    # mcap_ros2-decoded messages kept for the comparison with rosbags, by (topic, index in channel).
    samples: dict[tuple[str, int], Any] = dataclasses.field(default_factory=dict)
    sample_plan: dict[str, set[int]] = dataclasses.field(default_factory=dict)
    extra_samples: Counter = dataclasses.field(default_factory=Counter)
    compared: Counter = dataclasses.field(default_factory=Counter)
    # The rosbags typestore, once the log's schemas are registered.
    typestore: Any = None

    def stats_count(self, topic: str) -> Optional[int]:
        """The summary statistics' message count of a topic (0 when the channel has none, None without statistics)."""
        if self.summary is None or self.summary.statistics is None:
            return None
        counts = self.summary.statistics.channel_message_counts
        return sum(counts.get(cid, 0) for cid, ch in self.summary.channels.items() if ch.topic == topic)


# --------------------------------------------------------------------------------------------------
# Helpers


def stamp_ns(header: Any) -> int:
    """A std_msgs/Header stamp in ns."""
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def all_finite(values: Any) -> bool:
    return all(math.isfinite(v) for v in values)


def pose_tuple(pose: Any) -> tuple[list[float], list[float]]:
    """A geometry_msgs/Pose as (position xyz, orientation wxyz, the project's quaternion order)."""
    p, q = pose.position, pose.orientation
    return [p.x, p.y, p.z], [q.w, q.x, q.y, q.z]


def split_schema(text: str) -> list[tuple[str, str]]:
    """Splits a ros2msg schema text into (type name, body) sections; the first is named ``""``.

    Raises ValueError when the text is not laid out as the MCAP ros2msg profile describes: sections
    separated by a line of exactly 80 ``=``, each after the first starting with ``MSG: pkg/Type``.
    """
    sections: list[tuple[str, str]] = []
    name, body = "", []
    for number, line in enumerate(text.split("\n"), 1):
        if line and set(line.strip()) == {"="}:
            if line != SCHEMA_SEPARATOR:
                raise ValueError(f"line {number}: separator of {len(line)} characters, not 80 '='")
            sections.append((name, "\n".join(body)))
            name, body = None, []
        elif name is None:
            if not line.startswith("MSG: ") or not line[5:].strip():
                raise ValueError(f"line {number}: section starts with {line!r}, not 'MSG: pkg/Type'")
            name = line[5:].strip()
        else:
            body.append(line)
    if name is None:
        raise ValueError("ends with a separator")
    sections.append((name, "\n".join(body)))
    names = [n for n, _ in sections[1:]]
    if len(set(names)) != len(names):
        raise ValueError(f"a type is defined twice: {sorted(n for n in names if names.count(n) > 1)}")
    return sections


def message_fields(msg: Any) -> Optional[list[str]]:
    """Field names of a decoded message of either reader (rosbags: dataclasses; mcap_ros2: slots), else None."""
    if dataclasses.is_dataclass(msg) and not isinstance(msg, type):
        # rosbags lists a type's constants (`LINE_STRIP`, upper case by the ROS convention) as
        # fields too; they are part of the type, not of the message.
        return [f.name for f in dataclasses.fields(msg) if not f.name.startswith("__") and not f.name.isupper()]
    if isinstance(msg, (str, bytes, bytearray, list, tuple)):
        return None
    slots = getattr(type(msg), "__slots__", None)
    return list(slots) if isinstance(slots, (list, tuple)) else None


def as_list(value: Any) -> Any:
    """Arrays of either reader (numpy arrays, lists, tuples, bytes) as lists; other values unchanged."""
    if hasattr(value, "tolist") and not isinstance(value, (int, float)):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return list(value)
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    return value


def difference(a: Any, b: Any, path: str = "") -> Optional[str]:
    """The first difference between two decoded values, field by field; floats compared bit for bit."""
    fa, fb = message_fields(a), message_fields(b)
    if fa is not None or fb is not None:
        if fa != fb:
            return f"{path or 'message'}: fields {fa} vs {fb}"
        for name in fa or []:
            d = difference(getattr(a, name), getattr(b, name), f"{path}.{name}")
            if d:
                return d
        return None
    a, b = as_list(a), as_list(b)
    if isinstance(a, list) or isinstance(b, list):
        if not (isinstance(a, list) and isinstance(b, list)) or len(a) != len(b):
            return f"{path}: {a!r} vs {b!r}"
        for i, (x, y) in enumerate(zip(a, b)):
            d = difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if isinstance(a, float) or isinstance(b, float):
        if isinstance(a, float) and isinstance(b, float) and struct.pack("<d", a) == struct.pack("<d", b):
            return None
        return f"{path}: {a!r} vs {b!r}"
    return None if a == b else f"{path}: {a!r} vs {b!r}"


def package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "?"


# --------------------------------------------------------------------------------------------------
# Structure checks (mcap reader: header, summary, channels, schemas, metadata, attachments)


def check_header(log: Log) -> Optional[str]:
    """The MCAP header names the ros2 profile and a strand writer."""
    if log.header is None:
        return "no header"
    if log.header.profile != "ros2":
        return f"profile {log.header.profile!r}, expected 'ros2'"
    if not log.header.library.startswith("strand"):
        return f"library {log.header.library!r}, expected 'strand ...'"
    return None


def check_summary_statistics(log: Log) -> Optional[str]:
    """The summary holds statistics with messages and a per-channel count."""
    if log.summary is None:
        return "no summary section (file not finished?)"
    s = log.summary.statistics
    if s is None:
        return "summary has no statistics record"
    if s.message_count == 0 or not s.channel_message_counts:
        return f"statistics report {s.message_count} messages, channel counts {dict(s.channel_message_counts)}"
    if s.message_start_time > s.message_end_time:
        return f"message_start_time {s.message_start_time} > message_end_time {s.message_end_time}"
    if s.channel_count != len(log.summary.channels) or s.schema_count != len(log.summary.schemas):
        return (
            f"statistics count {s.channel_count} channels / {s.schema_count} schemas, "
            f"summary holds {len(log.summary.channels)} / {len(log.summary.schemas)}"
        )
    return None


def check_channels(log: Log) -> Optional[str]:
    """Every required topic has one channel, with cdr encoding, a ros2msg schema and the right type."""
    if log.summary is None:
        return "no summary"
    by_topic: dict[str, list[Any]] = {}
    for ch in log.summary.channels.values():
        by_topic.setdefault(ch.topic, []).append(ch)
    problems = []
    required = ALWAYS_PRESENT + (JOB_PRESENT if log.expect_job else ())
    problems += [f"{t} missing" for t in required if t not in by_topic]
    for topic, channels in sorted(by_topic.items()):
        if len(channels) > 1:
            problems.append(f"{topic} has {len(channels)} channels")
        for ch in channels:
            schema = log.summary.schemas.get(ch.schema_id)
            if ch.message_encoding != "cdr":
                problems.append(f"{topic} message_encoding {ch.message_encoding!r}")
            if schema is None:
                problems.append(f"{topic} has no schema")
                continue
            if schema.encoding != "ros2msg":
                problems.append(f"{topic} schema encoding {schema.encoding!r}")
            if topic in TOPIC_TYPES and schema.name != TOPIC_TYPES[topic]:
                problems.append(f"{topic} schema {schema.name!r}, expected {TOPIC_TYPES[topic]!r}")
    return "; ".join(problems) or None


def check_schema_texts(log: Log) -> Optional[str]:
    """Every schema text is ros2msg with its dependencies in 80-'=' / 'MSG: pkg/Type' sections."""
    if log.summary is None:
        return "no summary"
    problems = []
    for schema in log.summary.schemas.values():
        try:
            split_schema(schema.data.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as e:
            problems.append(f"{schema.name}: {e}")
    return "; ".join(problems) or None


def check_metadata(log: Log) -> Optional[str]:
    """The "strand" metadata record is present once, complete, and its dof equals len(joint_names)."""
    if log.metadata is None:
        return f"{log.metadata_records} metadata records named {METADATA_NAME!r}, expected 1"
    m = log.metadata
    missing = [k for k in METADATA_KEYS if k not in m]
    if missing:
        return f"keys missing: {missing}"
    if log.dof is None or log.joint_names is None:
        return f"dof {m['dof']!r} / joint_names {m['joint_names']!r} unreadable"
    if log.dof != len(log.joint_names) or log.dof == 0:
        return f"dof {log.dof} but {len(log.joint_names)} joint names {log.joint_names}"
    if len(set(log.joint_names)) != len(log.joint_names) or not all(log.joint_names):
        return f"joint names empty or repeated: {log.joint_names}"
    for key in ("part", "first_tick", "clock_offset_ns", "contract_version"):
        try:
            int(m[key])
        except ValueError:
            return f"{key} {m[key]!r} is not an integer"
    if log.rate_hz is None or not log.rate_hz > 0:
        return f"rate_hz {m['rate_hz']!r}"
    return None


def check_attachments(log: Log) -> Optional[str]:
    """effective-config.toml parses and has the metadata's rate; robot.urdf has every joint as a movable joint."""
    problems = []
    config = log.attachments.get(CONFIG_ATTACHMENT)
    if config is None:
        problems.append(f"{CONFIG_ATTACHMENT} missing")
    else:
        try:
            rate = tomllib.loads(config.data.decode("utf-8")).get("controller", {}).get("rate_hz")
            if log.rate_hz is not None and rate != log.rate_hz:
                problems.append(f"{CONFIG_ATTACHMENT} controller.rate_hz {rate!r}, metadata rate_hz {log.rate_hz}")
        except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            problems.append(f"{CONFIG_ATTACHMENT} is not TOML: {e}")
    urdf = log.attachments.get(URDF_ATTACHMENT)
    if urdf is None:
        problems.append(f"{URDF_ATTACHMENT} missing")
    else:
        try:
            root = ElementTree.fromstring(urdf.data)
            joints = {j.get("name"): j.get("type") for j in root.iter("joint")}
            for name in log.joint_names or []:
                if name not in joints:
                    problems.append(f"{URDF_ATTACHMENT} has no joint {name!r}")
                elif joints[name] == "fixed":
                    problems.append(f"{URDF_ATTACHMENT} joint {name!r} is fixed")
            if log.joint_names is None:
                problems.append("no joint names to look for (metadata)")
        except ElementTree.ParseError as e:
            problems.append(f"{URDF_ATTACHMENT} is not XML: {e}")
    return "; ".join(problems) or None


def check_message_counts(log: Log) -> Optional[str]:
    """Statistics: required topics have messages; /status, /extruder, /tcp/target, /base/estimated have one per tick,
    /joint_command, /joint_states, /tcp/actual at most one."""
    ticks = log.stats_count(TICK)
    if ticks is None:
        return "no statistics"
    problems = []
    required = ALWAYS_PRESENT + (JOB_PRESENT if log.expect_job else ())
    problems += [f"{t} has no messages" for t in required if not log.stats_count(t)]
    for topic in EVERY_TICK:
        if log.stats_count(topic) != ticks:
            problems.append(f"{topic} {log.stats_count(topic)} messages, {TICK} {ticks}")
    for topic in (JOINT_COMMAND, JOINT_STATES, TCP_ACTUAL):
        if (log.stats_count(topic) or 0) > ticks:
            problems.append(f"{topic} {log.stats_count(topic)} messages, more than {ticks} ticks")
    return "; ".join(problems) or None


STRUCTURE_CHECKS = [
    check_header,
    check_summary_statistics,
    check_channels,
    check_schema_texts,
    check_metadata,
    check_attachments,
    check_message_counts,
]


# --------------------------------------------------------------------------------------------------
# Message checks (mcap_ros2, every message of the topics they apply to)


def check_mcap_ros2_decodes(log: Log, topic: str, log_time: int, msg: Any) -> Optional[str]:
    """Every message decodes with mcap_ros2 (a failure stops the scan: see Log.scan_error)."""
    return None


def check_log_time_order(log: Log, topic: str, log_time: int, msg: Any) -> Optional[str]:
    """In file order, log times never decrease, and strictly increase on each once-per-tick channel."""
    if log.prev_log_time is not None and log_time < log.prev_log_time:
        return f"{topic} log_time {log_time} after {log.prev_log_time}"
    prev = log.prev_log_time_by_topic.get(topic)
    if prev is not None and topic not in MANY_PER_TICK and log_time <= prev:
        return f"{topic} log_time {log_time} not after its previous {prev}"
    return None


def check_messages_in_their_tick(log: Log, topic: str, log_time: int, msg: Any) -> Optional[str]:
    """Every other message follows its tick's /strand/tick in the file, with the same log time
    (/robot_description excepted: once per file, at its start, for a viewer's 3D panel)."""
    if topic == "/robot_description":
        return None
    if log.group is None:
        return f"{topic} at {log_time} before any {TICK}"
    if log_time != log.group.log_time:
        return f"{topic} log_time {log_time} after the {TICK} of {log.group.log_time}"
    return None


def check_joint_command_well_formed(log: Log, topic: str, log_time: int, msg: Any) -> Optional[str]:
    """/joint_command: names == metadata joint_names, dof finite positions, velocities; no effort, stamp == log_time."""
    if log.joint_names is None:
        return "no joint names (metadata)"
    dof = log.dof
    if list(msg.name) != log.joint_names:
        return f"at {log_time}: names {list(msg.name)}, metadata {log.joint_names}"
    if len(msg.position) != dof or len(msg.velocity) != dof:
        return f"at {log_time}: {len(msg.position)} positions, {len(msg.velocity)} velocities, dof {dof}"
    if len(msg.effort) != 0:
        return f"at {log_time}: {len(msg.effort)} efforts, expected none"
    if not all_finite(msg.position) or not all_finite(msg.velocity):
        return f"at {log_time}: not finite: position {list(msg.position)} velocity {list(msg.velocity)}"
    if stamp_ns(msg.header) != log_time:
        return f"at {log_time}: header stamp {stamp_ns(msg.header)} ns != log_time"
    if msg.header.frame_id != "":
        return f"at {log_time}: frame_id {msg.header.frame_id!r}"
    return None


def check_status_ticks_contiguous(log: Log, topic: str, log_time: int, msg: Any) -> Optional[str]:
    """/status: Status.tick starts at the metadata's first_tick and goes up by exactly 1 (no tick lost)."""
    if log.prev_status_tick is None:
        if log.first_tick is not None and msg.tick != log.first_tick:
            return f"first Status.tick {msg.tick}, metadata first_tick {log.first_tick}"
    elif msg.tick != log.prev_status_tick + 1:
        return f"Status.tick {msg.tick} after {log.prev_status_tick} (at {log_time})"
    if log.contract_version is not None and msg.contract_version != log.contract_version:
        return f"Status.contract_version {msg.contract_version}, metadata {log.contract_version}"
    return None


# Applied to every message (None) or to the messages of one topic.
MESSAGE_CHECKS: list[tuple[Optional[str], Callable[..., Optional[str]]]] = [
    (None, check_mcap_ros2_decodes),
    (None, check_log_time_order),
    (None, check_messages_in_their_tick),
    (JOINT_COMMAND, check_joint_command_well_formed),
    (STATUS, check_status_ticks_contiguous),
]


# --------------------------------------------------------------------------------------------------
# Tick checks (mcap_ros2: a /strand/tick record against the messages written with it)


def check_tick_numbering(log: Log, g: TickGroup) -> Optional[str]:
    """Ticks start at first_tick and go up by 1; the outputs (status, joint command, extruder) carry the tick number."""
    i, o = g.tick.input, g.tick.output
    if log.prev_tick is None:
        if log.first_tick is not None and i.tick != log.first_tick:
            return f"first tick {i.tick}, metadata first_tick {log.first_tick}"
    elif i.tick != log.prev_tick + 1:
        return f"tick {i.tick} after {log.prev_tick}"
    if not o.status.tick == o.joint_command.tick == o.extruder.tick == i.tick:
        return (
            f"tick {i.tick}: output status.tick {o.status.tick}, joint_command.tick {o.joint_command.tick}, "
            f"extruder.tick {o.extruder.tick}"
        )
    return None


def check_tick_log_time(log: Log, g: TickGroup) -> Optional[str]:
    """Log time == tick time_ns (monotonic) + metadata clock_offset_ns."""
    if log.clock_offset_ns is None:
        return "no clock_offset_ns (metadata)"
    expected = max(0, g.tick.input.time_ns + log.clock_offset_ns)
    if g.log_time != expected:
        return f"tick {g.tick.input.tick}: log_time {g.log_time}, time_ns + clock_offset_ns = {expected}"
    return None


def check_tick_channels(log: Log, g: TickGroup) -> Optional[str]:
    """Each tick wrote one message on each every-tick channel, one /joint_command iff the command is valid, and one
    /joint_states, /segments, /base/measured message per joint state, segment and base pose it received."""
    i, o = g.tick.input, g.tick.output
    expected = {topic: 1 for topic in EVERY_TICK}
    expected[JOINT_COMMAND] = 1 if o.joint_command.valid == 1 else 0
    expected[JOINT_STATES] = len(i.joint_state)
    expected[SEGMENTS] = len(i.segments)
    expected[BASE_MEASURED] = len(i.base_poses)
    wrong = {t: (len(g.on(t)), n) for t, n in expected.items() if len(g.on(t)) != n}
    if len(g.on(TCP_ACTUAL)) > 1:
        wrong[TCP_ACTUAL] = (len(g.on(TCP_ACTUAL)), 1)
    if wrong:
        return f"tick {i.tick}: " + ", ".join(f"{t} {got} messages (expected {n})" for t, (got, n) in wrong.items())
    return None


def check_known_joint_command(log: Log, g: TickGroup) -> Optional[str]:
    """A tick's /joint_command equals its output.joint_command position[:dof] and velocity[:dof] (float ==)."""
    if log.dof is None:
        return "no dof (metadata)"
    jc = g.tick.output.joint_command
    for msg in g.on(JOINT_COMMAND):
        for field in ("position", "velocity"):
            logged, known = list(getattr(msg, field)), list(getattr(jc, field)[: log.dof])
            if logged != known:
                return f"tick {g.tick.input.tick}: /joint_command {field} {logged}, tick output {known}"
    return None


def check_channels_agree_with_tick(log: Log, g: TickGroup) -> Optional[str]:
    """/status, /extruder, /segments and /joint_states equal what the tick record holds (every field, exactly)."""
    i, o = g.tick.input, g.tick.output
    pairs = [(STATUS, m, o.status) for m in g.on(STATUS)] + [(EXTRUDER, m, o.extruder) for m in g.on(EXTRUDER)]
    pairs += [(SEGMENTS, m, s) for m, s in zip(g.on(SEGMENTS), i.segments)]
    for topic, msg, expected in pairs:
        d = difference(msg, expected)
        if d:
            return f"tick {i.tick}: {topic} differs from the tick at {d}"
    for msg, js in zip(g.on(JOINT_STATES), i.joint_state):
        if log.dof is None or log.clock_offset_ns is None:
            return "no dof / clock_offset_ns (metadata)"
        n = min(js.dof, log.dof)
        if list(msg.name) != log.joint_names:
            return f"tick {i.tick}: /joint_states names {list(msg.name)}"
        for field in ("position", "velocity", "effort"):
            # Bit for bit: a measurement is logged as received, even a non-finite one the controller rejected.
            d = difference(getattr(msg, field), getattr(js, field)[:n], field)
            if d:
                return f"tick {i.tick}: /joint_states vs tick input at {d}"
        stamp = max(0, js.stamp_ns + log.clock_offset_ns)
        if stamp_ns(msg.header) != stamp:
            return f"tick {i.tick}: /joint_states stamp {stamp_ns(msg.header)}, expected {stamp} (stamp_ns + offset)"
    return None


def check_poses_agree_with_tick(log: Log, g: TickGroup) -> Optional[str]:
    """Pose channels: frame "world", stamp == log time (measured base: its own stamp); /tcp/target, /base/estimated,
    /base/measured equal the tick's values bit for bit, quaternion (w,x,y,z) reordered; the poses strand computes
    (all but the measured base, logged as received) are finite with unit quaternions."""
    d, i = g.tick.output.diagnostics, g.tick.input
    offset = log.clock_offset_ns or 0
    target = (list(d.tcp_target_world), list(d.tcp_target_orientation))
    base = (list(d.base.position), list(d.base.orientation))
    # (topic, message, (position, orientation w,x,y,z) it must hold or None, stamp it must carry)
    expected: list[tuple[str, Any, Optional[tuple[list[float], list[float]]], int]] = []
    expected += [(TCP_TARGET, m, target, g.log_time) for m in g.on(TCP_TARGET)]
    expected += [(BASE_ESTIMATED, m, base, g.log_time) for m in g.on(BASE_ESTIMATED)]
    expected += [(TCP_ACTUAL, m, None, g.log_time) for m in g.on(TCP_ACTUAL)]
    for m, p in zip(g.on(BASE_MEASURED), i.base_poses):
        expected.append((BASE_MEASURED, m, (list(p.position), list(p.orientation)), max(0, p.stamp_ns + offset)))
    for topic, msg, values, stamp in expected:
        position, orientation = pose_tuple(msg.pose)
        if msg.header.frame_id != "world":
            return f"tick {i.tick}: {topic} frame_id {msg.header.frame_id!r}"
        if stamp_ns(msg.header) != stamp:
            return f"tick {i.tick}: {topic} stamp {stamp_ns(msg.header)}, expected {stamp}"
        if values is not None and difference((position, orientation), values):
            return f"tick {i.tick}: {topic} pose {position} {orientation} (w,x,y,z), tick {values[0]} {values[1]}"
        if topic == BASE_MEASURED:
            continue
        if not all_finite(position + orientation):
            return f"tick {i.tick}: {topic} not finite: {position} {orientation}"
        norm = math.sqrt(sum(v * v for v in orientation))
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            return f"tick {i.tick}: {topic} quaternion norm {norm}"
    return None


TICK_CHECKS = [
    check_tick_numbering,
    check_tick_log_time,
    check_tick_channels,
    check_known_joint_command,
    check_channels_agree_with_tick,
    check_poses_agree_with_tick,
]


# --------------------------------------------------------------------------------------------------
# Whole-log checks after the mcap_ros2 scan


def check_scan_matches_statistics(log: Log) -> Optional[str]:
    """The messages decoded per channel, their total and their time range equal the summary statistics."""
    s = log.summary.statistics if log.summary is not None else None
    if s is None:
        return "no statistics"
    problems = []
    for cid, ch in sorted(log.summary.channels.items()):
        logged = s.channel_message_counts.get(cid, 0)
        if logged != log.counts[ch.topic]:
            problems.append(f"{ch.topic}: statistics {logged}, decoded {log.counts[ch.topic]}")
    total = sum(log.counts.values())
    if s.message_count != total:
        problems.append(f"message_count {s.message_count}, decoded {total}")
    if total and (s.message_start_time, s.message_end_time) != (log.first_log_time, log.last_log_time):
        stats_range, decoded_range = (s.message_start_time, s.message_end_time), (log.first_log_time, log.last_log_time)
        problems.append(f"statistics time range {stats_range}, decoded {decoded_range}")
    return "; ".join(problems) or None


def check_final_status(log: Log) -> Optional[str]:
    """The last Status reports no log drops, logging still recording, and matches the last tick."""
    s = log.last_status
    if s is None:
        return "no /status message"
    if s.log_drops != 0:
        return f"last Status.log_drops {s.log_drops}"
    if s.log_state != LogState.RECORDING:
        return f"last Status.log_state {s.log_state}, expected {int(LogState.RECORDING)} (RECORDING)"
    if log.last_tick_msg is not None and s.tick != log.last_tick_msg.input.tick:
        return f"last Status.tick {s.tick}, last tick {log.last_tick_msg.input.tick}"
    return None


def check_tick_period(log: Log) -> Optional[str]:
    """The median step of the tick times is the metadata's period (1/rate_hz), within 5 %."""
    if log.rate_hz is None:
        return "no rate_hz (metadata)"
    total = sum(log.tick_steps_ns.values())
    if total == 0:
        return "fewer than two ticks"
    seen = 0
    for median in sorted(log.tick_steps_ns):
        seen += log.tick_steps_ns[median]
        if 2 * seen > total:
            break
    period = 1e9 / log.rate_hz
    if abs(median - period) > PERIOD_TOLERANCE * period:
        return f"median tick step {median} ns, period {period:.0f} ns at {log.rate_hz} Hz"
    return None


FINAL_CHECKS = [check_scan_matches_statistics, check_final_status, check_tick_period]


def check_segments_logged(log: Log) -> Optional[str]:
    """(job) /segments holds at least one segment, as many as the final Status.segments_accepted."""
    n = log.counts[SEGMENTS]
    if n == 0:
        return "no /segments message"
    if log.last_status is None:
        return "no /status message"
    if log.last_status.segments_accepted != n:
        s = log.last_status
        return f"final Status.segments_accepted {s.segments_accepted} (rejected {s.rejected}), /segments messages {n}"
    return None


def check_job_finished(log: Log) -> Optional[str]:
    """(job) The final Status.job_outcome is FINISHED, and a tick reported the JobEnded(FINISHED) event."""
    if log.last_status is None:
        return "no /status message"
    if log.last_status.job_outcome != JobOutcome.FINISHED:
        return f"final Status.job_outcome {log.last_status.job_outcome}, expected {int(JobOutcome.FINISHED)} (FINISHED)"
    if JobOutcome.FINISHED not in log.job_end_outcomes:
        return f"no JobEnded(FINISHED) event in the ticks (job-ended outcomes seen: {log.job_end_outcomes})"
    return None


def check_extruder_ran(log: Log) -> Optional[str]:
    """(job) Some /extruder message has filament_rate > 0."""
    if not log.max_filament_rate > 0:
        return f"largest /extruder filament_rate {log.max_filament_rate}"
    return None


JOB_CHECKS = [check_segments_logged, check_job_finished, check_extruder_ran]


# --------------------------------------------------------------------------------------------------
# rosbags checks


def check_rosbags_schemas(log: Log) -> Optional[str]:
    """rosbags parses every schema section and registers it in its ROS 2 Humble typestore (which refuses a
    standard type whose definition differs from Humble's). Leaves the typestore in log.typestore."""
    if log.summary is None:
        return "no summary"
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    problems = []
    for schema in log.summary.schemas.values():
        try:
            types: dict[str, Any] = {}
            for name, body in split_schema(schema.data.decode("utf-8")):
                types.update(get_types_from_msg(body, name or schema.name))
            typestore.register(types)
        except Exception as e:  # noqa: BLE001 (rosbags raises several types; report any)
            problems.append(f"{schema.name}: {type(e).__name__}: {e}")
    log.typestore = typestore
    return "; ".join(problems) or None


def rosbags_type(schema: Any, topic: str) -> str:
    """The type rosbags decodes a message as: the topic's expected type (standard ones are Humble's built-ins)."""
    return TOPIC_TYPES.get(topic, schema.name)


def check_rosbags_decodes(log: Log, topic: str, typename: str, data: bytes, decoded: Any) -> Optional[str]:
    """Every message decodes with rosbags, using all of its bytes (see scan_rosbags)."""
    return None


def check_rosbags_reencodes(log: Log, topic: str, typename: str, data: bytes, decoded: Any) -> Optional[str]:
    """rosbags re-encodes every decoded message to the identical bytes (canonical CDR: padding, lengths)."""
    again = bytes(log.typestore.serialize_cdr(decoded, typename))
    if again != data:
        at = next((k for k, (x, y) in enumerate(zip(again, data)) if x != y), min(len(again), len(data)))
        return f"{topic}: {len(data)} bytes logged, {len(again)} re-encoded, first difference at byte {at}"
    return None


def check_readers_agree(log: Log, topic: str, index: int, decoded: Any) -> Optional[str]:
    """Sampled messages decode to the same values with rosbags and mcap_ros2, every field, floats bit for bit."""
    d = difference(log.samples[(topic, index)], decoded)
    if d:
        return f"{topic} #{index}: mcap_ros2 vs rosbags at {d}"
    return None


ROSBAGS_CHECKS = [check_rosbags_schemas, check_rosbags_decodes, check_rosbags_reencodes, check_readers_agree]


# --------------------------------------------------------------------------------------------------
# The scans


def read_structure(log: Log, f: Any) -> None:
    """Header, summary, the "strand" metadata and the attachments, with the plain mcap reader."""
    f.seek(0)
    reader = make_reader(f)
    log.header = reader.get_header()
    log.summary = reader.get_summary()
    records = [m for m in reader.iter_metadata() if m.name == METADATA_NAME]
    log.metadata_records = len(records)
    if len(records) == 1:
        log.metadata = dict(records[0].metadata)
    for a in reader.iter_attachments():
        log.attachments[a.name] = a
    m = log.metadata or {}

    def parse(key: str, kind: Callable[[str], Any]) -> Any:
        try:
            return kind(m[key])
        except (KeyError, ValueError):
            return None

    log.dof = parse("dof", int)
    log.joint_names = parse("joint_names", lambda s: s.split(","))
    log.clock_offset_ns = parse("clock_offset_ns", int)
    log.first_tick = parse("first_tick", int)
    log.rate_hz = parse("rate_hz", float)
    log.contract_version = parse("contract_version", int)
    # Which messages the readers compare: first, middle and last of every channel (more, below).
    if log.summary is not None:
        for ch in log.summary.channels.values():
            n = log.stats_count(ch.topic) or 0
            log.sample_plan[ch.topic] = {0, n // 2, n - 1} if n else set()


def keep_sample(log: Log, topic: str, index: int, decoded: Any) -> None:
    """Keeps a message for the comparison with rosbags if it is planned, or is a tick with variable-length
    content or a segment (the parts most likely to be misaligned), up to MAX_EXTRA_SAMPLES of those."""
    planned = index in log.sample_plan.get(topic, ())
    if topic == TICK:
        i, o = decoded.input, decoded.output
        interesting = any(len(x) for x in (i.segments, i.controls, i.base_poses, o.events))
    else:
        interesting = topic == SEGMENTS
    if not planned and interesting and log.extra_samples[topic] < MAX_EXTRA_SAMPLES:
        log.extra_samples[topic] += 1
        planned = True
    if planned:
        log.samples[(topic, index)] = decoded


def finish_tick(log: Log, results: Results) -> None:
    """Runs the tick checks on the tick just completed."""
    g = log.group
    if g is None:
        return
    for check in TICK_CHECKS:
        results.run(check, log, g)
    log.prev_tick = g.tick.input.tick


def scan_mcap_ros2(log: Log, f: Any, results: Results) -> None:
    """Decodes every message with mcap_ros2, in file order, running the message and tick checks."""
    f.seek(0)
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    index: Counter = Counter()
    try:
        for _schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            topic, t = channel.topic, message.log_time
            if topic == TICK:
                finish_tick(log, results)
                log.group = TickGroup(t, decoded)
                if log.first_tick_msg is None:
                    log.first_tick_msg = decoded
                elif log.last_tick_msg is not None:
                    log.tick_steps_ns[decoded.input.time_ns - log.last_tick_msg.input.time_ns] += 1
                log.last_tick_msg = decoded
                log.job_end_outcomes += [e.a for e in decoded.output.events if e.kind == EVENT_JOB_ENDED]
            for only, check in MESSAGE_CHECKS:
                if only is None or only == topic:
                    results.run(check, log, topic, t, decoded)
            if topic != TICK and log.group is not None:
                log.group.messages.setdefault(topic, []).append(decoded)
            if topic == STATUS:
                log.last_status = decoded
                log.prev_status_tick = decoded.tick
            elif topic == EXTRUDER:
                log.max_filament_rate = max(log.max_filament_rate, decoded.filament_rate)
            keep_sample(log, topic, index[topic], decoded)
            index[topic] += 1
            log.counts[topic] += 1
            log.first_log_time = t if log.first_log_time is None else min(log.first_log_time, t)
            log.last_log_time = t if log.last_log_time is None else max(log.last_log_time, t)
            log.prev_log_time = t
            log.prev_log_time_by_topic[topic] = t
    except Exception as e:  # noqa: BLE001 (a decoder or file error ends the scan; report it)
        log.scan_error = f"after {sum(log.counts.values())} messages: {type(e).__name__}: {e}"
        results.record(check_mcap_ros2_decodes, log.scan_error)
    finish_tick(log, results)


def scan_rosbags(log: Log, f: Any, results: Results) -> None:
    """Decodes the raw bytes of every message with rosbags (plain mcap reader, file order), re-encodes them, and
    compares the sampled ones with mcap_ros2's values."""
    results.run(check_rosbags_schemas, log)
    f.seek(0)
    reader = make_reader(f)
    index: Counter = Counter()
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        topic = channel.topic
        typename = rosbags_type(schema, topic)
        data = bytes(message.data)
        i = index[topic]
        index[topic] += 1
        try:
            decoded = log.typestore.deserialize_cdr(data, typename)
        except Exception as e:  # noqa: BLE001 (rosbags raises several types; report any)
            results.record(check_rosbags_decodes, f"{topic} #{i} as {typename}: {type(e).__name__}: {e}")
            continue
        results.record(check_rosbags_decodes, None)
        results.run(check_rosbags_reencodes, log, topic, typename, data, decoded)
        if (topic, i) in log.samples:
            results.run(check_readers_agree, log, topic, i, decoded)
            log.compared[topic] += 1


# --------------------------------------------------------------------------------------------------
# Report


def print_summary(log: Log) -> None:
    m = log.metadata or {}
    print(f"check_log: {log.path}")
    print(
        f"  strand {m.get('version', '?')}, robot {m.get('robot', '?')}, {m.get('dof', '?')} joints, "
        f"{m.get('rate_hz', '?')} Hz, contract {m.get('contract_version', '?')}, part {m.get('part', '?')}"
    )
    ticks = log.counts[TICK]
    if log.first_tick_msg is not None and log.last_tick_msg is not None:
        first, last = log.first_tick_msg.input, log.last_tick_msg.input
        span = f"ticks {first.tick}..{last.tick}, duration {(last.time_ns - first.time_ns) / 1e9:.3f} s"
    else:
        span = "no ticks"
    print(f"  {ticks} ticks ({span}), {sum(log.counts.values())} messages")
    s = log.last_status
    if s is not None:
        print(
            f"  final status: tick {s.tick}, run_state {enum_name(RunState, s.run_state)}, "
            f"job_outcome {enum_name(JobOutcome, s.job_outcome)}, "
            f"segments accepted {s.segments_accepted}, rejected {s.rejected}, log_drops {s.log_drops}"
        )
    if log.summary is not None:
        topics = [ch.topic for _, ch in sorted(log.summary.channels.items())]
        print("  channels: " + ", ".join(f"{t} {log.counts[t]}" for t in topics))
    print(
        f"  readers: mcap {package_version('mcap')} + mcap-ros2-support {package_version('mcap-ros2-support')} "
        f"(every message, cross-checked per tick); rosbags {package_version('rosbags')} ROS2_HUMBLE typestore "
        f"(every message decoded and re-encoded; {sum(log.compared.values())} compared field by field with mcap_ros2)"
    )


def print_results(results: Results) -> None:
    for o in results.outcomes.values():
        items = f" ({o.runs} items)" if o.runs > 1 else ""
        if o.failures == 0:
            print(f"  ok    {o.name}{items}")
        else:
            print(f"  FAIL  {o.name}: {o.failures} of {o.runs} failed; " + " | ".join(o.details))


def main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", help="the .mcap file")
    parser.add_argument(
        "--expect-job", action="store_true", help="the log holds a finished job: require segments, extrusion, FINISHED"
    )
    args = parser.parse_args(argv)

    log = Log(args.log, args.expect_job)
    results = Results()
    checks = STRUCTURE_CHECKS + [c for _, c in MESSAGE_CHECKS] + TICK_CHECKS + FINAL_CHECKS
    checks += (JOB_CHECKS if args.expect_job else []) + ROSBAGS_CHECKS
    results.declare(checks)
    fatal = None
    try:
        with open(args.log, "rb") as f:
            read_structure(log, f)
            for check in STRUCTURE_CHECKS:
                results.run(check, log)
            scan_mcap_ros2(log, f, results)
            for check in FINAL_CHECKS + (JOB_CHECKS if args.expect_job else []):
                results.run(check, log)
            scan_rosbags(log, f, results)
    except Exception as e:  # noqa: BLE001 (an unreadable file fails every check not yet run)
        fatal = f"{type(e).__name__}: {e}"
        results.not_run(checks, "the file could not be read")
    print_summary(log)
    if fatal:
        print(f"  cannot read the file: {fatal}")
    print_results(results)
    passed, failed = results.passed(), results.failed()
    print(f"check_log: {passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
