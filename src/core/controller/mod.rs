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
//! A cell with a positioner (external axes that carry the part) has its axes after the arm's in
//! every joint array; the job is in the work frame at home, the path runs along it (its speed is
//! the speed over the part), its segments say where the axes are, and the CLIK follows the target
//! where the axes carry it (`positioner.rs`).
//!
//! The final command stage enforces every joint's position, velocity and acceleration limits on
//! every command, counts each clamp, and never lets a non-finite number out: a NaN anywhere is a
//! fault, and the arm brakes from its last good command.
//!
//! This file is the run-state machine and the tick; each stage with its own state has its own
//! file: `tick.rs` the tick's types, `intake.rs` sequence and refusals, `approach.rs` the move to
//! the first point, `command.rs` the final command stage.

use nalgebra::{UnitQuaternion, Vector3};
use strand_wire as ipc;
use strand_wire::{Command, FaultCode, JobOutcome, RejectReason, RunState, joint_state_flags};

use super::base::{BaseEstimator, BaseState};
use super::base_setpoint::BaseSetpoint;
use super::extrude::Extruder;
use super::following::FollowingWatch;
use super::kin::{Clik, ClikStep, Frame, JointVector, MAX_JOINTS, PathVelocity, RobotModel, TcpTarget};
use super::path::{AxisLimits, Motion, PathEngine, PathSample, SegmentError, SegmentFlags, SegmentKind, rest_sample};
use super::positioner::{Positioner, PositionerError};
use strand_wire::MAX_EXTERNAL_AXES;

mod approach;
mod command;
mod heat;
mod intake;
mod probe;
mod tick;

use approach::{Approach, ApproachStep, FirstPoint};
use command::{CellJoints, JointCommandStage};
use heat::{Heat, HeatVerdict};
use intake::Intake;
use probe::NoProbe;
pub use probe::{TickProbe, TickStage};
pub use tick::{
    ControllerConfig, ControllerError, ControllerSettings, CycleCounters, Event, MAX_BASE_POSES_PER_TICK, MAX_CONTROLS_PER_TICK,
    MAX_EVENTS, MAX_SEGMENTS_PER_TICK, TickDiagnostics, TickInput, TickOutput,
};

/// The controller. See the module documentation.
pub struct Controller {
    model: RobotModel,
    /// The cell's positioner, if it has one.
    positioner: Option<Positioner>,
    /// The joints a command carries: the arm's, then the positioner's.
    joints: CellJoints,
    cfg: ControllerConfig,
    dt: f64,
    dt_ns: u64,
    engine: PathEngine,
    extruder: Extruder,
    clik: Clik,
    base: BaseEstimator,
    /// The joint-space move to a job's first point.
    approach: Approach,
    /// First point of the job (W) and its orientation.
    first_point: Option<FirstPoint>,

    state: RunState,
    fault: FaultCode,
    outcome: JobOutcome,
    /// A controlled stop that ends in this fault (tracking lost).
    fault_after_stop: FaultCode,
    job_open: bool,
    /// The stop in progress brakes the joints (it interrupted an approach) instead of the path.
    stop_by_brake: bool,
    /// Running, but holding the first point until the CLIK has the tool on it.
    settling: bool,
    /// State changes of the tick being computed (reported as events).
    transitions: [(RunState, RunState); 8],
    transition_count: u32,

    /// The joint command and its limits.
    command: JointCommandStage,
    /// The last measured joints (rad or m).
    q_measured: JointVector,
    /// The joint target the robot holds, as its driver last gave it (rad or m), when the driver
    /// says (`JointState::robot_target`): what the following error is measured against.
    robot_target: Option<JointVector>,
    /// That target's velocity (rad/s or m/s).
    robot_target_velocity: JointVector,
    last_state_ns: Option<u64>,
    last_state_seq: u64,
    last_state_stamp: u64,
    speed_scale: f64,
    /// Sequence, acceptance and refusals of what comes in.
    intake: Intake,
    flow_override: f64,
    /// The operator's feed override (fraction; `Command::FeedOverride`).
    feed_override: f64,
    /// The robot's own speed scaling (fraction; `Command::RobotSpeedScaling`): the path runs at
    /// the feed override times it.
    robot_speed_scaling: f64,
    last_sample: Option<PathSample>,
    layer: LayerCount,
    last_clik: Option<ClikStep>,
    out_seq: u64,
    /// The path's progress measure when it last changed, and when (ns): the stall watchdog.
    progress_mark: (f64, f64),
    progress_ns: Option<u64>,
    /// The Cartesian following-error watchdog.
    following: FollowingWatch,
    /// The moving base's setpoint from `[base] plan` (None without a plan).
    base_setpoint: Option<BaseSetpoint>,
    /// The print's progress the base's plan is read at: the path position of this job past its
    /// leading travel (m).
    base_progress: f64,
    /// The length of this job's leading travel (m; 0 without one): where its progress starts.
    base_lead_in: f64,
    /// Where along the base's plan the next (or this) job starts (m): `Command::ProgressOffset`,
    /// sent for a resumed job; 0 again when that job ends.
    base_offset: f64,
    /// Temperatures: targets, waits, the cold-extrusion guard (heat.rs).
    heat: Heat,
    /// Heat segments that arrived before the job's first move (a program's `M190`/`M109` come
    /// before its first travel): the first point is that move's, so they wait here until it (or
    /// Start) opens the job, then go into the path in order.
    pre_heat: [super::path::Segment; PRE_HEAT],
    pre_heat_len: usize,
}

/// Heat segments a job may send before its first move (more open the job where the tool is).
const PRE_HEAT: usize = 16;

impl Controller {
    /// A controller for `model`, idle, not yet knowing where the robot is (it learns from the first
    /// joint state). All memory is allocated here.
    pub fn new(settings: &ControllerSettings, model: RobotModel) -> Result<Self, ControllerError> {
        settings.controller.validate()?;
        settings.base.validate()?;
        let dt = settings.controller.dt();
        let mut engine = PathEngine::new(&settings.path, dt, Vector3::zeros(), UnitQuaternion::identity())?;
        engine.set_bed_mesh(settings.bed_mesh.clone());
        let extruder = Extruder::new(&settings.extruder, dt).map_err(ControllerError::Extruder)?;
        let clik = Clik::new(settings.clik)?;
        let joints = CellJoints::new(&model, None);
        let approach = Approach::new(&joints, settings.controller.approach_speed_fraction, dt, clik.clone());
        Ok(Controller {
            positioner: None,
            joints,
            cfg: settings.controller.clone(),
            dt,
            dt_ns: (dt * 1e9).round() as u64,
            engine,
            extruder,
            clik,
            base: BaseEstimator::new(&settings.base),
            base_setpoint: BaseSetpoint::new(&settings.base, dt),
            base_progress: 0.0,
            base_lead_in: 0.0,
            base_offset: 0.0,
            heat: Heat::new(&settings.extruder),
            pre_heat: [super::path::Segment::default(); PRE_HEAT],
            pre_heat_len: 0,
            approach,
            first_point: None,
            state: RunState::Idle,
            fault: FaultCode::None,
            outcome: JobOutcome::None,
            fault_after_stop: FaultCode::None,
            job_open: false,
            stop_by_brake: false,
            settling: false,
            transitions: [(RunState::Idle, RunState::Idle); 8],
            transition_count: 0,
            command: JointCommandStage::new(model.middle_configuration()),
            q_measured: JointVector::zeros(),
            robot_target: None,
            robot_target_velocity: JointVector::zeros(),
            last_state_ns: None,
            last_state_seq: 0,
            last_state_stamp: 0,
            speed_scale: 1.0,
            intake: Intake::new(settings.controller.bounds_min, settings.controller.bounds_max),
            flow_override: 1.0,
            feed_override: 1.0,
            robot_speed_scaling: 1.0,
            last_sample: None,
            layer: LayerCount::default(),
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

    /// The same controller in a cell with `positioner` under the part: its axes follow in every
    /// joint array after the arm's, segments may say where they are, and the arm follows the work
    /// they carry (module documentation). Call before the first tick.
    pub fn with_positioner(mut self, positioner: Positioner) -> Result<Self, PositionerError> {
        let (arm, axes) = (self.model.dof(), positioner.dof());
        if arm + axes > MAX_JOINTS {
            return Err(PositionerError::TooManyJoints { arm, axes, max: MAX_JOINTS });
        }
        let limits: [AxisLimits; MAX_EXTERNAL_AXES] = std::array::from_fn(|i| {
            let l = positioner.model().limits(i.min(axes - 1));
            AxisLimits { velocity: l.velocity, acceleration: l.acceleration, jerk: l.jerk }
        });
        self.engine.set_external_axes(&limits[..axes]);
        self.joints = CellJoints::new(&self.model, Some(&positioner));
        self.approach = Approach::new(&self.joints, self.cfg.approach_speed_fraction, self.dt, self.clik.clone());
        // At home until the first joint state says where the axes are.
        for i in 0..axes {
            let l = positioner.model().limits(i);
            self.command.q[arm + i] = 0f64.clamp(l.lower, l.upper);
        }
        self.positioner = Some(positioner);
        Ok(self)
    }

    /// The cell's positioner, if any.
    pub fn positioner(&self) -> Option<&Positioner> {
        self.positioner.as_ref()
    }

    /// All the joints a command carries: the arm's and the positioner's.
    pub fn cell_dof(&self) -> usize {
        self.joints.dof()
    }

    /// Where the positioner's axes are commanded (rad or m; zeros without one).
    fn axes_command(&self) -> [f64; MAX_EXTERNAL_AXES] {
        let arm = self.joints.arm();
        std::array::from_fn(|i| if arm + i < self.joints.dof() { self.command.q[arm + i] } else { 0.0 })
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
        &self.command.q
    }

    /// One control tick.
    pub fn step(&mut self, input: &TickInput) -> TickOutput {
        self.step_probed(input, &mut NoProbe)
    }

    /// [`step`](Self::step), telling `probe` as each of its stages ends ([`TickStage`], in that
    /// order): the same tick to the bit, for a bench that times the stages.
    pub fn step_probed<P: TickProbe>(&mut self, input: &TickInput, probe: &mut P) -> TickOutput {
        // `diagnostics.base` is the base at the command's time, set below.
        let mut out = TickOutput {
            diagnostics: TickDiagnostics { clik_scale: 1.0, path_scale: 1.0, ..TickDiagnostics::default() },
            ..TickOutput::default()
        };
        self.transition_count = 0;
        self.take_joint_state(input, &mut out);
        if let Some(h) = input.heater_state
            && !self.heat.measure(&h, input.time_ns)
        {
            out.push(Event::HeaterStateRejected { seq: h.seq });
        }
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
        probe.stage_done(TickStage::Intake);
        self.supervise(input.time_ns, &mut out);
        probe.stage_done(TickStage::Supervise);

        // The command takes effect at the next tick: targets and the base pose are for then.
        let t_cmd = input.time_ns + self.dt_ns;
        let base = self.base.at(t_cmd);
        out.diagnostics.base = base;
        probe.stage_done(TickStage::BaseEstimate);
        let q_des = self.motion(&base, &mut out, probe);
        probe.stage_done(TickStage::Clik);
        self.final_stage(&q_des, &mut out);
        probe.stage_done(TickStage::CommandLimits);
        self.step_heat(input.time_ns, &mut out);
        probe.stage_done(TickStage::Heat);
        self.after_motion(input.time_ns, &mut out);
        probe.stage_done(TickStage::RunState);
        self.step_base_setpoint();
        probe.stage_done(TickStage::BaseSetpoint);

        // The command's TCP; its FK and Jacobian are the next tick's CLIK's (it starts from this
        // command), computed once for both.
        let tcp_cmd_b = self.clik.kinematics_ahead(&self.model, &self.command.q).tcp;
        out.diagnostics.tcp_command_world = base.point_to_world(&tcp_cmd_b.translation.vector);
        probe.stage_done(TickStage::CommandKinematics);
        self.watch_tcp_error(input, &base, &tcp_cmd_b, &mut out);
        probe.stage_done(TickStage::FollowingWatch);
        self.fill_outputs(input, &mut out, probe);
        for k in 0..self.transition_count as usize {
            let (from, to) = self.transitions[k];
            out.push(Event::StateChanged { from, to });
        }
        probe.stage_done(TickStage::Outputs);
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
        self.heat.fault();
        self.pre_heat_len = 0;
        if self.job_open {
            self.end_job(JobOutcome::Faulted, out);
        }
        self.set_state(if self.is_moving() { RunState::EmergencyStopping } else { RunState::Fault });
        if self.state == RunState::Fault {
            self.hold_still();
        }
    }

    fn is_moving(&self) -> bool {
        self.command.is_moving(self.joints.dof())
    }

    fn hold_still(&mut self) {
        self.command.hold_still();
    }

    fn reject(&mut self, seq: Option<u64>, reason: RejectReason) {
        self.intake.reject(seq, reason);
    }

    fn take_joint_state(&mut self, input: &TickInput, out: &mut TickOutput) {
        let Some(js) = input.joint_state else { return };
        let n = self.joints.dof();
        if js.dof as usize != n {
            self.reject(None, RejectReason::WrongDof);
            out.push(Event::JointStateRejected { seq: js.seq, reason: RejectReason::WrongDof });
            return;
        }
        let Some(q) = self.joints.vector(&js.position) else {
            self.reject(None, RejectReason::NonFinite);
            out.push(Event::JointStateRejected { seq: js.seq, reason: RejectReason::NonFinite });
            return;
        };
        self.q_measured = q;
        self.last_state_ns = Some(input.time_ns);
        self.last_state_seq = js.seq;
        self.last_state_stamp = js.stamp_ns;
        self.robot_target = None;
        if js.flags & joint_state_flags::TARGET_KNOWN != 0
            && let (Some(target), Some(velocity)) = (self.joints.vector(&js.robot_target), self.joints.vector(&js.robot_target_velocity))
        {
            self.robot_target = Some(target);
            self.robot_target_velocity = velocity;
        }
        if !self.command.known {
            // The first state tells where the robot is: command exactly that, at rest.
            self.command.known = true;
            self.command.q = q;
            self.hold_still();
            self.clik.reset(JointVector::zeros());
        } else if js.flags & joint_state_flags::HELD != 0
            && let Some(target) = self.robot_target
        {
            self.robot_held(&target);
        }
    }

    /// The driver says the robot kept its target for a cycle or more (an answer never reached
    /// it): it is at `target` (rad or m), braking or at rest, behind the command. On the approach
    /// (a joint-space move with no path under it) the trajectory is planned again from the
    /// robot's own target and its velocity, so the next command steps from there within every
    /// limit and the driver has nothing to catch up (a catch-up at approach speed would fall
    /// behind by v²/2a first: 0.2 rad on a KR 6's A5). On the path, the driver's guard catches up
    /// with the command (time-optimally, without passing it): the path keeps its time, and the
    /// tool falls behind along it for the few cycles that takes.
    fn robot_held(&mut self, target: &JointVector) {
        let velocity = self.robot_target_velocity;
        if self.state == RunState::Approaching && self.approach.restart_from(target, &velocity, self.joints.dof()) {
            self.command.q = *target;
            self.command.qd = velocity;
            self.command.qdd = JointVector::zeros();
        }
    }

    fn take_control(&mut self, c: &ipc::Control, now_ns: u64, out: &mut TickOutput) {
        let command = Command::from_u32(c.command);
        let result = match command {
            Some(command) => self.apply_control(command, c.value, now_ns, out),
            None => Err(RejectReason::UnknownKind),
        };
        if matches!(command, Some(Command::Stop | Command::EmergencyStop)) {
            // What was sent before a stop belongs to the job it ends (or to none: in Idle, in
            // fault), never to a new one.
            self.intake.stopped_at(c.stamp_ns);
        }
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
                if !self.command.known {
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
                    if self.pre_heat_len > 0 && !self.job_open {
                        self.pre_heat_len = 0;
                        self.end_job(JobOutcome::Stopped, out);
                    }
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
                self.pre_heat_len = 0;
                self.intake.restart_sequence();
                self.set_state(RunState::Idle);
            }
            Command::FeedOverride => {
                if !(value.is_finite() && (0.01..=2.0).contains(&value)) {
                    return Err(RejectReason::BadValue);
                }
                self.feed_override = value;
                self.engine.set_feed_override(value * self.robot_speed_scaling);
            }
            Command::RobotSpeedScaling => {
                if !(value.is_finite() && (0.01..=1.0).contains(&value)) {
                    return Err(RejectReason::BadValue);
                }
                self.robot_speed_scaling = value;
                self.engine.set_feed_override(self.feed_override * value);
            }
            Command::FlowOverride => {
                if !(value.is_finite() && (0.0..=2.0).contains(&value)) {
                    return Err(RejectReason::BadValue);
                }
                self.flow_override = value;
            }
            Command::ProgressOffset => {
                if self.state != RunState::Idle {
                    return Err(RejectReason::NotAllowed);
                }
                if !(value.is_finite() && (0.0..=1e6).contains(&value)) {
                    return Err(RejectReason::BadValue);
                }
                self.base_offset = value;
                self.base_progress = value;
            }
        }
        Ok(())
    }

    /// The TCP of the current command in W (through the base estimate at `now_ns`), on the work
    /// at home (where a job's points are): brought back from where the positioner's axes are.
    fn tool_world(&self, now_ns: u64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let f = self.model.forward_kinematics(&self.command.q);
        let (mut p, mut q) = (f.translation.vector, UnitQuaternion::from_rotation_matrix(&f.rotation));
        if let Some(positioner) = &self.positioner {
            (p, q) = positioner.to_home(&p, &q, &self.axes_command());
        }
        self.base.at(now_ns).base_to_world(&p, &q)
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
        let mut segment = self.intake.admit(w)?;
        if segment.kind == SegmentKind::Heat {
            if !self.heat.has_room() {
                return Err((RejectReason::QueueFull, ""));
            }
            if !self.job_open && self.pre_heat_len < PRE_HEAT {
                // Before the job's first move: kept until that move says where the job starts.
                self.pre_heat[self.pre_heat_len] = segment;
                self.pre_heat_len += 1;
                self.intake.accepted(seq);
                if self.state == RunState::Idle {
                    self.outcome = JobOutcome::InProgress;
                }
                return Ok(());
            }
        }
        if let (Some(axes), Some(positioner)) = (segment.axes, &self.positioner) {
            let model = positioner.model();
            if (0..positioner.dof()).any(|i| !(model.limits(i).lower..=model.limits(i).upper).contains(&axes[i])) {
                return Err((RejectReason::OutOfBounds, "axes"));
            }
        }
        if self.engine.free_space() == 0 {
            return Err((RejectReason::QueueFull, ""));
        }
        if !self.job_open {
            // A new job. Its first point: `approach_lift` above the end of a leading non-extruding
            // line, back along the nozzle (tool z points at the substrate). The joint-space approach
            // goes there, and the line itself, now from there to its end, brings the tool straight
            // down on the path: a joint-space move sags between its ends, next to a bed a crash.
            // Without a leading travel the job starts where the tool is.
            // The positioner's axes start where the leading travel puts them, else where they are.
            let axes_now = self.axes_command();
            let first: FirstPoint = if segment.kind == SegmentKind::Line && !segment.extrudes() && segment.filament == 0.0 {
                let axes = segment.axes.unwrap_or(axes_now);
                // Where the tool must be (W): the travel's end on the bed's measured surface.
                let end = self.engine.to_world(&segment.end);
                let there = self.command.known && axes == axes_now && {
                    let (p, q) = self.tool_world(now_ns);
                    (p - end).norm() <= self.cfg.approach_position_tolerance
                        && (q * Vector3::z()).angle(&(segment.orientation * Vector3::z())) <= self.cfg.approach_orientation_tolerance
                };
                // Already there (a job following another at the same point): no approach at all.
                let lift = if there { 0.0 } else { self.cfg.approach_lift };
                (self.engine.to_world(&(segment.end - (segment.orientation * Vector3::z()) * lift)), segment.orientation, axes)
            } else if self.command.known {
                let (p, q) = self.tool_world(now_ns);
                (p, q, axes_now)
            } else {
                return Err((RejectReason::NotReady, ""));
            };
            self.engine.reset_with_axes(first.0, first.1, first.2);
            self.flush_pre_heat(first.0);
            self.first_point = Some(first);
            // The base's plan counts progress from the end of the leading travel (what the
            // approach replaced); a new job reads it from its start again (or from
            // `Command::ProgressOffset`: a resumed job).
            self.base_lead_in = if segment.kind == SegmentKind::Line && !segment.extrudes() && segment.filament == 0.0 {
                (segment.end - self.engine.to_program(&first.0)).norm()
            } else {
                0.0
            };
            self.base_progress = self.base_offset;
            // A job may open with a standstill (a slicer's first retraction, `G10`, a `G4`): it
            // stands wherever the tool is, whatever point the program had in mind.
            if matches!(segment.kind, SegmentKind::Dwell | SegmentKind::Heat) {
                segment.end = self.engine.to_program(&first.0);
            }
        }
        match self.engine.push(&segment) {
            Ok(()) => {
                if segment.kind == SegmentKind::Heat {
                    self.heat.push(seq, segment.heat);
                }
                self.job_open = true;
                self.intake.accepted(seq);
                if self.state == RunState::Idle {
                    self.outcome = JobOutcome::InProgress;
                }
                Ok(())
            }
            Err(SegmentError::QueueFull { .. }) => Err((RejectReason::QueueFull, "")),
            Err(SegmentError::Invalid { field, .. }) => Err((RejectReason::BadGeometry, field)),
        }
    }

    fn start_job(&mut self, now_ns: u64) {
        if !self.job_open {
            self.layer = LayerCount::default();
            // Nothing queued yet: the job starts where the tool is and waits for segments.
            let (p, q) = self.tool_world(now_ns);
            let axes = self.axes_command();
            self.engine.reset_with_axes(p, q, axes);
            self.flush_pre_heat(p);
            self.first_point = Some((p, q, axes));
            // A new job reads the base's plan from its start again (or from `Command::ProgressOffset`).
            self.base_progress = self.base_offset;
            self.base_lead_in = 0.0;
        }
        self.job_open = true;
        self.outcome = JobOutcome::InProgress;
        self.last_sample = None;
        self.engine.set_hold(false);
        let (p, q) = self.tool_world(now_ns + self.dt_ns);
        let axes = self.axes_command();
        let (first_p, first_q, first_axes) = self.first_point.unwrap_or((p, q, axes));
        let nozzle_angle = (q * Vector3::z()).angle(&(first_q * Vector3::z()));
        if (p - first_p).norm() <= self.cfg.approach_position_tolerance
            && nozzle_angle <= self.cfg.approach_orientation_tolerance
            && axes == first_axes
        {
            self.enter_running();
        } else {
            self.approach.begin(&self.command.q);
            self.set_state(RunState::Approaching);
        }
    }

    /// The heat segments kept before the job's first move, into the path at `at` (m, W: the
    /// job's first point, where the tool will stand for them), in order.
    fn flush_pre_heat(&mut self, at: Vector3<f64>) {
        let at = self.engine.to_program(&at);
        for k in 0..self.pre_heat_len {
            let segment = super::path::Segment { end: at, ..self.pre_heat[k] };
            // The queue was just emptied: it has room for these few.
            if self.engine.push(&segment).is_ok() {
                self.heat.push(segment.seq, segment.heat);
            }
        }
        self.pre_heat_len = 0;
    }

    /// The heat stage after this tick's motion ([`Heat::step`]): targets the path reached, the
    /// wait, the cold-extrusion and stale-temperature guards.
    fn step_heat(&mut self, now_ns: u64, out: &mut TickOutput) {
        let on_path = matches!(self.state, RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping)
            && !self.settling
            && !self.stop_by_brake;
        let sample = if on_path { self.last_sample } else { None };
        match self.heat.step(&mut self.engine, sample.as_ref(), now_ns) {
            HeatVerdict::Fine => {}
            HeatVerdict::Skipped(seq) => out.push(Event::HeatWaitSkipped { seq }),
            HeatVerdict::Fault(code) => self.latch_fault(code, out),
        }
    }

    fn enter_running(&mut self) {
        self.clik.reset(self.command.qd);
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
        self.heat.end_job(outcome == JobOutcome::Finished);
        self.pre_heat_len = 0;
        self.outcome = outcome;
        self.job_open = false;
        self.base_offset = 0.0;
        self.intake.restart_sequence();
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
        if self.cfg.following_error_limit > 0.0 && self.command.known && self.last_state_ns == Some(now_ns) {
            let n = self.joints.dof();
            // Against what the robot was told, when its driver says: after a hold the driver's
            // answers catch up with the command, and the robot follows the answers.
            let told = self.robot_target.as_ref().unwrap_or(&self.command.q);
            let worst = (0..n).map(|i| (self.q_measured[i] - told[i]).abs()).fold(0.0, f64::max);
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

    /// The joint positions this tick wants, before the final stage. On the path, `probe` hears
    /// the path sample and the base correction end (the caller, the CLIK).
    fn motion<P: TickProbe>(&mut self, base: &BaseState, out: &mut TickOutput, probe: &mut P) -> JointVector {
        if !self.command.known {
            return self.command.q;
        }
        match self.state {
            RunState::Idle | RunState::Fault => self.command.q,
            RunState::EmergencyStopping => self.brake(),
            RunState::Stopping if self.stop_by_brake => self.brake(),
            RunState::Approaching => self.approach_step(base, out),
            RunState::Running if self.settling => {
                let (p, q, axes) = self.first_point.unwrap_or_else(|| {
                    let (p, q) = self.tool_world(0);
                    (p, q, self.axes_command())
                });
                let (axes, axes_velocity) = self.axes_within_limits(&axes);
                let mut target = base.world_to_base(&TcpTarget::at_rest(p, q));
                if let Some(positioner) = &self.positioner {
                    target = positioner.carry(&target, &axes, &axes_velocity);
                }
                let mut step = self.clik.step(&self.model, &self.command.q, &target, self.dt);
                self.place_axes(&mut step.q, &axes);
                // On a planned base, the path also waits for the base's setpoint to be at the plan's
                // start (a second job brings the base back there first).
                let progress = self.base_progress;
                let base_there =
                    self.base_setpoint.as_ref().is_none_or(|b| b.distance_to(progress) <= self.cfg.approach_position_tolerance);
                if step.position_error <= self.cfg.approach_position_tolerance
                    && step.orientation_error <= self.cfg.approach_orientation_tolerance
                    && base_there
                {
                    self.settling = false;
                }
                let d = &mut out.diagnostics;
                (d.tcp_target_world, d.tcp_target_orientation) = base.base_to_world(&target.position, &target.orientation);
                d.clik_scale = step.scale;
                d.sigma_min = step.sigma_min;
                self.last_clik = Some(step);
                step.q
            }
            RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping => {
                let sample = self.engine.step(self.speed_scale);
                probe.stage_done(TickStage::PathSample);
                let target_w = TcpTarget {
                    position: sample.position,
                    orientation: sample.orientation,
                    linear_velocity: sample.velocity,
                    angular_velocity: sample.angular_velocity,
                };
                // Only the path's own velocity slows the path: what the base's motion or the feedback
                // costs is not cured by a slower path (slowing for it would stall the job).
                let r_bw = base.orientation.inverse();
                let mut path_b = PathVelocity { linear: r_bw * sample.velocity, angular: r_bw * sample.angular_velocity };
                let mut target_b = base.world_to_base(&target_w);
                let (axes, axes_velocity) = self.axes_within_limits(&sample.axes);
                if let Some(positioner) = &self.positioner {
                    // The positioner's axes move with the path: what they add to the target's
                    // velocity is the path's too (a slower path turns them slower). The work is
                    // carried where the axes are commanded, limits kept: should one fall behind
                    // the path, the nozzle still lands on the part where the path says.
                    let path_home = TcpTarget { linear_velocity: path_b.linear, angular_velocity: path_b.angular, ..target_b };
                    let (target, path) = positioner.carry_both(&target_b, &path_home, &axes, &axes_velocity);
                    path_b = PathVelocity { linear: path.linear_velocity, angular: path.angular_velocity };
                    target_b = target;
                }
                probe.stage_done(TickStage::BaseCorrection);
                let mut step = self.clik.step_on_path(&self.model, &self.command.q, &target_b, &path_b, self.dt);
                self.place_axes(&mut step.q, &axes);
                self.speed_scale = step.path_scale;
                let d = &mut out.diagnostics;
                d.path_scale = step.path_scale;
                (d.tcp_target_world, d.tcp_target_orientation) = base.base_to_world(&target_b.position, &target_b.orientation);
                d.clik_scale = step.scale;
                d.sigma_min = step.sigma_min;
                d.path_speed = sample.speed;
                self.layer.note(&sample);
                self.last_sample = Some(sample);
                self.last_clik = Some(step);
                step.q
            }
        }
    }

    /// The base's setpoint for this tick, read from its plan at the path's progress
    /// (base_setpoint.rs): it moves only while the path does, at the path's speed.
    fn step_base_setpoint(&mut self) {
        let Some(setpoint) = self.base_setpoint.as_mut() else {
            return;
        };
        let on_path = matches!(self.state, RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping)
            && !self.settling
            && !self.stop_by_brake;
        let mut rate = 0.0;
        if on_path && let Some(sample) = self.last_sample {
            self.base_progress = self.base_offset + (sample.s - self.base_lead_in).max(0.0);
            rate = if sample.s > self.base_lead_in { sample.speed } else { 0.0 };
        }
        let brake = matches!(self.state, RunState::EmergencyStopping | RunState::Fault);
        setpoint.step(self.base_progress, rate, brake);
    }

    /// Joint brake ([`JointCommandStage::brake`]).
    fn brake(&self) -> JointVector {
        self.command.brake(&self.joints, self.dt)
    }

    /// The positioner's axes this tick on their way to `wanted` (rad or m) within their limits, as
    /// the final stage will command them ([`crate::kin::JointLimits::step`] from the command), and
    /// their velocities (rad/s or m/s).
    fn axes_within_limits(&self, wanted: &[f64; MAX_EXTERNAL_AXES]) -> ([f64; MAX_EXTERNAL_AXES], [f64; MAX_EXTERNAL_AXES]) {
        let (arm, n) = (self.joints.arm(), self.joints.dof());
        let (mut axes, mut velocity) = ([0.0; MAX_EXTERNAL_AXES], [0.0; MAX_EXTERNAL_AXES]);
        for i in 0..n - arm {
            let (q, qd) = (self.command.q[arm + i], self.command.qd[arm + i]);
            let s = self.joints.limits(arm + i).step(q, qd, (wanted[i] - q) / self.dt, self.dt);
            (axes[i], velocity[i]) = (s.position, s.velocity);
        }
        (axes, velocity)
    }

    /// Writes the positioner's axes (rad or m) after the arm's joints in `q`.
    fn place_axes(&self, q: &mut JointVector, axes: &[f64; MAX_EXTERNAL_AXES]) {
        let arm = self.joints.arm();
        for i in arm..self.joints.dof() {
            q[i] = axes[i - arm];
        }
    }

    fn approach_step(&mut self, base: &BaseState, out: &mut TickOutput) -> JointVector {
        let Some(first_point) = self.first_point else {
            self.enter_running();
            return self.command.q;
        };
        let c = &self.command;
        match self.approach.step(&self.model, &self.joints, self.positioner.as_ref(), first_point, base, (&c.q, &c.qd, &c.qdd)) {
            ApproachStep::Hold => self.command.q,
            ApproachStep::Move(q) => q,
            ApproachStep::Failed => {
                self.latch_fault(FaultCode::ApproachFailed, out);
                self.command.q
            }
        }
    }

    /// Enforces every joint's position, velocity and acceleration limits on the command
    /// ([`JointCommandStage::limit`]), reports the start of a clamp, and turns a non-finite command
    /// into a fault with a brake from the last good one.
    fn final_stage(&mut self, q_des: &JointVector, out: &mut TickOutput) {
        let n = self.joints.dof();
        let mut q_des = *q_des;
        if !q_des.iter().take(n).all(|x| x.is_finite()) {
            self.latch_fault(FaultCode::NonFinite, out);
            q_des = self.brake();
        }
        if let Some(joint) = self.command.limit(&self.joints, self.dt, &q_des) {
            out.push(Event::Clamped { joint });
        }
    }

    /// State changes that follow from this tick's motion.
    fn after_motion(&mut self, now_ns: u64, out: &mut TickOutput) {
        if self.watch_progress(now_ns) {
            return self.latch_fault(FaultCode::PathStalled, out);
        }
        if self.state == RunState::Approaching && self.approach.done {
            self.approach.done = false;
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
        // A heat wait stands still by design: its own guard is the temperature's timeout.
        let stalled = running
            && progress == self.progress_mark
            && !self.engine.is_held()
            && self.engine.waiting_at().is_none()
            && self.engine.has_work();
        let Some(since) = self.progress_ns.filter(|_| stalled) else {
            // Waiting, moving on, or the first look: the clock starts now.
            self.progress_mark = progress;
            self.progress_ns = Some(now_ns);
            return false;
        };
        timeout > 0.0 && now_ns.saturating_sub(since) as f64 * 1e-9 > timeout
    }

    /// The Cartesian following-error watchdog (`core::following`), after this tick's command (with
    /// external axes: on the part):
    /// while the path runs, the commanded TCP against the path target and (with a joint state fresh
    /// this tick) the measured TCP against the recent path, both through the estimated base pose.
    /// A trip latches `TcpErrorLimit` in the same tick, so this tick's extruder command is already off.
    fn watch_tcp_error(&mut self, input: &TickInput, base: &BaseState, tcp_cmd_b: &Frame, out: &mut TickOutput) {
        let following = matches!(self.state, RunState::Running | RunState::Pausing | RunState::Paused | RunState::Stopping)
            && !self.settling
            && !self.stop_by_brake
            && self.last_sample.is_some();
        if !following {
            self.following.reset();
            return;
        }
        // With external axes, on the part (the work frame at home): the path's own target, the
        // commanded TCP brought back by the commanded axes, the measured one by the measured
        // axes, so a table or track that falls behind its command shows as what it does to the
        // bead. Without, in W as the diagnostics have them.
        let arm = self.joints.arm();
        // The TCP (its pose `f` in B) at joints `q` on the part.
        let on_part = |f: &Frame, q: &JointVector| -> Vector3<f64> {
            let mut p = f.translation.vector;
            if let Some(positioner) = &self.positioner {
                let axes = std::array::from_fn(|i| if arm + i < self.joints.dof() { q[arm + i] } else { 0.0 });
                p = positioner.to_home(&p, &UnitQuaternion::from_rotation_matrix(&f.rotation), &axes).0;
            }
            base.point_to_world(&p)
        };
        // The measured joints' FK: the CLIK's own when they are the command it started from (a
        // simulator's or a driver's echo), else computed here.
        let measured = (self.last_state_ns == Some(input.time_ns)).then(|| {
            let f = match self.clik.kinematics_at(&self.model, &self.q_measured) {
                Some(state) => state.tcp,
                None => self.model.forward_kinematics(&self.q_measured),
            };
            on_part(&f, &self.q_measured)
        });
        let d = &out.diagnostics;
        let (target, commanded) = match (&self.positioner, self.last_sample) {
            (Some(_), Some(sample)) => (sample.position, on_part(tcp_cmd_b, &self.command.q)),
            _ => (d.tcp_target_world, d.tcp_command_world),
        };
        let (error, trips) = self.following.observe(input.time_ns, &target, &commanded, measured.as_ref());
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
                let mut s = self.last_sample.unwrap_or_else(rest_sample);
                s.flow *= self.flow_override;
                s.dwell_filament_rate *= self.flow_override;
                self.extruder.step(&s)
            }
            RunState::EmergencyStopping | RunState::Fault => {
                // Extrusion off at once: no retraction, nothing pushed, nothing left on its way.
                self.extruder.halt();
                super::extrude::ExtruderCommand { position: self.extruder.position(), ..Default::default() }
            }
            _ => self.extruder.step(&rest_sample()),
        }
    }

    /// The tick's outputs; `probe` hears the joint command's part of them and the extrusion end.
    fn fill_outputs<P: TickProbe>(&mut self, input: &TickInput, out: &mut TickOutput, probe: &mut P) {
        let n = self.joints.dof();
        self.out_seq += 1;
        let seq = self.out_seq;
        let jc = &mut out.joint_command;
        jc.seq = seq;
        jc.stamp_ns = input.time_ns;
        jc.tick = input.tick;
        jc.state_seq = self.last_state_seq;
        jc.state_stamp_ns = self.last_state_stamp;
        jc.dof = n as u32;
        jc.valid = self.command.known as u32;
        for i in 0..n.min(MAX_JOINTS) {
            jc.position[i] = self.command.q[i];
            jc.velocity[i] = self.command.qd[i];
            jc.acceleration[i] = self.command.qdd[i];
        }
        probe.stage_done(TickStage::Outputs);
        let mut e = self.extruder_command();
        if e.filament_rate > 0.0
            && let Some(code) = self.heat.push_fault(input.time_ns)
        {
            // The last guard: nothing is pushed into a cold (or unmeasured) hot end.
            self.latch_fault(code, out);
            self.extruder.halt();
            e = super::extrude::ExtruderCommand { position: self.extruder.position(), ..Default::default() };
        }
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
        probe.stage_done(TickStage::Extrusion);
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
            last_reject_reason: self.intake.last_reject_reason as u32,
            queue_capacity: self.engine.config().queue_capacity as u32,
            queue_free: self.engine.free_space() as u32,
            executing_line: sample.map_or(0, |s| s.source_line),
            last_received_seq: self.intake.last_received_seq,
            last_rejected_seq: self.intake.last_rejected_seq,
            executing_seq: sample.map_or(0, |s| s.seq),
            segments_accepted: self.intake.accepted,
            rejected: self.intake.rejected,
            underruns: stats.underruns,
            overruns: input.cycle.overruns,
            late_wakeups: input.cycle.late_wakeups,
            worst_lateness_ns: input.cycle.worst_lateness_ns,
            clamps: self.command.clamps,
            log_drops: input.cycle.log_drops,
            log_state: input.cycle.log_state,
            executing_layer: self.layer.count,
            feed_override: self.feed_override,
            flow_override: self.flow_override,
            path_position: sample.map_or(0.0, |s| s.s),
            path_speed: sample.map_or(0.0, |s| s.speed),
            tcp_error: self.last_clik.map_or(0.0, |c| c.position_error),
            ..Default::default()
        };
        self.heat.fill_status(&mut out.status, input.time_ns);
        out.heater = self.heat.command(seq, input.time_ns, input.tick);
        if let Some(b) = &self.base_setpoint {
            out.base_command = b.command(seq, input.time_ns, input.tick);
        }
    }
}

/// The layer being printed: `LAYER_START` segments that have begun executing in this job.
#[derive(Clone, Copy, Debug, Default)]
struct LayerCount {
    /// Layers begun (0 before the first).
    count: u32,
    /// The segment that began the last one (0: none).
    seq: u64,
}

impl LayerCount {
    fn note(&mut self, sample: &PathSample) {
        if sample.flags.contains(SegmentFlags::LAYER_START) && sample.seq != self.seq {
            self.count = self.count.saturating_add(1);
            self.seq = sample.seq;
        }
    }
}

#[cfg(test)]
mod tests {
    //! The stall watchdog end to end: a path engine frozen mid-job (as a planner bug would leave
    //! it) becomes a `PathStalled` fault naming the segment and line, the extruder stops, and the
    //! arm brakes within its limits. (That it never fires on dwells, underruns and pauses is in
    //! tests/controller.rs.)
    use super::*;
    use crate::base::BaseConfig;
    use crate::extrude::ExtruderConfig;
    use crate::kin::{ClikConfig, Frame};
    use crate::path::PathConfig;
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

    /// The default settings (config/default.toml's values) on the iiwa7 with its 10 cm tool and
    /// the dynamic limits of config/robots/iiwa7.toml.
    fn iiwa7() -> (ControllerSettings, RobotModel) {
        let settings = ControllerSettings {
            controller: ControllerConfig::default(),
            clik: ClikConfig::default(),
            path: PathConfig::default(),
            extruder: ExtruderConfig::default(),
            base: BaseConfig::default(),
            bed_mesh: None,
        };
        let urdf = include_str!("../../../config/robots/iiwa7.urdf");
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
        (settings, model)
    }

    /// The following error is measured against what the robot was told when its driver says
    /// (after a hold the driver's answers lag the command while they catch up, and the robot
    /// follows the answers), and against the command when it does not.
    #[test]
    fn the_following_error_is_measured_against_what_the_robot_was_told() {
        let (settings, model) = iiwa7();
        let limit = settings.controller.following_error_limit;
        let dt_ns = (settings.controller.dt() * 1e9).round() as u64;
        let run = |told: bool| {
            let mut ctl = Controller::new(&settings, model.clone()).unwrap();
            let mut faults = Vec::new();
            for t in 0..3u64 {
                let now = 1_000_000_000 + t * dt_ns;
                let mut input = TickInput::new(t, now);
                let mut js = ipc::JointState { seq: t + 1, stamp_ns: now, dof: 7, ..Default::default() };
                js.position[..7].copy_from_slice(&START);
                if t > 0 {
                    // The robot stands 1.5 × the limit off the command on joint 1, where its
                    // driver's catch-up put it.
                    js.position[0] += 1.5 * limit;
                    if told {
                        js.flags = ipc::joint_state_flags::TARGET_KNOWN | ipc::joint_state_flags::CATCHING_UP;
                        js.robot_target = js.position;
                    }
                }
                input.joint_state = Some(js);
                let out = ctl.step(&input);
                faults.extend(out.events().iter().filter_map(|e| if let Event::Fault { code, .. } = *e { Some(code) } else { None }));
            }
            faults
        };
        assert_eq!(run(false), [FaultCode::RobotDeviation]);
        assert_eq!(run(true), []);
    }

    #[test]
    fn a_frozen_path_faults_as_path_stalled_and_the_arm_brakes() {
        let (settings, model) = iiwa7();
        let timeout = settings.path.stall_timeout;
        assert_eq!(timeout, 0.5);
        let dof = model.dof();
        let limits: Vec<_> = (0..dof).map(|i| *model.limits(i)).collect();
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
