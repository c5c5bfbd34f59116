//! The extruder drive's calibration: a commanded filament length against the length that actually
//! went in, and the drive wheel radius rescaled so that the next command moves what it says.
//!
//! The service turns a filament rate into the motor's speed as rate / `drive_wheel_radius` (002 Eq.
//! 19, `strand_core::extrude`). Commanded length L_c turned the wheel L_c / r; if L_m went in, the
//! wheel's effective radius is r·L_m / L_c. (Klipper's `rotation_distance` is 2π·r and rescales the
//! same way; strand has the radius.)

use crate::error::CalibrationError;

/// The most the measured length may differ from the commanded one, as a factor: beyond it the
/// measurement is more likely a typo (mm for cm) than the drive.
pub const MAX_RATIO: f64 = 2.0;

/// The new radius.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtruderFit {
    /// The rescaled `[extruder] drive_wheel_radius` (m).
    pub drive_wheel_radius: f64,
    /// The radius it replaces (m).
    pub previous: f64,
    /// Measured over commanded length (1: the drive was right).
    pub ratio: f64,
}

/// Rescales `radius` (m) after `commanded` (m) of filament was asked for and `measured` (m) went in.
pub fn rescale(radius: f64, commanded: f64, measured: f64) -> Result<ExtruderFit, CalibrationError> {
    for (what, v) in [("drive_wheel_radius", radius), ("commanded", commanded), ("measured", measured)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CalibrationError::BadValue { what, reason: format!("{v} must be finite and > 0") });
        }
    }
    let ratio = measured / commanded;
    if !(1.0 / MAX_RATIO..=MAX_RATIO).contains(&ratio) {
        return Err(CalibrationError::BadValue {
            what: "measured",
            reason: format!(
                "{:.2} mm measured for {:.2} mm commanded is off by more than a factor {MAX_RATIO}: check the measurement and its unit",
                measured * 1e3,
                commanded * 1e3
            ),
        });
    }
    Ok(ExtruderFit { drive_wheel_radius: radius * ratio, previous: radius, ratio })
}
