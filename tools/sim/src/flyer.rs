//! The free-flying base of 000 (Section 2.1): a planar rigid body (x, y, θ) on an air-bearing
//! table, eight thrusters of at most 2 N each, three PID loops (x, y, θ) on the tracked pose
//! following a planned trajectory, and the disturbances that make it wander: the table's residual
//! acceleration (a slope plus bumps at fixed places), the reaction of the moving arm and the torque
//! of the filament tension (000 Eq. 6).

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

pub use strand_job::load::BaseTrajectory;

use super::Gaussian;
use super::config::FlyerConfig;

/// One PID loop with a filtered derivative on the error.
#[derive(Clone, Copy, Debug, Default)]
struct Pid {
    gains: [f64; 3],
    integral: f64,
    last_error: Option<f64>,
    derivative: f64,
}

impl Pid {
    fn update(&mut self, error: f64, dt: f64, filter: f64) -> f64 {
        let [p, i, d] = self.gains;
        self.integral += error * dt;
        let raw = self.last_error.map_or(0.0, |e| (error - e) / dt);
        let a = if filter > 0.0 { dt / (filter + dt) } else { 1.0 };
        self.derivative += a * (raw - self.derivative);
        self.last_error = Some(error);
        p * error + i * self.integral + d * self.derivative
    }
}

/// The flyer's state and its control.
pub(crate) struct Flyer {
    cfg: FlyerConfig,
    trajectory: BaseTrajectory,
    /// Follow the service's setpoint (`BaseCommand`), not `trajectory`'s clock: no trajectory file.
    follows_setpoint: bool,
    /// The latest setpoint (x, y, θ), once one came; before, the trajectory's start (the mount).
    setpoint: Option<[f64; 3]>,
    /// Body wrench (Fx, Fy, τ) of unit thruster forces, one column per thruster.
    layout: SMatrix<f64, 3, 8>,
    /// Thruster forces from the body wrench: the least-norm allocation (layout's pseudo-inverse).
    allocation: SMatrix<f64, 8, 3>,
    /// Centre of mass (m, W) and heading (rad).
    pub com: Vector2<f64>,
    /// Heading (rad).
    pub theta: f64,
    /// Velocity of the centre of mass (m/s, W).
    pub velocity: Vector2<f64>,
    /// Yaw rate (rad/s).
    pub omega: f64,
    /// Base height above the table (m): the mount's.
    z: f64,
    pids: [Pid; 3],
    /// Thrust held between PID updates: force (N, W) and torque (N m).
    thrust: Vector3<f64>,
    next_pid_s: f64,
    tension_dev: f64,
    residual_dev: Vector2<f64>,
    /// Largest thruster command as a fraction of its limit, last update.
    pub saturation: f64,
}

impl Flyer {
    /// A flyer at rest whose robot base stands at `base_pose` (x, y, θ) and height `z`, following
    /// `trajectory` (robot-base poses) by the clock, or, with `follows_setpoint`, the setpoints
    /// given to [`Flyer::set_goal`] (holding the trajectory's start until the first).
    pub(crate) fn new(cfg: &FlyerConfig, trajectory: BaseTrajectory, follows_setpoint: bool, z: f64) -> Self {
        let start = trajectory.at(0.0);
        // Eight thrusters: at each corner (±a, ±a) one pushing along x, one along y.
        let a = cfg.thruster_arm;
        let mut b = SMatrix::<f64, 3, 8>::zeros();
        let corners = [(a, a), (-a, a), (-a, -a), (a, -a)];
        for (k, (x, y)) in corners.iter().enumerate() {
            // Along x at (x, y): torque = x·0 − y·1.
            b.set_column(2 * k, &Vector3::new(1.0, 0.0, -y));
            // Along y at (x, y): torque = x·1 − y·0.
            b.set_column(2 * k + 1, &Vector3::new(0.0, 1.0, *x));
        }
        let bbt: Matrix3<f64> = b * b.transpose();
        let allocation = b.transpose() * bbt.try_inverse().expect("the thruster layout spans (Fx, Fy, τ)");
        let mut flyer = Flyer {
            cfg: cfg.clone(),
            trajectory,
            follows_setpoint,
            setpoint: None,
            layout: b,
            allocation,
            com: Vector2::zeros(),
            theta: start[2],
            velocity: Vector2::zeros(),
            omega: 0.0,
            z,
            pids: [
                Pid { gains: cfg.pid_xy, ..Default::default() },
                Pid { gains: cfg.pid_xy, ..Default::default() },
                Pid { gains: cfg.pid_theta, ..Default::default() },
            ],
            thrust: Vector3::zeros(),
            next_pid_s: 0.0,
            tension_dev: 0.0,
            residual_dev: Vector2::zeros(),
            saturation: 0.0,
        };
        flyer.com = Vector2::new(start[0], start[1]) - flyer.rotate(&Vector2::from(cfg.base_offset));
        flyer
    }

    fn rotate(&self, v: &Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
    }

    /// The robot base's pose: (x, y, z) (m, W) and heading θ (rad).
    pub(crate) fn base_pose(&self) -> ([f64; 3], f64) {
        let p = self.com + self.rotate(&Vector2::from(self.cfg.base_offset));
        ([p.x, p.y, self.z], self.theta)
    }

    /// The planned robot-base pose at `t` seconds: the setpoint, or the trajectory's pose then.
    pub(crate) fn planned(&self, t: f64) -> [f64; 3] {
        match self.setpoint {
            Some(goal) if self.follows_setpoint => goal,
            _ => self.trajectory.at(if self.follows_setpoint { 0.0 } else { t }),
        }
    }

    /// Whether it follows the service's setpoints rather than a trajectory by the clock.
    pub(crate) fn follows_setpoint(&self) -> bool {
        self.follows_setpoint
    }

    /// A setpoint (x, y, θ: m, m, rad, W) from the service; ignored when following a trajectory
    /// by the clock.
    pub(crate) fn set_goal(&mut self, goal: [f64; 3]) {
        if self.follows_setpoint && goal.iter().all(|v| v.is_finite()) {
            self.setpoint = Some(goal);
        }
    }

    /// The table's residual acceleration at `p` (m/s², W).
    pub(crate) fn residual_acceleration(&self, p: &Vector2<f64>) -> Vector2<f64> {
        let mut a = Vector2::from(self.cfg.residual);
        for b in &self.cfg.bumps {
            let d2 = (p - Vector2::from(b.centre)).norm_squared();
            a += Vector2::from(b.accel) * (-d2 / (2.0 * b.radius * b.radius)).exp();
        }
        a
    }

    /// Advances `dt` seconds to time `t`. `measured` is the latest tracked robot-base pose (x, y, θ)
    /// the PID loops see; `tcp` and `tcp_accel` are the nozzle's position (m, W) and acceleration
    /// (m/s², W), whose reaction and filament tension push the flyer.
    pub(crate) fn step(
        &mut self,
        t: f64,
        dt: f64,
        measured: Option<[f64; 3]>,
        tcp: &Vector3<f64>,
        tcp_accel: &Vector3<f64>,
        noise: &mut Gaussian,
    ) {
        let cfg = &self.cfg;
        // The PID loops run every pid_period on the tracked pose, in W; the thrust is held between.
        if t >= self.next_pid_s {
            let period = cfg.pid_period;
            self.next_pid_s = t + period;
            if let Some(m) = measured {
                let goal = self.planned(t);
                let filter = cfg.derivative_filter;
                let fx = self.pids[0].update(goal[0] - m[0], period, filter);
                let fy = self.pids[1].update(goal[1] - m[1], period, filter);
                let tz = self.pids[2].update(wrap(goal[2] - m[2]), period, filter);
                // W force → body frame, allocate, scale every thruster into its limit, back to W.
                let (s, c) = self.theta.sin_cos();
                let body = Vector3::new(c * fx + s * fy, -s * fx + c * fy, tz);
                let mut f = self.allocation * body;
                let worst = f.amax() / cfg.thruster_force.max(1e-12);
                self.saturation = worst;
                if worst > 1.0 {
                    f /= worst;
                }
                let w = self.layout * f;
                self.thrust = Vector3::new(c * w.x - s * w.y, s * w.x + c * w.y, w.z);
            }
        }
        // Filament tension: its slow variation is an Ornstein-Uhlenbeck process.
        let k = dt / cfg.tension_time;
        self.tension_dev += -k * self.tension_dev + cfg.tension_variation * (2.0 * k).sqrt() * noise.sample();
        let tension = (cfg.tension + self.tension_dev).max(0.0);
        let k = dt / cfg.residual_time;
        let kick = cfg.residual_variation * (2.0 * k).sqrt();
        self.residual_dev += -k * self.residual_dev + Vector2::new(kick * noise.sample(), kick * noise.sample());
        // 000 Eq. 6: τ = ‖r_robot + d_base‖ · F_tension, about the centre of mass.
        let lever = Vector2::new(tcp.x, tcp.y) - self.com;
        let tension_torque = lever.norm() * tension;
        // The arm pushes back on the base as it accelerates the nozzle.
        let reaction = -cfg.arm_reaction_mass * Vector2::new(tcp_accel.x, tcp_accel.y);
        let reaction_torque = lever.x * reaction.y - lever.y * reaction.x;
        let force =
            Vector2::new(self.thrust.x, self.thrust.y) + reaction + cfg.mass * (self.residual_acceleration(&self.com) + self.residual_dev);
        let torque = self.thrust.z + tension_torque + reaction_torque;
        // Semi-implicit Euler.
        self.velocity += force / cfg.mass * dt;
        self.omega += torque / cfg.inertia * dt;
        self.com += self.velocity * dt;
        self.theta += self.omega * dt;
    }
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;

    fn still() -> (Vector3<f64>, Vector3<f64>) {
        (Vector3::new(0.3, 0.0, 0.0), Vector3::zeros())
    }

    #[test]
    fn the_allocation_reproduces_the_wrench() {
        let f = Flyer::new(&FlyerConfig::default(), BaseTrajectory::stationary([0.0, 0.0, 0.0]), false, 0.25);
        let w = Vector3::new(1.5, -0.7, 0.3);
        assert!((f.layout * (f.allocation * w) - w).norm() < 1e-12);
        // Full thrust along x: 4 thrusters × 2 N over 266.7 kg ≈ 30 mm/s² (000).
        let full = f.allocation * Vector3::new(8.0, 0.0, 0.0);
        assert!((full.amax() - 2.0).abs() < 1e-12);
        assert!((8.0 / f.cfg.mass - 0.030).abs() < 1e-4);
    }

    #[test]
    fn the_pid_loops_hold_the_base_against_a_slope() {
        let cfg = FlyerConfig { residual: [2e-3, -1e-3], tension: 0.0, tension_variation: 0.0, ..Default::default() };
        let mut f = Flyer::new(&cfg, BaseTrajectory::stationary([1.0, 0.5, 0.2]), false, 0.25);
        let mut g = Gaussian::new(3);
        let (tcp, acc) = still();
        let dt = 0.001;
        let mut worst: f64 = 0.0;
        for k in 0..600_000 {
            let t = k as f64 * dt;
            let (p, th) = f.base_pose();
            f.step(t, dt, Some([p[0], p[1], th]), &tcp, &acc, &mut g);
            if t > 300.0 {
                worst = worst.max(((p[0] - 1.0).powi(2) + (p[1] - 0.5).powi(2)).sqrt());
            }
        }
        // The integral removes the slope's offset: after 300 s the base is within 1 mm.
        assert!(worst < 1e-3, "worst {worst}");
        let (_, th) = f.base_pose();
        assert!((th - 0.2).abs() < 1e-3);
    }

    #[test]
    fn thrust_saturates_at_thirty_millimetres_per_second_squared() {
        let cfg = FlyerConfig { tension: 0.0, tension_variation: 0.0, ..Default::default() };
        // A goal 10 m away: the PID asks for far more than the thrusters give.
        let mut f =
            Flyer::new(&cfg, BaseTrajectory::from_samples(vec![[0.0, 0.0, 0.0, 0.0], [1e-3, 10.0, 0.0, 0.0]]).unwrap(), false, 0.25);
        let mut g = Gaussian::new(1);
        let (tcp, acc) = still();
        for k in 0..2000 {
            let (p, th) = f.base_pose();
            f.step(k as f64 * 1e-3, 1e-3, Some([p[0], p[1], th]), &tcp, &acc, &mut g);
        }
        let a = f.velocity.x / 2.0;
        assert!((a - 0.030).abs() < 0.002, "mean acceleration {a} m/s²");
        assert!(f.saturation > 1.0);
    }

    #[test]
    fn trajectories_interpolate_and_name_bad_lines() {
        let dir = std::env::temp_dir().join(format!("strand-traj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.csv");
        std::fs::write(&p, "t,tcp_x,base_x,base_y\n0,9,0,0\n2,9,1,0.5\n").unwrap();
        let t = BaseTrajectory::load(&p, 0.1).unwrap();
        assert_eq!(t.at(1.0), [0.5, 0.25, 0.1]);
        assert_eq!(t.at(5.0), [1.0, 0.5, 0.1]);
        std::fs::write(&p, "t,base_x,base_y\n0,0,0\n1,x,0\n").unwrap();
        let e = BaseTrajectory::load(&p, 0.0).unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("base_x"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
