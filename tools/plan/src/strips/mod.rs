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
//!
//! The code is split by idea: `read` (the job into layers of lines), `equations` (Eqs. 2-4), `joint`
//! (the staggered boundaries and the cutting at them), `chaining` (Fig. 8), `output` (the G-code) and
//! `plot` (the PNG); this file keeps the plan's types, `plan` itself, the JSON report and the
//! `strand-plan strips` command line, and re-exports the rest.

use std::fmt::Write as _;
use std::path::PathBuf;

use serde::Serialize;
use serde_json::json;
use strand_job::gcode::{GcodeOptions, parse_file};

mod chaining;
mod equations;
mod joint;
mod output;
mod plot;
mod read;

pub use chaining::chain;
pub use equations::{Checks, Eq2, Eq3, Eq4, check_equations};
pub use joint::{BOUNDARY_EPS, cut, layer_bounds};
use output::mm;
pub use output::{Travel, Written, write_gcode};
pub use plot::plot_png;
pub use read::{Job, Layer, Line, ReadOptions, flatten_arc, read_job};
use strand_cli::error::{Result, ToolError};

/// Direction the strips are measured along.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// Along x.
    X,
    /// Along y.
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

/// Strip widths: all equal (as many strips as the part needs) or given one by one.
#[derive(Clone, Debug, PartialEq)]
pub enum Widths {
    /// Every strip this wide (m).
    Uniform(f64),
    /// Strip by strip (m), from the origin.
    List(Vec<f64>),
}

/// What to split and how.
#[derive(Clone, Debug, PartialEq)]
pub struct StripSpec {
    /// The direction the strips are measured along.
    pub axis: Axis,
    /// Their widths.
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

/// One layer of one strip.
#[derive(Clone, Debug, PartialEq)]
pub struct StripLayer {
    /// Job layer (0-based).
    pub layer: usize,
    /// Its height (m).
    pub z: f64,
    /// This layer's bounds of the strip along the axis (m): the nominal ones moved per Fig. 6.
    pub lo: f64,
    /// The upper bound (m).
    pub hi: f64,
    /// Paths in print order.
    pub paths: Vec<Vec<Line>>,
}

/// One strip: every layer of it is printed before the next strip.
#[derive(Clone, Debug, PartialEq)]
pub struct Strip {
    /// Nominal bounds along the axis (m).
    pub lo: f64,
    /// The upper nominal bound (m).
    pub hi: f64,
    /// Layers that have lines in this strip, bottom up.
    pub layers: Vec<StripLayer>,
}

impl Strip {
    /// Its nominal width (m).
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
    /// The direction the strips are measured along.
    pub axis: Axis,
    /// Nominal bounds: origin, the boundaries between strips, far end (m, ascending).
    pub bounds: Vec<f64>,
    /// L, the overlap between neighbouring strips (m).
    pub overlap: f64,
    /// N.
    pub layers: usize,
    /// The strips, in print order.
    pub strips: Vec<Strip>,
    /// Eqs. 2-4 against this split.
    pub checks: Checks,
    /// Lines cut at a boundary.
    pub cuts: usize,
}

/// Most strips a plan may have (a job far wider than the strips is a mistake, not a plan).
pub(crate) const MAX_STRIPS: usize = 10_000;

/// Splits `job` per `spec`: nominal strips, Eqs. 2-4, the staggered boundaries, cutting, chaining.
/// Errors name the flag.
pub fn plan(job: &Job, spec: &StripSpec) -> Result<Plan> {
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
        return Err(ToolError::Plan(format!(
            "--origin {origin} m: the job extrudes at {a} = {lo} m ({}:{lo_line}), before the origin",
            job.name
        )));
    }
    let widths: Vec<f64> = match &spec.widths {
        Widths::Uniform(w) => {
            let n = (((hi - origin) - BOUNDARY_EPS) / w).ceil().max(1.0);
            if n.is_nan() || n > MAX_STRIPS as f64 {
                return Err(ToolError::Plan(format!(
                    "--width {w} m: the job extrudes from {a} = {origin} m to {a} = {hi} m ({}:{hi_line}), {n} strips; at most {MAX_STRIPS}",
                    job.name
                )));
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
        return Err(ToolError::Plan(format!(
            "--widths: the strips end at {a} = {end} m but the job extrudes up to {a} = {hi} m ({}:{hi_line}); add a strip or widen them",
            job.name
        )));
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

/// Strip widths: one for all strips, or one per strip.
#[derive(Debug, Clone)]
pub struct StripWidths {
    /// Strip width W (m); as many strips as the part needs, the last one possibly not full.
    pub width: Option<f64>,
    /// Strip widths (m), comma-separated, in print order (000's truss: 0.043,0.06,0.047).
    pub widths: Option<Vec<f64>>,
}

/// `strand-plan strips`: split a planar job into strips (000 Section 3.2).
#[derive(Debug, Clone)]
pub struct StripsOptions {
    /// The G-code job.
    pub job: PathBuf,
    /// The strips' width or widths.
    pub width: StripWidths,
    /// Overlap L (m): how far the boundaries move per layer below the top (000 Fig. 6).
    pub overlap: f64,
    /// Reach R (m) of the manipulator across the strips (Eq. 2: W ≤ R/2).
    pub reach: f64,
    /// Axis the strips are measured along.
    pub axis: Axis,
    /// Where strip 1 starts along the axis (m); default: the part's smallest coordinate.
    pub origin: Option<f64>,
    /// Nominal position x,y (m) each layer's chaining starts from (000: the origin).
    pub start: Vec<f64>,
    /// Endpoints closer than this (m) continue a path.
    pub join_tolerance: f64,
    /// Largest sagitta (m) of the chords replacing an arc.
    pub arc_tolerance: f64,
    /// Keep skirt and brim lines (dropped by default: not part of the structure).
    pub keep_skirt: bool,
    /// Travel speed between paths (m/s).
    pub travel_speed: f64,
    /// Filament retracted before each travel (m; 0: none).
    pub retract: f64,
    /// Retraction speed (m/s of filament).
    pub retract_speed: f64,
    /// Lift during travels (m; 0: none).
    pub z_hop: f64,
    /// Write the G-code here (default: standard output, unless --json).
    pub output: Option<PathBuf>,
    /// Draw the nominal and the split job (like 000's Fig. 13) into this PNG.
    pub png: Option<PathBuf>,
    /// Print one JSON report on standard output.
    pub json: bool,
}

fn non_negative(flag: &str, v: f64) -> Result<()> {
    if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(ToolError::Usage(format!("--{flag} {v}: must be finite and ≥ 0"))) }
}

impl StripsOptions {
    fn spec(&self) -> Result<StripSpec> {
        let widths = match (&self.width.width, &self.width.widths) {
            (Some(w), _) => {
                super::positive("width", *w)?;
                Widths::Uniform(*w)
            }
            (None, Some(ws)) => {
                if ws.is_empty() {
                    return Err(ToolError::Usage("--widths: give at least one width".to_string()));
                }
                for (k, w) in ws.iter().enumerate() {
                    super::positive(&format!("widths (strip {})", k + 1), *w)?;
                }
                Widths::List(ws.clone())
            }
            (None, None) => return Err(ToolError::Usage("give --width or --widths".to_string())),
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
            return Err(ToolError::Usage(format!("--origin {o}: must be finite")));
        }
        let start = match self.start.as_slice() {
            [x, y] if x.is_finite() && y.is_finite() => [*x, *y],
            _ => return Err(ToolError::Usage(format!("--start {:?}: expected X,Y in metres", self.start))),
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
pub fn run(args: &StripsOptions) -> Result<()> {
    let spec = args.spec()?;
    let name = args.job.display().to_string();
    let mut parser = parse_file(&args.job, GcodeOptions::for_path(&args.job))?;
    let job = read_job(&mut parser, &name, &ReadOptions { arc_tolerance: args.arc_tolerance, keep_skirt: args.keep_skirt })?;
    let plan = plan(&job, &spec)?;
    let travel = Travel { speed: args.travel_speed, retract: args.retract, retract_speed: args.retract_speed, z_hop: args.z_hop };
    let (text, written) = write_gcode(&plan, &travel, &args.header(&job, &plan));
    match &args.output {
        Some(p) => std::fs::write(p, &text).map_err(|e| ToolError::Plan(format!("--output {}: {e}", p.display())))?,
        None if !args.json => print!("{text}"),
        None => {}
    }
    if let Some(p) = &args.png {
        plot_png(&job, &plan, p).map_err(|e| ToolError::Plan(format!("--png {e}")))?;
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

/// Fixtures shared by the submodules' unit tests.
#[cfg(test)]
mod fixtures {
    use super::*;
    use nalgebra::Vector3;
    use strand_job::gcode::Parser;

    pub(super) fn line(a: [f64; 3], b: [f64; 3], filament: f64) -> Line {
        Line { a: Vector3::from(a), b: Vector3::from(b), filament, feed: 0.02, source_line: 1 }
    }

    pub(super) fn job_from(text: &str) -> Job {
        let mut parser = Parser::new(text.as_bytes(), "test.gcode", GcodeOptions::default());
        read_job(&mut parser, "test.gcode", &ReadOptions::default()).unwrap()
    }

    pub(super) fn spec(widths: Widths, overlap: f64, reach: f64) -> StripSpec {
        StripSpec { axis: Axis::X, widths, origin: None, overlap, reach, start: [0.0, 0.0], join_tolerance: 1e-6 }
    }
}
