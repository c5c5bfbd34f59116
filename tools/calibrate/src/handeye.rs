//! The tracked base's hand–eye calibration, AX = XB, by Park and Martin's method: F. C. Park and
//! B. J. Martin, "Robot sensor calibration: solving AX = XB on the Euclidean group", IEEE Trans.
//! Robotics and Automation 10(5), 1994.
//!
//! A marker body is fixed to the flange (or the tool) and the tracker sees it while the arm moves
//! through N poses. At pose i the flange is F_i in B (FK) and the marker C_i in the tracker's frame
//! W (or, with the base body's poses, in the base body's frame): C_i = Z·F_i·X, with X the marker in
//! the flange frame and Z the base frame B in W, both unknown. Between poses i and j,
//! A = F_i⁻¹F_j (the flange's motion) and B = C_i⁻¹C_j (the marker's) satisfy A·X = X·B.
//!
//! Rotation: the rotation vectors α = log R_A, β = log R_B satisfy α = R_X·β, so R_X is the
//! orthogonal Procrustes fit of the β onto the α over all pairs (i < j): Park–Martin's closed form
//! R_X = (MᵀM)^(−½)·Mᵀ with M = Σ β·αᵀ, computed by the SVD of M so that it stays a rotation when
//! the data are noisy. It needs motions about at least two non-parallel axes: the ratio of M's
//! largest to smallest singular value is the condition reported and judged. Translation: the
//! stacked (R_A − I)·t_X = R_X·t_B − t_A by linear least squares. Then Z from each pose,
//! Z_i = C_i·X⁻¹·F_i⁻¹, averaged (the rotation nearest the mean of the R_Z, the mean translation),
//! and each pose's residual is how far Z·F_i·X lands from the measured C_i.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Translation3, Vector3};
use strand_core::kin::{Frame, geom};

use crate::error::CalibrationError;
use crate::linalg::{angle_between, least_squares, nearest_rotation, rpy_of};

/// Poses the solve needs at least (two motions about different axes need three poses; one more to check).
pub const MIN_POSES: usize = 4;
/// Above this rotation condition the solve is refused: the motions turn about (nearly) one axis.
pub const MAX_CONDITION: f64 = 50.0;
/// Above this rotation condition, a warning.
pub const WARN_CONDITION: f64 = 10.0;

/// The method's name, as printed and in `--json`.
pub const METHOD: &str = "park-martin";

/// The hand–eye answer.
#[derive(Clone, Debug, PartialEq)]
pub struct HandEyeFit {
    /// Z: the robot base frame B in the tracker's frame (or in the base body's frame, when the
    /// pairs carry its poses): `[base] mount` (m).
    pub mount: Frame,
    /// `mount`'s translation (m).
    pub mount_xyz: [f64; 3],
    /// `mount`'s rotation as URDF roll, pitch, yaw (rad).
    pub mount_rpy: [f64; 3],
    /// X: the flange's marker body in the flange frame (m).
    pub hand: Frame,
    /// Position residual per pose (mm): |Z·F_i·X − C_i|.
    pub residuals_mm: Vec<f64>,
    /// Rotation residual per pose (degrees).
    pub residuals_deg: Vec<f64>,
    /// Condition of the rotation fit (largest over smallest singular value of M, ≥ 1).
    pub condition: f64,
    /// Why the answer should be taken with care, if it should.
    pub warnings: Vec<String>,
}

/// Solves AX = XB from the flange poses `flanges` (FK, no tool; B) and the marker poses `markers`
/// measured at the same instants.
pub fn solve_hand_eye(flanges: &[Frame], markers: &[Frame]) -> Result<HandEyeFit, CalibrationError> {
    let n = flanges.len().min(markers.len());
    if flanges.len() != markers.len() {
        return Err(CalibrationError::BadValue {
            what: "pairs",
            reason: format!("{} arm poses but {} tracker poses", flanges.len(), markers.len()),
        });
    }
    if n < MIN_POSES {
        return Err(CalibrationError::TooFew { what: "pairs", needed: MIN_POSES, got: n });
    }
    let mut motions = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            motions.push((flanges[i].inverse() * flanges[j], markers[i].inverse() * markers[j]));
        }
    }
    // Rotation: α = R_X·β for every motion.
    let mut m = Matrix3::zeros();
    for (a, b) in &motions {
        let alpha = geom::rotation_vector(&a.rotation);
        let beta = geom::rotation_vector(&b.rotation);
        m += alpha * beta.transpose();
    }
    let sv = m.svd(false, false).singular_values;
    let (max, min) = (sv.max(), sv.min());
    let condition = if min > max * 1e-14 { max / min } else { f64::INFINITY };
    if !condition.is_finite() || condition > MAX_CONDITION {
        return Err(CalibrationError::degenerate(format!(
            "the arm's motions turn about one axis only (rotation condition {}): the marker's offset along that axis is not \
             determined; move the wrist about at least two different axes between poses (30° or more)",
            if condition.is_finite() { format!("{condition:.0}") } else { "infinite".into() }
        )));
    }
    let r_x = nearest_rotation(&m);
    // Translation: (R_A − I)·t_X = R_X·t_B − t_A.
    let rows = 3 * motions.len();
    let mut a = DMatrix::zeros(rows, 3);
    let mut b = DVector::zeros(rows);
    for (k, (ma, mb)) in motions.iter().enumerate() {
        a.view_mut((3 * k, 0), (3, 3)).copy_from(&(ma.rotation.matrix() - Matrix3::identity()));
        b.rows_mut(3 * k, 3).copy_from(&(r_x * mb.translation.vector - ma.translation.vector));
    }
    let (t, t_condition) = least_squares(&a, &b);
    if !t_condition.is_finite() || t_condition > 1e6 {
        return Err(CalibrationError::degenerate("the marker's offset is not determined by these motions: turn the wrist further"));
    }
    let hand = Frame::from_parts(Translation3::new(t[0], t[1], t[2]), r_x);
    // Z from every pose, averaged.
    let zs: Vec<Frame> = (0..n).map(|i| markers[i] * hand.inverse() * flanges[i].inverse()).collect();
    let r_sum: Matrix3<f64> = zs.iter().map(|z| *z.rotation.matrix()).sum();
    let r_z: Rotation3<f64> = nearest_rotation(&r_sum);
    let t_z: Vector3<f64> = zs.iter().map(|z| z.translation.vector).sum::<Vector3<f64>>() / n as f64;
    let mount = Frame::from_parts(Translation3::from(t_z), r_z);
    let mut residuals_mm = Vec::with_capacity(n);
    let mut residuals_deg = Vec::with_capacity(n);
    for i in 0..n {
        let predicted = mount * flanges[i] * hand;
        residuals_mm.push((predicted.translation.vector - markers[i].translation.vector).norm() * 1e3);
        residuals_deg.push(angle_between(&predicted.rotation, &markers[i].rotation).to_degrees());
    }
    let mut warnings = Vec::new();
    if condition > WARN_CONDITION {
        warnings.push(format!(
            "the arm's motions turn mostly about one axis (rotation condition {condition:.1} > {WARN_CONDITION}): move the wrist \
             about more axes"
        ));
    }
    Ok(HandEyeFit { mount_xyz: t_z.into(), mount_rpy: rpy_of(&r_z), mount, hand, residuals_mm, residuals_deg, condition, warnings })
}
