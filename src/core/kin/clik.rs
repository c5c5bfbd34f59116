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
//! - Priority (`priority`, default `none`): the single damped J# above, or `position-first`, which
//!   solves the position rows first and the orientation rows in their null space, so a wrist
//!   singularity costs nozzle direction rather than tip position (see [`Priority`]).
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
use crate::setting::InvalidSetting;

/// How the position and orientation rows share the joints when they cannot both be met.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Priority {
    /// One damped inverse of the whole task Jacobian, as 002's Eq. 17 writes it (the default): near a
    /// singularity the damped direction costs position and orientation alike.
    None,
    /// Position first; the orientation rows act in the position task's null space (Chiaverini's
    /// singularity-robust task priority). Near a wrist singularity the nozzle axis lags and the tip
    /// holds: grazing the VP6242's wrist singularity, 2.1 mm of tip error instead of 8.7 mm
    /// (`tests/clik.rs`). Known limit, hence not the default: against a target it cannot reach with
    /// a large orientation residual (a joint at its limit, say) the orientation level can cycle
    /// under the acceleration limits instead of settling; the limits still hold.
    PositionFirst,
}

/// Tuning of the CLIK step.
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClikConfig {
    /// Task to follow: `pose6` or `print5` (rotation about the nozzle free; the default for printing).
    pub task: Task,
    /// `none` (default) or `position-first`: see [`Priority`].
    pub priority: Priority,
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
    /// Deceleration the position feedback plans with (m/s²; 0: none): the correction speed is at
    /// most the speed from which the error can be closed without overshoot at this deceleration
    /// (the discrete square-root law, [`braking_speed`]). Without it the feedback is deadbeat (K up to
    /// 1/dt): harmless while errors are micrometres, but an error the joints cannot close in one tick
    /// (a tracked base's unpredicted motion) makes an acceleration-limited arm overshoot, reverse and
    /// limit-cycle at its acceleration limits. Set it to what the arm can do at the TCP.
    pub max_correction_acceleration: f64,
    /// The same for the orientation feedback (rad/s²; 0: none).
    pub max_correction_angular_acceleration: f64,
}

impl Default for ClikConfig {
    fn default() -> Self {
        ClikConfig {
            task: Task::Print5,
            priority: Priority::None,
            gains: [1000.0; 6],
            sigma_threshold: 0.04,
            damping_max: 0.04,
            manipulability_gain: 0.5,
            joint_limit_gain: 0.5,
            joint_limit_margin: 0.1,
            nullspace_speed_fraction: 0.2,
            max_correction_speed: 0.1,
            max_correction_rate: 0.5,
            max_correction_acceleration: 2.0,
            max_correction_angular_acceleration: 10.0,
        }
    }
}

impl ClikConfig {
    /// Checks ranges; the error names the offending key.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let pos = |v: f64| v.is_finite() && v >= 0.0;
        if let Some(i) = self.gains.iter().position(|g| !(g.is_finite() && *g > 0.0)) {
            return Err(InvalidSetting::new("clik", format!("clik.gains[{i}] = {} must be finite and > 0 (1/s)", self.gains[i])));
        }
        if !(self.sigma_threshold.is_finite() && self.sigma_threshold > 0.0) {
            return Err(InvalidSetting::new("clik", format!("clik.sigma_threshold = {} must be finite and > 0", self.sigma_threshold)));
        }
        if !(self.damping_max.is_finite() && self.damping_max > 0.0) {
            return Err(InvalidSetting::new("clik", format!("clik.damping_max = {} must be finite and > 0", self.damping_max)));
        }
        for (key, v) in [("clik.manipulability_gain", self.manipulability_gain), ("clik.joint_limit_gain", self.joint_limit_gain)] {
            if !pos(v) {
                return Err(InvalidSetting::new("clik", format!("{key} = {v} must be finite and ≥ 0")));
            }
        }
        if !(self.joint_limit_margin >= 0.0 && self.joint_limit_margin <= 0.5) {
            return Err(InvalidSetting::new("clik", format!("clik.joint_limit_margin = {} must lie in [0, 0.5]", self.joint_limit_margin)));
        }
        for (key, v) in [("clik.max_correction_speed", self.max_correction_speed), ("clik.max_correction_rate", self.max_correction_rate)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(InvalidSetting::new("clik", format!("{key} = {v} must be finite and > 0")));
            }
        }
        for (key, v) in [
            ("clik.max_correction_acceleration", self.max_correction_acceleration),
            ("clik.max_correction_angular_acceleration", self.max_correction_angular_acceleration),
        ] {
            if !pos(v) {
                return Err(InvalidSetting::new("clik", format!("{key} = {v} must be finite and ≥ 0 (0: no limit)")));
            }
        }
        if !(self.nullspace_speed_fraction >= 0.0 && self.nullspace_speed_fraction <= 1.0) {
            return Err(InvalidSetting::new(
                "clik",
                format!("clik.nullspace_speed_fraction = {} must lie in [0, 1]", self.nullspace_speed_fraction),
            ));
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

/// The share of a target's velocity that the path timing owns (base frame): the path's own velocity,
/// without the base's motion. Slowing the path down scales this share and nothing else, so only the
/// part of a limit that this share causes should slow the path (see [`ClikStep::path_scale`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathVelocity {
    /// Linear velocity (m/s).
    pub linear: Vector3<f64>,
    /// Angular velocity (rad/s).
    pub angular: Vector3<f64>,
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
    /// What the task asked for before any limit (rad/s or m/s): the unsaturated, unscaled solution.
    /// When only `scaled` is set, `qd = scale · requested`.
    pub requested: JointVector,
    /// Common factor applied for velocity and acceleration limits (1 = none).
    pub scale: f64,
    /// The factor by which the path's own velocity would have to shrink for the step to fit every joint's
    /// box (1 = the path is not what the limits cut). Joints whose box the rest of the step (feedback,
    /// base motion, null space) breaks on its own are left out: no path speed fixes them, and slowing
    /// the path for them would stall it while the base moves. The path timing follows this, not `scale`.
    pub path_scale: f64,
    /// Flags.
    pub status: ClikStatus,
    /// Smallest singular value of the task Jacobian (task units).
    pub sigma_min: f64,
    /// Task manipulability √det(JJᵀ) at q_k.
    pub manipulability: f64,
    /// Damping λ at the smallest singular value of the task Jacobian (task units).
    pub damping: f64,
    /// Norm of the position error the step corrected (m).
    pub position_error: f64,
    /// Norm of the orientation error the step corrected (rad).
    pub orientation_error: f64,
    /// Bit i set: joint i was saturated at a position bound.
    pub saturated: u8,
}

// `ClikStep::saturated` holds one bit per joint.
const _: () = assert!(MAX_JOINTS <= 8);

/// The CLIK solver: its configuration and the little state carried from tick to tick (the last q̇ for
/// the acceleration limit, the last command for repairing bad input, and the SVD warm start). A replay
/// that starts from a fresh solver and feeds the same steps gets the same bits.
#[derive(Clone, Debug)]
pub struct Clik {
    config: ClikConfig,
    qd_prev: JointVector,
    q_last: Option<JointVector>,
    dt_last: Option<f64>,
    svd_start: [[f64; MAX_TASK]; MAX_TASK],
    /// Steps since `svd_start` was last made orthonormal again (count).
    svd_start_age: u32,
    level_starts: LevelStarts,
    /// FK and Jacobian in two slots: `states[current]` at the q of the last step, the other one
    /// computed ahead ([`Clik::kinematics_ahead`]) for the next.
    states: [ChainState; 2],
    /// The slot of the last step.
    current: usize,
    /// The joints each slot was computed at (rad or m; the chain's, spare entries 0), if any.
    keys: [Option<JointVector>; 2],
}

/// Steps between two re-orthonormalisations of the SVD warm start (count). Jacobi rotations keep it
/// orthonormal to within a few ulps a step; 64 steps of drift stay far below what the singular values
/// and vectors need (1e-13 relative), and the Gram–Schmidt pass (a chain of square roots, about 0.13 µs)
/// is then paid once in 64 ticks.
const ORTHONORMALIZE_EVERY: u32 = 64;

/// SVD warm starts of the two priority levels (position rows; orientation rows in its null space).
#[derive(Clone, Copy, Debug)]
struct LevelStarts {
    position: [[f64; MAX_TASK]; MAX_TASK],
    orientation: [[f64; MAX_TASK]; MAX_TASK],
}

impl LevelStarts {
    fn identity() -> Self {
        LevelStarts { position: identity_start(), orientation: identity_start() }
    }
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
/// `acc` before reaching either bound. Outside the range, the bound on the far side is 0: the joint may
/// come back (at its speed and acceleration limits) but not go further out.
fn position_velocity_bounds(q: f64, lo: f64, hi: f64, vmax: f64, acc: f64, dt: f64) -> (f64, f64) {
    // Farther from a limit than a stop from full speed needs, position does not bound the speed.
    let free = vmax * vmax / (2.0 * acc) + vmax * dt;
    let brake = |d: f64| if d > free { f64::INFINITY } else { braking_speed(d, acc, dt) };
    let upper = if !hi.is_finite() {
        f64::INFINITY
    } else if q <= hi {
        ((hi - q) / dt).min(brake(hi - q))
    } else {
        0.0 // past the limit: never further out; the lower bound lets it come back
    };
    let lower = if !lo.is_finite() {
        f64::NEG_INFINITY
    } else if q >= lo {
        ((lo - q) / dt).max(-brake(q - lo))
    } else {
        0.0
    };
    (lower, upper)
}

/// The largest speed (rad/s or m/s) from which a joint, one tick of `dt` at a time and slowing by at
/// most `acc·dt` per tick, stops within the distance `d`: the sequence v, v − a·dt, …, v − k·a·dt covers
/// exactly d with its last term in [0, a·dt]. Following it, one tick later the bound is exactly v − a·dt,
/// so braking never needs more than the acceleration limit.
pub(super) fn braking_speed(d: f64, acc: f64, dt: f64) -> f64 {
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

/// A [`ClikConfig`] that failed [`ClikConfig::validate`]; the message names the key.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InvalidClikConfig(pub InvalidSetting);

/// Per-joint velocity boxes for one tick (rad/s or m/s).
struct Boxes {
    /// From the position limits alone (including the distance needed to brake).
    pos_lo: [f64; MAX_JOINTS],
    pos_hi: [f64; MAX_JOINTS],
    /// From the speed and acceleration limits alone.
    dyn_lo: [f64; MAX_JOINTS],
    dyn_hi: [f64; MAX_JOINTS],
    /// All of them together.
    lo: [f64; MAX_JOINTS],
    hi: [f64; MAX_JOINTS],
}

impl Boxes {
    /// The speed nearest to `v` that joint i may take. If position and acceleration cannot both be met
    /// (the box is empty — by one rounding step on a braking curve, or really), the acceleration limit
    /// is met as far as the position limit allows: position first.
    #[inline]
    fn clamp(&self, i: usize, v: f64) -> f64 {
        // max/min rather than f64::clamp: no bound order can make this panic.
        if self.lo[i] <= self.hi[i] {
            v.max(self.lo[i]).min(self.hi[i])
        } else {
            v.max(self.dyn_lo[i]).min(self.dyn_hi[i]).max(self.pos_lo[i]).min(self.pos_hi[i])
        }
    }
}

impl Clik {
    /// A solver for a chain at rest. The configuration is checked here, so a step never meets a gain or
    /// threshold it cannot use.
    pub fn new(config: ClikConfig) -> Result<Self, InvalidClikConfig> {
        config.validate().map_err(InvalidClikConfig)?;
        Ok(Clik {
            config,
            qd_prev: JointVector::zeros(),
            q_last: None,
            dt_last: None,
            svd_start: identity_start(),
            svd_start_age: 0,
            level_starts: LevelStarts::identity(),
            states: [ChainState::new(0); 2],
            current: 0,
            keys: [None; 2],
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ClikConfig {
        &self.config
    }

    /// Forgets the history: the next step starts from joint velocity `qd` (rad/s or m/s), with a cold SVD.
    pub fn reset(&mut self, qd: JointVector) {
        self.qd_prev = qd.map(|v| if v.is_finite() { v } else { 0.0 });
        self.q_last = None;
        self.dt_last = None;
        self.svd_start = identity_start();
        self.svd_start_age = 0;
        self.level_starts = LevelStarts::identity();
    }

    /// The joint velocity of the last step (rad/s or m/s).
    pub fn last_velocity(&self) -> &JointVector {
        &self.qd_prev
    }

    /// FK and Jacobian at the q of the last step (before it moved).
    pub fn last_state(&self) -> &ChainState {
        &self.states[self.current]
    }

    /// FK and Jacobian of `model` at `q` (rad or m), computed now and kept for the next step: a step
    /// from the same joints, to the bit, takes them instead of computing them again. The controller
    /// asks for the TCP of its new command at the end of a tick, and the next tick's CLIK starts from
    /// that command: one FK a tick serves both. `model` must be the one the next step is given.
    /// The result is the step's own computation ([`RobotModel::kinematics`] at the same joints), so
    /// a step is the same to the bit with or without it.
    pub fn kinematics_ahead(&mut self, model: &RobotModel, q: &JointVector) -> &ChainState {
        let key = chain_joints(model, q);
        let slot = 1 - self.current;
        model.kinematics(&key, &mut self.states[slot]);
        self.keys[slot] = Some(key);
        &self.states[slot]
    }

    /// FK and Jacobian at `q` (rad or m) if the last step or [`Clik::kinematics_ahead`] computed
    /// them at the same joints, to the bit: what the controller's watchdog takes for the measured
    /// joints when they are the command it echoes (a simulator, a driver's echo).
    pub fn kinematics_at(&self, model: &RobotModel, q: &JointVector) -> Option<&ChainState> {
        let key = chain_joints(model, q);
        (0..2).find(|&slot| self.keys[slot].is_some_and(|k| same_bits(&k, &key))).map(|slot| &self.states[slot])
    }

    /// One tick: from the current command `q` (rad or m) towards `target`, over `dt` seconds.
    ///
    /// `q` is meant to be the controller's own last command. Bad input is survived, flagged and never
    /// passed on: a non-finite entry of `q` is replaced by the last command (or the middle of the range
    /// before any), a `q` outside the limits is brought back at no more than the speed and acceleration
    /// limits (never pushed further out), and a target holding NaN or ±∞ is not followed — the arm brakes
    /// at its acceleration limits. A `dt` that is not a positive finite number is treated the same way,
    /// braking over the last good tick length (or holding, if there was none).
    /// The returned command is always finite, and within the position limits whenever `q` was.
    pub fn step(&mut self, model: &RobotModel, q_in: &JointVector, target: &TcpTarget, dt: f64) -> ClikStep {
        let path = PathVelocity { linear: target.linear_velocity, angular: target.angular_velocity };
        self.step_on_path(model, q_in, target, &path, dt)
    }

    /// [`step`](Self::step) for a target whose velocity is partly the path's (`path`, base frame) and
    /// partly something the path timing does not own (the base's motion): `path_scale` then judges the
    /// path's share alone. [`step`](Self::step) counts the whole target velocity as the path's.
    pub fn step_on_path(&mut self, model: &RobotModel, q_in: &JointVector, target: &TcpTarget, path: &PathVelocity, dt: f64) -> ClikStep {
        let cfg = self.config;
        let n = model.dof();
        let (q, q_repaired) = self.sanitize(model, q_in);
        let dt_ok = dt.is_finite() && dt > 0.0;
        let dt = match (dt_ok, self.dt_last) {
            (true, _) => dt,
            // A tick length that cannot be used: brake over the last good one.
            (false, Some(last)) => last,
            // Nothing to go by (and so, from a fresh solver, nothing moving): hold.
            (false, None) => {
                self.qd_prev = JointVector::zeros();
                return ClikStep::hold(q);
            }
        };
        self.dt_last = Some(dt);
        let target_ok = dt_ok
            && target.position.iter().chain(target.linear_velocity.iter()).chain(target.angular_velocity.iter()).all(|x| x.is_finite())
            && target.orientation.coords.iter().all(|x| x.is_finite());

        // 1. Kinematics at q_k: FK, task Jacobian, its SVD (warm start from the last tick). The FK
        //    and Jacobian were computed ahead when the controller asked for its command's TCP.
        let ahead = 1 - self.current;
        if self.keys[ahead].is_some_and(|k| same_bits(&k, &q)) {
            self.current = ahead;
        } else {
            model.kinematics(&q, &mut self.states[self.current]);
            self.keys[self.current] = Some(q);
        }
        self.keys[1 - self.current] = None;
        let state = &self.states[self.current];
        let tj = TaskJacobian::new(state, cfg.task);
        let m = tj.m;
        let s0 = svd(&tj.rows, m, n, &self.svd_start);
        self.svd_start = s0.u;
        self.svd_start_age += 1;
        if self.svd_start_age >= ORTHONORMALIZE_EVERY {
            orthonormalize(&mut self.svd_start, m);
            self.svd_start_age = 0;
        }
        let manipulability = s0.manipulability();

        // 2. What the task asks for: ẋ_ref + K·e, with the feedback capped.
        let (rhs, e_pos_norm, e_rot_norm) =
            if target_ok { task_velocity(&cfg, state, &tj, target, dt) } else { ([0.0; MAX_TASK], 0.0, 0.0) };

        // 3. Secondary objectives, for the null space.
        let qd0 = if target_ok { secondary_velocity(&cfg, model, &q, state, &tj, &s0) } else { JointVector::zeros() };

        // 4. Velocity boxes from the position, speed and acceleration limits.
        let boxes = self.boxes(model, &q, dt);

        // 5. Solve, saturating joints at their position bounds (SNS). An invalid target asks for rest.
        let (mut qd, requested, saturated) = if target_ok {
            solve_with_saturation(model, &tj, &s0, &rhs, &qd0, &boxes, &cfg, &mut self.level_starts)
        } else {
            (JointVector::zeros(), JointVector::zeros(), 0)
        };

        // 6. One common factor for the boxes (direction kept); per-joint clamping only when none exists.
        let mut status = ClikStatus {
            near_singular: s0.sigma_min() < cfg.sigma_threshold,
            at_limit: saturated != 0 || q_repaired.out_of_range,
            scaled: false,
            invalid_input: !target_ok || q_repaired.non_finite,
        };
        //    Saturated joints are constraints: they stay at their box edge; the free joints are scaled.
        let (s_lo, s_hi) = common_scale_range(&qd, &boxes, n, saturated);
        let mut scale = s_hi.max(0.0);
        let path_scale = if !target_ok {
            0.0
        } else if s_hi >= 1.0 {
            1.0
        } else {
            path_share_scale(&tj, &s0, path, &qd, &boxes, &cfg, n, saturated)
        };
        for i in 0..n {
            if saturated & (1 << i) == 0 {
                qd[i] *= scale;
            }
        }
        if s_lo > s_hi {
            for i in 0..n {
                qd[i] = boxes.clamp(i, qd[i]);
            }
            status.at_limit |= target_ok;
        }
        if !target_ok {
            scale = 0.0;
        }
        status.scaled = scale < 1.0;
        if qd.iter().any(|x| !x.is_finite()) {
            // Cannot happen with finite inputs and a validated config; if it ever does, brake rather
            // than publish a NaN.
            for i in 0..n {
                qd[i] = boxes.clamp(i, 0.0);
            }
            status.invalid_input = true;
            scale = 0.0;
            status.scaled = true;
        }

        // 7. Integrate; the position clamp only removes rounding (and never pulls an out-of-range q in
        //    faster than the boxes allowed).
        let mut q_next = q;
        for i in 0..n {
            let l = model.limits(i);
            q_next[i] = (q[i] + qd[i] * dt).clamp(l.lower.min(q[i]), l.upper.max(q[i]));
            qd[i] = (q_next[i] - q[i]) / dt;
        }
        self.qd_prev = qd;
        self.q_last = Some(q_next);
        let sigma_min = s0.sigma_min();
        ClikStep {
            q: q_next,
            qd,
            requested,
            scale,
            path_scale,
            status,
            sigma_min,
            manipulability,
            damping: damping_sq(sigma_min, cfg.sigma_threshold, cfg.damping_max).sqrt(),
            position_error: e_pos_norm,
            orientation_error: e_rot_norm,
            saturated,
        }
    }

    /// Replaces non-finite entries of `q` (from the last command, or the range's middle before any).
    fn sanitize(&self, model: &RobotModel, q_in: &JointVector) -> (JointVector, Repair) {
        let n = model.dof();
        let mut q = *q_in;
        let mut repair = Repair { non_finite: false, out_of_range: false };
        for i in 0..MAX_JOINTS {
            if i >= n {
                q[i] = 0.0; // spare entries carry nothing
            } else if !q[i].is_finite() {
                q[i] = self.q_last.map_or_else(|| model.limits(i).middle(), |last| last[i]);
                repair.non_finite = true;
            }
        }
        repair.out_of_range = !model.within_limits(&q);
        (q, repair)
    }

    fn boxes(&self, model: &RobotModel, q: &JointVector, dt: f64) -> Boxes {
        let zero = [0.0; MAX_JOINTS];
        let mut b = Boxes { pos_lo: zero, pos_hi: zero, dyn_lo: zero, dyn_hi: zero, lo: zero, hi: zero };
        for i in 0..model.dof() {
            let l = model.limits(i);
            let (a, c) = position_velocity_bounds(q[i], l.lower, l.upper, l.velocity, l.acceleration, dt);
            let acc_step = l.acceleration * dt;
            b.pos_lo[i] = a;
            b.pos_hi[i] = c;
            b.dyn_lo[i] = (-l.velocity).max(self.qd_prev[i] - acc_step);
            b.dyn_hi[i] = l.velocity.min(self.qd_prev[i] + acc_step);
            if b.dyn_lo[i] > b.dyn_hi[i] {
                // Faster than the speed limit allows (a velocity handed to `reset`): slow down as hard
                // as the acceleration limit lets, towards the allowed range.
                let v = if self.qd_prev[i] > 0.0 { self.qd_prev[i] - acc_step } else { self.qd_prev[i] + acc_step };
                b.dyn_lo[i] = v;
                b.dyn_hi[i] = v;
            }
            b.lo[i] = a.max(b.dyn_lo[i]);
            b.hi[i] = c.min(b.dyn_hi[i]);
        }
        b
    }
}

/// `q` (rad or m) as the chain reads it: its joints, the spare entries 0 (as [`Clik::sanitize`]
/// leaves them).
fn chain_joints(model: &RobotModel, q: &JointVector) -> JointVector {
    let mut key = *q;
    for i in model.dof()..MAX_JOINTS {
        key[i] = 0.0;
    }
    key
}

/// The same joints to the bit (not `==`: 0.0 and −0.0 are equal, and give other bits downstream).
fn same_bits(a: &JointVector, b: &JointVector) -> bool {
    a.iter().zip(b.iter()).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// How [`Clik::sanitize`] had to repair the joint input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Repair {
    /// An entry was NaN or ±∞ and was replaced.
    non_finite: bool,
    /// A joint lies past its position limit.
    out_of_range: bool,
}

impl ClikStep {
    /// A step that does not move (for a `dt` that cannot be integrated).
    fn hold(q: JointVector) -> Self {
        ClikStep {
            q,
            qd: JointVector::zeros(),
            requested: JointVector::zeros(),
            scale: 0.0,
            path_scale: 0.0,
            status: ClikStatus { invalid_input: true, scaled: true, ..ClikStatus::default() },
            sigma_min: 0.0,
            manipulability: 0.0,
            damping: 0.0,
            position_error: 0.0,
            orientation_error: 0.0,
            saturated: 0,
        }
    }
}

/// Makes the columns `w[..m]` (length m) orthonormal again by modified Gram–Schmidt, so that rounding
/// cannot build up in the SVD warm start over millions of ticks.
fn orthonormalize(w: &mut [[f64; MAX_TASK]; MAX_TASK], m: usize) {
    for k in 0..m {
        for j in 0..k {
            let d: f64 = (0..m).map(|r| w[k][r] * w[j][r]).sum();
            for r in 0..m {
                w[k][r] -= d * w[j][r];
            }
        }
        let norm = (0..m).map(|r| w[k][r] * w[k][r]).sum::<f64>().sqrt();
        if norm > 0.5 {
            let inverse = 1.0 / norm;
            for r in 0..m {
                w[k][r] *= inverse;
            }
        } else {
            // Degenerate start (cannot come out of a Jacobi sweep): fall back to the identity.
            *w = identity_start();
            return;
        }
    }
}

/// ẋ_ref + K·e projected on the task rows, with |K·e| capped; also |e_pos| (m) and |e_rot| (rad).
fn task_velocity(cfg: &ClikConfig, state: &ChainState, tj: &TaskJacobian, target: &TcpTarget, dt: f64) -> ([f64; MAX_TASK], f64, f64) {
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
    // The speed from which the error closes without overshoot at the planned deceleration.
    let closing_speed = |part: &[f64], acc: f64| {
        if acc > 0.0 { braking_speed(part.iter().map(|x| x * x).sum::<f64>().sqrt(), acc, dt) } else { f64::INFINITY }
    };
    let cap_position = cfg.max_correction_speed.min(closing_speed(&e[..3], cfg.max_correction_acceleration));
    let cap_rotation = cfg.max_correction_rate.min(closing_speed(&e[3..m], cfg.max_correction_angular_acceleration));
    clamp_norm(&mut feedback[..3], cap_position);
    clamp_norm(&mut feedback[3..m], cap_rotation);
    let mut rhs = [0.0; MAX_TASK];
    for r in 0..m {
        rhs[r] = xd[r] + feedback[r];
    }
    let e_rot_norm = match cfg.task {
        Task::Pose6 => e_rot.norm(),
        Task::Print5 => (e[3] * e[3] + e[4] * e[4]).sqrt(),
    };
    (rhs, e_pos.norm(), e_rot_norm)
}

/// k₀∇ln w + k_jl∇h_jl, each joint capped at its share of the velocity limit.
fn secondary_velocity(
    cfg: &ClikConfig,
    model: &RobotModel,
    q: &JointVector,
    state: &ChainState,
    tj: &TaskJacobian,
    s0: &Svd,
) -> JointVector {
    let mut qd0 = JointVector::zeros();
    let w = s0.manipulability();
    if cfg.manipulability_gain > 0.0 && w > 0.0 {
        qd0 += manipulability_gradient(state, tj, s0) * (cfg.manipulability_gain / w);
    }
    for i in 0..model.dof() {
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
    qd0
}

/// The damped solve with saturation in the null space: a joint inside its braking zone (its position
/// bound is tighter than its speed limit) that the solution pushes past that bound is held at the
/// bound and the task re-solved with the others, most-violating joint first. Returns q̇, the first
/// (unsaturated) solution, and the saturated joints as bits.
#[allow(clippy::too_many_arguments)]
fn solve_with_saturation(
    model: &RobotModel,
    tj: &TaskJacobian,
    s0: &Svd,
    rhs: &[f64; MAX_TASK],
    qd0: &JointVector,
    boxes: &Boxes,
    cfg: &ClikConfig,
    starts: &mut LevelStarts,
) -> (JointVector, JointVector, u8) {
    let (m, n) = (tj.m, tj.n);
    let mut saturated: u8 = 0;
    let mut sat_value = JointVector::zeros();
    // The reduced problem (saturated columns removed), made only once a joint saturates.
    let mut reduced: Option<TaskJacobian> = None;
    let mut requested = None;
    loop {
        let mut rhs_k = *rhs;
        let mut qd0_k = *qd0;
        for j in 0..n {
            if saturated & (1 << j) != 0 {
                for (r, x) in rhs_k.iter_mut().enumerate().take(m) {
                    *x -= tj.rows[r][j] * sat_value[j];
                }
                qd0_k[j] = 0.0;
            }
        }
        let mut qd = match cfg.priority {
            Priority::None => match &reduced {
                None => damped_solve(s0, &rhs_k, &qd0_k, cfg.sigma_threshold, cfg.damping_max, n),
                Some(r) => damped_solve(&svd(&r.rows, m, n, &s0.u), &rhs_k, &qd0_k, cfg.sigma_threshold, cfg.damping_max, n),
            },
            Priority::PositionFirst => {
                let rows = reduced.as_ref().map_or(&tj.rows, |r| &r.rows);
                // Only the full problem moves the warm starts, so they follow the arm, not the saturations.
                let mut scratch = *starts;
                let level_starts = if reduced.is_none() { &mut *starts } else { &mut scratch };
                prioritized_solve(rows, m, n, &rhs_k, &qd0_k, cfg.sigma_threshold, cfg.damping_max, level_starts)
            }
        };
        let requested = *requested.get_or_insert(qd);
        for i in 0..n {
            if saturated & (1 << i) != 0 {
                qd[i] = sat_value[i];
            }
        }
        let mut worst: Option<(usize, f64, f64)> = None;
        for i in 0..n {
            if saturated & (1 << i) != 0 {
                continue;
            }
            // Judged on the unscaled solution: a joint pushing into its braking zone is frozen there even
            // when the common scale would have slowed it enough. That can bend the direction (flagged
            // `at_limit`), but judging on the scaled solution stalls the whole arm whenever one joint is
            // still braking from the other way (the common scale is then 0 and nothing ever saturates).
            let v = qd[i];
            let vmax = model.limits(i).velocity;
            let over = if v > boxes.pos_hi[i] && boxes.pos_hi[i] < vmax {
                Some((v / boxes.pos_hi[i].max(1e-300), boxes.pos_hi[i]))
            } else if v < boxes.pos_lo[i] && boxes.pos_lo[i] > -vmax {
                Some((v / boxes.pos_lo[i].min(-1e-300), boxes.pos_lo[i]))
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
                sat_value[i] = boxes.clamp(i, bound);
                let mut solve_tj = reduced.unwrap_or(*tj);
                solve_tj.remove_column(i);
                reduced = Some(solve_tj);
            }
            Some((i, _, bound)) => {
                // Nothing left to re-solve with: hold this joint too.
                saturated |= 1 << i;
                qd[i] = boxes.clamp(i, bound);
                return (qd, requested, saturated);
            }
            None => return (qd, requested, saturated),
        }
    }
}

/// The range [s_lo, s_hi] of factors s ∈ [0, 1] for which s·q̇ lies in the box of every joint that is
/// not `saturated`; empty when s_lo > s_hi (some joint cannot follow the direction within its
/// acceleration limit).
fn common_scale_range(qd: &JointVector, boxes: &Boxes, n: usize, saturated: u8) -> (f64, f64) {
    let (mut s_lo, mut s_hi) = (0.0f64, 1.0f64);
    for i in 0..n {
        if saturated & (1 << i) == 0 {
            let (a, b) = scale_interval(qd[i], boxes.lo[i], boxes.hi[i]);
            s_lo = s_lo.max(a);
            s_hi = s_hi.min(b);
        }
    }
    (s_lo, s_hi)
}

/// The largest s ∈ [0, 1] for which rest + s·q̇_path fits the box of every free joint that some
/// s ∈ [0, 1] can fit at all, with q̇_path = J#·ẋ_path (the full task's damped inverse; with saturated
/// joints this is an estimate, which is all the path timing needs) and rest = q̇ − q̇_path.
///
/// A joint that no path speed fits (the base's motion or the feedback alone asks more of it than its
/// box allows) does not bound s: slowing the path would not cure it, and would stall the path for as
/// long as the base keeps moving. The common scale of the step still keeps that joint within limits.
#[allow(clippy::too_many_arguments)]
fn path_share_scale(
    tj: &TaskJacobian,
    s0: &Svd,
    path: &PathVelocity,
    qd: &JointVector,
    boxes: &Boxes,
    cfg: &ClikConfig,
    n: usize,
    saturated: u8,
) -> f64 {
    let rhs = tj.project(&path.linear, &path.angular);
    let qd_path = damped_solve(s0, &rhs, &JointVector::zeros(), cfg.sigma_threshold, cfg.damping_max, n);
    let mut s_hi = 1.0f64;
    for i in 0..n {
        if saturated & (1 << i) != 0 {
            continue;
        }
        let rest = qd[i] - qd_path[i];
        let (a, b) = scale_interval(qd_path[i], boxes.lo[i] - rest, boxes.hi[i] - rest);
        if a <= 1.0 && b >= 0.0 && a <= b {
            s_hi = s_hi.min(b);
        }
    }
    if s_hi.is_finite() { s_hi.clamp(0.0, 1.0) } else { 0.0 }
}

/// The factors s for which s·v lies in [lo, hi], as an interval (empty: a > b; all s: (−∞, ∞)).
#[inline]
fn scale_interval(v: f64, lo: f64, hi: f64) -> (f64, f64) {
    if v > 0.0 {
        (lo / v, hi / v)
    } else if v < 0.0 {
        (hi / v, lo / v)
    } else if lo > 0.0 || hi < 0.0 {
        (f64::INFINITY, f64::NEG_INFINITY)
    } else {
        (f64::NEG_INFINITY, f64::INFINITY)
    }
}

/// Task priority with damping at both levels (Chiaverini 1997; Siciliano & Slotine 1991):
///
/// ```text
/// q̇ = J₁#r₁ + J̃₂#(r₂ − J₂J₁#r₁) + (N₁ − J̃₂#J̃₂)·q̇₀,   J̃₂ = J₂N₁,  N₁ = I − J₁#J₁
/// ```
///
/// with J₁ the position rows (0–2) and J₂ the orientation rows (3..m). Where both levels have full rank
/// this is the exact solution of the whole task, the same as [`damped_solve`]; where the orientation
/// rows lose rank (a wrist singularity), only they are damped and the position rows stay exact.
#[allow(clippy::too_many_arguments)]
fn prioritized_solve(
    rows: &[[f64; MAX_JOINTS]; MAX_TASK],
    m: usize,
    n: usize,
    rhs: &[f64; MAX_TASK],
    qd0: &JointVector,
    eps: f64,
    lambda_max: f64,
    starts: &mut LevelStarts,
) -> JointVector {
    let s1 = svd(rows, 3, n, &starts.position);
    starts.position = s1.u;
    orthonormalize(&mut starts.position, 3);
    // Level 1: J₁#r₁, and the weights of N₁ = I − Σ g_k v_k v_kᵀ.
    let mut qd = JointVector::zeros();
    let mut g1 = [0.0; 3];
    for k in 0..3 {
        let (f, _) = damped_weights(s1.sigma[k], eps, lambda_max);
        // The exact projector (not the damped one): the lower level must not leak into position even
        // where position itself is damped, or the two levels can trade motion back and forth.
        g1[k] = if s1.sigma[k] > 0.0 { 1.0 } else { 0.0 };
        let uk_r: f64 = (0..3).map(|r| s1.u[k][r] * rhs[r]).sum();
        for j in 0..n {
            qd[j] += f * uk_r * s1.v[k][j];
        }
    }
    let project_n1 = |x: &mut [f64; MAX_JOINTS]| {
        for k in 0..3 {
            let d: f64 = (0..n).map(|j| s1.v[k][j] * x[j]).sum::<f64>() * g1[k];
            for j in 0..n {
                x[j] -= d * s1.v[k][j];
            }
        }
    };
    // Level 2: J̃₂ = J₂N₁ (rows of J₂ projected), and the residual r₂ − J₂·(J₁#r₁).
    let m2 = m - 3;
    let mut rows2 = [[0.0; MAX_JOINTS]; MAX_TASK];
    let mut r2 = [0.0; MAX_TASK];
    for r in 0..m2 {
        rows2[r] = rows[3 + r];
        project_n1(&mut rows2[r]);
        r2[r] = rhs[3 + r] - (0..n).map(|j| rows[3 + r][j] * qd[j]).sum::<f64>();
    }
    let s2 = svd(&rows2, m2, n, &starts.orientation);
    starts.orientation = s2.u;
    orthonormalize(&mut starts.orientation, m2);
    // Null space of both levels applied to q̇₀: z = N₁q̇₀, then z − J̃₂#J̃₂z.
    let mut z = [0.0; MAX_JOINTS];
    z[..n].copy_from_slice(&qd0.as_slice()[..n]);
    project_n1(&mut z);
    for k in 0..m2 {
        let (f, g) = damped_weights(s2.sigma[k], eps, lambda_max);
        let uk_r: f64 = (0..m2).map(|r| s2.u[k][r] * r2[r]).sum();
        let vk_z: f64 = (0..n).map(|j| s2.v[k][j] * z[j]).sum();
        let coef = f * uk_r - g * vk_z;
        for j in 0..n {
            qd[j] += coef * s2.v[k][j];
        }
    }
    for j in 0..n {
        qd[j] += z[j];
    }
    qd
}

/// The damped inverse's weight σ/(σ² + λ²) and the null-space weight σ²/(σ² + λ²) of one singular value.
#[inline]
fn damped_weights(sigma: f64, eps: f64, lambda_max: f64) -> (f64, f64) {
    let denom = sigma * sigma + damping_sq(sigma, eps, lambda_max);
    if denom == 0.0 { (0.0, 0.0) } else { (sigma / denom, sigma * sigma / denom) }
}

/// q̇ = J#·rhs + (I − J#J)·qd0 with per-singular-value damping.
fn damped_solve(s: &Svd, rhs: &[f64; MAX_TASK], qd0: &JointVector, eps: f64, lambda_max: f64, n: usize) -> JointVector {
    let mut qd = *qd0;
    for k in 0..s.m {
        let (f, g) = damped_weights(s.sigma[k], eps, lambda_max);
        let uk_rhs: f64 = (0..s.m).map(|r| s.u[k][r] * rhs[r]).sum();
        let vk_qd0: f64 = (0..n).map(|j| s.v[k][j] * qd0[j]).sum();
        let coef = f * uk_rhs - g * vk_qd0;
        for j in 0..n {
            qd[j] += coef * s.v[k][j];
        }
    }
    qd
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The FK and Jacobian computed ahead are the step's own: [`RobotModel::kinematics`]'s TCP is
    /// [`RobotModel::forward_kinematics`]'s to the bit (the controller's command TCP and watchdog
    /// took the latter before they shared the former), and a CLIK given them ahead steps to the
    /// bit as one that computes them itself, on chains of 6 and 7 joints.
    #[test]
    fn kinematics_computed_ahead_change_no_bit() {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let robots = [
            (include_str!("../../../config/robots/iiwa7.urdf"), "world", "iiwa_link_ee"),
            (include_str!("../../../config/robots/kr6r900.urdf"), "base_link", "flange"),
            (include_str!("../../../config/robots/ur5e.urdf"), "base_link", "tool0"),
        ];
        for (urdf, root, tip) in robots {
            let model = RobotModel::from_urdf_str(urdf, "robot.urdf", root, tip).unwrap();
            let n = model.dof();
            let mut state = ChainState::new(n);
            let mut seed = 0x2545_F491_4F6C_DD1Du64;
            let mut random = move || {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                (seed >> 11) as f64 / (1u64 << 53) as f64
            };
            for _ in 0..2_000 {
                let mut q = JointVector::zeros();
                for i in 0..n {
                    let l = model.limits(i);
                    q[i] = l.lower + (l.upper - l.lower) * random();
                }
                model.kinematics(&q, &mut state);
                let f = model.forward_kinematics(&q);
                assert_eq!(bits(state.tcp.translation.vector.as_slice()), bits(f.translation.vector.as_slice()));
                assert_eq!(bits(state.tcp.rotation.matrix().as_slice()), bits(f.rotation.matrix().as_slice()));
            }
            // Two solvers along the same moving target: one told the kinematics ahead, one not.
            let start = model.middle_configuration();
            let tcp = model.forward_kinematics(&start);
            let (mut plain, mut ahead) = (Clik::new(ClikConfig::default()).unwrap(), Clik::new(ClikConfig::default()).unwrap());
            let (mut q_plain, mut q_ahead) = (start, start);
            for k in 0..3_000 {
                let t = k as f64 * 1e-3;
                let target = TcpTarget {
                    position: tcp.translation.vector + nalgebra::Vector3::new(0.02 * (5.0 * t).sin(), 0.02 * (1.0 - (5.0 * t).cos()), 0.0),
                    orientation: nalgebra::UnitQuaternion::from_rotation_matrix(&tcp.rotation),
                    linear_velocity: nalgebra::Vector3::new(0.1 * (5.0 * t).cos(), 0.1 * (5.0 * t).sin(), 0.0),
                    angular_velocity: nalgebra::Vector3::zeros(),
                };
                if k % 7 != 3 {
                    // Now and then not: the step then computes them itself.
                    let shared = ahead.kinematics_ahead(&model, &q_ahead).tcp;
                    assert_eq!(
                        bits(shared.translation.vector.as_slice()),
                        bits(model.forward_kinematics(&q_ahead).translation.vector.as_slice())
                    );
                }
                let (a, b) = (plain.step(&model, &q_plain, &target, 1e-3), ahead.step(&model, &q_ahead, &target, 1e-3));
                assert_eq!(bits(a.q.as_slice()), bits(b.q.as_slice()), "step {k}");
                assert_eq!(bits(a.qd.as_slice()), bits(b.qd.as_slice()), "step {k}");
                assert_eq!((a.sigma_min.to_bits(), a.position_error.to_bits()), (b.sigma_min.to_bits(), b.position_error.to_bits()));
                assert!(ahead.kinematics_at(&model, &q_ahead).is_some(), "the last step's joints are known");
                (q_plain, q_ahead) = (a.q, b.q);
            }
        }
    }

    /// The warm start re-orthonormalised every [`ORTHONORMALIZE_EVERY`] steps stays orthonormal to
    /// 1e-13 at every step of 200,000 of a smoothly moving 6 × 7 matrix (measured: 3.6e-14).
    #[test]
    fn the_svd_warm_start_stays_orthonormal() {
        let mut start = identity_start();
        let mut age = 0;
        let mut worst: f64 = 0.0;
        for k in 0..200_000u32 {
            let t = k as f64 * 1e-3;
            let mut rows = [[0.0; MAX_JOINTS]; MAX_TASK];
            for (r, row) in rows.iter_mut().enumerate() {
                for (j, x) in row.iter_mut().enumerate().take(7) {
                    *x = ((r * 7 + j) as f64 * 0.37 + t * (0.5 + 0.1 * j as f64)).sin() + if r == j { 2.0 } else { 0.0 };
                }
            }
            let s = svd(&rows, 6, 7, &start);
            start = s.u;
            age += 1;
            if age >= ORTHONORMALIZE_EVERY {
                orthonormalize(&mut start, 6);
                age = 0;
            }
            for a in 0..6 {
                for b in 0..6 {
                    let d: f64 = (0..6).map(|r| start[a][r] * start[b][r]).sum();
                    worst = worst.max((d - if a == b { 1.0 } else { 0.0 }).abs());
                }
            }
        }
        assert!(worst < 1e-13, "the warm start drifted {worst:e} from orthonormal");
    }

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
