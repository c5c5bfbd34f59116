//! Helpers shared by the integration tests: the bundled robots, a seeded random source, paths.
#![allow(dead_code)]

use std::path::PathBuf;

use strand::config::RobotConfig;
use strand::core::kin::{JointVector, RobotModel};

pub const ROBOTS: [&str; 5] = ["iiwa7", "iiwa14", "vp6242", "meca500", "irb140"];

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn robot(name: &str) -> RobotModel {
    let path = root().join("config/robots").join(format!("{name}.toml"));
    RobotConfig::load(&path).and_then(|c| c.build_model()).unwrap_or_else(|e| panic!("{e}"))
}

/// SplitMix64: a small seeded generator, so test inputs are the same on every run.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// A configuration inside the limits, kept `inset` (fraction of the range) away from them.
    pub fn config(&mut self, model: &RobotModel, inset: f64) -> JointVector {
        let mut q = JointVector::zeros();
        for (i, j) in model.joints().iter().enumerate() {
            let (lo, hi) = if j.limits.lower.is_finite() { (j.limits.lower, j.limits.upper) } else { (-3.0, 3.0) };
            let d = (hi - lo) * inset;
            q[i] = self.range(lo + d, hi - d);
        }
        q
    }
}

pub fn jv(values: &[f64]) -> JointVector {
    let mut q = JointVector::zeros();
    q.as_mut_slice()[..values.len()].copy_from_slice(values);
    q
}
