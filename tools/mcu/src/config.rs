//! The extruder board's configuration: `[extruder.board]` of the service config, whose type the
//! config owns (`strand::config::board`), and the thermistor model it describes.

pub use strand::config::board::{BoardConfig, ThermistorConfig};

use crate::thermal::Thermistor;

/// The thermistor model of a board's config.
pub fn thermistor(cfg: &BoardConfig) -> Thermistor {
    let mut t = match cfg.thermistor {
        ThermistorConfig::Beta { t0, r0, beta } => Thermistor::beta(t0, r0, beta, cfg.pullup_resistor),
        ThermistorConfig::SteinhartHart { points } => Thermistor::steinhart_hart(points, cfg.pullup_resistor),
    };
    t.inline_resistor = cfg.inline_resistor;
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_with_defaults_and_refuses_a_misspelt_key() {
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
        assert!((thermistor(&c).temp_of_resistance(100_000.0) - 25.0).abs() < 1e-9);
        assert_eq!(c.validate(), Ok(()));
        assert!(serde_json::from_str::<BoardConfig>(r#"{"serial": "x", "stepp_pin": "a"}"#).is_err());
    }
}
