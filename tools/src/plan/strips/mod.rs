//! `strand-plan strips`: 000's splitting of a planar job into strips a manipulator can reach
//! (Section 3.2, Eqs. 2-4, Figs. 6-9; the planar truss of Section 4.3 and Fig. 13).
//!
//! This module owns the offline transformation of one G-code job, larger than the arm's reach in
//! two directions, into one job printed strip by strip: reading the extruding lines per layer,
//! cutting them into strips of width W along an axis with the staggered joint of Fig. 6, checking
//! Eqs. 2-4, chaining each strip's lines per layer into continuous paths (Fig. 8), and writing the
//! result as G-code (plus a JSON report and a PNG like Fig. 13). It exists because a mobile base
//! whose arm reaches R across its track can only print a band of width ≤ R/2 without driving over
//! what it printed; the paper prints every layer of a strip before the next strip.
//!
//! # Reading of 000 (where the paper leaves room)
//!
//! - **Strips.** Strip 1 starts at the origin (the part's smallest coordinate along `axis`, or
//!   `--origin`) and the strips follow in increasing coordinate; they are printed in that order.
//!   A point exactly on a boundary belongs to the strip printed first, as 000 says of lines lying on
//!   one ("exactly" = within [`BOUNDARY_EPS`], 1 nm, so 93 mm typed in G-code and 0.05 + 0.043 m
//!   summed in floating point are the same boundary).
//! - **The joint (Fig. 6).** "The first layer of the second strip overlaps the first layer of the
//!   first strip. This is continued until the final layer, where no overlapping takes place, to
//!   ensure a constant height", and "the boundaries are moved by the desired overlap length for each
//!   layer". We read: on layer i (1-based) of a job of N layers, every boundary between two strips
//!   moves by (N − i)·L **towards the strip printed second**. Layer 1 of strip k reaches (N − 1)·L
//!   into strip k + 1's band, layer 2 (N − 2)·L, …, and layer N ends at the nominal boundary: the
//!   earlier strip ends in a staircase going down and out, every step on the layer below it. The
//!   later strip then fills the steps: its layer i + 1 lies on the earlier strip's layer i for a
//!   length L, so the two are bonded from the first layer on, and the top layers meet flush
//!   ("no overlapping takes place, to ensure a constant height"). The opposite direction (the later
//!   strip's low layers reaching back into the earlier strip) cannot be printed: the earlier strip's
//!   upper layers would overhang by L per layer, and the later strip's lower layers would have to be
//!   laid under them. Either way the arm printing one strip covers W plus up to (N − 1)·L < W of the
//!   neighbouring band, which is Eq. 2's W ≤ R/2; Eq. 3, N ≤ ⌊W/L⌋, keeps the deepest step, (N − 1)·L,
//!   at least L short of the next strip's far edge, so no layer of any strip is narrower than L. The
//!   outer edges of the part (the origin and the far end) do not move.
//! - **Eqs. 2-4** are checked per strip, with the strip's nominal width (for unequal strips the
//!   widest decides Eq. 2 and the narrowest Eq. 3); N is the number of layers of the job that
//!   extrude. The floors get a relative slack of 1e-9 so that decimal inputs whose quotient is an
//!   integer (0.043 / 0.01075 = 4) are not rounded down. All violations are reported together.
//! - **Chaining (Figs. 8, 9).** Each layer of each strip starts from the nominal position
//!   (`--start`, default the G-code origin): the line with the endpoint closest to it (in x-y)
//!   begins the first path; a line whose endpoint lies within the join tolerance of the current end
//!   continues the path (reversed if need be); otherwise a new path starts at the endpoint nearest the
//!   current end. 000 leaves the choice among several matches open; we take the line that follows
//!   in the job when it matches (the slicer's own continuation), else the nearest, then the earliest
//!   in the job, then a line's start before its end (deterministic). A slicer's open loop (a
//!   perimeter that stops short of its start by the seam gap) entered at a vertex other than its
//!   ends becomes two paths: Fig. 8 starts at the nearest *endpoint*, and every vertex is one.
//! - **Skirts.** A slicer's skirt or brim (a `;TYPE:` containing "skirt" or "brim") is not part of
//!   the structure and would move the part's origin, so it is dropped unless `--keep-skirt`; the
//!   report says how much was dropped. Conservation of filament is over the lines kept.
//! - **Arcs** are flattened to chords whose sagitta is at most `--arc-tolerance` (default 10 µm),
//!   with the arc's filament shared in proportion to chord length.
//!
//! Units are SI inside (m, m/s, m of filament); the G-code written is in mm with relative
//! extrusion (M83), numbers to 1e-9 mm, so the filament read back equals the filament read in to
//! rounding.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::BufRead;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use plotters::prelude::*;
use serde::Serialize;
use serde_json::json;
use strand::core::{Geometry, Segment, SegmentKind, arc_geometry};
use strand_job::gcode::{GcodeOptions, Parser, parse_file};

/// Two coordinates closer than this (m) along the split axis are the same: a line this close to a
/// boundary lies on it, and a line is not cut within this distance of its ends.
pub const BOUNDARY_EPS: f64 = 1e-9;

/// Relative slack on the floors of Eqs. 3 and 4.
const FLOOR_SLACK: f64 = 1e-9;

/// A path move shorter than this (m) is folded into its neighbour when writing (the G-code written
/// keeps 1e-12 m, and the parser would read a shorter move as an extrusion without motion).
const MIN_MOVE: f64 = 1e-11;

/// Direction the strips are measured along.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
}

impl Axis {
    /// Index of the coordinate in a point.
    pub fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Axis::X => "x",
            Axis::Y => "y",
        }
    }
}

/// One extruding straight line (m, G-code frame).
#[derive(Clone, Debug, PartialEq)]
pub struct Line {
    /// Start point.
    pub a: Vector3<f64>,
    /// End point.
    pub b: Vector3<f64>,
    /// Filament pushed along it (m of filament, > 0).
    pub filament: f64,
    /// Programmed speed (m/s).
    pub feed: f64,
    /// Source line in the input G-code (1-based).
    pub source_line: usize,
}

impl Line {
    /// Length (m).
    pub fn length(&self) -> f64 {
        (self.b - self.a).norm()
    }

    /// The same line traversed the other way.
    pub fn reversed(&self) -> Line {
        Line { a: self.b, b: self.a, ..self.clone() }
    }
}

/// The extruding lines of one layer, in job order.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// Nominal height (m): the `;Z:` marker if the slicer wrote one, else the first line's end z.
    pub z: f64,
    pub lines: Vec<Line>,
}

/// What was read from a job.
#[derive(Clone, Debug, PartialEq)]
pub struct Job {
    /// File name, for reports.
    pub name: String,
    /// Layers in the order they first appear.
    pub layers: Vec<Layer>,
    /// `"tags"` when the slicer's layer markers grouped the lines, `"z"` when their height did.
    pub layer_source: &'static str,
    /// Arcs flattened to chords.
    pub arcs_flattened: usize,
    /// Skirt/brim lines dropped, and their filament (m).
    pub skirt_lines: usize,
    pub skirt_filament: f64,
}

impl Job {
    pub fn lines(&self) -> impl Iterator<Item = &Line> {
        self.layers.iter().flat_map(|l| l.lines.iter())
    }

    /// Filament over all kept lines (m).
    pub fn filament(&self) -> f64 {
        self.lines().map(|l| l.filament).sum()
    }

    /// Extruded path length over all kept lines (m).
    pub fn path_length(&self) -> f64 {
        self.lines().map(Line::length).sum()
    }
}

/// How to read a job.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReadOptions {
    /// Largest sagitta (m) of the chords replacing an arc.
    pub arc_tolerance: f64,
    /// Keep skirt and brim lines.
    pub keep_skirt: bool,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions { arc_tolerance: 1e-5, keep_skirt: false }
    }
}

fn is_skirt(feature: Option<&str>) -> bool {
    feature.is_some_and(|f| {
        let f = f.to_ascii_lowercase();
        f.contains("skirt") || f.contains("brim")
    })
}

/// Reads the extruding lines of a job, grouped per layer (by the slicer's layer markers if every kept
/// line has one, else by the height of the line's end, to 1 µm). Errors name file and line.
pub fn read_job<R: BufRead>(parser: &mut Parser<R>, name: &str, options: &ReadOptions) -> Result<Job, String> {
    let mut start = GcodeOptions::default().start;
    let mut raw: Vec<(Option<i32>, Option<f64>, Line)> = Vec::new();
    let (mut arcs, mut skirt_lines, mut skirt_filament) = (0usize, 0usize, 0.0);
    for item in parser.by_ref() {
        let g = item.map_err(|e| e.to_string())?;
        let s = &g.segment;
        let from = start;
        start = s.end;
        if !s.extrudes() {
            continue;
        }
        if !options.keep_skirt && is_skirt(g.tags.feature.as_deref()) {
            skirt_lines += 1;
            skirt_filament += s.filament;
            continue;
        }
        let tag = (g.tags.layer, g.tags.z_marker);
        match s.kind {
            SegmentKind::Line => {
                raw.push((tag.0, tag.1, Line { a: from, b: s.end, filament: s.filament, feed: s.feed, source_line: g.line }))
            }
            SegmentKind::Arc => {
                arcs += 1;
                let points = flatten_arc(&from, s, options.arc_tolerance)
                    .map_err(|e| format!("{name}:{}: {e} (--arc-tolerance {} m)", g.line, options.arc_tolerance))?;
                let mut prev = from;
                let chords: Vec<(Vector3<f64>, Vector3<f64>)> = points
                    .iter()
                    .map(|p| {
                        let c = (prev, *p);
                        prev = *p;
                        c
                    })
                    .collect();
                let total: f64 = chords.iter().map(|(a, b)| (b - a).norm()).sum();
                let mut given = 0.0;
                for (k, (a, b)) in chords.iter().enumerate() {
                    let filament = if k + 1 == chords.len() { s.filament - given } else { s.filament * (b - a).norm() / total };
                    given += filament;
                    raw.push((tag.0, tag.1, Line { a: *a, b: *b, filament, feed: s.feed, source_line: g.line }));
                }
            }
            SegmentKind::Dwell => {}
        }
    }
    if raw.is_empty() {
        return Err(format!(
            "{name}: no extruding lines{}",
            if skirt_lines > 0 { format!(" besides {skirt_lines} skirt/brim lines (--keep-skirt keeps them)") } else { String::new() }
        ));
    }
    let by_tag = raw.iter().all(|r| r.0.is_some());
    let mut index: HashMap<i64, usize> = HashMap::new();
    let mut layers: Vec<Layer> = Vec::new();
    for (tag, z_marker, line) in raw {
        let key = if by_tag { i64::from(tag.expect("checked")) } else { (line.b.z * 1e6).round() as i64 };
        let k = *index.entry(key).or_insert_with(|| {
            layers.push(Layer { z: if by_tag { z_marker.unwrap_or(line.b.z) } else { line.b.z }, lines: Vec::new() });
            layers.len() - 1
        });
        layers[k].lines.push(line);
    }
    Ok(Job {
        name: name.to_string(),
        layers,
        layer_source: if by_tag { "tags" } else { "z" },
        arcs_flattened: arcs,
        skirt_lines,
        skirt_filament,
    })
}

/// Points after `start` along an arc segment, ending exactly at its end, such that each chord's
/// sagitta is at most `tolerance` (and each chord spans at most a quarter turn).
pub fn flatten_arc(start: &Vector3<f64>, s: &Segment, tolerance: f64) -> Result<Vec<Vector3<f64>>, String> {
    if tolerance.is_nan() || tolerance <= 0.0 {
        return Err("the arc tolerance must be positive".into());
    }
    // The core's geometry of the arc (the one the path engine runs): equal steps of θ along it.
    let Some(geometry) = arc_geometry(start, s) else {
        return Ok(vec![s.end]);
    };
    let Geometry::Arc { radius, radius_rate, sweep, .. } = geometry else { unreachable!("arc_geometry gives an arc") };
    let r = radius.max(radius + radius_rate * sweep);
    let step =
        if tolerance >= r { std::f64::consts::FRAC_PI_2 } else { (2.0 * (1.0 - tolerance / r).acos()).min(std::f64::consts::FRAC_PI_2) };
    let count = (sweep / step).ceil().max(1.0);
    if count > 1e6 {
        return Err(format!("an arc of radius {r} m would need {count} chords"));
    }
    let count = count as usize;
    let length = geometry.length(0.0);
    let mut points = Vec::with_capacity(count);
    for j in 1..count {
        let f = j as f64 / count as f64;
        points.push(geometry.point(length * f, length).position);
    }
    points.push(s.end);
    Ok(points)
}

/// Strip widths: all equal (as many strips as the part needs) or given one by one.
#[derive(Clone, Debug, PartialEq)]
pub enum Widths {
    Uniform(f64),
    List(Vec<f64>),
}

/// What to split and how.
#[derive(Clone, Debug, PartialEq)]
pub struct StripSpec {
    pub axis: Axis,
    pub widths: Widths,
    /// Where strip 1 starts (m, along `axis`); None: the part's smallest coordinate.
    pub origin: Option<f64>,
    /// L (m).
    pub overlap: f64,
    /// R (m).
    pub reach: f64,
    /// Nominal position (x, y; m) each layer's chaining starts from.
    pub start: [f64; 2],
    /// Endpoints closer than this (m) continue a path.
    pub join_tolerance: f64,
}

/// Eq. 2 for the widest strip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Eq2 {
    pub strip: usize,
    pub width_m: f64,
    pub half_reach_m: f64,
    pub ok: bool,
}

/// Eq. 3 for one strip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Eq3 {
    pub strip: usize,
    pub width_m: f64,
    /// ⌊W/L⌋.
    pub max_layers: u64,
    pub ok: bool,
}

/// Eq. 4.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Eq4 {
    /// ⌊R/(2L)⌋.
    pub max_layers: u64,
    pub ok: bool,
}

/// The checks of Eqs. 2-4.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Checks {
    /// N: layers of the job.
    pub layers: usize,
    pub eq2: Eq2,
    pub eq3: Vec<Eq3>,
    pub eq4: Eq4,
}

fn floor_ratio(a: f64, b: f64) -> u64 {
    ((a / b) * (1.0 + FLOOR_SLACK)).floor().max(0.0) as u64
}

/// Evaluates Eqs. 2-4 for strips of nominal `widths`, N = `layers`, L = `overlap`, R = `reach`.
/// Err lists every violated equation with its numbers and strip (1-based).
pub fn check_equations(widths: &[f64], layers: usize, overlap: f64, reach: f64) -> Result<Checks, String> {
    let (widest, width) = widths.iter().copied().enumerate().fold((0, f64::NEG_INFINITY), |m, (k, w)| if w > m.1 { (k, w) } else { m });
    let half = reach / 2.0;
    let eq2 = Eq2 { strip: widest + 1, width_m: width, half_reach_m: half, ok: width <= half * (1.0 + FLOOR_SLACK) };
    let eq3: Vec<Eq3> = widths
        .iter()
        .enumerate()
        .map(|(k, &w)| {
            let max = floor_ratio(w, overlap);
            Eq3 { strip: k + 1, width_m: w, max_layers: max, ok: layers as u64 <= max }
        })
        .collect();
    let max4 = floor_ratio(reach, 2.0 * overlap);
    let eq4 = Eq4 { max_layers: max4, ok: layers as u64 <= max4 };
    let mut errors = Vec::new();
    if !eq2.ok {
        errors.push(format!(
            "Eq. 2 (W ≤ R/2) violated: strip {} is W = {} m wide, more than --reach {} m / 2 = {} m",
            eq2.strip, eq2.width_m, reach, half
        ));
    }
    for e in eq3.iter().filter(|e| !e.ok) {
        errors.push(format!(
            "Eq. 3 (N ≤ ⌊W/L⌋) violated: strip {} (W = {} m) with --overlap {} m allows ⌊{}/{}⌋ = {} layers, the job has N = {layers}",
            e.strip, e.width_m, overlap, e.width_m, overlap, e.max_layers
        ));
    }
    if !eq4.ok {
        errors.push(format!(
            "Eq. 4 (N ≤ ⌊R/(2L)⌋) violated: --reach {reach} m and --overlap {overlap} m allow ⌊{reach}/(2·{overlap})⌋ = {} layers, the job has N = {layers}",
            eq4.max_layers
        ));
    }
    let checks = Checks { layers, eq2, eq3, eq4 };
    if errors.is_empty() { Ok(checks) } else { Err(errors.join("; ")) }
}

/// The strip boundaries on layer `layer` (0-based) of `layers`: `nominal` (origin, the boundaries
/// between strips, the far end; ascending) with every interior boundary moved by
/// (layers − 1 − layer)·`overlap` away from the origin (towards the strip printed second). The top
/// layer keeps the nominal boundaries.
pub fn layer_bounds(nominal: &[f64], layer: usize, layers: usize, overlap: f64) -> Vec<f64> {
    let shift = (layers - 1 - layer) as f64 * overlap;
    let last = nominal.len() - 1;
    nominal.iter().enumerate().map(|(k, &b)| if k == 0 || k == last { b } else { b + shift }).collect()
}

/// The strip (0-based) of a piece whose largest coordinate along the axis is `max`: one past the
/// number of interior boundaries it passes by more than [`BOUNDARY_EPS`]; so a piece lying on a
/// boundary, or ending on it, belongs to the strip below (printed first).
fn strip_of(max: f64, interior: &[f64]) -> usize {
    interior.iter().filter(|&&b| max > b + BOUNDARY_EPS).count()
}

/// Cuts `line` at the interior boundaries it crosses (by more than [`BOUNDARY_EPS`] on each side)
/// and returns each piece with its strip (0-based). A cut point lies exactly on the boundary along
/// `axis`; its other coordinates (z included) are interpolated linearly; each piece's filament is
/// the line's in proportion to its length (the last piece takes the remainder, so the sum is exact
/// to rounding).
pub fn cut(line: &Line, axis: usize, interior: &[f64]) -> Vec<(usize, Line)> {
    let (u, v) = (line.a[axis], line.b[axis]);
    let (lo, hi) = (u.min(v), u.max(v));
    let mut cuts: Vec<(f64, f64)> =
        interior.iter().filter(|&&b| b > lo + BOUNDARY_EPS && b < hi - BOUNDARY_EPS).map(|&b| ((b - u) / (v - u), b)).collect();
    if cuts.is_empty() {
        return vec![(strip_of(hi, interior), line.clone())];
    }
    cuts.sort_by(|p, q| p.0.total_cmp(&q.0));
    let d = line.b - line.a;
    let mut points = vec![line.a];
    for (t, b) in cuts {
        let mut p = line.a + d * t;
        p[axis] = b;
        points.push(p);
    }
    points.push(line.b);
    let total = line.length();
    let mut given = 0.0;
    let count = points.len() - 1;
    (0..count)
        .map(|k| {
            let (a, b) = (points[k], points[k + 1]);
            let filament = if k + 1 == count { line.filament - given } else { line.filament * (b - a).norm() / total };
            given += filament;
            (strip_of(a[axis].max(b[axis]), interior), Line { a, b, filament, ..line.clone() })
        })
        .collect()
}

/// A uniform grid over line endpoints in x-y for nearest-endpoint queries with removal.
struct Grid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: i64,
    ny: i64,
    /// Endpoint ids (2·line + end) per cell; entries of used lines are dropped lazily.
    cells: Vec<Vec<u32>>,
}

impl Grid {
    fn new(points: &[[f64; 2]], tolerance: f64) -> Grid {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in points {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        let area = ((x1 - x0) * (y1 - y0)).max(0.0);
        let side = (x1 - x0).max(y1 - y0);
        // About two endpoints per cell, at most 1024 cells a side, never finer than the tolerance.
        let mut cell = (2.0 * area / points.len() as f64).sqrt().max(side / 1024.0).max(tolerance).max(1e-9);
        if !cell.is_finite() {
            // The area overflowed (coordinates far apart): 1024 cells a side, or one cell.
            cell = side / 1024.0;
            if !(cell.is_finite() && cell > 0.0) {
                cell = f64::MAX;
            }
        }
        let count = |span: f64| (span / cell).floor().clamp(0.0, 1023.0) as i64 + 1;
        let (nx, ny) = (count(x1 - x0), count(y1 - y0));
        let mut cells = vec![Vec::new(); (nx * ny) as usize];
        let mut grid = Grid { x0, y0, cell, nx, ny, cells: Vec::new() };
        for (id, p) in points.iter().enumerate() {
            let (cx, cy) = grid.cell_of(p);
            cells[(cy * nx + cx) as usize].push(id as u32);
        }
        grid.cells = cells;
        grid
    }

    /// The cell of `p`, or for a point outside the grid the grid's cell nearest it (the ring search
    /// from there still ends with the nearest point: it stops early only once its square holds `p`).
    fn cell_of(&self, p: &[f64; 2]) -> (i64, i64) {
        let index = |v: f64, n: i64| if v.is_nan() { 0 } else { v.floor().clamp(0.0, (n - 1) as f64) as i64 };
        (index((p[0] - self.x0) / self.cell, self.nx), index((p[1] - self.y0) / self.cell, self.ny))
    }

    /// The live endpoint nearest `p` in x-y: (id, distance). Ties: the smaller id (earlier line, its
    /// start before its end).
    fn nearest(&mut self, p: &[f64; 2], points: &[[f64; 2]], used: &[bool]) -> Option<(usize, f64)> {
        let (cx, cy) = self.cell_of(p);
        let mut best: Option<(usize, f64)> = None;
        let mut r = 0i64;
        loop {
            // Ring r: cells with Chebyshev distance r from (cx, cy), clipped to the grid.
            let (ylo, yhi) = ((cy - r).max(0), (cy + r).min(self.ny - 1));
            for y in ylo..=yhi {
                // The top and bottom rows of the ring in full, the other rows at its two ends.
                let full = y == cy - r || y == cy + r;
                let step = if full { 1 } else { 2 * r };
                let (mut x, last) = if full { ((cx - r).max(0), (cx + r).min(self.nx - 1)) } else { (cx - r, cx + r) };
                while x <= last {
                    if (0..self.nx).contains(&x) {
                        let cell = &mut self.cells[(y * self.nx + x) as usize];
                        cell.retain(|&id| !used[id as usize / 2]);
                        for &id in cell.iter() {
                            let q = points[id as usize];
                            let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                            if best.is_none_or(|(bid, bd)| d < bd || (d == bd && (id as usize) < bid)) {
                                best = Some((id as usize, d));
                            }
                        }
                    }
                    x += step;
                }
            }
            // Everything not yet examined lies outside the square of rings 0..=r around p's cell.
            let left = p[0] - (self.x0 + (cx - r) as f64 * self.cell);
            let right = self.x0 + (cx + r + 1) as f64 * self.cell - p[0];
            let below = p[1] - (self.y0 + (cy - r) as f64 * self.cell);
            let above = self.y0 + (cy + r + 1) as f64 * self.cell - p[1];
            let bound = left.min(right).min(below).min(above);
            let covered = cx - r <= 0 && cy - r <= 0 && cx + r >= self.nx - 1 && cy + r >= self.ny - 1;
            if covered || best.is_some_and(|(_, d)| d < bound) {
                return best;
            }
            r += 1;
        }
    }
}

/// Chains lines into continuous paths (000 Fig. 8): from `start` (x-y), take the line with the
/// nearest endpoint; continue with a line having an endpoint within `tolerance` (3-D) of the current
/// end (reversing it if that endpoint is its end); when there is none, start a new path at the
/// remaining endpoint nearest the current end. Every line appears once, in one path.
///
/// Among several matching lines (000: "there is no rule dictating which will be selected next") the
/// one that follows the current line in `lines` (the job's own continuation: the next line if going
/// forwards, the previous one if going backwards) is taken when it matches; otherwise the nearest
/// endpoint, then the earlier line, then a line's start before its end.
pub fn chain(lines: &[Line], start: [f64; 2], tolerance: f64) -> Vec<Vec<Line>> {
    if lines.is_empty() {
        return Vec::new();
    }
    let points: Vec<[f64; 2]> = lines.iter().flat_map(|l| [[l.a.x, l.a.y], [l.b.x, l.b.y]]).collect();
    let mut grid = Grid::new(&points, tolerance);
    let mut used = vec![false; lines.len()];
    let mut paths: Vec<Vec<Line>> = Vec::new();
    let mut here = start;
    let mut end3: Option<Vector3<f64>> = None;
    let mut follow: Option<usize> = None;
    while let Some(id) = follow.take().or_else(|| grid.nearest(&here, &points, &used).map(|(id, _)| id)) {
        let (k, reversed) = (id / 2, id % 2 == 1);
        used[k] = true;
        let line = if reversed { lines[k].reversed() } else { lines[k].clone() };
        let joins = end3.is_some_and(|e| (line.a - e).norm() <= tolerance);
        if !joins {
            paths.push(Vec::new());
        }
        follow = if !reversed {
            (k + 1 < lines.len() && !used[k + 1] && (lines[k + 1].a - line.b).norm() <= tolerance).then(|| 2 * (k + 1))
        } else {
            (k >= 1 && !used[k - 1] && (lines[k - 1].b - line.b).norm() <= tolerance).then(|| 2 * (k - 1) + 1)
        };
        here = [line.b.x, line.b.y];
        end3 = Some(line.b);
        paths.last_mut().expect("a path was started").push(line);
    }
    paths
}

/// One layer of one strip.
#[derive(Clone, Debug, PartialEq)]
pub struct StripLayer {
    /// Job layer (0-based).
    pub layer: usize,
    pub z: f64,
    /// This layer's bounds of the strip along the axis (m): the nominal ones moved per Fig. 6.
    pub lo: f64,
    pub hi: f64,
    /// Paths in print order.
    pub paths: Vec<Vec<Line>>,
}

/// One strip: every layer of it is printed before the next strip.
#[derive(Clone, Debug, PartialEq)]
pub struct Strip {
    /// Nominal bounds along the axis (m).
    pub lo: f64,
    pub hi: f64,
    /// Layers that have lines in this strip, bottom up.
    pub layers: Vec<StripLayer>,
}

impl Strip {
    pub fn width(&self) -> f64 {
        self.hi - self.lo
    }
    fn lines(&self) -> impl Iterator<Item = &Line> {
        self.layers.iter().flat_map(|l| l.paths.iter().flatten())
    }
}

/// A job split into strips.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub axis: Axis,
    /// Nominal bounds: origin, the boundaries between strips, far end (m, ascending).
    pub bounds: Vec<f64>,
    pub overlap: f64,
    /// N.
    pub layers: usize,
    pub strips: Vec<Strip>,
    pub checks: Checks,
    /// Lines cut at a boundary.
    pub cuts: usize,
}

/// Most strips a plan may have (a job far wider than the strips is a mistake, not a plan).
pub const MAX_STRIPS: usize = 10_000;

/// Splits `job` per `spec`: nominal strips, Eqs. 2-4, the staggered boundaries, cutting, chaining.
/// Errors name the flag.
pub fn plan(job: &Job, spec: &StripSpec) -> Result<Plan, String> {
    let axis = spec.axis.index();
    let a = spec.axis.name();
    let (mut lo, mut hi, mut lo_line, mut hi_line) = (f64::INFINITY, f64::NEG_INFINITY, 0, 0);
    for l in job.lines() {
        for p in [l.a, l.b] {
            if p[axis] < lo {
                (lo, lo_line) = (p[axis], l.source_line);
            }
            if p[axis] > hi {
                (hi, hi_line) = (p[axis], l.source_line);
            }
        }
    }
    let origin = spec.origin.unwrap_or(lo);
    if lo < origin - BOUNDARY_EPS {
        return Err(format!("--origin {origin} m: the job extrudes at {a} = {lo} m ({}:{lo_line}), before the origin", job.name));
    }
    let widths: Vec<f64> = match &spec.widths {
        Widths::Uniform(w) => {
            let n = (((hi - origin) - BOUNDARY_EPS) / w).ceil().max(1.0);
            if n.is_nan() || n > MAX_STRIPS as f64 {
                return Err(format!(
                    "--width {w} m: the job extrudes from {a} = {origin} m to {a} = {hi} m ({}:{hi_line}), {n} strips; at most {MAX_STRIPS}",
                    job.name
                ));
            }
            vec![*w; n as usize]
        }
        Widths::List(ws) => ws.clone(),
    };
    let mut bounds = vec![origin];
    for w in &widths {
        bounds.push(bounds.last().expect("origin") + w);
    }
    let end = *bounds.last().expect("origin");
    if hi > end + BOUNDARY_EPS {
        return Err(format!(
            "--widths: the strips end at {a} = {end} m but the job extrudes up to {a} = {hi} m ({}:{hi_line}); add a strip or widen them",
            job.name
        ));
    }
    let layers = job.layers.len();
    let checks = check_equations(&widths, layers, spec.overlap, spec.reach)?;
    let mut strips: Vec<Strip> = (0..widths.len()).map(|k| Strip { lo: bounds[k], hi: bounds[k + 1], layers: Vec::new() }).collect();
    let mut cuts = 0;
    for (i, layer) in job.layers.iter().enumerate() {
        let lb = layer_bounds(&bounds, i, layers, spec.overlap);
        let interior = &lb[1..lb.len() - 1];
        let mut per_strip: Vec<Vec<Line>> = vec![Vec::new(); widths.len()];
        for line in &layer.lines {
            let pieces = cut(line, axis, interior);
            if pieces.len() > 1 {
                cuts += 1;
            }
            for (k, piece) in pieces {
                per_strip[k].push(piece);
            }
        }
        for (k, lines) in per_strip.into_iter().enumerate() {
            if lines.is_empty() {
                continue;
            }
            let paths = chain(&lines, spec.start, spec.join_tolerance);
            strips[k].layers.push(StripLayer { layer: i, z: layer.z, lo: lb[k], hi: lb[k + 1], paths });
        }
    }
    Ok(Plan { axis: spec.axis, bounds, overlap: spec.overlap, layers, strips, checks, cuts })
}

/// How to write moves between paths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Travel {
    /// Travel speed (m/s).
    pub speed: f64,
    /// Filament retracted before a travel and pushed back after it (m; 0: none).
    pub retract: f64,
    /// Speed of the retraction (m/s of filament).
    pub retract_speed: f64,
    /// Lift (m) above the higher of the two layers during a travel (0: none).
    pub z_hop: f64,
}

impl Default for Travel {
    /// The truss plate's slicer settings: 120 mm/s travel, 1 mm retraction at 35 mm/s, no lift.
    fn default() -> Self {
        Travel { speed: 0.12, retract: 1e-3, retract_speed: 0.035, z_hop: 0.0 }
    }
}

/// What the writer did.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Written {
    /// Travel moves between paths (including the one from the start position).
    pub travels: usize,
    pub retractions: usize,
    /// Extruding `G1` moves.
    pub moves: usize,
}

/// mm with at most 9 decimals, no exponent, no "-0".
fn mm(v: f64) -> String {
    let mut s = format!("{:.9}", v * 1e3);
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" { "0".into() } else { s }
}

/// mm/min for a speed in m/s.
fn per_min(v: f64) -> String {
    mm(v * 60.0)
}

/// The plan as G-code: mm, absolute positions, relative extrusion (M83); strips in order, all layers
/// of a strip before the next; each layer under a `;LAYER:n` marker (the job's layer, 0-based) and a
/// comment naming strip, layer and shift; each path after a travel (retract, lift, move, lower,
/// unretract). `header` lines are written as comments first.
pub fn write_gcode(plan: &Plan, travel: &Travel, header: &[String]) -> (String, Written) {
    let mut g = String::new();
    let mut w = Written::default();
    for h in header {
        let _ = writeln!(g, "; {h}");
    }
    let _ = writeln!(g, "G21 ; mm\nG90 ; absolute positions\nM83 ; relative extrusion");
    let mut at = GcodeOptions::default().start;
    let mut feed = f64::NAN;
    let mut extruded = false;
    let a = plan.axis.name();
    for (k, strip) in plan.strips.iter().enumerate() {
        let _ = writeln!(
            g,
            "; strip {} of {}: {a} from {} to {} mm (nominal), {} layers",
            k + 1,
            plan.strips.len(),
            mm(strip.lo),
            mm(strip.hi),
            strip.layers.len()
        );
        for sl in &strip.layers {
            let _ = writeln!(g, ";LAYER:{}", sl.layer);
            let _ = writeln!(
                g,
                "; strip {} layer {} (z {} mm): {a} from {} to {} mm, boundaries moved by {} mm, {} paths",
                k + 1,
                sl.layer + 1,
                mm(sl.z),
                mm(sl.lo),
                mm(sl.hi),
                mm((plan.layers - 1 - sl.layer) as f64 * plan.overlap),
                sl.paths.len()
            );
            for path in &sl.paths {
                // Fold moves too short to survive the text into their neighbour.
                let mut moves: Vec<(Vector3<f64>, f64, f64)> = Vec::with_capacity(path.len());
                let mut pending = 0.0;
                let mut from = path[0].a;
                for line in path {
                    if (line.b - from).norm() < MIN_MOVE {
                        match moves.last_mut() {
                            Some(m) => m.1 += line.filament,
                            None => pending += line.filament,
                        }
                        continue;
                    }
                    moves.push((line.b, line.filament + pending, line.feed));
                    pending = 0.0;
                    from = line.b;
                }
                if moves.is_empty() {
                    // A path of one line shorter than MIN_MOVE: write it as it is.
                    moves.push((path[0].b, pending, path[0].feed));
                }
                let to = path[0].a;
                if (to - at).norm() >= MIN_MOVE {
                    if extruded && travel.retract > 0.0 {
                        let _ = writeln!(g, "G1 E-{} F{}", mm(travel.retract), per_min(travel.retract_speed));
                        w.retractions += 1;
                    }
                    let high = at.z.max(to.z) + travel.z_hop;
                    let f = per_min(travel.speed);
                    if high != at.z {
                        let _ = writeln!(g, "G0 Z{} F{f}", mm(high));
                    }
                    let _ = writeln!(g, "G0 X{} Y{} F{f}", mm(to.x), mm(to.y));
                    if high != to.z {
                        let _ = writeln!(g, "G0 Z{} F{f}", mm(to.z));
                    }
                    feed = travel.speed;
                    if extruded && travel.retract > 0.0 {
                        let _ = writeln!(g, "G1 E{} F{}", mm(travel.retract), per_min(travel.retract_speed));
                        feed = f64::NAN;
                    }
                    w.travels += 1;
                    at = to;
                }
                for (p, filament, f) in moves {
                    let _ = write!(g, "G1 X{} Y{}", mm(p.x), mm(p.y));
                    if p.z != at.z {
                        let _ = write!(g, " Z{}", mm(p.z));
                    }
                    let _ = write!(g, " E{}", mm(filament));
                    if f != feed {
                        let _ = write!(g, " F{}", per_min(f));
                        feed = f;
                    }
                    g.push('\n');
                    at = p;
                    w.moves += 1;
                }
                extruded = true;
            }
        }
    }
    (g, w)
}

type PlotResult = Result<(), Box<dyn std::error::Error>>;

/// Colour of strip `k`, shaded by path `j`: 000's blue, green, orange, then more hues.
fn colour(k: usize, j: usize) -> HSLColor {
    const HUES: [f64; 6] = [0.60, 0.33, 0.08, 0.0, 0.78, 0.50];
    let lightness = 0.28 + 0.08 * (j % 5) as f64;
    HSLColor(HUES[k % HUES.len()], 0.85, lightness)
}

/// Layers shown in the split view: all if there are at most four, else four spread from first to last.
fn shown_layers(n: usize) -> Vec<usize> {
    if n <= 4 { (0..n).collect() } else { (0..4).map(|i| i * (n - 1) / 3).collect() }
}

/// PNG like 000's Fig. 13: the nominal job from above (left), and the split job layer by layer
/// (right; one colour per strip, a shade per path, the nominal boundaries dashed).
pub fn plot_png(job: &Job, plan: &Plan, path: &Path) -> Result<(), String> {
    crate::replay_plot::register_font()?;
    draw(job, plan, path).map_err(|e| format!("{}: {e}", path.display()))
}

fn draw(job: &Job, plan: &Plan, path: &Path) -> PlotResult {
    let root = BitMapBackend::new(path, (1800, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(800);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for l in job.lines() {
        for p in [l.a, l.b] {
            x0 = x0.min(p.x * 1e3);
            x1 = x1.max(p.x * 1e3);
            y0 = y0.min(p.y * 1e3);
            y1 = y1.max(p.y * 1e3);
        }
    }
    let pad = 0.04 * (x1 - x0).max(y1 - y0).max(1e-3);
    let (x0, x1, y0, y1) = (x0 - pad, x1 + pad, y0 - pad, y1 + pad);
    let boundary_lines = |k: usize| -> Vec<(f64, f64)> {
        let b = plan.bounds[k] * 1e3;
        match plan.axis {
            Axis::X => vec![(b, y0), (b, y1)],
            Axis::Y => vec![(x0, b), (x1, b)],
        }
    };
    let mut chart = ChartBuilder::on(&left)
        .caption(format!("nominal job: {} layers, {} lines", job.layers.len(), job.lines().count()), ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart.configure_mesh().x_desc("x (mm)").y_desc("y (mm)").max_light_lines(0).draw()?;
    for layer in &job.layers {
        for l in &layer.lines {
            chart.draw_series(LineSeries::new([(l.a.x * 1e3, l.a.y * 1e3), (l.b.x * 1e3, l.b.y * 1e3)], RGBColor(30, 60, 160)))?;
        }
    }
    for k in 1..plan.bounds.len() - 1 {
        chart.draw_series(DashedLineSeries::new(boundary_lines(k), 8, 6, BLACK.into()))?;
    }
    let shown = shown_layers(plan.layers);
    let cols = if shown.len() > 1 { 2 } else { 1 };
    let rows = shown.len().div_ceil(cols);
    let cells = right.split_evenly((rows, cols));
    for (cell, &i) in cells.iter().zip(&shown) {
        let shift = (plan.layers - 1 - i) as f64 * plan.overlap * 1e3;
        let paths: usize = plan.strips.iter().flat_map(|s| s.layers.iter().filter(|l| l.layer == i)).map(|l| l.paths.len()).sum();
        let mut chart = ChartBuilder::on(cell)
            .caption(format!("split, layer {} of {}: boundaries +{shift:.1} mm, {paths} paths", i + 1, plan.layers), ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(45)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart.configure_mesh().max_light_lines(0).draw()?;
        for (k, strip) in plan.strips.iter().enumerate() {
            for sl in strip.layers.iter().filter(|l| l.layer == i) {
                for (j, p) in sl.paths.iter().enumerate() {
                    let mut pts = vec![(p[0].a.x * 1e3, p[0].a.y * 1e3)];
                    pts.extend(p.iter().map(|l| (l.b.x * 1e3, l.b.y * 1e3)));
                    chart.draw_series(LineSeries::new(pts, colour(k, j).stroke_width(2)))?;
                }
            }
        }
        for k in 1..plan.bounds.len() - 1 {
            chart.draw_series(DashedLineSeries::new(boundary_lines(k), 6, 6, BLACK.into()))?;
        }
    }
    root.present()?;
    Ok(())
}

/// Strip widths: one for all strips, or one per strip.
#[derive(clap::Args, Debug, Clone)]
#[group(required = true, multiple = false)]
pub struct WidthArgs {
    /// Strip width W (m); as many strips as the part needs, the last one possibly not full.
    #[arg(long, value_name = "M")]
    pub width: Option<f64>,
    /// Strip widths (m), comma-separated, in print order (000's truss: 0.043,0.06,0.047).
    #[arg(long, value_name = "M,M,..", value_delimiter = ',')]
    pub widths: Option<Vec<f64>>,
}

/// `strand-plan strips`: split a planar job into strips (000 Section 3.2).
#[derive(clap::Args, Debug, Clone)]
pub struct StripsArgs {
    /// The G-code job.
    pub job: PathBuf,
    #[command(flatten)]
    pub width: WidthArgs,
    /// Overlap L (m): how far the boundaries move per layer below the top (000 Fig. 6).
    #[arg(long, value_name = "M")]
    pub overlap: f64,
    /// Reach R (m) of the manipulator across the strips (Eq. 2: W ≤ R/2).
    #[arg(long, value_name = "M")]
    pub reach: f64,
    /// Axis the strips are measured along.
    #[arg(long, value_enum, default_value_t = Axis::X)]
    pub axis: Axis,
    /// Where strip 1 starts along the axis (m); default: the part's smallest coordinate.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub origin: Option<f64>,
    /// Nominal position x,y (m) each layer's chaining starts from (000: the origin).
    #[arg(long, value_name = "X,Y", value_delimiter = ',', default_value = "0,0", allow_negative_numbers = true)]
    pub start: Vec<f64>,
    /// Endpoints closer than this (m) continue a path.
    #[arg(long, value_name = "M", default_value_t = 1e-6)]
    pub join_tolerance: f64,
    /// Largest sagitta (m) of the chords replacing an arc.
    #[arg(long, value_name = "M", default_value_t = 1e-5)]
    pub arc_tolerance: f64,
    /// Keep skirt and brim lines (dropped by default: not part of the structure).
    #[arg(long)]
    pub keep_skirt: bool,
    /// Travel speed between paths (m/s).
    #[arg(long, value_name = "M/S", default_value_t = 0.12)]
    pub travel_speed: f64,
    /// Filament retracted before each travel (m; 0: none).
    #[arg(long, value_name = "M", default_value_t = 1e-3)]
    pub retract: f64,
    /// Retraction speed (m/s of filament).
    #[arg(long, value_name = "M/S", default_value_t = 0.035)]
    pub retract_speed: f64,
    /// Lift during travels (m; 0: none).
    #[arg(long, value_name = "M", default_value_t = 0.0)]
    pub z_hop: f64,
    /// Write the G-code here (default: standard output, unless --json).
    #[arg(long, short, value_name = "FILE.gcode")]
    pub output: Option<PathBuf>,
    /// Draw the nominal and the split job (like 000's Fig. 13) into this PNG.
    #[arg(long, value_name = "FILE")]
    pub png: Option<PathBuf>,
    /// Print one JSON report on standard output.
    #[arg(long)]
    pub json: bool,
}

fn non_negative(flag: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(format!("--{flag} {v}: must be finite and ≥ 0")) }
}

impl StripsArgs {
    fn spec(&self) -> Result<StripSpec, String> {
        let widths = match (&self.width.width, &self.width.widths) {
            (Some(w), _) => {
                super::positive("width", *w)?;
                Widths::Uniform(*w)
            }
            (None, Some(ws)) => {
                if ws.is_empty() {
                    return Err("--widths: give at least one width".into());
                }
                for (k, w) in ws.iter().enumerate() {
                    super::positive(&format!("widths (strip {})", k + 1), *w)?;
                }
                Widths::List(ws.clone())
            }
            (None, None) => return Err("give --width or --widths".into()),
        };
        super::positive("overlap", self.overlap)?;
        super::positive("reach", self.reach)?;
        super::positive("join-tolerance", self.join_tolerance)?;
        super::positive("arc-tolerance", self.arc_tolerance)?;
        super::positive("travel-speed", self.travel_speed)?;
        super::positive("retract-speed", self.retract_speed)?;
        non_negative("retract", self.retract)?;
        non_negative("z-hop", self.z_hop)?;
        if let Some(o) = self.origin
            && !o.is_finite()
        {
            return Err(format!("--origin {o}: must be finite"));
        }
        let start = match self.start.as_slice() {
            [x, y] if x.is_finite() && y.is_finite() => [*x, *y],
            _ => return Err(format!("--start {:?}: expected X,Y in metres", self.start)),
        };
        Ok(StripSpec {
            axis: self.axis,
            widths,
            origin: self.origin,
            overlap: self.overlap,
            reach: self.reach,
            start,
            join_tolerance: self.join_tolerance,
        })
    }

    /// The parameters, for the output's header.
    fn header(&self, job: &Job, plan: &Plan) -> Vec<String> {
        let widths: Vec<String> = plan.strips.iter().map(|s| mm(s.width())).collect();
        vec![
            "generated by strand-plan strips (000 Section 3.2: strips with a staggered overlap joint)".into(),
            format!("source: {}", job.name),
            format!(
                "axis {}, origin {} mm, widths {} mm, overlap L {} mm, reach R {} mm, N = {} layers",
                self.axis.name(),
                mm(plan.bounds[0]),
                widths.join("/"),
                mm(self.overlap),
                mm(self.reach),
                plan.layers
            ),
            format!(
                "chaining from ({}, {}) mm, join tolerance {} mm; arcs flattened to {} mm; skirt {}",
                mm(self.start[0]),
                mm(self.start[1]),
                mm(self.join_tolerance),
                mm(self.arc_tolerance),
                if self.keep_skirt { "kept" } else { "dropped" }
            ),
            format!(
                "travel {} mm/s, retract {} mm at {} mm/s, z-hop {} mm",
                mm(self.travel_speed),
                mm(self.retract),
                mm(self.retract_speed),
                mm(self.z_hop)
            ),
            "layer i of N: boundaries between strips moved by (N - i)*L towards the strip printed second".into(),
        ]
    }
}

/// The JSON report.
pub fn report(job: &Job, plan: &Plan, written: &Written) -> serde_json::Value {
    let strips: Vec<serde_json::Value> = plan
        .strips
        .iter()
        .enumerate()
        .map(|(k, s)| {
            json!({
                "strip": k + 1,
                "lo_m": s.lo,
                "hi_m": s.hi,
                "width_m": s.width(),
                "layers": s.layers.len(),
                "paths_per_layer": s.layers.iter().map(|l| l.paths.len()).collect::<Vec<_>>(),
                "paths": s.layers.iter().map(|l| l.paths.len()).sum::<usize>(),
                "lines": s.lines().count(),
                "filament_m": s.lines().map(|l| l.filament).sum::<f64>(),
                "path_length_m": s.lines().map(Line::length).sum::<f64>(),
                "layer_bounds_m": s.layers.iter().map(|l| [l.lo, l.hi]).collect::<Vec<_>>(),
            })
        })
        .collect();
    let out_filament: f64 = plan.strips.iter().flat_map(|s| s.lines()).map(|l| l.filament).sum();
    let out_length: f64 = plan.strips.iter().flat_map(|s| s.lines()).map(Line::length).sum();
    json!({
        "file": job.name,
        "axis": plan.axis,
        "origin_m": plan.bounds[0],
        "bounds_m": plan.bounds,
        "overlap_m": plan.overlap,
        "layers": plan.layers,
        "layer_source": job.layer_source,
        "strip_count": plan.strips.len(),
        "strips": strips,
        "travels": written.travels,
        "retractions": written.retractions,
        "moves": written.moves,
        "cuts": plan.cuts,
        "input": {
            "lines": job.lines().count(),
            "filament_m": job.filament(),
            "path_length_m": job.path_length(),
            "arcs_flattened": job.arcs_flattened,
            "skirt_lines_dropped": job.skirt_lines,
            "skirt_filament_m": job.skirt_filament,
        },
        "output": { "lines": plan.strips.iter().map(|s| s.lines().count()).sum::<usize>(), "filament_m": out_filament, "path_length_m": out_length },
        "checks": plan.checks,
    })
}

/// Runs `strand-plan strips`.
pub fn run(args: &StripsArgs) -> Result<(), String> {
    let spec = args.spec()?;
    let name = args.job.display().to_string();
    let mut parser = parse_file(&args.job, GcodeOptions::for_path(&args.job)).map_err(|e| e.to_string())?;
    let job = read_job(&mut parser, &name, &ReadOptions { arc_tolerance: args.arc_tolerance, keep_skirt: args.keep_skirt })?;
    let plan = plan(&job, &spec)?;
    let travel = Travel { speed: args.travel_speed, retract: args.retract, retract_speed: args.retract_speed, z_hop: args.z_hop };
    let (text, written) = write_gcode(&plan, &travel, &args.header(&job, &plan));
    match &args.output {
        Some(p) => std::fs::write(p, &text).map_err(|e| format!("--output {}: {e}", p.display()))?,
        None if !args.json => print!("{text}"),
        None => {}
    }
    if let Some(p) = &args.png {
        plot_png(&job, &plan, p).map_err(|e| format!("--png {e}"))?;
    }
    if args.json {
        println!("{}", report(&job, &plan, &written));
        return Ok(());
    }
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{name}: {} strip{} along {} from {} mm, N = {} layers, L = {} mm, R = {} mm",
        plan.strips.len(),
        if plan.strips.len() == 1 { "" } else { "s" },
        args.axis.name(),
        mm(plan.bounds[0]),
        plan.layers,
        mm(args.overlap),
        mm(args.reach)
    );
    for (k, st) in plan.strips.iter().enumerate() {
        let paths: Vec<String> = st.layers.iter().map(|l| l.paths.len().to_string()).collect();
        let _ = writeln!(
            s,
            "  strip {}: {} mm wide, {} layers, paths per layer {}, {} lines, {:.3} mm of filament",
            k + 1,
            mm(st.width()),
            st.layers.len(),
            paths.join("/"),
            st.lines().count(),
            st.lines().map(|l| l.filament).sum::<f64>() * 1e3
        );
    }
    let _ = writeln!(
        s,
        "  {} travels, {} cuts; filament {:.6} mm in, {:.6} mm out{}",
        written.travels,
        plan.cuts,
        job.filament() * 1e3,
        plan.strips.iter().flat_map(|st| st.lines()).map(|l| l.filament).sum::<f64>() * 1e3,
        if job.skirt_lines > 0 { format!(" ({} skirt lines dropped)", job.skirt_lines) } else { String::new() }
    );
    let _ = writeln!(
        s,
        "  Eq. 2: W = {} mm ≤ R/2 = {} mm; Eq. 3: N = {} ≤ ⌊W/L⌋ = {}; Eq. 4: N ≤ ⌊R/(2L)⌋ = {}",
        mm(plan.checks.eq2.width_m),
        mm(plan.checks.eq2.half_reach_m),
        plan.layers,
        plan.checks.eq3.iter().map(|e| e.max_layers.to_string()).collect::<Vec<_>>().join("/"),
        plan.checks.eq4.max_layers
    );
    if args.output.is_some() {
        print!("{s}")
    } else {
        eprint!("{s}")
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(a: [f64; 3], b: [f64; 3], filament: f64) -> Line {
        Line { a: Vector3::from(a), b: Vector3::from(b), filament, feed: 0.02, source_line: 1 }
    }

    fn job_from(text: &str) -> Job {
        let mut parser = Parser::new(text.as_bytes(), "test.gcode", GcodeOptions::default());
        read_job(&mut parser, "test.gcode", &ReadOptions::default()).unwrap()
    }

    fn spec(widths: Widths, overlap: f64, reach: f64) -> StripSpec {
        StripSpec { axis: Axis::X, widths, origin: None, overlap, reach, start: [0.0, 0.0], join_tolerance: 1e-6 }
    }

    #[test]
    fn eq2_names_the_widest_strip_and_the_reach() {
        let e = check_equations(&[0.043, 0.06, 0.047], 4, 0.005, 0.1).unwrap_err();
        assert!(e.starts_with("Eq. 2 (W ≤ R/2) violated: strip 2 is W = 0.06 m wide"), "{e}");
        assert!(e.contains("--reach 0.1 m / 2 = 0.05 m"), "{e}");
        assert!(!e.contains("Eq. 3") && !e.contains("Eq. 4"), "{e}");
        // R = 0.12 m is exactly enough for 60 mm.
        let c = check_equations(&[0.043, 0.06, 0.047], 4, 0.005, 0.12).unwrap();
        assert_eq!((c.eq2.strip, c.eq2.half_reach_m, c.eq2.ok), (2, 0.06, true));
    }

    #[test]
    fn eq3_names_each_strip_too_narrow_for_the_layers() {
        // ⌊43/15⌋ = 2, ⌊60/15⌋ = 4, ⌊47/15⌋ = 3 against N = 4; ⌊120/30⌋ = 4 keeps Eq. 4.
        let e = check_equations(&[0.043, 0.06, 0.047], 4, 0.015, 0.12).unwrap_err();
        assert!(e.contains("Eq. 3 (N ≤ ⌊W/L⌋) violated: strip 1 (W = 0.043 m) with --overlap 0.015 m allows ⌊0.043/0.015⌋ = 2 layers, the job has N = 4"), "{e}");
        assert!(e.contains("strip 3 (W = 0.047 m) with --overlap 0.015 m allows ⌊0.047/0.015⌋ = 3 layers"), "{e}");
        assert!(!e.contains("strip 2 (") && !e.contains("Eq. 2") && !e.contains("Eq. 4"), "{e}");
        // A quotient that is an integer in decimal is not floored below it: 0.043/0.01075 = 4.
        let c = check_equations(&[0.043], 4, 0.01075, 0.1).unwrap();
        assert_eq!(c.eq3[0].max_layers, 4);
        assert!(check_equations(&[0.043], 5, 0.01075, 0.1).is_err());
    }

    #[test]
    fn eq4_bounds_the_layers_by_reach_and_overlap() {
        // R = 0.1, L = 0.015: ⌊0.1/0.03⌋ = 3 < 4. Eq. 4 follows from Eqs. 2 and 3, so one of them
        // fails too: here Eq. 2 (60 mm > 50 mm), while ⌊0.06/0.015⌋ = 4 keeps Eq. 3.
        let e = check_equations(&[0.06], 4, 0.015, 0.1).unwrap_err();
        assert!(
            e.contains(
                "Eq. 4 (N ≤ ⌊R/(2L)⌋) violated: --reach 0.1 m and --overlap 0.015 m allow ⌊0.1/(2·0.015)⌋ = 3 layers, the job has N = 4"
            ),
            "{e}"
        );
        assert!(e.contains("Eq. 2") && !e.contains("Eq. 3"), "{e}");
        let c = check_equations(&[0.05], 4, 0.0125, 0.1).unwrap();
        assert_eq!(c.eq4.max_layers, 4);
    }

    #[test]
    fn boundaries_move_by_l_per_layer_towards_the_second_strip() {
        let nominal = [0.05, 0.093, 0.153, 0.2];
        let expect = [[0.108, 0.168], [0.103, 0.163], [0.098, 0.158], [0.093, 0.153]];
        for (i, e) in expect.iter().enumerate() {
            let b = layer_bounds(&nominal, i, 4, 0.005);
            assert_eq!((b[0], b[3]), (0.05, 0.2), "outer edges stay");
            assert!((b[1] - e[0]).abs() < 1e-15 && (b[2] - e[1]).abs() < 1e-15, "layer {i}: {b:?}");
        }
        // Through plan(): one line across the part on each of 3 layers; its cut points.
        let mut g = String::from("M83\nG1 F600\n");
        for layer in 1..=3 {
            g += &format!(";LAYER_CHANGE\n;Z:{layer}\nG0 X0 Y10 Z{layer}\nG1 X30 Y10 E3\n");
        }
        let job = job_from(&g);
        let p = plan(&job, &spec(Widths::Uniform(0.01), 0.002, 0.02)).unwrap();
        assert_eq!(p.strips.len(), 3);
        assert_eq!(p.cuts, 3);
        for (i, shift) in [0.004, 0.002, 0.0].into_iter().enumerate() {
            let s1 = &p.strips[0].layers[i];
            let end = s1.paths[0][0].b.x.max(s1.paths[0][0].a.x);
            assert!((end - (0.01 + shift)).abs() < 1e-15, "layer {i}: strip 1 ends at {end}");
            let s2 = &p.strips[1].layers[i];
            assert!((s2.lo - (0.01 + shift)).abs() < 1e-15 && (s2.hi - (0.02 + shift)).abs() < 1e-15);
            // Strip 3 takes what strip 2 leaves: 10 mm − shift.
            let len3: f64 = p.strips[2].layers[i].paths.iter().flatten().map(Line::length).sum();
            assert!((len3 - (0.01 - shift)).abs() < 1e-12, "layer {i}: {len3}");
        }
    }

    #[test]
    fn a_line_on_a_boundary_goes_to_the_strip_printed_first() {
        let interior = [0.093];
        let on = line([0.093, 0.02, 0.001], [0.093, 0.1, 0.001], 1e-3);
        assert_eq!(cut(&on, 0, &interior), vec![(0, on.clone())]);
        let after = line([0.093, 0.02, 0.001], [0.12, 0.02, 0.001], 1e-3);
        assert_eq!(cut(&after, 0, &interior), vec![(1, after.clone())]);
        let before = line([0.06, 0.02, 0.001], [0.093, 0.02, 0.001], 1e-3);
        assert_eq!(cut(&before, 0, &interior), vec![(0, before.clone())]);
        // From G-code: X93 (0.093 after mm → m) against 0.05 + 0.043 summed in floating point.
        let job = job_from("M83\nG1 F600\nG0 X50 Y0 Z1\nG1 X60 Y0 E1\nG0 X93 Y20\nG1 X93 Y50 E1\nG0 X143 Y0\nG1 X140 Y0 E1\n");
        let mut s = spec(Widths::List(vec![0.043, 0.05]), 0.01, 0.2);
        s.origin = Some(0.05);
        let p = plan(&job, &s).unwrap();
        let xs = |k: usize| -> Vec<f64> { p.strips[k].layers.iter().flat_map(|l| l.paths.iter().flatten()).map(|l| l.a.x).collect() };
        assert_eq!(p.strips[0].layers[0].paths.len(), 2, "the X93 line is in strip 1");
        assert!(xs(0).iter().any(|x| (x - 0.093).abs() < 1e-12));
        assert_eq!(xs(1), vec![0.14], "reversed: its end is nearer the origin");
    }

    #[test]
    fn a_crossing_line_is_cut_exactly_at_the_boundary() {
        let l = line([0.08, 0.0, 0.001], [0.10, 0.02, 0.003], 1e-3);
        let pieces = cut(&l, 0, &[0.093]);
        assert_eq!(pieces.len(), 2);
        let ((s0, p0), (s1, p1)) = (&pieces[0], &pieces[1]);
        assert_eq!((*s0, *s1), (0, 1));
        assert_eq!(p0.b.x, 0.093, "exactly on the boundary");
        assert_eq!(p0.b, p1.a);
        assert!((p0.b.y - 0.013).abs() < 1e-15 && (p0.b.z - 0.0023).abs() < 1e-15, "{:?}", p0.b);
        assert!((p0.filament - 0.65e-3).abs() < 1e-15 && (p1.filament - 0.35e-3).abs() < 1e-15);
        assert_eq!(p0.filament + p1.filament, 1e-3);
        // Backwards across two boundaries: three pieces in travel order, strips 2, 1, 0.
        let back = line([0.2, 0.01, 0.001], [0.0, 0.01, 0.001], 2e-3);
        let pieces = cut(&back, 0, &[0.05, 0.15]);
        let strips: Vec<usize> = pieces.iter().map(|p| p.0).collect();
        assert_eq!(strips, vec![2, 1, 0]);
        assert_eq!((pieces[0].1.b.x, pieces[1].1.b.x), (0.15, 0.05));
        let f: Vec<f64> = pieces.iter().map(|p| p.1.filament).collect();
        assert!((f[0] - 0.5e-3).abs() < 1e-15 && (f[1] - 1e-3).abs() < 1e-15 && (f[2] - 0.5e-3).abs() < 1e-15, "{f:?}");
        // Within BOUNDARY_EPS of an end: not cut.
        let grazing = line([0.093 - 0.5e-9, 0.0, 0.0], [0.12, 0.0, 0.0], 1e-3);
        assert_eq!(cut(&grazing, 0, &[0.093]).len(), 1);
    }

    #[test]
    fn chaining_a_grid_follows_fig_8() {
        // A 2 × 2 grid of unit cells (3 × 3 nodes, 12 edges), edges listed rows first, then columns.
        let e = |a: [f64; 2], b: [f64; 2]| line([a[0], a[1], 0.001], [b[0], b[1], 0.001], 1.0);
        let mut lines = Vec::new();
        for y in 0..3 {
            for x in 0..2 {
                lines.push(e([x as f64, y as f64], [x as f64 + 1.0, y as f64]));
            }
        }
        for x in 0..3 {
            for y in 0..2 {
                lines.push(e([x as f64, y as f64], [x as f64, y as f64 + 1.0]));
            }
        }
        let paths = chain(&lines, [-0.5, -0.5], 1e-6);
        // By hand: from (0,0) the earlier of the two lines there, (0,0)→(1,0); then the job's next
        // line (1,0)→(2,0); at (2,0) the only match, (2,0)→(2,1), whose job successor (2,1)→(2,2)
        // follows; at (2,2) row 2 backwards to (0,2), column 0 down to (0,0): 8 lines. Nothing left at
        // (0,0): (0,1) and (1,0) are nearest at 1, the earlier line wins: (0,1)→(1,1)→(2,1). From
        // (2,1) the nearest ends are at (1,1): (1,1)→(1,0), then (1,1)→(1,2) alone.
        let lens: Vec<usize> = paths.iter().map(Vec::len).collect();
        assert_eq!(lens, vec![8, 2, 1, 1]);
        assert_eq!(paths[0][0].a, Vector3::new(0.0, 0.0, 0.001), "starts nearest the origin");
        assert_eq!(paths[0].last().unwrap().b, Vector3::new(0.0, 0.0, 0.001));
        assert_eq!(paths[1][0].a, Vector3::new(0.0, 1.0, 0.001));
        assert_eq!((paths[2][0].a, paths[2][0].b), (Vector3::new(1.0, 1.0, 0.001), Vector3::new(1.0, 0.0, 0.001)));
        for p in &paths {
            for w in p.windows(2) {
                assert_eq!(w[0].b, w[1].a, "continuous");
            }
        }
        // Disjoint polylines given shuffled and reversed come back as one path each.
        let mut pieces = Vec::new();
        for k in 0..5 {
            let y = 0.01 * k as f64;
            for j in 0..4 {
                let (a, b) = ([0.1 + 0.01 * j as f64, y, 0.0], [0.11 + 0.01 * j as f64, y, 0.0]);
                pieces.push(if (j + k) % 2 == 0 { line(a, b, 1.0) } else { line(b, a, 1.0) });
            }
        }
        pieces.reverse();
        let paths = chain(&pieces, [0.0, 0.0], 1e-9);
        assert_eq!(paths.iter().map(Vec::len).collect::<Vec<_>>(), vec![4; 5]);
        assert_eq!(paths[0][0].a, Vector3::new(0.1, 0.0, 0.0));
        // Each new path starts at the endpoint nearest the last end, one row up: a boustrophedon,
        // x = 0.10 on even rows and 0.14 on odd ones.
        for (k, p) in paths.iter().enumerate() {
            let x = if k % 2 == 0 { 0.1 } else { 0.14 };
            assert!((p[0].a.x - x).abs() < 1e-12 && (p[0].a.y - 0.01 * k as f64).abs() < 1e-12, "path {k}: {:?}", p[0].a);
        }
    }

    #[test]
    fn arcs_are_flattened_within_the_tolerance_and_keep_their_filament() {
        // A quarter circle of radius 10 mm about (10, 0) from (0, 0) to (10, 10), clockwise.
        let job = job_from("M83\nG1 F600\nG1 X0 Y0 Z1\nG2 X10 Y10 I10 J0 E2\n");
        let lines: Vec<&Line> = job.lines().collect();
        assert_eq!(job.arcs_flattened, 1);
        // Sagitta ≤ 10 µm on r = 10 mm: step ≤ 2·acos(0.999) = 0.0894 rad → ⌈(π/2)/0.0894⌉ = 18 chords.
        assert_eq!(lines.len(), 18);
        let centre = Vector3::new(0.01, 0.0, 0.001);
        for l in &lines {
            assert!(((l.b - centre).norm() - 0.01).abs() < 1e-15);
            let mid = (l.a + l.b) / 2.0;
            assert!(0.01 - (mid - centre).norm() <= 1e-5);
        }
        assert_eq!(lines.last().unwrap().b, Vector3::new(0.01, 0.01, 0.001));
        assert!((job.filament() - 2e-3).abs() < 1e-18, "{}", job.filament());
    }

    #[test]
    fn layers_come_from_tags_or_from_z() {
        let tagged = job_from("M83\nG1 F600\n;LAYER_CHANGE\n;Z:1\nG1 Z1\nG1 X10 E1\n;LAYER_CHANGE\n;Z:2\nG1 Z2\nG1 X0 E1\n");
        assert_eq!((tagged.layer_source, tagged.layers.len(), tagged.layers[1].z), ("tags", 2, 0.002));
        let untagged = job_from("M83\nG1 F600\nG1 Z1\nG1 X10 E1\nG1 Z2\nG1 X0 E1\nG1 Z1.0000002\nG1 X5 E1\n");
        assert_eq!(untagged.layer_source, "z");
        assert_eq!(untagged.layers.iter().map(|l| l.lines.len()).collect::<Vec<_>>(), vec![2, 1], "z to 1 µm");
        let skirt = job_from("M83\nG1 F600\n;TYPE:Skirt/Brim\nG1 X10 E1\n;TYPE:Perimeter\nG1 X20 E2\n");
        assert_eq!((skirt.skirt_lines, skirt.skirt_filament, skirt.filament()), (1, 1e-3, 2e-3));
    }

    #[test]
    fn the_output_is_strip_by_strip_and_reads_back() {
        // Two layers of a 30 mm line and a square loop across the middle; strips of 15 mm.
        let mut g = String::from("M83\nG1 F600\n");
        for z in [1, 2] {
            g += &format!(
                ";LAYER_CHANGE\n;Z:{z}\nG0 X0 Y0 Z{z}\nG1 X30 Y0 E3\nG0 X10 Y10\nG1 X20 Y10 E1\nG1 X20 Y20 E1\nG1 X10 Y20 E1\nG1 X10 Y10 E1\n"
            );
        }
        let job = job_from(&g);
        let mut s = spec(Widths::Uniform(0.015), 0.002, 0.04);
        s.origin = Some(0.0);
        let p = plan(&job, &s).unwrap();
        let (text, w) = write_gcode(&p, &Travel::default(), &["test".into()]);
        let parsed: Vec<_> = Parser::new(text.as_bytes(), "out", GcodeOptions::default())
            .collect::<Result<Vec<_>, _>>()
            .unwrap_or_else(|e| panic!("{e}\n{text}"));
        let out: f64 = parsed.iter().filter(|g| g.segment.extrudes()).map(|g| g.segment.filament).sum();
        assert!((out - job.filament()).abs() <= 1e-9 * job.filament(), "{out} vs {}", job.filament());
        // Order: strip 1 layers 1, 2, then strip 2 layers 1, 2 (layer tags from the ;LAYER: markers).
        let mut order: Vec<(usize, i32)> = Vec::new();
        let strip_lines: Vec<usize> =
            text.lines().enumerate().filter(|(_, l)| l.starts_with("; strip") && l.contains(" of ")).map(|(i, _)| i + 1).collect();
        for g in parsed.iter().filter(|g| g.segment.extrudes()) {
            let strip = strip_lines.iter().filter(|&&l| l < g.line).count();
            let key = (strip, g.tags.layer.unwrap());
            if order.last() != Some(&key) {
                order.push(key);
            }
        }
        assert_eq!(order, vec![(1, 0), (1, 1), (2, 0), (2, 1)]);
        // Layer 1: strip 1 ends at 13 mm. The loop is cut into a U on each side. Strip 1: the line,
        // then the U from its end nearest (13, 0): 2 paths. Strip 2: the line (13 → 30 mm), then the
        // endpoint nearest (30, 0) is the U's corner (20, 10), so the U is two paths: 3 paths.
        assert_eq!(p.strips[0].layers.iter().map(|l| l.paths.len()).collect::<Vec<_>>(), vec![2, 2]);
        assert_eq!(p.strips[1].layers.iter().map(|l| l.paths.len()).collect::<Vec<_>>(), vec![3, 3]);
        assert_eq!(p.strips[1].layers[0].paths[1][0].a, Vector3::new(0.02, 0.01, 0.001));
        // Travels: one per path (the first from the start position); a retraction before all but the first.
        assert_eq!((w.travels, w.retractions), (10, 9));
    }
}
