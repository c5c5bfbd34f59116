//! The tick's types: what goes into [`Controller::step`](super::Controller::step) ([`TickInput`]),
//! what comes out ([`TickOutput`], its [`Event`]s and [`TickDiagnostics`]), and the settings a
//! controller is built from ([`ControllerSettings`], [`ControllerConfig`]).

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use strand_wire as ipc;
use strand_wire::{FaultCode, JobOutcome, RejectReason, RunState};

use crate::base::{BaseConfig, BaseState};
use crate::extrude::ExtruderConfig;
use crate::kin::{ClikConfig, InvalidClikConfig};
use crate::path::{BedMesh, InvalidPathConfig, PathConfig};
use crate::setting::InvalidSetting;

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
    /// commanded joints (and, with a joint state fresh this tick, of the measured joints), in W
    /// (in a cell with external axes: on the part, each TCP brought back by its own axes).
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
    /// `strand-feed --resume-layer`: how far above everything printed before the layer (m) the tool
    /// travels to the layer's start before it goes straight down onto it.
    pub resume_clearance: f64,
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
            resume_clearance: 0.01,
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
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let k = "[controller]";
        if !(self.rate_hz.is_finite() && (100.0..=8000.0).contains(&self.rate_hz)) {
            return Err(InvalidSetting::new("controller", format!("{k} rate_hz = {}: must lie in [100, 8000] Hz", self.rate_hz)));
        }
        for (key, v, hi) in [
            ("joint_state_timeout", self.joint_state_timeout, 10.0),
            ("following_error_limit", self.following_error_limit, 10.0),
            ("tcp_error_limit", self.tcp_error_limit, 1.0),
            ("tcp_error_time", self.tcp_error_time, 10.0),
            ("tcp_error_lag", self.tcp_error_lag, 1.0),
            ("approach_position_tolerance", self.approach_position_tolerance, 0.1),
            ("approach_lift", self.approach_lift, 0.2),
            ("resume_clearance", self.resume_clearance, 0.5),
            ("approach_orientation_tolerance", self.approach_orientation_tolerance, 1.0),
        ] {
            if !(v.is_finite() && (0.0..=hi).contains(&v)) {
                return Err(InvalidSetting::new("controller", format!("{k} {key} = {v}: must lie in [0, {hi}]")));
            }
        }
        if !(self.approach_speed_fraction > 0.0 && self.approach_speed_fraction <= 1.0) {
            return Err(InvalidSetting::new(
                "controller",
                format!("{k} approach_speed_fraction = {}: must lie in (0, 1]", self.approach_speed_fraction),
            ));
        }
        for i in 0..3 {
            if !(self.bounds_min[i].is_finite() && self.bounds_max[i].is_finite() && self.bounds_min[i] < self.bounds_max[i]) {
                return Err(InvalidSetting::new(
                    "controller",
                    format!("{k} bounds_min/bounds_max: axis {i} must be finite with min < max"),
                ));
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
    /// The latest heater measurement, if one arrived since the last tick (`[extruder] heater =
    /// "wire"`: from strand-sim's thermal model or a board's process).
    pub heater_state: Option<ipc::HeaterState>,
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
            heater_state: None,
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
        self.heater_state = None;
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
    /// A heat wait was passed without waiting: the service has no temperature source
    /// (`[extruder] heater = "none"`).
    HeatWaitSkipped {
        /// The wait's segment.
        seq: u64,
    },
    /// A heater measurement was refused (a temperature not finite or outside −60…1000 °C: an
    /// open or shorted thermistor); it goes stale (`TemperatureLost` when one is needed).
    HeaterStateRejected {
        /// Its sequence number.
        seq: u64,
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
    /// For a moving base's controller (`valid` 0 without a `[base] plan`).
    pub base_command: ipc::BaseCommand,
    /// For the heaters' owner (strand-sim's thermal model, a board's process).
    pub heater: ipc::HeaterCommand,
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
            base_command: ipc::BaseCommand::default(),
            heater: ipc::HeaterCommand::default(),
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

/// Why the controller could not be built: which section of its settings, and why.
#[derive(Debug, thiserror::Error)]
pub enum ControllerError {
    /// A `[controller]` or `[base]` value is out of range.
    #[error("{0}")]
    Setting(#[from] InvalidSetting),
    /// A `[path]` value is out of range.
    #[error("[path] {0}")]
    Path(#[from] InvalidPathConfig),
    /// A `[clik]` value is out of range.
    #[error("[clik] {0}")]
    Clik(#[from] InvalidClikConfig),
    /// An `[extruder]` value is out of range (the message names the key).
    #[error("{0}")]
    Extruder(InvalidSetting),
}

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
    /// `[bed.mesh]` on the bed it was probed on: the path follows the bed's measured surface.
    pub bed_mesh: Option<BedMesh>,
}
