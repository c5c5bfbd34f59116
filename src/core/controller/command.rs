//! The final command stage: the joint command and its limits. Every command passes here; every
//! joint's position, velocity and acceleration limits are enforced on it, each clamp counted, and
//! the brake that a fault or an emergency stop uses is computed from it.

use crate::kin::{JointVector, RobotModel};

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
    pub(super) fn brake(&self, model: &RobotModel, dt: f64) -> JointVector {
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
    pub(super) fn limit(&mut self, model: &RobotModel, dt: f64, q_des: &JointVector) -> Option<u8> {
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
