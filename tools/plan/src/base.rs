//! The moving-base trajectory of 000 Section 3.1 (`strand-plan base`): the TCP path of a job as
//! time series x(t), y(t), low-passed with zero phase ([`super::filter`]) into the path of the robot
//! base, with the cut-off lowered step by step (Algorithm 1) until the arm would have to reach
//! further than allowed.
//!
//! Why a low-pass: the base (000's free flyer) should move as little and as gently as possible —
//! its work W_FF (Eq. 1) is fuel — while the arm, fast and precise, takes the detail. The lower the
//! cut-off, the smoother and shorter the base path, and the further the arm must reach; Algorithm 1
//! keeps the lowest cut-off on its grid whose reach stays within the limit.
//!
//! Definitions used here (000 leaves some implicit):
//! - **Time scaling**: `controller` runs the job through the same path engine the controller uses
//!   (a service config's `[path]` and rate, flat bed), `constant` moves each segment at its
//!   programmed feed with instant speed changes (000's constant-speed G-code interpretation).
//!   Either is sampled every `dt` (000: 60 ms); z is ignored (000: prints under 10 mm tall).
//! - **Reach**: the horizontal distance from the base to the TCP. The base is the filtered TCP
//!   position plus a constant offset of length `r_nom` (000's nominal reach, the arm's extension
//!   at the print origin) pointing from the print towards the base: by default along −y, the base
//!   beside a job laid out along x, as in 000's Fig. 2B.
//! - **Base acceleration**: central second differences of the filtered samples; a_max and a_mean
//!   are the largest and the mean of |a| over the samples.
//! - **W_FF** (Eq. 1, ∫ m·s̈·ds): taken with the magnitude of the acceleration, Σ m·|a_k|·|Δs_k| —
//!   thrust spends fuel when braking as well as when speeding up (the signed integral is the
//!   change of kinetic energy, zero from rest to rest).

use std::path::{Path, PathBuf};

use nalgebra::{Vector2, Vector3};
use plotters::prelude::*;
use serde::Serialize;
use strand::config::{Config, locate};
use strand_core::Geometry;
use strand_core::arc_geometry;
use strand_core::{Segment, SegmentKind};
use strand_job::bed::BedTransform;
use strand_job::gcode::{GcodeOptions, parse_file};
use strand_job::timing::time_program;

use super::filter::Butterworth2;
use strand_cli::error::{Result, ToolError};

/// How the job's path becomes a time series.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Timing {
    /// The controller's own path engine (junction blending, jerk-limited time scaling).
    Controller,
    /// Each segment at its programmed feed (000's constant speed).
    Constant,
}

/// The TCP path sampled every `dt` (m, s, G-code frame).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TcpSeries {
    /// Sample period (s).
    pub dt: f64,
    /// TCP x (m).
    pub x: Vec<f64>,
    /// TCP y (m).
    pub y: Vec<f64>,
    /// The print's progress at each sample (m): path length since the job's first point — the
    /// end of its leading travel, where the controller's path starts — negative before it.
    pub s: Vec<f64>,
}

impl TcpSeries {
    /// Time of sample `k` (s).
    pub fn t(&self, k: usize) -> f64 {
        k as f64 * self.dt
    }

    /// Samples.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// True without samples.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// Samples a job's TCP path. `config` gives the path engine's limits and rate for
/// [`Timing::Controller`]; the job stays in its own (bed) frame.
pub(crate) fn sample_job(job: &Path, timing: Timing, dt: f64, config: &Config) -> Result<TcpSeries> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(ToolError::Plan(format!("--dt {dt}: must be positive")));
    }
    let name = job.display().to_string();
    let mut parser = parse_file(job, GcodeOptions::for_path(job))?.peekable();
    // strand_job::timing::time_program never ends on a program without a segment.
    if parser.peek().is_none() {
        return Err(ToolError::Plan(format!("{name}: no motion in the program")));
    }
    let mut series = TcpSeries { dt, ..TcpSeries::default() };
    // The controller's path starts at the end of a leading travel (its approach goes there); this
    // engine starts at the bed's origin. Progress counts from the same point in both.
    let lead_in = match parser.peek() {
        Some(Ok(g))
            if g.segment.kind == SegmentKind::Line
                && !g.segment.flags.contains(strand_core::SegmentFlags::EXTRUDE)
                && g.segment.filament == 0.0 =>
        {
            g.segment.end.norm()
        }
        _ => 0.0,
    };
    match timing {
        Timing::Controller => {
            let rate = config.controller.rate_hz;
            let mut tick: u64 = 0;
            let mut next = 0usize;
            let bed = BedTransform::flat();
            time_program(parser, &name, &config.path, &config.extruder, &bed, rate, |s| {
                let t = tick as f64 / rate;
                // Keep the tick nearest each multiple of dt (ticks at or after k·dt − half a tick).
                while t + 0.5 / rate >= next as f64 * dt {
                    series.x.push(s.position.x);
                    series.y.push(s.position.y);
                    series.s.push(s.s - lead_in);
                    next += 1;
                }
                tick += 1;
            })?;
        }
        Timing::Constant => {
            let mut segments = Vec::new();
            for g in parser {
                segments.push(g?.segment);
            }
            constant_speed(&segments, dt, &mut series);
            for s in &mut series.s {
                *s -= lead_in;
            }
        }
    }
    if series.len() <= super::filter::PAD {
        return Err(ToolError::Plan(format!(
            "{name}: {} samples at dt = {dt} s; the filter needs more than {}",
            series.len(),
            super::filter::PAD
        )));
    }
    Ok(series)
}

/// 000's constant-speed reading: every line and arc at its feed, dwells standing, from the origin.
fn constant_speed(segments: &[Segment], dt: f64, out: &mut TcpSeries) {
    let mut start = Vector3::zeros();
    let mut t0 = 0.0;
    let mut next = 0usize;
    let mut travelled = 0.0;
    let push = |p: &Vector3<f64>, s: f64, out: &mut TcpSeries| {
        out.x.push(p.x);
        out.y.push(p.y);
        out.s.push(s);
    };
    for s in segments {
        let (geometry, length, duration) = match s.kind {
            SegmentKind::Dwell => (None, 0.0, s.duration),
            SegmentKind::Heat => (None, 0.0, 0.0),
            SegmentKind::Line => {
                let d = s.end - start;
                let l = d.norm();
                let g = (l > 0.0).then(|| Geometry::Line { start, direction: d / l });
                (g, l, l / s.feed)
            }
            SegmentKind::Arc => match arc_geometry(&start, s) {
                Some(g) => {
                    let l = g.length((s.end - start).norm());
                    (Some(g), l, l / s.feed)
                }
                None => (None, 0.0, 0.0),
            },
        };
        while (next as f64) * dt < t0 + duration {
            let u = (next as f64 * dt - t0).max(0.0);
            let along = if geometry.is_some() { (u * s.feed).min(length) } else { 0.0 };
            let p = match &geometry {
                Some(g) => g.point(along, length).position,
                None => start,
            };
            push(&p, travelled + along, out);
            next += 1;
        }
        t0 += duration;
        travelled += length;
        if s.kind != SegmentKind::Dwell {
            start = s.end;
        }
    }
    // The last point, held for the sample that closes the job.
    push(&start, travelled, out);
}

/// Where the base sits relative to the print, and how far the arm may reach.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Reach {
    /// Nominal reach r_nom (m): the arm's horizontal extension at the print origin.
    pub r_nom_m: f64,
    /// Reach limit r_lim (m): Algorithm 1's threshold.
    pub reach_limit_m: f64,
    /// Direction from the base to the print (rad, from +x towards +y); π/2: the base on the −y side.
    pub direction_rad: f64,
}

impl Reach {
    /// The constant offset from the filtered TCP signal to the base (m).
    pub fn offset(&self) -> Vector2<f64> {
        -self.r_nom_m * Vector2::new(self.direction_rad.cos(), self.direction_rad.sin())
    }
}

/// A base trajectory for one cut-off and its figures (000 Fig. 4).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BasePlan {
    /// Cut-off frequency (Hz).
    pub fc_hz: f64,
    /// Largest horizontal distance base → TCP (m).
    pub r_max_m: f64,
    /// Largest base acceleration |a| (m/s²).
    pub a_max_mps2: f64,
    /// Mean base acceleration |a| (m/s²).
    pub a_mean_mps2: f64,
    /// Distance the base travels (m).
    pub base_distance_m: f64,
    /// Work of Eq. 1 for the given mass (J).
    pub w_ff_j: f64,
    /// Filtered TCP x, the base before the nominal-reach offset (m).
    #[serde(skip)]
    pub base_x: Vec<f64>,
    /// Filtered TCP y (m).
    #[serde(skip)]
    pub base_y: Vec<f64>,
}

/// Filters `tcp` at `fc_hz` and measures the result.
pub(crate) fn plan_at(tcp: &TcpSeries, fc_hz: f64, reach: &Reach, mass_kg: f64) -> Result<BasePlan> {
    let filter = Butterworth2::lowpass(fc_hz, 1.0 / tcp.dt)?;
    let base_x = filter.filtfilt(&tcp.x)?;
    let base_y = filter.filtfilt(&tcp.y)?;
    let offset = reach.offset();
    let mut r_max: f64 = 0.0;
    for k in 0..tcp.len() {
        let d = Vector2::new(tcp.x[k] - base_x[k] - offset.x, tcp.y[k] - base_y[k] - offset.y);
        r_max = r_max.max(d.norm());
    }
    let n = tcp.len();
    let dt2 = tcp.dt * tcp.dt;
    // |a| by central second differences at the inner samples; the ends take their neighbour's.
    let acc = |j: usize| {
        let j = j.clamp(1, n - 2);
        ((base_x[j + 1] - 2.0 * base_x[j] + base_x[j - 1]) / dt2).hypot((base_y[j + 1] - 2.0 * base_y[j] + base_y[j - 1]) / dt2)
    };
    let a: Vec<f64> = (0..n).map(acc).collect();
    let inner = &a[1..n - 1];
    let a_max = inner.iter().cloned().fold(0.0f64, f64::max);
    let a_sum: f64 = inner.iter().sum();
    let (mut distance, mut work) = (0.0, 0.0);
    for k in 1..n {
        let ds = (base_x[k] - base_x[k - 1]).hypot(base_y[k] - base_y[k - 1]);
        distance += ds;
        // |a| at the middle of the step: the mean of its two ends.
        work += mass_kg * 0.5 * (a[k - 1] + a[k]) * ds;
    }
    Ok(BasePlan {
        fc_hz,
        r_max_m: r_max,
        a_max_mps2: a_max,
        a_mean_mps2: a_sum / (n - 2) as f64,
        base_distance_m: distance,
        w_ff_j: work,
        base_x,
        base_y,
    })
}

/// Algorithm 1's outcome.
#[derive(Clone, Debug, PartialEq)]
pub struct Search {
    /// The plan at the lowest cut-off on the grid whose reach stays within the limit.
    pub plan: BasePlan,
    /// Cut-offs tried (the last one exceeded the limit unless `floor_reached`).
    pub steps: usize,
    /// True if the search reached the lowest positive cut-off on its grid without exceeding.
    pub floor_reached: bool,
}

/// Algorithm 1: from `fc_start` lower the cut-off by `fc_step` until the reach exceeds the limit
/// and keep the previous cut-off. An error if `fc_start` already exceeds it.
pub fn search(tcp: &TcpSeries, reach: &Reach, mass_kg: f64, fc_start: f64, fc_step: f64) -> Result<Search> {
    if !(fc_step.is_finite() && fc_step > 0.0) {
        return Err(ToolError::Plan(format!("--fc-step {fc_step}: must be positive")));
    }
    let mut best: Option<BasePlan> = None;
    // fc = fc_start − k·Δfc, computed from k so the grid does not drift with rounding; k + 1 tried.
    for k in 0usize.. {
        let fc = fc_start - k as f64 * fc_step;
        if fc <= fc_step * 1e-9 {
            let plan = best.ok_or_else(|| ToolError::Plan(format!("--fc-start {fc_start}: no positive cut-off on the grid")))?;
            return Ok(Search { plan, steps: k, floor_reached: true });
        }
        let steps = k + 1;
        let plan = plan_at(tcp, fc, reach, mass_kg)?;
        if plan.r_max_m > reach.reach_limit_m {
            return match best {
                Some(plan) => Ok(Search { plan, steps, floor_reached: false }),
                None => Err(ToolError::Plan(format!(
                    "--fc-start {fc_start} Hz already needs a reach of {:.1} mm, over --reach-limit {:.1} mm: raise --fc-start or the limit",
                    plan.r_max_m * 1e3,
                    reach.reach_limit_m * 1e3
                ))),
            };
        }
        best = Some(plan);
    }
    unreachable!("the loop returns")
}

/// The figures of 000 Fig. 4 over a grid of cut-offs.
pub fn sweep(tcp: &TcpSeries, reach: &Reach, mass_kg: f64, from: f64, to: f64, step: f64) -> Result<Vec<BasePlan>> {
    if !(from > 0.0 && to >= from && step > 0.0) {
        return Err(ToolError::Plan(format!("sweep {from}..{to} Hz by {step}: needs 0 < from ≤ to and step > 0")));
    }
    let n = ((to - from) / step + 1e-9).floor() as usize + 1;
    (0..n)
        .map(|k| {
            let mut p = plan_at(tcp, from + k as f64 * step, reach, mass_kg)?;
            p.base_x = Vec::new();
            p.base_y = Vec::new();
            Ok(p)
        })
        .collect()
}

/// Writes t, tcp_x, tcp_y, base_x, base_y, s (s, m; base before the nominal-reach offset; s the
/// print's progress, as in `--plan`).
pub(crate) fn write_csv(path: &Path, tcp: &TcpSeries, plan: &BasePlan) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| ToolError::Write { path: path.to_path_buf(), why: e.to_string() };
    let mut w = csv::Writer::from_path(path).map_err(|e| err(&e))?;
    w.write_record(["t", "tcp_x", "tcp_y", "base_x", "base_y", "s"]).map_err(|e| err(&e))?;
    for k in 0..tcp.len() {
        let row = [tcp.t(k), tcp.x[k], tcp.y[k], plan.base_x[k], plan.base_y[k], tcp.s.get(k).copied().unwrap_or(f64::NAN)];
        w.write_record(row.iter().map(|v| format!("{v:?}"))).map_err(|e| err(&e))?;
    }
    w.flush().map_err(|e| err(&e))
}

/// Writes the robot base's planned trajectory for strand-sim (`[flyer] trajectory`): t, base_x,
/// base_y (s, m, W). The base starts at the config's mount and moves as the filtered TCP does:
/// base(t) = mount + filtered(t − delay) − filtered(0), held at the mount for the first `delay`
/// seconds (the controller's approach to the first point; the job's clock starts after it).
pub(crate) fn write_trajectory(path: &Path, tcp: &TcpSeries, plan: &BasePlan, mount: [f64; 2], delay: f64) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| ToolError::Write { path: path.to_path_buf(), why: e.to_string() };
    let mut w = csv::Writer::from_path(path).map_err(|e| err(&e))?;
    w.write_record(["t", "base_x", "base_y"]).map_err(|e| err(&e))?;
    let (x0, y0) = (plan.base_x[0], plan.base_y[0]);
    if delay > 0.0 {
        w.write_record([0.0, mount[0], mount[1]].iter().map(|v| format!("{v:?}"))).map_err(|e| err(&e))?;
    }
    for k in 0..tcp.len() {
        let row = [tcp.t(k) + delay, mount[0] + plan.base_x[k] - x0, mount[1] + plan.base_y[k] - y0];
        if k == 0 && delay > 0.0 && row[0] <= 0.0 {
            continue;
        }
        w.write_record(row.iter().map(|v| format!("{v:?}"))).map_err(|e| err(&e))?;
    }
    w.flush().map_err(|e| err(&e))
}

/// Writes the base's plan by the print's progress for the service's `[base] plan_file`: s, base_x,
/// base_y (m of path from the job's first point; m, W). The base is at the config's mount when the
/// path starts and moves as the filtered TCP does from there: base(s) = mount + filtered(t(s)) −
/// filtered(t(0)), t(s) the first planned time the path reaches s. Where the planned path stands
/// (a dwell, the approach before it starts) no row is written: the plan holds the base while the
/// nozzle does.
pub(crate) fn write_plan(path: &Path, tcp: &TcpSeries, plan: &BasePlan, mount: [f64; 2]) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| ToolError::Write { path: path.to_path_buf(), why: e.to_string() };
    let Some(k0) = tcp.s.iter().position(|s| *s >= 0.0) else {
        return Err(ToolError::Plan("the job's path never starts: no plan to write".to_string()));
    };
    let (x0, y0) = (plan.base_x[k0], plan.base_y[k0]);
    let mut rows: Vec<[f64; 3]> = Vec::new();
    for k in k0..tcp.len() {
        // The first row at exactly 0: the plan starts at the job's first point.
        let s = if k == k0 { 0.0 } else { tcp.s[k] };
        if rows.last().is_some_and(|r| s <= r[0]) {
            continue;
        }
        rows.push([s, mount[0] + plan.base_x[k] - x0, mount[1] + plan.base_y[k] - y0]);
    }
    let rows = thin(&rows, PLAN_TOLERANCE_M);
    let mut w = csv::Writer::from_path(path).map_err(|e| err(&e))?;
    w.write_record(["s", "base_x", "base_y"]).map_err(|e| err(&e))?;
    for row in rows {
        w.write_record(row.iter().map(|v| format!("{v:?}"))).map_err(|e| err(&e))?;
    }
    w.flush().map_err(|e| err(&e))
}

/// How far the thinned plan may pass from the filtered one (m): far below the base's own error
/// (millimetres), and it makes the plan of the 100 cm truss tens of times shorter (it travels in
/// the service's config and in every log's).
const PLAN_TOLERANCE_M: f64 = 10e-6;

/// The rows a piecewise-linear reading in s needs to stay within `tolerance` of every row
/// (greedy: each kept row reaches as far as the rows between stay within it).
fn thin(rows: &[[f64; 3]], tolerance: f64) -> Vec<[f64; 3]> {
    if rows.len() <= 2 {
        return rows.to_vec();
    }
    let mut kept = vec![rows[0]];
    let mut a = 0;
    let mut b = 2;
    while b < rows.len() {
        let (ra, rb) = (rows[a], rows[b]);
        let within = rows[a + 1..b].iter().all(|r| {
            let u = (r[0] - ra[0]) / (rb[0] - ra[0]);
            (ra[1] + u * (rb[1] - ra[1]) - r[1]).hypot(ra[2] + u * (rb[2] - ra[2]) - r[2]) <= tolerance
        });
        if within {
            b += 1;
        } else {
            a = b - 1;
            kept.push(rows[a]);
            b = a + 2;
        }
    }
    kept.push(rows[rows.len() - 1]);
    kept
}

/// 000 Fig. 4 as a PNG: a_max, r_max and W_FF against f_c, the chosen f_c marked.
pub(crate) fn plot_sweep(path: &Path, rows: &[BasePlan], reach: &Reach, chosen: Option<f64>) -> Result<()> {
    strand::check::plot::register_font()?;
    let e = |e: &dyn std::fmt::Display| ToolError::Plot { path: path.to_path_buf(), why: e.to_string() };
    let root = BitMapBackend::new(path, (1500, 450)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let panels = root.split_evenly((1, 3));
    let fc: Vec<f64> = rows.iter().map(|r| r.fc_hz * 1e3).collect();
    let (lo, hi) = (fc.first().copied().unwrap_or(0.0), fc.last().copied().unwrap_or(1.0).max(fc[0] + 1e-6));
    let series: [(&str, &str, Vec<f64>, Option<f64>); 3] = [
        ("A: max base acceleration", "a_max (mm/s²)", rows.iter().map(|r| r.a_max_mps2 * 1e3).collect(), None),
        ("B: max reach", "r_max (mm)", rows.iter().map(|r| r.r_max_m * 1e3).collect(), Some(reach.reach_limit_m * 1e3)),
        ("C: work W_FF", "W_FF (mJ)", rows.iter().map(|r| r.w_ff_j * 1e3).collect(), None),
    ];
    for (area, (title, label, ys, limit)) in panels.iter().zip(series) {
        let top = ys.iter().cloned().chain(limit).fold(0.0f64, f64::max) * 1.05 + 1e-9;
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 20))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(lo..hi, 0.0..top)
            .map_err(|x| e(&x))?;
        chart.configure_mesh().x_desc("f_c (mHz)").y_desc(label).draw().map_err(|x| e(&x))?;
        chart.draw_series(LineSeries::new(fc.iter().cloned().zip(ys.iter().cloned()), BLUE.stroke_width(2))).map_err(|x| e(&x))?;
        if let Some(l) = limit {
            chart.draw_series(LineSeries::new([(lo, l), (hi, l)], RED.stroke_width(1))).map_err(|x| e(&x))?;
        }
        if let Some(c) = chosen {
            chart.draw_series(LineSeries::new([(c * 1e3, 0.0), (c * 1e3, top)], GREEN.stroke_width(1))).map_err(|x| e(&x))?;
        }
    }
    root.present().map_err(|x| e(&x))
}

/// 000 Fig. 5 as a PNG: the TCP path in x–y with the base path (filtered, offset removed) over it.
pub(crate) fn plot_paths(path: &Path, tcp: &TcpSeries, plan: &BasePlan) -> Result<()> {
    strand::check::plot::register_font()?;
    let e = |e: &dyn std::fmt::Display| ToolError::Plot { path: path.to_path_buf(), why: e.to_string() };
    let root = BitMapBackend::new(path, (1400, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (panel_xy, panel_t) = root.split_horizontally(700);
    let mm = |v: &[f64]| v.iter().map(|x| x * 1e3).collect::<Vec<_>>();
    let (tx, ty, bx, by) = (mm(&tcp.x), mm(&tcp.y), mm(&plan.base_x), mm(&plan.base_y));
    let span = |a: &[f64], b: &[f64]| {
        let lo = a.iter().chain(b).cloned().fold(f64::INFINITY, f64::min);
        let hi = a.iter().chain(b).cloned().fold(f64::NEG_INFINITY, f64::max);
        (lo - 5.0)..(hi + 5.0)
    };
    let mut c = ChartBuilder::on(&panel_xy)
        .caption(format!("x–y, f_c = {:.2} mHz", plan.fc_hz * 1e3), ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(span(&tx, &bx), span(&ty, &by))
        .map_err(|x| e(&x))?;
    c.configure_mesh().x_desc("x (mm)").y_desc("y (mm)").draw().map_err(|x| e(&x))?;
    c.draw_series(LineSeries::new(tx.iter().cloned().zip(ty.iter().cloned()), BLACK.mix(0.4)))
        .map_err(|x| e(&x))?
        .label("TCP (G-code)")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
    c.draw_series(LineSeries::new(bx.iter().cloned().zip(by.iter().cloned()), RED.stroke_width(2)))
        .map_err(|x| e(&x))?
        .label("base (filtered)")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
    c.configure_series_labels().border_style(BLACK).background_style(WHITE).draw().map_err(|x| e(&x))?;
    let t_end = tcp.t(tcp.len() - 1);
    let mut c = ChartBuilder::on(&panel_t)
        .caption("x(t)", ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_end, span(&tx, &bx))
        .map_err(|x| e(&x))?;
    c.configure_mesh().x_desc("t (s)").y_desc("x (mm)").draw().map_err(|x| e(&x))?;
    c.draw_series(LineSeries::new(tx.iter().enumerate().map(|(k, v)| (tcp.t(k), *v)), BLACK.mix(0.4))).map_err(|x| e(&x))?;
    c.draw_series(LineSeries::new(bx.iter().enumerate().map(|(k, v)| (tcp.t(k), *v)), RED.stroke_width(2))).map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))
}

/// `strand-plan base`.
#[derive(Clone, Debug)]
pub struct BaseOptions {
    /// The G-code job (its frame: x along the job, the base beside it).
    pub job: PathBuf,
    /// Nominal reach r_nom (m): the arm's extension at the print origin (000: 230 mm).
    pub r_nom: f64,
    /// Reach limit (m): Algorithm 1 stops when the reach would exceed it (000: 270 mm).
    pub reach_limit: f64,
    /// Direction from the base to the print (degrees from +x towards +y; 90: the base on the −y side).
    pub direction_deg: f64,
    /// Sample period of the trajectory (s; 000: 60 ms, its position update rate).
    pub dt: f64,
    /// First cut-off tried (Hz).
    pub fc_start: f64,
    /// Step Δf_c by which the cut-off is lowered (Hz).
    pub fc_step: f64,
    /// Base mass for W_FF (kg; the sim's free flyer).
    pub mass: f64,
    /// How the path becomes a time series.
    pub timing: Timing,
    /// Service config whose [path] limits and rate time the job (`--timing controller`): a file or
    /// a NAME; default: free-flyer.toml by the search order ($STRAND_CONFIG_DIR, ./config,
    /// <prefix>/share/strand/config, the built-in copy).
    pub config: Option<PathBuf>,
    /// Print one JSON object.
    pub json: bool,
    /// Write t, tcp_x, tcp_y, base_x, base_y, s (s, m; s the print's progress) at the chosen cut-off.
    pub csv: Option<PathBuf>,
    /// Write the base trajectory for strand-sim (t, base_x, base_y in W, from the --config's mount).
    pub trajectory: Option<PathBuf>,
    /// With --trajectory: hold the mount this long before following the job (s; the approach).
    pub start_delay: f64,
    /// Write the base's plan by progress for the service's `[base] plan_file` (s, base_x, base_y).
    pub plan: Option<PathBuf>,
    /// Also tabulate a_max, r_max and W_FF over cut-offs from --fc-step to --fc-start (000 Fig. 4).
    pub sweep: bool,
    /// PNG: with --sweep 000's Fig. 4, otherwise the paths of Fig. 5 at the chosen cut-off.
    pub png: Option<PathBuf>,
}

/// What `--json` prints.
#[derive(Serialize)]
struct Summary<'a> {
    #[serde(flatten)]
    plan: &'a BasePlan,
    steps: usize,
    floor_reached: bool,
    samples: usize,
    duration_s: f64,
    timing: Timing,
    #[serde(flatten)]
    reach: Reach,
    mass_kg: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    sweep: Option<&'a [BasePlan]>,
}

/// Runs `strand-plan base`.
pub fn run(args: &BaseOptions) -> Result<()> {
    super::positive("r-nom", args.r_nom)?;
    super::positive("reach-limit", args.reach_limit)?;
    super::positive("mass", args.mass)?;
    super::positive("fc-start", args.fc_start)?;
    if args.reach_limit < args.r_nom {
        return Err(ToolError::Plan(format!("--reach-limit {} m is below --r-nom {} m", args.reach_limit, args.r_nom)));
    }
    let config = locate::service_config_or(args.config.as_deref(), "free-flyer.toml").and_then(|c| Config::load(&c))?;
    let tcp = sample_job(&args.job, args.timing, args.dt, &config)?;
    let reach = Reach { r_nom_m: args.r_nom, reach_limit_m: args.reach_limit, direction_rad: args.direction_deg.to_radians() };
    let found = search(&tcp, &reach, args.mass, args.fc_start, args.fc_step)?;
    let rows = if args.sweep { Some(sweep(&tcp, &reach, args.mass, args.fc_step, args.fc_start, args.fc_step)?) } else { None };
    if let Some(p) = &args.csv {
        write_csv(p, &tcp, &found.plan)?;
    }
    if let Some(p) = &args.trajectory {
        if !(args.start_delay.is_finite() && args.start_delay >= 0.0) {
            return Err(ToolError::Plan(format!("--start-delay {}: must be ≥ 0", args.start_delay)));
        }
        let m = config.base.mount_xyz;
        write_trajectory(p, &tcp, &found.plan, [m[0], m[1]], args.start_delay)?;
    }
    if let Some(p) = &args.plan {
        let m = config.base.mount_xyz;
        write_plan(p, &tcp, &found.plan, [m[0], m[1]])?;
    }
    if let Some(p) = &args.png {
        match &rows {
            Some(rows) => plot_sweep(p, rows, &reach, Some(found.plan.fc_hz))?,
            None => plot_paths(p, &tcp, &found.plan)?,
        }
    }
    let duration = tcp.t(tcp.len() - 1);
    if args.json {
        let s = Summary {
            plan: &found.plan,
            steps: found.steps,
            floor_reached: found.floor_reached,
            samples: tcp.len(),
            duration_s: duration,
            timing: args.timing,
            reach,
            mass_kg: args.mass,
            sweep: rows.as_deref(),
        };
        println!("{}", serde_json::to_string(&s).expect("a plan serialises"));
        return Ok(());
    }
    let p = &found.plan;
    println!("{} ({:?} timing, {} samples of {} s, {:.1} s)", args.job.display(), args.timing, tcp.len(), args.dt, duration);
    println!(
        "  f_c            {:.3} mHz  (Algorithm 1: {} steps of {:.3} mHz from {:.3} mHz{})",
        p.fc_hz * 1e3,
        found.steps,
        args.fc_step * 1e3,
        args.fc_start * 1e3,
        if found.floor_reached { "; the reach never exceeded the limit" } else { "" }
    );
    println!("  r_max          {:.1} mm  (r_nom {:.0} mm, limit {:.0} mm)", p.r_max_m * 1e3, args.r_nom * 1e3, args.reach_limit * 1e3);
    println!("  a_max          {:.4} mm/s²", p.a_max_mps2 * 1e3);
    println!("  a_mean         {:.4} mm/s²", p.a_mean_mps2 * 1e3);
    println!("  base distance  {:.3} m", p.base_distance_m);
    println!("  W_FF           {:.3} mJ  (m = {} kg)", p.w_ff_j * 1e3, args.mass);
    if let Some(rows) = &rows {
        println!("  {:>9} {:>9} {:>12} {:>12} {:>10} {:>10}", "f_c mHz", "r_max mm", "a_max mm/s²", "a_mean mm/s²", "dist m", "W_FF mJ");
        for r in rows {
            println!(
                "  {:>9.3} {:>9.1} {:>12.4} {:>12.4} {:>10.3} {:>10.3}",
                r.fc_hz * 1e3,
                r.r_max_m * 1e3,
                r.a_max_mps2 * 1e3,
                r.a_mean_mps2 * 1e3,
                r.base_distance_m,
                r.w_ff_j * 1e3
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reach(limit: f64) -> Reach {
        Reach { r_nom_m: 0.23, reach_limit_m: limit, direction_rad: std::f64::consts::FRAC_PI_2 }
    }

    /// x(t): out and back along 1 m at 3.33 mm/s, y fixed: a caricature of a 1D truss.
    #[test]
    fn a_thinned_plan_keeps_within_its_tolerance_with_far_fewer_rows() {
        // A slow sine of the base along 2 m of path, a row every millimetre.
        let rows: Vec<[f64; 3]> = (0..2000)
            .map(|k| {
                let s = k as f64 * 1e-3;
                [s, 0.05 * (s * 3.0).sin(), 0.02 * s]
            })
            .collect();
        let kept = thin(&rows, 10e-6);
        assert!(kept.len() < rows.len() / 10, "{} of {} rows", kept.len(), rows.len());
        assert_eq!((kept[0], kept[kept.len() - 1]), (rows[0], rows[1999]));
        for r in &rows {
            let j = kept.iter().position(|k| k[0] >= r[0]).unwrap();
            if j == 0 {
                continue;
            }
            let (a, b) = (kept[j - 1], kept[j]);
            let u = (r[0] - a[0]) / (b[0] - a[0]);
            let e = (a[1] + u * (b[1] - a[1]) - r[1]).hypot(a[2] + u * (b[2] - a[2]) - r[2]);
            assert!(e <= 10e-6 + 1e-12, "{e} at s = {}", r[0]);
        }
    }

    fn shuttle(dt: f64) -> TcpSeries {
        let v = 3.33e-3;
        let half = 1.0 / v;
        let n = (2.0 * half / dt) as usize;
        let x = (0..n).map(|k| {
            let t = k as f64 * dt;
            if t < half { v * t } else { 1.0 - v * (t - half) }
        });
        TcpSeries { dt, x: x.collect(), y: vec![0.02; n], s: Vec::new() }
    }

    #[test]
    fn lower_cut_offs_reach_further_and_spend_less() {
        let tcp = shuttle(0.06);
        let hi = plan_at(&tcp, 0.01, &reach(1.0), 266.7).unwrap();
        let lo = plan_at(&tcp, 0.002, &reach(1.0), 266.7).unwrap();
        assert!(lo.r_max_m > hi.r_max_m + 0.01, "{} vs {}", lo.r_max_m, hi.r_max_m);
        assert!(lo.base_distance_m < hi.base_distance_m);
        assert!(lo.a_max_mps2 < hi.a_max_mps2);
        assert!(lo.w_ff_j < hi.w_ff_j);
        // The base never leaves the span of the job by more than the filter's overshoot.
        assert!(hi.base_x.iter().all(|x| *x > -0.05 && *x < 1.05));
        // y is constant: the reach is at least r_nom and the base y equals it.
        assert!(hi.base_y.iter().all(|y| (y - 0.02).abs() < 1e-9));
        assert!(hi.r_max_m >= 0.23);
    }

    #[test]
    fn algorithm_1_keeps_the_last_cut_off_within_the_limit() {
        let tcp = shuttle(0.06);
        let r = reach(0.27);
        let found = search(&tcp, &r, 266.7, 0.01, 2e-4).unwrap();
        assert!(!found.floor_reached);
        assert!(found.plan.r_max_m <= 0.27);
        // One step lower exceeds the limit.
        let below = plan_at(&tcp, found.plan.fc_hz - 2e-4, &r, 266.7).unwrap();
        assert!(below.r_max_m > 0.27, "{}", below.r_max_m);
        // The grid: f_c = start − k·step exactly.
        let k = (0.01 - found.plan.fc_hz) / 2e-4;
        assert!((k - k.round()).abs() < 1e-9 && found.steps == k.round() as usize + 2, "{k} {}", found.steps);
        // A start that already exceeds is an error naming the flag; a limit never reached stops at the floor.
        let e = search(&tcp, &reach(0.2301), 266.7, 0.01, 2e-4).unwrap_err().to_string();
        assert!(e.contains("--fc-start"), "{e}");
        let all = search(&tcp, &reach(10.0), 266.7, 0.001, 2e-4).unwrap();
        assert!(all.floor_reached && (all.plan.fc_hz - 2e-4).abs() < 1e-12);
    }

    #[test]
    fn constant_timing_moves_at_the_feed() {
        let seg = |x: f64, feed: f64| Segment { end: Vector3::new(x, 0.0, 0.0), feed, ..Segment::default() };
        let mut out = TcpSeries { dt: 0.1, ..TcpSeries::default() };
        constant_speed(&[seg(0.01, 0.01), seg(0.03, 0.02)], 0.1, &mut out);
        // 1 s at 10 mm/s, then 1 s at 20 mm/s: 20 samples and the end point.
        assert_eq!(out.len(), 21);
        assert!((out.x[5] - 0.005).abs() < 1e-12 && (out.x[15] - 0.02).abs() < 1e-12 && (out.x[20] - 0.03).abs() < 1e-12, "{:?}", out.x);
    }

    #[test]
    fn work_is_mass_times_acceleration_over_distance() {
        // A base on a parabola x = a t²/2 has |a| constant: W = m·a·distance.
        let dt = 0.05;
        let a = 1e-3;
        let n = 2000;
        let tcp = TcpSeries { dt, x: (0..n).map(|k| 0.5 * a * (k as f64 * dt).powi(2)).collect(), y: vec![0.0; n], s: Vec::new() };
        // A cut-off far above the signal's content leaves the parabola as it is.
        let p = plan_at(&tcp, 4.0, &reach(100.0), 10.0).unwrap();
        let dist = *tcp.x.last().unwrap();
        assert!((p.base_distance_m - dist).abs() < 1e-6 * dist);
        // Within 0.5 %: the odd edge padding bends the last few samples (the parabola's own
        // continuation would curve the other way), where the base is fastest.
        assert!((p.w_ff_j - 10.0 * a * dist).abs() < 5e-3 * 10.0 * a * dist, "{} vs {}", p.w_ff_j, 10.0 * a * dist);
        assert!((p.a_mean_mps2 - a).abs() < 5e-3 * a, "{} {}", p.a_mean_mps2, p.a_max_mps2);
    }
}
