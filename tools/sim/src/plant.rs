//! The arm's joints and the extruder as a robot controller and a hot end would move them: a dead
//! time, first-order lags, position limits and measurement noise.

use std::collections::VecDeque;

use strand_ipc::MAX_JOINTS;

use super::Gaussian;
use super::config::{ExtruderPlantConfig, JointPlantConfig};

/// Joint positions through a dead time and a first-order lag, clamped to the URDF limits.
pub(crate) struct JointPlant {
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
    /// A plant of the joints whose position limits are `limits` ((lower, upper), rad or m: the
    /// arm's, then a positioner's), at rest at `start` (clamped to the limits), cycling every `dt` s.
    pub(crate) fn new(limits: &[(f64, f64)], cfg: &JointPlantConfig, dt: f64, start: &[f64]) -> Self {
        let dof = limits.len().min(MAX_JOINTS);
        let mut lower = [0.0; MAX_JOINTS];
        let mut upper = [0.0; MAX_JOINTS];
        let mut position = [0.0; MAX_JOINTS];
        for i in 0..dof {
            (lower[i], upper[i]) = limits[i];
            position[i] = start[i].clamp(lower[i], upper[i]);
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
    pub(crate) fn dof(&self) -> usize {
        self.dof
    }

    /// A command arrived this cycle.
    pub(crate) fn command(&mut self, position: &[f64; MAX_JOINTS]) {
        self.pending.push_back((self.cycle, *position));
    }

    /// Advances one cycle of `dt` seconds: commands that have waited out the dead time take effect,
    /// then each joint moves its lag's fraction of the way, never past a limit.
    pub(crate) fn step(&mut self, dt: f64) {
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
    pub(crate) fn measured(&self, noise: &mut Gaussian) -> [f64; MAX_JOINTS] {
        let mut q = self.position;
        for v in q.iter_mut().take(self.dof) {
            *v += self.noise * noise.sample();
        }
        q
    }
}

/// The extruder motor following the commanded filament speed, and the melt flow at the nozzle
/// lagging the filament pushed in (hot-end back pressure).
///
/// The hot end is a compliance: melt pushed in is stored under pressure and flows out at a rate
/// proportional to what is stored (`flow = stored / melt_lag`), so a steady push gives the
/// first-order lag 000 describes. A retraction pulls stored melt back: the flow falls faster than
/// by stopping, and below empty it leaves a void (nothing flows) that the prime must refill before
/// melt flows again. (Before, a retraction drew nothing back and the prime after it pushed its
/// whole length out: every unplanned stop left a blob that no compensation could avoid.)
pub(crate) struct ExtruderPlant {
    motor_gain: f64,
    melt_gain: f64,
    /// The melt time constant (s).
    melt_lag: f64,
    /// Filament area (m²).
    area: f64,
    /// Filament speed at the drive wheel (m/s).
    pub filament_rate: f64,
    /// Filament pushed in so far (m).
    pub filament_position: f64,
    /// The stored melt as the flow it drives (m³/s): `stored / melt_lag`; below 0 a void.
    pressure: f64,
    /// Melt leaving the nozzle (m³/s).
    pub nozzle_flow: f64,
    /// Melt deposited so far (m³).
    pub deposited: f64,
}

impl ExtruderPlant {
    /// An idle extruder for filament of `filament_diameter` (m), cycling every `dt` seconds.
    pub(crate) fn new(cfg: &ExtruderPlantConfig, filament_diameter: f64, dt: f64) -> Self {
        let gain = |tau: f64| if tau > 0.0 { 1.0 - (-dt / tau).exp() } else { 1.0 };
        ExtruderPlant {
            motor_gain: gain(cfg.motor_lag),
            melt_gain: gain(cfg.melt_lag),
            melt_lag: cfg.melt_lag,
            area: std::f64::consts::PI * 0.25 * filament_diameter * filament_diameter,
            filament_rate: 0.0,
            filament_position: 0.0,
            pressure: 0.0,
            nozzle_flow: 0.0,
            deposited: 0.0,
        }
    }

    /// Advances one cycle towards the commanded filament speed (m/s; < 0 retracts).
    pub(crate) fn step(&mut self, commanded_filament_rate: f64, dt: f64) {
        self.filament_rate += self.motor_gain * (commanded_filament_rate - self.filament_rate);
        self.filament_position += self.filament_rate * dt;
        let pushed = self.filament_rate * self.area;
        if self.pressure > 0.0 || (self.pressure == 0.0 && pushed >= 0.0) || self.melt_lag <= 0.0 {
            // Melt under pressure: the exact step of the first-order lag towards what is pushed.
            self.pressure += self.melt_gain * (pushed - self.pressure);
        } else {
            // A void: what is pushed fills it, nothing flows out.
            self.pressure += pushed * dt / self.melt_lag;
        }
        self.nozzle_flow = self.pressure.max(0.0);
        self.deposited += self.nozzle_flow * dt;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant() -> ExtruderPlant {
        ExtruderPlant::new(&ExtruderPlantConfig { motor_lag: 0.0, melt_lag: 0.08 }, 1.75e-3, 1e-3)
    }

    #[test]
    fn a_steady_push_flows_after_the_melt_lag() {
        let mut p = plant();
        for _ in 0..80 {
            p.step(1e-3, 1e-3);
        }
        let full = 1e-3 * p.area;
        // One time constant: 1 − 1/e of the pushed flow.
        assert!((p.nozzle_flow / full - (1.0 - (-1.0f64).exp())).abs() < 1e-9, "{}", p.nozzle_flow / full);
        for _ in 0..2000 {
            p.step(1e-3, 1e-3);
        }
        assert!((p.nozzle_flow / full - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_retraction_leaves_a_void_and_the_prime_only_gives_back_what_it_took() {
        let mut p = plant();
        for _ in 0..2000 {
            p.step(1e-3, 1e-3);
        }
        // Stop and retract 1 mm at 35 mm/s at once, stand, prime it back, stand: while retracted
        // (almost) nothing oozes; in all, the melt laid from the stop on is what was stored
        // (flow · lag) and no more: the prime gives back what the retraction took, no blob.
        let stored = p.nozzle_flow * 0.08;
        let before = p.deposited;
        let run = |p: &mut ExtruderPlant, rate: f64, ticks: usize| {
            for _ in 0..ticks {
                p.step(rate, 1e-3);
            }
        };
        run(&mut p, -0.035, 29);
        let at_retraction = p.deposited - before;
        run(&mut p, 0.0, 500);
        let while_retracted = p.deposited - before - at_retraction;
        assert!(while_retracted == 0.0 && at_retraction < 0.05 * stored, "{at_retraction:e} then {while_retracted:e} of {stored:e}");
        run(&mut p, 0.035, 29);
        run(&mut p, 0.0, 2000);
        let laid = p.deposited - before;
        assert!(laid <= stored * 1.0001, "laid {laid:e} m³ of {stored:e} stored");
        assert!(p.nozzle_flow < 1e-3 * stored, "at rest: {:e}", p.nozzle_flow);
    }
}
