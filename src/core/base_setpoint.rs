//! The moving base's setpoint, read from its plan at the print's progress (`[base] plan`).
//!
//! 000 (Section 3.1) plans the free flyer's path from the job's timing and synchronises base and
//! arm "through one common trajectory". Played against the clock, that plan breaks as soon as the
//! nozzle's timing does: a pause, a feed override, a slow-down for a joint limit leave the base on
//! its schedule and the arm out of reach within a minute (a 50 % override at 250 s into the 100 cm
//! truss faulted `TcpErrorLimit` at 300 s). So the plan is carried as a function of *path
//! progress* — the path length the nozzle has covered since the job's first point, the path
//! engine's own arc length, planned timing or not — and read there every tick: a pause stops the
//! base with the nozzle, an override slows both, a resume starts both. Where the planned nozzle
//! stands still (a dwell), the plan holds the base too: a base that moved on while the path stood
//! would be a clock again.
//!
//! The plan's pose at the progress, P(s), is where the base should be; the setpoint moves there
//! within the base's own limits, with the plan's velocity (dP/ds · ṡ) fed forward and the rest
//! closed as a braking-distance-limited correction:
//!
//!   v_des = dP/ds·ṡ + ê · min(k·|e|, √(2·a_max·|e|)),  e = P(s) − p,  |v_des| ≤ v_max,
//!   v ← v + clamp(v_des − v, a_max·dt),  p ← p + v·dt
//!
//! (the same on yaw). The plan's own accelerations are within the limits at the planned timing
//! (it is a low-passed TCP path, 000 Fig. 4); what the path's jerk-limited stops and restarts ask
//! beyond them becomes a lag of millimetres, reported per tick (`BaseCommand::lag`) and taken up by
//! the arm, which corrects for the *measured* base (base.rs) as always. Deterministic and
//! allocation-free after construction: the plan is copied once.

use nalgebra::{UnitQuaternion, Vector2};
use strand_wire as ipc;

use crate::base::BaseConfig;
use crate::kin::geom;

/// Gain of the correction towards the plan where it is small (1/s): a 1 mm error closes at 2 mm/s.
/// Further out the braking distance bounds it (√(2·a·|e|)), so the base arrives without overshoot.
const CORRECTION_GAIN: f64 = 2.0;

/// Closer than this to a plan that stands (m, or rad for the yaw), the setpoint has arrived.
const ARRIVED: f64 = 1e-6;

/// The setpoint state: where the base is told to be, and how fast it goes there.
#[derive(Clone, Debug)]
pub(crate) struct BaseSetpoint {
    /// (s, x, y, yaw) rows: m of path, m, m, rad (W). At least one row; s strictly increasing.
    plan: Vec<[f64; 4]>,
    /// Height, roll and pitch of the mount (the plan moves the base in the plane).
    z: f64,
    roll: f64,
    pitch: f64,
    max_speed: f64,
    max_acceleration: f64,
    max_yaw_rate: f64,
    max_yaw_acceleration: f64,
    dt: f64,
    position: Vector2<f64>,
    velocity: Vector2<f64>,
    yaw: f64,
    yaw_rate: f64,
    progress: f64,
    lag: f64,
}

/// The plan read at one progress: the pose and its slope along the path.
struct PlanPoint {
    position: Vector2<f64>,
    yaw: f64,
    /// dP/ds (m/m) and dyaw/ds (rad/m).
    slope: Vector2<f64>,
    yaw_slope: f64,
}

impl BaseSetpoint {
    /// A setpoint for `cfg`'s plan at tick period `dt` (s), starting at rest at the mount; `None`
    /// without a plan. The plan is checked by [`BaseConfig::validate`].
    pub(crate) fn new(cfg: &BaseConfig, dt: f64) -> Option<Self> {
        if cfg.plan.is_empty() {
            return None;
        }
        let [x, y, z] = cfg.mount_xyz;
        let [roll, pitch, yaw] = cfg.mount_rpy;
        Some(BaseSetpoint {
            plan: cfg.plan.clone(),
            z,
            roll,
            pitch,
            max_speed: cfg.max_speed,
            max_acceleration: cfg.max_acceleration,
            max_yaw_rate: cfg.max_yaw_rate,
            max_yaw_acceleration: cfg.max_yaw_acceleration,
            dt,
            position: Vector2::new(x, y),
            velocity: Vector2::zeros(),
            yaw,
            yaw_rate: 0.0,
            progress: 0.0,
            lag: 0.0,
        })
    }

    /// The plan at progress `s` (m): linear between rows, held before the first and after the last
    /// (a binary search: O(log n), no allocation).
    fn read(&self, s: f64) -> PlanPoint {
        let n = self.plan.len();
        // The last row at or before s (the first when s is before it).
        let k = self.plan.partition_point(|r| r[0] <= s).saturating_sub(1);
        let a = self.plan[k];
        if k + 1 >= n || s <= a[0] {
            return PlanPoint { position: Vector2::new(a[1], a[2]), yaw: a[3], slope: Vector2::zeros(), yaw_slope: 0.0 };
        }
        let b = self.plan[k + 1];
        let ds = b[0] - a[0];
        let u = ((s - a[0]) / ds).clamp(0.0, 1.0);
        let slope = Vector2::new(b[1] - a[1], b[2] - a[2]) / ds;
        PlanPoint {
            position: Vector2::new(a[1], a[2]) + slope * (u * ds),
            yaw: a[3] + (b[3] - a[3]) * u,
            slope,
            yaw_slope: (b[3] - a[3]) / ds,
        }
    }

    /// One tick: the plan read at `progress` (m of path since the job's first point), moving along
    /// it at `rate` (m/s, the path's speed). `brake`: stop as fast as the limits allow and stay
    /// (an emergency stop, a latched fault), not back to the plan.
    pub(crate) fn step(&mut self, progress: f64, rate: f64, brake: bool) {
        let progress = if progress.is_finite() { progress.max(0.0) } else { self.progress };
        let rate = if rate.is_finite() { rate.max(0.0) } else { 0.0 };
        self.progress = progress;
        let target = self.read(progress);
        let mut error = target.position - self.position;
        self.lag = error.norm();
        let mut yaw_error = target.yaw - self.yaw;
        // Within a micrometre (a microradian) of a plan that stands: there. The correction would
        // otherwise creep on for ever, and a paused base must stand still, not crawl.
        if rate == 0.0 && self.lag <= ARRIVED {
            error = Vector2::zeros();
        }
        if rate == 0.0 && yaw_error.abs() <= ARRIVED {
            yaw_error = 0.0;
        }
        let (v_des, w_des) = if brake {
            (Vector2::zeros(), 0.0)
        } else {
            let mut v = target.slope * rate;
            let e = error.norm();
            if e > 0.0 {
                v += error / e * correction(e, self.max_acceleration);
            }
            let w = target.yaw_slope * rate + yaw_error.signum() * correction(yaw_error.abs(), self.max_yaw_acceleration);
            (v, w)
        };
        let v_des = if v_des.norm() > self.max_speed { v_des * (self.max_speed / v_des.norm()) } else { v_des };
        let w_des = w_des.clamp(-self.max_yaw_rate, self.max_yaw_rate);
        let dv = v_des - self.velocity;
        let dv_max = self.max_acceleration * self.dt;
        self.velocity += if dv.norm() > dv_max { dv * (dv_max / dv.norm()) } else { dv };
        let dw_max = self.max_yaw_acceleration * self.dt;
        self.yaw_rate += (w_des - self.yaw_rate).clamp(-dw_max, dw_max);
        self.position += self.velocity * self.dt;
        self.yaw += self.yaw_rate * self.dt;
    }

    /// How far the setpoint is from the plan's pose at `progress` (m, horizontal): 0 once the base
    /// has arrived there.
    pub(crate) fn distance_to(&self, progress: f64) -> f64 {
        (self.read(progress).position - self.position).norm()
    }

    /// The wire message for this tick.
    pub(crate) fn command(&self, seq: u64, stamp_ns: u64, tick: u64) -> ipc::BaseCommand {
        let q = UnitQuaternion::from_rotation_matrix(&geom::rpy(self.roll, self.pitch, self.yaw));
        ipc::BaseCommand {
            seq,
            stamp_ns,
            tick,
            position: [self.position.x, self.position.y, self.z],
            orientation: [q.w, q.i, q.j, q.k],
            velocity: [self.velocity.x, self.velocity.y, 0.0],
            angular_velocity: [0.0, 0.0, self.yaw_rate],
            progress: self.progress,
            lag: self.lag,
            valid: 1,
            _reserved: 0,
        }
    }
}

/// Speed of the correction towards a plan `distance` away (m or rad): proportional near it,
/// bounded by the speed from which `acceleration` still stops at it.
fn correction(distance: f64, acceleration: f64) -> f64 {
    (CORRECTION_GAIN * distance).min((2.0 * acceleration * distance).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(plan: Vec<[f64; 4]>) -> BaseConfig {
        BaseConfig { plan, max_speed: 0.05, max_acceleration: 0.02, max_yaw_rate: 0.1, max_yaw_acceleration: 0.05, ..BaseConfig::default() }
    }

    /// A plan along x: the base goes 0.1 m for each metre of path.
    fn straight() -> BaseSetpoint {
        BaseSetpoint::new(&config(vec![[0.0, 0.0, 0.0, 0.0], [10.0, 1.0, 0.0, 0.0]]), 0.004).unwrap()
    }

    #[test]
    fn without_a_plan_there_is_no_setpoint() {
        assert!(BaseSetpoint::new(&BaseConfig::default(), 0.004).is_none());
    }

    #[test]
    fn the_setpoint_follows_progress_not_time() {
        let mut b = straight();
        // 20 s at 20 mm/s of path: the plan moves 2 mm/s, well inside the limits.
        let mut s = 0.0;
        for _ in 0..5000 {
            s += 0.02 * 0.004;
            b.step(s, 0.02, false);
        }
        assert!((b.position.x - 0.04).abs() < 1e-4, "{}", b.position.x);
        // A pause: the path stops; so does the base, at the plan's point, whatever the time.
        for _ in 0..25_000 {
            b.step(s, 0.0, false);
        }
        assert!((b.position.x - 0.04).abs() < 1e-6 && b.velocity.norm() < 1e-9, "{} {}", b.position.x, b.velocity.norm());
        // Half the feed: half the base's speed.
        for _ in 0..2500 {
            s += 0.01 * 0.004;
            b.step(s, 0.01, false);
        }
        assert!((b.velocity.x - 0.001).abs() < 1e-6, "{}", b.velocity.x);
        assert!(b.lag < 1e-4, "{}", b.lag);
    }

    #[test]
    fn a_far_plan_is_reached_within_the_limits_and_without_overshoot() {
        let mut b = BaseSetpoint::new(&config(vec![[0.0, 0.3, -0.2, 0.5]]), 0.004).unwrap();
        let (mut v_prev, mut worst_a, mut worst_v, mut past) = (Vector2::zeros(), 0.0f64, 0.0f64, 0.0f64);
        for _ in 0..20_000 {
            b.step(0.0, 0.0, false);
            worst_a = worst_a.max((b.velocity - v_prev).norm() / 0.004);
            worst_v = worst_v.max(b.velocity.norm());
            v_prev = b.velocity;
            // Beyond the target along the line from the start.
            let d = Vector2::new(0.3, -0.2);
            past = past.max(b.position.dot(&d) / d.norm() - d.norm());
        }
        assert!(worst_v <= 0.05 + 1e-12 && worst_a <= 0.02 + 1e-9, "v {worst_v} a {worst_a}");
        assert!(past < 1e-4, "overshoot {past}");
        assert!(b.lag < 1e-6 && (b.yaw - 0.5).abs() < 1e-6, "{} {}", b.lag, b.yaw);
    }

    #[test]
    fn a_brake_stops_the_base_where_it_is() {
        let mut b = straight();
        let mut s = 0.0;
        for _ in 0..2500 {
            s += 0.2 * 0.004;
            b.step(s, 0.2, false);
        }
        let v0 = b.velocity.norm();
        assert!(v0 > 0.019, "{v0}");
        let mut n = 0;
        while b.velocity.norm() > 0.0 && n < 10_000 {
            b.step(s, 0.0, true);
            n += 1;
        }
        // v / a to stop, within a tick.
        assert!((n as f64 * 0.004 - v0 / 0.02).abs() <= 0.0041, "{n} ticks from {v0} m/s");
        let x = b.position.x;
        for _ in 0..1000 {
            b.step(s, 0.0, true);
        }
        assert_eq!(b.position.x, x);
    }

    #[test]
    fn progress_back_to_the_start_reads_the_plan_backwards() {
        let b = straight();
        assert!((b.read(7.5).position.x - 0.75).abs() < 1e-12);
        assert!((b.read(2.5).position.x - 0.25).abs() < 1e-12);
        assert_eq!(b.read(-1.0).position.x, 0.0);
        assert_eq!(b.read(11.0).position.x, 1.0);
        assert_eq!(b.read(11.0).slope.x, 0.0);
    }
}
