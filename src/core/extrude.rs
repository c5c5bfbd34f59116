//! Extrusion synchronisation: the filament rate follows the TCP's speed along the path relative to
//! the substrate, Ė = (ΔE/L)·ṡ (002 Eq. 18, 000 Eq. 5's constant flow rate), the drive motor turns at
//! ω = Ė/r_w (002 Eq. 19), pressure advance adds K·Ë, and the filament is retracted when the motion
//! stops unplanned (an underrun) and primed again when it resumes.
//!
//! ṡ is the path speed in W, the substrate frame (the engine plans in W), so on a moving base the
//! flow follows the nozzle's motion over the part, not the arm's motion relative to its base.

use serde::{Deserialize, Serialize};

use crate::path::{Motion, PathSample};
use crate::setting::InvalidSetting;

/// `[extruder]`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ExtruderConfig {
    /// Radius of the drive (friction) wheel r_w (m), 002 Eq. 19.
    pub drive_wheel_radius: f64,
    /// Filament diameter (m), for the volumetric rate.
    pub filament_diameter: f64,
    /// Pressure-advance constant K (s): Ė_cmd = Ė + K·Ë. 0 disables it.
    pub pressure_advance: f64,
    /// The most pressure advance a program may set (s): `SET_PRESSURE_ADVANCE ADVANCE`, `M900 K` and
    /// `M572 S` replace `pressure_advance` from their segment on, clamped to [0, this]. 0 ignores
    /// the program's setting.
    pub max_pressure_advance: f64,
    /// Filament pulled back when the motion stops unplanned (m); 0 disables retraction.
    pub retract_length: f64,
    /// Filament speed of a retraction and of the prime that undoes it (m/s).
    pub retract_speed: f64,
}

impl Default for ExtruderConfig {
    fn default() -> Self {
        ExtruderConfig {
            drive_wheel_radius: 5.5e-3,
            filament_diameter: 1.75e-3,
            pressure_advance: 0.0,
            max_pressure_advance: 0.2,
            retract_length: 1.0e-3,
            retract_speed: 0.035,
        }
    }
}

impl ExtruderConfig {
    /// Checks every value; the error names the key.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.drive_wheel_radius.is_finite() && self.drive_wheel_radius > 0.0) {
            return Err(InvalidSetting::new("extruder", "[extruder] drive_wheel_radius: must be finite and > 0".to_string()));
        }
        if !(self.filament_diameter.is_finite() && self.filament_diameter > 0.0) {
            return Err(InvalidSetting::new("extruder", "[extruder] filament_diameter: must be finite and > 0".to_string()));
        }
        if !(self.pressure_advance.is_finite() && (0.0..1.0).contains(&self.pressure_advance)) {
            return Err(InvalidSetting::new("extruder", "[extruder] pressure_advance: must be in [0, 1) s".to_string()));
        }
        if !(self.max_pressure_advance.is_finite() && (0.0..1.0).contains(&self.max_pressure_advance)) {
            return Err(InvalidSetting::new("extruder", "[extruder] max_pressure_advance: must be in [0, 1) s".to_string()));
        }
        if !(self.retract_length.is_finite() && (0.0..0.05).contains(&self.retract_length)) {
            return Err(InvalidSetting::new("extruder", "[extruder] retract_length: must be in [0, 0.05) m".to_string()));
        }
        if !(self.retract_speed.is_finite() && self.retract_speed > 0.0) {
            return Err(InvalidSetting::new("extruder", "[extruder] retract_speed: must be finite and > 0".to_string()));
        }
        Ok(())
    }
}

/// The extruder command for one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExtruderCommand {
    /// Filament rate Ė that the path asks for (m/s of filament), 002 Eq. 18.
    pub path_rate: f64,
    /// Commanded filament rate (m/s): path rate plus pressure advance, or a retraction/prime.
    pub filament_rate: f64,
    /// Drive motor speed ω = filament_rate / r_w (rad/s), 002 Eq. 19.
    pub motor_speed: f64,
    /// Volumetric rate of the commanded filament (m³/s).
    pub volumetric_rate: f64,
    /// Filament pushed since the start (m; retractions subtract).
    pub position: f64,
    /// True while the filament is pulled back.
    pub retracted: bool,
}

/// Extruder state: retraction and the integrated filament position.
#[derive(Clone, Debug)]
pub struct Extruder {
    config: ExtruderConfig,
    dt: f64,
    area: f64,
    /// Filament still to pull back (> 0) or to prime (< 0) (m).
    pending: f64,
    retracted: bool,
    position: f64,
}

impl Extruder {
    /// An extruder ticking every `dt` seconds.
    pub fn new(config: &ExtruderConfig, dt: f64) -> Result<Self, InvalidSetting> {
        config.validate()?;
        let r = 0.5 * config.filament_diameter;
        Ok(Extruder { config: config.clone(), dt, area: std::f64::consts::PI * r * r, pending: 0.0, retracted: false, position: 0.0 })
    }

    /// Filament pushed since the start (m; retractions subtract).
    pub fn position(&self) -> f64 {
        self.position
    }

    /// The command for the path sample of this tick.
    pub fn step(&mut self, sample: &PathSample) -> ExtruderCommand {
        let path_rate = sample.flow * sample.speed + sample.dwell_filament_rate;
        let advance = sample.pressure_advance.map_or(self.config.pressure_advance, |k| k.clamp(0.0, self.config.max_pressure_advance));
        let mut rate = path_rate + advance * sample.flow * sample.path_acceleration;
        let stopped_unplanned = matches!(sample.motion, Motion::Starved | Motion::Held);
        if stopped_unplanned && !self.retracted && self.config.retract_length > 0.0 {
            self.retracted = true;
            self.pending = self.config.retract_length;
        } else if sample.motion == Motion::Moving && self.retracted {
            self.retracted = false;
            self.pending = -self.config.retract_length;
        }
        if self.pending != 0.0 {
            // A retraction (pending > 0) or prime (pending < 0) at retract_speed, on top of the path.
            let step = self.config.retract_speed * self.dt;
            let moved = self.pending.abs().min(step);
            let direction = if self.pending > 0.0 { -1.0 } else { 1.0 };
            rate += direction * moved / self.dt;
            self.pending -= -direction * moved;
            if self.pending.abs() < 1e-15 {
                self.pending = 0.0;
            }
        }
        if !rate.is_finite() {
            rate = 0.0;
        }
        self.position += rate * self.dt;
        ExtruderCommand {
            path_rate,
            filament_rate: rate,
            motor_speed: rate / self.config.drive_wheel_radius,
            volumetric_rate: rate * self.area,
            position: self.position,
            retracted: self.retracted,
        }
    }
}
