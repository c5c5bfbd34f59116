//! The tool centre point from touches: the nozzle tip held on one fixed point from several
//! orientations (the "4-point" TCP method of every robot controller), solved by linear least
//! squares, and the nozzle's axis from touches further up it.
//!
//! At touch i the flange is at (R_i, p_i) in the base frame B (FK of the snapshot, no tool), the tip
//! at t in the flange frame and the fixed point at P in B: R_i·t + p_i = P. Stacked, the unknowns
//! (t, P) solve `[R_i  −I]·[t; P] = −p_i` (3N equations, 6 unknowns). Why the condition is the
//! measure of "too alike": AᵀA = [N·I, −ΣR_iᵀ; −ΣR_i, N·I] has eigenvalues N·(1 ± m_k), m_k the
//! singular values of the mean rotation (1/N)·ΣR_i, so cond(A) = √((1 + m)/(1 − m)) with m the
//! largest: orientations that all share a rotation about one axis (or are all the same) leave an
//! m = 1 and the offset along that axis undetermined, and a touch error is amplified by about the
//! condition. (Cf. Jmeyer1292/tool_point_calibration, which solves the same stacked system.)

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};
use strand_core::kin::Frame;

use crate::error::CalibrationError;
use crate::linalg::{angle_between, least_squares, rpy_of};

/// Touches the solve needs at least (3 determine it; the fourth is the check).
pub const MIN_TOUCHES: usize = 4;
/// Above this condition the orientations are too alike: a warning (a touch error is amplified about
/// this much; six touches tilted ±30° in different directions give ≈ 5, ±3° ≈ 50).
pub const WARN_CONDITION: f64 = 10.0;
/// Above this condition the solve is refused: the offset along some axis is not determined.
pub const MAX_CONDITION: f64 = 1000.0;
/// Shortest distance (m) from the tip to an axis touch for it to say anything about the direction.
pub const MIN_AXIS_DISTANCE: f64 = 5e-3;

/// The tool offset and the touched point.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolFit {
    /// The nozzle tip in the flange frame (m): `[tool] xyz`.
    pub xyz: Vector3<f64>,
    /// The fixed point touched, in the robot base frame B (m).
    pub point: Vector3<f64>,
    /// Distance (mm) from the fixed point to where each touch put the tip, in snapshot order.
    pub residuals_mm: Vec<f64>,
    /// The condition of the stacked system (largest over smallest singular value, ≥ 1).
    pub condition: f64,
    /// Why the answer should be taken with care (orientations too alike), if it should.
    pub warnings: Vec<String>,
}

/// Solves the tip offset and the fixed point from the flange poses of ≥ 4 touches (FK with no tool).
pub fn solve_tcp(flanges: &[Frame]) -> Result<ToolFit, CalibrationError> {
    let n = flanges.len();
    if n < MIN_TOUCHES {
        return Err(CalibrationError::TooFew { what: "touches", needed: MIN_TOUCHES, got: n });
    }
    let mut a = DMatrix::zeros(3 * n, 6);
    let mut b = DVector::zeros(3 * n);
    for (i, f) in flanges.iter().enumerate() {
        a.view_mut((3 * i, 0), (3, 3)).copy_from(f.rotation.matrix());
        a.view_mut((3 * i, 3), (3, 3)).copy_from(&(-Matrix3::identity()));
        b.rows_mut(3 * i, 3).copy_from(&(-f.translation.vector));
    }
    let (x, condition) = least_squares(&a, &b);
    if !condition.is_finite() || condition > MAX_CONDITION {
        let spread = orientation_spread_deg(flanges);
        return Err(CalibrationError::degenerate(format!(
            "the {n} orientations are too alike to locate the tip (condition {}; they differ by at most {spread:.1}°, or turn \
             about one axis only): touch the point again with the nozzle tilted 20–40° in different directions",
            fmt_condition(condition)
        )));
    }
    let xyz = Vector3::new(x[0], x[1], x[2]);
    let point = Vector3::new(x[3], x[4], x[5]);
    let residuals_mm = flanges.iter().map(|f| (f * nalgebra::Point3::from(xyz) - nalgebra::Point3::from(point)).norm() * 1e3).collect();
    let mut warnings = Vec::new();
    if condition > WARN_CONDITION {
        warnings.push(format!(
            "the orientations are alike (condition {condition:.1} > {WARN_CONDITION}): a touch error of 0.1 mm moves the tip by \
             about {:.1} mm; tilt the nozzle further between touches",
            0.1 * condition
        ));
    }
    Ok(ToolFit { xyz, point, residuals_mm, condition, warnings })
}

fn fmt_condition(c: f64) -> String {
    if c.is_finite() { format!("{c:.3e}") } else { "infinite".into() }
}

/// The largest angle (degrees) between any two of the flange orientations.
fn orientation_spread_deg(flanges: &[Frame]) -> f64 {
    let mut max: f64 = 0.0;
    for (i, a) in flanges.iter().enumerate() {
        for b in &flanges[i + 1..] {
            max = max.max(angle_between(&a.rotation, &b.rotation));
        }
    }
    max.to_degrees()
}

/// The nozzle's axis in the flange frame from touches up the nozzle.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisFit {
    /// Unit direction of the nozzle in the flange frame, from up the nozzle towards the tip (the
    /// TCP's z axis).
    pub z: Vector3<f64>,
    /// Distance (mm) of each axis touch from the fitted axis.
    pub residuals_mm: Vec<f64>,
    /// The tool rotation (flange → TCP) with this z and the x axis nearest the current tool's.
    pub rotation: Rotation3<f64>,
    /// That rotation as `[tool] rpy` (rad).
    pub rpy: [f64; 3],
    /// Angle (degrees) between this axis and the current tool's z.
    pub change_deg: f64,
}

/// The nozzle axis from `axis_flanges`: flange poses (FK, no tool) at which a point further up the
/// nozzle, on its axis, touches the same fixed point as [`solve_tcp`]'s touches. Each gives that
/// point in the flange frame, s_k = F_k⁻¹·P; the axis is the line through the tip t that fits them
/// best (least squares, the principal direction of s_k − t). `current` is the configured tool
/// rotation, whose x axis is kept as near as the new z allows (for the 5-D print task the turn about
/// the nozzle is free anyway).
pub fn solve_axis(tcp: &ToolFit, axis_flanges: &[Frame], current: &Rotation3<f64>) -> Result<AxisFit, CalibrationError> {
    if axis_flanges.is_empty() {
        return Err(CalibrationError::TooFew { what: "axis touches", needed: 1, got: 0 });
    }
    let t = tcp.xyz;
    let ups: Vec<Vector3<f64>> = axis_flanges.iter().map(|f| f.inverse_transform_point(&tcp.point.into()).coords - t).collect();
    for (k, u) in ups.iter().enumerate() {
        if u.norm() < MIN_AXIS_DISTANCE {
            return Err(CalibrationError::degenerate(format!(
                "axis touch {} is {:.1} mm from the tip: touch the point at least {:.0} mm up the nozzle",
                k + 1,
                u.norm() * 1e3,
                MIN_AXIS_DISTANCE * 1e3
            )));
        }
    }
    let scatter: Matrix3<f64> = ups.iter().map(|u| u * u.transpose()).sum();
    let eig = scatter.symmetric_eigen();
    let k = eig.eigenvalues.imax();
    let mut up = eig.eigenvectors.column(k).into_owned();
    if up.dot(&ups[0]) < 0.0 {
        up = -up;
    }
    let residuals_mm = ups.iter().map(|u| (u - up * up.dot(u)).norm() * 1e3).collect();
    // The nozzle points from up the nozzle to the tip.
    let z = -up.normalize();
    let x_old = current * Vector3::x();
    let mut x = x_old - z * z.dot(&x_old);
    if x.norm() < 1e-6 {
        x = strand_core::kin::geom::any_perpendicular(&nalgebra::Unit::new_normalize(z)).into_inner();
    }
    let x = x.normalize();
    let y = z.cross(&x);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    let change_deg = (current * Vector3::z()).angle(&z).to_degrees();
    Ok(AxisFit { z, residuals_mm, rpy: rpy_of(&rotation), rotation, change_deg })
}
