//! Sampling a face into a point cloud: 003's Algorithm 1 (rows of samples at a desired spacing) with
//! Algorithm 2's step calibration, both as printed ([`SamplingMode::Paper`]) and made robust
//! ([`SamplingMode::Robust`]); the module doc of `surface` says where and why they differ.

use nalgebra::Vector3;

use super::{Domain, Surface};
use strand_cli::error::{Result, ToolError};

/// One sample of the point cloud (003's `Sample` object, less the FreeCAD sub-object reference).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Parameter u (the surface's u unit).
    pub u: f64,
    /// Parameter v (the surface's v unit).
    pub v: f64,
    /// The point r(u, v) (m, bed frame).
    pub point: Vector3<f64>,
    /// Unit normal on the nozzle's side (1).
    pub normal: Vector3<f64>,
}

/// The samples of a face, in sampling order (row by row: u outer, v inner).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// The samples.
    pub samples: Vec<Sample>,
    /// Mean calibrated step between rows, α_u (u unit).
    pub step_u: f64,
    /// Mean calibrated step along a row, α_v (v unit).
    pub step_v: f64,
    /// Surface evaluations spent (`valueAt` calls, including the calibration's).
    pub evaluations: u64,
    /// The parameters' periods where the surface closes on itself (a full cylinder's u: 2π): a step
    /// between samples goes the short way round, across the seam.
    pub periods: [Option<f64>; 2],
}

impl PointCloud {
    /// The (u, v) step from sample `a` to sample `b`, the short way round a periodic parameter.
    pub fn step(&self, a: usize, b: usize) -> (f64, f64) {
        let (sa, sb) = (&self.samples[a], &self.samples[b]);
        let wrap = |d: f64, period: Option<f64>| match period {
            Some(p) if p > 0.0 => d - (d / p).round() * p,
            _ => d,
        };
        (wrap(sb.u - sa.u, self.periods[0]), wrap(sb.v - sa.v, self.periods[1]))
    }

    /// True if the step from `a` to `b` crosses a periodic seam (its (u, v) chord is not the short way).
    pub(crate) fn crosses_seam(&self, a: usize, b: usize) -> bool {
        let (du, dv) = self.step(a, b);
        let (sa, sb) = (&self.samples[a], &self.samples[b]);
        du != sb.u - sa.u || dv != sb.v - sa.v
    }
}

/// Which version of Algorithm 1 to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SamplingMode {
    /// Algorithm 1 as printed (first sample missing, a lone sample after the last row), with Algorithm 2 as
    /// printed (restarting from α = d*, the ratio update α ← α·d*/d_k); iterations are capped only so
    /// that it terminates.
    Paper,
    /// Whole rows from edge to edge of the domain, the row step calibrated at three points across the row
    /// (the smallest wins, so no two rows are farther apart than d*), warm-started and bracketed
    /// calibration, degenerate (collapsed) edges stepped over. The default.
    Robust,
}

/// What Algorithms 1 and 2 are asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sampling {
    /// Desired distance between samples along u, d*_u (m, measured on the surface as a chord).
    pub spacing_u: f64,
    /// Desired distance between samples along v, d*_v (m, measured on the surface as a chord).
    pub spacing_v: f64,
    /// Relative calibration tolerance: a step is accepted when |d* − d_k| ≤ tolerance·d_k (1; 003's 1/t).
    pub tolerance: f64,
    /// Algorithm 1 as printed or made robust.
    pub mode: SamplingMode,
}

/// Sampling stops with an error past this many samples (the spacing is far too small for the face).
pub const MAX_SAMPLES: usize = 2_000_000;
/// Algorithm 2's iterations in paper mode (the paper has no cap).
const PAPER_MAX_ITERATIONS: usize = 100;
/// Algorithm 2's iterations in robust mode (bracketed: converges in a handful on smooth faces).
const ROBUST_MAX_ITERATIONS: usize = 60;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Dir {
    U,
    V,
}

/// Surface evaluations, counted.
struct Evaluator<'a, S: Surface + ?Sized> {
    surface: &'a S,
    evaluations: u64,
}

impl<S: Surface + ?Sized> Evaluator<'_, S> {
    fn point(&mut self, u: f64, v: f64) -> Vector3<f64> {
        self.evaluations += 1;
        self.surface.point(u, v)
    }

    /// d_k of Eq. 3: the chord from (u, v) one step α along `dir` (m).
    fn chord(&mut self, u: f64, v: f64, dir: Dir, alpha: f64) -> f64 {
        let p1 = self.point(u, v);
        let p2 = match dir {
            Dir::U => self.point(u + alpha, v),
            Dir::V => self.point(u, v + alpha),
        };
        (p2 - p1).norm()
    }

    /// Algorithm 2 as printed: α = d*, then α ← α·d*/d_k until |d* − d_k| ≤ d_k·tolerance (our reading of
    /// the printed test). Gives up with the current α on a zero chord (the paper would divide by zero) or
    /// after [`PAPER_MAX_ITERATIONS`].
    fn calibrate_paper(&mut self, u: f64, v: f64, dir: Dir, target: f64, tolerance: f64) -> f64 {
        let mut alpha = target;
        for _ in 0..PAPER_MAX_ITERATIONS {
            let dk = self.chord(u, v, dir, alpha);
            if !(dk.is_finite() && dk > 0.0) {
                return alpha;
            }
            if (target - dk).abs() > dk * tolerance {
                alpha *= target / dk;
            } else {
                return alpha;
            }
        }
        alpha
    }

    /// Algorithm 2 made robust: the same ratio update, from a warm start, kept inside a bracket
    /// [lo, hi] (chord(lo) < d* < chord(hi)) and bisecting when it would leave it, α within
    /// [1e-12·max, max] where max is what is left of the domain in that direction, so the calibration
    /// never probes past the face's edge. None when even α = max falls short of d* by more than the
    /// tolerance: no full step fits (the end of a row, or a face collapsed to a point there). Never more
    /// than [`ROBUST_MAX_ITERATIONS`] iterations; without convergence it returns the best α seen.
    #[allow(clippy::too_many_arguments)]
    fn calibrate_robust(&mut self, u: f64, v: f64, dir: Dir, target: f64, tolerance: f64, start: f64, max: f64) -> Option<f64> {
        if max.is_nan() || max <= 0.0 {
            return None;
        }
        let min = 1e-12 * max;
        let mut alpha = if start.is_finite() && start > 0.0 { start.clamp(min, max) } else { target.clamp(min, max) };
        let (mut lo, mut hi) = (0.0, f64::INFINITY);
        let mut best = (f64::INFINITY, alpha);
        for _ in 0..ROBUST_MAX_ITERATIONS {
            let dk = self.chord(u, v, dir, alpha);
            if !dk.is_finite() {
                hi = alpha;
                alpha = 0.5 * (lo + alpha);
                continue;
            }
            let err = (dk - target).abs();
            if err < best.0 {
                best = (err, alpha);
            }
            if err <= dk * tolerance {
                return Some(alpha);
            }
            if dk < target {
                lo = alpha;
                if alpha >= max {
                    return None;
                }
            } else {
                hi = alpha;
            }
            let mut next = if dk > 0.0 { alpha * target / dk } else { 2.0 * alpha };
            if !(next > lo && next < hi) {
                next = if hi.is_finite() { 0.5 * (lo + hi) } else { 2.0 * alpha };
            }
            alpha = next.clamp(min, max);
        }
        Some(best.1)
    }
}

/// Samples `surface` by Algorithm 1 (with Algorithm 2's calibration) at the spacing and in the mode given.
/// Errors when the request is invalid or the face would need more than [`MAX_SAMPLES`] samples.
pub fn sample<S: Surface + ?Sized>(surface: &S, sampling: &Sampling) -> Result<PointCloud> {
    let d = surface.domain();
    if !(d.span_u() > 0.0 && d.span_v() > 0.0 && d.span_u().is_finite() && d.span_v().is_finite()) {
        return Err(ToolError::Plan(format!("the surface's parameter domain u {:?}, v {:?} is empty", d.u, d.v)));
    }
    for (name, x) in [("spacing u", sampling.spacing_u), ("spacing v", sampling.spacing_v)] {
        if !(x.is_finite() && x > 0.0) {
            return Err(ToolError::Plan(format!("{name} = {x} m: must be positive")));
        }
    }
    if !(sampling.tolerance.is_finite() && sampling.tolerance > 0.0 && sampling.tolerance < 1.0) {
        return Err(ToolError::Plan(format!("tolerance = {}: must lie in (0, 1)", sampling.tolerance)));
    }
    let estimate = estimated_samples(surface, &d, sampling);
    if estimate > MAX_SAMPLES as f64 {
        return Err(ToolError::Plan(format!(
            "about {estimate:.1e} samples, more than {MAX_SAMPLES}: the spacing ({} m, {} m) is too small for this surface",
            sampling.spacing_u, sampling.spacing_v
        )));
    }
    let mut eval = Evaluator { surface, evaluations: 0 };
    let mut cloud = PointCloud::default();
    let (mut sum_u, mut n_u, mut sum_v, mut n_v) = (0.0, 0usize, 0.0, 0usize);
    // A face that closes on itself (a whole cylinder): its far edge is its near edge again, so the
    // samples there would lay the same bead twice.
    let periods = surface.periods();
    let closes = |span: f64, period: Option<f64>| period.filter(|p| span >= p * (1.0 - 1e-9));
    let (close_u, close_v) = (closes(d.span_u(), periods[0]), closes(d.span_v(), periods[1]));
    let add = |cloud: &mut PointCloud, eval: &mut Evaluator<S>, u: f64, v: f64| -> Result<()> {
        let seam = |x: f64, start: f64, period: Option<f64>| period.is_some_and(|p| x - start >= p * (1.0 - 1e-9));
        if !surface.contains(u, v) || seam(u, d.u.0, close_u) || seam(v, d.v.0, close_v) {
            return Ok(());
        }
        if cloud.samples.len() >= MAX_SAMPLES {
            return Err(ToolError::Plan(format!(
                "more than {MAX_SAMPLES} samples: the spacing ({} m, {} m) is too small for this surface",
                sampling.spacing_u, sampling.spacing_v
            )));
        }
        let point = eval.point(u, v);
        if let Some(normal) = sample_normal(surface, &d, u, v)
            && point.iter().all(|x| x.is_finite())
        {
            cloud.samples.push(Sample { u, v, point, normal });
        }
        Ok(())
    };
    let (eu, ev) = (1e-9 * d.span_u(), 1e-9 * d.span_v());
    let tol = sampling.tolerance;
    // Guards the paper mode's loops: a step that has shrunk to nothing would never leave the domain.
    let max_steps = 4 * MAX_SAMPLES;
    let mut steps = 0usize;
    let step = |steps: &mut usize| -> Result<()> {
        *steps += 1;
        if *steps > max_steps {
            Err(ToolError::Plan(format!("sampling did not terminate within {max_steps} steps (the calibrated step collapsed)")))
        } else {
            Ok(())
        }
    };
    match sampling.mode {
        SamplingMode::Paper => {
            let (mut uc, mut vc) = (d.u.0, d.v.0);
            while uc < d.u.1 {
                while vc < d.v.1 {
                    step(&mut steps)?;
                    let av = eval.calibrate_paper(uc, vc, Dir::V, sampling.spacing_v, tol);
                    if av.is_nan() || av <= 0.0 {
                        return Err(ToolError::Plan(format!("Algorithm 2 found no positive v step at (u, v) = ({uc}, {vc})")));
                    }
                    vc += av;
                    (sum_v, n_v) = (sum_v + av, n_v + 1);
                    add(&mut cloud, &mut eval, uc, vc)?;
                }
                vc = d.v.0;
                step(&mut steps)?;
                let au = eval.calibrate_paper(uc, vc, Dir::U, sampling.spacing_u, tol);
                if au.is_nan() || au <= 0.0 {
                    return Err(ToolError::Plan(format!("Algorithm 2 found no positive u step at (u, v) = ({uc}, {vc})")));
                }
                uc += au;
                (sum_u, n_u) = (sum_u + au, n_u + 1);
                add(&mut cloud, &mut eval, uc, vc)?;
            }
        }
        SamplingMode::Robust => {
            let probes = [d.v.0, 0.5 * (d.v.0 + d.v.1), d.v.1];
            let (mut au, mut av) = (f64::NAN, f64::NAN);
            let mut uc = d.u.0;
            loop {
                let mut vc = d.v.0;
                add(&mut cloud, &mut eval, uc, vc)?;
                loop {
                    step(&mut steps)?;
                    match eval.calibrate_robust(uc, vc, Dir::V, sampling.spacing_v, tol, av, d.v.1 - vc) {
                        Some(a) if vc + a <= d.v.1 + ev => av = a,
                        // A step that overshoots the edge by no more than the calibration's own tolerance
                        // ends on the edge: whether the last sample exists must not hang on the rounding
                        // of d* (a face whose side is a whole number of spacings long).
                        _ if vc + ev < d.v.1 && eval.chord(uc, vc, Dir::V, d.v.1 - vc) >= sampling.spacing_v * (1.0 - tol) => {
                            av = d.v.1 - vc
                        }
                        _ => break,
                    }
                    vc += av;
                    (sum_v, n_v) = (sum_v + av, n_v + 1);
                    add(&mut cloud, &mut eval, uc, vc)?;
                }
                step(&mut steps)?;
                // The row step where the rows are closest together: calibrated at both ends and the middle.
                let mut row = f64::INFINITY;
                for pv in probes {
                    if let Some(a) = eval.calibrate_robust(uc, pv, Dir::U, sampling.spacing_u, tol, au, d.u.1 - uc) {
                        row = row.min(a);
                    }
                }
                if !(row.is_finite() && uc + row <= d.u.1 + eu) {
                    // As in v: the last row on the edge if the rows would be within tolerance there.
                    let to_edge = d.u.1 - uc;
                    let closest = probes.iter().map(|&pv| eval.chord(uc, pv, Dir::U, to_edge)).fold(f64::INFINITY, f64::min);
                    if !(to_edge > eu && closest >= sampling.spacing_u * (1.0 - tol)) {
                        break;
                    }
                    row = to_edge;
                }
                au = row;
                uc += au;
                (sum_u, n_u) = (sum_u + au, n_u + 1);
            }
        }
    }
    // Across the seam of a closed face the last row (or sample of a row) comes round to the first: one
    // that lands within half a spacing of it would lay its bead almost on the first's, so it goes (the
    // gap there is then at most 1.5 spacings instead of as little as nothing).
    if close_u.is_some() || close_v.is_some() {
        let near_seam = |s: &Sample| {
            let past_u =
                close_u.is_some_and(|p| s.u - d.u.0 > 0.5 * p) && (surface.point(d.u.0, s.v) - s.point).norm() < 0.5 * sampling.spacing_u;
            let past_v =
                close_v.is_some_and(|p| s.v - d.v.0 > 0.5 * p) && (surface.point(s.u, d.v.0) - s.point).norm() < 0.5 * sampling.spacing_v;
            past_u || past_v
        };
        cloud.samples.retain(|s| !near_seam(s));
    }
    cloud.step_u = if n_u > 0 { sum_u / n_u as f64 } else { d.span_u() };
    cloud.step_v = if n_v > 0 { sum_v / n_v as f64 } else { d.span_v() };
    cloud.evaluations = eval.evaluations;
    cloud.periods = surface.periods();
    Ok(cloud)
}

/// A cheap estimate of the sample count, to refuse hopeless requests before sampling: the longest of
/// three iso-curves in each direction (32-chord polylines) over the spacing, multiplied.
fn estimated_samples<S: Surface + ?Sized>(s: &S, d: &Domain, sampling: &Sampling) -> f64 {
    let along = |f: &dyn Fn(f64) -> Vector3<f64>| (0..32).map(|k| (f((k + 1) as f64 / 32.0) - f(k as f64 / 32.0)).norm()).sum::<f64>();
    let (mut lu, mut lv) = (0.0f64, 0.0f64);
    for t in [0.0, 0.5, 1.0] {
        let (u, v) = (d.u.0 + t * d.span_u(), d.v.0 + t * d.span_v());
        lu = lu.max(along(&|x| s.point(d.u.0 + x * d.span_u(), v)));
        lv = lv.max(along(&|x| s.point(u, d.v.0 + x * d.span_v())));
    }
    (lu / sampling.spacing_u + 1.0) * (lv / sampling.spacing_v + 1.0)
}

/// The normal for a sample; where the parametrisation degenerates (a collapsed edge, where Eq. 2 gives
/// zero), the normal a hair towards the middle of the domain. None if that fails too.
fn sample_normal<S: Surface + ?Sized>(s: &S, d: &Domain, u: f64, v: f64) -> Option<Vector3<f64>> {
    let ok = |n: Vector3<f64>| n.iter().all(|x| x.is_finite()) && (n.norm() - 1.0).abs() < 1e-6;
    let n = s.normal(u, v);
    if ok(n) {
        return Some(n);
    }
    let (cu, cv) = (0.5 * (d.u.0 + d.u.1), 0.5 * (d.v.0 + d.v.1));
    let n = s.normal(u + 1e-4 * (cu - u), v + 1e-4 * (cv - v));
    ok(n).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::fixtures::{D, blade, bump, curved, cylinder, paper, robust};
    use crate::surface::{Cylinder, Plane};
    use std::f64::consts::PI;

    /// Each sample's nearest other sample (m, 3D).
    fn nearest(cloud: &PointCloud) -> Vec<f64> {
        let s = &cloud.samples;
        (0..s.len())
            .map(|i| (0..s.len()).filter(|&j| j != i).map(|j| (s[i].point - s[j].point).norm()).fold(f64::INFINITY, f64::min))
            .collect()
    }

    #[test]
    fn robust_sampling_keeps_the_spacing_on_the_surface() {
        let surfaces: [(&str, &dyn Surface, usize); 4] = [
            ("plane", &Plane { length: 0.1, width: 0.1, z: 0.0 }, 121),
            ("cylinder", &cylinder(), 11 * 11),
            ("bump", &bump(), 121),
            ("curved-rect", &curved(), 121),
        ];
        for tol in [0.01, 1e-4] {
            for (name, s, count) in surfaces {
                let cloud = sample(s, &robust(tol)).unwrap();
                assert_eq!(cloud.samples.len(), count, "{name}");
                assert_eq!((cloud.samples[0].u, cloud.samples[0].v), (s.domain().u.0, s.domain().v.0), "{name} starts at the corner");
                // Steps along a row (same u): chords within the tolerance of d*.
                for w in cloud.samples.windows(2).filter(|w| w[0].u == w[1].u) {
                    let dk = (w[1].point - w[0].point).norm();
                    assert!((dk - D).abs() <= tol * dk * (1.0 + 1e-9), "{name}: step {dk} at u = {}", w[0].u);
                }
                // Every sample's nearest neighbour is d* away within the tolerance: no gaps, no clumps.
                for (k, nn) in nearest(&cloud).into_iter().enumerate() {
                    assert!((nn - D).abs() <= tol * D * 1.02, "{name} (tol {tol}): sample {k} nearest {nn}");
                }
                for s2 in &cloud.samples {
                    assert!((s2.normal.norm() - 1.0).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn robust_rows_are_at_most_d_apart_where_the_face_widens() {
        // The blade is twisted: rows are closest at one chordwise end; the row step is calibrated at both
        // ends and the middle, so no two rows are farther apart than d* anywhere along them (the paper
        // calibrates at v_min only).
        let b = blade();
        let cloud = sample(&b, &robust(0.01)).unwrap();
        let mut rows: Vec<f64> = cloud.samples.iter().map(|s| s.u).collect();
        rows.dedup();
        for w in rows.windows(2) {
            for v in [b.domain().v.0, 0.0, b.domain().v.1] {
                let gap = (b.point(w[1], v) - b.point(w[0], v)).norm();
                assert!(gap <= D * 1.01, "rows {} and {}: {gap} m apart at v = {v}", w[0], w[1]);
            }
        }
        assert!(cloud.samples.iter().all(|s| b.contains(s.u, s.v)));
        assert!(cloud.samples.len() > 40, "{}", cloud.samples.len());
    }

    #[test]
    fn paper_sampling_keeps_its_quirks() {
        let plane = Plane { length: 0.1, width: 0.1, z: 0.0 };
        let cloud = sample(&plane, &paper()).unwrap();
        // Algorithm 1 as printed never stores the start (u_min, v_min): 11 × 11 − 1.
        assert_eq!(cloud.samples.len(), 120);
        assert!(cloud.samples.iter().all(|s| (s.u, s.v) != (0.0, 0.0)));
        assert!((cloud.samples[0].v - D).abs() < 1e-15 && cloud.samples[0].u == 0.0);
        // Algorithm 2 as read: on the curved rectangle the first guess α = d* (arc length) gives a chord
        // 0.17 % short, inside 1 %, so it is kept.
        let c = sample(&curved(), &paper()).unwrap();
        assert!((c.step_u - D).abs() < 1e-12, "{}", c.step_u);
    }

    #[test]
    fn calibration_converges_where_the_first_guess_is_far_off() {
        // A cylinder in angle parameters: α = d* (0.01 rad) gives a 0.1 mm chord at R = 10 mm, 100× short
        // of 10 mm; at d* = 25 mm the ratio update would overshoot past half a turn (the chord is not
        // monotone in α); the bracket keeps it on the first branch.
        let c = Cylinder { radius: 0.01, length: 0.05, sweep: 1.5 * PI };
        for d in [0.005, 0.015] {
            let cloud = sample(&c, &Sampling { spacing_u: d, spacing_v: d, tolerance: 1e-3, mode: SamplingMode::Robust }).unwrap();
            for w in cloud.samples.windows(2).filter(|w| w[0].u == w[1].u) {
                let dk = (w[1].point - w[0].point).norm();
                assert!((dk - d).abs() <= 1e-3 * dk * 1.001, "d* {d}: chord {dk}");
                assert!(w[1].v - w[0].v < PI, "one step per chord, not round the back");
            }
        }
    }

    /// A triangle collapsing to a point at u = 0: r = (u, u·v, 0).
    struct Fan;
    impl Surface for Fan {
        fn domain(&self) -> Domain {
            Domain { u: (0.0, 0.1), v: (0.0, 1.0) }
        }
        fn point(&self, u: f64, v: f64) -> Vector3<f64> {
            Vector3::new(u, u * v, 0.0)
        }
        fn parameter_labels(&self) -> (&'static str, &'static str) {
            ("u", "v")
        }
    }

    /// Collapsed everywhere: one point.
    struct Dot;
    impl Surface for Dot {
        fn domain(&self) -> Domain {
            Domain { u: (0.0, 1.0), v: (0.0, 1.0) }
        }
        fn point(&self, _u: f64, _v: f64) -> Vector3<f64> {
            Vector3::new(0.1, 0.2, 0.3)
        }
        fn parameter_labels(&self) -> (&'static str, &'static str) {
            ("u", "v")
        }
    }

    #[test]
    fn degenerate_patches_terminate() {
        let fan = sample(&Fan, &robust(0.01)).unwrap();
        // The apex row is one sample (its normal taken a hair inside); the other rows fan out at d*. Rows
        // are d* apart where the fan is widest (v = 1), closer elsewhere.
        assert_eq!(fan.samples.iter().filter(|s| s.u == 0.0).count(), 1);
        for w in fan.samples.windows(2).filter(|w| w[0].u == w[1].u) {
            let dk = (w[1].point - w[0].point).norm();
            assert!((dk - D).abs() <= 0.0101 * dk, "{dk}");
        }
        assert!(fan.samples.iter().all(|s| (s.normal - Vector3::z()).norm() < 1e-9), "normal at the apex taken beside it");
        // The paper's Algorithm 2 meets d_k = 0 at the apex and keeps α = d* (in v units), so Algorithm 1
        // stacks 100 samples on the one point.
        let p = sample(&Fan, &paper()).unwrap();
        assert!(p.samples.iter().filter(|s| s.u == 0.0).count() >= 99);
        // A face collapsed to a point: no endless loop, and no sample (it has no normal anywhere).
        assert!(sample(&Dot, &robust(0.01)).unwrap().samples.is_empty());
        // Bad requests are refused with the quantity named.
        let bad = Sampling { spacing_u: 0.0, ..robust(0.01) };
        assert!(sample(&Fan, &bad).unwrap_err().to_string().contains("spacing u"));
        let tiny = Sampling { spacing_u: 1e-7, spacing_v: 1e-7, ..robust(0.01) };
        assert!(sample(&Plane { length: 1.0, width: 1.0, z: 0.0 }, &tiny).unwrap_err().to_string().contains("too small"));
    }
}
