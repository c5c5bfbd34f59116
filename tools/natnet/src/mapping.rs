//! From Motive's pose of the rigid body to the base pose B in the cell's world W.
//!
//! Three fixed transforms, in order (`[tracker]`):
//!
//! 1. Motive's up axis: Motive streams Y-up by default; W is Z-up. A Y-up pose is changed to Z-up
//!    by the turn U of +90° about x, (x, y, z) → (x, −z, y), applied to both of its frames — the
//!    world and the body's own axes: T ← U·T·Uᵀ (meant as the change Motive's own Z-up option
//!    makes; not checked against Motive). A rigid body created in Motive has its axes along the
//!    world's, so after the change its z is up too, and `body_xyz/rpy` are in a Z-up body frame. With `up_axis = "z"` nothing is changed.
//! 2. Motive's world in W (`world_xyz`, `world_rpy`): where Motive's calibrated ground-plane
//!    origin is in the cell, after the turn.
//! 3. The base in the rigid body (`body_xyz`, `body_rpy`): where B is in the body Motive tracks
//!    (its pivot point and axes, as set in Motive).
//!
//! So T_WB = T_W,M · U·T_M,body·Uᵀ · T_body,B. The service uses the published pose as B itself (for a
//! tracked base `[base] mount_xyz/rpy` is only the pose before the first sample), which is why the
//! body-to-base offset is applied here and only here.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use strand::config::tracker::{TrackerConfig, UpAxis};

/// The fixed transforms of `[tracker]`, ready to map each frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMapping {
    /// T_W,M: Motive's world (after the up-axis change) in W.
    world: Isometry3<f64>,
    /// U: the up-axis change (Y-up → Z-up, or identity).
    up: UnitQuaternion<f64>,
    /// T_body,B: the base in the rigid body.
    body: Isometry3<f64>,
}

fn isometry(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(xyz[0], xyz[1], xyz[2]), UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]))
}

impl FrameMapping {
    /// The mapping `[tracker]` describes.
    pub fn new(cfg: &TrackerConfig) -> Self {
        let up = match cfg.up_axis {
            UpAxis::Y => UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
            UpAxis::Z => UnitQuaternion::identity(),
        };
        FrameMapping { world: isometry(cfg.world_xyz, cfg.world_rpy), up, body: isometry(cfg.body_xyz, cfg.body_rpy) }
    }

    /// B in W — position (m) and orientation R_WB (w, x, y, z) — for the body at `position` (m)
    /// with orientation `orientation` (x, y, z, w, NatNet's order) in Motive's world. `None` if the
    /// pose is not finite or the quaternion is far from unit length (a garbled body).
    pub fn base_pose(&self, position: [f32; 3], orientation: [f32; 4]) -> Option<([f64; 3], [f64; 4])> {
        let p = Vector3::new(position[0] as f64, position[1] as f64, position[2] as f64);
        let [x, y, z, w] = orientation.map(|v| v as f64);
        let q = Quaternion::new(w, x, y, z);
        let norm = q.norm();
        if !(p.iter().all(|v| v.is_finite()) && norm.is_finite() && (norm - 1.0).abs() < 1e-2) {
            return None;
        }
        // U·T·Uᵀ: the position turned, the rotation conjugated.
        let q = self.up * UnitQuaternion::from_quaternion(q) * self.up.inverse();
        let m_body = Isometry3::from_parts(Translation3::from(self.up * p), q);
        let wb = self.world * m_body * self.body;
        let t = wb.translation.vector;
        let r = wb.rotation.into_inner();
        // One sign for a rotation: w ≥ 0, so consecutive samples do not flip.
        let s = if r.w < 0.0 { -1.0 } else { 1.0 };
        Some(([t.x, t.y, t.z], [s * r.w, s * r.i, s * r.j, s * r.k]))
    }
}
