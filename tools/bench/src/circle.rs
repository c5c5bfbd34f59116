//! The CLIK benchmarks' targets, one table for all of them (`benches/kin.rs` includes this file;
//! `strand-bench clik` uses it; `benches/pinocchio/clik_dls.cpp` builds the same table): the iiwa7
//! from [`IIWA_Q0`] tracing a 20 mm circle in the world x-y plane at 50 mm/s, sampled at 1 kHz, its
//! orientation held.

use nalgebra::{UnitQuaternion, Vector3};
use strand_core::kin::{JointVector, RobotModel, TcpTarget};

/// The iiwa7's start configuration (rad).
pub(crate) const IIWA_Q0: [f64; 7] = [0.2, 0.6, -0.1, -1.3, 0.2, 0.9, 0.3];

/// The circle's targets from the tool pose at `q0`: 20 mm radius at 50 mm/s, 1 kHz, one period
/// rounded down (2513 ticks for these figures), then the table wraps.
pub(crate) fn circle(model: &RobotModel, q0: &JointVector) -> Vec<TcpTarget> {
    let start = model.forward_kinematics(q0);
    let orientation = UnitQuaternion::from_rotation_matrix(&start.rotation);
    let (r, v) = (0.02, 0.05);
    let omega = v / r;
    let ticks = (2.0 * std::f64::consts::PI / omega * 1000.0) as usize;
    let centre = start.translation.vector - Vector3::x() * r;
    (0..ticks)
        .map(|k| {
            let th = omega * (k + 1) as f64 * 1e-3;
            TcpTarget {
                position: centre + Vector3::new(r * th.cos(), r * th.sin(), 0.0),
                orientation,
                linear_velocity: Vector3::new(-r * omega * th.sin(), r * omega * th.cos(), 0.0),
                angular_velocity: Vector3::zeros(),
            }
        })
        .collect()
}
