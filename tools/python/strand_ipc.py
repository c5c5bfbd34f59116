"""strand's wire contract in Python: ctypes mirrors of the messages in ``wire/src/lib.rs``.

Every message is a fixed-size ``#[repr(C)]`` struct on the Rust side with no implicit padding (each
gap is a named ``_reserved`` field, always zero), so the ``ctypes.Structure`` below with the same
fields in the same order has the same layout. iceoryx2 checks the type name, size and alignment
when a service is opened, so each class has a ``type_name()`` staticmethod returning the exact
string of the Rust ``#[type_name("strand.v5.…")]`` attribute; a mismatch gives ``IncompatibleTypes``
instead of misread bytes. The sizes are asserted at import time (they are part of the contract and
the Rust test ``sizes_are_stable`` pins the same numbers).

Conventions (as in Rust): SI units (temperatures in °C, the one exception), world frame W, quaternions (w, x, y, z), timestamps in ns of
CLOCK_MONOTONIC (``time.monotonic_ns()`` on Linux), joint arrays of MAX_JOINTS of which the first
``dof`` are used.

Only the standard library is needed here; ``strand_client.py`` adds iceoryx2.
"""

from __future__ import annotations

import ctypes
import enum
from dataclasses import dataclass

__all__ = [
    "CONTRACT_VERSION",
    "MAX_JOINTS",
    "SEGMENT_BATCH_CAPACITY",
    "DEFAULT_PREFIX",
    "SegmentKind",
    "SegmentFlags",
    "ExtruderFlags",
    "JointStateFlags",
    "HeaterFlags",
    "Heater",
    "HeatWait",
    "HeatHold",
    "Command",
    "RunState",
    "FaultCode",
    "RejectReason",
    "JobOutcome",
    "Segment",
    "SegmentBatch",
    "Control",
    "JointState",
    "BasePose",
    "JointCommand",
    "ExtruderCommand",
    "BaseCommand",
    "HeaterState",
    "HeaterCommand",
    "Status",
    "JobProgress",
    "ServiceNames",
    "service_names",
    "MESSAGE_TYPES",
    "EXPECTED_SIZES",
]

# --- constants -------------------------------------------------------------------------------------

#: Version of the contract; part of every type name and published in every Status.
CONTRACT_VERSION = 5
#: Joints per message (the longest chain strand drives).
MAX_JOINTS = 8
#: Segments per SegmentBatch.
SEGMENT_BATCH_CAPACITY = 32
#: Default service-name prefix.
DEFAULT_PREFIX = "strand/cell"


class SegmentKind(enum.IntEnum):
    """``Segment.kind``."""

    LINE = 0
    ARC = 1
    DWELL = 2
    #: A heater's target and, with ``heat_wait``, a hold until its temperature has settled.
    HEAT = 3


class Heater(enum.IntEnum):
    """``Segment.heater``."""

    HOT_END = 0
    BED = 1


class HeatWait(enum.IntEnum):
    """``Segment.heat_wait``."""

    NONE = 0
    #: M109 S / M190 S: hold while heating until |T - target| <= tolerance (no wait for cooling).
    HEATING = 1
    #: M109 R / M190 R: hold until |T - target| <= tolerance, cooling too.
    BOTH = 2
    #: TEMPERATURE_WAIT: hold until temperature_range[0] <= T <= temperature_range[1].
    RANGE = 3


class HeatHold(enum.IntEnum):
    """``Status.heat_hold``."""

    NONE = 0
    HOT_END = 1
    BED = 2


class HeaterFlags(enum.IntFlag):
    """Bits of ``HeaterState.flags`` and ``Status.heater_flags``."""

    NONE = 0
    HOT_END = 1
    BED = 2
    #: (Status only) the service acts on temperatures ([extruder] heater = "wire").
    ACTING = 4
    #: (HeaterState only) the owner switched a heater off for a fault: the service faults HEATER_FAULT.
    FAULT = 8


class SegmentFlags(enum.IntFlag):
    """Bits of ``Segment.flags``."""

    NONE = 0
    EXTRUDE = 1
    TRAVEL = 2
    LAYER_START = 4
    #: The last segment of the job: the controller stops at its end and reports the job finished.
    LAST = 8
    #: ``Segment.pressure_advance`` holds the program's pressure advance for this segment.
    PRESSURE_ADVANCE = 16
    #: ``Segment.axes`` holds where the cell's external axes are at the segment's end.
    AXES = 32


class ExtruderFlags(enum.IntFlag):
    """Bits of ``ExtruderCommand.flags``."""

    NONE = 0
    EXTRUDING = 1
    RETRACTED = 2


class JointStateFlags(enum.IntFlag):
    """Bits of ``JointState.flags``."""

    NONE = 0
    #: ``JointState.robot_target`` holds the joint target the robot was last given.
    TARGET_KNOWN = 1
    #: Since the previous JointState the robot kept its last target through one cycle or more.
    HELD = 2
    #: The robot's last target was not the service's command: the driver's guard is catching up.
    CATCHING_UP = 4


class Command(enum.IntEnum):
    """``Control.command``."""

    START = 1
    PAUSE = 2
    RESUME = 3
    STOP = 4
    EMERGENCY_STOP = 5
    CLEAR_FAULT = 6
    FEED_OVERRIDE = 7
    FLOW_OVERRIDE = 8
    #: The robot's own speed scaling (fraction, 0.01 to 1), from its driver: the path runs at the
    #: feed override times it.
    ROBOT_SPEED_SCALING = 9
    #: The next job starts ``value`` m along a moving base's plan (a resumed job).
    PROGRESS_OFFSET = 10


class RunState(enum.IntEnum):
    """``Status.run_state``."""

    IDLE = 0
    APPROACHING = 1
    RUNNING = 2
    PAUSING = 3
    PAUSED = 4
    STOPPING = 5
    EMERGENCY_STOPPING = 6
    FAULT = 7


class FaultCode(enum.IntEnum):
    """``Status.fault``."""

    NONE = 0
    EMERGENCY_STOP = 1
    TRACKING_LOST = 2
    JOINT_STATE_LOST = 3
    NON_FINITE = 4
    APPROACH_FAILED = 5
    ROBOT_DEVIATION = 6
    PATH_STALLED = 7
    TCP_ERROR_LIMIT = 8
    COLD_EXTRUSION = 9
    TEMPERATURE_LOST = 10
    HEATER_FAULT = 11


class RejectReason(enum.IntEnum):
    """``Status.last_reject_reason``."""

    NONE = 0
    NON_FINITE = 1
    BAD_FEED = 2
    OUT_OF_BOUNDS = 3
    SEQUENCE_GAP = 4
    QUEUE_FULL = 5
    BAD_GEOMETRY = 6
    UNKNOWN_KIND = 7
    NOT_READY = 8
    NOT_ALLOWED = 9
    BAD_VALUE = 10
    WRONG_DOF = 11
    STALE = 12


class JobOutcome(enum.IntEnum):
    """``Status.job_outcome``."""

    NONE = 0
    IN_PROGRESS = 1
    FINISHED = 2
    STOPPED = 3
    FAULTED = 4


class LogState(enum.IntEnum):
    """``Status.log_state``."""

    OFF = 0
    RECORDING = 1
    FAILED = 2
    RECORD_ONLY = 3


def enum_name(cls: type[enum.IntEnum], value: int) -> str:
    """``cls(value).name``, or ``"<unknown N>"`` for a wire value the enum does not name."""
    try:
        return cls(value).name
    except ValueError:
        return f"<unknown {value}>"


# --- messages --------------------------------------------------------------------------------------

_u32 = ctypes.c_uint32
_u64 = ctypes.c_uint64
_f64 = ctypes.c_double
_i32 = ctypes.c_int32
_u8 = ctypes.c_uint8


class _Message(ctypes.Structure):
    """Common helpers (not a message itself)."""

    def copy(self):
        """A detached copy (e.g. of a sample's payload that points into shared memory)."""
        return type(self).from_buffer_copy(self)

    def to_dict(self) -> dict:
        out = {}
        for name, _t in self._fields_:
            v = getattr(self, name)
            if isinstance(v, ctypes.Array):
                v = [x.to_dict() if isinstance(x, _Message) else x for x in v]
            out[name] = v
        return out

    def __repr__(self) -> str:
        body = ", ".join(f"{k}={v!r}" for k, v in self.to_dict().items() if k != "segments")
        return f"{type(self).__name__}({body})"


class Segment(_Message):
    """One planned motion segment, world frame W (with a positioner: the work frame at home). 224 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("kind", _u32),
        ("flags", _u32),
        ("end", _f64 * 3),
        ("centre", _f64 * 3),
        ("normal", _f64 * 3),
        ("sweep", _f64),
        ("orientation", _f64 * 4),
        ("feed", _f64),
        ("filament", _f64),
        ("duration", _f64),
        ("source_line", _u32),
        ("_reserved", _u32),
        ("pressure_advance", _f64),
        ("axes", _f64 * 2),
        ("heater", _u32),
        ("heat_wait", _u32),
        ("temperature", _f64),
        ("temperature_range", _f64 * 2),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.Segment"

    @classmethod
    def line(
        cls,
        seq: int,
        end,
        feed: float,
        orientation=(0.0, 0.0, 1.0, 0.0),
        filament: float = 0.0,
        flags: int = 0,
        source_line: int = 0,
    ) -> "Segment":
        """A straight line to ``end`` (m, W) at ``feed`` (m/s)."""
        s = cls()
        s.seq = seq
        s.kind = SegmentKind.LINE
        s.flags = int(flags)
        s.end[:] = [float(x) for x in end]
        s.orientation[:] = [float(x) for x in orientation]
        s.feed = float(feed)
        s.filament = float(filament)
        s.source_line = source_line
        return s


class SegmentBatch(_Message):
    """Up to SEGMENT_BATCH_CAPACITY segments, in order; entries at ``len`` and beyond are ignored."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("len", _u32),
        ("_reserved", _u32),
        ("segments", Segment * SEGMENT_BATCH_CAPACITY),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.SegmentBatch"

    def as_list(self) -> list[Segment]:
        """The segments in use (copies)."""
        return [self.segments[k].copy() for k in range(min(self.len, SEGMENT_BATCH_CAPACITY))]


class Control(_Message):
    """A command to the controller. 32 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("command", _u32),
        ("_reserved", _u32),
        ("value", _f64),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.Control"


class JointState(_Message):
    """Measured joint state from the robot driver, and what the driver last told the robot. 344 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("dof", _u32),
        ("flags", _u32),
        ("position", _f64 * MAX_JOINTS),
        ("velocity", _f64 * MAX_JOINTS),
        ("effort", _f64 * MAX_JOINTS),
        ("robot_target", _f64 * MAX_JOINTS),
        ("robot_target_velocity", _f64 * MAX_JOINTS),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.JointState"


class BasePose(_Message):
    """A measured pose of the robot base B in W, from tracking. 72 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("position", _f64 * 3),
        ("orientation", _f64 * 4),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.BasePose"


class JointCommand(_Message):
    """The joint command for the robot driver. 240 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("tick", _u64),
        ("state_seq", _u64),
        ("state_stamp_ns", _u64),
        ("dof", _u32),
        ("valid", _u32),
        ("position", _f64 * MAX_JOINTS),
        ("velocity", _f64 * MAX_JOINTS),
        ("acceleration", _f64 * MAX_JOINTS),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.JointCommand"


class ExtruderCommand(_Message):
    """The extruder command for the extruder driver. 64 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("tick", _u64),
        ("motor_speed", _f64),
        ("filament_rate", _f64),
        ("filament_position", _f64),
        ("volumetric_rate", _f64),
        ("flags", _u32),
        ("_reserved", _u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.ExtruderCommand"


class BaseCommand(_Message):
    """The moving base's setpoint, by the print's progress (``[base] plan``). 152 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("tick", _u64),
        ("position", _f64 * 3),
        ("orientation", _f64 * 4),
        ("velocity", _f64 * 3),
        ("angular_velocity", _f64 * 3),
        ("progress", _f64),
        ("lag", _f64),
        ("valid", _u32),
        ("_reserved", _u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.BaseCommand"


class Status(_Message):
    """The controller's state, published every tick. 192 bytes.

    Credit-based back-pressure: a feeder may send segment sequence numbers up to
    ``last_received_seq + queue_free`` (see :meth:`credit_limit`).
    """

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("tick", _u64),
        ("contract_version", _u32),
        ("run_state", _u32),
        ("fault", _u32),
        ("job_outcome", _u32),
        ("last_reject_reason", _u32),
        ("queue_capacity", _u32),
        ("queue_free", _u32),
        ("executing_line", _u32),
        ("last_received_seq", _u64),
        ("last_rejected_seq", _u64),
        ("executing_seq", _u64),
        ("segments_accepted", _u64),
        ("rejected", _u64),
        ("underruns", _u64),
        ("overruns", _u64),
        ("late_wakeups", _u64),
        ("worst_lateness_ns", _u64),
        ("clamps", _u64),
        ("log_drops", _u64),
        ("feed_override", _f64),
        ("flow_override", _f64),
        ("path_position", _f64),
        ("path_speed", _f64),
        ("tcp_error", _f64),
        ("log_state", _u32),
        ("executing_layer", _u32),
        ("hot_end_temperature", _f64),
        ("hot_end_target", _f64),
        ("bed_temperature", _f64),
        ("bed_target", _f64),
        ("heater_flags", _u32),
        ("heat_hold", _u32),
        ("heat_hold_left", _f64),
        ("heat_hold_band", _f64 * 2),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.Status"

    def credit_limit(self) -> int:
        """The last segment sequence number a feeder may send now."""
        return self.last_received_seq + self.queue_free

    def describe(self) -> str:
        """One line for humans."""
        return (
            f"tick {self.tick} state {enum_name(RunState, self.run_state)} "
            f"outcome {enum_name(JobOutcome, self.job_outcome)} fault {enum_name(FaultCode, self.fault)} "
            f"accepted {self.segments_accepted} last_received {self.last_received_seq} "
            f"free {self.queue_free}/{self.queue_capacity} rejected {self.rejected} "
            f"(last {enum_name(RejectReason, self.last_reject_reason)} seq {self.last_rejected_seq}) "
            f"executing {self.executing_seq} (line {self.executing_line}) path {self.path_position:.4f} m at {self.path_speed:.4f} m/s "
            f"underruns {self.underruns} overruns {self.overruns} clamps {self.clamps}"
        )


class HeaterState(_Message):
    """Measured heater temperatures (°C) from the heaters' owner (strand-sim, a board's process). 56 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("hot_end", _f64),
        ("bed", _f64),
        ("hot_end_power", _f64),
        ("bed_power", _f64),
        ("flags", _u32),
        ("_reserved", _u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.HeaterState"


class HeaterCommand(_Message):
    """The heater targets (°C; 0 = off), every tick. 48 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("tick", _u64),
        ("hot_end_target", _f64),
        ("bed_target", _f64),
        ("_reserved", _u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.HeaterCommand"


class JobProgress(_Message):
    """A feeder's progress of the job it streams, for consoles (its own service). 112 bytes."""

    _fields_ = [
        ("seq", _u64),
        ("stamp_ns", _u64),
        ("first_seq", _u64),
        ("last_seq", _u64),
        ("segments_sent", _u64),
        ("layer", _i32),
        ("last_layer", _i32),
        ("fraction", _f64),
        ("elapsed_s", _f64),
        ("eta_s", _f64),
        ("name", _u8 * 40),
    ]

    @staticmethod
    def type_name() -> str:
        return "strand.v5.JobProgress"


# --- service names ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ServiceNames:
    """The service names of one cell, all under one prefix (no trailing slash)."""

    prefix: str
    segments: str
    control: str
    joint_state: str
    base_pose: str
    joint_command: str
    extruder_command: str
    base_command: str
    status: str
    job_progress: str
    heater_state: str
    heater_command: str


def service_names(prefix: str = DEFAULT_PREFIX) -> ServiceNames:
    """Names under ``prefix``, as ``ServiceNames::new`` builds them in Rust."""
    p = prefix.rstrip("/")
    return ServiceNames(
        prefix=p,
        segments=f"{p}/segments",
        control=f"{p}/control",
        joint_state=f"{p}/joint_state",
        base_pose=f"{p}/base_pose",
        joint_command=f"{p}/joint_command",
        extruder_command=f"{p}/extruder_command",
        base_command=f"{p}/base_command",
        status=f"{p}/status",
        job_progress=f"{p}/job_progress",
        heater_state=f"{p}/heater_state",
        heater_command=f"{p}/heater_command",
    )


# --- layout self-check -----------------------------------------------------------------------------

MESSAGE_TYPES = (
    Segment,
    SegmentBatch,
    Control,
    JointState,
    BasePose,
    HeaterState,
    JointCommand,
    ExtruderCommand,
    HeaterCommand,
    BaseCommand,
    Status,
    JobProgress,
)

#: Sizes from the Rust test ``sizes_are_stable`` (wire/src/lib.rs).
EXPECTED_SIZES = {
    Segment: 224,
    SegmentBatch: 24 + 32 * 224,
    Control: 32,
    JointState: 24 + 5 * 64,
    BasePose: 72,
    JointCommand: 48 + 3 * 64,
    ExtruderCommand: 64,
    BaseCommand: 152,
    HeaterState: 56,
    HeaterCommand: 48,
    Status: 256,
    JobProgress: 112,
}

assert ctypes.sizeof(Segment) == 224
assert ctypes.sizeof(SegmentBatch) == 24 + 32 * 224
assert ctypes.sizeof(Control) == 32
assert ctypes.sizeof(JointState) == 344
assert ctypes.sizeof(BasePose) == 72
assert ctypes.sizeof(JointCommand) == 240
assert ctypes.sizeof(ExtruderCommand) == 64
assert ctypes.sizeof(BaseCommand) == 152
assert ctypes.sizeof(Status) == 256
for _t in MESSAGE_TYPES:
    assert ctypes.sizeof(_t) == EXPECTED_SIZES[_t], _t
    assert ctypes.alignment(_t) == 8, _t
    assert _t.type_name() == f"strand.v{CONTRACT_VERSION}.{_t.__name__}", _t
del _t
assert service_names("strand/test/").segments == "strand/test/segments"
assert service_names("strand/test/").status == "strand/test/status"


if __name__ == "__main__":
    for t in MESSAGE_TYPES:
        print(f"{t.type_name():28s} size {ctypes.sizeof(t):5d} align {ctypes.alignment(t)}")
