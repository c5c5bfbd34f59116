//! Rotation arithmetic that must give the same bits on every machine.
//!
//! Trigonometry goes through the `libm` crate (a pure-Rust port of musl's libm) rather than the
//! platform's C library, so a log recorded on the robot PC replays to the bit on a laptop with a
//! different glibc. Everything else is plain IEEE-754 arithmetic, which Rust does not reorder or
//! fuse unless asked to.

use nalgebra::{Matrix3, Rotation3, Unit, UnitQuaternion, Vector3};

/// Rotation by `angle` (rad) about the unit `axis`, by Rodrigues' formula.
#[inline]
pub fn axis_angle(axis: &Vector3<f64>, angle: f64) -> Rotation3<f64> {
    let (s, c) = libm::sincos(angle);
    let t = 1.0 - c;
    let (x, y, z) = (axis.x, axis.y, axis.z);
    Rotation3::from_matrix_unchecked(Matrix3::new(
        t * x * x + c,
        t * x * y - s * z,
        t * x * z + s * y,
        t * x * y + s * z,
        t * y * y + c,
        t * y * z - s * x,
        t * x * z - s * y,
        t * y * z + s * x,
        t * z * z + c,
    ))
}

/// URDF's `rpy`: fixed-axis roll about x, then pitch about y, then yaw about z, i.e.
/// R = Rz(yaw) · Ry(pitch) · Rx(roll).
pub fn rpy(roll: f64, pitch: f64, yaw: f64) -> Rotation3<f64> {
    axis_angle(&Vector3::z(), yaw) * axis_angle(&Vector3::y(), pitch) * axis_angle(&Vector3::x(), roll)
}

/// The rotation vector (axis · angle, angle in [0, π]) of `r`: the log map of SO(3), computed through
/// the quaternion so that it stays accurate for small and for near-π angles.
pub fn rotation_vector(r: &Rotation3<f64>) -> Vector3<f64> {
    quaternion_log(&UnitQuaternion::from_rotation_matrix(r))
}

/// The rotation vector of a unit quaternion (w, x, y, z), taking the shorter of the two ways round.
pub(crate) fn quaternion_log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = (q.w, q.imag());
    let (w, v) = if w < 0.0 { (-w, -v) } else { (w, v) };
    let s = v.norm();
    if s < 1e-12 {
        // sin(θ/2) ≈ θ/2 here; the factor 2 makes this the first-order term of the exact formula.
        return v * 2.0;
    }
    v * (2.0 * libm::atan2(s, w) / s)
}

/// The smallest rotation vector that turns the unit vector `from` onto the unit vector `to`.
/// When they are opposite, the turn is about `fallback` (any unit vector perpendicular to `from`).
pub(crate) fn swing_vector(from: &Vector3<f64>, to: &Vector3<f64>, fallback: &Vector3<f64>) -> Vector3<f64> {
    let c = from.cross(to);
    let s = c.norm();
    let d = from.dot(to);
    let angle = libm::atan2(s, d);
    if s > 1e-12 {
        c * (angle / s)
    } else if d > 0.0 {
        Vector3::zeros()
    } else {
        fallback * angle
    }
}

/// A unit vector perpendicular to `a` (unit), chosen deterministically from the axis least aligned with it.
pub fn any_perpendicular(a: &Unit<Vector3<f64>>) -> Unit<Vector3<f64>> {
    let pick = if a.x.abs() <= a.y.abs() && a.x.abs() <= a.z.abs() {
        Vector3::x()
    } else if a.y.abs() <= a.z.abs() {
        Vector3::y()
    } else {
        Vector3::z()
    };
    Unit::new_normalize(a.cross(&pick))
}

/// The unit quaternion of a rotation vector (angle × axis), the inverse of [`quaternion_log`].
pub(crate) fn quaternion_exp(rotation: &Vector3<f64>) -> UnitQuaternion<f64> {
    let angle = rotation.norm();
    if angle < 1e-12 {
        let h = rotation * 0.5;
        return UnitQuaternion::new_normalize(nalgebra::Quaternion::new(1.0, h.x, h.y, h.z));
    }
    let (s, c) = libm::sincos(0.5 * angle);
    let v = rotation * (s / angle);
    UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(c, v.x, v.y, v.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rodrigues_matches_nalgebra() {
        let axis = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
        for &a in &[-3.0, -1.0, 0.0, 0.4, 2.9] {
            let mine = axis_angle(&axis, a);
            let theirs = Rotation3::from_axis_angle(&axis, a);
            assert!((mine.matrix() - theirs.matrix()).norm() < 1e-15);
        }
    }

    #[test]
    fn rpy_matches_nalgebra_euler() {
        let mine = rpy(0.1, -0.7, 2.0);
        let theirs = Rotation3::from_euler_angles(0.1, -0.7, 2.0);
        assert!((mine.matrix() - theirs.matrix()).norm() < 1e-15);
    }

    #[test]
    fn log_inverts_exp() {
        for v in [Vector3::new(0.0, 0.0, 1e-9), Vector3::new(0.3, -0.2, 1.0), Vector3::new(3.1, 0.0, 0.0)] {
            let r = Rotation3::new(v);
            assert!((rotation_vector(&r) - v).norm() < 1e-12, "{v:?}");
        }
    }

    #[test]
    fn swing_turns_from_onto_to() {
        let from = Vector3::new(0.0, 0.0, 1.0);
        let to = Vector3::new(1.0, 1.0, 0.2).normalize();
        let r = Rotation3::new(swing_vector(&from, &to, &Vector3::x()));
        assert!((r * from - to).norm() < 1e-14);
        let back = swing_vector(&from, &(-from), &Vector3::x());
        assert!((back.norm() - std::f64::consts::PI).abs() < 1e-15);
    }
}
