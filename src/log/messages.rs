//! What each log channel carries: the ros2msg schemas and CDR encodings of the wire messages
//! (`strand_msgs/msg/*`), of the standard ROS types the third-party tools understand
//! (`sensor_msgs/msg/JointState`, `geometry_msgs/msg/PoseStamped`), and of `strand_msgs/msg/Tick`,
//! which holds a tick's complete `TickInput` and `TickOutput` with every `f64` bit, for replay.
//!
//! Variable-length parts (segments, controls, tracking samples, events) are CDR sequences holding
//! only the used entries, so a quiet tick costs a few hundred bytes, not the 12 kB of the in-memory
//! `TickInput`.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use strand_ipc as ipc;
use strand_ipc::{FaultCode, JobOutcome, RejectReason, RunState};

use super::cdr::{CdrError, CdrReader, CdrType, CdrWriter, Scalar, add_dependency};
use crate::cdr_message;
use strand_core::BaseState;
use strand_core::{
    CycleCounters, Event, MAX_BASE_POSES_PER_TICK, MAX_CONTROLS_PER_TICK, MAX_EVENTS, MAX_SEGMENTS_PER_TICK, TickDiagnostics, TickInput,
    TickOutput,
};

cdr_message!(
    ipc::Segment,
    "strand_msgs/msg/Segment",
    [seq, stamp_ns, kind, flags, end, centre, normal, sweep, orientation, feed, filament, duration, source_line, pressure_advance]
);
cdr_message!(ipc::Control, "strand_msgs/msg/Control", [seq, stamp_ns, command, value]);
cdr_message!(
    ipc::JointState,
    "strand_msgs/msg/JointState",
    [seq, stamp_ns, dof, flags, position, velocity, effort, robot_target, robot_target_velocity]
);
cdr_message!(ipc::BasePose, "strand_msgs/msg/BasePose", [seq, stamp_ns, position, orientation]);
cdr_message!(
    ipc::JointCommand,
    "strand_msgs/msg/JointCommand",
    [seq, stamp_ns, tick, state_seq, state_stamp_ns, dof, valid, position, velocity, acceleration]
);
cdr_message!(
    ipc::ExtruderCommand,
    "strand_msgs/msg/ExtruderCommand",
    [seq, stamp_ns, tick, motor_speed, filament_rate, filament_position, volumetric_rate, flags]
);
cdr_message!(
    ipc::BaseCommand,
    "strand_msgs/msg/BaseCommand",
    [seq, stamp_ns, tick, position, orientation, velocity, angular_velocity, progress, lag, valid]
);
cdr_message!(
    ipc::Status,
    "strand_msgs/msg/Status",
    [
        seq,
        stamp_ns,
        tick,
        contract_version,
        run_state,
        fault,
        job_outcome,
        last_reject_reason,
        queue_capacity,
        queue_free,
        executing_line,
        last_received_seq,
        last_rejected_seq,
        executing_seq,
        segments_accepted,
        rejected,
        underruns,
        overruns,
        late_wakeups,
        worst_lateness_ns,
        clamps,
        log_drops,
        feed_override,
        flow_override,
        path_position,
        path_speed,
        tcp_error,
        log_state,
        executing_layer
    ]
);
cdr_message!(ipc::HeaterState, "strand_msgs/msg/HeaterState", [seq, stamp_ns, hot_end, bed, hot_end_power, bed_power, flags]);
cdr_message!(ipc::HeaterCommand, "strand_msgs/msg/HeaterCommand", [seq, stamp_ns, tick, hot_end_target, bed_target]);

/// The temperature part of a tick (contract v5), logged after the segments' axes: the input's
/// heater measurement, the heat fields of the input's segments, the heater command and the heat
/// fields of the status. A log from before reads back without them (zeros: what a controller
/// without temperatures had).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeatStatus {
    /// `Status::hot_end_temperature` (°C).
    pub hot_end_temperature: f64,
    /// `Status::hot_end_target` (°C).
    pub hot_end_target: f64,
    /// `Status::bed_temperature` (°C).
    pub bed_temperature: f64,
    /// `Status::bed_target` (°C).
    pub bed_target: f64,
    /// `Status::heater_flags`.
    pub heater_flags: u32,
    /// `Status::heat_hold`.
    pub heat_hold: u32,
    /// `Status::heat_hold_left` (s).
    pub heat_hold_left: f64,
    /// `Status::heat_hold_band` (°C).
    pub heat_hold_band: [f64; 2],
}
cdr_message!(
    HeatStatus,
    "strand_msgs/msg/HeatStatus",
    [hot_end_temperature, hot_end_target, bed_temperature, bed_target, heater_flags, heat_hold, heat_hold_left, heat_hold_band]
);

impl HeatStatus {
    /// The temperature fields of `s`.
    pub fn of(s: &ipc::Status) -> Self {
        HeatStatus {
            hot_end_temperature: s.hot_end_temperature,
            hot_end_target: s.hot_end_target,
            bed_temperature: s.bed_temperature,
            bed_target: s.bed_target,
            heater_flags: s.heater_flags,
            heat_hold: s.heat_hold,
            heat_hold_left: s.heat_hold_left,
            heat_hold_band: s.heat_hold_band,
        }
    }
    pub(crate) fn put(&self, s: &mut ipc::Status) {
        s.hot_end_temperature = self.hot_end_temperature;
        s.hot_end_target = self.hot_end_target;
        s.bed_temperature = self.bed_temperature;
        s.bed_target = self.bed_target;
        s.heater_flags = self.heater_flags;
        s.heat_hold = self.heat_hold;
        s.heat_hold_left = self.heat_hold_left;
        s.heat_hold_band = self.heat_hold_band;
    }
}

cdr_message!(CycleCounters, "strand_msgs/msg/CycleCounters", [overruns, late_wakeups, worst_lateness_ns, log_drops, log_state]);
cdr_message!(BaseState, "strand_msgs/msg/BaseState", [position, orientation, linear_velocity, angular_velocity]);
cdr_message!(
    TickDiagnostics,
    "strand_msgs/msg/TickDiagnostics",
    [tcp_target_world, tcp_target_orientation, tcp_command_world, base, clik_scale, path_scale, sigma_min, path_speed, tcp_error]
);

impl CdrType for Vector3<f64> {
    fn ros_type() -> String {
        "float64[3]".to_string()
    }
    fn write(&self, w: &mut CdrWriter) {
        for v in self.iter() {
            w.f64(*v);
        }
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Vector3::new(r.f64()?, r.f64()?, r.f64()?))
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        for (i, v) in self.iter().enumerate() {
            out.push((format!("{path}[{i}]"), Scalar::F(*v)));
        }
    }
}

/// Stored as (w, x, y, z), the project's order, without renormalising (bit-exact round trip).
impl CdrType for UnitQuaternion<f64> {
    fn ros_type() -> String {
        "float64[4]".to_string()
    }
    fn write(&self, w: &mut CdrWriter) {
        for v in [self.w, self.i, self.j, self.k] {
            w.f64(v);
        }
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        let (qw, qx, qy, qz) = (r.f64()?, r.f64()?, r.f64()?, r.f64()?);
        Ok(UnitQuaternion::new_unchecked(Quaternion::new(qw, qx, qy, qz)))
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        for (name, v) in [("w", self.w), ("x", self.i), ("y", self.j), ("z", self.k)] {
            out.push((format!("{path}.{name}"), Scalar::F(v)));
        }
    }
}

/// Field names the controller reports in rejections; a decoded name maps back to the same
/// `&'static str` (unknown ones, from another build, are kept by leaking them: replay only).
const FIELD_NAMES: &[&str] =
    &["", "kind", "end", "centre", "normal", "sweep", "orientation", "feed", "filament", "duration", "seq", "flags", "source_line"];

fn intern(s: &str) -> &'static str {
    FIELD_NAMES.iter().find(|f| **f == s).copied().unwrap_or_else(|| Box::leak(s.to_string().into_boxed_str()))
}

const EVENT_DEFINITION: &str = "\
# 1 segment rejected (seq, a = reason, field), 2 control rejected (a = command, b = reason),
# 3 joint state rejected (seq, a = reason), 4 base pose rejected (seq), 5 state changed (a = from, b = to),
# 6 fault (a = code, seq = segment executing, b = its source line, value = the figure that tripped it, e.g. the TCP error in m),
# 7 job ended (a = outcome, seq = last segment), 8 clamped (a = joint)
uint8 kind
uint64 seq
uint32 a
uint32 b
float64 value
string field
";

fn unknown(what: &'static str, value: u32) -> CdrError {
    CdrError::Unknown { what, value }
}

impl CdrType for Event {
    fn ros_type() -> String {
        "strand_msgs/Event".to_string()
    }
    fn dependencies(out: &mut Vec<(String, String)>) {
        add_dependency(out, Self::ros_type(), || EVENT_DEFINITION.to_string());
    }
    fn write(&self, w: &mut CdrWriter) {
        let (kind, seq, a, b, value, field) = event_parts(self);
        w.u8(kind);
        w.u64(seq);
        w.u32(a);
        w.u32(b);
        w.f64(value);
        w.string(field);
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        let (kind, seq, a, b, value, field) = (r.u8()?, r.u64()?, r.u32()?, r.u32()?, r.f64()?, r.string()?);
        let reason = |v| RejectReason::from_u32(v).ok_or(unknown("RejectReason", v));
        let state = |v| RunState::from_u32(v).ok_or(unknown("RunState", v));
        Ok(match kind {
            1 => Event::SegmentRejected { seq, reason: reason(a)?, field: intern(field) },
            2 => Event::ControlRejected { command: a, reason: reason(b)? },
            3 => Event::JointStateRejected { seq, reason: reason(a)? },
            4 => Event::BasePoseRejected { seq },
            5 => Event::StateChanged { from: state(a)?, to: state(b)? },
            6 => Event::Fault { code: FaultCode::from_u32(a).ok_or(unknown("FaultCode", a))?, seq, line: b, value },
            7 => Event::JobEnded { outcome: JobOutcome::from_u32(a).ok_or(unknown("JobOutcome", a))?, last_seq: seq },
            8 => Event::Clamped { joint: a as u8 },
            9 => Event::HeatWaitSkipped { seq },
            10 => Event::HeaterStateRejected { seq },
            k => return Err(unknown("event kind", k as u32)),
        })
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        let (kind, seq, a, b, value, field) = event_parts(self);
        out.push((format!("{path}.kind"), Scalar::U(kind as u64)));
        out.push((format!("{path}.seq"), Scalar::U(seq)));
        out.push((format!("{path}.a"), Scalar::U(a as u64)));
        out.push((format!("{path}.b"), Scalar::U(b as u64)));
        out.push((format!("{path}.value"), Scalar::F(value)));
        out.push((format!("{path}.field"), Scalar::S(field)));
    }
}

/// The wire fields (kind, seq, a, b, value, field) of `EVENT_DEFINITION`.
fn event_parts(event: &Event) -> (u8, u64, u32, u32, f64, &'static str) {
    match *event {
        Event::SegmentRejected { seq, reason, field } => (1, seq, reason as u32, 0, 0.0, field),
        Event::ControlRejected { command, reason } => (2, 0, command, reason as u32, 0.0, ""),
        Event::JointStateRejected { seq, reason } => (3, seq, reason as u32, 0, 0.0, ""),
        Event::BasePoseRejected { seq } => (4, seq, 0, 0, 0.0, ""),
        Event::StateChanged { from, to } => (5, 0, from as u32, to as u32, 0.0, ""),
        Event::Fault { code, seq, line, value } => (6, seq, code as u32, line, value, ""),
        Event::JobEnded { outcome, last_seq } => (7, last_seq, outcome as u32, 0, 0.0, ""),
        Event::Clamped { joint } => (8, 0, joint as u32, 0, 0.0, ""),
        Event::HeatWaitSkipped { seq } => (9, seq, 0, 0, 0.0, ""),
        Event::HeaterStateRejected { seq } => (10, seq, 0, 0, 0.0, ""),
    }
}

fn write_seq<T: CdrType>(w: &mut CdrWriter, items: &[T]) {
    w.len(items.len());
    for v in items {
        v.write(w);
    }
}

fn flatten_seq<T: CdrType>(items: &[T], path: &str, out: &mut Vec<(String, Scalar)>) {
    out.push((format!("{path}.len"), Scalar::U(items.len() as u64)));
    for (i, v) in items.iter().enumerate() {
        v.flatten(&format!("{path}[{i}]"), out);
    }
}

const TICK_INPUT_DEFINITION: &str = "\
uint64 tick
uint64 time_ns
strand_msgs/Segment[<=64] segments
strand_msgs/Control[<=8] controls
strand_msgs/JointState[<=1] joint_state
strand_msgs/BasePose[<=8] base_poses
bool feeder_lost
strand_msgs/CycleCounters cycle
";

impl CdrType for TickInput {
    fn ros_type() -> String {
        "strand_msgs/TickInput".to_string()
    }
    fn dependencies(out: &mut Vec<(String, String)>) {
        ipc::Segment::dependencies(out);
        ipc::Control::dependencies(out);
        ipc::JointState::dependencies(out);
        ipc::BasePose::dependencies(out);
        CycleCounters::dependencies(out);
        add_dependency(out, Self::ros_type(), || TICK_INPUT_DEFINITION.to_string());
    }
    fn write(&self, w: &mut CdrWriter) {
        w.u64(self.tick);
        w.u64(self.time_ns);
        write_seq(w, self.segments());
        write_seq(w, self.controls());
        write_seq(w, self.joint_state.as_slice());
        write_seq(w, self.base_poses());
        self.feeder_lost.write(w);
        self.cycle.write(w);
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        let mut v = TickInput::new(r.u64()?, r.u64()?);
        for _ in 0..r.len(MAX_SEGMENTS_PER_TICK)? {
            v.push_segment(&ipc::Segment::read(r)?);
        }
        for _ in 0..r.len(MAX_CONTROLS_PER_TICK)? {
            v.push_control(&ipc::Control::read(r)?);
        }
        if r.len(1)? == 1 {
            v.joint_state = Some(ipc::JointState::read(r)?);
        }
        for _ in 0..r.len(MAX_BASE_POSES_PER_TICK)? {
            v.push_base_pose(&ipc::BasePose::read(r)?);
        }
        v.feeder_lost = bool::read(r)?;
        v.cycle = CycleCounters::read(r)?;
        Ok(v)
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        out.push((format!("{path}.tick"), Scalar::U(self.tick)));
        out.push((format!("{path}.time_ns"), Scalar::U(self.time_ns)));
        flatten_seq(self.segments(), &format!("{path}.segments"), out);
        flatten_seq(self.controls(), &format!("{path}.controls"), out);
        flatten_seq(self.joint_state.as_slice(), &format!("{path}.joint_state"), out);
        flatten_seq(self.base_poses(), &format!("{path}.base_poses"), out);
        self.feeder_lost.flatten(&format!("{path}.feeder_lost"), out);
        self.cycle.flatten(&format!("{path}.cycle"), out);
    }
}

const TICK_OUTPUT_DEFINITION: &str = "\
strand_msgs/JointCommand joint_command
strand_msgs/ExtruderCommand extruder
strand_msgs/Status status
strand_msgs/Event[<=16] events
uint32 events_dropped
strand_msgs/TickDiagnostics diagnostics
";

impl CdrType for TickOutput {
    fn ros_type() -> String {
        "strand_msgs/TickOutput".to_string()
    }
    fn dependencies(out: &mut Vec<(String, String)>) {
        ipc::JointCommand::dependencies(out);
        ipc::ExtruderCommand::dependencies(out);
        ipc::Status::dependencies(out);
        Event::dependencies(out);
        TickDiagnostics::dependencies(out);
        add_dependency(out, Self::ros_type(), || TICK_OUTPUT_DEFINITION.to_string());
    }
    fn write(&self, w: &mut CdrWriter) {
        self.joint_command.write(w);
        self.extruder.write(w);
        self.status.write(w);
        write_seq(w, self.events());
        w.u32(self.events_dropped);
        self.diagnostics.write(w);
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        let mut v = TickOutput {
            joint_command: ipc::JointCommand::read(r)?,
            extruder: ipc::ExtruderCommand::read(r)?,
            status: ipc::Status::read(r)?,
            ..Default::default()
        };
        for _ in 0..r.len(MAX_EVENTS)? {
            v.push(Event::read(r)?);
        }
        v.events_dropped = r.u32()?;
        v.diagnostics = TickDiagnostics::read(r)?;
        Ok(v)
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        self.joint_command.flatten(&format!("{path}.joint_command"), out);
        self.extruder.flatten(&format!("{path}.extruder"), out);
        self.status.flatten(&format!("{path}.status"), out);
        flatten_seq(self.events(), &format!("{path}.events"), out);
        out.push((format!("{path}.events_dropped"), Scalar::U(self.events_dropped as u64)));
        self.diagnostics.flatten(&format!("{path}.diagnostics"), out);
        self.base_command.flatten(&format!("{path}.base_command"), out);
    }
}

pub use crate::io::runner::TickTiming;
cdr_message!(TickTiming, "strand_msgs/msg/TickTiming", [wake_lateness_ns, step_ns, tick_ns]);

/// One tick as logged on `/strand/tick`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Tick {
    /// Everything that influenced the tick.
    pub input: TickInput,
    /// Everything it decided.
    pub output: TickOutput,
    /// What it cost.
    pub timing: TickTiming,
}

const TICK_DEFINITION: &str = "\
strand_msgs/TickInput input
strand_msgs/TickOutput output
strand_msgs/TickTiming timing
strand_msgs/BaseCommand base_command
float64[] segment_axes
strand_msgs/HeaterState[<=1] heater_state
float64[] segment_heat
strand_msgs/HeaterCommand heater
strand_msgs/HeatStatus heat_status
uint64 receive_ns
uint64 command_ns
";

/// The base command (`TickOutput::base_command`) is written after the timing, then the external
/// axes of this tick's input segments (`Segment::axes`, two numbers each, in order: a `Segment`
/// record leaves them out so that logs from before them keep their layout). A log from before
/// either ends earlier and reads back with an invalid (absent) base command and zero axes, which is
/// what its controller had. Replays compare the base command with the rest of the output
/// ([`encode_output`]).
impl CdrType for Tick {
    fn ros_type() -> String {
        "strand_msgs/Tick".to_string()
    }
    fn dependencies(out: &mut Vec<(String, String)>) {
        TickInput::dependencies(out);
        TickOutput::dependencies(out);
        TickTiming::dependencies(out);
        ipc::BaseCommand::dependencies(out);
        ipc::HeaterState::dependencies(out);
        ipc::HeaterCommand::dependencies(out);
        HeatStatus::dependencies(out);
        add_dependency(out, Self::ros_type(), || TICK_DEFINITION.to_string());
    }
    fn write(&self, w: &mut CdrWriter) {
        self.input.write(w);
        self.output.write(w);
        self.timing.write(w);
        self.output.base_command.write(w);
        let segments = self.input.segments();
        w.len(segments.len() * ipc::MAX_EXTERNAL_AXES);
        for s in segments {
            for a in s.axes {
                w.f64(a);
            }
        }
        write_heat(w, &self.input, &self.output);
        w.u64(self.timing.receive_ns);
        w.u64(self.timing.command_ns);
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        let mut v = Tick { input: TickInput::read(r)?, output: TickOutput::read(r)?, timing: TickTiming::read(r)? };
        // More than the alignment padding a writer may add: the base command follows, then the axes.
        if r.remaining() > 3 {
            v.output.base_command = ipc::BaseCommand::read(r)?;
        }
        if r.remaining() > 3 {
            let n = v.input.segment_count as usize;
            if r.len(n * ipc::MAX_EXTERNAL_AXES)? != n * ipc::MAX_EXTERNAL_AXES {
                return Err(CdrError::Truncated { at: r.position(), what: "segment_axes (two per segment)" });
            }
            for k in 0..n {
                for a in 0..ipc::MAX_EXTERNAL_AXES {
                    v.input.segments[k].axes[a] = r.f64()?;
                }
            }
        }
        if r.remaining() > 3 {
            read_heat(r, &mut v.input, &mut v.output)?;
        }
        // The timing's stages (receive, command), after the heat part: absent (0) in older logs.
        if r.remaining() > 3 {
            v.timing.receive_ns = r.u64()?;
            v.timing.command_ns = r.u64()?;
        }
        Ok(v)
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        self.input.flatten(&format!("{path}.input"), out);
        self.output.flatten(&format!("{path}.output"), out);
        self.timing.flatten(&format!("{path}.timing"), out);
    }
}

/// A tick's whole output in CDR, base command included (what a replay compares).
pub fn encode_output(w: &mut CdrWriter, output: &TickOutput) {
    w.begin();
    output.write(w);
    output.base_command.write(w);
    output.heater.write(w);
    HeatStatus::of(&output.status).write(w);
}

/// Numbers per segment in `segment_heat`: heater, wait, target, band low, band high.
const HEAT_PER_SEGMENT: usize = 5;

/// The temperature part of a tick (see [`HeatStatus`]).
fn write_heat(w: &mut CdrWriter, input: &TickInput, output: &TickOutput) {
    write_seq(w, input.heater_state.as_slice());
    let segments = input.segments();
    w.len(segments.len() * HEAT_PER_SEGMENT);
    for s in segments {
        for x in [f64::from(s.heater), f64::from(s.heat_wait), s.temperature, s.temperature_range[0], s.temperature_range[1]] {
            w.f64(x);
        }
    }
    output.heater.write(w);
    HeatStatus::of(&output.status).write(w);
}

fn read_heat(r: &mut CdrReader, input: &mut TickInput, output: &mut TickOutput) -> Result<(), CdrError> {
    if r.len(1)? == 1 {
        input.heater_state = Some(ipc::HeaterState::read(r)?);
    }
    let n = input.segment_count as usize;
    if r.len(n * HEAT_PER_SEGMENT)? != n * HEAT_PER_SEGMENT {
        return Err(CdrError::Truncated { at: r.position(), what: "segment_heat (five per segment)" });
    }
    for k in 0..n {
        let s = &mut input.segments[k];
        let (heater, wait) = (r.f64()?, r.f64()?);
        // Small whole numbers written from u32: exact in f64.
        (s.heater, s.heat_wait) = (heater as u32, wait as u32);
        s.temperature = r.f64()?;
        s.temperature_range = [r.f64()?, r.f64()?];
    }
    output.heater = ipc::HeaterCommand::read(r)?;
    HeatStatus::read(r)?.put(&mut output.status);
    Ok(())
}

/// Schema names and texts of the standard ROS 2 types, as in ROS 2 Humble (comments and default
/// values left out).
pub mod ros {
    use super::CdrWriter;

    const SEPARATOR: &str = "================================================================================";

    /// `sensor_msgs/msg/JointState`.
    pub(crate) const JOINT_STATE: &str = "sensor_msgs/msg/JointState";
    /// `geometry_msgs/msg/PoseStamped`.
    pub(crate) const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";

    fn header_deps() -> String {
        format!(
            "{SEPARATOR}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\
             {SEPARATOR}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
        )
    }

    /// The schema text of `sensor_msgs/msg/JointState`.
    pub(crate) fn joint_state_schema() -> String {
        format!("std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n{}", header_deps())
    }

    /// The schema text of `geometry_msgs/msg/PoseStamped`.
    pub(crate) fn pose_stamped_schema() -> String {
        format!(
            "std_msgs/Header header\ngeometry_msgs/Pose pose\n{}\
             {SEPARATOR}\nMSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n\
             {SEPARATOR}\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n\
             {SEPARATOR}\nMSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
            header_deps()
        )
    }

    fn header(w: &mut CdrWriter, stamp_ns: u64, frame_id: &str) {
        w.i32((stamp_ns / 1_000_000_000) as i32);
        w.u32((stamp_ns % 1_000_000_000) as u32);
        w.string(frame_id);
    }

    /// Encodes a JointState (`effort` may be empty).
    pub fn joint_state(w: &mut CdrWriter, stamp_ns: u64, names: &[String], position: &[f64], velocity: &[f64], effort: &[f64]) {
        w.begin();
        header(w, stamp_ns, "");
        w.len(names.len());
        for n in names {
            w.string(n);
        }
        for values in [position, velocity, effort] {
            w.len(values.len());
            for v in values {
                w.f64(*v);
            }
        }
    }

    /// Encodes a PoseStamped; `orientation` is (w, x, y, z) and goes out in ROS order (x, y, z, w).
    pub(crate) fn pose_stamped(w: &mut CdrWriter, stamp_ns: u64, frame_id: &str, position: [f64; 3], orientation: [f64; 4]) {
        w.begin();
        header(w, stamp_ns, frame_id);
        for v in position {
            w.f64(v);
        }
        let [qw, qx, qy, qz] = orientation;
        for v in [qx, qy, qz, qw] {
            w.f64(v);
        }
    }
}
