//! Joint snapshots: the arm's joints at each touch, one per line of a CSV file (joint angles in rad,
//! or m for a prismatic joint, in chain order; `#` comments allowed), and the poses the project's own
//! FK puts the arm in at each of them.
//!
//! ```text
//! # strand calibrate tool --snapshots touches.csv   (KR 6: A1..A6, rad)
//! 0.02, -1.31, 1.62, 0.40, 1.21, -0.35
//! -0.11, -1.29, 1.58, -0.52, 1.30, 0.61
//! ```

use std::path::Path;

use strand_core::kin::{Frame, JointVector, MAX_JOINTS, RobotModel};

use crate::error::CalibrationError;
use crate::rows;

/// The joints at one touch.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// 1-based line in the file it came from (0 when it was read live).
    pub line: usize,
    /// Joint positions in chain order (rad, or m for a prismatic joint).
    pub joints: Vec<f64>,
}

impl Snapshot {
    /// The joints as the core's joint vector (entries past the chain's joints 0).
    pub fn joint_vector(&self) -> JointVector {
        let mut q = JointVector::zeros();
        for (k, v) in self.joints.iter().take(MAX_JOINTS).enumerate() {
            q[k] = *v;
        }
        q
    }
}

/// Reads snapshots of a `dof`-joint chain from `text` (`file` names it in errors).
pub fn parse_snapshots(text: &str, file: &str, dof: usize) -> Result<Vec<Snapshot>, CalibrationError> {
    let expect = format!("{dof} joint angles (rad, chain order)");
    let rows = rows::parse(text, file, &|n| n == dof, &expect)?;
    Ok(rows.into_iter().map(|r| Snapshot { line: r.line, joints: r.values }).collect())
}

/// Reads a snapshot file of a `dof`-joint chain.
pub fn read_snapshots(path: &Path, dof: usize) -> Result<Vec<Snapshot>, CalibrationError> {
    parse_snapshots(&rows::read(path)?, &path.display().to_string(), dof)
}

/// The pose FK gives `model` at each snapshot (the model's tip, or its TCP if it carries a tool),
/// in its base frame B (m). A snapshot outside a joint's limits is kept (a touch is where the arm
/// was), but one with the wrong joint count is an error.
pub fn poses(model: &RobotModel, snapshots: &[Snapshot]) -> Result<Vec<Frame>, CalibrationError> {
    snapshots
        .iter()
        .map(|s| {
            if s.joints.len() != model.dof() {
                return Err(CalibrationError::Input {
                    file: "snapshot".into(),
                    line: s.line,
                    column: 0,
                    message: format!("{} joints, the chain has {}", s.joints.len(), model.dof()),
                });
            }
            Ok(model.forward_kinematics(&s.joint_vector()))
        })
        .collect()
}
