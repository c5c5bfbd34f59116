//! The extruder board's configuration (a later step reads it from the service config's
//! `[extruder.board]` section).

use std::path::PathBuf;

use serde::Deserialize;

use crate::thermal::Thermistor;

/// The thermistor: a beta model or Steinhart–Hart through three points.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ThermistorConfig {
    /// `type = "beta"`: resistance `r0` (Ω) at `t0` (°C), `beta` (K).
    Beta {
        /// Reference temperature, °C.
        t0: f64,
        /// Resistance at t0, Ω.
        r0: f64,
        /// Beta, K.
        beta: f64,
    },
    /// `type = "steinhart_hart"`: three `[°C, Ω]` points.
    SteinhartHart {
        /// Three (temperature °C, resistance Ω) points.
        points: [(f64, f64); 3],
    },
}

fn d_baud() -> u32 {
    250_000
}
fn d_full_steps() -> u32 {
    200
}
fn d_pulse() -> f64 {
    2e-6
}
fn d_max_error() -> f64 {
    25e-6
}
fn d_pullup() -> f64 {
    4700.0
}
fn d_max_duration() -> f64 {
    3.0
}
fn d_pwm_cycle() -> f64 {
    0.1
}
fn d_one() -> f64 {
    1.0
}
fn d_report() -> f64 {
    0.3
}
fn d_samples() -> u8 {
    8
}
fn d_sample_time() -> f64 {
    0.001
}
fn d_lead() -> f64 {
    0.1
}
fn d_min_temp() -> f64 {
    0.0
}

/// One Klipper board driving the extruder stepper and the hot end.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoardConfig {
    /// Serial port, e.g. `/dev/serial/by-id/usb-Klipper_rp2040_...`.
    pub serial: PathBuf,
    /// Baud rate of a UART board, bit/s (USB boards ignore it). Default 250000.
    #[serde(default = "d_baud")]
    pub baud: u32,
    /// Step pin name as the board's dictionary spells it ("PA3", "gpio11").
    pub step_pin: String,
    /// Direction pin name.
    pub dir_pin: String,
    /// Whether positive motion drives the dir pin low.
    #[serde(default)]
    pub invert_dir: bool,
    /// Driver enable pin (active low, as most drivers), if wired.
    #[serde(default)]
    pub enable_pin: Option<String>,
    /// Microsteps per full step.
    pub microsteps: u32,
    /// Full steps per motor rotation (200 for 1.8° motors).
    #[serde(default = "d_full_steps")]
    pub full_steps_per_rotation: u32,
    /// Filament length per motor rotation, m (Klipper's rotation_distance, in metres here).
    pub rotation_distance: f64,
    /// Minimum step pulse, s (Klipper: 2 µs).
    #[serde(default = "d_pulse")]
    pub step_pulse_duration: f64,
    /// Largest allowed step timing error, s (Klipper: 25 µs).
    #[serde(default = "d_max_error")]
    pub max_step_error: f64,
    /// How far ahead of the MCU clock steps are sent, s.
    #[serde(default = "d_lead")]
    pub step_lead_time: f64,
    /// Heater output pin (hardware PWM).
    pub heater_pin: String,
    /// PWM cycle time, s.
    #[serde(default = "d_pwm_cycle")]
    pub pwm_cycle_time: f64,
    /// Largest heater duty, 0..1.
    #[serde(default = "d_one")]
    pub max_power: f64,
    /// The MCU turns the heater off if not refreshed within this, s (Klipper MAX_HEAT_TIME).
    #[serde(default = "d_max_duration")]
    pub heater_max_duration: f64,
    /// Thermistor ADC pin.
    pub thermistor_pin: String,
    /// Thermistor model.
    pub thermistor: ThermistorConfig,
    /// Divider pull-up, Ω.
    #[serde(default = "d_pullup")]
    pub pullup_resistor: f64,
    /// Resistor in series with the thermistor, Ω.
    #[serde(default)]
    pub inline_resistor: f64,
    /// Temperature report period, s.
    #[serde(default = "d_report")]
    pub report_time: f64,
    /// ADC samples summed per report.
    #[serde(default = "d_samples")]
    pub sample_count: u8,
    /// Time between those samples, s.
    #[serde(default = "d_sample_time")]
    pub sample_time: f64,
    /// PID proportional gain, duty/255 per K (Klipper pid_Kp).
    pub pid_kp: f64,
    /// PID integral gain, duty/255 per K·s (Klipper pid_Ki).
    pub pid_ki: f64,
    /// PID derivative gain, duty/255 per K/s (Klipper pid_Kd).
    pub pid_kd: f64,
    /// Derivative smoothing, s (Klipper smooth_time).
    #[serde(default = "d_one")]
    pub smooth_time: f64,
    /// Lowest plausible temperature, °C (below: thermistor fault).
    #[serde(default = "d_min_temp")]
    pub min_temp: f64,
    /// Highest allowed temperature, °C (the MCU also shuts down past it).
    pub max_temp: f64,
}

impl BoardConfig {
    /// The thermistor model.
    pub fn thermistor(&self) -> Thermistor {
        let mut t = match self.thermistor {
            ThermistorConfig::Beta { t0, r0, beta } => Thermistor::beta(t0, r0, beta, self.pullup_resistor),
            ThermistorConfig::SteinhartHart { points } => Thermistor::steinhart_hart(points, self.pullup_resistor),
        };
        t.inline_resistor = self.inline_resistor;
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_json_with_defaults() {
        let c: BoardConfig = serde_json::from_str(
            r#"{"serial": "/dev/ttyACM0", "step_pin": "gpio11", "dir_pin": "gpio10",
                "microsteps": 16, "rotation_distance": 0.0226, "heater_pin": "gpio23",
                "thermistor_pin": "gpio26",
                "thermistor": {"type": "beta", "t0": 25.0, "r0": 100000.0, "beta": 3950.0},
                "pid_kp": 22.2, "pid_ki": 1.08, "pid_kd": 114.0, "max_temp": 280.0}"#,
        )
        .unwrap();
        assert_eq!(c.baud, 250_000);
        assert_eq!(c.full_steps_per_rotation, 200);
        assert!((c.thermistor().temp_of_resistance(100_000.0) - 25.0).abs() < 1e-9);
        assert!(serde_json::from_str::<BoardConfig>(r#"{"serial": "x", "stepp_pin": "a"}"#).is_err());
    }
}
