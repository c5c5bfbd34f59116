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
use crate::setting::InvalidSetting;

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

/// `[base] mount = { xyz, rpy }`: the base frame B's pose in W as one value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MountPose {
    /// The base origin in W (m).
    pub xyz: [f64; 3],
    /// The base orientation as roll, pitch, yaw (rad), fixed axes x, y, z.
    pub rpy: [f64; 3],
}

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
    /// The mount as one pose, `[base] mount = { xyz, rpy }` (m, rad): what `strand calibrate base`
    /// writes. The same keys as `mount_xyz`/`mount_rpy`, which it replaces (giving both is refused);
    /// [`BaseConfig::fold_mount`] moves it into them when a config is loaded, so everything else
    /// reads `mount_xyz`/`mount_rpy` and a log's effective config has those only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mount: Option<MountPose>,
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
    /// The base's planned path by the print's progress (base_setpoint.rs): rows `[s, x, y, yaw]`
    /// — s the path length since the job's first point (m, strictly increasing, from 0), then the
    /// base origin's x and y (m, W) and yaw (rad, about W's z) there. The service publishes a
    /// `BaseCommand` read from it every tick. Empty: no plan, no base command. Made by
    /// `strand-plan base --plan`; usually given as `plan_file`.
    pub plan: Vec<[f64; 4]>,
    /// A CSV file with the plan (header `s,base_x,base_y[,base_theta]`; m, m, m, rad), read into
    /// `plan` when the config is loaded (a relative path from the config file's folder). Empty: none.
    pub plan_file: String,
    /// The base setpoint's speed limit (m/s).
    pub max_speed: f64,
    /// The base setpoint's acceleration limit (m/s²); 000's free flyer: 30 mm/s² of thrust.
    pub max_acceleration: f64,
    /// The base setpoint's yaw rate limit (rad/s).
    pub max_yaw_rate: f64,
    /// The base setpoint's yaw acceleration limit (rad/s²).
    pub max_yaw_acceleration: f64,
}

impl Default for BaseConfig {
    fn default() -> Self {
        BaseConfig {
            mode: BaseMode::Fixed,
            mount_xyz: [0.0; 3],
            mount_rpy: [0.0; 3],
            mount: None,
            estimator: EstimatorKind::AlphaBeta,
            // Critically damped (discount 0.7): α = 1 − 0.7², β = (1 − 0.7)².
            alpha: 0.51,
            beta: 0.09,
            window: 8,
            timeout: 0.1,
            measurement_delay: 0.0,
            max_prediction: 0.25,
            smoothing: 0.02,
            plan: Vec::new(),
            plan_file: String::new(),
            max_speed: 0.1,
            max_acceleration: 0.02,
            max_yaw_rate: 0.2,
            max_yaw_acceleration: 0.05,
        }
    }
}

impl BaseConfig {
    /// Moves `mount = { xyz, rpy }` into `mount_xyz`/`mount_rpy` (call once, after parsing);
    /// refused, naming both forms, when the file gives the pose both ways.
    pub fn fold_mount(&mut self) -> Result<(), InvalidSetting> {
        let Some(pose) = self.mount.take() else { return Ok(()) };
        if self.mount_xyz != [0.0; 3] || self.mount_rpy != [0.0; 3] {
            return Err(InvalidSetting::new(
                "base",
                format!(
                    "[base] mount replaces mount_xyz and mount_rpy: give one form (mount = {{ xyz = {:?}, rpy = {:?} }}, \
                     mount_xyz = {:?}, mount_rpy = {:?})",
                    pose.xyz, pose.rpy, self.mount_xyz, self.mount_rpy
                ),
            ));
        }
        self.mount_xyz = pose.xyz;
        self.mount_rpy = pose.rpy;
        Ok(())
    }

    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if self.mount.is_some() {
            return Err(InvalidSetting::new(
                "base",
                "[base] mount: not moved into mount_xyz/mount_rpy (BaseConfig::fold_mount)".to_string(),
            ));
        }
        for (key, v) in [("mount_xyz", self.mount_xyz), ("mount_rpy", self.mount_rpy)] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(InvalidSetting::new("base", format!("[base] {key}: values must be finite")));
            }
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(InvalidSetting::new("base", format!("[base] alpha = {}: must lie in (0, 1]", self.alpha)));
        }
        if !(self.beta > 0.0 && self.beta < 2.0) {
            return Err(InvalidSetting::new("base", format!("[base] beta = {}: must lie in (0, 2)", self.beta)));
        }
        if !(2..=MAX_WINDOW).contains(&self.window) {
            return Err(InvalidSetting::new("base", format!("[base] window = {}: must lie in 2..={MAX_WINDOW}", self.window)));
        }
        if !(self.timeout.is_finite() && self.timeout > 0.0 && self.timeout <= 10.0) {
            return Err(InvalidSetting::new("base", format!("[base] timeout = {}: must lie in (0, 10] s", self.timeout)));
        }
        if !(self.measurement_delay.is_finite() && (0.0..=1.0).contains(&self.measurement_delay)) {
            return Err(InvalidSetting::new(
                "base",
                format!("[base] measurement_delay = {}: must lie in [0, 1] s", self.measurement_delay),
            ));
        }
        if !(self.smoothing.is_finite() && (0.0..=1.0).contains(&self.smoothing)) {
            return Err(InvalidSetting::new("base", format!("[base] smoothing = {}: must lie in [0, 1] s", self.smoothing)));
        }
        if !(self.max_prediction.is_finite() && self.max_prediction > 0.0 && self.max_prediction <= 1.0) {
            return Err(InvalidSetting::new("base", format!("[base] max_prediction = {}: must lie in (0, 1] s", self.max_prediction)));
        }
        for (key, v, unit) in [
            ("max_speed", self.max_speed, "m/s"),
            ("max_acceleration", self.max_acceleration, "m/s²"),
            ("max_yaw_rate", self.max_yaw_rate, "rad/s"),
            ("max_yaw_acceleration", self.max_yaw_acceleration, "rad/s²"),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 100.0) {
                return Err(InvalidSetting::new("base", format!("[base] {key} = {v}: must lie in (0, 100] {unit}")));
            }
        }
        self.validate_plan()?;
        Ok(())
    }

    /// The plan's rows: finite, s from 0 and strictly increasing, the yaw turning less than π
    /// from one row to the next (unwrapped). The message names the row (1-based).
    fn validate_plan(&self) -> Result<(), InvalidSetting> {
        let from = if self.plan_file.is_empty() { String::new() } else { format!(" (from {})", self.plan_file) };
        if !self.plan.is_empty() && self.mode != BaseMode::Tracked {
            return Err(InvalidSetting::new(
                "base",
                format!("[base] plan{from}: a base that moves is tracked: set mode = \"tracked\" (the arm corrects for its measured pose)"),
            ));
        }
        let bad = |k: usize, why: &str| Err(InvalidSetting::new("base", format!("[base] plan{from}: row {}: {why}", k + 1)));
        for (k, row) in self.plan.iter().enumerate() {
            if row.iter().any(|v| !v.is_finite()) {
                return bad(k, "values must be finite");
            }
            if k == 0 && row[0] != 0.0 {
                return bad(k, &format!("s = {} m: the plan starts at the job's first point, s = 0", row[0]));
            }
            if k > 0 {
                let before = self.plan[k - 1];
                if row[0] <= before[0] {
                    return bad(k, &format!("s = {} m after {} m: s must increase", row[0], before[0]));
                }
                if (row[3] - before[3]).abs() >= std::f64::consts::PI {
                    return bad(k, &format!("yaw {} rad after {} rad: unwrap the yaw (less than π a row)", row[3], before[3]));
                }
            }
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
        (self.point_to_world(position_b), self.orientation * orientation_b)
    }

    /// Maps a base-frame position (m) into W (m): [`BaseState::base_to_world`]'s position, for a
    /// caller with no orientation to map (the tick's TCPs: a rotation matrix turned into a
    /// quaternion only to be dropped costs tens of nanoseconds).
    pub fn point_to_world(&self, position_b: &Vector3<f64>) -> Vector3<f64> {
        self.position + self.orientation * position_b
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
    /// The last estimates, newest last, each with the time it arrived (ns): the output blends from
    /// the one before into each over `smoothing` (see [`BaseEstimator::at`]).
    blends: [Blend; MAX_BLENDS],
    blends_len: usize,
    blends_next: usize,
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
            blends: [Blend { arrived_ns: 0, time_ns: 0, estimate: mount }; MAX_BLENDS],
            blends_len: 0,
            blends_next: 0,
        }
    }

    /// Whether this base needs tracking input.
    pub(crate) fn is_tracked(&self) -> bool {
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
        self.apply_sample(stamp_ns, position, orientation)?;
        if self.is_tracked() {
            self.blends[self.blends_next] = Blend { arrived_ns: now_ns, time_ns: self.time_ns, estimate: self.estimate };
            self.blends_next = (self.blends_next + 1) % MAX_BLENDS;
            self.blends_len = (self.blends_len + 1).min(MAX_BLENDS);
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
        straight_line(&self.estimate, dt)
    }

    /// What one estimate says about `time_ns`: predicted forward at its velocity (at most
    /// `max_prediction`; never backward), or held as it is for `latest`.
    fn estimate_at(&self, blend: &Blend, time_ns: u64) -> BaseState {
        match self.config.estimator {
            EstimatorKind::Latest => blend.estimate,
            _ => {
                let dt = (time_ns.saturating_sub(blend.time_ns) as f64 * 1e-9).min(self.config.max_prediction);
                straight_line(&blend.estimate, dt)
            }
        }
    }

    /// The base's pose and twist at `time_ns`: the mount for a fixed base (or before the first
    /// sample); otherwise the estimate predicted forward (at most `max_prediction`; never backward).
    pub fn at(&self, time_ns: u64) -> BaseState {
        if !self.is_tracked() || self.last_sample_ns.is_none() || self.blends_len == 0 {
            return self.mount;
        }
        let newest = (self.blends_next + MAX_BLENDS - 1) % MAX_BLENDS;
        let smoothing_ns = (self.config.smoothing * 1e9) as u64;
        // Walk back to the newest estimate whose blend is over (or the oldest kept): the output is
        // that estimate, blended forward into each later one in turn.
        let mut depth = 0;
        while depth + 1 < self.blends_len {
            let b = &self.blends[(newest + MAX_BLENDS - depth) % MAX_BLENDS];
            if time_ns.saturating_sub(b.arrived_ns) >= smoothing_ns {
                break;
            }
            depth += 1;
        }
        let first = (newest + MAX_BLENDS - depth) % MAX_BLENDS;
        let mut state = self.estimate_at(&self.blends[first], time_ns);
        for k in (0..depth).rev() {
            let b = &self.blends[(newest + MAX_BLENDS - k) % MAX_BLENDS];
            let since = time_ns.saturating_sub(b.arrived_ns) as f64 * 1e-9;
            state = blend_into(&state, &self.estimate_at(b, time_ns), since, self.config.smoothing);
        }
        state
    }
}

/// How many recent estimates the blend keeps: a sample arriving while this many are still blending
/// starts from the oldest kept one as it is (at 120 Hz that takes a `smoothing` over 130 ms).
const MAX_BLENDS: usize = 16;

/// One estimate and when it came.
#[derive(Clone, Copy, Debug)]
struct Blend {
    /// When the sample arrived (ns): its blend starts here.
    arrived_ns: u64,
    /// The time the estimate is for (the sample's measurement time, ns).
    time_ns: u64,
    estimate: BaseState,
}

/// A state moved on `dt` seconds at constant velocity.
fn straight_line(e: &BaseState, dt: f64) -> BaseState {
    BaseState {
        position: e.position + e.linear_velocity * dt,
        orientation: geom::quaternion_exp(&(e.angular_velocity * dt)) * e.orientation,
        linear_velocity: e.linear_velocity,
        angular_velocity: e.angular_velocity,
    }
}

/// `from` blended into `to`, `since` seconds into a blend `length` s long (u = since/length):
/// x = x_to + w·(x_from −
/// x_to) with the smoothstep weight w = 1 − 3u² + 2u³, whose rate is 0 at both ends. At u = 0 this is
/// `from` in position and velocity, at u ≥ 1 it is `to`: a new sample never steps the pose or the
/// twist the arm must follow (a step in either asks the joints for an unbounded acceleration). The
/// rotation uses the rotation vector of the (small) difference.
fn blend_into(from: &BaseState, to: &BaseState, since: f64, length: f64) -> BaseState {
    let u = since / length;
    if u.is_nan() || u >= 1.0 {
        return *to;
    }
    let u = u.max(0.0);
    let w = 1.0 - u * u * (3.0 - 2.0 * u);
    let dw = -6.0 * u * (1.0 - u) / length;
    let gap_position = from.position - to.position;
    let gap_rotation = geom::quaternion_log(&(from.orientation * to.orientation.inverse()));
    BaseState {
        position: to.position + gap_position * w,
        orientation: geom::quaternion_exp(&(gap_rotation * w)) * to.orientation,
        linear_velocity: to.linear_velocity + (from.linear_velocity - to.linear_velocity) * w + gap_position * dw,
        angular_velocity: to.angular_velocity + (from.angular_velocity - to.angular_velocity) * w + gap_rotation * dw,
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
    fn the_mount_as_one_pose_is_the_two_keys_and_not_both() {
        let pose = MountPose { xyz: [1.0, -0.5, 0.2], rpy: [0.0, 0.1, 1.2] };
        let mut one = BaseConfig { mount: Some(pose), ..BaseConfig::default() };
        assert!(one.validate().is_err(), "validated before the fold");
        one.fold_mount().unwrap();
        let two = BaseConfig { mount_xyz: pose.xyz, mount_rpy: pose.rpy, ..BaseConfig::default() };
        assert_eq!(one, two);
        one.validate().unwrap();
        let mut both = BaseConfig { mount: Some(pose), mount_xyz: [0.1, 0.0, 0.0], ..BaseConfig::default() };
        let e = both.fold_mount().unwrap_err().to_string();
        assert!(e.contains("[base] mount replaces mount_xyz and mount_rpy"), "{e}");
    }

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

    /// Noisy samples at 120 Hz: at each sample's arrival the output's position and velocity do not
    /// step (read 1 µs before and after it, they agree to what 1 µs of bounded acceleration allows),
    /// and once its blend is over the output is that estimate's own straight line.
    #[test]
    fn a_sample_steps_neither_position_nor_velocity() {
        for kind in [EstimatorKind::AlphaBeta, EstimatorKind::MovingAverage, EstimatorKind::Latest] {
            let mut e = tracked(kind);
            let period_ns = 8_333_333u64;
            let (mut worst_dp, mut worst_dv) = (0.0f64, 0.0f64);
            for k in 1..200u64 {
                let now = k * period_ns;
                // ±0.2 mm and ±1 mrad of alternating noise on a base drifting at 5 mm/s.
                let noise = if k % 2 == 0 { 2e-4 } else { -2e-4 };
                let p = [0.005 * now as f64 * 1e-9 + noise, -noise, 0.0];
                let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), noise * 5.0);
                let before = e.at(now - 1_000);
                e.update(now, now, p, [q.w, q.i, q.j, q.k]).unwrap();
                let after = e.at(now + 1_000);
                if k > 1 {
                    worst_dp = worst_dp.max((after.position - before.position - before.linear_velocity * 2e-6).norm());
                    worst_dv = worst_dv.max((after.linear_velocity - before.linear_velocity).norm());
                    let turn = (after.orientation * before.orientation.inverse()).angle();
                    assert!(turn < 1e-6, "{kind:?}: orientation stepped by {turn} rad");
                }
            }
            assert!(worst_dv < 1e-4, "{kind:?}: velocity stepped by {worst_dv} m/s at a sample");
            assert!(worst_dp < 1e-9, "{kind:?}: position stepped by {worst_dp} m at a sample");
            // 20 ms (the smoothing) after the last sample the output is that estimate's own.
            let last = 199 * period_ns;
            let own = e.estimate_at(&e.blends[(e.blends_next + MAX_BLENDS - 1) % MAX_BLENDS], last + 25_000_000);
            assert!((e.at(last + 25_000_000).position - own.position).norm() < 1e-15);
        }
    }
}
