//! The calibration tests' common ground (tools/calibrate/tests and the root's tests/calibrate.rs): robots from the bundled URDFs (the project's own FK), a small inverse
//! kinematics to put the tool where a test wants it, and a seeded noise source.

#![allow(dead_code, unreachable_pub)]

use nalgebra::{Matrix6, Rotation3, Translation3, Vector3, Vector6};
use strand_core::kin::{ChainState, Frame, JointVector, RobotModel, geom};

/// A bundled robot's chain (`config/robots/NAME.urdf`), no tool. (The folder is found upwards from
/// the package, so the workspace root's tests/calibrate.rs shares this file.)
pub fn robot(name: &str, root: &str, tip: &str) -> RobotModel {
    let robots = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .map(|a| a.join("config/robots"))
        .find(|p| p.is_dir())
        .expect("config/robots above the package");
    let path = robots.join(format!("{name}.urdf")).display().to_string();
    let text = std::fs::read_to_string(&path).unwrap();
    RobotModel::from_urdf_str(&text, &path, root, tip).unwrap()
}

/// The KUKA KR 6 R900 sixx, no tool.
pub fn kr6() -> RobotModel {
    robot("kr6r900", "base_link", "flange")
}

/// The KR 6's start pose (0, −90, 90, 0, 90, 0)°: flange x (the approach) pointing down.
pub fn kr6_home() -> JointVector {
    let h = std::f64::consts::FRAC_PI_2;
    let mut q = JointVector::zeros();
    q[1] = -h;
    q[2] = h;
    q[4] = h;
    q
}

/// A frame from xyz (m) and URDF rpy (rad).
pub fn frame(xyz: [f64; 3], rpy: [f64; 3]) -> Frame {
    Frame::from_parts(Translation3::new(xyz[0], xyz[1], xyz[2]), geom::rpy(rpy[0], rpy[1], rpy[2]))
}

/// Joints that put `model`'s TCP at `target` (damped least squares from `start`); panics if it
/// does not converge to 1e-10 (a test set-up error, not a finding).
pub fn ik(model: &RobotModel, target: &Frame, start: &JointVector) -> JointVector {
    let mut q = *start;
    let mut state = ChainState::new(model.dof());
    for _ in 0..500 {
        model.kinematics(&q, &mut state);
        let dp = target.translation.vector - state.tcp.translation.vector;
        let dr = geom::rotation_vector(&(target.rotation * state.tcp.rotation.inverse()));
        let e = Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z);
        if e.norm() < 1e-12 {
            return q;
        }
        let j = state.jacobian.columns(0, model.dof()).into_owned();
        let jjt: Matrix6<f64> = &j * j.transpose() + Matrix6::identity() * 1e-8;
        let step = j.transpose() * jjt.try_inverse().unwrap() * e;
        for k in 0..model.dof() {
            q[k] += step[k];
        }
    }
    model.kinematics(&q, &mut state);
    let err = (target.translation.vector - state.tcp.translation.vector).norm();
    assert!(err < 1e-10, "IK did not converge: {err} m");
    q
}

/// A seeded noise source (xorshift64*, Box–Muller): the same numbers on every machine.
pub struct Noise(u64);

impl Noise {
    pub fn new(seed: u64) -> Self {
        Noise(seed.max(1))
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Normal with standard deviation `sigma`.
    pub fn normal(&mut self, sigma: f64) -> f64 {
        let (u1, u2) = (self.uniform().max(1e-300), self.uniform());
        sigma * (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    /// A vector of three normals.
    pub fn vector(&mut self, sigma: f64) -> Vector3<f64> {
        Vector3::new(self.normal(sigma), self.normal(sigma), self.normal(sigma))
    }

    /// A small random rotation (each rotation-vector component normal with `sigma` rad).
    pub fn rotation(&mut self, sigma: f64) -> Rotation3<f64> {
        Rotation3::new(self.vector(sigma))
    }
}
