//! A heater's plant, for the simulator and for the job check's prediction: the heater block as one
//! first-order node driven by its heater toward a full-power temperature, the thermistor as a
//! second node lagging the block, and the firmware's controller (feed-forward plus proportional
//! on the measured value, duty clamped to [0, 1]). Deterministic: the same targets and steps give
//! the same temperatures, so `strand check-job` predicts a heat-up as strand-sim then runs it.
//!
//! Block:  τ·dT_b/dt = T_amb + u·(T_max − T_amb) − T_b
//! Sensor: τ_s·dT_s/dt = T_b − T_s
//! Duty:   u = clamp((T* − T_amb)/(T_max − T_amb) + k·(T* − T_s), 0, 1), 0 when T* = 0 (off)
//!
//! From ambient at full power the block reaches T in τ·ln((T_max − T_amb)/(T_max − T)): with the
//! defaults a hot end at 210 °C in 40·ln(375/190) = 27 s, a bed at 60 °C in 120·ln(105/70) = 49 s.
//! Temperatures are °C (the wire's exception to SI); times s.

use serde::{Deserialize, Serialize};

use crate::setting::InvalidSetting;

/// One heater's parameters.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HeaterModelConfig {
    /// Time constant of the heater block (s).
    pub time_constant: f64,
    /// Where the block settles at full power (°C).
    pub max_temperature: f64,
    /// Time constant of the thermistor behind the block (s; 0: none).
    pub sensor_lag: f64,
    /// Proportional gain of the firmware's controller (duty per °C below target).
    pub gain: f64,
}

/// `[thermal]`: the cell's heaters as a plant (strand-sim runs it; `strand check-job` predicts
/// heat-up waits with it).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ThermalConfig {
    /// The room (°C): where both heaters start and settle when off.
    pub ambient: f64,
    /// The hot end.
    pub hot_end: HeaterModelConfig,
    /// The bed.
    pub bed: HeaterModelConfig,
}

impl Default for ThermalConfig {
    fn default() -> Self {
        ThermalConfig {
            ambient: 25.0,
            hot_end: HeaterModelConfig { time_constant: 40.0, max_temperature: 400.0, sensor_lag: 1.0, gain: 0.05 },
            bed: HeaterModelConfig { time_constant: 120.0, max_temperature: 130.0, sensor_lag: 2.0, gain: 0.1 },
        }
    }
}

impl ThermalConfig {
    /// Checks every value; the message names the key.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.ambient.is_finite() && (-50.0..=100.0).contains(&self.ambient)) {
            return Err(InvalidSetting::new("thermal", format!("[thermal] ambient = {}: must lie in [-50, 100] degC", self.ambient)));
        }
        for (name, h) in [("hot_end", &self.hot_end), ("bed", &self.bed)] {
            for (key, v, lo, hi) in [
                ("time_constant", h.time_constant, 0.1, 3600.0),
                ("max_temperature", h.max_temperature, self.ambient + 1.0, 1000.0),
                ("sensor_lag", h.sensor_lag, 0.0, 60.0),
                ("gain", h.gain, 0.0, 10.0),
            ] {
                if !(v.is_finite() && (lo..=hi).contains(&v)) {
                    return Err(InvalidSetting::new("thermal", format!("[thermal] {name}.{key} = {v}: must lie in [{lo}, {hi}]")));
                }
            }
        }
        Ok(())
    }
}

/// One heater: block and sensor temperatures (°C) and the last duty.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeaterModel {
    config: HeaterModelConfig,
    ambient: f64,
    /// The block (°C).
    pub block: f64,
    /// What the thermistor reads (°C).
    pub sensor: f64,
    /// The heater's duty of the last step (0 to 1).
    pub duty: f64,
}

impl HeaterModel {
    /// A heater at `start` (°C) in a room at `ambient` (°C).
    pub fn new(config: HeaterModelConfig, ambient: f64, start: f64) -> Self {
        HeaterModel { config, ambient, block: start, sensor: start, duty: 0.0 }
    }

    /// Advances `dt` seconds toward `target` (°C; ≤ 0 is off), in sub-steps of at most 10 ms.
    pub fn step(&mut self, target: f64, dt: f64) {
        let c = self.config;
        let span = c.max_temperature - self.ambient;
        let duty = if target > 0.0 && target.is_finite() {
            ((target - self.ambient) / span + c.gain * (target - self.sensor)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.duty = duty;
        if !(dt.is_finite() && dt > 0.0) {
            return;
        }
        let n = (dt / 0.01).ceil().clamp(1.0, 1e6) as usize;
        let h = dt / n as f64;
        for _ in 0..n {
            // Exact over the sub-step for the block; the sensor by the same exponential.
            let drive = self.ambient + duty * span;
            self.block = drive + (self.block - drive) * (-h / c.time_constant).exp();
            self.sensor = if c.sensor_lag > 0.0 { self.block + (self.sensor - self.block) * (-h / c.sensor_lag).exp() } else { self.block };
        }
    }
}

/// Both heaters of a cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThermalModel {
    /// The hot end.
    pub hot_end: HeaterModel,
    /// The bed.
    pub bed: HeaterModel,
}

impl ThermalModel {
    /// Both heaters at the room's temperature.
    pub fn new(config: &ThermalConfig) -> Self {
        ThermalModel {
            hot_end: HeaterModel::new(config.hot_end, config.ambient, config.ambient),
            bed: HeaterModel::new(config.bed, config.ambient, config.ambient),
        }
    }

    /// Advances both `dt` seconds toward their targets (°C).
    pub fn step(&mut self, hot_end_target: f64, bed_target: f64, dt: f64) {
        self.hot_end.step(hot_end_target, dt);
        self.bed.step(bed_target, dt);
    }

    /// The measurement the heaters' owner publishes (both sensors, their duties).
    pub fn state(&self, seq: u64, stamp_ns: u64) -> strand_wire::HeaterState {
        strand_wire::HeaterState {
            seq,
            stamp_ns,
            hot_end: self.hot_end.sensor,
            bed: self.bed.sensor,
            hot_end_power: self.hot_end.duty,
            bed_power: self.bed.duty,
            flags: strand_wire::heater_flags::HOT_END | strand_wire::heater_flags::BED,
            _reserved: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Full power from ambient follows the closed form; the controller settles on the target.
    #[test]
    fn heats_as_the_closed_form_and_settles_on_target() {
        let cfg = ThermalConfig::default();
        let mut m = HeaterModel::new(HeaterModelConfig { sensor_lag: 0.0, gain: 0.0, ..cfg.hot_end }, 25.0, 25.0);
        // Duty 1 needs a target at T_max: 10 s toward 400 °C.
        m.step(400.0, 10.0);
        let expected = 400.0 - 375.0 * (-10.0f64 / 40.0).exp();
        assert!((m.block - expected).abs() < 1e-9, "{} vs {expected}", m.block);
        let mut m = HeaterModel::new(cfg.hot_end, 25.0, 25.0);
        for _ in 0..3000 {
            m.step(210.0, 0.1);
        }
        assert!((m.sensor - 210.0).abs() < 0.01, "settled at {}", m.sensor);
        m.step(0.0, 0.1);
        assert_eq!(m.duty, 0.0);
    }
}
