//! The controller: one deterministic state machine that joins intake, the path engine, extrusion, the
//! base correction and the CLIK into `Controller::step(&TickInput) -> TickOutput`.
//!
//! Everything that may influence a tick is in [`TickInput`] (tick index and nominal time, segments and
//! controls received since the last tick, the latest joint state, tracking samples, what the shell
//! observed of its peers and its own timing), and everything decided is in [`TickOutput`]. There is
//! no I/O, clock, thread or allocation in here, so a logged run replays bit for bit.
//!
//! Run states ([`RunState`]): idle → (approaching →) running ⇄ pausing → paused → running; stop
//! (controlled, on the path, then the rest of the job is discarded); fault (latched until ClearFault);
//! emergency stop (joints brake as hard as their acceleration limits allow, extrusion off at once,
//! then fault). A fault that arrives while the arm moves brakes it the same way.
//!
//! A job: segments arrive (they may queue while idle), then Start. The first point of a job is the
//! end of its first segment when that is a non-extruding line (G-code programs open with a travel
//! move); otherwise it is where the tool is. If the robot is not at the first point, Start first moves
//! it there in joint space with rsruckig (jerk-limited, all joints synchronised), without extruding.
//!
//! The final command stage enforces every joint's position, velocity and acceleration limits on
//! every command, counts each clamp, and never lets a non-finite number out: a NaN anywhere is a
//! fault, and the arm brakes from its last good command.

use nalgebra::{UnitQuaternion, Vector3};
use rsruckig::prelude::*;
use serde::{Deserialize, Serialize};
use strand_ipc as ipc;
use strand_ipc::{Command, FaultCode, JobOutcome, RejectReason, RunState};

use super::base::{BaseConfig, BaseEstimator, BaseState};
use super::extrude::{Extruder, ExtruderConfig};
use super::following::FollowingWatch;
use super::kin::{Clik, ClikConfig, ClikStep, JointVector, MAX_JOINTS, PathVelocity, RobotModel, TcpTarget};
use super::path::{Motion, PathConfig, PathEngine, PathSample, Segment, SegmentError, SegmentFlags, SegmentKind};

/// Segments a [`TickInput`] carries at most (the shell keeps the rest for the next tick).
pub const MAX_SEGMENTS_PER_TICK: usize = 64;
/// Controls a [`TickInput`] carries at most.
pub const MAX_CONTROLS_PER_TICK: usize = 8;
/// Tracking samples a [`TickInput`] carries at most (the newest are kept).
pub const MAX_BASE_POSES_PER_TICK: usize = 8;
/// Events a [`TickOutput`] carries at most; more are counted in `events_dropped`.
pub const MAX_EVENTS: usize = 16;

/// `[controller]`: the control loop and its supervision.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerConfig {
    /// Tick rate (Hz), 250 to 8000.
    pub rate_hz: f64,
    /// Joint state silent for longer than this (s) → fault. 0 disables (a driver that only listens).
    pub joint_state_timeout: f64,
    /// Measured joints further than this (rad or m) from the last command → fault. 0 disables.
    pub following_error_limit: f64,
    /// Cartesian following error (m): the distance between the path target and the TCP of the
    /// commanded joints (and, with a joint state fresh this tick, of the measured joints), in W.
    /// Above it for `tcp_error_time` while the path runs → `TcpErrorLimit` fault. 0 disables.
    pub tcp_error_limit: f64,
    /// How long (s) the Cartesian following error may stay above `tcp_error_limit`.
    pub tcp_error_time: f64,
    /// How far behind its command (s) the measured TCP may be and still count as on its path:
    /// the robot's command-to-motion delay, with margin (see `core::following`).
    pub tcp_error_lag: f64,
    /// Fraction of each joint's velocity, acceleration and jerk limit the approach move uses (0, 1].
    pub approach_speed_fraction: f64,
    /// The joint-space approach ends this far (m) above the end of the job's leading travel, back
    /// along the nozzle, and that travel then brings the tool straight down onto it on the path: a
    /// joint-space move sags between its ends, and next to the bed that is a crash.
    pub approach_lift: f64,
    /// The tool counts as at the first point within this distance (m) …
    pub approach_position_tolerance: f64,
    /// … and this nozzle-axis angle (rad).
    pub approach_orientation_tolerance: f64,
    /// Segment points must lie in this box (m, W): lower corner.
    pub bounds_min: [f64; 3],
    /// Upper corner (m, W).
    pub bounds_max: [f64; 3],
}

impl Default for ControllerConfig {
    fn default() -> Self {
        ControllerConfig {
            rate_hz: 1000.0,
            joint_state_timeout: 0.05,
            following_error_limit: 0.2,
            tcp_error_limit: 2e-3,
            tcp_error_time: 0.05,
            tcp_error_lag: 0.1,
            approach_speed_fraction: 0.3,
            approach_lift: 0.01,
            approach_position_tolerance: 0.1e-3,
            approach_orientation_tolerance: 0.01,
            bounds_min: [-2.0, -2.0, -1.0],
            bounds_max: [2.0, 2.0, 2.5],
        }
    }
}

impl ControllerConfig {
    /// The tick period (s).
    pub fn dt(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), String> {
        let k = "[controller]";
        if !(self.rate_hz.is_finite() && (250.0..=8000.0).contains(&self.rate_hz)) {
            return Err(format!("{k} rate_hz = {}: must lie in [250, 8000] Hz", self.rate_hz));
        }
        for (key, v, hi) in [
            ("joint_state_timeout", self.joint_state_timeout, 10.0),
            ("following_error_limit", self.following_error_limit, 10.0),
            ("tcp_error_limit", self.tcp_error_limit, 1.0),
            ("tcp_error_time", self.tcp_error_time, 10.0),
            ("tcp_error_lag", self.tcp_error_lag, 1.0),
            ("approach_position_tolerance", self.approach_position_tolerance, 0.1),
            ("approach_lift", self.approach_lift, 0.2),
            ("approach_orientation_tolerance", self.approach_orientation_tolerance, 1.0),
        ] {
            if !(v.is_finite() && (0.0..=hi).contains(&v)) {
                return Err(format!("{k} {key} = {v}: must lie in [0, {hi}]"));
            }
        }
        if !(self.approach_speed_fraction > 0.0 && self.approach_speed_fraction <= 1.0) {
            return Err(format!("{k} approach_speed_fraction = {}: must lie in (0, 1]", self.approach_speed_fraction));
        }
        for i in 0..3 {
            if !(self.bounds_min[i].is_finite() && self.bounds_max[i].is_finite() && self.bounds_min[i] < self.bounds_max[i]) {
                return Err(format!("{k} bounds_min/bounds_max: axis {i} must be finite with min < max"));
            }
        }
        Ok(())
    }
}

/// Cycle figures the shell measured, passed through to `Status` (they never change what the
/// controller does; they are inputs so that a replay reproduces Status exactly).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C)]
pub struct CycleCounters {
    /// Ticks whose work ended after the next deadline.
    pub overruns: u64,
    /// Wake-ups later than the threshold.
    pub late_wakeups: u64,
    /// Worst wake-up lateness (ns).
    pub worst_lateness_ns: u64,
    /// Log records dropped.
    pub log_drops: u64,
    /// [`ipc::LogState`] as u32.
    pub log_state: u32,
}

/// Everything that may influence one tick.
#[derive(Clone, Copy, Debug)]
pub struct TickInput {
    /// Tick index, from 0.
    pub tick: u64,
    /// Nominal time of this tick (ns, monotonic): the time the shell woke for it.
    pub time_ns: u64,
    /// Segments received since the last tick, in arrival order (`segment_count` used).
    pub segments: [ipc::Segment; MAX_SEGMENTS_PER_TICK],
    /// Segments used.
    pub segment_count: u32,
    /// Controls received since the last tick, in arrival order.
    pub controls: [ipc::Control; MAX_CONTROLS_PER_TICK],
    /// Controls used.
    pub control_count: u32,
    /// The latest joint state, if one arrived since the last tick.
    pub joint_state: Option<ipc::JointState>,
    /// Tracking samples received since the last tick, oldest first.
    pub base_poses: [ipc::BasePose; MAX_BASE_POSES_PER_TICK],
    /// Tracking samples used.
    pub base_pose_count: u32,
    /// The shell saw no segment publisher left while a job was in progress.
    pub feeder_lost: bool,
    /// The shell's timing counters.
    pub cycle: CycleCounters,
}

impl Default for TickInput {
    fn default() -> Self {
        TickInput::new(0, 0)
    }
}

impl TickInput {
    /// An input for tick `tick` at `time_ns` with nothing received.
    pub fn new(tick: u64, time_ns: u64) -> Self {
        TickInput {
            tick,
            time_ns,
            segments: [ipc::Segment::default(); MAX_SEGMENTS_PER_TICK],
            segment_count: 0,
            controls: [ipc::Control::default(); MAX_CONTROLS_PER_TICK],
            control_count: 0,
            joint_state: None,
            base_poses: [ipc::BasePose::default(); MAX_BASE_POSES_PER_TICK],
            base_pose_count: 0,
            feeder_lost: false,
            cycle: CycleCounters::default(),
        }
    }

    /// Clears what was received, for reuse as tick `tick` at `time_ns`.
    pub fn reset(&mut self, tick: u64, time_ns: u64) {
        self.tick = tick;
        self.time_ns = time_ns;
        self.segment_count = 0;
        self.control_count = 0;
        self.joint_state = None;
        self.base_pose_count = 0;
        self.feeder_lost = false;
    }

    /// Adds a segment; false if the tick is full (keep it for the next tick).
    pub fn push_segment(&mut self, s: &ipc::Segment) -> bool {
        let n = self.segment_count as usize;
        if n >= MAX_SEGMENTS_PER_TICK {
            return false;
        }
        self.segments[n] = *s;
        self.segment_count += 1;
        true
    }

    /// Room for more segments this tick.
    pub fn segment_room(&self) -> usize {
        MAX_SEGMENTS_PER_TICK - self.segment_count as usize
    }

    /// Adds a control; false if the tick is full (keep it for the next tick).
    pub fn push_control(&mut self, c: &ipc::Control) -> bool {
        let n = self.control_count as usize;
        if n >= MAX_CONTROLS_PER_TICK {
            return false;
        }
        self.controls[n] = *c;
        self.control_count += 1;
        true
    }

    /// Adds a tracking sample; when full, the oldest is dropped (only the newest matter).
    pub fn push_base_pose(&mut self, p: &ipc::BasePose) {
        let n = self.base_pose_count as usize;
        if n >= MAX_BASE_POSES_PER_TICK {
            self.base_poses.copy_within(1.., 0);
            self.base_poses[MAX_BASE_POSES_PER_TICK - 1] = *p;
        } else {
            self.base_poses[n] = *p;
            self.base_pose_count += 1;
        }
    }

    /// The segments used.
    pub fn segments(&self) -> &[ipc::Segment] {
        &self.segments[..self.segment_count as usize]
    }

    /// The controls used.
    pub fn controls(&self) -> &[ipc::Control] {
        &self.controls[..self.control_count as usize]
    }

    /// The tracking samples used.
    pub fn base_poses(&self) -> &[ipc::BasePose] {
        &self.base_poses[..self.base_pose_count as usize]
    }
}

/// Something the shell should tell a human about (through `tracing`, after publishing).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// A segment was refused; everything accepted before it is kept.
    SegmentRejected {
        /// Its sequence number.
        seq: u64,
        /// Why.
        reason: RejectReason,
        /// The offending field, if one.
        field: &'static str,
    },
    /// A control was refused.
    ControlRejected {
        /// The command's wire value.
        command: u32,
        /// Why.
        reason: RejectReason,
    },
    /// A joint state was refused (wrong joint count, non-finite value).
    JointStateRejected {
        /// Its sequence number.
        seq: u64,
        /// Why.
        reason: RejectReason,
    },
    /// A tracking sample was refused (invalid or out of order).
    BasePoseRejected {
        /// Its sequence number.
        seq: u64,
    },
    /// The run state changed.
    StateChanged {
        /// Before.
        from: RunState,
        /// After.
        to: RunState,
    },
    /// A fault latched.
    Fault {
        /// Which.
        code: FaultCode,
        /// The segment executing when it latched (0 before the path started).
        seq: u64,
        /// Its source line (0 if none).
        line: u32,
        /// The figure that tripped it: the TCP error (m) for `TcpErrorLimit`, else 0.
        value: f64,
    },
    /// A job ended.
    JobEnded {
        /// How.
        outcome: JobOutcome,
        /// The last segment executed.
        last_seq: u64,
    },
    /// The final stage clamped a joint command for the first time in a run of clamped ticks.
    Clamped {
        /// The joint (chain order).
        joint: u8,
    },
}

/// Diagnostic values of a tick that are not on the wire but belong in the log.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TickDiagnostics {
    /// Where the path wants the TCP (m, W).
    pub tcp_target_world: Vector3<f64>,
    /// Tool orientation the path wants (W).
    pub tcp_target_orientation: UnitQuaternion<f64>,
    /// Where the commanded joints put the TCP, through the estimated base pose (m, W).
    pub tcp_command_world: Vector3<f64>,
    /// Estimated base pose and twist used this tick (for the command time).
    pub base: BaseState,
    /// The CLIK's common speed scale (1 = unconstrained).
    pub clik_scale: f64,
    /// The speed scale the CLIK puts on the path for the next tick (1 = the path runs at its
    /// planned speed; below 1 a joint limit slows it).
    pub path_scale: f64,
    /// Smallest task singular value.
    pub sigma_min: f64,
    /// Path speed (m/s).
    pub path_speed: f64,
    /// Cartesian following error this tick (m): the larger of |target − TCP(commanded joints)| and,
    /// with a fresh joint state, |target − TCP(measured joints)|, in W; 0 while no path runs.
    pub tcp_error: f64,
}

/// Everything one tick decided.
#[derive(Clone, Copy, Debug)]
pub struct TickOutput {
    /// For the robot driver.
    pub joint_command: ipc::JointCommand,
    /// For the extruder driver.
    pub extruder: ipc::ExtruderCommand,
    /// For feeders and HMIs.
    pub status: ipc::Status,
    /// Events of this tick (`event_count` used).
    pub events: [Event; MAX_EVENTS],
    /// Events used.
    pub event_count: u32,
    /// Events that did not fit.
    pub events_dropped: u32,
    /// For the log.
    pub diagnostics: TickDiagnostics,
}

impl Default for TickOutput {
    fn default() -> Self {
        TickOutput {
            joint_command: ipc::JointCommand::default(),
            extruder: ipc::ExtruderCommand::default(),
            status: ipc::Status::default(),
            events: [Event::Clamped { joint: 0 }; MAX_EVENTS],
            event_count: 0,
            events_dropped: 0,
            diagnostics: TickDiagnostics::default(),
        }
    }
}

impl TickOutput {
    /// The events used.
    pub fn events(&self) -> &[Event] {
        &self.events[..self.event_count as usize]
    }

    /// Adds an event (counted as dropped when the tick has no room left).
    pub fn push(&mut self, e: Event) {
        let n = self.event_count as usize;
        if n < MAX_EVENTS {
            self.events[n] = e;
            self.event_count += 1;
        } else {
            self.events_dropped += 1;
        }
    }
}

/// Why the controller could not be built.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ControllerError(pub String);

/// The parts of the service config the controller uses.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerSettings {
    /// `[controller]`.
    pub controller: ControllerConfig,
    /// `[clik]`.
    pub clik: ClikConfig,
    /// `[path]`.
    pub path: PathConfig,
    /// `[extruder]`.
    pub extruder: ExtruderConfig,
    /// `[base]`.
    pub base: BaseConfig,
}

/// The approach move to a job's first point.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Approach {
    /// Solving the inverse kinematics of the first point, a few iterations per tick.
    Solving { iterations: u32 },
    /// Following the joint-space trajectory.
    Moving,
}

/// IK iterations per tick while solving for the first point, and in total before giving up.
const IK_ITERATIONS_PER_TICK: u32 = 25;
const IK_ITERATIONS_MAX: u32 = 4000;
/// Joint speed below which a braking arm counts as stopped (rad/s or m/s).
const AT_REST: f64 = 1e-9;

/// The controller. See the module documentation.
pub struct Controller {
    model: RobotModel,
    cfg: ControllerConfig,
    dt: f64,
    dt_ns: u64,
    engine: PathEngine,
    extruder: Extruder,
    clik: Clik,
    ik: Clik,
    base: BaseEstimator,
    approach_otg: Ruckig<0, IgnoreErrorHandler>,
    approach_in: InputParameter<0>,
    approach_out: OutputParameter<0>,
    approach: Approach,
    /// First point of the job (W) and its orientation, and the joints that reach it.
    first_point: Option<(Vector3<f64>, UnitQuaternion<f64>)>,
    q_first: JointVector,

    state: RunState,
    fault: FaultCode,
    outcome: JobOutcome,
    /// A controlled stop that ends in this fault (tracking lost).
    fault_after_stop: FaultCode,
    job_open: bool,
    /// The stop in progress brakes the joints (it interrupted an approach) instead of the path.
    stop_by_brake: bool,
    /// The approach trajectory reached its end this tick.
    approach_done: bool,
    /// Running, but holding the first point until the CLIK has the tool on it.
    settling: bool,
    /// The approach's IK target (B), fixed when the approach starts.
    approach_target: TcpTarget,
    /// State changes of the tick being computed (reported as events).
    transitions: [(RunState, RunState); 8],
    transition_count: u32,

    // Joint command state.
    known: bool,
    q: JointVector,
    qd: JointVector,
    qdd: JointVector,
    q_measured: JointVector,
    last_state_ns: Option<u64>,
    last_state_seq: u64,
    last_state_stamp: u64,
    speed_scale: f64,
    was_clamped: bool,

    // Intake.
    expected_seq: Option<u64>,
    last_received_seq: u64,
    last_rejected_seq: u64,
    last_reject_reason: RejectReason,
    rejected: u64,
    accepted: u64,
    clamps: u64,
    flow_override: f64,
    last_sample: Option<PathSample>,
    last_clik: Option<ClikStep>,
    out_seq: u64,
    /// The path's progress measure when it last changed, and when (ns): the stall watchdog.
    progress_mark: (f64, f64),
    progress_ns: Option<u64>,
    /// The Cartesian following-error watchdog.
    following: FollowingWatch,
}

impl Controller {
    /// A controller for `model`, idle, not yet knowing where the robot is (it learns from the first
    /// joint state). All memory is allocated here.
    pub fn new(settings: &ControllerSettings, model: RobotModel) -> Result<Self, ControllerError> {
        let e = |m: String| ControllerError(m);
        settings.controller.validate().map_err(e)?;
        settings.base.validate().map_err(e)?;
        let dt = settings.controller.dt();
        let engine = PathEngine::new(&settings.path, dt, Vector3::zeros(), UnitQuaternion::identity())
            .map_err(|err| ControllerError(format!("[path] {err}")))?;
        let extruder = Extruder::new(&settings.extruder, dt).map_err(|m| ControllerError(format!("[extruder] {m}")))?;
        let clik = Clik::new(settings.clik).map_err(|err| ControllerError(format!("[clik] {err}")))?;
        let ik = clik.clone();
        let n = model.dof();
        let mut approach_in = InputParameter::new(Some(n));
        approach_in.synchronization = Synchronization::Time;
        let f = settings.controller.approach_speed_fraction;
        for i in 0..n {
            let l = model.limits(i);
            approach_in.max_velocity[i] = l.velocity * f;
            approach_in.max_acceleration[i] = l.acceleration * f;
            approach_in.max_jerk[i] = l.jerk * f;
        }
        Ok(Controller {
            cfg: settings.controller.clone(),
            dt,
            dt_ns: (dt * 1e9).round() as u64,
            engine,
            extruder,
            clik,
            ik,
            base: BaseEstimator::new(&settings.base),
            approach_otg: Ruckig::new(Some(n), dt),
            approach_in,
            approach_out: OutputParameter::new(Some(n)),
            approach: Approach::Moving,
            first_point: None,
            q_first: JointVector::zeros(),
            state: RunState::Idle,
            fault: FaultCode::None,
            outcome: JobOutcome::None,
            fault_after_stop: FaultCode::None,
            job_open: false,
            stop_by_brake: false,
            approach_done: false,
            settling: false,
            approach_target: TcpTarget::at_rest(Vector3::zeros(), UnitQuaternion::identity()),
            transitions: [(RunState::Idle, RunState::Idle); 8],
            transition_count: 0,
            known: false,
            q: model.middle_configuration(),
            qd: JointVector::zeros(),
            qdd: JointVector::zeros(),
            q_measured: JointVector::zeros(),
            last_state_ns: None,
            last_state_seq: 0,
            last_state_stamp: 0,
            speed_scale: 1.0,
            was_clamped: false,
            expected_seq: None,
            last_received_seq: 0,
            last_rejected_seq: 0,
            last_reject_reason: RejectReason::None,
            rejected: 0,
            accepted: 0,
            clamps: 0,
            flow_override: 1.0,
            last_sample: None,
            last_clik: None,
            out_seq: 0,
            progress_mark: (0.0, 0.0),
            progress_ns: None,
            following: FollowingWatch::new(
                settings.controller.tcp_error_limit,
                settings.controller.tcp_error_time,
                settings.controller.tcp_error_lag,
            ),
            model,
        })
    }

    /// The robot.
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// The run state.
    pub fn run_state(&self) -> RunState {
        self.state
    }

    /// The latched fault.
    pub fn fault(&self) -> FaultCode {
        self.fault
    }

    /// The path engine (for its counters).
    pub fn engine(&self) -> &PathEngine {
        &self.engine
    }

    /// The last joint command (rad or m).
    pub fn joint_command(&self) -> &JointVector {
        &self.q
    }

    /// One control tick.
    pub fn step(&mut self, input: &TickInput) -> TickOutput {
        let mut out = TickOutput {
            joint_command: ipc::JointCommand::default(),
            extruder: ipc::ExtruderCommand::default(),
            status: ipc::Status::default(),
            events: [Event::Clamped { joint: 0 }; MAX_EVENTS],
            event_count: 0,
            events_dropped: 0,
            diagnostics: TickDiagnostics {
                tcp_target_world: Vector3::zeros(),
                tcp_target_orientation: UnitQuaternion::identity(),
                tcp_command_world: Vector3::zeros(),
                base: self.base.at(input.time_ns),
                clik_scale: 1.0,
                path_scale: 1.0,
                sigma_min: 0.0,
                path_speed: 0.0,
                tcp_error: 0.0,
            },
        };
        self.transition_count = 0;
        self.take_joint_state(input, &mut out);
        for p in input.base_poses() {
            if self.base.update(input.time_ns, p.stamp_ns, p.position, p.orientation).is_err() {
                out.push(Event::BasePoseRejected { seq: p.seq });
            }
        }
        // Segments first: a job and its Start may arrive in the same tick.
        for s in input.segments() {
            self.take_segment(s, input.time_ns, &mut out);
        }
        for c in input.controls() {
            self.take_control(c, input.time_ns, &mut out);
        }
        if input.feeder_lost
            && self.job_open
            && matches!(self.state, RunState::Approaching | RunState::Running | RunState::Pausing | RunState::Paused)
        {
            self.begin_stop(FaultCode::None);
        }
        self.supervise(input.time_ns, &mut out);

        // The command takes effect at the next tick: targets and the base pose are for then.
        let t_cmd = input.time_ns + self.dt_ns;
        let base = self.base.at(t_cmd);
        out.diagnostics.base = base;
        let q_des = self.motion(&base, &mut out);
        self.final_stage(&q_des, &mut out);
        self.after_motion(input.time_ns, &mut out);

        let (p_cmd_b, q_cmd_b) = {
            let f = self.model.forward_kinematics(&self.q);
            (f.translation.vector, UnitQuaternion::from_rotation_matrix(&f.rotation))
        };
        out.diagnostics.tcp_command_world = base.base_to_world(&p_cmd_b, &q_cmd_b).0;
        self.watch_tcp_error(input, &base, &mut out);
        self.fill_outputs(input, &mut out);
        for k in 0..self.transition_count as usize {
            let (from, to) = self.transitions[k];
            out.push(Event::StateChanged { from, to });
        }
        out
    }

    fn set_state(&mut self, to: RunState) {
        if to != self.state {
            let n = self.transition_count as usize;
            if n < self.transitions.len() {
                self.transitions[n] = (self.state, to);
                self.transition_count += 1;
            }
            self.state = to;
        }
    }

    fn latch_fault(&mut self, code: FaultCode, out: &mut TickOutput) {
        self.latch_fault_with(code, 0.0, out);
    }

    fn latch_fault_with(&mut self, code: FaultCode, value: f64, out: &mut TickOutput) {
        if self.fault == FaultCode::None {
            self.fault = code;
            let (seq, line) = self.last_sample.map_or((0, 0), |s| (s.seq, s.source_line));
            out.push(Event::Fault { code, seq, line, value });
        }
        if self.job_open {
            self.end_job(JobOutcome::Faulted, out);
        }
        self.set_state(if self.is_moving() { RunState::EmergencyStopping } else { RunState::Fault });
        if self.state == RunState::Fault {
            self.hold_still();
        }
    }

    fn is_moving(&self) -> bool {
        self.qd.iter().take(self.model.dof()).any(|v| v.abs() > AT_REST)
    }

    fn hold_still(&mut self) {
        self.qd = JointVector::zeros();
        self.qdd = JointVector::zeros();
    }

    fn reject(&mut self, seq: Option<u64>, reason: RejectReason) {
        self.rejected += 1;
        self.last_reject_reason = reason;
        if let Some(seq) = seq {
            self.last_rejected_seq = seq;
        }
    }

    fn take_joint_state(&mut self, input: &TickInput, out: &mut TickOutput) {
        let Some(js) = input.joint_state else { return };
        let n = self.model.dof();
        if js.dof as usize != n {
            self.reject(None, RejectReason::WrongDof);
            out.push(Event::JointStateRejected { seq: js.seq, reason: RejectReason::WrongDof });
            return;
        }
        let Some(q) = self.model.joint_vector(&js.position[..n]) else {
            self.reject(None, RejectReason::NonFinite);
            out.push(Event::JointStateRejected { seq: js.seq, reason: RejectReason::NonFinite });
            return;
        };
        self.q_measured = q;
        self.last_state_ns = Some(input.time_ns);
        self.last_state_seq = js.seq;
        self.last_state_stamp = js.stamp_ns;
        if !self.known {
            // The first state tells where the robot is: command exactly that, at rest.
            self.known = true;
            self.q = q;
            self.hold_still();
            self.clik.reset(JointVector::zeros());
        }
    }

    fn take_control(&mut self, c: &ipc::Control, now_ns: u64, out: &mut TickOutput) {
        let result = match Command::from_u32(c.command) {
            Some(command) => self.apply_control(command, c.value, now_ns, out),
            None => Err(RejectReason::UnknownKind),
        };
        if let Err(reason) = result {
            self.reject(None, reason);
            out.push(Event::ControlRejected { command: c.command, reason });
        }
    }

    fn apply_control(&mut self, command: Command, value: f64, now_ns: u64, out: &mut TickOutput) -> Result<(), RejectReason> {
        match command {
            Command::Start => {
                if self.state != RunState::Idle {
                    return Err(RejectReason::NotAllowed);
                }
                if !self.known {
                    return Err(RejectReason::NotReady);
                }
                self.start_job(now_ns);
            }
            Command::Pause => match self.state {
                RunState::Running => {
                    self.engine.set_hold(true);
                    self.set_state(RunState::Pausing);
                }
                RunState::Pausing | RunState::Paused => {}
                _ => return Err(RejectReason::NotAllowed),
            },
            Command::Resume => match self.state {
                RunState::Pausing | RunState::Paused => {
                    self.engine.set_hold(false);
                    self.set_state(RunState::Running);
                }
                RunState::Running => {}
                _ => return Err(RejectReason::NotAllowed),
            },
            Command::Stop => match self.state {
                RunState::Running | RunState::Pausing | RunState::Paused | RunState::Approaching => self.begin_stop(FaultCode::None),
                RunState::Idle => {
                    // Nothing moving: drop whatever was queued for the next job.
                    if self.job_open {
                        let (p, q) = self.tool_world(now_ns);
                        self.engine.reset_at(p, q);
                        self.end_job(JobOutcome::Stopped, out);
                    }
                }
                RunState::Stopping => {}
                _ => return Err(RejectReason::NotAllowed),
            },
            Command::EmergencyStop => {
                if self.state != RunState::Fault && self.state != RunState::EmergencyStopping {
                    self.latch_fault(FaultCode::EmergencyStop, out);
                    if self.state != RunState::Fault {
                        self.set_state(RunState::EmergencyStopping);
                    }
                }
            }
            Command::ClearFault => {
                if self.state != RunState::Fault {
                    return Err(RejectReason::NotAllowed);
                }
                self.fault = FaultCode::None;
                self.fault_after_stop = FaultCode::None;
                let (p, q) = self.tool_world(now_ns);
                self.engine.reset_at(p, q);
                self.job_open = false;
                self.expected_seq = None;
                self.set_state(RunState::Idle);
            }
            Command::FeedOverride => {
                if !(value.is_finite() && (0.01..=2.0).contains(&value)) {
                    return Err(RejectReason::BadValue);
                }
                self.engine.set_feed_override(value);
            }
            Command::FlowOverride => {
                if !(value.is_finite() && (0.0..=2.0).contains(&value)) {
                    return Err(RejectReason::BadValue);
                }
                self.flow_override = value;
            }
        }
        Ok(())
    }

    /// The TCP of the current command in W (through the base estimate at `now_ns`).
    fn tool_world(&self, now_ns: u64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let f = self.model.forward_kinematics(&self.q);
        let base = self.base.at(now_ns);
        base.base_to_world(&f.translation.vector, &UnitQuaternion::from_rotation_matrix(&f.rotation))
    }

    fn take_segment(&mut self, w: &ipc::Segment, now_ns: u64, out: &mut TickOutput) {
        if let Err((reason, field)) = self.accept_segment(w, now_ns) {
            self.reject(Some(w.seq), reason);
            out.push(Event::SegmentRejected { seq: w.seq, reason, field });
        }
    }

    fn accept_segment(&mut self, w: &ipc::Segment, now_ns: u64) -> Result<(), (RejectReason, &'static str)> {
        let seq = w.seq;
        if matches!(self.state, RunState::Fault | RunState::EmergencyStopping | RunState::Stopping) {
            return Err((RejectReason::NotReady, ""));
        }
        if let Some(expected) = self.expected_seq
            && seq != expected
        {
            return Err((RejectReason::SequenceGap, "seq"));
        }
        let mut segment = self.validate_segment(w)?;
        if self.engine.free_space() == 0 {
            return Err((RejectReason::QueueFull, ""));
        }
        if !self.job_open {
            // A new job. Its first point: `approach_lift` above the end of a leading non-extruding
            // line, back along the nozzle (tool z points at the substrate). The joint-space approach
            // goes there, and the line itself, now from there to its end, brings the tool straight
            // down on the path: a joint-space move sags between its ends, next to a bed a crash.
            // Without a leading travel the job starts where the tool is.
            let first = if segment.kind == SegmentKind::Line && !segment.extrudes() && segment.filament == 0.0 {
                let there = self.known && {
                    let (p, q) = self.tool_world(now_ns);
                    (p - segment.end).norm() <= self.cfg.approach_position_tolerance
                        && (q * Vector3::z()).angle(&(segment.orientation * Vector3::z())) <= self.cfg.approach_orientation_tolerance
                };
                // Already there (a job following another at the same point): no approach at all.
                let lift = if there { 0.0 } else { self.cfg.approach_lift };
                (segment.end - (segment.orientation * Vector3::z()) * lift, segment.orientation)
            } else if self.known {
                self.tool_world(now_ns)
            } else {
                return Err((RejectReason::NotReady, ""));
            };
            self.engine.reset_at(first.0, first.1);
            self.first_point = Some(first);
            // A job may open with a standstill (a slicer's first retraction, `G10`, a `G4`): it
            // stands wherever the tool is, whatever point the program had in mind.
            if segment.kind == SegmentKind::Dwell {
                segment.end = first.0;
            }
        }
        match self.engine.push(&segment) {
            Ok(()) => {
                self.job_open = true;
                self.accepted += 1;
                self.expected_seq = Some(seq.wrapping_add(1));
                self.last_received_seq = seq;
                if self.state == RunState::Idle {
                    self.outcome = JobOutcome::InProgress;
                }
                Ok(())
            }
            Err(SegmentError::QueueFull { .. }) => Err((RejectReason::QueueFull, "")),
            Err(SegmentError::Invalid { field, .. }) => Err((RejectReason::BadGeometry, field)),
        }
    }

    /// Wire segment → core segment: the segment's own check ([`Segment::try_from`]) and the
    /// workspace bounds, which only the controller knows.
    fn validate_segment(&self, w: &ipc::Segment) -> Result<Segment, (RejectReason, &'static str)> {
        let segment = Segment::try_from(w).map_err(|e| (e.reject, e.field))?;
        let inside = |p: &[f64; 3]| (0..3).all(|i| p[i] >= self.cfg.bounds_min[i] && p[i] <= self.cfg.bounds_max[i]);
        if segment.kind != SegmentKind::Dwell && !inside(&w.end) {
            return Err((RejectReason::OutOfBounds, "end"));
        }
        Ok(segment)
    }

    fn start_job(&mut self, now_ns: u64) {
        if !self.job_open {
            // Nothing queued yet: the job starts where the tool is and waits for segments.
            let (p, q) = self.tool_world(now_ns);
            self.engine.reset_at(p, q);
            self.first_point = Some((p, q));
        }
        self.job_open = true;
        self.outcome = JobOutcome::InProgress;
        self.last_sample = None;
        self.engine.set_hold(false);
        let (p, q) = self.tool_world(now_ns + self.dt_ns);
        let (first_p, first_q) = self.first_point.unwrap_or((p, q));
        let nozzle_angle = (q * Vector3::z()).angle(&(first_q * Vector3::z()));
        if (p - first_p).norm() <= self.cfg.approach_position_tolerance && nozzle_angle <= self.cfg.approach_orientation_tolerance {
            self.enter_running();
        } else {
            self.ik.reset(JointVector::zeros());
            self.q_first = self.q;
            self.approach = Approach::Solving { iterations: 0 };
            self.set_state(RunState::Approaching);
        }
    }

    fn enter_running(&mut self) {
        self.clik.reset(self.qd);
        self.speed_scale = 1.0;
        // The path starts once the CLIK holds the tool on the first point (on a moving base it has
        // moved since the approach was planned).
        self.settling = true;
        self.set_state(RunState::Running);
    }

    fn begin_stop(&mut self, then: FaultCode) {
        self.fault_after_stop = then;
        // An approach is a joint-space move with no path under it: brake the joints instead.
        self.stop_by_brake = self.state == RunState::Approaching;
        self.engine.set_hold(true);
        self.set_state(RunState::Stopping);
    }

    fn end_job(&mut self, outcome: JobOutcome, out: &mut TickOutput) {
        self.outcome = outcome;
        self.job_open = false;
        self.expected_seq = None;
        let last_seq = self.last_sample.map_or(0, |s| s.seq);
        out.push(Event::JobEnded { outcome, last_seq });
    }

    /// Timeouts and following error.
    fn supervise(&mut self, now_ns: u64, out: &mut TickOutput) {
        if self.state == RunState::Fault || self.state == RunState::EmergencyStopping {
            return;
        }
        if self.cfg.joint_state_timeout > 0.0
            && let Some(t) = self.last_state_ns
            && now_ns.saturating_sub(t) as f64 * 1e-9 > self.cfg.joint_state_timeout
        {
            return self.latch_fault(FaultCode::JointStateLost, out);
        }
        if self.cfg.following_error_limit > 0.0 && self.known && self.last_state_ns == Some(now_ns) {
            let n = self.model.dof();
            let worst = (0..n).map(|i| (self.q_measured[i] - self.q[i]).abs()).fold(0.0, f64::max);
            if worst > self.cfg.following_error_limit {
                return self.latch_fault(FaultCode::RobotDeviation, out);
            }
        }
        let in_motion = matches!(self.state, RunState::Approaching | RunState::Running | RunState::Pausing | RunState::Paused);
        if self.base.is_tracked() && in_motion && self.base.age(now_ns) > self.base.timeout() {
            if self.state == RunState::Approaching {
                return self.latch_fault(FaultCode::TrackingLost, out);
            }
            self.begin_stop(FaultCode::TrackingLost);
        }
    }

    /// The joint positions this tick wants, before the final stage.
    fn motion(&mut self, base: &BaseState, out: &mut TickOutput) -> JointVector {
        if !self.known {
            return self.q;
        }
        match self.state {
            RunState::Idle | RunState::Fault => self.q,
            RunState::EmergencyStopping => self.brake(),
            RunState::Stopping if self.stop_by_brake => self.brake(),
            RunState::Approaching => self.approach_step(base, out),
            RunState::Running if self.settling => {
                let (p, q) = self.first_point.unwrap_or_else(|| self.tool_world(0));
                let step = self.clik.step(&self.model, &self.q, &base.world_to_base(&TcpTarget::at_rest(p, q)), self.dt);
                if step.position_error <= self.cfg.approach_position_tolerance
                    && step.orientation_error <= self.cfg.approach_orientation_tolerance
                {
                    self.settling = false;
                }
                let d = &mut out.diagnostics;
                d.tcp_target_world = p;
                d.tcp_target_orientation = q;
                d.clik_scale = step.scale;
                d.sigma_min = step.sigma_min;
                self.last_clik = Some(step);
                step.q
            }
            RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping => {
                let sample = self.engine.step(self.speed_scale);
                let target_w = TcpTarget {
                    position: sample.position,
                    orientation: sample.orientation,
                    linear_velocity: sample.velocity,
                    angular_velocity: sample.angular_velocity,
                };
                // Only the path's own velocity slows the path: what the base's motion or the feedback
                // costs is not cured by a slower path (slowing for it would stall the job).
                let r_bw = base.orientation.inverse();
                let path_b = PathVelocity { linear: r_bw * sample.velocity, angular: r_bw * sample.angular_velocity };
                let step = self.clik.step_on_path(&self.model, &self.q, &base.world_to_base(&target_w), &path_b, self.dt);
                self.speed_scale = step.path_scale;
                let d = &mut out.diagnostics;
                d.path_scale = step.path_scale;
                d.tcp_target_world = sample.position;
                d.tcp_target_orientation = sample.orientation;
                d.clik_scale = step.scale;
                d.sigma_min = step.sigma_min;
                d.path_speed = sample.speed;
                self.last_sample = Some(sample);
                self.last_clik = Some(step);
                step.q
            }
        }
    }

    /// Joint brake: every joint slows at its acceleration limit or less, all by one common factor
    /// (the direction of motion is kept, so the tool leaves the path as little as braking allows).
    fn brake(&self) -> JointVector {
        let n = self.model.dof();
        let mut factor: f64 = 1.0;
        for i in 0..n {
            let v = self.qd[i].abs();
            if v > 0.0 {
                factor = factor.min((1.0 - self.model.limits(i).acceleration * self.dt / v).max(0.0));
            }
        }
        let mut q = self.q;
        for i in 0..n {
            q[i] += self.qd[i] * factor * self.dt;
        }
        q
    }

    fn approach_step(&mut self, base: &BaseState, out: &mut TickOutput) -> JointVector {
        let n = self.model.dof();
        if let Approach::Solving { iterations } = self.approach {
            let Some((p, q)) = self.first_point else {
                self.enter_running();
                return self.q;
            };
            if iterations == 0 {
                // The IK target is fixed when the approach starts; if the base moves meanwhile, the
                // CLIK takes up the difference when the path starts.
                let b = base.world_to_base(&TcpTarget::at_rest(p, q));
                self.approach_target = TcpTarget::at_rest(b.position, b.orientation);
            }
            let target = self.approach_target;
            let mut done = false;
            let mut k = iterations;
            while k < iterations + IK_ITERATIONS_PER_TICK {
                // A virtual tick of 0.1 s: each iteration is a Newton step within the joint limits.
                let r = self.ik.step(&self.model, &self.q_first, &target, 0.1);
                self.q_first = r.q;
                k += 1;
                if r.position_error < 1e-7 && r.orientation_error < 1e-6 {
                    done = true;
                    break;
                }
            }
            if !done {
                if k >= IK_ITERATIONS_MAX {
                    self.latch_fault(FaultCode::ApproachFailed, out);
                } else {
                    self.approach = Approach::Solving { iterations: k };
                }
                return self.q;
            }
            for i in 0..n {
                self.approach_in.current_position[i] = self.q[i];
                self.approach_in.current_velocity[i] = self.qd[i];
                self.approach_in.current_acceleration[i] = self.qdd[i];
                self.approach_in.target_position[i] = self.q_first[i];
                self.approach_in.target_velocity[i] = 0.0;
                self.approach_in.target_acceleration[i] = 0.0;
            }
            self.approach = Approach::Moving;
        }
        match self.approach_otg.update(&self.approach_in, &mut self.approach_out) {
            Ok(RuckigResult::Working) => {
                let mut q = self.q;
                for i in 0..n {
                    q[i] = self.approach_out.new_position[i];
                }
                self.approach_out.pass_to_input(&mut self.approach_in);
                q
            }
            Ok(RuckigResult::Finished) => {
                let mut q = self.q;
                for i in 0..n {
                    q[i] = self.approach_out.new_position[i];
                }
                self.approach_done = true;
                q
            }
            _ => {
                self.latch_fault(FaultCode::ApproachFailed, out);
                self.q
            }
        }
    }

    /// Enforces every joint's position, velocity and acceleration limits on the command, counts
    /// clamps, and turns a non-finite command into a fault with a brake from the last good one.
    fn final_stage(&mut self, q_des: &JointVector, out: &mut TickOutput) {
        let n = self.model.dof();
        let mut q_des = *q_des;
        if !q_des.iter().take(n).all(|x| x.is_finite()) {
            self.latch_fault(FaultCode::NonFinite, out);
            q_des = self.brake();
        }
        let dt = self.dt;
        let mut clamped = None;
        for i in 0..n {
            let l = self.model.limits(i);
            let dv = l.acceleration * dt;
            let (mut lo, mut hi) = ((-l.velocity).max(self.qd[i] - dv), l.velocity.min(self.qd[i] + dv));
            if lo > hi {
                // Faster than the limit already (cannot happen from our own commands): slow down
                // at the acceleration limit.
                let v = if self.qd[i] > 0.0 { self.qd[i] - dv } else { self.qd[i] + dv };
                (lo, hi) = (v, v);
            }
            let tol = 1e-9 * (1.0 + l.velocity);
            let mut v = (q_des[i] - self.q[i]) / dt;
            if v < lo - tol || v > hi + tol {
                clamped.get_or_insert(i);
            }
            v = v.max(lo).min(hi);
            let mut qn = self.q[i] + v * dt;
            // Never further out than the limit (or than where it is, if it starts outside).
            let (q_lo, q_hi) = (l.lower.min(self.q[i]), l.upper.max(self.q[i]));
            if qn > q_hi + 1e-12 || qn < q_lo - 1e-12 {
                clamped.get_or_insert(i);
            }
            qn = qn.max(q_lo).min(q_hi);
            v = (qn - self.q[i]) / dt;
            self.qdd[i] = (v - self.qd[i]) / dt;
            self.qd[i] = v;
            self.q[i] = qn;
        }
        match clamped {
            Some(joint) => {
                self.clamps += 1;
                if !self.was_clamped {
                    out.push(Event::Clamped { joint: joint as u8 });
                }
                self.was_clamped = true;
            }
            None => self.was_clamped = false,
        }
    }

    /// State changes that follow from this tick's motion.
    fn after_motion(&mut self, now_ns: u64, out: &mut TickOutput) {
        if self.watch_progress(now_ns) {
            return self.latch_fault(FaultCode::PathStalled, out);
        }
        if self.state == RunState::Approaching && self.approach_done {
            self.approach_done = false;
            self.enter_running();
            return;
        }
        let motion = self.last_sample.map(|s| s.motion);
        match self.state {
            RunState::Running if motion == Some(Motion::Finished) => {
                self.finish_job(JobOutcome::Finished, out);
            }
            RunState::Pausing if motion == Some(Motion::Held) => self.set_state(RunState::Paused),
            RunState::Stopping => {
                let at_rest = if self.stop_by_brake { !self.is_moving() } else { self.engine.is_held() && motion == Some(Motion::Held) };
                let path_done = motion
                    .is_some_and(|m| matches!(m, Motion::Finished | Motion::Idle | Motion::Starved) && self.engine.path_motion().0 == 0.0);
                if at_rest || (!self.stop_by_brake && path_done) {
                    self.stop_by_brake = false;
                    let then = self.fault_after_stop;
                    self.finish_job(if then == FaultCode::None { JobOutcome::Stopped } else { JobOutcome::Faulted }, out);
                    if then != FaultCode::None {
                        self.latch_fault(then, out);
                    }
                }
            }
            RunState::EmergencyStopping if !self.is_moving() => {
                self.hold_still();
                self.set_state(RunState::Fault);
            }
            _ => {}
        }
    }

    /// The progress watchdog: true when the path has had work to do, no hold, and made no
    /// progress (path position or dwell clock) for `[path] stall_timeout`. The clock restarts
    /// whenever the path advances, waits for segments (an underrun is the feeder's business,
    /// reported as such), or holds by request.
    fn watch_progress(&mut self, now_ns: u64) -> bool {
        let timeout = self.engine.config().stall_timeout;
        let running =
            matches!(self.state, RunState::Running | RunState::Pausing | RunState::Stopping) && !self.settling && !self.stop_by_brake;
        let progress = self.engine.progress();
        // `has_work` walks the window, so it is asked only on a tick without progress.
        let stalled = running && progress == self.progress_mark && !self.engine.is_held() && self.engine.has_work();
        let Some(since) = self.progress_ns.filter(|_| stalled) else {
            // Waiting, moving on, or the first look: the clock starts now.
            self.progress_mark = progress;
            self.progress_ns = Some(now_ns);
            return false;
        };
        timeout > 0.0 && now_ns.saturating_sub(since) as f64 * 1e-9 > timeout
    }

    /// The Cartesian following-error watchdog (`core::following`), after this tick's command:
    /// while the path runs, the commanded TCP against the path target and (with a joint state fresh
    /// this tick) the measured TCP against the recent path, both through the estimated base pose.
    /// A trip latches `TcpErrorLimit` in the same tick, so this tick's extruder command is already off.
    fn watch_tcp_error(&mut self, input: &TickInput, base: &BaseState, out: &mut TickOutput) {
        let following = matches!(self.state, RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping)
            && !self.settling
            && !self.stop_by_brake
            && self.last_sample.is_some();
        if !following {
            self.following.reset();
            return;
        }
        let measured = (self.last_state_ns == Some(input.time_ns)).then(|| {
            let f = self.model.forward_kinematics(&self.q_measured);
            base.base_to_world(&f.translation.vector, &UnitQuaternion::from_rotation_matrix(&f.rotation)).0
        });
        let d = &out.diagnostics;
        let (error, trips) = self.following.observe(input.time_ns, &d.tcp_target_world, &d.tcp_command_world, measured.as_ref());
        out.diagnostics.tcp_error = error;
        if trips {
            self.latch_fault_with(FaultCode::TcpErrorLimit, error, out);
        }
    }

    /// Ends the job at rest and readies the engine for the next one, where the tool is.
    fn finish_job(&mut self, outcome: JobOutcome, out: &mut TickOutput) {
        let (p, q) = match self.last_sample {
            Some(s) => (s.position, s.orientation),
            None => (self.first_point.map_or(Vector3::zeros(), |f| f.0), UnitQuaternion::identity()),
        };
        self.engine.reset_at(p, q);
        self.end_job(outcome, out);
        self.set_state(RunState::Idle);
    }

    fn extruder_command(&mut self) -> super::extrude::ExtruderCommand {
        match self.state {
            RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping if !self.stop_by_brake => {
                let mut s = self.last_sample.unwrap_or_else(|| rest_sample());
                s.flow *= self.flow_override;
                s.dwell_filament_rate *= self.flow_override;
                self.extruder.step(&s)
            }
            RunState::EmergencyStopping | RunState::Fault => {
                // Extrusion off at once: no retraction, nothing pushed.
                super::extrude::ExtruderCommand { position: self.extruder.position(), ..Default::default() }
            }
            _ => self.extruder.step(&rest_sample()),
        }
    }

    fn fill_outputs(&mut self, input: &TickInput, out: &mut TickOutput) {
        let n = self.model.dof();
        self.out_seq += 1;
        let seq = self.out_seq;
        let jc = &mut out.joint_command;
        jc.seq = seq;
        jc.stamp_ns = input.time_ns;
        jc.tick = input.tick;
        jc.state_seq = self.last_state_seq;
        jc.state_stamp_ns = self.last_state_stamp;
        jc.dof = n as u32;
        jc.valid = self.known as u32;
        for i in 0..n.min(MAX_JOINTS) {
            jc.position[i] = self.q[i];
            jc.velocity[i] = self.qd[i];
            jc.acceleration[i] = self.qdd[i];
        }
        let e = self.extruder_command();
        let finite = [e.motor_speed, e.filament_rate, e.position, e.volumetric_rate].iter().all(|x| x.is_finite());
        out.extruder = ipc::ExtruderCommand {
            seq,
            stamp_ns: input.time_ns,
            tick: input.tick,
            motor_speed: if finite { e.motor_speed } else { 0.0 },
            filament_rate: if finite { e.filament_rate } else { 0.0 },
            filament_position: if finite { e.position } else { 0.0 },
            volumetric_rate: if finite { e.volumetric_rate } else { 0.0 },
            flags: (if e.filament_rate > 0.0 && finite { ipc::extruder_flags::EXTRUDING } else { 0 })
                | (if e.retracted { ipc::extruder_flags::RETRACTED } else { 0 }),
            _reserved: 0,
        };
        let stats = self.engine.stats();
        let sample = self.last_sample;
        out.status = ipc::Status {
            seq,
            stamp_ns: input.time_ns,
            tick: input.tick,
            contract_version: ipc::CONTRACT_VERSION,
            run_state: self.state as u32,
            fault: self.fault as u32,
            job_outcome: self.outcome as u32,
            last_reject_reason: self.last_reject_reason as u32,
            queue_capacity: self.engine.config().queue_capacity as u32,
            queue_free: self.engine.free_space() as u32,
            executing_line: sample.map_or(0, |s| s.source_line),
            last_received_seq: self.last_received_seq,
            last_rejected_seq: self.last_rejected_seq,
            executing_seq: sample.map_or(0, |s| s.seq),
            segments_accepted: self.accepted,
            rejected: self.rejected,
            underruns: stats.underruns,
            overruns: input.cycle.overruns,
            late_wakeups: input.cycle.late_wakeups,
            worst_lateness_ns: input.cycle.worst_lateness_ns,
            clamps: self.clamps,
            log_drops: input.cycle.log_drops,
            log_state: input.cycle.log_state,
            _reserved: 0,
            feed_override: self.engine.feed_override(),
            flow_override: self.flow_override,
            path_position: sample.map_or(0.0, |s| s.s),
            path_speed: sample.map_or(0.0, |s| s.speed),
            tcp_error: self.last_clik.map_or(0.0, |c| c.position_error),
        };
    }
}

/// A path sample of a tool at rest, extruding nothing (what the extruder sees outside a job).
fn rest_sample() -> PathSample {
    PathSample {
        position: Vector3::zeros(),
        velocity: Vector3::zeros(),
        acceleration: Vector3::zeros(),
        orientation: UnitQuaternion::identity(),
        angular_velocity: Vector3::zeros(),
        s: 0.0,
        speed: 0.0,
        path_acceleration: 0.0,
        path_jerk: 0.0,
        seq: 0,
        source_line: 0,
        flags: SegmentFlags::default(),
        flow: 0.0,
        dwell_filament_rate: 0.0,
        pressure_advance: None,
        motion: Motion::Idle,
    }
}

#[cfg(test)]
mod tests {
    //! The stall watchdog end to end: a path engine frozen mid-job (as a planner bug would leave
    //! it) becomes a `PathStalled` fault naming the segment and line, the extruder stops, and the
    //! arm brakes within its limits. (That it never fires on dwells, underruns and pauses is in
    //! tests/controller.rs.)
    use super::*;
    use crate::kin::Frame;
    use nalgebra::{Rotation3, Translation3};

    const START: [f64; 7] = [0.0, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0];
    const DOWN: [f64; 4] = [0.0, 0.0, 1.0, 0.0];

    fn segment(seq: u64, end: [f64; 3], filament: f64, last: bool) -> ipc::Segment {
        let mut flags = if filament > 0.0 { ipc::segment_flags::EXTRUDE } else { ipc::segment_flags::TRAVEL };
        if last {
            flags |= ipc::segment_flags::LAST;
        }
        ipc::Segment {
            seq,
            kind: ipc::SegmentKind::Line as u32,
            flags,
            end,
            orientation: DOWN,
            feed: 0.02,
            filament,
            source_line: seq as u32 * 10,
            ..Default::default()
        }
    }

    #[test]
    fn a_frozen_path_faults_as_path_stalled_and_the_arm_brakes() {
        // The default settings (config/default.toml's values) on the iiwa7 with its 10 cm tool and
        // the dynamic limits of config/robots/iiwa7.toml.
        let settings = ControllerSettings {
            controller: ControllerConfig::default(),
            clik: ClikConfig::default(),
            path: PathConfig::default(),
            extruder: ExtruderConfig::default(),
            base: BaseConfig::default(),
        };
        let timeout = settings.path.stall_timeout;
        assert_eq!(timeout, 0.5);
        let urdf = include_str!("../../config/robots/iiwa7.urdf");
        let model = RobotModel::from_urdf_str(urdf, "iiwa7.urdf", "world", "iiwa_link_ee")
            .unwrap()
            .with_tool(Frame::from_parts(Translation3::new(0.0, 0.0, 0.10), Rotation3::identity()))
            .unwrap()
            .with_dynamic_limits(
                &[8.0, 8.0, 8.0, 10.0, 12.0, 15.0, 15.0],
                &[80.0, 80.0, 80.0, 100.0, 120.0, 150.0, 150.0],
                ("acceleration", "jerk"),
            )
            .unwrap();
        let dof = model.dof();
        let limits: Vec<_> = (0..dof).map(|i| model.limits(i).clone()).collect();
        let mut ctl = Controller::new(&settings, model).unwrap();
        let dt_ns = (settings.controller.dt() * 1e9).round() as u64;
        let mut q = [0.0; 8];
        q[..7].copy_from_slice(&START);
        let job = [
            segment(1, [0.45, -0.02, 0.2], 0.0, false),
            segment(2, [0.55, -0.02, 0.2], 3e-3, false),
            segment(3, [0.55, 0.08, 0.2], 3e-3, true),
        ];
        let tick = std::cell::Cell::new(0u64);
        let mut step = |ctl: &mut Controller, segments: &[ipc::Segment], start: bool| {
            let t = tick.get();
            let now = 1_000_000_000 + t * dt_ns;
            let mut input = TickInput::new(t, now);
            input.joint_state = Some(ipc::JointState { seq: t + 1, stamp_ns: now, dof: dof as u32, position: q, ..Default::default() });
            for s in segments {
                input.push_segment(s);
            }
            if start {
                input.push_control(&ipc::Control { seq: 1, stamp_ns: now, command: Command::Start as u32, value: 0.0, _reserved: 0 });
            }
            let out = ctl.step(&input);
            if out.joint_command.valid == 1 {
                q = out.joint_command.position;
            }
            tick.set(t + 1);
            out
        };
        step(&mut ctl, &job, true);
        // Run until the tool is well into the second (extruding) segment.
        let mut out = step(&mut ctl, &[], false);
        for _ in 0..60_000 {
            if ctl.last_sample.is_some_and(|s| s.seq == 2 && s.speed > 0.019) {
                break;
            }
            out = step(&mut ctl, &[], false);
        }
        assert_eq!(ctl.run_state(), RunState::Running);
        assert!(out.extruder.filament_rate > 0.0);
        ctl.engine.freeze_for_test();
        let frozen_at = tick.get();
        let mut fault = None;
        let mut previous_speed = f64::INFINITY;
        for _ in 0..2_000 {
            let out = step(&mut ctl, &[], false);
            for e in out.events() {
                if let Event::Fault { code, seq, line, .. } = *e {
                    fault = Some((tick.get(), code, seq, line));
                }
            }
            let jc = &out.joint_command;
            for i in 0..dof {
                assert!(jc.position[i].is_finite() && jc.velocity[i].abs() <= limits[i].velocity * (1.0 + 1e-9));
                assert!(jc.acceleration[i].abs() <= limits[i].acceleration * (1.0 + 1e-6) + 1e-6, "joint {i} brakes too hard");
            }
            if fault.is_some() {
                // From the fault on: no filament, and the joints only slow down.
                assert_eq!(out.extruder.filament_rate, 0.0, "extrusion stops at the fault");
                let speed = (0..dof).map(|i| jc.velocity[i].abs()).fold(0.0, f64::max);
                assert!(speed <= previous_speed + 1e-12, "the arm brakes: {speed} after {previous_speed}");
                previous_speed = speed;
                if ctl.run_state() == RunState::Fault {
                    break;
                }
            }
        }
        let (at, code, seq, line) = fault.expect("the watchdog fired");
        assert_eq!(code, FaultCode::PathStalled);
        assert_eq!((seq, line), (2, 20), "the fault names the segment and its source line");
        let waited = (at - frozen_at) as f64 * settings.controller.dt();
        assert!(waited > timeout && waited < timeout + 0.01, "fired after {waited} s");
        assert_eq!(ctl.run_state(), RunState::Fault);
        assert_eq!(ctl.outcome, JobOutcome::Faulted);
    }
}
