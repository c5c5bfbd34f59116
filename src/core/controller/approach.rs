//! The approach: a joint-space move to a job's first point, without extruding. The inverse
//! kinematics of the first point is solved a few iterations per tick (so no tick takes long), then
//! one rsruckig trajectory, jerk-limited and with every joint synchronised, takes the arm there at
//! `[controller] approach_speed_fraction` of its limits. A positioner's axes move in the same
//! trajectory to where the job starts them, and the first point is solved where they put the work.

use nalgebra::{UnitQuaternion, Vector3};
use rsruckig::prelude::*;

use strand_wire::MAX_EXTERNAL_AXES;

use super::command::CellJoints;
use crate::base::BaseState;
use crate::kin::{Clik, JointVector, RobotModel, TcpTarget};
use crate::positioner::Positioner;

/// Where a job starts: the first point (m, W, in the work frame at home), the tool orientation
/// there, and the positioner's axes (rad or m).
pub(super) type FirstPoint = (Vector3<f64>, UnitQuaternion<f64>, [f64; MAX_EXTERNAL_AXES]);

/// IK iterations per tick while solving for the first point, and in total before giving up.
const IK_ITERATIONS_PER_TICK: u32 = 25;
const IK_ITERATIONS_MAX: u32 = 4000;
/// IK iterations from one seed before the next is tried (see [`reseed`]).
const IK_ITERATIONS_PER_SEED: u32 = 1000;

/// The seed the IK of the first point starts from after `attempt` seeds did not converge: from
/// where the arm is (attempt 0, not here); then with its wrist (the last three joints) in the
/// middle of their ranges, the rest as it is; then every joint in the middle of its range.
fn reseed(model: &RobotModel, q: &JointVector, attempt: u32) -> JointVector {
    let n = model.dof();
    let middle = model.middle_configuration();
    let mut seed = *q;
    let first = if attempt == 1 { n.saturating_sub(3) } else { 0 };
    for i in first..n {
        seed[i] = middle[i];
    }
    seed
}

/// Where the approach is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Solving the inverse kinematics of the first point, a few iterations per tick.
    Solving { iterations: u32 },
    /// Following the joint-space trajectory.
    Moving,
}

/// What one tick of the approach asks of the controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum ApproachStep {
    /// Hold the current command (still solving the IK).
    Hold,
    /// Command these joints (rad or m); [`Approach::done`] tells whether it is the last point.
    Move(JointVector),
    /// No IK solution within the iteration budget, or no trajectory: the approach failed.
    Failed,
}

/// The approach move and its state.
pub(super) struct Approach {
    otg: Ruckig<0, IgnoreErrorHandler>,
    input: InputParameter<0>,
    output: OutputParameter<0>,
    phase: Phase,
    /// The IK solver for the first point (a copy of the CLIK's settings, its own state).
    ik: Clik,
    /// The IK target (B), fixed when the approach starts.
    target: TcpTarget,
    /// The joints that reach the first point (rad or m).
    q_first: JointVector,
    /// The trajectory reached its end this tick.
    pub(super) done: bool,
}

impl Approach {
    /// An approach for the cell's joints at `speed_fraction` of their limits, ticking every `dt` s.
    pub(super) fn new(model: &CellJoints, speed_fraction: f64, dt: f64, ik: Clik) -> Self {
        let n = model.dof();
        let mut input = InputParameter::new(Some(n));
        input.synchronization = Synchronization::Time;
        for i in 0..n {
            let l = model.limits(i);
            input.max_velocity[i] = l.velocity * speed_fraction;
            input.max_acceleration[i] = l.acceleration * speed_fraction;
            input.max_jerk[i] = l.jerk * speed_fraction;
        }
        Approach {
            otg: Ruckig::new(Some(n), dt),
            input,
            output: OutputParameter::new(Some(n)),
            phase: Phase::Moving,
            ik,
            target: TcpTarget::at_rest(Vector3::zeros(), UnitQuaternion::identity()),
            q_first: JointVector::zeros(),
            done: false,
        }
    }

    /// Starts a new approach from the joints `q`.
    pub(super) fn begin(&mut self, q: &JointVector) {
        self.ik.reset(JointVector::zeros());
        self.q_first = *q;
        self.phase = Phase::Solving { iterations: 0 };
    }

    /// The robot is at `q` (rad or m) moving at `qd` (rad/s or m/s) instead of where the
    /// trajectory put it (its driver held it for a cycle or more): the rest of the move starts
    /// again from there. Whether the move was under way (while the IK is still solved the command
    /// stands still anyway).
    pub(super) fn restart_from(&mut self, q: &JointVector, qd: &JointVector, dof: usize) -> bool {
        if self.phase != Phase::Moving || self.done {
            return false;
        }
        for i in 0..dof {
            self.input.current_position[i] = q[i];
            self.input.current_velocity[i] = qd[i];
            self.input.current_acceleration[i] = 0.0;
        }
        true
    }

    /// One tick towards `first_point` (W) from the command (`q`, `qd`, `qdd`: the cell's joints)
    /// through `base`, the work where `positioner` puts it with the first point's axes.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn step(
        &mut self,
        model: &RobotModel,
        joints: &CellJoints,
        positioner: Option<&Positioner>,
        first_point: FirstPoint,
        base: &BaseState,
        (q, qd, qdd): (&JointVector, &JointVector, &JointVector),
    ) -> ApproachStep {
        let (arm, n) = (joints.arm(), joints.dof());
        if let Phase::Solving { iterations } = self.phase {
            if iterations == 0 {
                // The IK target is fixed when the approach starts; if the base moves meanwhile, the
                // CLIK takes up the difference when the path starts.
                let mut b = base.world_to_base(&TcpTarget::at_rest(first_point.0, first_point.1));
                if let Some(p) = positioner {
                    b = p.carry(&b, &first_point.2, &[0.0; MAX_EXTERNAL_AXES]);
                }
                self.target = TcpTarget::at_rest(b.position, b.orientation);
            }
            let target = self.target;
            let mut done = false;
            let mut k = iterations;
            while k < iterations + IK_ITERATIONS_PER_TICK {
                // A virtual tick of 0.1 s: each iteration is a Newton step within the joint limits.
                let r = self.ik.step(model, &self.q_first, &target, 0.1);
                self.q_first = r.q;
                k += 1;
                if r.position_error < 1e-7 && r.orientation_error < 1e-6 {
                    done = true;
                    break;
                }
            }
            if !done {
                if k >= IK_ITERATIONS_MAX {
                    return ApproachStep::Failed;
                }
                if k.is_multiple_of(IK_ITERATIONS_PER_SEED) {
                    // Stuck from this seed (a far start: a wrist turned well away from the job, a
                    // joint against its limit): start again from another.
                    self.q_first = reseed(model, q, k / IK_ITERATIONS_PER_SEED);
                    self.ik.reset(JointVector::zeros());
                }
                self.phase = Phase::Solving { iterations: k };
                return ApproachStep::Hold;
            }
            for i in 0..n {
                self.input.current_position[i] = q[i];
                self.input.current_velocity[i] = qd[i];
                self.input.current_acceleration[i] = qdd[i];
                self.input.target_position[i] = if i < arm { self.q_first[i] } else { first_point.2[i - arm] };
                self.input.target_velocity[i] = 0.0;
                self.input.target_acceleration[i] = 0.0;
            }
            self.phase = Phase::Moving;
        }
        match self.otg.update(&self.input, &mut self.output) {
            Ok(RuckigResult::Working) => {
                let mut next = *q;
                for i in 0..n {
                    next[i] = self.output.new_position[i];
                }
                self.output.pass_to_input(&mut self.input);
                ApproachStep::Move(next)
            }
            Ok(RuckigResult::Finished) => {
                let mut next = *q;
                for i in 0..n {
                    next[i] = self.output.new_position[i];
                }
                self.done = true;
                ApproachStep::Move(next)
            }
            _ => ApproachStep::Failed,
        }
    }
}
