//! Hand–eye pairs: at each pose of the arm, its joints and the tracker's pose of a marker body
//! fixed to the flange (or tool), one pair per line of a CSV file:
//!
//! ```text
//! # q1..qn (rad, chain order), then the flange marker in the tracker's frame:
//! #   x, y, z (m), qw, qx, qy, qz (unit quaternion)
//! # optionally 7 more: the base's own marker body at the same instant (x, y, z, qw, qx, qy, qz);
//! # with them the answer is the base frame B in the base body's frame instead of in the tracker's.
//! 0.1, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0,   1.204, -0.310, 0.822,   0.0123, 0.7071, -0.7070, 0.0051
//! ```
//!
//! Either every line has the base body's columns or none does.

use std::path::Path;

use nalgebra::{Quaternion, Translation3, UnitQuaternion};
use strand_core::kin::Frame;

use crate::error::CalibrationError;
use crate::rows::{self, Row};
use crate::snapshots::Snapshot;

/// Columns of one tracked pose: x, y, z, qw, qx, qy, qz.
pub const POSE_COLUMNS: usize = 7;

/// How far from 1 a quaternion's norm may be (it is normalised; further off is a typo).
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// One hand–eye pair.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair {
    /// The arm's joints (rad, chain order) and the line they came from.
    pub snapshot: Snapshot,
    /// The flange's marker body in the tracker's frame (m, unit rotation).
    pub marker: Frame,
    /// The base's marker body in the tracker's frame at the same instant (m), if given.
    pub base_body: Option<Frame>,
}

/// A tracked pose from x, y, z (m) and a quaternion (w, x, y, z); `column` is where `v` starts.
pub fn pose_from(v: &[f64], file: &str, line: usize, column: usize) -> Result<Frame, CalibrationError> {
    let q = Quaternion::new(v[3], v[4], v[5], v[6]);
    let norm = q.norm();
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(CalibrationError::Input {
            file: file.into(),
            line,
            column,
            message: format!("quaternion (w, x, y, z) has norm {norm:.6}, not 1"),
        });
    }
    let r = UnitQuaternion::from_quaternion(q).to_rotation_matrix();
    Ok(Frame::from_parts(Translation3::new(v[0], v[1], v[2]), r))
}

/// Reads pairs of a `dof`-joint chain from `text` (`file` names it in errors).
pub fn parse_pairs(text: &str, file: &str, dof: usize) -> Result<Vec<Pair>, CalibrationError> {
    let (short, long) = (dof + POSE_COLUMNS, dof + 2 * POSE_COLUMNS);
    let expect = format!("{dof} joint angles then 7 pose columns (x, y, z, qw, qx, qy, qz): {short}, or {long} with the base body's pose");
    let rows = rows::parse(text, file, &|n| n == short || n == long, &expect)?;
    let mut pairs = Vec::with_capacity(rows.len());
    for Row { line, values, columns } in &rows {
        let marker = pose_from(&values[dof..short], file, *line, columns[dof + 3])?;
        let base_body = if values.len() == long { Some(pose_from(&values[short..long], file, *line, columns[short + 3])?) } else { None };
        if let Some(first) = pairs.first().map(|p: &Pair| p.base_body.is_some())
            && first != base_body.is_some()
        {
            return Err(CalibrationError::Input {
                file: file.into(),
                line: *line,
                column: 0,
                message: "every line has the base body's 7 columns or none does".into(),
            });
        }
        pairs.push(Pair { snapshot: Snapshot { line: *line, joints: values[..dof].to_vec() }, marker, base_body });
    }
    Ok(pairs)
}

/// Reads a pairs file of a `dof`-joint chain.
pub fn read_pairs(path: &Path, dof: usize) -> Result<Vec<Pair>, CalibrationError> {
    parse_pairs(&rows::read(path)?, &path.display().to_string(), dof)
}
