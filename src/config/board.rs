//! `[extruder.board]`: the Klipper board that drives the extruder's stepper and the hot end
//! (`strand-mcu` reads it and runs the board; the config owns the type so that a service config
//! with the section loads and `strand check-config` checks it, as `[tracker]`). Units as Klipper's
//! config spells them, but SI: `rotation_distance` in m (Klipper: mm), times in s, temperatures in
//! °C (the wire's and the heaters' one exception).
//!
//! The section sits inside `[extruder]`, whose other keys are the core's `ExtruderConfig`: the
//! loader takes it out of the table before the core's section is read ([`take`]), and puts it back
//! in the effective config a log stores.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// The thermistor: a beta model or Steinhart–Hart through three points.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
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
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
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
    /// verify_heater: how far below its target (K) the hot end still counts as at it (Klipper 5).
    #[serde(default = "d_hysteresis")]
    pub hysteresis: f64,
    /// verify_heater: the shortfall below target, summed once a second (K), that faults a hot end
    /// which had reached its target (Klipper 120).
    #[serde(default = "d_verify_max_error")]
    pub max_error: f64,
    /// verify_heater: while heating, the rise (K) required every `check_gain_time` (Klipper 2).
    #[serde(default = "d_heating_gain")]
    pub heating_gain: f64,
    /// verify_heater: the time (s) allowed for each `heating_gain` rise (Klipper 20 for an extruder).
    #[serde(default = "d_check_gain_time")]
    pub check_gain_time: f64,
}

fn d_hysteresis() -> f64 {
    5.0
}
fn d_verify_max_error() -> f64 {
    120.0
}
fn d_heating_gain() -> f64 {
    2.0
}
fn d_check_gain_time() -> f64 {
    20.0
}

impl BoardConfig {
    /// Checks every key; the message names it, its value and its range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.check().map_err(|m| InvalidSetting::new("extruder.board", m))
    }

    fn check(&self) -> Result<(), String> {
        let k = "[extruder.board]";
        for (key, pin) in [
            ("step_pin", &self.step_pin),
            ("dir_pin", &self.dir_pin),
            ("heater_pin", &self.heater_pin),
            ("thermistor_pin", &self.thermistor_pin),
        ] {
            if pin.trim().is_empty() {
                return Err(format!("{k} {key}: empty; name the pin as the board's firmware does (\"PA3\", \"gpio11\")"));
            }
        }
        if self.serial.as_os_str().is_empty() {
            return Err(format!("{k} serial: empty; the board's serial port (/dev/serial/by-id/...)"));
        }
        let range = |key: &str, v: f64, lo: f64, hi: f64, unit: &str| {
            if v.is_finite() && (lo..=hi).contains(&v) { Ok(()) } else { Err(format!("{k} {key} = {v}: must lie in [{lo}, {hi}] {unit}")) }
        };
        if !(1..=256).contains(&self.microsteps) {
            return Err(format!("{k} microsteps = {}: must lie in [1, 256]", self.microsteps));
        }
        if !(1..=1000).contains(&self.full_steps_per_rotation) {
            return Err(format!("{k} full_steps_per_rotation = {}: must lie in [1, 1000]", self.full_steps_per_rotation));
        }
        range("rotation_distance", self.rotation_distance, 1e-4, 0.5, "m (Klipper's mm / 1000)")?;
        range("step_pulse_duration", self.step_pulse_duration, 0.0, 1e-3, "s")?;
        range("max_step_error", self.max_step_error, 1e-6, 1e-3, "s")?;
        range("step_lead_time", self.step_lead_time, 0.005, 1.0, "s")?;
        range("pwm_cycle_time", self.pwm_cycle_time, 1e-4, 1.0, "s")?;
        range("max_power", self.max_power, 0.01, 1.0, "(duty)")?;
        range("heater_max_duration", self.heater_max_duration, 0.5, 10.0, "s")?;
        range("report_time", self.report_time, 0.01, 1.0, "s")?;
        range("sample_time", self.sample_time, 1e-5, 0.1, "s")?;
        if self.sample_count == 0 || f64::from(self.sample_count) * self.sample_time >= self.report_time {
            return Err(format!(
                "{k} sample_count = {}, sample_time = {} s: at least one sample, all of them within report_time ({} s)",
                self.sample_count, self.sample_time, self.report_time
            ));
        }
        range("pullup_resistor", self.pullup_resistor, 1.0, 1e7, "Ω")?;
        range("inline_resistor", self.inline_resistor, 0.0, 1e6, "Ω")?;
        for (key, v) in [("pid_kp", self.pid_kp), ("pid_ki", self.pid_ki), ("pid_kd", self.pid_kd)] {
            range(key, v, 0.0, 1e4, "")?;
        }
        range("smooth_time", self.smooth_time, 0.0, 60.0, "s")?;
        range("min_temp", self.min_temp, -60.0, 100.0, "°C")?;
        range("max_temp", self.max_temp, self.min_temp + 1.0, 500.0, "°C (above min_temp)")?;
        range("hysteresis", self.hysteresis, 0.1, 100.0, "K")?;
        range("max_error", self.max_error, 1.0, 10_000.0, "K")?;
        range("heating_gain", self.heating_gain, 0.1, 100.0, "K")?;
        range("check_gain_time", self.check_gain_time, 0.5, 600.0, "s")?;
        match &self.thermistor {
            ThermistorConfig::Beta { t0, r0, beta } => {
                range("thermistor.t0", *t0, -50.0, 300.0, "°C")?;
                range("thermistor.r0", *r0, 1.0, 1e8, "Ω")?;
                range("thermistor.beta", *beta, 100.0, 1e5, "K")?;
            }
            ThermistorConfig::SteinhartHart { points } => {
                for (t, r) in points {
                    range("thermistor.points (°C)", *t, -50.0, 500.0, "°C")?;
                    range("thermistor.points (Ω)", *r, 1e-3, 1e8, "Ω")?;
                }
                if points[0].0 == points[1].0 || points[1].0 == points[2].0 || points[0].0 == points[2].0 {
                    return Err(format!("{k} thermistor.points: three different temperatures"));
                }
            }
        }
        Ok(())
    }
}

/// Takes `[extruder.board]` out of a parsed config table (so that the rest of `[extruder]` is the
/// core's section alone) and reads it; `Ok(None)` without one. Errors name the section.
pub fn take(table: &mut toml::Table) -> Result<Option<BoardConfig>, InvalidSetting> {
    let Some(extruder) = table.get_mut("extruder").and_then(toml::Value::as_table_mut) else {
        return Ok(None);
    };
    let Some(board) = extruder.remove("board") else {
        return Ok(None);
    };
    let board: BoardConfig = board
        .try_into()
        .map_err(|e: toml::de::Error| InvalidSetting::new("extruder.board", format!("[extruder.board] {}", e.to_string().trim_end())))?;
    board.validate()?;
    Ok(Some(board))
}

/// Puts `board` back into a config table as `[extruder.board]` (the effective config).
pub fn put(table: &mut toml::Table, board: &BoardConfig) {
    let value = toml::Value::try_from(board).expect("a board config is representable in TOML");
    let extruder = table.entry("extruder").or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let Some(t) = extruder.as_table_mut() {
        t.insert("board".into(), value);
    }
}
