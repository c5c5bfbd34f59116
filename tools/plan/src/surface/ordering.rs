//! Ordering the samples into one extrusion path: greedy (Algorithm 3), weighted greedy (Algorithm 4) and a
//! greedy tour improved by 2-opt on the open path (Algorithm 5). Each path is timed and its Eq. 3 distance
//! evaluations counted, the machine-independent measure of work the report compares.

use std::cell::Cell;
use std::time::Instant;

use nalgebra::Vector3;
use serde::Serialize;

use super::{PointCloud, Sample};

/// A path algorithm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Algorithm {
    /// Algorithm 3: always the nearest unvisited sample (Eq. 3 distance).
    #[serde(rename = "greedy")]
    Greedy,
    /// Algorithm 4 with the weight on u: leaving the current u row costs extra, so the path runs along
    /// v to the end of the row before it changes row (side to side, 003's Figs. 6 and 7).
    #[serde(rename = "weighted-u")]
    WeightedU,
    /// Algorithm 4 with the weight on v: the path runs along u.
    #[serde(rename = "weighted-v")]
    WeightedV,
    /// Algorithm 5: greedy tour, then 2-opt local search.
    #[serde(rename = "tsp")]
    Tsp,
}

impl Algorithm {
    /// All four, in the order the report lists them.
    pub const ALL: [Algorithm; 4] = [Algorithm::Greedy, Algorithm::WeightedU, Algorithm::WeightedV, Algorithm::Tsp];

    /// The CLI name.
    pub fn name(self) -> &'static str {
        match self {
            Algorithm::Greedy => "greedy",
            Algorithm::WeightedU => "weighted-u",
            Algorithm::WeightedV => "weighted-v",
            Algorithm::Tsp => "tsp",
        }
    }
}

/// The parameter a weighted greedy path is kept on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// Weight on u: stay on the current u (run along v).
    U,
    /// Weight on v: stay on the current v (run along u).
    V,
}

/// Algorithm 4's weighting criterion and weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Weighting {
    /// The weighted parameter.
    pub axis: Axis,
    /// Added to the distance of a candidate whose weighted parameter differs from the current sample's (m).
    pub weight: f64,
    /// Parameter difference above which the criterion holds (the parameter's unit).
    pub tolerance: f64,
}

impl Weighting {
    /// The weighting for `axis` on `cloud`: a weight of the cloud's bounding-box diagonal (so any sample on
    /// the current row beats any sample off it) unless `weight` is given, and half the mean calibrated
    /// step as the tolerance.
    pub(crate) fn for_cloud(cloud: &PointCloud, axis: Axis, weight: Option<f64>) -> Weighting {
        let tolerance = 0.5 * if axis == Axis::U { cloud.step_u } else { cloud.step_v };
        Weighting { axis, weight: weight.unwrap_or_else(|| bounding_diagonal(cloud)), tolerance }
    }

    fn applies(&self, a: &Sample, b: &Sample) -> bool {
        match self.axis {
            Axis::U => (a.u - b.u).abs() > self.tolerance,
            Axis::V => (a.v - b.v).abs() > self.tolerance,
        }
    }
}

/// The diagonal of the cloud's bounding box (m).
pub fn bounding_diagonal(cloud: &PointCloud) -> f64 {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for s in &cloud.samples {
        lo = lo.inf(&s.point);
        hi = hi.sup(&s.point);
    }
    if cloud.samples.is_empty() { 0.0 } else { (hi - lo).norm() }
}

/// An ordered path through every sample of a cloud.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannedPath {
    /// The algorithm that made it.
    pub algorithm: Algorithm,
    /// Sample indices in print order; each sample exactly once.
    pub order: Vec<usize>,
    /// Polyline length through the samples (m).
    pub length: f64,
    /// Eq. 3 distance evaluations spent: the machine-independent measure of work.
    pub distance_evaluations: u64,
    /// Wall-clock time to make the path (s).
    pub compute_s: f64,
}

/// Eq. 3 distances between samples, counted.
struct Metric<'a> {
    points: Vec<[f64; 3]>,
    samples: &'a [Sample],
    count: Cell<u64>,
}

impl<'a> Metric<'a> {
    fn new(samples: &'a [Sample]) -> Metric<'a> {
        Metric { points: samples.iter().map(|s| [s.point.x, s.point.y, s.point.z]).collect(), samples, count: Cell::new(0) }
    }

    #[inline]
    fn d(&self, i: usize, j: usize) -> f64 {
        self.count.set(self.count.get() + 1);
        let (a, b) = (&self.points[i], &self.points[j]);
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    }
}

/// The polyline length of `order` through `cloud` (m).
pub fn path_length(cloud: &PointCloud, order: &[usize]) -> f64 {
    order.windows(2).map(|w| (cloud.samples[w[1]].point - cloud.samples[w[0]].point).norm()).sum()
}

/// Algorithms 3 and 4: from `start`, repeatedly the unvisited sample with the smallest (weighted) Eq. 3
/// distance; ties go to the lower index. O(n²) distance evaluations, as in the paper.
fn greedy_order(m: &Metric, start: usize, weighting: Option<&Weighting>) -> Vec<usize> {
    let n = m.points.len();
    if n == 0 {
        return Vec::new();
    }
    let mut unvisited: Vec<usize> = (0..n).filter(|&i| i != start).collect();
    let mut order = Vec::with_capacity(n);
    order.push(start);
    let mut current = start;
    while !unvisited.is_empty() {
        // Calculate distance to the other samples; weight where the criterion holds; greedy choice.
        let mut best = (f64::INFINITY, usize::MAX, 0usize);
        for (k, &j) in unvisited.iter().enumerate() {
            let mut dist = m.d(current, j);
            if let Some(w) = weighting
                && w.applies(&m.samples[current], &m.samples[j])
            {
                dist += w.weight;
            }
            if dist < best.0 || (dist == best.0 && j < best.1) {
                best = (dist, j, k);
            }
        }
        current = best.1;
        unvisited.swap_remove(best.2);
        order.push(current);
    }
    order
}

/// Algorithm 3, greedy choice, from sample `start`.
pub fn greedy(cloud: &PointCloud, start: usize) -> PlannedPath {
    timed(cloud, Algorithm::Greedy, |m| greedy_order(m, start, None))
}

/// Algorithm 4, weighted greedy choice, from sample `start`.
pub fn weighted_greedy(cloud: &PointCloud, start: usize, weighting: &Weighting) -> PlannedPath {
    let algorithm = if weighting.axis == Axis::U { Algorithm::WeightedU } else { Algorithm::WeightedV };
    timed(cloud, algorithm, |m| greedy_order(m, start, Some(weighting)))
}

/// Algorithm 5: a greedy tour from `start` (Algorithm 3), then 2-opt local search on the open path with
/// `neighbours`-nearest candidate lists (Pedroso and Kubo's `improve`, sweep after sweep until a sweep
/// finds nothing), then exhaustive 2-opt sweeps until none improves (a true 2-opt local optimum, which on a
/// plane has no crossing edges). Endpoints are free: reversing a prefix or a suffix is a move too.
pub fn tsp(cloud: &PointCloud, start: usize, neighbours: usize) -> PlannedPath {
    timed(cloud, Algorithm::Tsp, |m| {
        let mut tour = greedy_order(m, start, None);
        let scale = bounding_diagonal(cloud).max(f64::MIN_POSITIVE);
        let lists = nearest_lists(m, neighbours);
        let mut opt = TwoOpt::new(m, &mut tour, 1e-12 * scale);
        while opt.neighbour_sweep(&lists) {}
        while opt.exhaustive_sweep() {}
        tour
    })
}

fn timed(cloud: &PointCloud, algorithm: Algorithm, f: impl FnOnce(&Metric) -> Vec<usize>) -> PlannedPath {
    let t0 = Instant::now();
    let m = Metric::new(&cloud.samples);
    let order = f(&m);
    let compute_s = t0.elapsed().as_secs_f64();
    PlannedPath { algorithm, length: path_length(cloud, &order), order, distance_evaluations: m.count.get(), compute_s }
}

/// Each sample's `k` nearest others, nearest first, with their distances (brute force, O(n²)).
fn nearest_lists(m: &Metric, k: usize) -> Vec<Vec<(f64, usize)>> {
    let n = m.points.len();
    let k = k.min(n.saturating_sub(1));
    let mut all = Vec::with_capacity(n);
    let mut lists = Vec::with_capacity(n);
    for i in 0..n {
        all.clear();
        all.extend((0..n).filter(|&j| j != i).map(|j| (m.d(i, j), j)));
        let by = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        if k < all.len() && k > 0 {
            all.select_nth_unstable_by(k - 1, by);
        }
        let mut list: Vec<(f64, usize)> = all.iter().take(k).copied().collect();
        list.sort_by(by);
        lists.push(list);
    }
    lists
}

/// 2-opt on an open path: `tour[i]` the sample at position i, `pos` its inverse.
struct TwoOpt<'m, 'a, 't> {
    m: &'m Metric<'a>,
    tour: &'t mut Vec<usize>,
    pos: Vec<usize>,
    /// An exchange must shorten the path by more than this (m): no cycling on rounding.
    eps: f64,
}

impl<'m, 'a, 't> TwoOpt<'m, 'a, 't> {
    fn new(m: &'m Metric<'a>, tour: &'t mut Vec<usize>, eps: f64) -> Self {
        let mut pos = vec![0; tour.len()];
        for (k, &c) in tour.iter().enumerate() {
            pos[c] = k;
        }
        TwoOpt { m, tour, pos, eps }
    }

    /// Reverses tour[a..=b] and updates the positions.
    fn reverse(&mut self, a: usize, b: usize) {
        self.tour[a..=b].reverse();
        for k in a..=b {
            self.pos[self.tour[k]] = k;
        }
    }

    /// Replaces edges (i, i+1) and (j, j+1) by (i, j) and (i+1, j+1) (`exchange` in tsp.py).
    fn exchange(&mut self, i: usize, j: usize) {
        let (i, j) = if i < j { (i, j) } else { (j, i) };
        self.reverse(i + 1, j);
    }

    /// One sweep of tsp.py's `improve` over the edges (a, b) = (tour[i], tour[i+1]): try the neighbours
    /// c of a closer than b (new edges (a, c), (b, succ c)), then the neighbours d of b closer than a (new
    /// edges (a, pred d), (b, d)); the first improving exchange is made. With c the last sample or d the
    /// first, the move reverses the suffix or the prefix (one edge changes). True if anything improved.
    fn neighbour_sweep(&mut self, lists: &[Vec<(f64, usize)>]) -> bool {
        let n = self.tour.len();
        let mut improved = false;
        for i in 0..n.saturating_sub(1) {
            let (a, b) = (self.tour[i], self.tour[i + 1]);
            let dab = self.m.d(a, b);
            let mut moved = false;
            for &(dac, c) in &lists[a] {
                if dac >= dab {
                    break;
                }
                let j = self.pos[c];
                if j == n - 1 {
                    if j > i + 1 && dac - dab < -self.eps {
                        self.reverse(i + 1, n - 1);
                        moved = true;
                        break;
                    }
                    continue;
                }
                let d = self.tour[j + 1];
                let delta = dac + self.m.d(b, d) - dab - self.m.d(c, d);
                if delta < -self.eps {
                    self.exchange(i, j);
                    moved = true;
                    break;
                }
            }
            if !moved {
                for &(dbd, d) in &lists[b] {
                    if dbd >= dab {
                        break;
                    }
                    let k = self.pos[d];
                    if k == 0 {
                        if i > 0 && dbd - dab < -self.eps {
                            self.reverse(0, i);
                            moved = true;
                            break;
                        }
                        continue;
                    }
                    let j = k - 1;
                    let c = self.tour[j];
                    let delta = self.m.d(a, c) + dbd - dab - self.m.d(c, d);
                    if delta < -self.eps {
                        self.exchange(i, j);
                        moved = true;
                        break;
                    }
                }
            }
            improved |= moved;
        }
        improved
    }

    /// Every pair of edges and every prefix/suffix reversal, first improvement. True if anything improved.
    fn exhaustive_sweep(&mut self) -> bool {
        let n = self.tour.len();
        let mut improved = false;
        for i in 0..n.saturating_sub(1) {
            let (a, b) = (self.tour[i], self.tour[i + 1]);
            let dab = self.m.d(a, b);
            // Suffix reversal: (a, b) → (a, last).
            if i + 2 < n && self.m.d(a, self.tour[n - 1]) - dab < -self.eps {
                self.reverse(i + 1, n - 1);
                improved = true;
                continue;
            }
            // Prefix reversal: (a, b) → (first, b).
            if i > 0 && self.m.d(self.tour[0], b) - dab < -self.eps {
                self.reverse(0, i);
                improved = true;
                continue;
            }
            for j in i + 2..n - 1 {
                let (a, b) = (self.tour[i], self.tour[i + 1]);
                let (c, d) = (self.tour[j], self.tour[j + 1]);
                let delta = self.m.d(a, c) + self.m.d(b, d) - self.m.d(a, b) - self.m.d(c, d);
                if delta < -self.eps {
                    self.exchange(i, j);
                    improved = true;
                }
            }
        }
        improved
    }
}

/// Runs `algorithm` on `cloud` from sample 0 (the first sample: the corner (u_min, v_min) in robust mode).
pub fn plan(cloud: &PointCloud, algorithm: Algorithm, weight: Option<f64>, neighbours: usize) -> PlannedPath {
    match algorithm {
        Algorithm::Greedy => greedy(cloud, 0),
        Algorithm::WeightedU => weighted_greedy(cloud, 0, &Weighting::for_cloud(cloud, Axis::U, weight)),
        Algorithm::WeightedV => weighted_greedy(cloud, 0, &Weighting::for_cloud(cloud, Axis::V, weight)),
        Algorithm::Tsp => tsp(cloud, 0, neighbours),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::fixtures::{D, cloud_of, curved, identity, paper, robust};
    use crate::surface::{Plane, sample, self_intersections};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    fn random_plane_cloud(n: usize, seed: u64) -> PointCloud {
        let mut rng = StdRng::seed_from_u64(seed);
        cloud_of(&(0..n).map(|_| (rng.random::<f64>() * 0.1, rng.random::<f64>() * 0.1)).collect::<Vec<_>>())
    }

    #[test]
    fn two_opt_never_lengthens_and_uncrosses_a_plane() {
        for seed in 0..4 {
            let cloud = random_plane_cloud(250, seed);
            let g = greedy(&cloud, 0);
            let t = tsp(&cloud, 0, 8);
            assert!(!self_intersections(&cloud, &g.order).is_empty(), "greedy on random points crosses itself");
            assert!(t.length <= g.length + 1e-12, "seed {seed}: tsp {} > greedy {}", t.length, g.length);
            assert!(t.length < 0.95 * g.length, "seed {seed}: tsp {} vs greedy {}", t.length, g.length);
            assert_eq!(self_intersections(&cloud, &t.order), vec![], "seed {seed}");
            let mut seen = t.order.clone();
            seen.sort_unstable();
            assert_eq!(seen, identity(250), "every sample once");
            // From a random order, each sweep shortens the path or leaves it as it was.
            let m = Metric::new(&cloud.samples);
            let mut rng = StdRng::seed_from_u64(seed + 100);
            let mut tour = identity(250);
            for k in (1..tour.len()).rev() {
                tour.swap(k, rng.random_range(0..=k));
            }
            let lists = nearest_lists(&m, 8);
            let mut last = path_length(&cloud, &tour);
            let mut opt = TwoOpt::new(&m, &mut tour, 1e-14);
            loop {
                let more = opt.neighbour_sweep(&lists) | opt.exhaustive_sweep();
                let now = path_length(&cloud, opt.tour);
                assert!(now <= last + 1e-12, "{now} > {last}");
                last = now;
                if !more {
                    break;
                }
            }
            assert!(self_intersections(&cloud, &tour).is_empty());
        }
    }

    #[test]
    fn weighted_greedy_is_a_boustrophedon_on_a_grid() {
        let plane = Plane { length: 0.1, width: 0.05, z: 0.0 };
        let cloud = sample(&plane, &robust(0.01)).unwrap();
        assert_eq!(cloud.samples.len(), 66);
        for axis in [Axis::U, Axis::V] {
            let p = weighted_greedy(&cloud, 0, &Weighting::for_cloud(&cloud, axis, None));
            assert!((p.length - 65.0 * D).abs() < 1e-9, "{axis:?}: {}", p.length);
            assert!(self_intersections(&cloud, &p.order).is_empty());
            // Runs along the other parameter: the weighted one changes only at the ends of a run.
            let changes = p
                .order
                .windows(2)
                .filter(|w| {
                    let (a, b) = (&cloud.samples[w[0]], &cloud.samples[w[1]]);
                    if axis == Axis::U { a.u != b.u } else { (a.v - b.v).abs() > 1e-9 }
                })
                .count();
            assert_eq!(changes, if axis == Axis::U { 10 } else { 5 }, "{axis:?}");
        }
    }

    /// 003 Section 3.2 on the curved rectangle, sampled as 003 samples (Algorithm 1 as printed, d* =
    /// 10 mm): greedy self-intersects, the u-weighted greedy does not, TSP is the slowest and not longer.
    #[test]
    fn findings_of_003_on_the_curved_rectangle() {
        let cloud = sample(&curved(), &paper()).unwrap();
        assert_eq!(cloud.samples.len(), 120);
        let run = |a| {
            let p = plan(&cloud, a, None, 10);
            let n = self_intersections(&cloud, &p.order).len();
            (p, n)
        };
        let (g, gi) = run(Algorithm::Greedy);
        let (w, wi) = run(Algorithm::WeightedU);
        let (t, ti) = run(Algorithm::Tsp);
        assert!(gi > 0, "greedy: {gi} self-intersections");
        assert_eq!(wi, 0, "weighted greedy (u)");
        assert!(t.length <= g.length, "tsp {} vs greedy {}", t.length, g.length);
        assert_eq!(ti, 0, "tsp");
        // Slowest, in work rather than noisy time: more than three times the Eq. 3 evaluations of either greedy.
        assert!(
            t.distance_evaluations > 3 * g.distance_evaluations.max(w.distance_evaluations),
            "{} vs {}",
            t.distance_evaluations,
            g.distance_evaluations
        );
        assert_eq!(g.distance_evaluations, 120 * 119 / 2);
        // With robust sampling the grid is whole and regular from its corner, and greedy runs it as a
        // boustrophedon along the bend (its chords are 0.17 % shorter than the straight steps across):
        // the crossings above come from the sample Algorithm 1 leaves out.
        let whole = sample(&curved(), &robust(0.01)).unwrap();
        for a in Algorithm::ALL {
            let p = plan(&whole, a, None, 10);
            assert!(self_intersections(&whole, &p.order).is_empty(), "{a:?}");
        }
    }
}
