//! Singularity-robust closed-loop inverse kinematics: one call per control tick turns a TCP target into
//! the next joint command, within the joint limits.
//!
//! The law is 002's Eq. 17, generalised:
//!
//! ```text
//! q̇ = J#(ẋ_ref + K·e) + N·(k₀∇w + k_jl∇h_jl),   q_{k+1} = q_k + q̇·dt
//! ```
//!
//! Conventions:
//! - The target is the TCP pose and twist (base frame) for the time the command takes effect, t_{k+1}.
//!   The error is the *predicted* one, e = x_ref(t_{k+1}) ⊖ x(q_k) − ẋ_ref·dt ≈ x_ref(t_k) ⊖ x(q_k), so
//!   002's e = x − x_ref appears here with the opposite sign and +K. With K·dt = 1 the step lands on the
//!   next target up to the second-order FK term (a Newton step); the effective gain is min(K, 1/dt).
//! - Orientation error: the rotation vector of R_ref·Rᵀ (the log map through the quaternion q_ref ⊗ q̄,
//!   shorter way round), in the base frame. In the 5-D printing task it is the smallest rotation turning
//!   the nozzle axis onto the target's nozzle axis, projected on the two axes perpendicular to the nozzle.
//! - J# is damped least squares applied per singular value (numerical filtering, Chiaverini 1997 /
//!   Maciejewski & Klein 1988): J# = Σ σ_k/(σ_k² + λ_k²) v_k u_kᵀ with λ_k² = λ_max²(1 − (σ_k/ε)²)² for
//!   σ_k < ε and 0 otherwise. Away from singularities J# is the exact pseudoinverse, so tracking is
//!   exact; near one, only the vanishing directions are damped and joint speeds stay bounded. The null
//!   space projector N = I − J#J = I − Σ σ_k²/(σ_k² + λ_k²) v_k v_kᵀ is the one consistent with it.
//! - Secondary objectives (null space): the task manipulability w (002 Eq. 16) and a joint-limit margin
//!   h_jl = −½ Σ (d_i/m_i)², where d_i is how far joint i has entered a margin m_i next to a limit (zero in
//!   the free middle of the range). Their joint speed is capped per joint at a fraction of the limit.
//!   The manipulability term ascends ln w: its gradient ∇w/w points where 002's ∇w points, but its
//!   size does not depend on the arm's size (w is ~0.1 m³ on an iiwa, ~0.007 on a VP6242), so one gain
//!   suits every robot, and it pushes harder the closer the arm comes to a singularity.
//! - Joint position limits: a joint whose step would cross its position bound (including the distance
//!   it needs to brake at its acceleration limit) is saturated at that bound and the task is re-solved
//!   with the remaining joints (saturation in the null space, after Flacco et al. 2012), so a joint is
//!   never driven past its limit and the others keep the TCP on target where they can.
//! - Velocity and acceleration limits: the whole q̇ is scaled by one factor s ∈ [0, 1] (direction kept);
//!   `scale` reports s so the path timing can slow down instead of leaving the path. Only when no
//!   common factor exists (braking from a speed the new direction cannot keep) is each joint clamped on
//!   its own; that is reported as `at_limit`.
//!
//! A step is deterministic (no hidden state beyond the previous q̇ and the SVD warm start, both part of
//! [`Clik`]) and does not allocate.

use nalgebra::{UnitQuaternion, Vector3};

use super::fk::ChainState;
use super::geom;
use super::model::{JointVector, MAX_JOINTS, RobotModel};
use super::svd::{MAX_TASK, Svd, identity_start, svd};
use super::task::{Task, TaskJacobian, manipulability_gradient};

/// Tuning of the CLIK step.
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClikConfig {
    /// Task to follow: `pose6` or `print5` (rotation about the nozzle free; the default for printing).
    pub task: Task,
    /// Diagonal of K (1/s): x, y, z, then rotation about x, y, z (in the 5-D task the first two rotation
    /// gains act on the two axes perpendicular to the nozzle). Capped at 1/dt.
    pub gains: [f64; 6],
    /// ε: the singular value (task units: m per rad for position rows) below which damping starts.
    pub sigma_threshold: f64,
    /// λ_max: the damping reached at σ = 0 (same units as σ).
    pub damping_max: f64,
    /// k₀: gain on the manipulability objective (rad²/s): q̇₀ = k₀∇(ln w) = k₀∇w/w.
    pub manipulability_gain: f64,
    /// k_jl: gain on the joint-limit margin gradient (rad²/s, q̇ = k_jl∇h_jl).
    pub joint_limit_gain: f64,
    /// Width of the margin next to each position limit, as a fraction of the joint's range (0–0.5).
    pub joint_limit_margin: f64,
    /// Cap on each joint's null-space speed, as a fraction of its velocity limit (0–1).
    pub nullspace_speed_fraction: f64,
    /// Cap on the position feedback |K·e| (m/s): a large error (an unreachable target, a resumed job)
    /// is closed at this speed instead of in one Newton step, which keeps the step in the region where
    /// the linearisation holds. Tracking errors are micrometres, far below it.
    pub max_correction_speed: f64,
    /// Cap on the orientation feedback |K·e| (rad/s).
    pub max_correction_rate: f64,
}

impl Default for ClikConfig {
    fn default() -> Self {
        ClikConfig {
            task: Task::Print5,
            gains: [1000.0; 6],
            sigma_threshold: 0.04,
            damping_max: 0.04,
            manipulability_gain: 0.5,
            joint_limit_gain: 0.5,
            joint_limit_margin: 0.1,
            nullspace_speed_fraction: 0.2,
            max_correction_speed: 0.1,
            max_correction_rate: 0.5,
        }
    }
}

impl ClikConfig {
    /// Checks ranges; the error names the offending key.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v >= 0.0;
        if let Some(i) = self.gains.iter().position(|g| !(g.is_finite() && *g > 0.0)) {
            return Err(format!("clik.gains[{i}] = {} must be finite and > 0 (1/s)", self.gains[i]));
        }
        if !(self.sigma_threshold.is_finite() && self.sigma_threshold > 0.0) {
            return Err(format!("clik.sigma_threshold = {} must be finite and > 0", self.sigma_threshold));
        }
        if !(self.damping_max.is_finite() && self.damping_max > 0.0) {
            return Err(format!("clik.damping_max = {} must be finite and > 0", self.damping_max));
        }
        for (key, v) in [("clik.manipulability_gain", self.manipulability_gain), ("clik.joint_limit_gain", self.joint_limit_gain)] {
            if !pos(v) {
                return Err(format!("{key} = {v} must be finite and ≥ 0"));
            }
        }
        if !(self.joint_limit_margin >= 0.0 && self.joint_limit_margin <= 0.5) {
            return Err(format!("clik.joint_limit_margin = {} must lie in [0, 0.5]", self.joint_limit_margin));
        }
        for (key, v) in [("clik.max_correction_speed", self.max_correction_speed), ("clik.max_correction_rate", self.max_correction_rate)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{key} = {v} must be finite and > 0"));
            }
        }
        if !(self.nullspace_speed_fraction >= 0.0 && self.nullspace_speed_fraction <= 1.0) {
            return Err(format!("clik.nullspace_speed_fraction = {} must lie in [0, 1]", self.nullspace_speed_fraction));
        }
        Ok(())
    }
}

/// What the TCP should do at the time the command takes effect. Base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TcpTarget {
    /// TCP position (m).
    pub position: Vector3<f64>,
    /// TCP orientation (unit quaternion w, x, y, z); in the 5-D task only its z axis (the nozzle) counts.
    pub orientation: UnitQuaternion<f64>,
    /// TCP linear velocity (m/s).
    pub linear_velocity: Vector3<f64>,
    /// TCP angular velocity (rad/s).
    pub angular_velocity: Vector3<f64>,
}

impl TcpTarget {
    /// A target at rest.
    pub fn at_rest(position: Vector3<f64>, orientation: UnitQuaternion<f64>) -> Self {
        TcpTarget { position, orientation, linear_velocity: Vector3::zeros(), angular_velocity: Vector3::zeros() }
    }
}

/// Flags describing one step. All false means the step tracked the target exactly, unscaled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClikStatus {
    /// Velocity or acceleration limits scaled the step (`scale` < 1).
    pub scaled: bool,
    /// The smallest task singular value was below the damping threshold.
    pub near_singular: bool,
    /// A joint was held at a position bound, or joints had to be clamped one by one.
    pub at_limit: bool,
    /// The target (or dt) held a non-finite number, or the solve produced one: the step ignored the
    /// target and braked within the acceleration limits instead.
    pub invalid_input: bool,
}

impl ClikStatus {
    /// No flag set.
    pub fn is_ok(&self) -> bool {
        !(self.scaled || self.near_singular || self.at_limit || self.invalid_input)
    }
}

/// The result of one step.
#[derive(Clone, Copy, Debug)]
pub struct ClikStep {
    /// Joint command for t_{k+1} (rad or m). Always within the position limits and finite.
    pub q: JointVector,
    /// Joint velocity of the step (rad/s or m/s), (q_{k+1} − q_k)/dt.
    pub qd: JointVector,
    /// Common factor applied for velocity and acceleration limits (1 = none).
    pub scale: f64,
    /// Flags.
    pub status: ClikStatus,
    /// Smallest singular value of the task Jacobian (task units).
    pub sigma_min: f64,
    /// Task manipulability √det(JJᵀ) at q_k.
    pub manipulability: f64,
    /// Damping λ applied to the smallest singular value.
    pub damping: f64,
    /// Norm of the position error the step corrected (m).
    pub position_error: f64,
    /// Norm of the orientation error the step corrected (rad).
    pub orientation_error: f64,
    /// Bit i set: joint i was saturated at a position bound.
    pub saturated: u8,
}

/// The CLIK solver: its configuration and the little state carried from tick to tick.
#[derive(Clone, Debug)]
pub struct Clik {
    config: ClikConfig,
    qd_prev: JointVector,
    svd_start: [[f64; MAX_TASK]; MAX_TASK],
    state: ChainState,
}

fn damping_sq(sigma: f64, eps: f64, lambda_max: f64) -> f64 {
    if sigma >= eps {
        0.0
    } else {
        let r = 1.0 - (sigma / eps) * (sigma / eps);
        lambda_max * lambda_max * r * r
    }
}

/// Velocity bounds (lower, upper) that keep joint i inside [lo, hi] this tick and able to brake at
/// `acc` before reaching either bound. `q` outside the range yields a bound that moves it back.
fn position_velocity_bounds(q: f64, lo: f64, hi: f64, vmax: f64, acc: f64, dt: f64) -> (f64, f64) {
    // Farther from a limit than a stop from full speed needs, position does not bound the speed.
    let free = vmax * vmax / (2.0 * acc) + vmax * dt;
    let brake = |d: f64| if d > free { f64::INFINITY } else { braking_speed(d, acc, dt) };
    let upper = if !hi.is_finite() {
        f64::INFINITY
    } else if q <= hi {
        ((hi - q) / dt).min(brake(hi - q))
    } else {
        (hi - q) / dt
    };
    let lower = if !lo.is_finite() {
        f64::NEG_INFINITY
    } else if q >= lo {
        ((lo - q) / dt).max(-brake(q - lo))
    } else {
        (lo - q) / dt
    };
    (lower, upper)
}

/// The largest speed (rad/s or m/s) from which a joint, one tick of `dt` at a time and slowing by at
/// most `acc·dt` per tick, stops within the distance `d`: the sequence v, v − a·dt, …, v − k·a·dt covers
/// exactly d with its last term in [0, a·dt]. Following it, one tick later the bound is exactly v − a·dt,
/// so braking never needs more than the acceleration limit.
pub fn braking_speed(d: f64, acc: f64, dt: f64) -> f64 {
    if d <= 0.0 {
        return 0.0;
    }
    if !acc.is_finite() {
        return f64::INFINITY;
    }
    let ad = acc * dt;
    // Continuous estimate v²/(2a) + v·dt/2 = d gives the number of whole braking ticks k.
    let h = 0.5 * ad;
    let estimate = -h + (h * h + 2.0 * acc * d).sqrt();
    let mut k = (estimate / ad).floor().max(0.0);
    let speed = |k: f64| (d / dt + ad * k * (k + 1.0) * 0.5) / (k + 1.0);
    let mut v = speed(k);
    for _ in 0..4 {
        if v - k * ad > ad {
            k += 1.0;
        } else if v - k * ad < 0.0 && k > 0.0 {
            k -= 1.0;
        } else {
            break;
        }
        v = speed(k);
    }
    v
}

impl Clik {
    /// A solver for a chain at rest.
    pub fn new(config: ClikConfig) -> Self {
        Clik { config, qd_prev: JointVector::zeros(), svd_start: identity_start(), state: ChainState::new(0) }
    }

    /// The configuration.
    pub fn config(&self) -> &ClikConfig {
        &self.config
    }

    /// Forgets the history: the next step starts from joint velocity `qd` (rad/s or m/s).
    pub fn reset(&mut self, qd: JointVector) {
        self.qd_prev = qd;
        self.svd_start = identity_start();
    }

    /// The joint velocity of the last step (rad/s or m/s).
    pub fn last_velocity(&self) -> &JointVector {
        &self.qd_prev
    }

    /// FK and Jacobian at the q of the last step (before it moved).
    pub fn last_state(&self) -> &ChainState {
        &self.state
    }

    /// One tick: from the current command `q` (rad or m; finite, within limits: it is the controller's
    /// own last command) towards `target`, over `dt` seconds (> 0). A target holding NaN or ±∞ is not
    /// followed: the arm brakes at its acceleration limits and `invalid_input` is set. The returned
    /// command is always finite and within the position limits.
    pub fn step(&mut self, model: &RobotModel, q: &JointVector, target: &TcpTarget, dt: f64) -> ClikStep {
        let cfg = self.config;
        let n = model.dof();
        debug_assert!(q.iter().all(|x| x.is_finite()), "CLIK needs a finite q");
        model.kinematics(q, &mut self.state);
        let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
        let target_ok = finite(&target.position)
            && finite(&target.linear_velocity)
            && finite(&target.angular_velocity)
            && target.orientation.coords.iter().all(|x| x.is_finite());
        if !(dt.is_finite() && dt > 0.0) {
            // Without a tick length nothing can be integrated: hold, and say so.
            self.qd_prev = JointVector::zeros();
            return ClikStep {
                q: *q,
                qd: JointVector::zeros(),
                scale: 0.0,
                status: ClikStatus { invalid_input: true, ..ClikStatus::default() },
                sigma_min: 0.0,
                manipulability: 0.0,
                damping: 0.0,
                position_error: 0.0,
                orientation_error: 0.0,
                saturated: 0,
            };
        }
        let hold;
        let target = if target_ok {
            target
        } else {
            hold = TcpTarget::at_rest(self.state.tcp.translation.vector, UnitQuaternion::from_rotation_matrix(&self.state.tcp.rotation));
            &hold
        };
        let state = &self.state;
        let tj = TaskJacobian::new(state, cfg.task);
        let m = tj.m;

        // Predicted error, e = x_ref(t_{k+1}) ⊖ x(q_k) − ẋ_ref·dt.
        let e_pos = target.position - state.tcp.translation.vector - target.linear_velocity * dt;
        let rot = state.tcp.rotation;
        let e_rot_full = match cfg.task {
            Task::Pose6 => geom::quaternion_log(&(target.orientation * UnitQuaternion::from_rotation_matrix(&rot).inverse())),
            Task::Print5 => {
                let axis = rot.matrix().column(2).into_owned();
                let axis_ref = target.orientation * Vector3::z();
                geom::swing_vector(&axis, &axis_ref, &rot.matrix().column(0).into_owned())
            }
        };
        let e_rot = e_rot_full - target.angular_velocity * dt;
        let e = tj.project(&e_pos, &e_rot);
        let xd = tj.project(&target.linear_velocity, &target.angular_velocity);
        let mut feedback = [0.0; MAX_TASK];
        for r in 0..m {
            feedback[r] = cfg.gains[r].min(1.0 / dt) * e[r];
        }
        let clamp_norm = |part: &mut [f64], cap: f64| {
            let norm = part.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > cap {
                part.iter_mut().for_each(|x| *x *= cap / norm);
            }
        };
        clamp_norm(&mut feedback[..3], cfg.max_correction_speed);
        clamp_norm(&mut feedback[3..m], cfg.max_correction_rate);
        let mut rhs = [0.0; MAX_TASK];
        for r in 0..m {
            rhs[r] = xd[r] + feedback[r];
        }

        let s0 = svd(&tj.rows, m, n, &self.svd_start);
        self.svd_start = s0.u;
        let manipulability = s0.manipulability();

        // Secondary objectives.
        let mut qd0 = JointVector::zeros();
        if cfg.manipulability_gain > 0.0 && manipulability > 0.0 {
            qd0 += manipulability_gradient(state, &tj, &s0) * (cfg.manipulability_gain / manipulability);
        }
        for i in 0..n {
            let l = model.limits(i);
            if cfg.joint_limit_gain > 0.0 && l.lower.is_finite() && l.upper.is_finite() && cfg.joint_limit_margin > 0.0 {
                let margin = cfg.joint_limit_margin * (l.upper - l.lower);
                let d_hi = q[i] - (l.upper - margin);
                let d_lo = (l.lower + margin) - q[i];
                if d_hi > 0.0 {
                    qd0[i] -= cfg.joint_limit_gain * d_hi / (margin * margin);
                } else if d_lo > 0.0 {
                    qd0[i] += cfg.joint_limit_gain * d_lo / (margin * margin);
                }
            }
            let cap = cfg.nullspace_speed_fraction * l.velocity;
            qd0[i] = qd0[i].clamp(-cap, cap);
        }

        // Per-joint velocity boxes: from position (with braking), and the full box with speed and acceleration.
        let mut pos_lo = [0.0; MAX_JOINTS];
        let mut pos_hi = [0.0; MAX_JOINTS];
        let mut lo = [0.0; MAX_JOINTS];
        let mut hi = [0.0; MAX_JOINTS];
        for i in 0..n {
            let l = model.limits(i);
            let (a, b) = position_velocity_bounds(q[i], l.lower, l.upper, l.velocity, l.acceleration, dt);
            pos_lo[i] = a;
            pos_hi[i] = b;
            let acc_step = l.acceleration * dt;
            lo[i] = a.max(-l.velocity).max(self.qd_prev[i] - acc_step);
            hi[i] = b.min(l.velocity).min(self.qd_prev[i] + acc_step);
        }

        // Solve, saturating joints at their position bounds (SNS): a joint inside its braking zone (its
        // position bound is tighter than its speed limit) that the solution pushes past that bound is
        // held at the bound and the task re-solved with the others, most-violating joint first.
        let mut saturated: u8 = 0;
        let mut sat_value = JointVector::zeros();
        // The reduced problem (saturated columns removed), made only once a joint saturates.
        let mut reduced: Option<(TaskJacobian, Svd)> = None;
        let mut qd;
        let mut lambda_min_sq;
        loop {
            let mut rhs_k = rhs;
            let mut qd0_k = qd0;
            for j in 0..n {
                if saturated & (1 << j) != 0 {
                    for (r, x) in rhs_k.iter_mut().enumerate().take(m) {
                        *x -= tj.rows[r][j] * sat_value[j];
                    }
                    qd0_k[j] = 0.0;
                }
            }
            let solve_svd = reduced.as_ref().map_or(&s0, |r| &r.1);
            let (v, lam) = damped_solve(solve_svd, &rhs_k, &qd0_k, cfg.sigma_threshold, cfg.damping_max, n);
            qd = v;
            lambda_min_sq = lam;
            let mut worst: Option<(usize, f64, f64)> = None;
            for i in 0..n {
                if saturated & (1 << i) != 0 {
                    qd[i] = sat_value[i];
                    continue;
                }
                let vmax = model.limits(i).velocity;
                let over = if qd[i] > pos_hi[i] && pos_hi[i] < vmax {
                    Some((qd[i] / pos_hi[i].max(1e-300), pos_hi[i]))
                } else if qd[i] < pos_lo[i] && pos_lo[i] > -vmax {
                    Some((qd[i] / pos_lo[i].min(-1e-300), pos_lo[i]))
                } else {
                    None
                };
                if let Some((ratio, bound)) = over
                    && worst.is_none_or(|w| ratio > w.1)
                {
                    worst = Some((i, ratio, bound));
                }
            }
            match worst {
                Some((i, _, bound)) if (saturated.count_ones() as usize) + 1 < n => {
                    saturated |= 1 << i;
                    sat_value[i] = bound;
                    let mut solve_tj = reduced.map_or(tj, |r| r.0);
                    solve_tj.remove_column(i);
                    let solve_svd = svd(&solve_tj.rows, m, n, &s0.u);
                    reduced = Some((solve_tj, solve_svd));
                }
                Some((i, _, bound)) => {
                    saturated |= 1 << i;
                    qd[i] = bound;
                    break;
                }
                None => break,
            }
        }

        // One common factor s for the speed, acceleration and position boxes (direction kept).
        let (mut s_lo, mut s_hi) = (0.0f64, 1.0f64);
        for i in 0..n {
            let v = qd[i];
            if v > 0.0 {
                s_hi = s_hi.min(hi[i] / v);
                s_lo = s_lo.max(lo[i] / v);
            } else if v < 0.0 {
                s_hi = s_hi.min(lo[i] / v);
                s_lo = s_lo.max(hi[i] / v);
            } else if lo[i] > 0.0 || hi[i] < 0.0 {
                s_lo = f64::INFINITY;
            }
        }
        let mut status = ClikStatus {
            near_singular: s0.sigma_min() < cfg.sigma_threshold,
            at_limit: saturated != 0,
            scaled: false,
            invalid_input: !target_ok,
        };
        let scale;
        if s_lo <= s_hi {
            scale = s_hi.max(0.0);
            qd *= scale;
        } else {
            // No common factor: clamp each joint into its own box (limits before direction).
            scale = s_hi.max(0.0);
            qd *= scale;
            for i in 0..n {
                qd[i] = if lo[i] <= hi[i] { qd[i].clamp(lo[i], hi[i]) } else { qd[i].clamp(pos_lo[i], pos_hi[i]) };
            }
            status.at_limit = true;
        }
        status.scaled = scale < 1.0;
        if qd.iter().any(|x| !x.is_finite()) {
            // Cannot happen with finite inputs; if it ever does, brake rather than publish a NaN.
            for i in 0..n {
                qd[i] = 0.0f64.clamp(lo[i].min(hi[i]), hi[i].max(lo[i]));
            }
            status.invalid_input = true;
        }

        // Integrate and make sure of the position limits (rounding can leave one ulp over).
        let mut q_next = *q;
        for i in 0..n {
            let l = model.limits(i);
            q_next[i] = (q[i] + qd[i] * dt).clamp(l.lower, l.upper);
            qd[i] = (q_next[i] - q[i]) / dt;
        }
        self.qd_prev = qd;
        ClikStep {
            q: q_next,
            qd,
            scale,
            status,
            sigma_min: s0.sigma_min(),
            manipulability,
            damping: lambda_min_sq.sqrt(),
            position_error: e_pos.norm(),
            orientation_error: match cfg.task {
                Task::Pose6 => e_rot.norm(),
                Task::Print5 => (e[3] * e[3] + e[4] * e[4]).sqrt(),
            },
            saturated,
        }
    }
}

/// q̇ = J#·rhs + (I − J#J)·qd0 with per-singular-value damping; returns q̇ and λ² of the smallest σ.
fn damped_solve(s: &Svd, rhs: &[f64; MAX_TASK], qd0: &JointVector, eps: f64, lambda_max: f64, n: usize) -> (JointVector, f64) {
    let mut qd = *qd0;
    let mut lambda_sq_min = 0.0;
    for k in 0..s.m {
        let sigma = s.sigma[k];
        let lam2 = damping_sq(sigma, eps, lambda_max);
        if k == s.m - 1 {
            lambda_sq_min = lam2;
        }
        let denom = sigma * sigma + lam2;
        if denom == 0.0 {
            continue;
        }
        let uk_rhs: f64 = (0..s.m).map(|r| s.u[k][r] * rhs[r]).sum();
        let vk_qd0: f64 = (0..n).map(|j| s.v[k][j] * qd0[j]).sum();
        let coef = sigma * uk_rhs / denom - sigma * sigma * vk_qd0 / denom;
        for j in 0..n {
            qd[j] += coef * s.v[k][j];
        }
    }
    (qd, lambda_sq_min)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Braking from `braking_speed(d)` at most `a·dt` per tick covers at most d and ends at rest, for
    /// distances from far below one tick's travel to many braking distances.
    #[test]
    fn braking_speed_is_exact_for_the_discrete_stop() {
        for &(acc, dt) in &[(4.0, 1e-3), (15.0, 2.5e-4), (0.5, 8e-3)] {
            for e in -9..2 {
                for frac in [1.0, 2.7, 5.3] {
                    let d = frac * 10f64.powi(e);
                    let mut v = braking_speed(d, acc, dt);
                    let mut left = d;
                    let mut ticks = 0;
                    while v > 0.0 {
                        left -= v * dt;
                        assert!(left >= -1e-12 * d.max(1.0), "overshoot {left} at a={acc} dt={dt} d={d}");
                        let bound = braking_speed(left.max(0.0), acc, dt);
                        assert!(v - bound <= acc * dt * (1.0 + 1e-9), "needs more than a·dt to stay in bound");
                        v = bound.min(v);
                        ticks += 1;
                        assert!(ticks < 10_000_000);
                    }
                }
            }
        }
        assert_eq!(braking_speed(0.0, 4.0, 1e-3), 0.0);
        assert_eq!(braking_speed(-1.0, 4.0, 1e-3), 0.0);
    }
}
