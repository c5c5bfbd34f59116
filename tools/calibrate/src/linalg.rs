//! The few linear-algebra steps the solvers share: a least-squares solve that reports its
//! condition instead of hiding it, the rotation nearest to a matrix, and URDF roll-pitch-yaw.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};

/// The least-squares solution of `a x = b` and the condition of `a` (largest over smallest singular
/// value; infinite when `a` is rank deficient). The caller judges the condition: a solution of an
/// ill-conditioned system is returned only for the caller to refuse or warn about.
pub(crate) fn least_squares(a: &DMatrix<f64>, b: &DVector<f64>) -> (DVector<f64>, f64) {
    let svd = a.clone().svd(true, true);
    let max = svd.singular_values.max();
    let min = svd.singular_values.min();
    let condition = if min > max * 1e-14 { max / min } else { f64::INFINITY };
    let x = svd.solve(b, max * 1e-14).unwrap_or_else(|_| DVector::zeros(a.ncols()));
    (x, condition)
}

/// The rotation nearest (Frobenius) to `m`, with determinant +1.
pub(crate) fn nearest_rotation(m: &Matrix3<f64>) -> Rotation3<f64> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u.unwrap_or_else(Matrix3::identity), svd.v_t.unwrap_or_else(Matrix3::identity));
    let d = (u * v_t).determinant().signum();
    let fix = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
    Rotation3::from_matrix_unchecked(u * fix * v_t)
}

/// URDF roll, pitch, yaw (rad) of `r` = Rz(yaw)·Ry(pitch)·Rx(roll) (`strand_core::kin::geom::rpy`'s
/// inverse).
pub(crate) fn rpy_of(r: &Rotation3<f64>) -> [f64; 3] {
    let (roll, pitch, yaw) = r.euler_angles();
    [roll, pitch, yaw]
}

/// The angle (rad) between two rotations, through the log map: `Rotation3::angle_to` takes the
/// arccosine of the trace, which is NaN for two equal rotations a rounding error off orthonormal.
pub(crate) fn angle_between(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    strand_core::kin::geom::rotation_vector(&(a.inverse() * b)).norm()
}
