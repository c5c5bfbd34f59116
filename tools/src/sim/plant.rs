//! The arm's joints and the extruder as a robot controller and a hot end would move them: a dead
//! time, first-order lags, position limits and measurement noise.

use std::collections::VecDeque;

use strand::core::kin::RobotModel;
use strand_ipc::MAX_JOINTS;

use super::Gaussian;
use super::config::{ExtruderPlantConfig, JointPlantConfig};

/// Joint positions through a dead time and a first-order lag, clamped to the URDF limits.
pub struct JointPlant {
    dof: usize,
    lower: [f64; MAX_JOINTS],
    upper: [f64; MAX_JOINTS],
    /// Commands waiting out the dead time: (cycle they arrived in, positions), oldest first.
    pending: VecDeque<(u64, [f64; MAX_JOINTS])>,
    /// Cycles stepped.
    cycle: u64,
    latency: usize,
    /// Fraction of the remaining error removed per cycle: 1 − exp(−dt/lag).
    gain: f64,
    noise: f64,
    /// Where the commands last put the joints (rad or m).
    target: [f64; MAX_JOINTS],
    /// Actual positions (rad or m).
    pub position: [f64; MAX_JOINTS],
    /// Actual velocities (rad/s or m/s).
    pub velocity: [f64; MAX_JOINTS],
}

impl JointPlant {
    /// A plant at rest at `start` (clamped to the limits), cycling every `dt` seconds.
    pub fn new(model: &RobotModel, cfg: &JointPlantConfig, dt: f64, start: &[f64]) -> Self {
        let dof = model.dof();
        let mut lower = [0.0; MAX_JOINTS];
        let mut upper = [0.0; MAX_JOINTS];
        let mut position = [0.0; MAX_JOINTS];
        for i in 0..dof {
            let l = model.limits(i);
            lower[i] = l.lower;
            upper[i] = l.upper;
            position[i] = start[i].clamp(l.lower, l.upper);
        }
        let gain = if cfg.lag > 0.0 { 1.0 - (-dt / cfg.lag).exp() } else { 1.0 };
        JointPlant {
            dof,
            lower,
            upper,
            pending: VecDeque::with_capacity(cfg.latency_ticks + 2),
            cycle: 0,
            latency: cfg.latency_ticks,
            gain,
            noise: cfg.noise,
            target: position,
            position,
            velocity: [0.0; MAX_JOINTS],
        }
    }

    /// Joints.
    pub fn dof(&self) -> usize {
        self.dof
    }

    /// A command arrived this cycle.
    pub fn command(&mut self, position: &[f64; MAX_JOINTS]) {
        self.pending.push_back((self.cycle, *position));
    }

    /// Advances one cycle of `dt` seconds: commands that have waited out the dead time take effect,
    /// then each joint moves its lag's fraction of the way, never past a limit.
    pub fn step(&mut self, dt: f64) {
        // A command that arrived in cycle c acts from the step of cycle c + latency on.
        while self.pending.front().is_some_and(|(c, _)| c + self.latency as u64 <= self.cycle) {
            self.target = self.pending.pop_front().expect("non-empty").1;
        }
        self.cycle += 1;
        for i in 0..self.dof {
            let before = self.position[i];
            let next = before + self.gain * (self.target[i] - before);
            self.position[i] = next.clamp(self.lower[i], self.upper[i]);
            self.velocity[i] = (self.position[i] - before) / dt;
        }
    }

    /// What the encoders report: the actual positions plus noise.
    pub fn measured(&self, noise: &mut Gaussian) -> [f64; MAX_JOINTS] {
        let mut q = self.position;
        for v in q.iter_mut().take(self.dof) {
            *v += self.noise * noise.sample();
        }
        q
    }
}

/// The extruder motor following the commanded filament speed, and the melt flow at the nozzle
/// lagging the filament pushed in (hot-end back pressure).
pub struct ExtruderPlant {
    motor_gain: f64,
    melt_gain: f64,
    /// Filament area (m²).
    area: f64,
    /// Filament speed at the drive wheel (m/s).
    pub filament_rate: f64,
    /// Filament pushed in so far (m).
    pub filament_position: f64,
    /// Melt leaving the nozzle (m³/s).
    pub nozzle_flow: f64,
    /// Melt deposited so far (m³).
    pub deposited: f64,
}

impl ExtruderPlant {
    /// An idle extruder for filament of `filament_diameter` (m), cycling every `dt` seconds.
    pub fn new(cfg: &ExtruderPlantConfig, filament_diameter: f64, dt: f64) -> Self {
        let gain = |tau: f64| if tau > 0.0 { 1.0 - (-dt / tau).exp() } else { 1.0 };
        ExtruderPlant {
            motor_gain: gain(cfg.motor_lag),
            melt_gain: gain(cfg.melt_lag),
            area: std::f64::consts::PI * 0.25 * filament_diameter * filament_diameter,
            filament_rate: 0.0,
            filament_position: 0.0,
            nozzle_flow: 0.0,
            deposited: 0.0,
        }
    }

    /// Advances one cycle towards the commanded filament speed (m/s). Retraction pulls filament
    /// back but draws no melt out of the nozzle.
    pub fn step(&mut self, commanded_filament_rate: f64, dt: f64) {
        self.filament_rate += self.motor_gain * (commanded_filament_rate - self.filament_rate);
        self.filament_position += self.filament_rate * dt;
        let pushed = self.filament_rate.max(0.0) * self.area;
        self.nozzle_flow += self.melt_gain * (pushed - self.nozzle_flow);
        self.deposited += self.nozzle_flow * dt;
    }
}
