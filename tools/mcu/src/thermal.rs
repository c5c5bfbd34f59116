//! The hot end: thermistor conversion, Klipper's PID, and heater verification.
//!
//! The MCU reports the thermistor divider's ADC value (a sum of `sample_count` samples of 0..=
//! ADC_MAX); the host converts it to °C, runs the PID and schedules the heater's duty. Klipper's
//! safety split is kept: the MCU itself shuts the heater off if the host stops refreshing it
//! (max_duration) or the ADC leaves the host-given range (min_temp/max_temp), and the host checks
//! that the heater actually heats ([`HeaterCheck`], Klipper's verify_heater).

/// Kelvin at 0 °C.
pub const KELVIN: f64 = 273.15;
/// Klipper's PID gains are given per 255 of duty (PID_PARAM_BASE).
pub const PID_PARAM_BASE: f64 = 255.0;
/// Temperature the PID assumes before its first sample, °C (heaters.py AMBIENT_TEMP).
pub const AMBIENT_TEMP: f64 = 25.0;

/// A thermistor as Klipper models it: 1/T = c1 + c2·ln R + c3·(ln R)³, T in K, R in Ω.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thermistor {
    /// Steinhart–Hart c1, 1/K.
    pub c1: f64,
    /// Steinhart–Hart c2, 1/K.
    pub c2: f64,
    /// Steinhart–Hart c3, 1/K.
    pub c3: f64,
    /// Pull-up resistor of the divider, Ω.
    pub pullup: f64,
    /// Resistance in series with the thermistor (inline_resistor), Ω.
    pub inline_resistor: f64,
}

impl Thermistor {
    /// The beta model: resistance `r0` (Ω) at `t0` (°C) and `beta` (K); c3 = 0.
    pub fn beta(t0: f64, r0: f64, beta: f64, pullup: f64) -> Self {
        let c2 = 1.0 / beta;
        let c1 = 1.0 / (t0 + KELVIN) - c2 * r0.ln();
        Self { c1, c2, c3: 0.0, pullup, inline_resistor: 0.0 }
    }

    /// Steinhart–Hart through three (°C, Ω) points.
    pub fn steinhart_hart(p: [(f64, f64); 3], pullup: f64) -> Self {
        let inv = |t: f64| 1.0 / (t + KELVIN);
        let (l1, l2, l3) = (p[0].1.ln(), p[1].1.ln(), p[2].1.ln());
        let (i1, i2, i3) = (inv(p[0].0), inv(p[1].0), inv(p[2].0));
        let c3 = ((i1 - i2) - (l1 - l2) * (i1 - i3) / (l1 - l3))
            / ((l1.powi(3) - l2.powi(3)) - (l1 - l2) * (l1.powi(3) - l3.powi(3)) / (l1 - l3));
        let c2 = ((i1 - i3) - c3 * (l1.powi(3) - l3.powi(3))) / (l1 - l3);
        let c1 = i1 - c2 * l1 - c3 * l1.powi(3);
        Self { c1, c2, c3, pullup, inline_resistor: 0.0 }
    }

    /// Temperature (°C) at resistance `r` (Ω).
    pub fn temp_of_resistance(&self, r: f64) -> f64 {
        let l = r.max(1e-9).ln();
        1.0 / (self.c1 + self.c2 * l + self.c3 * l.powi(3)) - KELVIN
    }

    /// Resistance (Ω) at temperature `t` (°C), by bisection of the monotonic model.
    pub fn resistance_of_temp(&self, t: f64) -> f64 {
        let (mut lo, mut hi) = (1e-3f64.ln(), 1e9f64.ln());
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if self.temp_of_resistance(mid.exp()) > t {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (0.5 * (lo + hi)).exp()
    }

    /// Temperature (°C) from a normalised ADC reading (0..1 of full scale).
    pub fn temp_of_adc(&self, adc: f64) -> f64 {
        let adc = adc.clamp(0.00001, 0.99999);
        let r = self.pullup * adc / (1.0 - adc) - self.inline_resistor;
        self.temp_of_resistance(r)
    }

    /// The normalised ADC reading (0..1) at temperature `t` (°C), for the MCU's range check.
    pub fn adc_of_temp(&self, t: f64) -> f64 {
        let r = self.resistance_of_temp(t) + self.inline_resistor;
        r / (self.pullup + r)
    }
}

/// Klipper's PID (heaters.py ControlPID): derivative smoothed over `min_deriv_time`, integral
/// clamped so the integral term alone cannot exceed full power, and not accumulated while the
/// output saturates.
#[derive(Debug, Clone)]
pub struct Pid {
    kp: f64,
    ki: f64,
    kd: f64,
    /// Largest duty, 0..1.
    pub max_power: f64,
    /// Derivative smoothing time (heater smooth_time), s.
    pub min_deriv_time: f64,
    integ_max: f64,
    prev_temp: f64,
    prev_time: f64,
    prev_deriv: f64,
    prev_integ: f64,
}

impl Pid {
    /// Gains as in a Klipper config (pid_Kp, pid_Ki, pid_Kd: duty per 255 per K, K·s, K/s).
    pub fn new(pid_kp: f64, pid_ki: f64, pid_kd: f64, max_power: f64, smooth_time: f64) -> Self {
        let ki = pid_ki / PID_PARAM_BASE;
        Self {
            kp: pid_kp / PID_PARAM_BASE,
            ki,
            kd: pid_kd / PID_PARAM_BASE,
            max_power,
            min_deriv_time: smooth_time,
            integ_max: if ki != 0.0 { max_power / ki } else { 0.0 },
            prev_temp: AMBIENT_TEMP,
            prev_time: 0.0,
            prev_deriv: 0.0,
            prev_integ: 0.0,
        }
    }

    /// One update: `temp` (°C) read at `time` (s), `target` (°C). Returns the duty (0..max_power).
    pub fn update(&mut self, time: f64, temp: f64, target: f64) -> f64 {
        let dt = time - self.prev_time;
        let dtemp = temp - self.prev_temp;
        let deriv = if dt >= self.min_deriv_time {
            dtemp / dt
        } else {
            (self.prev_deriv * (self.min_deriv_time - dt) + dtemp) / self.min_deriv_time
        };
        let err = target - temp;
        let integ = (self.prev_integ + err * dt).clamp(0.0, self.integ_max);
        let co = self.kp * err + self.ki * integ - self.kd * deriv;
        let bounded = co.clamp(0.0, self.max_power);
        self.prev_temp = temp;
        self.prev_time = time;
        self.prev_deriv = deriv;
        if co == bounded {
            self.prev_integ = integ;
        }
        bounded
    }
}

/// Why the heater was shut off.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeaterFault {
    /// Not heating at the expected rate, or not holding the target (verify_heater).
    #[error("heater not heating at expected rate: {0}")]
    NotHeating(String),
    /// Above max_temp.
    #[error("temperature {temp:.1} °C above max_temp {max:.1} °C")]
    TooHot {
        /// Read temperature, °C.
        temp: f64,
        /// Limit, °C.
        max: f64,
    },
    /// Below min_temp (an open or shorted thermistor reads far out).
    #[error("temperature {temp:.1} °C below min_temp {min:.1} °C (thermistor disconnected?)")]
    TooCold {
        /// Read temperature, °C.
        temp: f64,
        /// Limit, °C.
        min: f64,
    },
}

/// Klipper's verify_heater as a state machine, checked once a second, plus the range check.
#[derive(Debug, Clone)]
pub struct HeaterCheck {
    /// Allowed shortfall below target that still counts as "at target", K.
    pub hysteresis: f64,
    /// Accumulated shortfall (K per check) that faults a heater that had reached its target, K.
    pub max_error: f64,
    /// Required rise while heating, K per check_gain_time.
    pub heating_gain: f64,
    /// Time allowed for each heating_gain rise, s.
    pub check_gain_time: f64,
    /// Lowest plausible temperature, °C.
    pub min_temp: f64,
    /// Highest allowed temperature, °C.
    pub max_temp: f64,
    approaching: bool,
    starting: bool,
    last_target: f64,
    goal_temp: f64,
    goal_time: f64,
    error: f64,
    next_check: f64,
}

impl HeaterCheck {
    /// Klipper's defaults for an extruder: hysteresis 5, max_error 120, heating_gain 2,
    /// check_gain_time 20.
    pub fn new(min_temp: f64, max_temp: f64) -> Self {
        Self {
            hysteresis: 5.0,
            max_error: 120.0,
            heating_gain: 2.0,
            check_gain_time: 20.0,
            min_temp,
            max_temp,
            approaching: false,
            starting: false,
            last_target: 0.0,
            goal_temp: 0.0,
            goal_time: f64::INFINITY,
            error: 0.0,
            next_check: 0.0,
        }
    }

    /// Feeds a reading (`temp` °C at `time` s, `target` °C); range checks every reading, the
    /// heating checks once a second.
    pub fn check(&mut self, time: f64, temp: f64, target: f64) -> Result<(), HeaterFault> {
        if temp > self.max_temp {
            return Err(HeaterFault::TooHot { temp, max: self.max_temp });
        }
        if temp < self.min_temp {
            return Err(HeaterFault::TooCold { temp, min: self.min_temp });
        }
        if time < self.next_check {
            return Ok(());
        }
        self.next_check = time + 1.0;
        if temp >= target - self.hysteresis || target <= 0.0 {
            self.approaching = false;
            self.starting = false;
            if temp <= target + self.hysteresis {
                self.error = 0.0;
            }
            self.last_target = target;
            return Ok(());
        }
        self.error += (target - self.hysteresis) - temp;
        if !self.approaching {
            if target != self.last_target {
                self.approaching = true;
                self.starting = true;
                self.goal_temp = temp + self.heating_gain;
                self.goal_time = time + self.check_gain_time;
            } else if self.error >= self.max_error {
                return Err(HeaterFault::NotHeating(format!(
                    "{temp:.1} °C is {:.1} K below target {target:.1} °C and not recovering",
                    target - temp
                )));
            }
        } else if temp >= self.goal_temp {
            self.starting = false;
            self.error = 0.0;
            self.goal_temp = temp + self.heating_gain;
            self.goal_time = time + self.check_gain_time;
        } else if time >= self.goal_time {
            self.approaching = false;
        } else if self.starting {
            self.goal_temp = self.goal_temp.min(temp + self.heating_gain);
        }
        self.last_target = target;
        Ok(())
    }
}

/// A simulated hot end (first-order block, first-order sensor lag), the same model as the fake
/// MCU's, for offline tests and PID tuning.
#[derive(Debug, Clone)]
pub struct HotEndModel {
    /// Heater power at full duty, W.
    pub power: f64,
    /// Heat capacity, J/K.
    pub capacity: f64,
    /// Loss to ambient, W/K.
    pub loss: f64,
    /// Sensor lag, s.
    pub lag: f64,
    /// Ambient, °C.
    pub ambient: f64,
    /// Block temperature, °C.
    pub block: f64,
    /// Sensor temperature, °C.
    pub sensor: f64,
}

impl HotEndModel {
    /// Advances `dt` s at `duty` (0..1); returns the sensor temperature, °C.
    pub fn step(&mut self, duty: f64, dt: f64) -> f64 {
        self.block += (duty * self.power - self.loss * (self.block - self.ambient)) / self.capacity * dt;
        self.sensor += (self.block - self.sensor) * (dt / self.lag).min(1.0);
        self.sensor
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermistor_models_roundtrip() {
        // EPCOS 100K B57560G104F points (Klipper's table): 25 °C 100 kΩ, 150 °C 1641.9 Ω,
        // 250 °C 226.15 Ω.
        let sh = Thermistor::steinhart_hart([(25.0, 100_000.0), (150.0, 1641.9), (250.0, 226.15)], 4700.0);
        for (t, r) in [(25.0, 100_000.0), (150.0, 1641.9), (250.0, 226.15)] {
            assert!((sh.temp_of_resistance(r) - t).abs() < 1e-6);
        }
        let b = Thermistor::beta(25.0, 100_000.0, 3950.0, 4700.0);
        assert!((b.temp_of_resistance(100_000.0) - 25.0).abs() < 1e-9);
        for t in [20.0, 100.0, 210.0, 280.0] {
            let adc = b.adc_of_temp(t);
            assert!((b.temp_of_adc(adc) - t).abs() < 1e-6, "{t}");
        }
        // 210 °C on a 4.7k pull-up reads near the bottom of the ADC.
        assert!(b.adc_of_temp(210.0) < 0.15);
    }

    pub(crate) fn model() -> HotEndModel {
        HotEndModel { power: 40.0, capacity: 0.5, loss: 0.1, lag: 0.3, ambient: 25.0, block: 25.0, sensor: 25.0 }
    }

    #[test]
    fn pid_heats_and_holds_offline() {
        let mut m = model();
        let mut pid = Pid::new(8.0, 1.5, 5.0, 1.0, 1.0);
        let mut chk = HeaterCheck::new(0.0, 300.0);
        let dt = 0.1;
        let mut duty = 0.0;
        let mut reached = None;
        let mut peak: f64 = 0.0;
        let mut worst_hold: f64 = 0.0;
        for i in 0..600 {
            let t = i as f64 * dt;
            let temp = m.step(duty, dt);
            chk.check(t, temp, 210.0).unwrap();
            duty = pid.update(t, temp, 210.0);
            if reached.is_none() && temp >= 208.0 {
                reached = Some(t);
            }
            peak = peak.max(temp);
            if t > 30.0 {
                worst_hold = worst_hold.max((temp - 210.0).abs());
            }
        }
        println!(
            "offline: within 2 K of 210 °C after {:.1} s, overshoot {:.1} K, hold ±{:.2} K",
            reached.unwrap(),
            peak - 210.0,
            worst_hold
        );
        assert!(reached.unwrap() < 8.0);
        assert!(peak - 210.0 < 5.0);
        assert!(worst_hold < 1.0);
    }

    #[test]
    fn verify_heater_faults_a_weak_heater_and_a_lost_one() {
        // A heater with a tenth of the power cannot reach 210 °C: faults while approaching.
        let mut m = HotEndModel { power: 8.0, ..model() };
        let mut pid = Pid::new(8.0, 1.5, 5.0, 1.0, 1.0);
        let mut chk = HeaterCheck::new(0.0, 300.0);
        let mut duty = 0.0;
        let mut fault = None;
        for i in 0..3000 {
            let t = i as f64 * 0.1;
            let temp = m.step(duty, 0.1);
            if let Err(e) = chk.check(t, temp, 210.0) {
                fault = Some((t, e));
                break;
            }
            duty = pid.update(t, temp, 210.0);
        }
        let (t, e) = fault.expect("weak heater faults");
        println!("weak heater: {e} after {t:.0} s");
        assert!(matches!(e, HeaterFault::NotHeating(_)));
        // Over max_temp.
        let mut chk = HeaterCheck::new(0.0, 280.0);
        assert!(matches!(chk.check(0.0, 290.0, 210.0), Err(HeaterFault::TooHot { .. })));
        assert!(chk.check(0.0, -20.0, 210.0).unwrap_err().to_string().contains("disconnected"));
    }
}
