//! The Cartesian following-error watchdog (`TcpErrorLimit`): how far the tool is from its path,
//! and for how long.
//!
//! Two distances, both in W. The TCP of the *commanded* joints against the path target of the same
//! tick: the controller's own command leaving the path (out of reach, a joint limit, a singularity,
//! a base that drifted away). The TCP of the *measured* joints against the path *recently
//! commanded*: a robot always lags its command (a cycle or two of the driver, the servo's delay —
//! tens of milliseconds on an industrial arm), so the measured tool is compared with the trail of
//! targets over the last `tcp_error_lag` seconds, as a polyline. A robot that follows late is on its
//! path; one that cuts a corner, sags or was pushed is not. The larger distance is the error; above
//! `tcp_error_limit` for `tcp_error_time` it trips.
//!
//! Fixed size, no allocation: the trail keeps at most [`TRAIL_POINTS`] targets, one every
//! `tcp_error_lag / TRAIL_POINTS` seconds (and at least one a tick).

use nalgebra::Vector3;

use super::path::distance_to_segment;

/// Targets the trail keeps.
pub(crate) const TRAIL_POINTS: usize = 64;

/// The watchdog's state.
#[derive(Clone, Debug)]
pub(crate) struct FollowingWatch {
    limit: f64,
    time_ns: u64,
    every_ns: u64,
    trail: [Vector3<f64>; TRAIL_POINTS],
    len: usize,
    head: usize,
    last_point_ns: u64,
    since_ns: Option<u64>,
}

impl FollowingWatch {
    /// A watchdog tripping at `limit` (m; 0 disables tripping) held for `time` (s), tolerating a
    /// robot lag of up to `lag` (s).
    pub(crate) fn new(limit: f64, time: f64, lag: f64) -> Self {
        FollowingWatch {
            limit,
            time_ns: (time * 1e9).round() as u64,
            every_ns: (lag * 1e9 / TRAIL_POINTS as f64).round() as u64,
            trail: [Vector3::zeros(); TRAIL_POINTS],
            len: 0,
            head: 0,
            last_point_ns: 0,
            since_ns: None,
        }
    }

    /// Forgets the trail and the clock (the path is not running).
    pub(crate) fn reset(&mut self) {
        self.len = 0;
        self.since_ns = None;
    }

    /// One tick at `now_ns` with the path `target`, the `commanded` TCP and, with a fresh joint
    /// state, the `measured` one (all m, W). Returns the error (m) and whether the watchdog trips.
    pub(crate) fn observe(
        &mut self,
        now_ns: u64,
        target: &Vector3<f64>,
        commanded: &Vector3<f64>,
        measured: Option<&Vector3<f64>>,
    ) -> (f64, bool) {
        let mut error = (commanded - target).norm();
        if let Some(m) = measured {
            error = error.max(self.distance_to_trail(m, target));
        }
        if self.len == 0 || now_ns.saturating_sub(self.last_point_ns) >= self.every_ns {
            self.trail[self.head] = *target;
            self.head = (self.head + 1) % TRAIL_POINTS;
            self.len = (self.len + 1).min(TRAIL_POINTS);
            self.last_point_ns = now_ns;
        }
        if !error.is_finite() {
            error = f64::INFINITY;
        }
        if self.limit <= 0.0 || error <= self.limit {
            self.since_ns = None;
            return (error, false);
        }
        let since = *self.since_ns.get_or_insert(now_ns);
        (error, now_ns.saturating_sub(since) >= self.time_ns)
    }

    /// Distance (m) from `p` to the polyline of the trail, ending at the current `target`.
    fn distance_to_trail(&self, p: &Vector3<f64>, target: &Vector3<f64>) -> f64 {
        let mut best = (p - target).norm();
        let mut next = *target;
        for k in 0..self.len {
            let point = self.trail[(self.head + TRAIL_POINTS - 1 - k) % TRAIL_POINTS];
            best = best.min(distance_to_segment(p, &point, &next));
            next = point;
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_robot_that_lags_along_the_path_is_on_it_and_one_beside_it_is_not() {
        // 1 kHz, a path along x at 0.25 m/s; the robot 40 ms behind (10 mm), then 3 mm beside it.
        let mut w = FollowingWatch::new(2e-3, 0.05, 0.1);
        let at = |t: f64| Vector3::new(0.25 * t, 0.0, 0.0);
        let mut tripped_at = None;
        for k in 0..400u64 {
            let t = k as f64 * 1e-3;
            let lagging = at((t - 0.04).max(0.0));
            let measured = if k < 200 { lagging } else { lagging + Vector3::new(0.0, 3e-3, 0.0) };
            let (error, trip) = w.observe(k * 1_000_000, &at(t), &at(t), Some(&measured));
            if k < 200 {
                assert!(error < 1e-12, "tick {k}: lag taken for error {error}");
            } else {
                assert!((error - 3e-3).abs() < 1e-9, "tick {k}: error {error}");
            }
            if trip && tripped_at.is_none() {
                tripped_at = Some(k);
            }
        }
        assert_eq!(tripped_at, Some(250), "50 ms above the limit");
        // The commanded TCP is held to the target of the same tick.
        let mut w = FollowingWatch::new(2e-3, 0.0, 0.1);
        let (error, trip) = w.observe(0, &at(0.0), &Vector3::new(0.0, 0.0, 2.5e-3), None);
        assert_eq!((error, trip), (2.5e-3, true));
        // A limit of 0 never trips but still measures.
        let mut w = FollowingWatch::new(0.0, 0.0, 0.1);
        assert_eq!(w.observe(0, &at(0.0), &Vector3::new(1.0, 0.0, 0.0), None), (1.0, false));
    }
}
