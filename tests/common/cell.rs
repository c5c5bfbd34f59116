//! A printing cell in one thread for driving `Controller::step` directly: a robot that follows its
//! commands exactly (joint state = last command), segment and control helpers, and limit checks.
#![allow(dead_code)]

use strand::config::Config;
use strand_core::{Controller, MAX_SEGMENTS_PER_TICK, TickInput, TickOutput};
use strand_ipc as ipc;

use strand_testkit::root;

/// Nozzle pointing down in W (π about y).
pub(crate) const DOWN: [f64; 4] = [0.0, 0.0, 1.0, 0.0];
/// A start posture for the iiwa7: elbow bent, wrist down, away from singularities.
pub(crate) const IIWA_START: [f64; 7] = [0.0, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0];
/// Filament per metre for a 0.4 × 0.2 mm bead of 1.75 mm filament (m/m).
pub(crate) const FLOW: f64 = 0.4e-3 * 0.2e-3 / (std::f64::consts::PI * 0.875e-3 * 0.875e-3);

pub(crate) fn config(mutate: impl FnOnce(&mut Config)) -> Config {
    let mut c = Config::load(&root().join("config/default.toml")).unwrap_or_else(|e| panic!("{e}"));
    mutate(&mut c);
    c
}

pub(crate) struct Cell {
    pub ctl: Controller,
    pub tick: u64,
    pub dt_ns: u64,
    /// Time of tick 0 (ns).
    pub t0: u64,
    /// When false, no joint state is sent (a silent driver).
    pub driver: bool,
    /// Joint state the driver reports (echo of the last command after the first tick).
    pub q_robot: [f64; 8],
    pub segments: std::collections::VecDeque<ipc::Segment>,
    pub controls: Vec<ipc::Control>,
    pub poses: Vec<ipc::BasePose>,
    pub feeder_lost: bool,
    /// The heater measurement sent with every tick (None: no heater publishes).
    pub heater_state: Option<ipc::HeaterState>,
    /// A tracked base that is exactly where the service's `BaseCommand` put it, reported by its
    /// tracker every tick (a base that follows its setpoint, as the robot follows its commands).
    pub base_follows_command: bool,
    pub last: Option<TickOutput>,
    state_seq: u64,
    pose_seq: u64,
    control_seq: u64,
}

impl Cell {
    pub(crate) fn new(cfg: &Config, q_start: &[f64]) -> Self {
        let ctl = cfg.robot.build_controller(&cfg.controller_settings()).unwrap_or_else(|e| panic!("{e}"));
        let mut q_robot = [0.0; 8];
        q_robot[..q_start.len()].copy_from_slice(q_start);
        Cell {
            ctl,
            tick: 0,
            dt_ns: (cfg.controller.dt() * 1e9).round() as u64,
            t0: 1_000_000_000,
            driver: true,
            q_robot,
            segments: Default::default(),
            controls: Vec::new(),
            poses: Vec::new(),
            feeder_lost: false,
            heater_state: None,
            base_follows_command: false,
            last: None,
            state_seq: 0,
            pose_seq: 0,
            control_seq: 0,
        }
    }

    pub(crate) fn iiwa() -> Self {
        Cell::new(&config(|_| {}), &IIWA_START)
    }

    pub(crate) fn now_ns(&self) -> u64 {
        self.t0 + self.tick * self.dt_ns
    }

    pub(crate) fn input(&mut self) -> TickInput {
        let mut input = TickInput::new(self.tick, self.now_ns());
        if self.driver {
            self.state_seq += 1;
            let dof = self.ctl.cell_dof();
            input.joint_state = Some(ipc::JointState {
                seq: self.state_seq,
                stamp_ns: self.now_ns(),
                dof: dof as u32,
                position: self.q_robot,
                ..Default::default()
            });
        }
        while input.segment_count < MAX_SEGMENTS_PER_TICK as u32 {
            let Some(s) = self.segments.pop_front() else { break };
            input.push_segment(&s);
        }
        for c in self.controls.drain(..) {
            input.push_control(&c);
        }
        for p in self.poses.drain(..) {
            input.push_base_pose(&p);
        }
        input.feeder_lost = self.feeder_lost;
        input.heater_state = self.heater_state;
        input
    }

    /// One tick; the robot follows the command exactly.
    pub(crate) fn step(&mut self) -> TickOutput {
        self.step_observed(&mut |_, _| {})
    }

    /// One tick, handing its input and output to `observe` (a logger).
    pub(crate) fn step_observed(&mut self, observe: &mut dyn FnMut(&TickInput, &TickOutput)) -> TickOutput {
        let input = self.input();
        let out = self.ctl.step(&input);
        observe(&input, &out);
        if out.joint_command.valid == 1 {
            self.q_robot = out.joint_command.position;
        }
        if self.base_follows_command && out.base_command.valid == 1 {
            self.pose_seq += 1;
            let b = &out.base_command;
            self.poses.push(ipc::BasePose {
                seq: self.pose_seq,
                stamp_ns: self.now_ns(),
                position: b.position,
                orientation: b.orientation,
            });
        }
        self.tick += 1;
        self.last = Some(out);
        out
    }

    pub(crate) fn send(&mut self, segments: &[ipc::Segment]) {
        self.segments.extend(segments.iter().copied());
    }

    pub(crate) fn control(&mut self, command: ipc::Command, value: f64) {
        self.control_seq += 1;
        self.controls.push(ipc::Control { seq: self.control_seq, stamp_ns: self.now_ns(), command: command as u32, value, _reserved: 0 });
    }

    pub(crate) fn state(&self) -> ipc::RunState {
        self.ctl.run_state()
    }

    /// Steps until `until` holds for the output or `max` ticks pass; checks limits on every tick.
    pub(crate) fn run_until(&mut self, max: u64, mut until: impl FnMut(&TickOutput) -> bool) -> Option<TickOutput> {
        for _ in 0..max {
            let out = self.step();
            check_limits(self.ctl.model(), &out);
            if until(&out) {
                return Some(out);
            }
        }
        None
    }
}

/// The command is finite and within position, velocity and acceleration limits.
pub(crate) fn check_limits(model: &strand_core::kin::RobotModel, out: &TickOutput) {
    let jc = &out.joint_command;
    for i in 0..model.dof() {
        let l = model.limits(i);
        let (q, v, a) = (jc.position[i], jc.velocity[i], jc.acceleration[i]);
        assert!(q.is_finite() && v.is_finite() && a.is_finite(), "tick {}: joint {i} not finite", jc.tick);
        assert!(q >= l.lower - 1e-12 && q <= l.upper + 1e-12, "tick {}: joint {i} at {q} outside [{}, {}]", jc.tick, l.lower, l.upper);
        assert!(v.abs() <= l.velocity * (1.0 + 1e-9), "tick {}: joint {i} speed {v} > {}", jc.tick, l.velocity);
        assert!(a.abs() <= l.acceleration * (1.0 + 1e-6) + 1e-6, "tick {}: joint {i} acceleration {a} > {}", jc.tick, l.acceleration);
    }
    let e = &out.extruder;
    assert!(e.motor_speed.is_finite() && e.filament_rate.is_finite() && e.filament_position.is_finite());
}

pub(crate) fn line(seq: u64, end: [f64; 3], feed: f64, filament: f64) -> ipc::Segment {
    let flags = if filament > 0.0 { ipc::segment_flags::EXTRUDE } else { ipc::segment_flags::TRAVEL };
    ipc::Segment { seq, kind: ipc::SegmentKind::Line as u32, flags, end, orientation: DOWN, feed, filament, ..Default::default() }
}

/// A travel to `origin`, then `loops` squares of side `side` (m) extruding at `feed`, the last
/// segment flagged LAST. Sequence numbers start at `seq0`.
pub(crate) fn square_job(seq0: u64, origin: [f64; 3], side: f64, loops: usize, feed: f64) -> Vec<ipc::Segment> {
    let mut v = vec![line(seq0, origin, 0.1, 0.0)];
    let [x, y, z] = origin;
    let corners = [[x + side, y, z], [x + side, y + side, z], [x, y + side, z], [x, y, z]];
    for _ in 0..loops {
        for c in corners {
            let seq = seq0 + v.len() as u64;
            v.push(line(seq, c, feed, side * FLOW));
        }
    }
    v.last_mut().unwrap().flags |= ipc::segment_flags::LAST;
    v
}

/// Filament the job asks for (m).
pub(crate) fn job_filament(job: &[ipc::Segment]) -> f64 {
    job.iter().map(|s| s.filament).sum()
}
