//! strand-sim's plant, with no I/O: the robot arm's joints, the extruder, the base (fixed, or 000's
//! free flyer) and the tracker, advanced one robot cycle at a time by [`Sim::step`]. The binary
//! (`strand-sim`) wires it to the service over iceoryx2; tests drive it directly.
//!
//! The sim also knows the truth the controller cannot see: where the nozzle really is (the actual
//! joints through the actual base; with a positioner, also where it is on the part the actual axes
//! carry) and how much melt really leaves it. A positioner's axes are joints like the arm's, after
//! them: the same dead time, lag, limits and noise. [`Truth`] rows carry that,
//! stamped with the sim's time, so the demo can compare them with the targets in the service's log.
//!
//! [`demo`] is strand-demo: the service, this sim and the feeder on a bundled job, then a summary.

pub mod config;
pub mod demo;
pub mod flyer;
pub mod plant;
pub mod process;
pub mod tracker;

use nalgebra::{UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use strand::config::Config;
use strand_core::kin::{JointVector, RobotModel};
use strand_core::{BaseMode, Carries, Positioner};
use strand_ipc as ipc;

use config::SimConfig;
use flyer::{BaseTrajectory, Flyer};
use plant::{ExtruderPlant, JointPlant};
use strand_cli::error::{Result, ToolError};
use strand_replay::truth::Truth;
use tracker::{Sample, Tracker};

/// Seeded noise: standard normal and uniform draws.
pub struct Gaussian {
    rng: StdRng,
    spare: Option<f64>,
}

impl Gaussian {
    /// A source seeded with `seed` (the same seed, the same draws).
    pub fn new(seed: u64) -> Self {
        Gaussian { rng: StdRng::seed_from_u64(seed), spare: None }
    }

    /// A draw from N(0, 1) (Box-Muller).
    pub fn sample(&mut self) -> f64 {
        if let Some(s) = self.spare.take() {
            return s;
        }
        let u1: f64 = 1.0 - self.rng.random::<f64>();
        let u2: f64 = self.rng.random::<f64>();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        self.spare = Some(r * s);
        r * c
    }

    /// A draw from U[0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.rng.random::<f64>()
    }
}

/// The plant. See the module documentation.
pub struct Sim {
    model: RobotModel,
    /// The cell's positioner, if any: its axes follow the arm's joints.
    positioner: Option<Positioner>,
    /// Mount pose of a fixed base (and the flyer's z, roll and pitch).
    mount_position: Vector3<f64>,
    mount_orientation: UnitQuaternion<f64>,
    mount_yaw: f64,
    joints: JointPlant,
    extruder: ExtruderPlant,
    tracker: Option<Tracker>,
    flyer: Option<Flyer>,
    noise: Gaussian,
    dt_ns: u64,
    start_ns: u64,
    time_ns: u64,
    /// Commanded filament speed (m/s) and melt flow (m³/s), latest.
    extruder_command: (f64, f64),
    /// The nozzle's last two positions in the base frame (m) for the arm's own acceleration.
    tcp_history: [Vector3<f64>; 2],
    /// The bed: the service config's plane and the sim's true surface on it.
    bed: strand_job::BedTransform,
    bed_surface: Option<strand_core::BedMesh>,
    truth: Truth,
}

impl Sim {
    /// A plant for the service config `cfg` (robot, rate, base mode and mount), at rest at `start`
    /// joint positions, its clock starting at `start_ns`.
    pub fn new(cfg: &Config, sim: &SimConfig, start: &[f64], start_ns: u64) -> Result<Self> {
        let model = cfg.robot.build_model()?;
        let positioner = cfg.robot.build_positioner()?;
        let n = model.dof();
        let axes = positioner.as_ref().map_or(0, Positioner::dof);
        if start.len() != n && start.len() != n + axes {
            return Err(ToolError::Usage(format!(
                "start posture has {} values; the robot has {n} joints{}",
                start.len(),
                if axes > 0 { format!(" and its positioner {axes} axes") } else { String::new() }
            )));
        }
        let mut limits: Vec<(f64, f64)> = (0..n).map(|i| (model.limits(i).lower, model.limits(i).upper)).collect();
        if let Some(p) = &positioner {
            limits.extend((0..axes).map(|i| (p.model().limits(i).lower, p.model().limits(i).upper)));
        }
        // A positioner not in the start posture starts at home.
        let start: Vec<f64> = (0..n + axes).map(|i| start.get(i).copied().unwrap_or(0.0)).collect();
        let dt = 1.0 / cfg.controller.rate_hz;
        let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
        let mount = cfg.base.mount();
        let mount_position = mount.translation.vector;
        let mount_orientation = UnitQuaternion::from_rotation_matrix(&mount.rotation);
        let mount_yaw = cfg.base.mount_rpy[2];
        let tracked = cfg.base.mode == BaseMode::Tracked;
        let flyer = match (&sim.flyer, tracked) {
            (Some(f), true) => {
                let start_pose = [mount_position.x, mount_position.y, mount_yaw];
                let by_clock = !f.trajectory.as_os_str().is_empty();
                let trajectory =
                    if by_clock { BaseTrajectory::load(&f.trajectory, mount_yaw)? } else { BaseTrajectory::stationary(start_pose) };
                Some(Flyer::new(f, trajectory, !by_clock, mount_position.z))
            }
            _ => None,
        };
        let bed = cfg.bed_transform()?;
        let bed_surface = match &sim.bed {
            Some(surface) => Some(
                strand_core::BedMesh::new(&surface.as_mesh(), bed.point(&Vector3::zeros()), bed.rotation())
                    .map_err(|e| ToolError::Usage(e.message.replace("[bed.mesh]", "sim [bed]")))?,
            ),
            None => None,
        };
        let mut sim = Sim {
            bed,
            bed_surface,
            joints: JointPlant::new(&limits, &sim.joints, dt, &start),
            positioner,
            extruder: ExtruderPlant::new(&sim.extruder, cfg.extruder.filament_diameter, dt),
            tracker: tracked.then(|| Tracker::new(&sim.tracker, start_ns)),
            flyer,
            model,
            mount_position,
            mount_orientation,
            mount_yaw,
            noise: Gaussian::new(sim.seed),
            dt_ns,
            start_ns,
            time_ns: start_ns,
            extruder_command: (0.0, 0.0),
            tcp_history: [Vector3::zeros(); 2],
            truth: Truth::default(),
        };
        let tcp = sim.tcp_in_base();
        sim.tcp_history = [tcp, tcp];
        sim.truth = sim.observe();
        Ok(sim)
    }

    /// The robot model.
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// Sim time (ns).
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }

    /// The robot cycle (ns).
    pub fn dt_ns(&self) -> u64 {
        self.dt_ns
    }

    /// The latest truth.
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    /// The tracker's counters (measured, dropped), if the base is tracked.
    pub(crate) fn tracker_counts(&self) -> Option<(u64, u64)> {
        self.tracker.as_ref().map(|t| (t.measured, t.dropped))
    }

    /// The actual robot-base pose: position (m, W) and orientation.
    pub fn base_pose(&self) -> (Vector3<f64>, UnitQuaternion<f64>) {
        match &self.flyer {
            Some(f) => {
                let (p, theta) = f.base_pose();
                let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta - self.mount_yaw);
                (Vector3::from(p), yaw * self.mount_orientation)
            }
            None => (self.mount_position, self.mount_orientation),
        }
    }

    /// The nozzle in the robot's base frame (m): FK of the actual joints.
    fn tcp_in_base(&self) -> Vector3<f64> {
        let q = JointVector::from_fn(|i, _| if i < self.model.dof() { self.joints.position[i] } else { 0.0 });
        self.model.forward_kinematics(&q).translation.vector
    }

    /// The positioner's actual axes (rad or m; zeros without one).
    fn axes(&self) -> [f64; ipc::MAX_EXTERNAL_AXES] {
        let (arm, n) = (self.model.dof(), self.joints.dof());
        std::array::from_fn(|i| if arm + i < n { self.joints.position[arm + i] } else { 0.0 })
    }

    /// The nozzle on the part (m, W, in the work frame at home): where the actual axes carry the
    /// part, brought back; the nozzle in W without a positioner.
    fn tcp_on_part(&self) -> Vector3<f64> {
        let Some(positioner) = &self.positioner else {
            return self.actual_tcp();
        };
        let (home, _) = positioner.to_home(&self.tcp_in_base(), &UnitQuaternion::identity(), &self.axes());
        let (p, r) = self.base_pose();
        p + r * home
    }

    /// The nozzle in W (m): through the actual base (and where a track has carried it).
    fn actual_tcp(&self) -> Vector3<f64> {
        let (p, r) = self.base_pose();
        let in_base = match &self.positioner {
            Some(track) if track.carries() == Carries::Robot => {
                track.to_home(&self.tcp_in_base(), &UnitQuaternion::identity(), &self.axes()).0
            }
            _ => self.tcp_in_base(),
        };
        p + r * in_base
    }

    fn heading(&self) -> f64 {
        self.flyer.as_ref().map_or(self.mount_yaw, |f| f.theta)
    }

    fn observe(&self) -> Truth {
        let (p, _) = self.base_pose();
        let tcp = self.actual_tcp();
        let t = (self.time_ns - self.start_ns) as f64 * 1e-9;
        let planned = self.flyer.as_ref().map_or([p.x, p.y, self.mount_yaw], |f| f.planned(t));
        let on_part = self.tcp_on_part();
        // The bed is on the part (with a positioner, in its frame at home).
        let on_bed = self.bed.to_bed(&on_part);
        let surface = self.bed_surface.as_ref().map_or(0.0, |m| m.height(on_bed.x, on_bed.y));
        Truth {
            bed_gap: on_bed.z - surface,
            time_ns: self.time_ns,
            tcp: [tcp.x, tcp.y, tcp.z],
            tcp_part: [on_part.x, on_part.y, on_part.z],
            base: [p.x, p.y, p.z],
            base_theta: self.heading(),
            base_planned: [planned[0], planned[1], p.z],
            flow_commanded: self.extruder_command.1,
            flow_actual: self.extruder.nozzle_flow,
            thrust_saturation: self.flyer.as_ref().map_or(0.0, |f| f.saturation),
        }
    }

    /// The JointState the encoders report now (stamped with the sim's time).
    pub fn joint_state(&mut self, seq: u64) -> ipc::JointState {
        let mut js = ipc::JointState { seq, stamp_ns: self.time_ns, dof: self.joints.dof() as u32, ..Default::default() };
        js.position = self.joints.measured(&mut self.noise);
        js.velocity = self.joints.velocity;
        js
    }

    /// Tracking samples that arrive by now, as BasePose messages (stamped with their measurement
    /// time), appended to `out`.
    pub fn base_poses(&mut self, seq: &mut u64, out: &mut Vec<ipc::BasePose>) {
        let truth_pose = {
            let (p, _) = self.base_pose();
            ([p.x, p.y, p.z], self.heading())
        };
        let Some(tracker) = self.tracker.as_mut() else { return };
        let mut samples: Vec<Sample> = Vec::new();
        tracker.poll(self.time_ns, truth_pose, &mut self.noise, &mut samples);
        for s in samples {
            *seq += 1;
            let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), s.theta - self.mount_yaw);
            let q = yaw * self.mount_orientation;
            out.push(ipc::BasePose { seq: *seq, stamp_ns: s.stamp_ns, position: s.position, orientation: [q.w, q.i, q.j, q.k] });
        }
    }

    /// A joint command arrived (invalid ones are ignored, as a robot would).
    pub fn command_joints(&mut self, cmd: &ipc::JointCommand) {
        if cmd.valid == 1 && cmd.position[..self.joints.dof()].iter().all(|v| v.is_finite()) {
            self.joints.command(&cmd.position);
        }
    }

    /// An extruder command arrived.
    pub fn command_extruder(&mut self, cmd: &ipc::ExtruderCommand) {
        if cmd.filament_rate.is_finite() && cmd.volumetric_rate.is_finite() {
            self.extruder_command = (cmd.filament_rate, cmd.volumetric_rate);
        }
    }

    /// Whether the plant takes the service's base setpoint (a flyer with no trajectory by the clock).
    pub fn takes_base_commands(&self) -> bool {
        self.flyer.as_ref().is_some_and(|f| f.follows_setpoint())
    }

    /// A base setpoint arrived (`[base] plan`): the flyer's PID loops head for it (invalid and
    /// non-finite ones are ignored, as a base controller would).
    pub fn command_base(&mut self, cmd: &ipc::BaseCommand) {
        let [w, x, y, z] = cmd.orientation;
        let yaw = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)).euler_angles().2;
        if let Some(f) = self.flyer.as_mut()
            && cmd.valid == 1
        {
            f.set_goal([cmd.position[0], cmd.position[1], yaw]);
        }
    }

    /// Advances one robot cycle and returns the truth at its end.
    pub fn step(&mut self) -> Truth {
        let dt = self.dt_ns as f64 * 1e-9;
        self.joints.step(dt);
        self.extruder.step(self.extruder_command.0, dt);
        // The arm's reaction on the base comes from the nozzle's acceleration relative to the base
        // (the base's own acceleration is the flyer's rigid-body dynamics), turned into W.
        let in_base = self.tcp_in_base();
        let accel_b = (in_base - 2.0 * self.tcp_history[1] + self.tcp_history[0]) / (dt * dt);
        self.tcp_history = [self.tcp_history[1], in_base];
        let accel = self.base_pose().1 * accel_b;
        let tcp = self.actual_tcp();
        let t = (self.time_ns - self.start_ns) as f64 * 1e-9;
        let measured = self.tracker.as_ref().and_then(|tr| tr.latest).map(|s| [s.position[0], s.position[1], s.theta]);
        if let Some(f) = self.flyer.as_mut() {
            f.step(t, dt, measured, &tcp, &accel, &mut self.noise);
        }
        self.time_ns += self.dt_ns;
        self.truth = self.observe();
        self.truth
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn configs(service: &str, sim: &str) -> (Config, SimConfig) {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        (Config::load(&root.join(service)).unwrap(), SimConfig::load(&root.join(sim)).unwrap())
    }

    #[test]
    fn joints_follow_commands_after_the_dead_time_and_lag() {
        let (cfg, sim_cfg) = configs("config/default.toml", "config/sim/default.toml");
        let start = cfg.service.initial_joints.clone();
        let mut sim = Sim::new(&cfg, &sim_cfg, &start, 1_000).unwrap();
        let mut cmd = ipc::JointCommand { valid: 1, dof: 7, ..Default::default() };
        cmd.position[..7].copy_from_slice(&start);
        cmd.position[0] += 0.01;
        sim.command_joints(&cmd);
        sim.step();
        // One cycle of dead time: nothing moved yet.
        assert_eq!(sim.joints.position[0], start[0]);
        for _ in 0..30 {
            sim.step();
        }
        // 30 ms after, with a 2 ms lag: within 1e-6 of the command.
        assert!((sim.joints.position[0] - (start[0] + 0.01)).abs() < 1e-7);
        assert_eq!(sim.time_ns(), 1_000 + 31 * 1_000_000);
        // A fixed base sends no tracking.
        let mut poses = Vec::new();
        sim.base_poses(&mut 0, &mut poses);
        assert!(poses.is_empty());
    }

    #[test]
    fn the_flyer_holds_still_with_the_arm_at_rest() {
        let (cfg, sim_cfg) = configs("config/free-flyer.toml", "config/sim/free-flyer.toml");
        let start = cfg.service.initial_joints.clone();
        let mut sim = Sim::new(&cfg, &sim_cfg, &start, 0).unwrap();
        let mut poses = Vec::new();
        let mut seq = 0;
        let mut worst: f64 = 0.0;
        for _ in 0..60_000 {
            poses.clear();
            sim.base_poses(&mut seq, &mut poses);
            let t = sim.step();
            worst = worst.max(((t.base[0] - t.base_planned[0]).powi(2) + (t.base[1] - t.base_planned[1]).powi(2)).sqrt());
        }
        // 60 s: tracking arrives at about 120 Hz, and the PID loops keep the base within centimetres
        // of its place against the table's drift and the filament's torque.
        assert!((6_900..7_100).contains(&seq), "{seq} samples");
        assert!(worst < 0.03, "base wandered {worst} m");
        assert!(worst > 1e-4, "the disturbances move the base: {worst} m");
    }
}
