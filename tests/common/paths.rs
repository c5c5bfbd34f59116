//! Reference TCP paths for CLIK tests: smooth rest-to-rest motions along a line or round a circle.
#![allow(dead_code)]

use nalgebra::{UnitQuaternion, Vector3};
use strand_core::kin::{Clik, ClikStep, JointVector, RobotModel, TcpTarget};

/// Quintic rest-to-rest profile: fraction of the path and its rate at time t of T.
pub(crate) fn quintic(t: f64, total: f64) -> (f64, f64) {
    let tau = (t / total).clamp(0.0, 1.0);
    let s = tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau);
    let ds = 30.0 * tau * tau * (1.0 - tau) * (1.0 - tau) / total;
    (s, if t > total { 0.0 } else { ds })
}

#[derive(Clone, Copy, Debug)]
pub(crate) enum Shape {
    /// From the start along `dir` (unit) for `length` m.
    Line { dir: Vector3<f64>, length: f64 },
    /// A full circle of `radius` m in the plane spanned by unit `a` (towards the centre) and `b`.
    Circle { a: Vector3<f64>, b: Vector3<f64>, radius: f64 },
}

/// Position and velocity of the path at time t, starting at `p0`.
pub(crate) fn sample(shape: Shape, p0: Vector3<f64>, t: f64, total: f64) -> (Vector3<f64>, Vector3<f64>) {
    let (s, ds) = quintic(t, total);
    match shape {
        Shape::Line { dir, length } => (p0 + dir * (length * s), dir * (length * ds)),
        Shape::Circle { a, b, radius } => {
            let th = 2.0 * std::f64::consts::PI * s;
            let dth = 2.0 * std::f64::consts::PI * ds;
            let centre = p0 + a * radius;
            let p = centre - a * (radius * th.cos()) + b * (radius * th.sin());
            let v = (a * (radius * th.sin()) + b * (radius * th.cos())) * dth;
            (p, v)
        }
    }
}

/// What a tracking run saw.
#[derive(Debug, Default)]
pub(crate) struct Tracking {
    pub max_pos_err: f64,
    pub max_axis_err: f64,
    pub max_rot_err: f64,
    pub ticks: usize,
    pub flagged: usize,
    pub max_speed_ratio: f64,
    pub max_accel_ratio: f64,
    pub min_scale: f64,
    pub steps: Vec<ClikStep>,
}

/// Runs CLIK at `rate` Hz along `shape` for `total` s (plus a short hold), holding the start
/// orientation, and measures the error of FK(q_{k+1}) against the target for t_{k+1}.
pub(crate) fn track(model: &RobotModel, clik: &mut Clik, q0: JointVector, shape: Shape, total: f64, rate: f64) -> Tracking {
    let dt = 1.0 / rate;
    let start = model.forward_kinematics(&q0);
    let p0 = start.translation.vector;
    let orient = UnitQuaternion::from_rotation_matrix(&start.rotation);
    let mut q = q0;
    let mut out = Tracking { min_scale: 1.0, ..Default::default() };
    let mut qd_prev = JointVector::zeros();
    let ticks = ((total + 0.2) * rate) as usize;
    for k in 0..ticks {
        let t_next = (k + 1) as f64 * dt;
        let (p, v) = sample(shape, p0, t_next, total);
        let target = TcpTarget { position: p, orientation: orient, linear_velocity: v, angular_velocity: Vector3::zeros() };
        let step = clik.step(model, &q, &target, dt);
        for i in 0..model.dof() {
            let l = model.limits(i);
            out.max_speed_ratio = out.max_speed_ratio.max(step.qd[i].abs() / l.velocity);
            out.max_accel_ratio = out.max_accel_ratio.max((step.qd[i] - qd_prev[i]).abs() / dt / l.acceleration);
        }
        qd_prev = step.qd;
        q = step.q;
        let reached = model.forward_kinematics(&q);
        out.max_pos_err = out.max_pos_err.max((reached.translation.vector - p).norm());
        let za = reached.rotation * Vector3::z();
        let zt = orient * Vector3::z();
        out.max_axis_err = out.max_axis_err.max(za.cross(&zt).norm());
        let rot_err = strand_core::kin::geom::rotation_vector(&(orient.to_rotation_matrix() * reached.rotation.inverse())).norm();
        out.max_rot_err = out.max_rot_err.max(rot_err);
        out.min_scale = out.min_scale.min(step.scale);
        if !step.status.is_ok() {
            out.flagged += 1;
        }
        out.ticks += 1;
        out.steps.push(step);
    }
    out
}
