//! The robot base's pose in the world, and the world → base correction of every target (000
//! Sections 2.1, 4.1, 4.2).
//!
//! A fixed robot's base pose is its mount transform from the config. A robot on a moving base (000's
//! free-flyer) is tracked: pose samples arrive at their own rate (120-360 Hz) and latency, each
//! stamped with the time it was *measured*. A constant-velocity estimator turns them into a pose and
//! twist that can be predicted to any time, in particular to the time the next joint command takes
//! effect; 000 blames part of its error on a delayed, noisy velocity from a moving average, which is
//! why the default is an alpha-beta filter and why the others exist (for comparison):
//!
//! - `alpha-beta`: p̂ = p + v·Δ, r = p_m − p̂, p = p̂ + α·r, v = v + (β/Δ)·r; the same on orientation
//!   with the rotation vector of q_m·q̂⁻¹ (in W) and the angular velocity ω.
//! - `moving-average` (000's method): the latest sample, predicted with the mean finite-difference
//!   velocity over the last `window` samples.
//! - `latest`: the latest sample as it is, no prediction: no latency compensation at all.
//!
//! The correction maps a world target into B: p_B = R_WBᵀ(p_W − p_b), q_B = q_WB⁻¹·q_W and, for the
//! velocity feed-forward, ẋ_B = R_WBᵀ(ẋ_W − v_b − ω_b × (p_W − p_b)), ω_B = R_WBᵀ(ω_W − ω_b).
//!
//! Everything here is deterministic and allocation-free; time comes in as arguments.

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::kin::{Frame, TcpTarget, geom};

/// How the base pose is known.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BaseMode {
    /// Bolted down: the mount transform from config; no tracking input needed.
    #[default]
    Fixed,
    /// On a moving base: BasePose samples from tracking, through the estimator.
    Tracked,
}

/// Which estimator turns tracking samples into a pose at the tick time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum EstimatorKind {
    /// Constant-velocity alpha-beta filter, predicted to the command time (the default).
    #[default]
    AlphaBeta,
    /// 000's method: latest sample plus a moving-average velocity.
    MovingAverage,
    /// Latest sample as measured: no latency compensation.
    Latest,
}

/// Samples the moving-average estimator keeps at most.
pub const MAX_WINDOW: usize = 64;

/// `[base]`: where the base is and how it is tracked.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaseConfig {
    /// Fixed or tracked.
    pub mode: BaseMode,
    /// Mount: base origin in W (m). For a tracked base, the pose assumed before the first sample.
    pub mount_xyz: [f64; 3],
    /// Mount orientation as roll, pitch, yaw (rad), fixed axes x, y, z.
    pub mount_rpy: [f64; 3],
    /// Estimator for a tracked base.
    pub estimator: EstimatorKind,
    /// Alpha-beta position gain α (0, 1].
    pub alpha: f64,
    /// Alpha-beta velocity gain β (0, 2).
    pub beta: f64,
    /// Moving-average window (samples, 2 to 64).
    pub window: usize,
    /// Tracking silent for longer than this (s) while a job moves: controlled stop, then fault.
    pub timeout: f64,
    /// Subtracted from each sample's stamp (s), for trackers that stamp on arrival, not capture.
    pub measurement_delay: f64,
    /// Longest prediction horizon (s); beyond it the estimate is held, not extrapolated.
    pub max_prediction: f64,
    /// Each new sample moves the estimate; the step is spread over this time (s) so the targets the
    /// arm follows stay continuous (a 0.2 mrad yaw step is a 0.1 mm jump half a metre out, which no
    /// joint could follow in one tick). 0 applies it at once.
    pub smoothing: f64,
}

impl Default for BaseConfig {
    fn default() -> Self {
        BaseConfig {
            mode: BaseMode::Fixed,
            mount_xyz: [0.0; 3],
            mount_rpy: [0.0; 3],
            estimator: EstimatorKind::AlphaBeta,
            // Critically damped (discount 0.7): α = 1 − 0.7², β = (1 − 0.7)².
            alpha: 0.51,
            beta: 0.09,
            window: 8,
            timeout: 0.1,
            measurement_delay: 0.0,
            max_prediction: 0.25,
            smoothing: 0.02,
        }
    }
}

impl BaseConfig {
    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), String> {
        for (key, v) in [("mount_xyz", self.mount_xyz), ("mount_rpy", self.mount_rpy)] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(format!("[base] {key}: values must be finite"));
            }
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(format!("[base] alpha = {}: must lie in (0, 1]", self.alpha));
        }
        if !(self.beta > 0.0 && self.beta < 2.0) {
            return Err(format!("[base] beta = {}: must lie in (0, 2)", self.beta));
        }
        if !(2..=MAX_WINDOW).contains(&self.window) {
            return Err(format!("[base] window = {}: must lie in 2..={MAX_WINDOW}", self.window));
        }
        if !(self.timeout.is_finite() && self.timeout > 0.0 && self.timeout <= 10.0) {
            return Err(format!("[base] timeout = {}: must lie in (0, 10] s", self.timeout));
        }
        if !(self.measurement_delay.is_finite() && (0.0..=1.0).contains(&self.measurement_delay)) {
            return Err(format!("[base] measurement_delay = {}: must lie in [0, 1] s", self.measurement_delay));
        }
        if !(self.smoothing.is_finite() && (0.0..=1.0).contains(&self.smoothing)) {
            return Err(format!("[base] smoothing = {}: must lie in [0, 1] s", self.smoothing));
        }
        if !(self.max_prediction.is_finite() && self.max_prediction > 0.0 && self.max_prediction <= 1.0) {
            return Err(format!("[base] max_prediction = {}: must lie in (0, 1] s", self.max_prediction));
        }
        Ok(())
    }

    /// The mount transform W → B.
    pub fn mount(&self) -> Frame {
        let [x, y, z] = self.mount_xyz;
        let [r, p, w] = self.mount_rpy;
        Frame::from_parts(Translation3::new(x, y, z), geom::rpy(r, p, w))
    }
}

/// The base's pose and twist at one time, in W.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BaseState {
    /// Base origin (m, W).
    pub position: Vector3<f64>,
    /// R_WB.
    pub orientation: UnitQuaternion<f64>,
    /// Linear velocity of the base origin (m/s, W).
    pub linear_velocity: Vector3<f64>,
    /// Angular velocity (rad/s, W).
    pub angular_velocity: Vector3<f64>,
}

impl BaseState {
    /// A base at rest at `frame`.
    pub fn at_rest(frame: &Frame) -> Self {
        BaseState {
            position: frame.translation.vector,
            orientation: UnitQuaternion::from_rotation_matrix(&frame.rotation),
            linear_velocity: Vector3::zeros(),
            angular_velocity: Vector3::zeros(),
        }
    }

    /// Maps a world-frame TCP target into the base frame, with the velocity feed-forward corrected
    /// for the base's own motion.
    pub fn world_to_base(&self, target_w: &TcpTarget) -> TcpTarget {
        let r_bw = self.orientation.inverse();
        let r = target_w.position - self.position;
        TcpTarget {
            position: r_bw * r,
            orientation: r_bw * target_w.orientation,
            linear_velocity: r_bw * (target_w.linear_velocity - self.linear_velocity - self.angular_velocity.cross(&r)),
            angular_velocity: r_bw * (target_w.angular_velocity - self.angular_velocity),
        }
    }

    /// Maps a base-frame position and orientation into W.
    pub fn base_to_world(&self, position_b: &Vector3<f64>, orientation_b: &UnitQuaternion<f64>) -> (Vector3<f64>, UnitQuaternion<f64>) {
        (self.position + self.orientation * position_b, self.orientation * orientation_b)
    }

    fn is_finite(&self) -> bool {
        self.position.iter().chain(self.linear_velocity.iter()).chain(self.angular_velocity.iter()).all(|x| x.is_finite())
            && self.orientation.coords.iter().all(|x| x.is_finite())
    }
}

/// Why a tracking sample was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseRejection {
    /// A NaN or infinite value, or a quaternion far from unit length.
    Invalid,
    /// Not newer than the last sample used (out of order or repeated).
    Stale,
}

/// The base estimator: fixed mount, or one of the tracking estimators. See the module docs.
#[derive(Clone, Debug)]
pub struct BaseEstimator {
    config: BaseConfig,
    mount: BaseState,
    /// The estimate at `time_ns` (the last sample's measurement time).
    estimate: BaseState,
    time_ns: u64,
    /// Measurement time of the last sample used (ns); None before the first.
    last_sample_ns: Option<u64>,
    /// Moving-average history: (time ns, position, orientation) ring.
    history: [(u64, Vector3<f64>, UnitQuaternion<f64>); MAX_WINDOW],
    history_len: usize,
    history_next: usize,
    samples: u64,
    rejected: u64,
    /// The step the last sample made in the estimate (position m, rotation vector rad, W), taken
    /// out again linearly over `smoothing` from `offset_ns`.
    offset_position: Vector3<f64>,
    offset_rotation: Vector3<f64>,
    offset_ns: u64,
}

impl BaseEstimator {
    /// An estimator at the mount pose. The config must have passed [`BaseConfig::validate`].
    pub fn new(config: &BaseConfig) -> Self {
        let mount = BaseState::at_rest(&config.mount());
        BaseEstimator {
            config: config.clone(),
            mount,
            estimate: mount,
            time_ns: 0,
            last_sample_ns: None,
            history: [(0, Vector3::zeros(), UnitQuaternion::identity()); MAX_WINDOW],
            history_len: 0,
            history_next: 0,
            samples: 0,
            rejected: 0,
            offset_position: Vector3::zeros(),
            offset_rotation: Vector3::zeros(),
            offset_ns: 0,
        }
    }

    /// Whether this base needs tracking input.
    pub fn is_tracked(&self) -> bool {
        self.config.mode == BaseMode::Tracked
    }

    /// Tracking timeout (s).
    pub fn timeout(&self) -> f64 {
        self.config.timeout
    }

    /// Samples used so far.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Samples refused so far.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    /// Measurement time of the last sample used (ns), if any.
    pub fn last_sample_ns(&self) -> Option<u64> {
        self.last_sample_ns
    }

    /// Age of the newest sample at `now_ns` (s); infinite before the first.
    pub fn age(&self, now_ns: u64) -> f64 {
        match self.last_sample_ns {
            Some(t) => now_ns.saturating_sub(t) as f64 * 1e-9,
            None => f64::INFINITY,
        }
    }

    /// Feeds one tracking sample that arrived at `now_ns`: position (m, W), orientation R_WB
    /// (w, x, y, z) measured at `stamp_ns` (before `measurement_delay` is subtracted). Ignored for a
    /// fixed base.
    pub fn update(&mut self, now_ns: u64, stamp_ns: u64, position: [f64; 3], orientation: [f64; 4]) -> Result<(), PoseRejection> {
        let before = self.at(now_ns);
        let had_estimate = self.last_sample_ns.is_some();
        self.apply_sample(stamp_ns, position, orientation)?;
        if had_estimate && self.config.smoothing > 0.0 {
            // Whatever of the step is left from the last sample is folded into the new one.
            self.offset_ns = now_ns;
            self.offset_position = Vector3::zeros();
            self.offset_rotation = Vector3::zeros();
            let after = self.at(now_ns);
            self.offset_position = before.position - after.position;
            self.offset_rotation = geom::quaternion_log(&(before.orientation * after.orientation.inverse()));
        }
        Ok(())
    }

    fn apply_sample(&mut self, stamp_ns: u64, position: [f64; 3], orientation: [f64; 4]) -> Result<(), PoseRejection> {
        if !self.is_tracked() {
            return Ok(());
        }
        let [w, x, y, z] = orientation;
        let norm = (w * w + x * x + y * y + z * z).sqrt();
        if !(position.iter().all(|v| v.is_finite()) && norm.is_finite() && (norm - 1.0).abs() < 1e-3) {
            self.rejected += 1;
            return Err(PoseRejection::Invalid);
        }
        let delay_ns = (self.config.measurement_delay * 1e9).round() as u64;
        let t = stamp_ns.saturating_sub(delay_ns);
        if self.last_sample_ns.is_some_and(|last| t <= last) {
            self.rejected += 1;
            return Err(PoseRejection::Stale);
        }
        let p_m = Vector3::from(position);
        let q_m = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        self.history[self.history_next] = (t, p_m, q_m);
        self.history_next = (self.history_next + 1) % self.config.window;
        self.history_len = (self.history_len + 1).min(self.config.window);
        let gap = self.last_sample_ns.map(|last| (t - last) as f64 * 1e-9);
        self.estimate = match (self.config.estimator, gap) {
            // First sample, or a gap long enough that the old velocity means nothing: start over.
            (_, None) => {
                BaseState { position: p_m, orientation: q_m, linear_velocity: Vector3::zeros(), angular_velocity: Vector3::zeros() }
            }
            (_, Some(g)) if g > self.config.timeout => {
                BaseState { position: p_m, orientation: q_m, linear_velocity: Vector3::zeros(), angular_velocity: Vector3::zeros() }
            }
            (EstimatorKind::AlphaBeta, Some(g)) => {
                let predicted = self.predicted(g);
                let (alpha, beta) = (self.config.alpha, self.config.beta);
                let r = p_m - predicted.position;
                let r_rot = geom::quaternion_log(&(q_m * predicted.orientation.inverse()));
                BaseState {
                    position: predicted.position + r * alpha,
                    orientation: geom::quaternion_exp(&(r_rot * alpha)) * predicted.orientation,
                    linear_velocity: predicted.linear_velocity + r * (beta / g),
                    angular_velocity: predicted.angular_velocity + r_rot * (beta / g),
                }
            }
            (EstimatorKind::MovingAverage, Some(_)) => {
                let (t0, p0, q0) = self.history[(self.history_next + self.config.window - self.history_len) % self.config.window];
                let span = (t - t0) as f64 * 1e-9;
                let (v, w) = if self.history_len >= 2 && span > 0.0 {
                    ((p_m - p0) / span, geom::quaternion_log(&(q_m * q0.inverse())) / span)
                } else {
                    (Vector3::zeros(), Vector3::zeros())
                };
                BaseState { position: p_m, orientation: q_m, linear_velocity: v, angular_velocity: w }
            }
            (EstimatorKind::Latest, Some(_)) => {
                BaseState { position: p_m, orientation: q_m, linear_velocity: Vector3::zeros(), angular_velocity: Vector3::zeros() }
            }
        };
        if !self.estimate.is_finite() {
            // Cannot happen with finite inputs and Δ > 0; never let it through if it does.
            self.estimate =
                BaseState { position: p_m, orientation: q_m, linear_velocity: Vector3::zeros(), angular_velocity: Vector3::zeros() };
        }
        self.time_ns = t;
        self.last_sample_ns = Some(t);
        self.samples += 1;
        Ok(())
    }

    /// The estimate `dt` seconds after the last sample, at constant velocity.
    fn predicted(&self, dt: f64) -> BaseState {
        let e = &self.estimate;
        BaseState {
            position: e.position + e.linear_velocity * dt,
            orientation: geom::quaternion_exp(&(e.angular_velocity * dt)) * e.orientation,
            linear_velocity: e.linear_velocity,
            angular_velocity: e.angular_velocity,
        }
    }

    /// The base's pose and twist at `time_ns`: the mount for a fixed base (or before the first
    /// sample); otherwise the estimate predicted forward (at most `max_prediction`; never backward).
    pub fn at(&self, time_ns: u64) -> BaseState {
        if !self.is_tracked() || self.last_sample_ns.is_none() {
            return self.mount;
        }
        let dt = (time_ns.saturating_sub(self.time_ns) as f64 * 1e-9).min(self.config.max_prediction);
        let mut state = match self.config.estimator {
            EstimatorKind::Latest => self.estimate,
            _ => self.predicted(dt),
        };
        let since = time_ns.saturating_sub(self.offset_ns) as f64 * 1e-9;
        if self.config.smoothing > 0.0 && since < self.config.smoothing {
            // Smoothstep: the step fades in with zero velocity at both ends.
            let u = since / self.config.smoothing;
            let w = 1.0 - u * u * (3.0 - 2.0 * u);
            let dw = -6.0 * u * (1.0 - u) / self.config.smoothing;
            state.position += self.offset_position * w;
            state.orientation = geom::quaternion_exp(&(self.offset_rotation * w)) * state.orientation;
            state.linear_velocity += self.offset_position * dw;
            state.angular_velocity += self.offset_rotation * dw;
        }
        state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tracked(kind: EstimatorKind) -> BaseEstimator {
        BaseEstimator::new(&BaseConfig { mode: BaseMode::Tracked, estimator: kind, ..BaseConfig::default() })
    }

    /// A base moving at constant velocity is predicted exactly once the filter has settled.
    #[test]
    fn alpha_beta_converges_on_constant_velocity() {
        let mut e = tracked(EstimatorKind::AlphaBeta);
        let v = Vector3::new(0.02, -0.01, 0.0);
        let w = 0.05;
        for k in 0..400u64 {
            let t = k * 5_000_000; // 200 Hz
            let ts = t as f64 * 1e-9;
            let p = v * ts;
            let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), w * ts);
            e.update(t, t, p.into(), [q.w, q.i, q.j, q.k]).unwrap();
        }
        let t = 399 * 5_000_000 + 30_000_000; // predicted 30 ms ahead
        let s = e.at(t);
        let ts = t as f64 * 1e-9;
        assert!((s.position - v * ts).norm() < 1e-9, "{:?}", s.position - v * ts);
        assert!((s.linear_velocity - v).norm() < 1e-9);
        assert!((s.angular_velocity.z - w).abs() < 1e-9);
        assert!(s.orientation.angle_to(&UnitQuaternion::from_axis_angle(&Vector3::z_axis(), w * ts)) < 1e-9);
    }

    #[test]
    fn stale_and_invalid_samples_are_refused() {
        let mut e = tracked(EstimatorKind::AlphaBeta);
        e.update(10, 10, [0.0; 3], [1.0, 0.0, 0.0, 0.0]).unwrap();
        assert_eq!(e.update(10, 10, [0.0; 3], [1.0, 0.0, 0.0, 0.0]), Err(PoseRejection::Stale));
        assert_eq!(e.update(20, 20, [f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]), Err(PoseRejection::Invalid));
        assert_eq!(e.update(30, 30, [0.0; 3], [2.0, 0.0, 0.0, 0.0]), Err(PoseRejection::Invalid));
        assert_eq!(e.rejected(), 3);
        assert_eq!(e.samples(), 1);
    }

    /// ẋ_B = R_WBᵀ(ẋ_W − v_b − ω × r): a target fixed in W seen from a spinning base.
    #[test]
    fn world_to_base_velocity_feed_forward() {
        let base = BaseState {
            position: Vector3::new(1.0, 0.0, 0.0),
            orientation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3),
            linear_velocity: Vector3::new(0.1, 0.0, 0.0),
            angular_velocity: Vector3::new(0.0, 0.0, 0.2),
        };
        let target = TcpTarget::at_rest(Vector3::new(1.5, 0.2, 0.1), UnitQuaternion::identity());
        let b = base.world_to_base(&target);
        // Finite difference of p_B over a small step of the base's motion.
        let h = 1e-6;
        let later = BaseState {
            position: base.position + base.linear_velocity * h,
            orientation: UnitQuaternion::from_scaled_axis(base.angular_velocity * h) * base.orientation,
            ..base
        };
        let fd = (later.world_to_base(&target).position - b.position) / h;
        assert!((fd - b.linear_velocity).norm() < 1e-5, "{fd:?} vs {:?}", b.linear_velocity);
        let (p, _) = base.base_to_world(&b.position, &b.orientation);
        assert!((p - target.position).norm() < 1e-12);
    }
}
