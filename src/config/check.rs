//! `[check]`: the thresholds of `strand check-job` (the check module reads them; the config owns
//! the type so that config and check do not import each other).

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// `[check]`: thresholds of `strand check-job` (the run-time limits come from `[controller]`).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CheckConfig {
    /// A joint closer than this to a position limit (rad or m) is reported as near its limit.
    pub joint_margin: f64,
    /// Every joint frame must stay this far above the bed plane (m); the nozzle must not go below
    /// it (it prints a first layer a fraction of a millimetre above).
    pub bed_clearance: f64,
    /// Findings of one kind closer together than this (s) are one stretch.
    pub merge_gap: f64,
    /// Slow-down stretches that cost less than this (s) are only counted in the total, not listed.
    pub min_slowdown_cost: f64,
}

impl Default for CheckConfig {
    fn default() -> Self {
        CheckConfig { joint_margin: 0.05, bed_clearance: 0.05, merge_gap: 0.05, min_slowdown_cost: 0.01 }
    }
}

impl CheckConfig {
    /// Checks every key; the message names it.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        for (key, v, hi) in [
            ("joint_margin", self.joint_margin, 1.0),
            ("bed_clearance", self.bed_clearance, 1.0),
            ("merge_gap", self.merge_gap, 10.0),
            ("min_slowdown_cost", self.min_slowdown_cost, 60.0),
        ] {
            if !(v.is_finite() && (0.0..=hi).contains(&v)) {
                return Err(InvalidSetting::new("check", format!("[check] {key} = {v}: must lie in [0, {hi}]")));
            }
        }
        Ok(())
    }
}
