//! Helpers shared by the integration tests: the bundled robots, a seeded random source, paths.
#![allow(dead_code)]

pub(crate) mod cell;

use strand::config::RobotConfig;
use strand_core::kin::{ClikStep, JointVector, RobotModel};

pub(crate) const ROBOTS: [&str; 7] = ["iiwa7", "iiwa14", "vp6242", "meca500", "irb140", "kr6r900", "ur5e"];

pub(crate) fn robot(name: &str) -> RobotModel {
    let path = strand_testkit::root().join("config/robots").join(format!("{name}.toml"));
    RobotConfig::load(&path).and_then(|c| c.build_model()).unwrap_or_else(|e| panic!("{e}"))
}

/// SplitMix64: a small seeded generator, so test inputs are the same on every run.
pub(crate) struct Rng(pub u64);

impl Rng {
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal (Box-Muller).
    pub(crate) fn normal(&mut self) -> f64 {
        let u = self.unit().max(1e-300);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// A configuration inside the limits, kept `inset` (fraction of the range) away from them.
    pub(crate) fn config(&mut self, model: &RobotModel, inset: f64) -> JointVector {
        let mut q = JointVector::zeros();
        for (i, j) in model.joints().iter().enumerate() {
            let (lo, hi) = if j.limits.lower.is_finite() { (j.limits.lower, j.limits.upper) } else { (-3.0, 3.0) };
            let d = (hi - lo) * inset;
            q[i] = self.range(lo + d, hi - d);
        }
        q
    }
}

pub(crate) fn jv(values: &[f64]) -> JointVector {
    let mut q = JointVector::zeros();
    q.as_mut_slice()[..values.len()].copy_from_slice(values);
    q
}

/// A 7-joint chain no bundled robot has: a prismatic rail along x carrying a 6-axis arm whose first
/// and last joints are continuous and whose axes are skewed, so FK, the Jacobian and its derivative
/// are exercised on every joint type and on non-principal axes.
pub(crate) fn rail_arm() -> RobotModel {
    let urdf = r#"<robot name="rail_arm">
  <link name="floor"/><link name="carriage"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="l4"/><link name="l5"/><link name="l6"/><link name="flange"/>
  <joint name="rail" type="prismatic"><parent link="floor"/><child link="carriage"/><origin xyz="0 0 0.05"/><axis xyz="1 0 0"/><limit lower="0" upper="2.0" velocity="0.5"/></joint>
  <joint name="j1" type="continuous"><parent link="carriage"/><child link="l1"/><origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.05 0 0.2" rpy="0.1 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" velocity="2"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.35"/><axis xyz="0 1 0.2"/><limit lower="-2.5" upper="2.5" velocity="2"/></joint>
  <joint name="j4" type="revolute"><parent link="l3"/><child link="l4"/><origin xyz="0.3 0 0.02" rpy="0 0.2 0"/><axis xyz="1 0 0"/><limit lower="-3" upper="3" velocity="3"/></joint>
  <joint name="j5" type="revolute"><parent link="l4"/><child link="l5"/><origin xyz="0.05 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" velocity="3"/></joint>
  <joint name="j6" type="continuous"><parent link="l5"/><child link="l6"/><origin xyz="0.06 0 0"/><axis xyz="1 0 0"/><limit velocity="4"/></joint>
  <joint name="f" type="fixed"><parent link="l6"/><child link="flange"/><origin xyz="0.01 0 0" rpy="0 1.5707963267948966 0"/></joint>
</robot>"#;
    RobotModel::from_urdf_str(urdf, "rail_arm.urdf", "floor", "flange")
        .unwrap()
        .with_tool(strand_core::kin::Frame::from_parts(
            nalgebra::Translation3::new(0.0, 0.01, 0.08),
            strand_core::kin::geom::rpy(0.05, 0.0, 0.0),
        ))
        .unwrap()
        .with_dynamic_limits(&[2.0, 10.0, 10.0, 10.0, 20.0, 20.0, 20.0], &[20.0, 100.0, 100.0, 100.0, 200.0, 200.0, 200.0], ("acc", "jerk"))
        .unwrap()
}

/// A well-conditioned start configuration of a bundled arm, away from its limits and singularities.
pub(crate) fn start(name: &str) -> JointVector {
    match name {
        "iiwa7" => jv(&[0.2, 0.6, -0.1, -1.3, 0.2, 0.9, 0.3]),
        "vp6242" => jv(&[0.1, 0.0, 2.1, 0.3, 0.9, 0.2]),
        "meca500" => jv(&[0.1, 0.2, 0.1, 0.3, 0.9, 0.2]),
        _ => panic!("no start configuration for {name}"),
    }
}

/// Asserts that one step's command is finite and meets every joint's speed limit and, against the
/// previous step's velocity `qd_prev`, its acceleration limit over `dt`.
pub(crate) fn assert_within_limits(model: &RobotModel, step: &ClikStep, qd_prev: &JointVector, dt: f64, label: &str) {
    assert!(step.q.iter().chain(step.qd.iter()).all(|x| x.is_finite()), "{label}: not finite: {step:?}");
    for i in 0..model.dof() {
        let l = model.limits(i);
        assert!(step.qd[i].abs() <= l.velocity * (1.0 + 1e-12), "{label}: joint {i} speed {} > {}", step.qd[i], l.velocity);
        let acc = (step.qd[i] - qd_prev[i]).abs() / dt;
        assert!(acc <= l.acceleration * (1.0 + 1e-9), "{label}: joint {i} acceleration {acc} > {}", l.acceleration);
    }
}
