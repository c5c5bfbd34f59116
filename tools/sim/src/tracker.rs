//! Optical tracking of the robot base: samples at a fixed rate, each stamped with its measurement
//! time, delivered after a latency, with noise and occasional dropouts (occluded markers).

use std::collections::VecDeque;

use super::Gaussian;
use super::config::TrackerConfig;

/// A measured robot-base pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Measurement time (ns, the sim's clock).
    pub stamp_ns: u64,
    /// Position (m, W).
    pub position: [f64; 3],
    /// Heading about W's z axis (rad).
    pub theta: f64,
}

/// The tracker's schedule and its samples in flight.
pub(crate) struct Tracker {
    cfg: TrackerConfig,
    period_ns: u64,
    latency_ns: u64,
    next_ns: u64,
    in_flight: VecDeque<Sample>,
    /// Samples measured.
    pub measured: u64,
    /// Samples lost.
    pub dropped: u64,
    /// The latest sample delivered.
    pub latest: Option<Sample>,
}

impl Tracker {
    /// A tracker whose first measurement is at `start_ns`.
    pub(crate) fn new(cfg: &TrackerConfig, start_ns: u64) -> Self {
        Tracker {
            cfg: cfg.clone(),
            period_ns: (1e9 / cfg.rate_hz).round() as u64,
            latency_ns: (cfg.latency * 1e9).round() as u64,
            next_ns: start_ns,
            in_flight: VecDeque::new(),
            measured: 0,
            dropped: 0,
            latest: None,
        }
    }

    /// At sim time `now_ns`, with the true pose `truth` (position, θ): takes the measurements that
    /// are due and returns the samples that arrive by now (oldest first).
    pub(crate) fn poll(&mut self, now_ns: u64, truth: ([f64; 3], f64), noise: &mut Gaussian, out: &mut Vec<Sample>) {
        while self.next_ns <= now_ns {
            self.measured += 1;
            let lost = noise.uniform() < self.cfg.dropout;
            if lost {
                self.dropped += 1;
            } else {
                let (p, th) = truth;
                let n = self.cfg.noise;
                self.in_flight.push_back(Sample {
                    stamp_ns: self.next_ns,
                    position: [p[0] + n * noise.sample(), p[1] + n * noise.sample(), p[2] + n * noise.sample()],
                    theta: th + self.cfg.noise_yaw * noise.sample(),
                });
            }
            self.next_ns += self.period_ns;
        }
        while self.in_flight.front().is_some_and(|s| s.stamp_ns + self.latency_ns <= now_ns) {
            let s = self.in_flight.pop_front().expect("non-empty");
            self.latest = Some(s);
            out.push(s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_arrive_late_at_the_rate_with_dropouts() {
        let cfg = TrackerConfig { rate_hz: 100.0, latency: 0.02, noise: 0.0, noise_yaw: 0.0, dropout: 0.1 };
        let mut t = Tracker::new(&cfg, 0);
        let mut g = Gaussian::new(7);
        let mut got = Vec::new();
        for k in 0..100_000u64 {
            let now = k * 1_000_000;
            let before = got.len();
            t.poll(now, ([1.0, 2.0, 0.3], 0.5), &mut g, &mut got);
            for s in &got[before..] {
                assert_eq!(now - s.stamp_ns, 20_000_000, "delivered exactly one latency after measurement");
                assert_eq!(s.position, [1.0, 2.0, 0.3]);
            }
        }
        assert_eq!(t.measured, 10_000);
        assert_eq!(got.len() as u64 + t.dropped + t.in_flight.len() as u64, t.measured);
        assert!(t.in_flight.len() <= 2, "only the last 20 ms are still in flight");
        let rate = t.dropped as f64 / t.measured as f64;
        assert!((rate - 0.1).abs() < 0.01, "dropout rate {rate}");
    }
}
