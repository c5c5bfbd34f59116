//! `strand-plan surface`: 003's path generation on a CAD-like surface (Onstein, Evjemo, Gravdahl, "Additive
//! Manufacturing Path Generation for Robot Manipulators Based on CAD Models"). This module owns the whole
//! chain from a parametric face r(u, v) to a segment stream the feeder can send: sampling the face at a
//! desired spacing (Algorithms 1 and 2), ordering the samples into one extrusion path (greedy, Algorithm 3;
//! weighted greedy, Algorithm 4; greedy tour + 2-opt local search, Algorithm 5), judging each path (length,
//! self-intersections in the parameter plane, compute time), and turning the chosen path into `Segment`s
//! whose tool z axis follows the surface normal — the six-axis paths a 3-axis printer cannot make.
//!
//! Everything is SI: points in m in the bed frame (z up), angles in rad, times in s. The parameters (u, v)
//! are in each surface's own units (m of length or arc length, or rad), named by
//! [`Surface::parameter_labels`].
//!
//! Where we read 003 rather than copy it (each is repeated where it is implemented):
//!
//! - Algorithm 2's stopping test is printed as `d* > d_k + d_k/t OR d* < d_k + d_k/t`, which holds for
//!   almost every d_k and never stops. We read it as `|d* − d_k| > d_k/t` (t = 1/tolerance), the band the
//!   surrounding text describes.
//! - Algorithm 1 as printed never stores the start sample (u_min, v_min), and its last u step stores one
//!   lone sample at (u, v_min) without sampling that row. [`SamplingMode::Paper`] keeps both quirks (they
//!   explain outliers like the "two samples sticking out" of 003's Fig. 4); [`SamplingMode::Robust`], the
//!   default, stores whole rows, calibrates the row step where the rows are closest, warm-starts and
//!   brackets the calibration, and always terminates, also on degenerate patches.
//! - Algorithm 5's distance matrix becomes k-nearest neighbour lists with distances computed on demand
//!   (an n×n matrix of thousands of samples does not fit the point of the exercise), and 003's solver
//!   (Pedroso and Kubo's `tsp.py`: neighbour-list 2-opt from a nearest-neighbour tour) runs on an open path,
//!   since an extrusion does not return to its start; a final exhaustive 2-opt pass makes the result a true
//!   2-opt local optimum.
//! - Fig. 3's curved rectangle is not specified in the text; see [`CurvedRect`] for our reading.
//! - Every path starts at the first sample (003: "choose starting sample"). With Algorithm 1 as printed
//!   that sample is (u_min, v_min + α_v), not a corner, and on the curved rectangle this, not the
//!   surface, is what makes greedy cross itself: from the whole, regular grid of the robust mode greedy
//!   runs a clean boustrophedon (see the tests).
//!
//! No STL input: 003 chose STEP faces precisely because they carry the exact parametrisation r(u, v)
//! that Algorithms 1 and 2 step through and Algorithm 4 weights; a triangle mesh has no (u, v), so it
//! would need a mesh parametrisation first, a different method from the paper's.

use std::cell::Cell;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Vector3;
use plotters::prelude::*;
use serde::Serialize;
use strand::core::{Segment, SegmentFlags, SegmentKind};

// ---------------------------------------------------------------------------------------------------------
// Surfaces
// ---------------------------------------------------------------------------------------------------------

/// The rectangle of parameters a surface is defined on: 003's `pRange` (units: the surface's u and v).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Domain {
    /// (u_min, u_max), in the surface's u unit (m or rad).
    pub u: (f64, f64),
    /// (v_min, v_max), in the surface's v unit (m or rad).
    pub v: (f64, f64),
}

impl Domain {
    /// u_max − u_min (u unit).
    pub fn span_u(&self) -> f64 {
        self.u.1 - self.u.0
    }

    /// v_max − v_min (v unit).
    pub fn span_v(&self) -> f64 {
        self.v.1 - self.v.0
    }

    /// True if (u, v) lies in the rectangle, with a tolerance of 1e-9 of each span for the rounding of
    /// summed steps.
    pub fn contains(&self, u: f64, v: f64) -> bool {
        let (eu, ev) = (1e-9 * self.span_u(), 1e-9 * self.span_v());
        u >= self.u.0 - eu && u <= self.u.1 + eu && v >= self.v.0 - ev && v <= self.v.1 + ev
    }
}

/// A face r(u, v) (003 Eq. 1) over a parameter rectangle, possibly trimmed.
pub trait Surface {
    /// The parameter rectangle (003's `pRange`).
    fn domain(&self) -> Domain;

    /// The point r(u, v) (m, bed frame; 003's `valueAt`). Defined on the whole domain and a little beyond
    /// (the calibration probes past the edges).
    fn point(&self, u: f64, v: f64) -> Vector3<f64>;

    /// The unit normal at (u, v), on the side the nozzle works from (the tool z axis is its negative).
    /// The default is 003's Eq. 2, ∂r/∂u × ∂r/∂v by central differences, normalised: a surface whose
    /// parametrisation has the nozzle on the other side must override it.
    fn normal(&self, u: f64, v: f64) -> Vector3<f64> {
        eq2_normal(self, u, v)
    }

    /// 003's `isInside`: true if (u, v) lies on the face. The default is the whole domain; a trimmed face
    /// narrows it.
    fn contains(&self, u: f64, v: f64) -> bool {
        self.domain().contains(u, v)
    }

    /// Axis labels for plots, with units: (u, v).
    fn parameter_labels(&self) -> (&'static str, &'static str);
}

/// 003's Eq. 2 normal, n = ∂r/∂u × ∂r/∂v, by central differences (step 1e-6 of each span), normalised.
/// Zero where the parametrisation is degenerate (both partials parallel or zero).
pub fn eq2_normal<S: Surface + ?Sized>(s: &S, u: f64, v: f64) -> Vector3<f64> {
    let d = s.domain();
    let (hu, hv) = (1e-6 * d.span_u(), 1e-6 * d.span_v());
    let ru = (s.point(u + hu, v) - s.point(u - hu, v)) / (2.0 * hu);
    let rv = (s.point(u, v + hv) - s.point(u, v - hv)) / (2.0 * hv);
    ru.cross(&rv).try_normalize(1e-300).unwrap_or_else(Vector3::zeros)
}

/// A flat rectangle on the bed plane z = `z`: u along x, v along y (both m), normal +z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Extent along x = u (m).
    pub length: f64,
    /// Extent along y = v (m).
    pub width: f64,
    /// Height of the plane above the bed (m).
    pub z: f64,
}

impl Surface for Plane {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.length), v: (0.0, self.width) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(u, v, self.z)
    }
    fn normal(&self, _u: f64, _v: f64) -> Vector3<f64> {
        Vector3::z()
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = x (m)", "v = y (m)")
    }
}

/// A patch of a cylinder lying on the bed with its axis along x at height 0, printed from outside:
/// r(u, v) = (u, R sin v, R cos v), u ∈ [0, length] (m), v ∈ [−sweep/2, sweep/2] (rad from the top),
/// normal (0, sin v, cos v) (radially out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    /// Radius R (m).
    pub radius: f64,
    /// Extent along the axis (m).
    pub length: f64,
    /// Angle the patch spans around the axis, centred on the top (rad, < 2π).
    pub sweep: f64,
}

impl Surface for Cylinder {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.length), v: (-0.5 * self.sweep, 0.5 * self.sweep) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(u, self.radius * v.sin(), self.radius * v.cos())
    }
    fn normal(&self, _u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(0.0, v.sin(), v.cos())
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = x (m)", "v = angle from the top (rad)")
    }
}

/// 003's curved rectangle (Figs. 3, 5, 6), our reading. The text says only "a curved rectangular surface",
/// chosen "to demonstrate how a path for printing in overhang can be achieved", sampled at 10 mm, and that
/// weighting u is "to guide the path along the v-direction, resulting in movements from side to side". We take
/// a rectangular sheet, `width` wide along x, bent along its length into a circular arc of radius R in the
/// y–z plane: it leaves the bed tangentially, rises through vertical and, past 90°, curls back over the
/// bed, so its upper part overhangs and is printed with the nozzle pointing up-ish (a quarter pipe printed
/// from its concave side). u runs along the bend (up the sheet), v across it (side to side), so a u-weighted
/// path prints horizontal lines across the width, climbing the arch line by line into the overhang:
///
/// r(u, v) = (v, R sin φ, R (1 − cos φ)), φ = u / R, u ∈ [0, R·bend] (m of arc length), v ∈ [0, width] (m),
/// normal (0, −sin φ, cos φ), towards the centre of the bend (that is −(∂r/∂u × ∂r/∂v)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurvedRect {
    /// Width along x = v (m).
    pub width: f64,
    /// Bend radius R (m).
    pub radius: f64,
    /// Bend angle (rad); above π/2 the sheet overhangs.
    pub bend: f64,
}

impl Surface for CurvedRect {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.radius * self.bend), v: (0.0, self.width) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        let phi = u / self.radius;
        Vector3::new(v, self.radius * phi.sin(), self.radius * (1.0 - phi.cos()))
    }
    fn normal(&self, u: f64, _v: f64) -> Vector3<f64> {
        let phi = u / self.radius;
        Vector3::new(0.0, -phi.sin(), phi.cos())
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = arc length up the bend (m)", "v = x across (m)")
    }
}

/// 002's Gaussian bump (Eq. 20), a ridge along x: z = z0·exp(−y²/β²), u = x ∈ [0, length],
/// v = y ∈ [−width/2, width/2] (m); normal (0, −∂z/∂y, 1)/|·|.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bump {
    /// Extent along x (m).
    pub length: f64,
    /// Extent along y, centred on the ridge (m).
    pub width: f64,
    /// Peak height z0 (m).
    pub height: f64,
    /// Width parameter β (m).
    pub beta: f64,
}

impl Bump {
    /// Eq. 20: the height at y (m).
    pub fn z(&self, y: f64) -> f64 {
        self.height * (-(y * y) / (self.beta * self.beta)).exp()
    }

    /// dz/dy of Eq. 20.
    pub fn slope(&self, y: f64) -> f64 {
        -2.0 * y / (self.beta * self.beta) * self.z(y)
    }
}

impl Surface for Bump {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.length), v: (-0.5 * self.width, 0.5 * self.width) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(u, v, self.z(v))
    }
    fn normal(&self, _u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(0.0, -self.slope(v), 1.0).normalize()
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = x (m)", "v = y (m)")
    }
}

/// A twisted, cambered, propeller-like blade standing in for 003's propeller blade (Figs. 4, 7, 8), a
/// trimmed face. Not a real propeller section; it has the features that matter to the paper: twist,
/// curvature, a non-rectangular outline.
///
/// u = r ∈ [hub_radius, tip_radius] is the span along x (m); v = s ∈ [−chord/2, chord/2] the chordwise
/// coordinate (m). The blade section at r is the camber line (s, h(s)), h(s) = camber·chord/2·(1 − (2s/chord)²),
/// turned by the pitch angle θ(r) = atan(pitch / (2π r)) (a constant-pitch helix: steep at the hub, flat at
/// the tip) in the y–z plane and lifted by `lift`:
///
/// r(u, v) = (r, s cos θ − h sin θ, s sin θ + h cos θ + lift).
///
/// The face is trimmed (003's `isInside`) to |s| ≤ c(r)/2 with the outline
/// c(r) = chord·(0.6 + 0.4 sin πσ)·√(1 − σ⁶), σ = (r − hub_radius)/(tip_radius − hub_radius): 60 % of the
/// chord at the root, widest mid-span, closing to a round tip. The normal is Eq. 2's (the suction side,
/// +z-ish).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blade {
    /// Span start (m from the propeller axis).
    pub hub_radius: f64,
    /// Span end (m from the propeller axis).
    pub tip_radius: f64,
    /// Widest chord (m).
    pub chord: f64,
    /// Geometric pitch (m per turn).
    pub pitch: f64,
    /// Camber height as a fraction of the half chord (1).
    pub camber: f64,
    /// Height of the blade's axis above the bed (m).
    pub lift: f64,
}

impl Blade {
    /// The trimmed chord length at span r (m).
    pub fn outline(&self, r: f64) -> f64 {
        let sigma = ((r - self.hub_radius) / (self.tip_radius - self.hub_radius)).clamp(0.0, 1.0);
        self.chord * (0.6 + 0.4 * (PI * sigma).sin()) * (1.0 - sigma.powi(6)).max(0.0).sqrt()
    }
}

impl Surface for Blade {
    fn domain(&self) -> Domain {
        Domain { u: (self.hub_radius, self.tip_radius), v: (-0.5 * self.chord, 0.5 * self.chord) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        let theta = (self.pitch / (2.0 * PI * u)).atan();
        let s = 2.0 * v / self.chord;
        let h = self.camber * 0.5 * self.chord * (1.0 - s * s);
        let (st, ct) = theta.sin_cos();
        Vector3::new(u, v * ct - h * st, v * st + h * ct + self.lift)
    }
    fn contains(&self, u: f64, v: f64) -> bool {
        self.domain().contains(u, v) && v.abs() <= 0.5 * self.outline(u) * (1.0 + 1e-9)
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = span r (m)", "v = chordwise s (m)")
    }
}

// ---------------------------------------------------------------------------------------------------------
// Sampling: Algorithms 1 and 2
// ---------------------------------------------------------------------------------------------------------

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
}

/// Which version of Algorithm 1 to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
pub fn sample<S: Surface + ?Sized>(surface: &S, sampling: &Sampling) -> Result<PointCloud, String> {
    let d = surface.domain();
    if !(d.span_u() > 0.0 && d.span_v() > 0.0 && d.span_u().is_finite() && d.span_v().is_finite()) {
        return Err(format!("the surface's parameter domain u {:?}, v {:?} is empty", d.u, d.v));
    }
    for (name, x) in [("spacing u", sampling.spacing_u), ("spacing v", sampling.spacing_v)] {
        if !(x.is_finite() && x > 0.0) {
            return Err(format!("{name} = {x} m: must be positive"));
        }
    }
    if !(sampling.tolerance.is_finite() && sampling.tolerance > 0.0 && sampling.tolerance < 1.0) {
        return Err(format!("tolerance = {}: must lie in (0, 1)", sampling.tolerance));
    }
    let estimate = estimated_samples(surface, &d, sampling);
    if estimate > MAX_SAMPLES as f64 {
        return Err(format!(
            "about {estimate:.1e} samples, more than {MAX_SAMPLES}: the spacing ({} m, {} m) is too small for this surface",
            sampling.spacing_u, sampling.spacing_v
        ));
    }
    let mut eval = Evaluator { surface, evaluations: 0 };
    let mut cloud = PointCloud::default();
    let (mut sum_u, mut n_u, mut sum_v, mut n_v) = (0.0, 0usize, 0.0, 0usize);
    let add = |cloud: &mut PointCloud, eval: &mut Evaluator<S>, u: f64, v: f64| -> Result<(), String> {
        if !surface.contains(u, v) {
            return Ok(());
        }
        if cloud.samples.len() >= MAX_SAMPLES {
            return Err(format!(
                "more than {MAX_SAMPLES} samples: the spacing ({} m, {} m) is too small for this surface",
                sampling.spacing_u, sampling.spacing_v
            ));
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
    let step = |steps: &mut usize| -> Result<(), String> {
        *steps += 1;
        if *steps > max_steps {
            Err(format!("sampling did not terminate within {max_steps} steps (the calibrated step collapsed)"))
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
                        return Err(format!("Algorithm 2 found no positive v step at (u, v) = ({uc}, {vc})"));
                    }
                    vc += av;
                    (sum_v, n_v) = (sum_v + av, n_v + 1);
                    add(&mut cloud, &mut eval, uc, vc)?;
                }
                vc = d.v.0;
                step(&mut steps)?;
                let au = eval.calibrate_paper(uc, vc, Dir::U, sampling.spacing_u, tol);
                if au.is_nan() || au <= 0.0 {
                    return Err(format!("Algorithm 2 found no positive u step at (u, v) = ({uc}, {vc})"));
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
                    break;
                }
                au = row;
                uc += au;
                (sum_u, n_u) = (sum_u + au, n_u + 1);
            }
        }
    }
    cloud.step_u = if n_u > 0 { sum_u / n_u as f64 } else { d.span_u() };
    cloud.step_v = if n_v > 0 { sum_v / n_v as f64 } else { d.span_v() };
    cloud.evaluations = eval.evaluations;
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

// ---------------------------------------------------------------------------------------------------------
// Path generation: Algorithms 3, 4, 5
// ---------------------------------------------------------------------------------------------------------

/// A path algorithm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
pub enum Algorithm {
    /// Algorithm 3: always the nearest unvisited sample (Eq. 3 distance).
    #[value(name = "greedy")]
    #[serde(rename = "greedy")]
    Greedy,
    /// Algorithm 4 with the weight on u: leaving the current u row costs extra, so the path runs along
    /// v to the end of the row before it changes row (side to side, 003's Figs. 6 and 7).
    #[value(name = "weighted-u")]
    #[serde(rename = "weighted-u")]
    WeightedU,
    /// Algorithm 4 with the weight on v: the path runs along u.
    #[value(name = "weighted-v")]
    #[serde(rename = "weighted-v")]
    WeightedV,
    /// Algorithm 5: greedy tour, then 2-opt local search.
    #[value(name = "tsp")]
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
    pub fn for_cloud(cloud: &PointCloud, axis: Axis, weight: Option<f64>) -> Weighting {
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

// ---------------------------------------------------------------------------------------------------------
// Self-intersections in the parameter plane
// ---------------------------------------------------------------------------------------------------------

/// How two segments of a path meet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactKind {
    /// The interiors cross at one point.
    Proper,
    /// An endpoint lies on the other segment (a T), or the segments overlap collinearly (including an
    /// adjacent pair that folds back on itself).
    Touching,
}

/// One self-intersection: segments `first` < `second` (segment k joins path points k and k+1) meet at
/// `at` (u, v).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Index of the earlier segment.
    pub first: usize,
    /// Index of the later segment.
    pub second: usize,
    /// A point of the contact in the parameter plane (u unit, v unit).
    pub at: (f64, f64),
    /// Crossing or touching.
    pub kind: ContactKind,
}

/// Signed area test with a relative tolerance: 0 if c is within 1e-9 (relative) of the line ab.
fn orient(a: (f64, f64), b: (f64, f64), c: (f64, f64)) -> i8 {
    let (abx, aby, acx, acy) = (b.0 - a.0, b.1 - a.1, c.0 - a.0, c.1 - a.1);
    let cross = abx * acy - aby * acx;
    let scale = (abx.hypot(aby)) * (acx.hypot(acy));
    if cross.abs() <= 1e-9 * scale {
        0
    } else if cross > 0.0 {
        1
    } else {
        -1
    }
}

/// For c collinear with ab: true if c lies within the segment ab's box.
fn within(a: (f64, f64), b: (f64, f64), c: (f64, f64)) -> bool {
    let e = 1e-12;
    c.0 >= a.0.min(b.0) - e && c.0 <= a.0.max(b.0) + e && c.1 >= a.1.min(b.1) - e && c.1 <= a.1.max(b.1) + e
}

/// How segments pq and rs meet, and a point where.
fn contact(p: (f64, f64), q: (f64, f64), r: (f64, f64), s: (f64, f64)) -> Option<(ContactKind, (f64, f64))> {
    let (d1, d2, d3, d4) = (orient(r, s, p), orient(r, s, q), orient(p, q, r), orient(p, q, s));
    if d1 * d2 < 0 && d3 * d4 < 0 {
        let (ex, ey, fx, fy) = (q.0 - p.0, q.1 - p.1, s.0 - r.0, s.1 - r.1);
        let t = ((r.0 - p.0) * fy - (r.1 - p.1) * fx) / (ex * fy - ey * fx);
        return Some((ContactKind::Proper, (p.0 + t * ex, p.1 + t * ey)));
    }
    for (d, x, a, b) in [(d1, p, r, s), (d2, q, r, s), (d3, r, p, q), (d4, s, p, q)] {
        if d == 0 && within(a, b, x) {
            return Some((ContactKind::Touching, x));
        }
    }
    None
}

/// The self-intersections of the path `order` through `cloud`, in the (u, v) plane: every pair of
/// segments that meet, counted once per pair. Non-adjacent segments count when they share any point: a
/// proper crossing, a T (an endpoint on the other segment) or a collinear overlap, since each deposits
/// material twice. Adjacent segments share their joint and count only when they overlap beyond it (the
/// path turns back 180° on itself). Zero-length segments are skipped.
///
/// A uniform grid over the normalised (u, v) box (about one cell per segment) holds each segment in the
/// cells its bounding box covers; a pair is tested in the one cell holding the lower corner of the
/// intersection of their boxes, so each pair once. Near O(n) for paths of short steps; a long jump costs
/// the cells it spans.
pub fn self_intersections(cloud: &PointCloud, order: &[usize]) -> Vec<Contact> {
    let m = order.len().saturating_sub(1);
    if m < 2 {
        return Vec::new();
    }
    let (mut u0, mut u1, mut v0, mut v1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in &cloud.samples {
        (u0, u1, v0, v1) = (u0.min(s.u), u1.max(s.u), v0.min(s.v), v1.max(s.v));
    }
    let (su, sv) = ((u1 - u0).max(f64::MIN_POSITIVE), (v1 - v0).max(f64::MIN_POSITIVE));
    let pt = |k: usize| {
        let s = &cloud.samples[order[k]];
        ((s.u - u0) / su, (s.v - v0) / sv)
    };
    let g = ((m as f64).sqrt().ceil() as usize).clamp(1, 1024);
    let cell = |x: f64| ((x * g as f64) as usize).min(g - 1);
    let mut boxes = Vec::with_capacity(m);
    let mut grid: Vec<Vec<usize>> = vec![Vec::new(); g * g];
    for k in 0..m {
        let (a, b) = (pt(k), pt(k + 1));
        let bb = (a.0.min(b.0), a.1.min(b.1), a.0.max(b.0), a.1.max(b.1));
        boxes.push(bb);
        if a == b {
            continue;
        }
        for cy in cell(bb.1)..=cell(bb.3) {
            for cx in cell(bb.0)..=cell(bb.2) {
                grid[cy * g + cx].push(k);
            }
        }
    }
    let mut found = Vec::new();
    for (c, members) in grid.iter().enumerate() {
        let (cx, cy) = (c % g, c / g);
        for (x, &i) in members.iter().enumerate() {
            for &j in &members[x + 1..] {
                let (i, j) = if i < j { (i, j) } else { (j, i) };
                let (bi, bj) = (boxes[i], boxes[j]);
                let (lx, ly, hx, hy) = (bi.0.max(bj.0), bi.1.max(bj.1), bi.2.min(bj.2), bi.3.min(bj.3));
                if lx > hx + 1e-12 || ly > hy + 1e-12 || cell(lx) != cx || cell(ly) != cy {
                    continue;
                }
                let (p, q, r, s) = (pt(i), pt(i + 1), pt(j), pt(j + 1));
                let hit = if j == i + 1 {
                    // Adjacent: q == r is the joint; a fold-back is p, q, s collinear with p and s on the
                    // same side of q.
                    let folds = orient(p, q, s) == 0 && (p.0 - q.0) * (s.0 - q.0) + (p.1 - q.1) * (s.1 - q.1) > 0.0;
                    folds.then_some((ContactKind::Touching, q))
                } else {
                    contact(p, q, r, s)
                };
                if let Some((kind, at)) = hit {
                    found.push(Contact { first: i, second: j, at: (u0 + at.0 * su, v0 + at.1 * sv), kind });
                }
            }
        }
    }
    found.sort_by_key(|c| (c.first, c.second));
    found
}

// ---------------------------------------------------------------------------------------------------------
// Report
// ---------------------------------------------------------------------------------------------------------

/// One algorithm's result, as `--json` prints it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AlgorithmReport {
    /// Samples on the path (1).
    pub points: usize,
    /// Path length (m).
    pub path_length_m: f64,
    /// Self-intersections in the (u, v) plane: proper crossings + touchings (1).
    pub self_intersections: usize,
    /// Of which proper crossings (1).
    pub proper_crossings: usize,
    /// Wall-clock time to make the path (s).
    pub compute_s: f64,
    /// Eq. 3 distance evaluations (1): the machine-independent measure of work.
    pub distance_evaluations: u64,
}

impl AlgorithmReport {
    /// The report for `path` with its `contacts`.
    pub fn new(path: &PlannedPath, contacts: &[Contact]) -> AlgorithmReport {
        AlgorithmReport {
            points: path.order.len(),
            path_length_m: path.length,
            self_intersections: contacts.len(),
            proper_crossings: contacts.iter().filter(|c| c.kind == ContactKind::Proper).count(),
            compute_s: path.compute_s,
            distance_evaluations: path.distance_evaluations,
        }
    }
}

// ---------------------------------------------------------------------------------------------------------
// Segments
// ---------------------------------------------------------------------------------------------------------

/// Bead and motion parameters for the segment stream (SI).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deposition {
    /// Extrusion (line) width w (m).
    pub line_width: f64,
    /// Layer height h (m).
    pub layer_height: f64,
    /// Filament diameter d (m).
    pub filament_diameter: f64,
    /// Print speed (m/s).
    pub speed: f64,
    /// Speed of the travel move to the start (m/s).
    pub travel_speed: f64,
    /// Nozzle tip offset from the surface along its normal (m): one layer height lays the bead onto the
    /// surface; 0 puts the tip on 003's sample points themselves.
    pub standoff: f64,
}

impl Default for Deposition {
    /// A 0.45 mm line, 0.2 mm layers, 1.75 mm filament, 10 mm/s printing, 50 mm/s travel, tip one layer
    /// off the surface.
    fn default() -> Self {
        Deposition {
            line_width: 0.45e-3,
            layer_height: 0.2e-3,
            filament_diameter: 1.75e-3,
            speed: 0.01,
            travel_speed: 0.05,
            standoff: 0.2e-3,
        }
    }
}

impl Deposition {
    /// Filament per metre of path (m/m): Slic3r's bead cross-section A = h(w − h) + π(h/2)² (a rectangle
    /// with round ends) over the filament's area π(d/2)².
    pub fn filament_per_metre(&self) -> f64 {
        super::filament_per_metre(self.line_width, self.layer_height, self.filament_diameter)
    }

    /// Checks the values; the message names the flag.
    pub fn validate(&self) -> Result<(), String> {
        super::positive("line-width", self.line_width)?;
        super::positive("layer-height", self.layer_height)?;
        super::positive("filament-diameter", self.filament_diameter)?;
        super::positive("speed", self.speed)?;
        super::positive("travel-speed", self.travel_speed)?;
        if self.layer_height > self.line_width {
            return Err(format!("--layer-height = {} m is more than --line-width = {} m", self.layer_height, self.line_width));
        }
        if !self.standoff.is_finite() {
            return Err(format!("--standoff = {}: must be finite", self.standoff));
        }
        Ok(())
    }
}

/// The segment stream for `order` through `cloud`: a travel to the first sample, then one extruding line
/// per step, the last flagged LAST. Each end is the sample point offset by the standoff along its normal
/// (m, bed frame), with the nozzle along −normal (`strand_job::segfile::tool_pointing`: the shortest turn from
/// nozzle-down, π about x for straight up); sequence numbers from 0.
pub fn segments(cloud: &PointCloud, order: &[usize], dep: &Deposition) -> Vec<Segment> {
    let per_m = dep.filament_per_metre();
    let tip = |k: usize| {
        let s = &cloud.samples[order[k]];
        (s.point + dep.standoff * s.normal, strand_job::segfile::tool_pointing(&-s.normal))
    };
    let mut out = Vec::with_capacity(order.len());
    for k in 0..order.len() {
        let (end, orientation) = tip(k);
        let (feed, filament, flags) = if k == 0 {
            (dep.travel_speed, 0.0, SegmentFlags::TRAVEL.with(SegmentFlags::LAYER_START))
        } else {
            (dep.speed, per_m * (end - tip(k - 1).0).norm(), SegmentFlags::EXTRUDE)
        };
        out.push(Segment { seq: k as u64, kind: SegmentKind::Line, end, orientation, feed, filament, flags, ..Segment::default() });
    }
    if let Some(last) = out.last_mut() {
        last.flags = last.flags.with(SegmentFlags::LAST);
    }
    out
}

/// Writes the segments as a segment file (`strand_job::segfile`). The one place this module touches that
/// format.
pub fn write_segments(path: &Path, segments: &[Segment], note: &str) -> Result<(), String> {
    strand_job::segfile::write_path(path, segments, note)
}

// ---------------------------------------------------------------------------------------------------------
// PNG
// ---------------------------------------------------------------------------------------------------------

/// One panel of the figure.
pub struct Panel<'a> {
    /// The path.
    pub path: &'a PlannedPath,
    /// Its self-intersections.
    pub contacts: &'a [Contact],
}

/// Draws each path in the (u, v) plane side by side, samples as dots, the start as a green dot, proper
/// crossings as red circles and touchings as orange ones.
pub fn plot_png(file: &Path, title: &str, labels: (&str, &str), cloud: &PointCloud, panels: &[Panel]) -> Result<(), String> {
    crate::replay_plot::register_font()?;
    draw(file, title, labels, cloud, panels).map_err(|e| format!("{}: {e}", file.display()))
}

fn draw(file: &Path, title: &str, labels: (&str, &str), cloud: &PointCloud, panels: &[Panel]) -> Result<(), Box<dyn std::error::Error>> {
    let k = panels.len().max(1);
    let root = BitMapBackend::new(file, (560 * k as u32, 640)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(title, ("sans-serif", 24))?;
    let cells = root.split_evenly((1, k));
    let (mut u0, mut u1, mut v0, mut v1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in &cloud.samples {
        (u0, u1, v0, v1) = (u0.min(s.u), u1.max(s.u), v0.min(s.v), v1.max(s.v));
    }
    if !u0.is_finite() {
        (u0, u1, v0, v1) = (0.0, 1.0, 0.0, 1.0);
    }
    let (pu, pv) = (0.04 * (u1 - u0).max(1e-9), 0.04 * (v1 - v0).max(1e-9));
    for (area, panel) in cells.iter().zip(panels) {
        let p = panel.path;
        let proper = panel.contacts.iter().filter(|c| c.kind == ContactKind::Proper).count();
        let caption = format!(
            "{}: {:.3} m, {} self-int. ({} crossing), {:.3} s",
            p.algorithm.name(),
            p.length,
            panel.contacts.len(),
            proper,
            p.compute_s
        );
        let mut chart = ChartBuilder::on(area)
            .caption(caption, ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(u0 - pu..u1 + pu, v0 - pv..v1 + pv)?;
        chart.configure_mesh().x_desc(labels.0).y_desc(labels.1).light_line_style(WHITE).draw()?;
        chart.draw_series(LineSeries::new(p.order.iter().map(|&i| (cloud.samples[i].u, cloud.samples[i].v)), BLUE.stroke_width(1)))?;
        chart.draw_series(cloud.samples.iter().map(|s| Circle::new((s.u, s.v), 2, BLACK.filled())))?;
        if let Some(&first) = p.order.first() {
            let s = &cloud.samples[first];
            chart.draw_series(std::iter::once(Circle::new((s.u, s.v), 6, GREEN.filled())))?;
        }
        chart.draw_series(panel.contacts.iter().map(|c| {
            let colour = if c.kind == ContactKind::Proper { RED } else { RGBColor(255, 140, 0) };
            Circle::new(c.at, 7, colour.stroke_width(2))
        }))?;
    }
    root.present()?;
    Ok(())
}

// ---------------------------------------------------------------------------------------------------------
// CLI
// ---------------------------------------------------------------------------------------------------------

/// The surfaces `strand-plan surface` knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Shape {
    /// 003's curved rectangle (Fig. 3), our reading: a sheet bent up past vertical (overhang).
    CurvedRect,
    /// A flat rectangle.
    Plane,
    /// A cylinder patch printed from outside.
    Cylinder,
    /// 002's Gaussian bump (Eq. 20).
    Bump,
    /// A twisted, cambered, trimmed propeller-like blade (003's Figs. 4, 7, 8).
    Blade,
}

/// Which algorithms to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AlgorithmChoice {
    /// Algorithm 3.
    Greedy,
    /// Algorithm 4, weight on u.
    WeightedU,
    /// Algorithm 4, weight on v.
    WeightedV,
    /// Algorithm 5.
    Tsp,
    /// All four.
    All,
}

/// `strand-plan surface`: sample a surface, order the samples into an extrusion path, report, write.
#[derive(Clone, Debug, clap::Args)]
pub struct SurfaceArgs {
    /// The surface.
    #[arg(long, value_enum, default_value = "curved-rect")]
    pub shape: Shape,
    /// Desired distance between samples in both directions, d*_u = d*_v (m; 003 uses 10 mm).
    #[arg(long, default_value_t = 0.01)]
    pub spacing: f64,
    /// Relative tolerance of the step calibration, Algorithm 2 (1; the paper's 1/t).
    #[arg(long, default_value_t = 0.01)]
    pub tolerance: f64,
    /// Algorithm 1 as printed, or made robust.
    #[arg(long, value_enum, default_value = "robust")]
    pub sampling: SamplingMode,
    /// Path algorithm(s).
    #[arg(long, value_enum, default_value = "all")]
    pub algorithm: AlgorithmChoice,
    /// Weighted greedy: the weight added to the distance of a sample off the current row (m; default the
    /// cloud's bounding-box diagonal, so the row is always finished first).
    #[arg(long)]
    pub weight: Option<f64>,
    /// TSP: candidates per sample in the 2-opt neighbour lists (1).
    #[arg(long, default_value_t = 10)]
    pub neighbours: usize,
    /// curved-rect: width along x (across the bend); plane: extent along x; cylinder, bump: length along x (m)
    /// [default 0.1].
    #[arg(long)]
    pub length: Option<f64>,
    /// plane: extent along y; bump: extent along y across the ridge (m) [default 0.1].
    #[arg(long)]
    pub width: Option<f64>,
    /// curved-rect: bend radius; cylinder: radius (m) [default 0.05].
    #[arg(long)]
    pub radius: Option<f64>,
    /// curved-rect: bend angle; cylinder: angle the patch spans (rad) [default 2π/3].
    #[arg(long)]
    pub sweep: Option<f64>,
    /// bump: peak height z0 (m) [default 3 mm, 002].
    #[arg(long)]
    pub height: Option<f64>,
    /// bump: width parameter β (m) [default 18 mm, 002].
    #[arg(long)]
    pub beta: Option<f64>,
    /// blade: hub radius, where the span starts (m).
    #[arg(long, default_value_t = 0.03)]
    pub hub_radius: f64,
    /// blade: tip radius, where the span ends (m).
    #[arg(long, default_value_t = 0.15)]
    pub tip_radius: f64,
    /// blade: widest chord (m).
    #[arg(long, default_value_t = 0.06)]
    pub chord: f64,
    /// blade: geometric pitch (m per turn).
    #[arg(long, default_value_t = 0.2)]
    pub pitch: f64,
    /// blade: camber height as a fraction of the half chord (1).
    #[arg(long, default_value_t = 0.1)]
    pub camber: f64,
    /// Extrusion line width (m).
    #[arg(long, default_value_t = 0.45e-3)]
    pub line_width: f64,
    /// Layer height (m).
    #[arg(long, default_value_t = 0.2e-3)]
    pub layer_height: f64,
    /// Filament diameter (m).
    #[arg(long, default_value_t = 1.75e-3)]
    pub filament_diameter: f64,
    /// Print speed (m/s).
    #[arg(long, default_value_t = 0.01)]
    pub speed: f64,
    /// Travel speed to the first sample (m/s).
    #[arg(long, default_value_t = 0.05)]
    pub travel_speed: f64,
    /// Nozzle tip offset from the surface along its normal (m) [default: the layer height].
    #[arg(long)]
    pub standoff: Option<f64>,
    /// Write the path as segments (JSON lines, strand_job::segfile); needs one --algorithm.
    #[arg(long, short)]
    pub output: Option<PathBuf>,
    /// Draw the paths in the (u, v) plane, self-intersections marked.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print one JSON object instead of the summary.
    #[arg(long)]
    pub json: bool,
}

impl SurfaceArgs {
    /// The surface the flags describe, with its defaults filled in; errors name the flag and value.
    pub fn surface(&self) -> Result<Box<dyn Surface>, String> {
        let length = super::positive("length", self.length.unwrap_or(0.1))?;
        let width = super::positive("width", self.width.unwrap_or(0.1))?;
        let radius = super::positive("radius", self.radius.unwrap_or(0.05))?;
        let sweep = super::positive("sweep", self.sweep.unwrap_or(2.0 * PI / 3.0))?;
        Ok(match self.shape {
            Shape::CurvedRect => {
                if sweep > 2.0 * PI {
                    return Err(format!("--sweep = {sweep} rad: the bend must stay below 2π (the sheet would pass through itself)"));
                }
                Box::new(CurvedRect { width: length, radius, bend: sweep })
            }
            Shape::Plane => Box::new(Plane { length, width, z: 0.0 }),
            Shape::Cylinder => {
                if sweep >= 2.0 * PI {
                    return Err(format!("--sweep = {sweep} rad: a patch must span less than 2π"));
                }
                Box::new(Cylinder { radius, length, sweep })
            }
            Shape::Bump => {
                let height = self.height.unwrap_or(3.0e-3);
                if !height.is_finite() {
                    return Err(format!("--height = {height}: must be finite"));
                }
                Box::new(Bump { length, width, height, beta: super::positive("beta", self.beta.unwrap_or(18.0e-3))? })
            }
            Shape::Blade => {
                let hub = super::positive("hub-radius", self.hub_radius)?;
                let tip = super::positive("tip-radius", self.tip_radius)?;
                if tip <= hub {
                    return Err(format!("--tip-radius = {tip} m must exceed --hub-radius = {hub} m"));
                }
                let chord = super::positive("chord", self.chord)?;
                let pitch = super::positive("pitch", self.pitch)?;
                if !(self.camber.is_finite() && self.camber.abs() <= 1.0) {
                    return Err(format!("--camber = {}: must lie in [-1, 1]", self.camber));
                }
                Box::new(Blade { hub_radius: hub, tip_radius: tip, chord, pitch, camber: self.camber, lift: chord })
            }
        })
    }

    /// The sampling request; errors name the flag.
    pub fn sampling(&self) -> Result<Sampling, String> {
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            return Err(format!("--spacing = {}: must be positive", self.spacing));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0 && self.tolerance < 1.0) {
            return Err(format!("--tolerance = {}: must lie in (0, 1)", self.tolerance));
        }
        Ok(Sampling { spacing_u: self.spacing, spacing_v: self.spacing, tolerance: self.tolerance, mode: self.sampling })
    }

    /// The deposition parameters; errors name the flag.
    pub fn deposition(&self) -> Result<Deposition, String> {
        let d = Deposition {
            line_width: self.line_width,
            layer_height: self.layer_height,
            filament_diameter: self.filament_diameter,
            speed: self.speed,
            travel_speed: self.travel_speed,
            standoff: self.standoff.unwrap_or(self.layer_height),
        };
        d.validate()?;
        Ok(d)
    }

    /// The algorithms to run, in report order.
    pub fn algorithms(&self) -> Vec<Algorithm> {
        match self.algorithm {
            AlgorithmChoice::Greedy => vec![Algorithm::Greedy],
            AlgorithmChoice::WeightedU => vec![Algorithm::WeightedU],
            AlgorithmChoice::WeightedV => vec![Algorithm::WeightedV],
            AlgorithmChoice::Tsp => vec![Algorithm::Tsp],
            AlgorithmChoice::All => Algorithm::ALL.to_vec(),
        }
    }
}

fn shape_name(shape: Shape) -> &'static str {
    match shape {
        Shape::CurvedRect => "curved-rect",
        Shape::Plane => "plane",
        Shape::Cylinder => "cylinder",
        Shape::Bump => "bump",
        Shape::Blade => "blade",
    }
}

/// `strand-plan surface`: samples, plans, reports (summary or `--json`), and writes the segment file and
/// the PNG if asked.
pub fn run(args: &SurfaceArgs) -> Result<(), String> {
    let surface = args.surface()?;
    let sampling = args.sampling()?;
    let deposition = args.deposition()?;
    if let Some(w) = args.weight
        && !(w.is_finite() && w >= 0.0)
    {
        return Err(format!("--weight = {w}: must be a non-negative length (m)"));
    }
    if args.neighbours == 0 {
        return Err("--neighbours = 0: the 2-opt needs at least one candidate per sample".to_string());
    }
    let algorithms = args.algorithms();
    if args.output.is_some() && algorithms.len() != 1 {
        return Err("--output writes one path: give one --algorithm (greedy, weighted-u, weighted-v or tsp), not all".to_string());
    }
    let t0 = Instant::now();
    let cloud = sample(surface.as_ref(), &sampling).map_err(|e| format!("--spacing = {} m: {e}", args.spacing))?;
    let sampling_s = t0.elapsed().as_secs_f64();
    if cloud.samples.len() < 2 {
        return Err(format!("--spacing = {} m leaves {} sample(s) on the surface: nothing to print", args.spacing, cloud.samples.len()));
    }
    let mut results = Vec::new();
    for &a in &algorithms {
        let path = plan(&cloud, a, args.weight, args.neighbours);
        let contacts = self_intersections(&cloud, &path.order);
        results.push((path, contacts));
    }
    let name = shape_name(args.shape);
    if let Some(file) = &args.output {
        let (path, _) = &results[0];
        let segs = segments(&cloud, &path.order, &deposition);
        let note = format!(
            "strand-plan surface --shape {name} --spacing {} --algorithm {} ({} samples, {:.4} m)",
            args.spacing,
            path.algorithm.name(),
            path.order.len(),
            path.length
        );
        write_segments(file, &segs, &note)?;
    }
    if let Some(file) = &args.png {
        let panels: Vec<Panel> = results.iter().map(|(path, contacts)| Panel { path, contacts }).collect();
        let title = format!("strand-plan surface: {name}, {} samples at {} mm", cloud.samples.len(), args.spacing * 1e3);
        plot_png(file, &title, surface.parameter_labels(), &cloud, &panels)?;
    }
    if args.json {
        let mut algos = serde_json::Map::new();
        for (path, contacts) in &results {
            let report = AlgorithmReport::new(path, contacts);
            algos.insert(path.algorithm.name().to_string(), serde_json::to_value(report).map_err(|e| e.to_string())?);
        }
        let out = serde_json::json!({
            "shape": name,
            "spacing_m": args.spacing,
            "sampling": match args.sampling { SamplingMode::Paper => "paper", SamplingMode::Robust => "robust" },
            "samples": cloud.samples.len(),
            "sampling_s": sampling_s,
            "algorithms": algos,
        });
        println!("{out}");
    } else {
        println!(
            "{name}: {} samples at {} m spacing ({} sampling, {:.3} s)",
            cloud.samples.len(),
            args.spacing,
            shape_sampling(args),
            sampling_s
        );
        println!("  {:<11} {:>7} {:>12} {:>10} {:>9} {:>11}", "algorithm", "points", "length (m)", "self-int.", "crossing", "compute (s)");
        for (path, contacts) in &results {
            let r = AlgorithmReport::new(path, contacts);
            println!(
                "  {:<11} {:>7} {:>12.4} {:>10} {:>9} {:>11.4}",
                path.algorithm.name(),
                r.points,
                r.path_length_m,
                r.self_intersections,
                r.proper_crossings,
                r.compute_s
            );
        }
        if let Some(f) = &args.output {
            println!("  wrote {}", f.display());
        }
        if let Some(f) = &args.png {
            println!("  wrote {}", f.display());
        }
    }
    Ok(())
}

fn shape_sampling(args: &SurfaceArgs) -> &'static str {
    match args.sampling {
        SamplingMode::Paper => "paper",
        SamplingMode::Robust => "robust",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    const D: f64 = 0.01;

    fn robust(tolerance: f64) -> Sampling {
        Sampling { spacing_u: D, spacing_v: D, tolerance, mode: SamplingMode::Robust }
    }

    fn paper() -> Sampling {
        Sampling { spacing_u: D, spacing_v: D, tolerance: 0.01, mode: SamplingMode::Paper }
    }

    fn curved() -> CurvedRect {
        CurvedRect { width: 0.1, radius: 0.05, bend: 2.0 * PI / 3.0 }
    }

    fn bump() -> Bump {
        Bump { length: 0.1, width: 0.1, height: 3.0e-3, beta: 18.0e-3 }
    }

    fn cylinder() -> Cylinder {
        Cylinder { radius: 0.05, length: 0.1, sweep: 2.0 * PI / 3.0 }
    }

    fn blade() -> Blade {
        Blade { hub_radius: 0.03, tip_radius: 0.15, chord: 0.06, pitch: 0.2, camber: 0.1, lift: 0.06 }
    }

    /// A cloud from (u, v) points on the plane z = 0.
    fn cloud_of(uv: &[(f64, f64)]) -> PointCloud {
        let samples = uv.iter().map(|&(u, v)| Sample { u, v, point: Vector3::new(u, v, 0.0), normal: Vector3::z() }).collect();
        PointCloud { samples, step_u: 1.0, step_v: 1.0, evaluations: 0 }
    }

    fn identity(n: usize) -> Vec<usize> {
        (0..n).collect()
    }

    /// Each sample's nearest other sample (m, 3D).
    fn nearest(cloud: &PointCloud) -> Vec<f64> {
        let s = &cloud.samples;
        (0..s.len())
            .map(|i| (0..s.len()).filter(|&j| j != i).map(|j| (s[i].point - s[j].point).norm()).fold(f64::INFINITY, f64::min))
            .collect()
    }

    #[test]
    fn analytic_normals_are_unit_and_agree_with_eq2() {
        let surfaces: [(&dyn Surface, f64); 4] =
            [(&Plane { length: 0.1, width: 0.1, z: 0.0 }, 1.0), (&cylinder(), 1.0), (&bump(), 1.0), (&curved(), -1.0)];
        for (s, sign) in surfaces {
            let d = s.domain();
            for i in 0..=6 {
                for j in 0..=6 {
                    let u = d.u.0 + d.span_u() * i as f64 / 6.0;
                    let v = d.v.0 + d.span_v() * j as f64 / 6.0;
                    let n = s.normal(u, v);
                    assert!((n.norm() - 1.0).abs() < 1e-12, "{n:?}");
                    let e = eq2_normal(s, u, v) * sign;
                    assert!((n - e).norm() < 1e-6, "({u}, {v}): {n:?} vs Eq. 2 {e:?}");
                }
            }
        }
    }

    #[test]
    fn normals_point_where_the_geometry_says() {
        // Cylinder: radially out from the axis (the x axis).
        let c = cylinder();
        for v in [-1.0, -0.3, 0.0, 0.7, 1.0] {
            let p = c.point(0.05, v);
            let radial = Vector3::new(0.0, p.y, p.z).normalize();
            assert!((c.normal(0.05, v) - radial).norm() < 1e-12);
        }
        // Bump: perpendicular to the ridge slope, up; level on the crest and tilted by atan(z') off it.
        let b = bump();
        assert!((b.normal(0.02, 0.0) - Vector3::z()).norm() < 1e-12);
        let y = b.beta / 2f64.sqrt(); // steepest point: z' = −√2·z0/β·e^(−1/2)
        let slope = 2f64.sqrt() * b.height / b.beta * (-0.5f64).exp();
        let n = b.normal(0.02, y);
        assert!((n.z.acos() - slope.atan()).abs() < 1e-12 && n.y > 0.0 && n.x == 0.0, "{n:?}");
        // Curved rectangle: up at the foot, −y at the vertical, pointing down past it (the overhang).
        let r = curved();
        assert!((r.normal(0.0, 0.05) - Vector3::z()).norm() < 1e-12);
        assert!((r.normal(0.05 * PI / 2.0, 0.05) + Vector3::y()).norm() < 1e-12);
        let top = r.normal(r.domain().u.1, 0.05);
        assert!(top.z < -0.49 && top.y < 0.0, "{top:?}");
        // Blade: Eq. 2 (finite differences) is unit and faces up on the suction side.
        let bl = blade();
        let n = bl.normal(0.09, 0.0);
        assert!((n.norm() - 1.0).abs() < 1e-9 && n.z > 0.5, "{n:?}");
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
        assert!(sample(&Fan, &bad).unwrap_err().contains("spacing u"));
        let tiny = Sampling { spacing_u: 1e-7, spacing_v: 1e-7, ..robust(0.01) };
        assert!(sample(&Plane { length: 1.0, width: 1.0, z: 0.0 }, &tiny).unwrap_err().contains("too small"));
    }

    #[test]
    fn intersection_counter_on_hand_made_paths() {
        let count = |uv: &[(f64, f64)]| {
            let c = cloud_of(uv);
            let found = self_intersections(&c, &identity(uv.len()));
            (
                found.iter().filter(|k| k.kind == ContactKind::Proper).count(),
                found.iter().filter(|k| k.kind == ContactKind::Touching).count(),
            )
        };
        // A boustrophedon and a spiral: clean.
        assert_eq!(count(&[(0.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (2.0, 0.0), (2.0, 1.0)]), (0, 0));
        assert_eq!(count(&[(0.0, 0.0), (3.0, 0.0), (3.0, 3.0), (0.0, 3.0), (0.0, 1.0), (2.0, 1.0), (2.0, 2.0), (1.0, 2.0)]), (0, 0));
        // An X: one proper crossing, at the middle.
        let x = cloud_of(&[(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)]);
        let found = self_intersections(&x, &identity(4));
        assert_eq!(found.len(), 1);
        assert_eq!((found[0].first, found[0].second, found[0].kind), (0, 2, ContactKind::Proper));
        assert!((found[0].at.0 - 0.5).abs() < 1e-12 && (found[0].at.1 - 0.5).abs() < 1e-12);
        // A T: the path ends on its first segment.
        assert_eq!(count(&[(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0, 1.0), (1.0, 0.0)]), (0, 1));
        // A fold-back of adjacent segments, and a plain 90° turn that is not one.
        assert_eq!(count(&[(0.0, 0.0), (2.0, 0.0), (1.0, 0.0)]), (0, 1));
        assert_eq!(count(&[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]), (0, 0));
        // A collinear overlap of non-adjacent segments, which also runs through the corner (2, 0).
        assert_eq!(count(&[(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (3.0, 1.0), (3.0, 0.0), (1.0, 0.0)]), (0, 2));
        // Passing exactly through a joint of the path: a touching with each of the two segments there.
        assert_eq!(count(&[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (2.0, -1.0)]), (0, 2));
        // Several crossings of one long segment: a zigzag cut by a line.
        let mut zig: Vec<(f64, f64)> = (0..10).map(|k| (k as f64, if k % 2 == 0 { 0.0 } else { 2.0 })).collect();
        zig.extend([(9.5, 1.0), (-0.5, 1.0)]);
        assert_eq!(count(&zig), (9, 0));
    }

    #[test]
    fn grid_counter_matches_all_pairs() {
        let mut rng = StdRng::seed_from_u64(3);
        for trial in 0..20 {
            let n = 10 + 15 * trial;
            // Integer points make touching and collinear cases common.
            let uv: Vec<(f64, f64)> =
                (0..n).map(|_| (rng.random_range(0..12) as f64 * 0.01, rng.random_range(0..12) as f64 * 0.01)).collect();
            let c = cloud_of(&uv);
            let order = identity(n);
            let fast = self_intersections(&c, &order);
            let pt = |k: usize| uv[k];
            let mut slow = 0;
            for i in 0..n - 1 {
                for j in i + 1..n - 1 {
                    if pt(i) == pt(i + 1) || pt(j) == pt(j + 1) {
                        continue;
                    }
                    let hit = if j == i + 1 {
                        let (p, q, s) = (pt(i), pt(i + 1), pt(j + 1));
                        orient(p, q, s) == 0 && (p.0 - q.0) * (s.0 - q.0) + (p.1 - q.1) * (s.1 - q.1) > 0.0
                    } else {
                        contact(pt(i), pt(i + 1), pt(j), pt(j + 1)).is_some()
                    };
                    slow += usize::from(hit);
                }
            }
            assert_eq!(fast.len(), slow, "trial {trial}");
        }
    }

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

    #[test]
    fn segments_follow_the_normal_and_meter_the_filament() {
        let surface = curved();
        let cloud = sample(&surface, &robust(0.01)).unwrap();
        let p = plan(&cloud, Algorithm::WeightedU, None, 10);
        let dep = Deposition::default();
        // Slic3r: A = 0.2·(0.45 − 0.2) + π·0.1² mm² over π·0.875² mm².
        let per_m = (0.2 * 0.25 + PI * 0.01) / (PI * 0.875 * 0.875);
        assert!((dep.filament_per_metre() - per_m).abs() < 1e-15);
        let segs = segments(&cloud, &p.order, &dep);
        assert_eq!(segs.len(), cloud.samples.len());
        assert_eq!(segs[0].flags, SegmentFlags::TRAVEL.with(SegmentFlags::LAYER_START));
        assert_eq!(segs[0].filament, 0.0);
        assert!(segs[1..segs.len() - 1].iter().all(|s| s.flags == SegmentFlags::EXTRUDE && s.feed == dep.speed));
        assert_eq!(segs.last().unwrap().flags, SegmentFlags::EXTRUDE.with(SegmentFlags::LAST));
        let mut length = 0.0;
        for (k, s) in segs.iter().enumerate() {
            let sample = &cloud.samples[p.order[k]];
            assert_eq!(s.seq, k as u64);
            assert!((s.end - (sample.point + 0.2e-3 * sample.normal)).norm() < 1e-15);
            let tool_z = s.orientation * Vector3::z();
            assert!((tool_z + sample.normal).norm() < 1e-12, "nozzle along −normal");
            if k > 0 {
                let step = (s.end - segs[k - 1].end).norm();
                assert!((s.filament - per_m * step).abs() < 1e-15);
                length += step;
            }
        }
        // The standoff makes the concave side's path a little shorter than the samples' polyline.
        assert!(length < p.length && length > 0.99 * p.length);
        // The overhang: past vertical the nozzle points up.
        assert!(segs.iter().any(|s| (s.orientation * Vector3::z()).z > 0.4));
        // Straight up (normal −z, a ceiling) takes the π turn about x.
        let q = strand_job::segfile::tool_pointing(&Vector3::z());
        assert!(((q * Vector3::z()) - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn segment_file_round_trips() {
        let cloud = sample(&bump(), &robust(0.01)).unwrap();
        let p = plan(&cloud, Algorithm::Tsp, None, 10);
        let segs = segments(&cloud, &p.order, &Deposition::default());
        let file = std::env::temp_dir().join(format!("strand-surface-unit-{}.jsonl", std::process::id()));
        write_segments(&file, &segs, "unit test").unwrap();
        let back = strand_job::segfile::read_path(&file, 0).unwrap();
        let _ = std::fs::remove_file(&file);
        assert_eq!(back.note.as_deref(), Some("unit test"));
        // The reader numbers source lines by file line (the header is line 1).
        let read: Vec<Segment> = back.segments.into_iter().map(|(s, _)| s).collect();
        assert_eq!(read.len(), segs.len());
        for (k, (r, s)) in read.iter().zip(&segs).enumerate() {
            assert_eq!(r.source_line as usize, k + 2);
            assert_eq!(Segment { source_line: 0, ..*r }, *s, "segment {k}");
        }
    }

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: SurfaceArgs,
    }

    fn args(line: &[&str]) -> SurfaceArgs {
        use clap::Parser;
        Cli::try_parse_from(std::iter::once("surface").chain(line.iter().copied())).unwrap().args
    }

    #[test]
    fn flags_are_checked_by_name() {
        assert!(args(&["--spacing=-0.01"]).sampling().unwrap_err().contains("--spacing = -0.01"));
        assert!(args(&["--tolerance", "2"]).sampling().unwrap_err().contains("--tolerance"));
        assert!(args(&["--shape", "cylinder", "--sweep", "7"]).surface().err().unwrap().contains("--sweep = 7"));
        assert!(args(&["--shape", "blade", "--tip-radius", "0.01"]).surface().err().unwrap().contains("--tip-radius"));
        assert!(args(&["--shape", "bump", "--beta", "0"]).surface().err().unwrap().contains("--beta = 0"));
        assert!(args(&["--line-width", "0.1e-3"]).deposition().unwrap_err().contains("--layer-height"));
        assert!(run(&args(&["--output", "/nonexistent/x.jsonl"])).unwrap_err().contains("--output"));
        assert!(run(&args(&["--neighbours", "0"])).unwrap_err().contains("--neighbours"));
        assert!(run(&args(&["--weight=-1"])).unwrap_err().contains("--weight = -1"));
        // Defaults are 003's and 002's.
        let a = args(&["--shape", "bump"]);
        assert_eq!(a.spacing, 0.01);
        let d = a.deposition().unwrap();
        assert_eq!((d.line_width, d.layer_height, d.filament_diameter, d.standoff), (0.45e-3, 0.2e-3, 1.75e-3, 0.2e-3));
        let s = a.surface().unwrap();
        assert!((s.point(0.0, 0.0).z - 3.0e-3).abs() < 1e-15 && (s.point(0.0, 0.018).z - 3.0e-3 / 1f64.exp()).abs() < 1e-15);
    }
}
