//! Forward kinematics and the geometric Jacobian of the TCP, and the Jacobian's derivative (the
//! kinematic Hessian), all in the base frame B (the chain's root link).
//!
//! One pass over the chain gives the TCP pose and every joint's axis and position; the Jacobian's
//! columns follow from those. Column i is `[ω_i × (p − p_i); ω_i]` for a rotating joint and `[z_i; 0]`
//! for a prismatic one, with linear rows first and the reference point at the TCP p.

use nalgebra::{SMatrix, Vector3};

use super::geom;
use super::model::{Frame, JointKind, JointVector, MAX_JOINTS, RobotModel};

/// 6 × [`MAX_JOINTS`] Jacobian; columns at and past `dof()` are zero.
pub type Jacobian = SMatrix<f64, 6, MAX_JOINTS>;

/// Everything one FK pass yields, on the stack.
#[derive(Clone, Copy, Debug)]
pub struct ChainState {
    /// Number of joints.
    pub n: usize,
    /// TCP pose in the base frame (position in m).
    pub tcp: Frame,
    /// Geometric Jacobian at the TCP in the base frame: rows vx, vy, vz (m/s per joint unit), ωx, ωy, ωz
    /// (rad/s per joint unit).
    pub jacobian: Jacobian,
}

impl ChainState {
    /// An empty state for a chain of `n` joints (identity TCP, zero Jacobian).
    pub fn new(n: usize) -> Self {
        ChainState { n, tcp: Frame::identity(), jacobian: Jacobian::zeros() }
    }

    /// Linear part of column `i` (m per joint unit).
    #[inline]
    pub fn lin(&self, i: usize) -> Vector3<f64> {
        self.jacobian.fixed_view::<3, 1>(0, i).into_owned()
    }

    /// Angular part of column `i` (rad per joint unit): the joint axis for a rotating joint, 0 for a
    /// prismatic one.
    #[inline]
    pub fn ang(&self, i: usize) -> Vector3<f64> {
        self.jacobian.fixed_view::<3, 1>(3, i).into_owned()
    }

    /// ∂J/∂q_i, the i-th slice of the kinematic Hessian, in closed form:
    /// ∂J_v,j/∂q_i = J_ω,min(i,j) × J_v,max(i,j) and ∂J_ω,j/∂q_i = J_ω,i × J_ω,j for i < j, else 0.
    /// (Each joint i turns everything after it about its own axis; a prismatic joint has J_ω = 0.)
    pub fn jacobian_derivative(&self, i: usize) -> Jacobian {
        let mut d = Jacobian::zeros();
        for j in 0..self.n {
            let (a, b) = (i.min(j), i.max(j));
            let dv = self.ang(a).cross(&self.lin(b));
            d.fixed_view_mut::<3, 1>(0, j).copy_from(&dv);
            if i < j {
                let dw = self.ang(i).cross(&self.ang(j));
                d.fixed_view_mut::<3, 1>(3, j).copy_from(&dw);
            }
        }
        d
    }
}

/// The motion of joint `i` at position `q` (rad or m): a rotation about or a translation along its axis.
#[inline]
fn joint_motion(kind: JointKind, axis: &Vector3<f64>, q: f64) -> Frame {
    match kind {
        JointKind::Prismatic => Frame::from_parts((axis * q).into(), nalgebra::Rotation3::identity()),
        _ => Frame::from_parts(nalgebra::Translation3::identity(), geom::axis_angle(axis, q)),
    }
}

impl RobotModel {
    /// TCP pose in the base frame at joint positions `q`.
    pub fn forward_kinematics(&self, q: &JointVector) -> Frame {
        let (origins, axes, kinds, tcp_offset) = self.hot();
        let mut t = Frame::identity();
        for i in 0..origins.len() {
            t = t * origins[i] * joint_motion(kinds[i], &axes[i], q[i]);
        }
        t * tcp_offset
    }

    /// Origins (m, B) of every joint's frame at `q` — where joint i sits, the origin of the link it
    /// moves — followed by the TCP, written into `out`; returns how many (`dof() + 1`). For
    /// clearance checks of the arm's links against a bed or a table.
    pub fn frame_origins(&self, q: &JointVector, out: &mut [Vector3<f64>; MAX_JOINTS + 1]) -> usize {
        let (origins, axes, kinds, tcp_offset) = self.hot();
        let n = origins.len();
        let mut t = Frame::identity();
        for i in 0..n {
            t *= origins[i];
            out[i] = t.translation.vector;
            t *= joint_motion(kinds[i], &axes[i], q[i]);
        }
        out[n] = (t * tcp_offset).translation.vector;
        n + 1
    }

    /// TCP pose and geometric Jacobian at `q`, written into `out` (no allocation).
    pub fn kinematics(&self, q: &JointVector, out: &mut ChainState) {
        let (origins, axes, kinds, tcp_offset) = self.hot();
        let n = origins.len();
        let mut axis_world = [Vector3::zeros(); MAX_JOINTS];
        let mut pos_world = [Vector3::zeros(); MAX_JOINTS];
        let mut t = Frame::identity();
        for i in 0..n {
            t *= origins[i];
            axis_world[i] = t.rotation * axes[i];
            pos_world[i] = t.translation.vector;
            t *= joint_motion(kinds[i], &axes[i], q[i]);
        }
        let tcp = t * tcp_offset;
        let p = tcp.translation.vector;
        out.n = n;
        out.tcp = tcp;
        out.jacobian = Jacobian::zeros();
        for i in 0..n {
            let (lin, ang) = if kinds[i].rotates() {
                (axis_world[i].cross(&(p - pos_world[i])), axis_world[i])
            } else {
                (axis_world[i], Vector3::zeros())
            };
            out.jacobian.fixed_view_mut::<3, 1>(0, i).copy_from(&lin);
            out.jacobian.fixed_view_mut::<3, 1>(3, i).copy_from(&ang);
        }
    }
}
