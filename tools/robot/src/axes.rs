//! Between the robot controller's axes and the URDF joints: per joint a sign and an offset
//! (`[driver] axis_sign`, `axis_offset`), because the makers' zeros and directions differ from the
//! URDFs'. The controller's axis angle is `sign · joint + offset`; every conversion goes through
//! here, and a test per bundled robot checks that it round-trips.

use strand_wire::MAX_JOINTS;

/// The mapping of one robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisMap {
    dof: usize,
    sign: [f64; MAX_JOINTS],
    offset: [f64; MAX_JOINTS],
}

impl AxisMap {
    /// The identity for `dof` joints.
    pub fn identity(dof: usize) -> AxisMap {
        AxisMap { dof, sign: [1.0; MAX_JOINTS], offset: [0.0; MAX_JOINTS] }
    }

    /// From the config's lists (empty: identity for that list). The lists are checked by
    /// `DriverConfig::validate`: `dof` values, signs ±1, finite offsets.
    pub fn new(dof: usize, sign: &[f64], offset: &[f64]) -> AxisMap {
        let mut m = AxisMap::identity(dof);
        for (k, s) in sign.iter().take(dof).enumerate() {
            m.sign[k] = *s;
        }
        for (k, o) in offset.iter().take(dof).enumerate() {
            m.offset[k] = *o;
        }
        m
    }

    /// Joints mapped.
    pub fn dof(&self) -> usize {
        self.dof
    }

    /// URDF joint positions (rad or m) from the controller's axes.
    pub fn joints_from_axes(&self, axes: &[f64]) -> [f64; MAX_JOINTS] {
        let mut q = [0.0; MAX_JOINTS];
        for k in 0..self.dof.min(axes.len()) {
            q[k] = self.sign[k] * (axes[k] - self.offset[k]);
        }
        q
    }

    /// The controller's axes from URDF joint positions (rad or m).
    pub fn axes_from_joints(&self, q: &[f64]) -> [f64; MAX_JOINTS] {
        let mut a = [0.0; MAX_JOINTS];
        for k in 0..self.dof.min(q.len()) {
            a[k] = self.sign[k] * q[k] + self.offset[k];
        }
        a
    }

    /// A joint-space rate (velocity, acceleration) in the controller's axes: the sign only.
    pub fn axis_rate(&self, k: usize, joint_rate: f64) -> f64 {
        self.sign[k] * joint_rate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mapping_round_trips() {
        let m = AxisMap::new(6, &[1.0, -1.0, 1.0, -1.0, 1.0, -1.0], &[0.0, 1.25, -0.3, 0.0, 0.1, 3.0]);
        let q = [0.1, -0.2, 0.3, -0.4, 0.5, -0.6, 0.0, 0.0];
        let a = m.axes_from_joints(&q[..6]);
        let back = m.joints_from_axes(&a[..6]);
        for k in 0..6 {
            assert!((back[k] - q[k]).abs() < 1e-15, "joint {k}: {} vs {}", back[k], q[k]);
        }
        assert_eq!(a[1], 0.2 + 1.25);
    }
}
