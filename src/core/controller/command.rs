//! The final command stage: the joint command and its limits. Every command passes here; every
//! joint's position, velocity and acceleration limits are enforced on it, each clamp counted, and
//! the brake that a fault or an emergency stop uses is computed from it. The joints are the cell's
//! ([`CellJoints`]): the arm's, then its positioner's external axes.

use crate::kin::{JointLimits, JointVector, MAX_JOINTS, RobotModel};
use crate::positioner::Positioner;

/// The joints a joint command carries, in order: the arm's chain, then the positioner's axes.
#[derive(Clone, Copy, Debug)]
pub(super) struct CellJoints {
    limits: [JointLimits; MAX_JOINTS],
    /// The arm's joints (the first `arm`).
    arm: usize,
    /// All of them.
    count: usize,
}

impl CellJoints {
    /// The arm's joints and, if the cell has one, the positioner's (the caller checked that they fit).
    pub(super) fn new(model: &RobotModel, positioner: Option<&Positioner>) -> Self {
        let none = JointLimits { lower: 0.0, upper: 0.0, velocity: 0.0, acceleration: 0.0, jerk: 0.0 };
        let mut limits = [none; MAX_JOINTS];
        let arm = model.dof();
        for (i, l) in limits.iter_mut().enumerate().take(arm) {
            *l = *model.limits(i);
        }
        let mut count = arm;
        if let Some(p) = positioner {
            for i in 0..p.dof() {
                limits[arm + i] = *p.model().limits(i);
            }
            count += p.dof();
        }
        CellJoints { limits, arm, count }
    }

    /// All the cell's joints.
    pub(super) fn dof(&self) -> usize {
        self.count
    }

    /// The arm's.
    pub(super) fn arm(&self) -> usize {
        self.arm
    }

    /// Limits of joint `i` (chain order, the external axes after the arm's).
    pub(super) fn limits(&self, i: usize) -> &JointLimits {
        &self.limits[i]
    }

    /// A joint vector of the first `dof()` values of `q`; None if one is not finite.
    pub(super) fn vector(&self, q: &[f64]) -> Option<JointVector> {
        let q = q.get(..self.count)?;
        if q.iter().any(|x| !x.is_finite()) {
            return None;
        }
        let mut v = JointVector::zeros();
        v.as_mut_slice()[..self.count].copy_from_slice(q);
        Some(v)
    }
}

/// Joint speed below which a braking arm counts as stopped (rad/s or m/s).
const AT_REST: f64 = 1e-9;

/// The joint command (rad or m, and their rates) and its clamp bookkeeping.
pub(super) struct JointCommandStage {
    /// The robot's joints are known (a joint state arrived): commands are valid.
    pub(super) known: bool,
    /// Position (rad or m).
    pub(super) q: JointVector,
    /// Velocity (rad/s or m/s).
    pub(super) qd: JointVector,
    /// Acceleration (rad/s² or m/s²).
    pub(super) qdd: JointVector,
    /// The last command was clamped (a run of clamped ticks reports one event).
    was_clamped: bool,
    /// Ticks whose command was clamped (count).
    pub(super) clamps: u64,
}

impl JointCommandStage {
    /// At `q`, at rest, not yet known.
    pub(super) fn new(q: JointVector) -> Self {
        JointCommandStage { known: false, q, qd: JointVector::zeros(), qdd: JointVector::zeros(), was_clamped: false, clamps: 0 }
    }

    /// Some of the first `dof` joints still move.
    pub(super) fn is_moving(&self, dof: usize) -> bool {
        self.qd.iter().take(dof).any(|v| v.abs() > AT_REST)
    }

    /// Stands still where the command is.
    pub(super) fn hold_still(&mut self) {
        self.qd = JointVector::zeros();
        self.qdd = JointVector::zeros();
    }

    /// Joint brake: every joint slows at its acceleration limit or less, all by one common factor
    /// (the direction of motion is kept, so the tool leaves the path as little as braking allows).
    pub(super) fn brake(&self, model: &CellJoints, dt: f64) -> JointVector {
        let n = model.dof();
        let mut factor: f64 = 1.0;
        for i in 0..n {
            let v = self.qd[i].abs();
            if v > 0.0 {
                factor = factor.min((1.0 - model.limits(i).acceleration * dt / v).max(0.0));
            }
        }
        let mut q = self.q;
        for i in 0..n {
            q[i] += self.qd[i] * factor * dt;
        }
        q
    }

    /// Moves the command towards `q_des` within every joint's position, velocity and acceleration
    /// limits, by the rule the drivers' reply guard keeps too ([`crate::kin::JointLimits::step`]:
    /// it brakes before a position limit rather than stop on it dead). Returns the first clamped
    /// joint when this tick starts a run of clamped ticks (the controller reports it once).
    pub(super) fn limit(&mut self, model: &CellJoints, dt: f64, q_des: &JointVector) -> Option<u8> {
        let n = model.dof();
        let mut clamped = None;
        for i in 0..n {
            let s = model.limits(i).step(self.q[i], self.qd[i], (q_des[i] - self.q[i]) / dt, dt);
            if s.clamped {
                clamped.get_or_insert(i);
            }
            self.qdd[i] = (s.velocity - self.qd[i]) / dt;
            self.qd[i] = s.velocity;
            self.q[i] = s.position;
        }
        match clamped {
            Some(joint) => {
                self.clamps += 1;
                let first = !self.was_clamped;
                self.was_clamped = true;
                first.then_some(joint as u8)
            }
            None => {
                self.was_clamped = false;
                None
            }
        }
    }
}
