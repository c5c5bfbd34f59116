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
//!
//! The distance to the trail is incremental, and exactly the full scan's. The trail is kept in
//! [`BLOCKS`] blocks of consecutive points, each with the box that holds its segments, updated as
//! a point arrives. Each tick starts at the block that held the nearest segment last tick (the
//! nearest point moves forward along the path with the robot), and then skips every block whose box
//! is farther than the nearest distance found: a robot near its path looks at one or two blocks, not
//! at 64 segments. A box holds every segment of its block, so no skipped segment could have been
//! nearer, and the minimum is taken over the same segment distances, computed by the same function,
//! as a scan of all of them: the result is the scan's to the bit (a test compares them on random
//! trails), and logs replay unchanged. A walk that only follows the nearest point forward would be
//! cheaper still, but it returns a local minimum: where the path folds back within the lag window
//! (a corner, a zig-zag infill) it reports another distance than the scan, and the watchdog would
//! trip on another tick than the logs recorded.

use nalgebra::Vector3;

use super::path::distance_to_segment;

/// Targets the trail keeps.
pub(crate) const TRAIL_POINTS: usize = 64;
/// Blocks the trail is kept in, [`BLOCK`] points each.
pub(crate) const BLOCKS: usize = 8;
/// Points a block holds.
const BLOCK: usize = TRAIL_POINTS / BLOCKS;
/// How much nearer than its box (m) a segment's computed distance may come, by rounding: far
/// above the rounding of coordinates of metres (1e-15 m), far below anything a watchdog tells.
const ROUNDING: f64 = 1e-9;

/// An axis-aligned box (m, W): the corners.
#[derive(Clone, Copy, Debug)]
struct Bounds {
    lo: Vector3<f64>,
    hi: Vector3<f64>,
}

impl Bounds {
    const EMPTY: Bounds = Bounds {
        lo: Vector3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY),
        hi: Vector3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY),
    };

    fn add(&mut self, p: &Vector3<f64>) {
        self.lo = self.lo.inf(p);
        self.hi = self.hi.sup(p);
    }

    /// The squared distance (m²) from `p` to the box (0 inside; +∞ for an empty box).
    fn distance_squared(&self, p: &Vector3<f64>) -> f64 {
        let mut d = 0.0;
        for i in 0..3 {
            let e = (self.lo[i] - p[i]).max(p[i] - self.hi[i]).max(0.0);
            d += e * e;
        }
        if self.lo[0] > self.hi[0] { f64::INFINITY } else { d }
    }
}

/// The watchdog's state.
#[derive(Clone, Debug)]
pub(crate) struct FollowingWatch {
    limit: f64,
    time_ns: u64,
    every_ns: u64,
    trail: [Vector3<f64>; TRAIL_POINTS],
    len: usize,
    head: usize,
    /// Per block: the box of its points and of the point before its first (the older end of its
    /// oldest segment), among the points kept.
    bounds: [Bounds; BLOCKS],
    /// The slots holding a non-finite point (bit i: slot i): with one kept, the full scan decides.
    non_finite: u64,
    /// The block that held the nearest segment last tick: where the next search starts.
    near_block: usize,
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
            bounds: [Bounds::EMPTY; BLOCKS],
            non_finite: 0,
            near_block: 0,
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
            self.push(target);
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

    /// Keeps `point` as the trail's newest and brings the boxes it belongs to up to date.
    fn push(&mut self, point: &Vector3<f64>) {
        let slot = self.head;
        self.trail[slot] = *point;
        let bit = 1u64 << slot;
        self.non_finite = if point.iter().all(|x| x.is_finite()) { self.non_finite & !bit } else { self.non_finite | bit };
        self.head = (self.head + 1) % TRAIL_POINTS;
        self.len = (self.len + 1).min(TRAIL_POINTS);
        self.update_bounds(slot / BLOCK);
        if slot % BLOCK == BLOCK - 1 {
            // The first point of the next block's oldest segment.
            self.update_bounds((slot / BLOCK + 1) % BLOCKS);
        }
    }

    /// Whether `slot` holds one of the points kept.
    fn kept(&self, slot: usize) -> bool {
        (self.head + TRAIL_POINTS - 1 - slot) % TRAIL_POINTS < self.len
    }

    fn update_bounds(&mut self, block: usize) {
        let mut b = Bounds::EMPTY;
        let before = (block * BLOCK + TRAIL_POINTS - 1) % TRAIL_POINTS;
        for slot in core::iter::once(before).chain(block * BLOCK..(block + 1) * BLOCK) {
            if self.kept(slot) {
                b.add(&self.trail[slot]);
            }
        }
        self.bounds[block] = b;
    }

    /// Distance (m) from `p` to the polyline of the trail, ending at the current `target`: the
    /// segment from the target to the newest point, the nearest block of last tick's, then every
    /// block whose box is not farther than the nearest found (module documentation).
    fn distance_to_trail(&mut self, p: &Vector3<f64>, target: &Vector3<f64>) -> f64 {
        let finite = self.non_finite == 0 && p.iter().chain(target.iter()).all(|x| x.is_finite());
        if !finite {
            return self.distance_to_trail_scan(p, target);
        }
        let mut best = (p - target).norm();
        if self.len == 0 {
            return best;
        }
        let newest = (self.head + TRAIL_POINTS - 1) % TRAIL_POINTS;
        best = best.min(distance_to_segment(p, &self.trail[newest], target));
        let first = self.near_block;
        for k in 0..BLOCKS {
            let block = (first + k) % BLOCKS;
            let reach = best + ROUNDING;
            if self.bounds[block].distance_squared(p) > reach * reach {
                continue;
            }
            let d = self.block_distance(p, block);
            if d < best {
                best = d;
                self.near_block = block;
            }
        }
        best
    }

    /// The nearest (m) of the segments of `block` that the trail holds (+∞ for none): each from a
    /// kept point of the block to the kept point before it.
    fn block_distance(&self, p: &Vector3<f64>, block: usize) -> f64 {
        let mut best = f64::INFINITY;
        for slot in block * BLOCK..(block + 1) * BLOCK {
            let before = (slot + TRAIL_POINTS - 1) % TRAIL_POINTS;
            // Both kept: `slot` is kept and not the oldest.
            if self.kept(slot) && (self.head + TRAIL_POINTS - 1 - slot) % TRAIL_POINTS + 1 < self.len {
                best = best.min(distance_to_segment(p, &self.trail[before], &self.trail[slot]));
            }
        }
        best
    }

    /// The same distance by a scan of every segment: the reference, and the answer when a point
    /// is not finite.
    fn distance_to_trail_scan(&self, p: &Vector3<f64>, target: &Vector3<f64>) -> f64 {
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
    /// A small deterministic generator (xorshift64*), so the random trails are the same every run.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn vector(&mut self, scale: f64) -> Vector3<f64> {
            Vector3::new(self.next() - 0.5, self.next() - 0.5, self.next() - 0.5) * scale
        }
    }

    /// The incremental distance is the full scan's to the bit, on trails of every kind: random
    /// points, zig-zags that fold back within the lag window, a robot lagging on the path, beside
    /// it and far from it, a trail filling up, wrapping round and reset, and points kept on only
    /// some ticks.
    #[test]
    fn the_incremental_distance_is_the_full_scans_to_the_bit() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let mut compared = 0usize;
        let mut skipped_blocks = 0usize;
        for trial in 0..60 {
            let every_ns = [1_000_000u64, 1_562_500, 3_000_000][trial % 3];
            let mut w = FollowingWatch::new(1e-3, 0.01, every_ns as f64 * TRAIL_POINTS as f64 * 1e-9);
            let mut target = rng.vector(1.0);
            let mut velocity = rng.vector(0.5);
            let mut history = Vec::new();
            for k in 0..700u64 {
                if trial % 4 == 0 {
                    // Random points: no path at all.
                    target = rng.vector(0.05);
                } else {
                    // A path that turns, sharply and often on some trails (zig-zags).
                    if rng.next() < [0.0, 0.02, 0.2, 0.5][trial % 4] {
                        velocity = rng.vector(0.5);
                    }
                    target += velocity * 1e-3;
                }
                history.push(target);
                let lag = (rng.next() * 150.0) as usize;
                let behind = history[history.len().saturating_sub(1 + lag)];
                let measured = match k % 5 {
                    0 => rng.vector(0.2) + target,
                    1 => behind + rng.vector(2e-3),
                    _ => behind,
                };
                if k == 400 && trial % 2 == 1 {
                    w.reset();
                    history.clear();
                    history.push(target);
                }
                let scan = w.distance_to_trail_scan(&measured, &target);
                let mut copy = w.clone();
                let incremental = copy.distance_to_trail(&measured, &target);
                assert_eq!(incremental.to_bits(), scan.to_bits(), "trial {trial}, tick {k}: {incremental} against {scan}");
                compared += 1;
                skipped_blocks += (0..BLOCKS).filter(|&b| copy.bounds[b].distance_squared(&measured) > (scan + ROUNDING).powi(2)).count();
                w.observe(k * 1_000_000, &target, &target, Some(&measured));
            }
        }
        assert_eq!(compared, 60 * 700);
        assert!(skipped_blocks > compared, "the boxes skip blocks ({skipped_blocks} in {compared} ticks)");
    }

    /// A non-finite point in the trail or in the question: the full scan's answer, whatever it is.
    #[test]
    fn a_non_finite_point_gets_the_full_scans_answer() {
        let mut w = FollowingWatch::new(1e-3, 0.0, 0.064);
        for k in 0..100u64 {
            let target = if k == 50 { Vector3::new(f64::NAN, 0.0, 0.0) } else { Vector3::new(k as f64 * 1e-4, 0.0, 0.0) };
            w.observe(k * 1_000_000, &target, &target, None);
        }
        let p = Vector3::new(5e-3, 1e-3, 0.0);
        let target = Vector3::new(0.01, 0.0, 0.0);
        assert_eq!(w.distance_to_trail(&p, &target).to_bits(), w.distance_to_trail_scan(&p, &target).to_bits());
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(w.distance_to_trail(&nan, &target).to_bits(), w.distance_to_trail_scan(&nan, &target).to_bits());
    }
}
