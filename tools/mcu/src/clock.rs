//! The MCU's clock in terms of the host's CLOCK_MONOTONIC.
//!
//! Every scheduled MCU command (a step, a heater update) carries an MCU clock value, so the host
//! must know what MCU clock a host instant corresponds to, to a fraction of a millisecond, while
//! the two crystals drift apart by tens of ppm. As Klipper's clocksync.py: the host sends
//! `get_clock` periodically and regresses the MCU clock of each answer against the host time the
//! request was *sent* (exponentially decaying averages, so old samples fade), which gives the
//! frequency (ticks per host second) and an offset. The prediction's variance rejects outliers (a
//! reply delayed by a busy host would otherwise pull the estimate late). The MCU reports a 32-bit
//! clock (wraps every 358 s at 12 MHz); `get_uptime` gives the 64-bit start and each 32-bit value
//! is extended from the last one.

/// Decay of the regression averages per sample (clocksync.py DECAY).
pub const DECAY: f64 = 1.0 / 30.0;
/// How much slower an old best round trip becomes per second of age (clocksync.py RTT_AGE).
pub const RTT_AGE: f64 = 0.000010 / (60.0 * 60.0);

/// The host's estimate of the MCU clock.
#[derive(Debug, Clone)]
pub struct ClockSync {
    /// Nominal frequency from the dictionary (CLOCK_FREQ), Hz.
    pub mcu_freq: f64,
    last_clock: u64,
    time_avg: f64,
    time_variance: f64,
    clock_avg: f64,
    clock_covariance: f64,
    prediction_variance: f64,
    last_prediction_time: f64,
    /// Half the smallest round-trip time seen (aged), s.
    pub min_half_rtt: f64,
    min_rtt_time: f64,
    /// The estimate: (host time s, MCU clock ticks, frequency ticks/s).
    est: (f64, f64, f64),
    /// Samples rejected as outliers (count).
    pub outliers: u64,
}

impl ClockSync {
    /// Starts from a `get_uptime` answer: the 64-bit clock `clock64` (ticks) seen for a request
    /// sent at host time `sent_time` (s).
    pub fn new(mcu_freq: f64, clock64: u64, sent_time: f64) -> Self {
        Self {
            mcu_freq,
            last_clock: clock64,
            time_avg: sent_time,
            time_variance: 0.0,
            clock_avg: clock64 as f64,
            clock_covariance: 0.0,
            prediction_variance: (0.001 * mcu_freq).powi(2),
            last_prediction_time: -9999.0,
            min_half_rtt: f64::MAX,
            min_rtt_time: 0.0,
            est: (sent_time, clock64 as f64, mcu_freq),
            outliers: 0,
        }
    }

    /// Extends a 32-bit MCU clock (ticks) to 64 bits, taking the nearest value to the last seen
    /// (good for ±2^31 ticks: ±179 s at 12 MHz).
    pub fn clock32_to_64(&self, clock32: u32) -> u64 {
        let diff = clock32.wrapping_sub(self.last_clock as u32) as i32;
        (self.last_clock as i64 + i64::from(diff)).max(0) as u64
    }

    /// Handles a `clock` answer: 32-bit `clock32` (ticks) for a request sent at `sent_time` and
    /// received at `receive_time` (host s). Returns false for a rejected outlier.
    pub fn handle_clock(&mut self, clock32: u32, sent_time: f64, receive_time: f64) -> bool {
        let delta = clock32.wrapping_sub(self.last_clock as u32);
        let clock = self.last_clock + u64::from(delta);
        self.last_clock = clock;
        let clock = clock as f64;
        // Compare with the prediction; drop a sample far later than expected (a delayed reply).
        let old_freq = self.est.2;
        let exp_clock = (sent_time - self.time_avg) * old_freq + self.clock_avg;
        let diff2 = (clock - exp_clock).powi(2);
        if diff2 > 25.0 * self.prediction_variance && diff2 > (0.000500 * self.mcu_freq).powi(2) {
            if clock > exp_clock && sent_time < self.last_prediction_time + 10.0 {
                self.outliers += 1;
                return false;
            }
            self.prediction_variance = (0.001 * self.mcu_freq).powi(2);
        } else {
            self.last_prediction_time = sent_time;
            self.prediction_variance = (1.0 - DECAY) * (self.prediction_variance + diff2 * DECAY);
        }
        let dt = sent_time - self.time_avg;
        self.time_avg += DECAY * dt;
        self.time_variance = (1.0 - DECAY) * (self.time_variance + dt * dt * DECAY);
        let dc = clock - self.clock_avg;
        self.clock_avg += DECAY * dc;
        self.clock_covariance = (1.0 - DECAY) * (self.clock_covariance + dt * dc * DECAY);
        let freq = if self.time_variance > 0.0 { self.clock_covariance / self.time_variance } else { self.mcu_freq };
        // The MCU read its clock somewhere between send and receive; the best round trip bounds
        // where: half of it after sending.
        let half_rtt = 0.5 * (receive_time - sent_time);
        let aged = (sent_time - self.min_rtt_time) * RTT_AGE;
        if half_rtt < self.min_half_rtt + aged {
            self.min_half_rtt = half_rtt;
            self.min_rtt_time = sent_time;
        }
        self.est = (self.time_avg + self.min_half_rtt, self.clock_avg, freq);
        true
    }

    /// The estimated MCU clock at host time `t` (s), ticks (64-bit).
    pub fn clock_at(&self, t: f64) -> f64 {
        let (st, c, f) = self.est;
        c + (t - st) * f
    }

    /// The host time (s) when the MCU clock reads `clock` (ticks, 64-bit).
    pub fn time_of(&self, clock: f64) -> f64 {
        let (st, c, f) = self.est;
        (clock - c) / f + st
    }

    /// The estimated frequency, ticks per host second.
    pub fn freq(&self) -> f64 {
        self.est.2
    }

    /// One standard deviation of the prediction, ticks.
    pub fn prediction_stddev(&self) -> f64 {
        self.prediction_variance.sqrt()
    }

    /// The latest 64-bit clock seen, ticks.
    pub fn last_clock(&self) -> u64 {
        self.last_clock
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_on_drifting_clock_with_jittery_rtt() {
        let nominal = 12e6;
        let true_freq = nominal * (1.0 + 50e-6);
        let offset = 4_000_000_000.0; // wraps the 32-bit clock soon
        let mcu = |t: f64| offset + t * true_freq;
        let mut s = 12345u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut cs = ClockSync::new(nominal, mcu(0.0) as u64, 0.0);
        let mut t = 0.0;
        let mut worst_late = 0.0f64;
        for i in 0..400 {
            // Klipper's period (0.9839 s); USB-serial jitter up to 1 ms each way; 1 in 20 replies
            // delayed 20 ms (a busy host).
            t += 0.9839;
            let up = 0.0001 + 0.001 * rnd();
            let down = 0.0001 + 0.001 * rnd() + if i % 20 == 7 { 0.02 } else { 0.0 };
            let clock = mcu(t + up) as u64;
            cs.handle_clock(clock as u32, t, t + up + down);
            if i > 200 {
                let err_s = (cs.clock_at(t) - mcu(t)) / true_freq;
                worst_late = worst_late.max(err_s.abs());
            }
        }
        let ppm = (cs.freq() / true_freq - 1.0) * 1e6;
        println!("frequency error {ppm:.2} ppm, worst clock error {:.0} us", worst_late * 1e6);
        // The nominal frequency is 50 ppm off; the estimate must find the true one.
        assert!(ppm.abs() < 10.0, "frequency error {ppm} ppm");
        // Error bounded by the round trip's uncertainty (1 ms jitter) after convergence.
        assert!(worst_late < 0.001, "clock error {worst_late} s");
        assert!(cs.last_clock() > u64::from(u32::MAX), "64-bit extension across the wrap");
    }
}
