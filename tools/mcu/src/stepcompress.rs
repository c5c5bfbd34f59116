//! Step times → Klipper `queue_step` commands, and step times from a position trajectory.
//!
//! The MCU steps by arithmetic (firmware `stepper_event`): after `queue_step interval count add`,
//! the first step comes `interval` ticks after the previous step (or after `reset_step_clock`),
//! and each following interval grows by `add`. So step k (1-based) of a command is at
//! `base + k*interval + add*k*(k-1)/2`. A command covers a stretch of steps whose ideal times all
//! fit that quadratic within the allowed error; like Klipper, a step may be early by up to
//! `max_error` but never late, and never before the midpoint to the previous step (so order is
//! kept). Direction changes (retractions) split the stream with `set_next_step_dir`.
//!
//! [`StepGenerator`] turns motor positions sampled at the controller's tick into the exact step
//! instants: the position is linear between samples, and a step happens when it crosses a
//! half-step boundary (so the stepper's count is always the nearest integer to the commanded
//! position).

/// One command for the stepper (MCU clocks are 64-bit here; the wire takes the low 32 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepCmd {
    /// `reset_step_clock`: the next step's interval counts from this clock, ticks.
    Reset {
        /// MCU clock, ticks.
        clock: u64,
    },
    /// `set_next_step_dir`: direction of the following steps (1 = positive).
    Dir(u8),
    /// `queue_step`.
    Queue {
        /// Ticks from the previous step to the first one.
        interval: u32,
        /// Number of steps.
        count: u16,
        /// Change of the interval after each step, ticks.
        add: i16,
    },
}

/// Compresses a stream of step times into [`StepCmd`]s.
#[derive(Debug, Clone)]
pub struct StepCompress {
    /// Largest allowed earliness of a step, ticks (Klipper: 25 µs worth).
    pub max_error: u64,
    /// A gap longer than this between steps restarts the clock with `reset_step_clock`, ticks
    /// (well under 2^31 so the 32-bit interval never overflows).
    pub reset_gap: u64,
    last_step: Option<u64>,
    dir: Option<u8>,
    pending: Vec<u64>,
    pending_dir: u8,
}

impl StepCompress {
    /// A compressor allowing `max_error` ticks of error.
    pub fn new(max_error: u64) -> Self {
        Self { max_error, reset_gap: 1 << 28, last_step: None, dir: None, pending: Vec::new(), pending_dir: 1 }
    }

    /// Adds steps (MCU clock ticks, increasing; direction 1 = positive, 0 = negative) and returns
    /// the commands for all but the last few (kept to compress with what follows). Call
    /// [`StepCompress::flush`] to emit everything.
    pub fn push(&mut self, steps: &[(u64, u8)]) -> Vec<StepCmd> {
        let mut out = Vec::new();
        for &(t, d) in steps {
            if d != self.pending_dir && !self.pending.is_empty() {
                self.compress(&mut out, true);
            }
            self.pending_dir = d;
            self.pending.push(t);
        }
        if self.pending.len() > 2000 {
            self.compress(&mut out, false);
        }
        out
    }

    /// The earliest step not yet compressed, ticks.
    pub fn oldest_pending(&self) -> Option<u64> {
        self.pending.first().copied()
    }

    /// Emits commands for every pending step.
    pub fn flush(&mut self) -> Vec<StepCmd> {
        let mut out = Vec::new();
        self.compress(&mut out, true);
        out
    }

    fn compress(&mut self, out: &mut Vec<StepCmd>, all: bool) {
        let keep = if all { 0 } else { 500 };
        let mut i = 0;
        while self.pending.len() - i > keep {
            let first = self.pending[i];
            let base = match self.last_step {
                Some(l) if first > l && first - l < self.reset_gap => l,
                _ => {
                    // Idle or first ever: restart the clock just before the step.
                    let b = first.saturating_sub(1);
                    out.push(StepCmd::Reset { clock: b });
                    b
                }
            };
            if self.dir != Some(self.pending_dir) {
                out.push(StepCmd::Dir(self.pending_dir));
                self.dir = Some(self.pending_dir);
            }
            let prev_ideal = self.last_step.unwrap_or(base);
            let (interval, count, add) = self.best(base, prev_ideal, &self.pending[i..]);
            out.push(StepCmd::Queue { interval, count, add });
            let c = u64::from(count);
            let end = base as i128 + c as i128 * i128::from(interval) + i128::from(add) * (c * (c - 1) / 2) as i128;
            self.last_step = Some(end as u64);
            i += count as usize;
        }
        self.pending.drain(..i);
    }

    /// Bounds of step k's time (absolute ticks): early by at most max_error, not before the
    /// midpoint to the previous ideal step, never late.
    fn bounds(&self, prev_ideal: u64, ideal: &[u64], k: usize) -> (i128, i128) {
        let t = ideal[k] as i128;
        let prev = if k == 0 { prev_ideal as i128 } else { ideal[k - 1] as i128 };
        let lo = (t - self.max_error as i128).max((prev + t).div_euclid(2) + 1).min(t);
        (lo, t)
    }

    /// The feasible (interval) range for `count` steps with this `add`, if any.
    fn interval_range(&self, base: u64, prev_ideal: u64, ideal: &[u64], count: usize, add: i64) -> Option<(i128, i128)> {
        let mut lo = i128::MIN;
        let mut hi = i128::MAX;
        for k in 0..count {
            let (l, h) = self.bounds(prev_ideal, ideal, k);
            let n = (k + 1) as i128;
            let q = i128::from(add) * n * (n - 1) / 2;
            // l <= base + n*I + q <= h
            let lo_k = (l - base as i128 - q + n - 1).div_euclid(n);
            let hi_k = (h - base as i128 - q).div_euclid(n);
            lo = lo.max(lo_k);
            hi = hi.min(hi_k);
            if lo > hi {
                return None;
            }
        }
        let lo = lo.max(1);
        if lo > hi || lo > i128::from(i32::MAX) {
            return None;
        }
        Some((lo, hi))
    }

    /// A feasible (interval, add) for `count` steps, trying adds near the end-point fit.
    fn fit(&self, base: u64, prev_ideal: u64, ideal: &[u64], count: usize) -> Option<(u32, i16)> {
        let t1 = ideal[0] as f64 - base as f64;
        let add0 = if count > 1 {
            let n = count as f64;
            let tn = ideal[count - 1] as f64 - base as f64;
            let t1m = t1 - self.max_error as f64 / 2.0;
            let tnm = tn - self.max_error as f64 / 2.0;
            ((tnm - n * t1m) * 2.0 / (n * (n - 1.0))).round()
        } else {
            0.0
        };
        let add0 = add0.clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i64;
        for da in [0i64, -1, 1, -2, 2, -3, 3] {
            let add = add0 + da;
            if add < i64::from(i16::MIN) || add > i64::from(i16::MAX) {
                continue;
            }
            // The last interval must stay positive: the firmware's interval is unsigned.
            if let Some((lo, hi)) = self.interval_range(base, prev_ideal, ideal, count, add) {
                let last_iv = hi + i128::from(add) * (count as i128 - 1);
                if last_iv <= 0 {
                    continue;
                }
                // Latest feasible interval: closest to the ideal times (steps are never late).
                let _ = lo;
                return Some((hi as u32, add as i16));
            }
        }
        None
    }

    fn best(&self, base: u64, prev_ideal: u64, ideal: &[u64]) -> (u32, u16, i16) {
        let maxc = ideal.len().min(u16::MAX as usize);
        // Exponential then binary search for the longest feasible count.
        let mut good = 1usize;
        let mut good_fit = self.fit(base, prev_ideal, ideal, 1).unwrap_or_else(|| {
            // A single step always fits exactly at its ideal time.
            ((ideal[0].saturating_sub(base)).clamp(1, u64::from(u32::MAX)) as u32, 0)
        });
        let mut bad = maxc + 1;
        let mut c = 2;
        while c <= maxc {
            match self.fit(base, prev_ideal, ideal, c) {
                Some(f) => {
                    good = c;
                    good_fit = f;
                    c *= 2;
                }
                None => {
                    bad = c;
                    break;
                }
            }
        }
        if c > maxc && good < maxc {
            if let Some(f) = self.fit(base, prev_ideal, ideal, maxc) {
                return (f.0, maxc as u16, f.1);
            }
            bad = maxc;
        }
        while bad - good > 1 {
            let mid = (good + bad) / 2;
            match self.fit(base, prev_ideal, ideal, mid) {
                Some(f) => {
                    good = mid;
                    good_fit = f;
                }
                None => bad = mid,
            }
        }
        (good_fit.0, good as u16, good_fit.1)
    }
}

/// Step instants from a motor position sampled at a fixed tick.
#[derive(Debug, Clone)]
pub struct StepGenerator {
    /// Steps per metre of position (full steps × microsteps / rotation distance), 1/m.
    pub steps_per_m: f64,
    /// Steps taken (the stepper's count), steps.
    pub position: i64,
    last: Option<(f64, f64)>,
}

impl StepGenerator {
    /// A generator for `full_steps_per_rotation`, `microsteps` and `rotation_distance` (m).
    pub fn new(full_steps_per_rotation: u32, microsteps: u32, rotation_distance: f64) -> Self {
        Self { steps_per_m: f64::from(full_steps_per_rotation * microsteps) / rotation_distance, position: 0, last: None }
    }

    /// The next sample: position `pos` (m) at time `t` (s). Returns the steps since the previous
    /// sample: time (s) and direction (1 = positive).
    pub fn sample(&mut self, t: f64, pos: f64) -> Vec<(f64, u8)> {
        let s = pos * self.steps_per_m;
        let mut out = Vec::new();
        let Some((t0, s0)) = self.last else {
            self.last = Some((t, s));
            self.position = s.round() as i64;
            return out;
        };
        self.last = Some((t, s));
        let at = |x: f64| if s == s0 { t } else { t0 + (t - t0) * (x - s0) / (s - s0) };
        // Up: cross position + 0.5; down: cross position - 0.5.
        while s >= self.position as f64 + 0.5 {
            out.push((at(self.position as f64 + 0.5), 1));
            self.position += 1;
        }
        while s < self.position as f64 - 0.5 {
            out.push((at(self.position as f64 - 0.5), 0));
            self.position -= 1;
        }
        out
    }
}

/// The firmware's step times for a command list (the `stepper_event` arithmetic, 32-bit wrapping
/// intervals), as 64-bit clocks with the direction; for tests and for the fake's cross-check.
pub fn reconstruct(cmds: &[StepCmd]) -> Vec<(u64, u8)> {
    let mut out = Vec::new();
    let mut t = 0u64;
    let mut dir = 1u8;
    for c in cmds {
        match *c {
            StepCmd::Reset { clock } => t = clock,
            StepCmd::Dir(d) => dir = d,
            StepCmd::Queue { interval, count, add } => {
                let mut iv = interval;
                for _ in 0..count {
                    t = t.wrapping_add(u64::from(iv));
                    out.push((t, dir));
                    iv = iv.wrapping_add(add as i32 as u32);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 kHz extrusion profile: accelerate, cruise, retract, un-retract, slow down.
    fn profile(t: f64) -> f64 {
        let v = 0.004; // 4 mm/s filament
        let base = if t < 0.2 { 0.5 * v / 0.2 * t * t } else { v * 0.1 + v * (t - 0.2) };
        // Retraction of 1 mm at 40 mm/s between 0.6 and 0.625 s, back between 0.8 and 0.825 s.
        let r = |a: f64| ((t - a) / 0.025).clamp(0.0, 1.0);
        base - 0.001 * r(0.6) + 0.001 * r(0.8)
    }

    #[test]
    fn compresses_within_max_error_and_tracks_the_command() {
        let freq = 12e6;
        let max_error = (25e-6 * freq) as u64;
        let mut g = StepGenerator::new(200, 16, 0.0226); // a geared extruder, ~141 steps/mm
        let mut sc = StepCompress::new(max_error);
        let t0 = 0.1;
        let mut ideal = Vec::new();
        let mut cmds = Vec::new();
        let mut samples = Vec::new();
        for i in 0..=1200 {
            let t = i as f64 * 0.001;
            let steps = g.sample(t, profile(t));
            samples.push((t, g.position, profile(t) * g.steps_per_m));
            let s: Vec<(u64, u8)> = steps.iter().map(|&(ts, d)| (((ts + t0) * freq) as u64, d)).collect();
            ideal.extend_from_slice(&s);
            cmds.extend(sc.push(&s));
        }
        cmds.extend(sc.flush());
        let got = reconstruct(&cmds);
        assert_eq!(got.len(), ideal.len());
        let mut worst = 0i64;
        for (g, i) in got.iter().zip(&ideal) {
            assert_eq!(g.1, i.1, "direction");
            let e = i.0 as i64 - g.0 as i64;
            assert!((0..=max_error as i64).contains(&e), "step early by {e} ticks");
            worst = worst.max(e);
        }
        let queue_steps = cmds.iter().filter(|c| matches!(c, StepCmd::Queue { .. })).count();
        let dirs = cmds.iter().filter(|c| matches!(c, StepCmd::Dir(_))).count();
        println!(
            "{} steps in {queue_steps} queue_step commands, {dirs} direction changes, worst {:.1} us early",
            ideal.len(),
            worst as f64 / 12.0
        );
        assert!(dirs >= 3, "retraction and un-retraction change direction");
        // The stepper's count follows the command within one step at every sample instant.
        for &(t, _, cmd) in &samples {
            let c = ((t + t0) * freq) as u64;
            let count: i64 = got.iter().filter(|s| s.0 <= c).map(|s| if s.1 == 1 { 1 } else { -1 }).sum();
            assert!((count as f64 - cmd).abs() <= 1.0, "at {t}: {count} steps for {cmd}");
        }
    }
}
