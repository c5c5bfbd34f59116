//! The bed (or a work piece) frame from touched points: the origin, a point on +x, a point on the
//! +y side (the "3-point" base frame of every robot controller), and any number more on the surface,
//! with a least-squares plane through them all and its flatness.
//!
//! The plane is the total-least-squares one (through the centroid, normal along the smallest
//! singular vector of the centred points); for three points it is their plane. Then z is that
//! normal, turned to the side of (p₁ − p₀) × (p₂ − p₀), so the order of the first three touches
//! says which way is up; x is p₀ → p₁ projected into the plane; the origin is p₀ projected onto it.
//! Flatness is peak-to-valley of the points' distances from the plane (the least-squares estimate of
//! the ISO minimum-zone flatness; it is never smaller).

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector3};

use crate::error::CalibrationError;
use crate::linalg::rpy_of;

/// Points the solve needs at least.
pub const MIN_POINTS: usize = 3;
/// Shortest origin → +x distance (m) that gives the x direction to better than a degree or so.
pub const MIN_X_DISTANCE: f64 = 10e-3;
/// Least distance (m) of the third point from the x line, and least spread (RMS, m) of all the points
/// across their main direction: below either the points are (nearly) collinear.
pub const MIN_OFF_LINE: f64 = 5e-3;

/// The frame found.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameFit {
    /// The frame's origin in the frame the points were given in (m): `[bed] frame.xyz`.
    pub xyz: [f64; 3],
    /// The frame's orientation as URDF roll, pitch, yaw (rad): `[bed] frame.rpy`.
    pub rpy: [f64; 3],
    /// The same orientation as a rotation (columns: the frame's x, y, z axes).
    pub rotation: Rotation3<f64>,
    /// Peak-to-valley of the points' distances from the plane (mm); 0 for three points.
    pub flatness_mm: f64,
    /// Signed distance (mm) of each point from the plane, along z.
    pub residuals_mm: Vec<f64>,
}

/// The frame through `points` (origin, +x, +y side, then any more on the surface), all in one
/// frame (m). `nozzle`, if given, is the nozzle's mean direction at the touches in that frame: the
/// frame's z must oppose it (a nozzle points into the bed), else the +y point was on the wrong side.
pub fn solve_frame(points: &[Vector3<f64>], nozzle: Option<Vector3<f64>>) -> Result<FrameFit, CalibrationError> {
    let n = points.len();
    if n < MIN_POINTS {
        return Err(CalibrationError::TooFew { what: "points", needed: MIN_POINTS, got: n });
    }
    let (p0, p1, p2) = (points[0], points[1], points[2]);
    let along = p1 - p0;
    if along.norm() < MIN_X_DISTANCE {
        return Err(CalibrationError::degenerate(format!(
            "the +x point is {:.1} mm from the origin: touch it at least {:.0} mm away along the bed's x",
            along.norm() * 1e3,
            MIN_X_DISTANCE * 1e3
        )));
    }
    let x_line = along.normalize();
    let off = (p2 - p0) - x_line * x_line.dot(&(p2 - p0));
    if off.norm() < MIN_OFF_LINE {
        return Err(CalibrationError::degenerate(format!(
            "the third point is {:.2} mm off the line through the origin and the +x point (the three are collinear): touch \
             it at least {:.0} mm to the +y side",
            off.norm() * 1e3,
            MIN_OFF_LINE * 1e3
        )));
    }
    let centroid: Vector3<f64> = points.iter().sum::<Vector3<f64>>() / n as f64;
    let mut centred = DMatrix::zeros(n, 3);
    for (i, p) in points.iter().enumerate() {
        centred.row_mut(i).copy_from(&(p - centroid).transpose());
    }
    let svd = centred.svd(false, true);
    let v_t = svd.v_t.ok_or_else(|| CalibrationError::degenerate("the plane fit did not converge"))?;
    // nalgebra does not promise the singular values in order: sort them.
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let spread = svd.singular_values[order[1]] / (n as f64).sqrt();
    if spread < MIN_OFF_LINE {
        return Err(CalibrationError::degenerate(format!(
            "the points lie on a line (RMS spread across it {:.2} mm): touch points spread over the surface",
            spread * 1e3
        )));
    }
    let row = v_t.row(order[2]);
    let mut z = Vector3::new(row[0], row[1], row[2]).normalize();
    if z.dot(&along.cross(&(p2 - p0))) < 0.0 {
        z = -z;
    }
    if let Some(d) = nozzle
        && d.norm() > 0.0
        && z.dot(&d.normalize()) > 0.0
    {
        return Err(CalibrationError::degenerate(
            "with these touches the bed's z would point along the nozzle, into the bed: touch the third point on the other \
             side of the x line (origin, +x, then a point on the +y side)",
        ));
    }
    let x = (along - z * z.dot(&along)).normalize();
    let y = z.cross(&x);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    let origin = p0 - z * z.dot(&(p0 - centroid));
    let residuals_mm: Vec<f64> = points.iter().map(|p| z.dot(&(p - centroid)) * 1e3).collect();
    let max = residuals_mm.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let min = residuals_mm.iter().copied().fold(f64::INFINITY, f64::min);
    let flatness_mm = if n == 3 { 0.0 } else { max - min };
    Ok(FrameFit { xyz: origin.into(), rpy: rpy_of(&rotation), rotation, flatness_mm, residuals_mm })
}
