//! Job check (`strand check-job`): a whole job run through the real [`Controller::step`] in virtual
//! time, before anything moves. The approach from the start posture is included and the commands
//! are fed back as the joint state (a robot that follows exactly), so what the check sees is what
//! the controller will do with this job on this robot — the same code, the same config, the same
//! ticks — only without the clock. Nothing here is an estimate of the controller's behaviour.
//!
//! Per tick it watches the Cartesian following error (path target against the TCP of the commanded
//! joints), the joint margins to their position limits, the CLIK's speed scale (where the path is
//! slowed, and what that costs), the smallest singular value of the task Jacobian, and the height of
//! the nozzle and of every joint frame above the bed plane. Consecutive ticks with the same finding
//! become one [`Problem`] with the segment and source-line range, the time and the worst figure.
//!
//! The controller runs with the `TcpErrorLimit` fault switched off, so a job that leaves its path
//! twice is reported twice; a stretch above `tcp_error_limit` that lasts `tcp_error_time` is marked
//! as the fault the run would latch. Any other fault (approach failed, stalled path) ends the check
//! as it would end the run.

/// Drawn only with the `plots` feature (on by default): the operator's tools that never draw
/// (strand-feed) build without plotters.
#[cfg(feature = "plots")]
pub mod plot;

/// No font to draw text with: plotters needs a TrueType file. Outside `plot` so that the tools'
/// error type names it in a build without plots.
#[derive(Clone, Debug, thiserror::Error)]
#[error("no TrueType font found (tried {tried}); install fonts-dejavu-core or set STRAND_PLOT_FONT")]
pub struct NoFont {
    /// The files tried, comma-separated.
    pub tried: String,
}

use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;
use strand_ipc as ipc;
use strand_ipc::{Command, FaultCode, JobOutcome, RunState};

use crate::config::Config;
use strand_core::BaseMode;
use strand_core::kin::{JointVector, MAX_JOINTS};
use strand_core::{Event, HeaterSource, MAX_SEGMENTS_PER_TICK, ThermalModel, TickInput};
use strand_job::bed::BedTransform;
use strand_job::load::BaseTrajectory;
use strand_job::timing::MAX_SEGMENT_SECONDS;

pub use crate::config::check::CheckConfig;

/// What a finding is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ProblemKind {
    /// The TCP of the commanded joints is further from the path target than `tcp_error_limit`:
    /// the target is out of reach (or a limit or singularity keeps the arm off it).
    Unreachable,
    /// A joint at its position limit (error) or within `[check] joint_margin` of it (warning).
    JointLimit,
    /// The CLIK slowed the path (speed scale < 1) to keep the joints within their limits.
    Slowdown,
    /// The smallest singular value of the task Jacobian is below `[clik] sigma_threshold`.
    NearSingular,
    /// The nozzle or a joint frame is below the bed plane plus `[check] bed_clearance`.
    BelowBed,
    /// The final stage had to clamp a joint command to its velocity or acceleration limit.
    Clamped,
    /// The controller latched a fault (or would: `TcpErrorLimit`).
    Fault,
    /// The job did not end within the tick bound.
    DidNotFinish,
}

/// How bad a finding is: an error makes the job fail the check (exit 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Severity {
    /// The job would fault, leave its path or hit a limit.
    Error,
    /// Worth knowing (time lost, a margin used up); the job runs.
    Warning,
}

/// One finding over a stretch of the job.
#[derive(Clone, Debug, Serialize)]
pub struct Problem {
    /// What.
    pub kind: ProblemKind,
    /// Error or warning.
    pub severity: Severity,
    /// The joint (chain order), for joint findings.
    pub joint: Option<usize>,
    /// The frame (a joint's name, or "tcp"), for bed findings.
    pub frame: Option<String>,
    /// The fault code, for faults.
    pub fault: Option<String>,
    /// First and last segment (seq) of the stretch.
    pub seqs: [u64; 2],
    /// First and last source line (0 where no segment was executing, e.g. the approach).
    pub lines: [u32; 2],
    /// Start and end (s from Start).
    pub time_s: [f64; 2],
    /// The worst figure over the stretch, in `unit`.
    pub worst: f64,
    /// Unit of `worst`: "m", "rad" (or "m" for a prismatic joint), "1" for a scale or singular value.
    pub unit: &'static str,
    /// Time the stretch costs against the unscaled path (s); slowdowns only.
    pub cost_s: f64,
    /// One line for a human, with the figures.
    pub message: String,
}

/// Time spent in one slicer layer (s).
#[derive(Clone, Debug, Serialize)]
pub struct LayerTime {
    /// The layer (None: segments without a layer tag, e.g. the start code).
    pub layer: Option<i32>,
    /// Seconds with its segments executing.
    pub seconds: f64,
}

/// Predicted times (s), from the tick counts.
#[derive(Clone, Debug, Default, Serialize)]
pub struct JobTime {
    /// From Start to the end of the job (approach included): what the run will take.
    pub total_s: f64,
    /// The move to the first point (approach and settling).
    pub approach_s: f64,
    /// The path, from its first tick to its end.
    pub path_s: f64,
    /// Time lost to CLIK slow-downs (Σ dt·(1 − scale) while slowed).
    pub slowdown_s: f64,
    /// Time the job holds at heat waits (`M109`, `M190`, `TEMPERATURE_WAIT`), predicted with the
    /// config's `[thermal]` plant from ambient (with `[extruder] heater = "wire"`; 0 otherwise:
    /// the waits are skipped, `heat_waits_skipped` counts them). Part of `path_s` and `total_s`.
    pub heat_s: f64,
    /// Heat waits the service will skip (`[extruder] heater = "none"`).
    pub heat_waits_skipped: u64,
    /// Per layer, in order of first appearance.
    pub layers: Vec<LayerTime>,
}

/// An axis-aligned box (m).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Bounds {
    /// Lower corner.
    pub min: [f64; 3],
    /// Upper corner.
    pub max: [f64; 3],
}

impl Bounds {
    fn empty() -> Self {
        Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] }
    }
    fn add(&mut self, p: &Vector3<f64>) {
        for i in 0..3 {
            self.min[i] = self.min[i].min(p[i]);
            self.max[i] = self.max[i].max(p[i]);
        }
    }
}

/// The smallest margin of any joint to its position limits over the job.
#[derive(Clone, Debug, Serialize)]
pub struct JointMargin {
    /// The joint (chain order).
    pub joint: usize,
    /// Its name in the URDF.
    pub name: String,
    /// Distance to the nearer limit (rad or m).
    pub margin: f64,
    /// Segment and source line executing then (0 during the approach).
    pub seq: u64,
    /// Source line.
    pub line: u32,
}

/// Everything `strand check-job` reports.
#[derive(Clone, Debug, Serialize)]
pub struct CheckReport {
    /// The job file.
    pub file: String,
    /// The config file.
    pub config: String,
    /// The robot's name.
    pub robot: String,
    /// Tick rate (Hz).
    pub rate_hz: f64,
    /// How the base was taken: fixed mount, a still tracked base (assumed), or a planned trajectory.
    pub base: String,
    /// The room the heaters start from (°C, `[thermal] ambient`).
    pub ambient: f64,
    /// True when no finding is an error (exit 0).
    pub clean: bool,
    /// How the job ended in the check: Finished, Faulted, Stopped, or DidNotFinish.
    pub outcome: String,
    /// Findings, in time order.
    pub problems: Vec<Problem>,
    /// Findings left out past the first [`MAX_PROBLEMS`].
    pub problems_omitted: usize,
    /// Predicted times.
    pub time: JobTime,
    /// Segments in the job.
    pub segments: usize,
    /// Filament pushed over the job (m).
    pub filament_m: f64,
    /// Where the path goes, in W (path targets).
    pub bbox_world: Bounds,
    /// Where the TCP goes, in the robot's base frame B (commanded joints).
    pub bbox_base: Bounds,
    /// The smallest joint margin.
    pub min_joint_margin: Option<JointMargin>,
    /// The largest Cartesian following error on the path (m).
    pub max_tcp_error_m: f64,
    /// With a `[base] plan`: the base setpoint's largest lag behind its plan at the print's
    /// progress (m), what the base's own speed and acceleration limits cost.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_base_lag_m: Option<f64>,
    /// Joint frames below the bed plane already at the start posture (a pedestal lower than the
    /// bed): not checked against the bed.
    pub unchecked_frames: Vec<String>,
    /// `[bed.mesh]` in one line (grid, extent, heights, fade), if the config has one: the path
    /// follows that surface, and the bed clearance is measured from it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bed_mesh: Option<String>,
    /// Ticks simulated.
    pub ticks: u64,
}

/// Findings kept in a report; more are counted in `problems_omitted`.
pub(crate) const MAX_PROBLEMS: usize = 500;

/// Series for `--png` (decimated to at most about [`SERIES_POINTS`] points).
#[derive(Clone, Debug, Default)]
pub struct CheckSeries {
    /// Time (s from Start).
    pub t: Vec<f64>,
    /// Joint positions (rad or m), one vector per joint.
    pub q: Vec<Vec<f64>>,
    /// Cartesian following error (m).
    pub tcp_error: Vec<f64>,
}

/// Points a series keeps.
pub(crate) const SERIES_POINTS: usize = 4000;

/// The job to check: wire segments in W (numbered, the last flagged LAST) and their layers.
pub struct CheckJob<'a> {
    /// The job file, for the report.
    pub file: &'a str,
    /// The segments as strand-feed would send them.
    pub segments: &'a [ipc::Segment],
    /// Slicer layer of each segment.
    pub layers: &'a [Option<i32>],
}

/// Why a check could not run.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// The controller could not be built from the config.
    #[error("{0}")]
    Controller(String),
    /// The planned base trajectory cannot be read.
    #[error(transparent)]
    Trajectory(#[from] strand_job::JobError),
    /// The job has no segment.
    #[error("{0}: the job has no segments")]
    Empty(String),
    /// A segment that would take longer than [`MAX_SEGMENT_SECONDS`]: a typo, not a job.
    #[error("{file}:{line}: segment {seq} would take {seconds:.3e} s (more than {MAX_SEGMENT_SECONDS} s): check its feed and end point")]
    Absurd {
        /// The job file.
        file: String,
        /// Its source line.
        line: u32,
        /// Its number.
        seq: u64,
        /// How long it would take (s).
        seconds: f64,
    },
}

/// A stretch being grown.
struct Open {
    problem: Problem,
    last_tick: u64,
}

/// Collects findings into stretches.
struct Findings {
    open: Vec<Open>,
    done: Vec<Problem>,
    omitted: usize,
    merge_ticks: u64,
    min_slowdown_cost: f64,
}

/// Where the tick is on the job.
#[derive(Clone, Copy)]
struct At {
    tick: u64,
    t: f64,
    seq: u64,
    line: u32,
}

impl Findings {
    fn note(
        &mut self,
        kind: ProblemKind,
        severity: Severity,
        key: (Option<usize>, Option<&str>),
        at: At,
        figure: f64,
        worse: fn(f64, f64) -> bool,
    ) {
        let matches = |o: &Open| o.problem.kind == kind && o.problem.joint == key.0 && o.problem.frame.as_deref() == key.1;
        if let Some(k) = self.open.iter().position(matches) {
            let o = &mut self.open[k];
            if at.tick <= o.last_tick + self.merge_ticks {
                let p = &mut o.problem;
                o.last_tick = at.tick;
                p.time_s[1] = at.t;
                if at.seq > 0 {
                    p.seqs = [if p.seqs[0] == 0 { at.seq } else { p.seqs[0] }, at.seq];
                    p.lines = [if p.lines[0] == 0 { at.line } else { p.lines[0] }, at.line.max(p.lines[1])];
                }
                if worse(figure, p.worst) {
                    p.worst = figure;
                }
                if severity == Severity::Error {
                    p.severity = Severity::Error;
                }
                return;
            }
            let closed = self.open.swap_remove(k);
            self.close(closed.problem);
        }
        let unit = match kind {
            ProblemKind::JointLimit => "rad",
            ProblemKind::Slowdown | ProblemKind::NearSingular => "1",
            _ => "m",
        };
        let problem = Problem {
            kind,
            severity,
            joint: key.0,
            frame: key.1.map(str::to_string),
            fault: None,
            seqs: [at.seq, at.seq],
            lines: [at.line, at.line],
            time_s: [at.t, at.t],
            worst: figure,
            unit,
            cost_s: 0.0,
            message: String::new(),
        };
        self.open.push(Open { problem, last_tick: at.tick });
    }

    fn add_cost(&mut self, kind: ProblemKind, cost: f64) {
        if let Some(o) = self.open.iter_mut().find(|o| o.problem.kind == kind) {
            o.problem.cost_s += cost;
        }
    }

    /// Closes stretches that ended more than the merge gap ago.
    fn age(&mut self, tick: u64) {
        let mut k = 0;
        while k < self.open.len() {
            if tick > self.open[k].last_tick + self.merge_ticks {
                let o = self.open.swap_remove(k);
                self.close(o.problem);
            } else {
                k += 1;
            }
        }
    }

    fn close(&mut self, p: Problem) {
        if p.kind == ProblemKind::Slowdown && p.cost_s < self.min_slowdown_cost {
            return;
        }
        if self.done.len() < MAX_PROBLEMS {
            self.done.push(p);
        } else {
            self.omitted += 1;
        }
    }

    fn finish(mut self) -> (Vec<Problem>, usize) {
        for o in std::mem::take(&mut self.open) {
            self.close(o.problem);
        }
        self.done.sort_by(|a, b| a.time_s[0].total_cmp(&b.time_s[0]));
        (self.done, self.omitted)
    }
}

fn larger(a: f64, b: f64) -> bool {
    a > b
}
fn smaller(a: f64, b: f64) -> bool {
    a < b
}

/// Runs `job` through a controller built from `cfg` and reports. `trajectory` is the planned base
/// trajectory (t from Start) for a tracked base; without one a tracked base is assumed still at its
/// mount, and the report says so. With `series`, the decimated series for the plots are kept.
pub fn check_job(
    job: &CheckJob,
    cfg: &Config,
    trajectory: Option<(&BaseTrajectory, &str)>,
    mut series: Option<&mut CheckSeries>,
) -> Result<CheckReport, CheckError> {
    if job.segments.is_empty() {
        return Err(CheckError::Empty(job.file.to_string()));
    }
    let model = cfg.robot.build_model().map_err(|e| CheckError::Controller(e.to_string()))?;
    let n = model.dof();
    // The arm's joints, then a positioner's axes: the names a finding gives.
    let positioner = cfg.robot.build_positioner().map_err(|e| CheckError::Controller(e.to_string()))?;
    let joint_names: Vec<String> =
        model.joints().iter().chain(positioner.iter().flat_map(|p| p.model().joints())).map(|j| j.name.clone()).collect();
    let limits: Vec<_> = (0..n).map(|i| *model.limits(i)).collect();
    let mut settings = cfg.controller_settings();
    // Every stretch off the path is reported; the fault it would cause is marked on it.
    let tcp_limit = settings.controller.tcp_error_limit;
    let tcp_time = settings.controller.tcp_error_time;
    settings.controller.tcp_error_limit = 0.0;
    let sigma_threshold = settings.clik.sigma_threshold;
    let mut ctl = cfg.robot.build_controller(&settings).map_err(|e| CheckError::Controller(e.to_string()))?;
    let bed = BedTransform::new(&cfg.bed).map_err(|e| CheckError::Controller(e.to_string()))?;
    let bed_origin = bed.point(&Vector3::zeros());
    let bed_normal = (bed.point(&Vector3::z()) - bed_origin).normalize();
    // Height (m) of a point in W above the bed: its plane, or the measured surface on it.
    let above_bed = |w: &Vector3<f64>| (w - bed_origin).dot(&bed_normal) - bed.mesh().map_or(0.0, |m| m.height_at(w).0);
    let check = &cfg.check;

    let dt = cfg.controller.dt();
    let dt_ns = (dt * 1e9).round() as u64;
    let t0_ns: u64 = 1_000_000_000;
    let mount = cfg.base.mount();
    let mount_position = mount.translation.vector;
    let mount_orientation = UnitQuaternion::from_rotation_matrix(&mount.rotation);
    let tracked = cfg.base.mode == BaseMode::Tracked;
    // A base with a plan by progress is where the service commands it (a base that follows its
    // setpoint exactly, as the joints follow theirs); a trajectory by time is followed by the clock.
    let planned = !cfg.base.plan.is_empty();
    let base_note = match (tracked, trajectory) {
        (false, _) => "fixed mount ([base] mode = \"fixed\")".to_string(),
        (true, Some((_, name))) => format!("tracked, following the planned trajectory {name} by the clock"),
        (true, None) if planned => format!(
            "tracked, following its setpoint from the [base] plan by the print's progress ({} rows{})",
            cfg.base.plan.len(),
            if cfg.base.plan_file.is_empty() { String::new() } else { format!(", {}", cfg.base.plan_file) }
        ),
        (true, None) => "tracked, ASSUMED STILL at the mount (no --base-trajectory given)".to_string(),
    };
    let mut base_setpoint: Option<ipc::BaseCommand> = None;
    // Tracking samples every 10 ms, as a tracker would send them.
    let pose_every = ((0.01 / dt).round() as u64).max(1);

    // The arm's joints, then a positioner's axes (at home unless `initial_joints` says).
    let cell_dof = ctl.cell_dof();
    let mut q_robot = [0.0; MAX_JOINTS];
    for i in 0..cell_dof {
        q_robot[i] = cfg.service.initial_joints.get(i).copied().unwrap_or(if i < n { limits[i].middle() } else { 0.0 });
    }
    let first_seq = job.segments[0].seq;
    let layer_of = |seq: u64| -> Option<i32> { job.layers.get(seq.checked_sub(first_seq)? as usize).copied().flatten() };

    // A generous bound: every segment from rest to rest at its feed, 20 times over, plus a minute.
    let mut bound_s = 60.0;
    let mut at = Vector3::from(job.segments[0].end);
    for s in job.segments {
        let end = Vector3::from(s.end);
        let seconds = match s.kind {
            k if k == ipc::SegmentKind::Dwell as u32 => s.duration,
            // A heat wait: at most the plant's slowest heat-up (five time constants) and the settle.
            k if k == ipc::SegmentKind::Heat as u32 => {
                5.0 * cfg.thermal.hot_end.time_constant.max(cfg.thermal.bed.time_constant) + cfg.extruder.temperature_settle_time
            }
            _ => (end - at).norm().max(s.sweep.abs() * (end - Vector3::from(s.centre)).norm()) / s.feed.min(cfg.path.max_speed),
        };
        // NaN (a zero feed) is absurd too.
        if seconds.is_nan() || seconds > MAX_SEGMENT_SECONDS {
            return Err(CheckError::Absurd { file: job.file.to_string(), line: s.source_line, seq: s.seq, seconds });
        }
        bound_s += 20.0 * (seconds + 0.1);
        at = end;
    }
    let max_ticks = (bound_s / dt).min(1e10) as u64;

    let mut findings = Findings {
        open: Vec::new(),
        done: Vec::new(),
        omitted: 0,
        merge_ticks: ((check.merge_gap / dt).round() as u64).max(1),
        min_slowdown_cost: check.min_slowdown_cost,
    };
    let mut report = CheckReport {
        file: job.file.to_string(),
        config: cfg.file.display().to_string(),
        robot: model.name().to_string(),
        rate_hz: cfg.controller.rate_hz,
        base: base_note,
        ambient: cfg.thermal.ambient,
        clean: true,
        outcome: "DidNotFinish".to_string(),
        problems: Vec::new(),
        problems_omitted: 0,
        time: JobTime::default(),
        segments: job.segments.len(),
        filament_m: 0.0,
        bbox_world: Bounds::empty(),
        bbox_base: Bounds::empty(),
        min_joint_margin: None,
        max_tcp_error_m: 0.0,
        max_base_lag_m: None,
        unchecked_frames: Vec::new(),
        bed_mesh: cfg.bed.mesh.as_ref().map(|m| m.summary()),
        ticks: 0,
    };
    let frame_name = |k: usize| if k < n { joint_names[k].as_str() } else { "tcp" };
    let mut frames = [Vector3::zeros(); MAX_JOINTS + 1];
    // Frames below the bed at the start posture are the pedestal: not checked.
    let mut checked_frames = [true; MAX_JOINTS + 1];
    {
        let q = JointVector::from_fn(|i, _| if i < n { q_robot[i] } else { 0.0 });
        let count = model.frame_origins(&q, &mut frames);
        for k in 0..count - 1 {
            let w = mount_position + mount_orientation * frames[k];
            if above_bed(&w) < check.bed_clearance {
                checked_frames[k] = false;
                report.unchecked_frames.push(frame_name(k).to_string());
            }
        }
    }
    let mut series_every = 1u64;
    if let Some(s) = series.as_deref_mut() {
        s.q = vec![Vec::new(); n];
    }

    let mut next = 0usize;
    let mut last_status: Option<ipc::Status> = None;
    let mut state_seq = 0u64;
    let mut pose_seq = 0u64;
    let mut approach_ticks = 0u64;
    let mut path_ticks = 0u64;
    let mut layer_times: Vec<LayerTime> = Vec::new();
    let mut ended: Option<(u64, JobOutcome)> = None;
    let mut above_since: Option<u64> = None;
    let mut would_fault_marked = false;
    let mut tick = 0u64;
    // The heaters, as strand-sim runs them (`[thermal]`), measured at 100 Hz.
    let mut thermal = (cfg.extruder.heater == HeaterSource::Wire).then(|| ThermalModel::new(&cfg.thermal));
    let heater_every = ((0.01 / dt).round() as u64).max(1);
    let mut heat_ticks = 0u64;
    while tick < max_ticks {
        let now = t0_ns + tick * dt_ns;
        let mut input = TickInput::new(tick, now);
        if let Some(th) = &thermal
            && tick.is_multiple_of(heater_every)
        {
            input.heater_state = Some(th.state(tick / heater_every + 1, now));
        }
        state_seq += 1;
        input.joint_state =
            Some(ipc::JointState { seq: state_seq, stamp_ns: now, dof: cell_dof as u32, position: q_robot, ..Default::default() });
        if tracked && tick.is_multiple_of(pose_every) {
            let (p, q) = match (trajectory, &base_setpoint) {
                (Some((traj, _)), _) => traj.pose_at(tick as f64 * dt, &mount_position, &mount_orientation, cfg.base.mount_rpy[2]),
                (None, Some(b)) => {
                    let [w, x, y, z] = b.orientation;
                    (Vector3::from(b.position), UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)))
                }
                (None, None) => (mount_position, mount_orientation),
            };
            pose_seq += 1;
            input.push_base_pose(&ipc::BasePose { seq: pose_seq, stamp_ns: now, position: p.into(), orientation: [q.w, q.i, q.j, q.k] });
        }
        // The feeder's credit: up to last_received + queue_free.
        let credit = match last_status {
            Some(s) if s.last_received_seq > 0 => s.last_received_seq + u64::from(s.queue_free),
            Some(s) => first_seq.saturating_sub(1) + u64::from(s.queue_free),
            None => first_seq.saturating_sub(1) + cfg.path.queue_capacity as u64,
        };
        while next < job.segments.len() && (input.segment_count as usize) < MAX_SEGMENTS_PER_TICK && job.segments[next].seq <= credit {
            input.push_segment(&job.segments[next]);
            next += 1;
        }
        if tick == 0 {
            input.push_control(&ipc::Control { seq: 1, stamp_ns: now, command: Command::Start as u32, value: 0.0, _reserved: 0 });
        }
        let out = ctl.step(&input);
        if let Some(th) = thermal.as_mut() {
            th.step(out.heater.hot_end_target, out.heater.bed_target, dt);
        }
        heat_ticks += u64::from(out.status.heat_hold != 0);
        if out.joint_command.valid == 1 {
            q_robot = out.joint_command.position;
        }
        if out.base_command.valid == 1 {
            base_setpoint = Some(out.base_command);
            let lag = report.max_base_lag_m.get_or_insert(0.0);
            *lag = lag.max(out.base_command.lag);
        }
        last_status = Some(out.status);
        let status = out.status;
        let t = tick as f64 * dt;
        let seq = status.executing_seq;
        let here = At { tick, t, seq, line: status.executing_line };
        let state = RunState::from_u32(status.run_state).unwrap_or(RunState::Fault);
        // The path runs once the tool has settled on the first point (a segment executing).
        let on_path = matches!(state, RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping) && seq > 0;
        match state {
            RunState::Approaching => approach_ticks += 1,
            RunState::Running if seq == 0 => approach_ticks += 1,
            RunState::Running | RunState::Stopping | RunState::Pausing => {
                path_ticks += 1;
                let layer = layer_of(seq);
                match layer_times.iter_mut().find(|l| l.layer == layer) {
                    Some(l) => l.seconds += dt,
                    None => layer_times.push(LayerTime { layer, seconds: dt }),
                }
            }
            _ => {}
        }
        let d = out.diagnostics;
        let q = JointVector::from_fn(|i, _| if i < n { q_robot[i] } else { 0.0 });
        // Joint margins (every tick with a known state).
        for i in 0..n {
            let l = &limits[i];
            if !(l.lower.is_finite() && l.upper.is_finite()) {
                continue;
            }
            let margin = (q[i] - l.lower).min(l.upper - q[i]);
            if report.min_joint_margin.as_ref().is_none_or(|m| margin < m.margin) {
                report.min_joint_margin = Some(JointMargin { joint: i, name: joint_names[i].clone(), margin, seq, line: here.line });
            }
            if margin < check.joint_margin {
                let severity = if margin <= 1e-6 { Severity::Error } else { Severity::Warning };
                findings.note(ProblemKind::JointLimit, severity, (Some(i), None), here, margin, smaller);
            }
        }
        // Bed clearance of the nozzle and every joint frame.
        let count = model.frame_origins(&q, &mut frames);
        for k in 0..count {
            if !checked_frames[k] {
                continue;
            }
            let w = d.base.position + d.base.orientation * frames[k];
            let height = above_bed(&w);
            let clearance = if k + 1 == count { -1e-6 } else { check.bed_clearance };
            if height < clearance {
                findings.note(ProblemKind::BelowBed, Severity::Error, (None, Some(frame_name(k))), here, height, smaller);
            }
        }
        if on_path {
            report.bbox_world.add(&d.tcp_target_world);
            report.bbox_base.add(&frames[count - 1]);
            report.max_tcp_error_m = report.max_tcp_error_m.max(d.tcp_error);
            if d.tcp_error > tcp_limit && tcp_limit > 0.0 {
                let since = *above_since.get_or_insert(tick);
                let faults = (tick - since) as f64 * dt >= tcp_time;
                findings.note(ProblemKind::Unreachable, Severity::Error, (None, None), here, d.tcp_error, larger);
                if faults && !would_fault_marked {
                    would_fault_marked = true;
                    findings.close(Problem {
                        kind: ProblemKind::Fault,
                        severity: Severity::Error,
                        joint: None,
                        frame: None,
                        fault: Some(format!("{:?}", FaultCode::TcpErrorLimit)),
                        seqs: [seq, seq],
                        lines: [here.line, here.line],
                        time_s: [t, t],
                        worst: d.tcp_error,
                        unit: "m",
                        cost_s: 0.0,
                        message: String::new(),
                    });
                }
            } else {
                above_since = None;
            }
            if d.path_scale < 1.0 - 1e-9 && d.path_speed > 0.0 {
                findings.note(ProblemKind::Slowdown, Severity::Warning, (None, None), here, d.path_scale, smaller);
                findings.add_cost(ProblemKind::Slowdown, dt * (1.0 - d.path_scale));
                report.time.slowdown_s += dt * (1.0 - d.path_scale);
            }
            if d.sigma_min < sigma_threshold {
                findings.note(ProblemKind::NearSingular, Severity::Warning, (None, None), here, d.sigma_min, smaller);
            }
        }
        for e in out.events() {
            match *e {
                Event::Clamped { joint } if on_path => {
                    findings.note(ProblemKind::Clamped, Severity::Warning, (Some(joint as usize), None), here, 0.0, larger);
                }
                Event::Fault { code, seq, line, value } => {
                    findings.close(Problem {
                        kind: ProblemKind::Fault,
                        severity: Severity::Error,
                        joint: None,
                        frame: None,
                        fault: Some(format!("{code:?}")),
                        seqs: [seq, seq],
                        lines: [line, line],
                        time_s: [t, t],
                        worst: value,
                        unit: "m",
                        cost_s: 0.0,
                        message: String::new(),
                    });
                }
                Event::JobEnded { outcome, .. } => ended = Some((tick, outcome)),
                Event::HeatWaitSkipped { .. } => report.time.heat_waits_skipped += 1,
                _ => {}
            }
        }
        if let Some(s) = series.as_deref_mut()
            && tick.is_multiple_of(series_every)
        {
            s.t.push(t);
            for i in 0..n {
                s.q[i].push(q[i]);
            }
            s.tcp_error.push(if on_path { d.tcp_error } else { 0.0 });
            if s.t.len() > 2 * SERIES_POINTS {
                // Halve the series and the rate at which it grows.
                for v in std::iter::once(&mut s.t).chain(s.q.iter_mut()).chain(std::iter::once(&mut s.tcp_error)) {
                    let kept: Vec<f64> = v.iter().step_by(2).copied().collect();
                    *v = kept;
                }
                series_every *= 2;
            }
        }
        findings.age(tick);
        report.filament_m = out.extruder.filament_position;
        tick += 1;
        if let Some((_, outcome)) = ended
            && (outcome != JobOutcome::Faulted || matches!(state, RunState::Fault))
        {
            break;
        }
    }
    report.ticks = tick;
    let (mut problems, omitted) = findings.finish();
    match ended {
        Some((end_tick, outcome)) => {
            report.outcome = format!("{outcome:?}");
            report.time.total_s = (end_tick + 1) as f64 * dt;
        }
        None => {
            report.time.total_s = tick as f64 * dt;
            let at = problems.last().map_or([0, 0], |p| p.seqs);
            problems.push(Problem {
                kind: ProblemKind::DidNotFinish,
                severity: Severity::Error,
                joint: None,
                frame: None,
                fault: None,
                seqs: at,
                lines: [last_status.map_or(0, |s| s.executing_line); 2],
                time_s: [report.time.total_s; 2],
                worst: 0.0,
                unit: "m",
                cost_s: 0.0,
                message: String::new(),
            });
        }
    }
    report.time.approach_s = approach_ticks as f64 * dt;
    report.time.path_s = path_ticks as f64 * dt;
    report.time.heat_s = heat_ticks as f64 * dt;
    report.time.layers = layer_times;
    for p in &mut problems {
        p.message = describe(p, job.file, &joint_names, tcp_limit, tcp_time);
    }
    report.clean = problems.iter().all(|p| p.severity != Severity::Error) && report.outcome == "Finished";
    report.problems = problems;
    report.problems_omitted = omitted;
    Ok(report)
}

impl CheckReport {
    /// Errors among the findings.
    pub fn errors(&self) -> usize {
        self.problems.iter().filter(|p| p.severity == Severity::Error).count()
    }

    /// The report for a human: the job, time, filament, boxes, margins, every finding, the verdict.
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let mm = |b: &Bounds| {
            let axis = |i: usize| format!("{:.1}..{:.1}", b.min[i] * 1e3, b.max[i] * 1e3);
            if b.min[0].is_finite() { format!("x {} y {} z {} mm", axis(0), axis(1), axis(2)) } else { "(no path ran)".to_string() }
        };
        let _ = writeln!(s, "check-job: {} on {} ({} at {} Hz)", self.file, self.robot, self.config, self.rate_hz);
        let _ = writeln!(s, "  base       {}", self.base);
        let t = &self.time;
        let _ = writeln!(
            s,
            "  job        {} | {} segments | predicted {:.1} s (approach {:.1} s, path {:.1} s; slow-downs cost {:.2} s)",
            self.outcome, self.segments, t.total_s, t.approach_s, t.path_s, t.slowdown_s
        );
        if t.heat_s > 0.0 {
            let _ = writeln!(
                s,
                "  heat       {:.1} s holding at heat waits (predicted with [thermal] from {:.0} degC)",
                t.heat_s, self.ambient
            );
        }
        if t.heat_waits_skipped > 0 {
            let _ = writeln!(
                s,
                "  heat       WARNING: {} heat waits will be skipped: no temperature source ([extruder] heater = \"none\")",
                t.heat_waits_skipped
            );
        }
        let layered: Vec<&LayerTime> = t.layers.iter().filter(|l| l.layer.is_some()).collect();
        if !layered.is_empty() {
            let shown: Vec<String> = layered.iter().take(8).map(|l| format!("{}: {:.1} s", l.layer.unwrap_or(0), l.seconds)).collect();
            let more = if layered.len() > 8 { format!(" … ({} layers)", layered.len()) } else { String::new() };
            let _ = writeln!(s, "  layers     {}{more}", shown.join(", "));
        }
        let _ = writeln!(s, "  filament   {:.4} m", self.filament_m);
        let _ = writeln!(s, "  box W      {}", mm(&self.bbox_world));
        let _ = writeln!(s, "  box B      {}", mm(&self.bbox_base));
        if let Some(m) = &self.min_joint_margin {
            let at = if m.line > 0 { format!(" at line {}", m.line) } else { " during the approach".to_string() };
            let _ = writeln!(s, "  joints     smallest margin {:.4} (rad or m): joint {} ({}){at}", m.margin, m.joint + 1, m.name);
        }
        let _ = writeln!(s, "  TCP error  max {:.4} mm on the path", self.max_tcp_error_m * 1e3);
        if let Some(lag) = self.max_base_lag_m {
            let _ = writeln!(s, "  base       setpoint at most {:.2} mm behind its plan", lag * 1e3);
        }
        if let Some(m) = &self.bed_mesh {
            let _ = writeln!(s, "  bed mesh   {m}");
        }
        if !self.unchecked_frames.is_empty() {
            let _ = writeln!(s, "  bed        not checked (below the bed at the start posture): {}", self.unchecked_frames.join(", "));
        }
        let warnings = self.problems.len() - self.errors();
        let _ = writeln!(
            s,
            "  findings   {} errors, {} warnings{}",
            self.errors(),
            warnings,
            if self.problems_omitted > 0 { format!(" (+{} not listed)", self.problems_omitted) } else { String::new() }
        );
        for p in &self.problems {
            let _ = writeln!(s, "    {}", p.message);
        }
        let _ = write!(
            s,
            "  verdict    {}",
            if self.clean {
                "CLEAN: the job runs within every limit"
            } else {
                "FAILS: the job would fault, leave its path or hit a limit (exit 3)"
            }
        );
        s
    }
}

/// Checks `job` with the planned base trajectory read from `trajectory` (a CSV as `strand-plan
/// base --trajectory` writes it), if any: the one entry `strand check-job`, strand-feed and
/// strand-demo share. Errors (an unreadable trajectory, an absurd segment) are one line each.
pub fn check_with_trajectory(
    job: &CheckJob,
    cfg: &Config,
    trajectory: Option<&std::path::Path>,
    series: Option<&mut CheckSeries>,
) -> Result<CheckReport, CheckError> {
    let planned = match trajectory {
        Some(p) => Some((BaseTrajectory::load(p, cfg.base.mount_rpy[2])?, p.display().to_string())),
        None => None,
    };
    check_job(job, cfg, planned.as_ref().map(|(t, n)| (t, n.as_str())), series)
}

/// One line for a human: what, where (file:line range, segments), when, how bad.
fn describe(p: &Problem, file: &str, joints: &[String], tcp_limit: f64, tcp_time: f64) -> String {
    let lines = match p.lines {
        [0, 0] => "the approach".to_string(),
        [a, b] if a == b || b == 0 => format!("{file}:{a}"),
        [a, b] => format!("{file}:{a}-{b}"),
    };
    let seqs = if p.seqs[0] == p.seqs[1] { format!("segment {}", p.seqs[0]) } else { format!("segments {}-{}", p.seqs[0], p.seqs[1]) };
    let when = format!("{:.2}-{:.2} s", p.time_s[0], p.time_s[1]);
    let joint = p.joint.map_or(String::new(), |j| format!("joint {} ({})", j + 1, joints.get(j).map_or("?", |s| s.as_str())));
    let what = match p.kind {
        ProblemKind::Unreachable => {
            format!("TCP off its path by up to {:.3} mm (limit {:.3} mm): out of reach", p.worst * 1e3, tcp_limit * 1e3)
        }
        ProblemKind::JointLimit if p.severity == Severity::Error => format!("{joint} at its position limit"),
        ProblemKind::JointLimit => format!("{joint} within {:.4} of its position limit", p.worst),
        ProblemKind::Slowdown => format!("CLIK slows the path to {:.0} % (costs {:.2} s)", p.worst * 100.0, p.cost_s),
        ProblemKind::NearSingular => format!("near a singularity (smallest singular value {:.4})", p.worst),
        ProblemKind::BelowBed => format!("{} {:.1} mm from the bed plane", p.frame.as_deref().unwrap_or("?"), p.worst * 1e3),
        ProblemKind::Clamped => format!("{joint} command clamped to its velocity or acceleration limit"),
        ProblemKind::Fault if p.fault.as_deref() == Some("TcpErrorLimit") => {
            format!("the run would fault: TcpErrorLimit (TCP error {:.3} mm for {:.3} s)", p.worst * 1e3, tcp_time)
        }
        ProblemKind::Fault => format!("the run faults: {}", p.fault.as_deref().unwrap_or("?")),
        ProblemKind::DidNotFinish => "the job did not end within its tick bound".to_string(),
    };
    let severity = if p.severity == Severity::Error { "error" } else { "warning" };
    format!("{severity}: {lines} ({seqs}, {when}): {what}")
}
