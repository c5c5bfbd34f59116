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
//!
//! The code is split by idea: `shapes` (the [`Surface`] trait and the faces), `sampling` (Algorithms 1
//! and 2), `ordering` (Algorithms 3, 4 and 5), `intersect` (self-intersections in the parameter plane),
//! `output` (the segment stream and its file) and `plot` (the PNG); this file keeps the report and the
//! `strand-plan surface` command line, and re-exports the rest.

use std::f64::consts::PI;
use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;
use strand_cli::error::{Result, ToolError};

mod intersect;
mod ordering;
mod output;
mod plot;
mod sampling;
mod shapes;
mod step;

pub use intersect::{Contact, ContactKind, self_intersections};
pub use ordering::{Algorithm, Axis, PlannedPath, Weighting, bounding_diagonal, greedy, path_length, plan, tsp, weighted_greedy};
pub use output::{Curvature, Deposition, curvature, layered_segments, segments, segments_on, steps_off_face, write_segments};
pub use plot::{Panel, plot_png};
pub use sampling::{MAX_SAMPLES, PointCloud, Sample, Sampling, SamplingMode, sample};
pub use shapes::{Blade, Bump, CurvedRect, Cylinder, Domain, Plane, Surface, eq2_normal};
pub use step::{Placement, StepSurface, list_faces};

// ---------------------------------------------------------------------------------------------------------
// Report
// ---------------------------------------------------------------------------------------------------------

/// One algorithm's result, as `--json` prints it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub(crate) struct AlgorithmReport {
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
    pub(crate) fn new(path: &PlannedPath, contacts: &[Contact]) -> AlgorithmReport {
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
// Options (strand-plan's command line maps onto these)
// ---------------------------------------------------------------------------------------------------------

/// The surfaces `strand-plan surface` knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
#[derive(Clone, PartialEq, Debug)]
pub struct SurfaceOptions {
    /// The surface.
    pub shape: Shape,
    /// Desired distance between samples in both directions, d*_u = d*_v (m; 003 uses 10 mm).
    pub spacing: f64,
    /// Relative tolerance of the step calibration, Algorithm 2 (1; the paper's 1/t).
    pub tolerance: f64,
    /// Algorithm 1 as printed, or made robust.
    pub sampling: SamplingMode,
    /// Path algorithm(s).
    pub algorithm: AlgorithmChoice,
    /// Weighted greedy: the weight added to the distance of a sample off the current row (m; default the
    /// cloud's bounding-box diagonal, so the row is always finished first).
    pub weight: Option<f64>,
    /// TSP: candidates per sample in the 2-opt neighbour lists (1).
    pub neighbours: usize,
    /// curved-rect: width along x (across the bend); plane: extent along x; cylinder, bump: length along x (m)
    /// [default 0.1].
    pub length: Option<f64>,
    /// plane: extent along y; bump: extent along y across the ridge (m) [default 0.1].
    pub width: Option<f64>,
    /// curved-rect: bend radius; cylinder: radius (m) [default 0.05].
    pub radius: Option<f64>,
    /// curved-rect: bend angle; cylinder: angle the patch spans (rad) [default 2π/3].
    pub sweep: Option<f64>,
    /// bump: peak height z0 (m) [default 3 mm, 002].
    pub height: Option<f64>,
    /// bump: width parameter β (m) [default 18 mm, 002].
    pub beta: Option<f64>,
    /// blade: hub radius, where the span starts (m).
    pub hub_radius: f64,
    /// blade: tip radius, where the span ends (m).
    pub tip_radius: f64,
    /// blade: widest chord (m).
    pub chord: f64,
    /// blade: geometric pitch (m per turn).
    pub pitch: f64,
    /// blade: camber height as a fraction of the half chord (1).
    pub camber: f64,
    /// Extrusion line width (m).
    pub line_width: f64,
    /// Layer height (m).
    pub layer_height: f64,
    /// Filament diameter (m).
    pub filament_diameter: f64,
    /// Print speed (m/s).
    pub speed: f64,
    /// Travel speed to the first sample (m/s).
    pub travel_speed: f64,
    /// Nozzle tip offset from the surface along its normal (m) [default: the layer height].
    pub standoff: Option<f64>,
    /// Write the path as segments (JSON lines, strand_job::segfile); needs one --algorithm.
    pub output: Option<PathBuf>,
    /// Draw the paths in the (u, v) plane, self-intersections marked.
    pub png: Option<PathBuf>,
    /// Print one JSON object instead of the summary.
    pub json: bool,
    /// A face of this STEP model instead of `shape`.
    pub step: Option<PathBuf>,
    /// The STEP face by index (as `list_faces` numbers them).
    pub face: Option<usize>,
    /// The STEP face by its label.
    pub face_name: Option<String>,
    /// List the STEP model's faces and stop.
    pub list_faces: bool,
    /// Print the STEP face from its other side (the nozzle along +normal of the file's face).
    pub flip_normal: bool,
    /// Where the STEP face's points go in the segment file.
    pub place: Placement,
    /// Layers, each offset one layer height further along the normal (1).
    pub layers: usize,
    /// Run the written path through `strand check-job` with `config`.
    pub check: bool,
    /// Service config for `check` (resolved path).
    pub config: Option<PathBuf>,
}

impl Default for SurfaceOptions {
    /// The values `strand-plan` uses when no flag is given.
    fn default() -> Self {
        SurfaceOptions {
            shape: Shape::CurvedRect,
            spacing: 0.01,
            tolerance: 0.01,
            sampling: SamplingMode::Robust,
            algorithm: AlgorithmChoice::All,
            weight: None,
            neighbours: 10,
            length: None,
            width: None,
            radius: None,
            sweep: None,
            height: None,
            beta: None,
            hub_radius: 0.03,
            tip_radius: 0.15,
            chord: 0.06,
            pitch: 0.2,
            camber: 0.1,
            line_width: 0.45e-3,
            layer_height: 0.2e-3,
            filament_diameter: 1.75e-3,
            speed: 0.01,
            travel_speed: 0.05,
            standoff: None,
            output: None,
            png: None,
            json: false,
            step: None,
            face: None,
            face_name: None,
            list_faces: false,
            flip_normal: false,
            place: Placement::Model,
            layers: 1,
            check: false,
            config: None,
        }
    }
}

impl SurfaceOptions {
    /// The surface the flags describe, with its defaults filled in; errors name the flag and value.
    pub fn surface(&self) -> Result<Box<dyn Surface>> {
        if let Some(file) = &self.step {
            let model = strand_cad::read_step(file).map_err(step::cad)?;
            return Ok(Box::new(StepSurface::new(&model, self.face, self.face_name.as_deref(), self.flip_normal, self.place)?));
        }
        let length = super::positive("length", self.length.unwrap_or(0.1))?;
        let width = super::positive("width", self.width.unwrap_or(0.1))?;
        let radius = super::positive("radius", self.radius.unwrap_or(0.05))?;
        let sweep = super::positive("sweep", self.sweep.unwrap_or(2.0 * PI / 3.0))?;
        Ok(match self.shape {
            Shape::CurvedRect => {
                if sweep > 2.0 * PI {
                    return Err(ToolError::Plan(format!(
                        "--sweep = {sweep} rad: the bend must stay below 2π (the sheet would pass through itself)"
                    )));
                }
                Box::new(CurvedRect { width: length, radius, bend: sweep })
            }
            Shape::Plane => Box::new(Plane { length, width, z: 0.0 }),
            Shape::Cylinder => {
                if sweep >= 2.0 * PI {
                    return Err(ToolError::Plan(format!("--sweep = {sweep} rad: a patch must span less than 2π")));
                }
                Box::new(Cylinder { radius, length, sweep })
            }
            Shape::Bump => {
                let height = self.height.unwrap_or(3.0e-3);
                if !height.is_finite() {
                    return Err(ToolError::Plan(format!("--height = {height}: must be finite")));
                }
                Box::new(Bump { length, width, height, beta: super::positive("beta", self.beta.unwrap_or(18.0e-3))? })
            }
            Shape::Blade => {
                let hub = super::positive("hub-radius", self.hub_radius)?;
                let tip = super::positive("tip-radius", self.tip_radius)?;
                if tip <= hub {
                    return Err(ToolError::Plan(format!("--tip-radius = {tip} m must exceed --hub-radius = {hub} m")));
                }
                let chord = super::positive("chord", self.chord)?;
                let pitch = super::positive("pitch", self.pitch)?;
                if !(self.camber.is_finite() && self.camber.abs() <= 1.0) {
                    return Err(ToolError::Plan(format!("--camber = {}: must lie in [-1, 1]", self.camber)));
                }
                Box::new(Blade { hub_radius: hub, tip_radius: tip, chord, pitch, camber: self.camber, lift: chord })
            }
        })
    }

    /// The sampling request; errors name the flag.
    pub fn sampling(&self) -> Result<Sampling> {
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            return Err(ToolError::Usage(format!("--spacing = {}: must be positive", self.spacing)));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0 && self.tolerance < 1.0) {
            return Err(ToolError::Usage(format!("--tolerance = {}: must lie in (0, 1)", self.tolerance)));
        }
        Ok(Sampling { spacing_u: self.spacing, spacing_v: self.spacing, tolerance: self.tolerance, mode: self.sampling })
    }

    /// The deposition parameters; errors name the flag.
    pub fn deposition(&self) -> Result<Deposition> {
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

/// The chosen STEP face, as the report names it.
struct StepChoice {
    file: String,
    index: usize,
    entity: u64,
    kind: &'static str,
    area_m2: f64,
    offset: nalgebra::Vector3<f64>,
}

/// `strand-plan surface`: samples, plans, reports (summary or `--json`), and writes the segment file and
/// the PNG if asked; with `--step`, on a face of the user's model, and with `--check`, checks the written
/// path on the robot (an error if the check refuses it).
pub fn run(args: &SurfaceOptions) -> Result<()> {
    if args.list_faces {
        let Some(file) = &args.step else {
            return Err(ToolError::Usage("--list-faces lists the faces of a STEP model: give --step FILE".to_string()));
        };
        let model = strand_cad::read_step(file).map_err(step::cad)?;
        println!("{}", list_faces(&model, args.json).trim_end());
        return Ok(());
    }
    if args.check && args.output.is_none() {
        return Err(ToolError::Usage("--check checks the path it writes: give --output FILE".to_string()));
    }
    if args.layers == 0 {
        return Err(ToolError::Usage("--layers 0: print at least one layer".to_string()));
    }
    let (surface, choice): (Box<dyn Surface>, Option<StepChoice>) = match &args.step {
        Some(file) => {
            let model = strand_cad::read_step(file).map_err(step::cad)?;
            let s = StepSurface::new(&model, args.face, args.face_name.as_deref(), args.flip_normal, args.place)?;
            let f = s.face();
            let choice = StepChoice {
                file: file.display().to_string(),
                index: f.index,
                entity: f.entity,
                kind: f.kind.name(),
                area_m2: f.area_m2,
                offset: s.offset,
            };
            (Box::new(s), Some(choice))
        }
        None => (args.surface()?, None),
    };
    let sampling = args.sampling()?;
    let deposition = args.deposition()?;
    if let Some(w) = args.weight
        && !(w.is_finite() && w >= 0.0)
    {
        return Err(ToolError::Plan(format!("--weight = {w}: must be a non-negative length (m)")));
    }
    if args.neighbours == 0 {
        return Err(ToolError::Plan("--neighbours = 0: the 2-opt needs at least one candidate per sample".to_string()));
    }
    let algorithms = args.algorithms();
    if args.output.is_some() && algorithms.len() != 1 {
        return Err(ToolError::Plan(
            "--output writes one path: give one --algorithm (greedy, weighted-u, weighted-v or tsp), not all".to_string(),
        ));
    }
    let t0 = Instant::now();
    let cloud = sample(surface.as_ref(), &sampling).map_err(|e| ToolError::Plan(format!("--spacing = {} m: {e}", args.spacing)))?;
    let sampling_s = t0.elapsed().as_secs_f64();
    if cloud.samples.len() < 2 {
        return Err(ToolError::Plan(format!(
            "--spacing = {} m leaves {} sample(s) on the surface: nothing to print",
            args.spacing,
            cloud.samples.len()
        )));
    }
    let mut results = Vec::new();
    for &a in &algorithms {
        let path = plan(&cloud, a, args.weight, args.neighbours);
        let contacts = self_intersections(&cloud, &path.order);
        results.push((path, contacts));
    }
    let name = match &choice {
        Some(c) => format!("{} face {} ({} #{})", c.file, c.index, c.kind, c.entity),
        None => shape_name(args.shape).to_string(),
    };
    // What the nozzle cannot do here, said before anything runs: on the path that is written (or on
    // each path when only comparing).
    let mut warnings = Vec::new();
    let bend = curvature(&cloud, &results[0].0.order, 2.0 * args.spacing);
    let offset = deposition.standoff + (args.layers - 1) as f64 * deposition.layer_height;
    if let Some(r) = bend.min_concave_radius_m {
        if r <= offset {
            warnings.push(format!(
                "too curved for the layers: the face bends towards the nozzle with a radius of {:.2} mm, less than the {:.2} mm the layers stand off it: the offset layers fold over themselves",
                r * 1e3,
                offset * 1e3
            ));
        } else if r < 10.0 * deposition.line_width {
            warnings.push(format!(
                "too curved for the nozzle: the face bends towards it with a radius of {:.2} mm (under 10 line widths, {:.2} mm): the nozzle's tip may touch the surface beside the bead",
                r * 1e3,
                10e3 * deposition.line_width
            ));
        }
    }
    if let Some(r) = bend.min_convex_radius_m
        && r < 2.0 * deposition.line_width
    {
        warnings.push(format!(
            "too curved for the bead: the face bends away with a radius of {:.2} mm, under two line widths ({:.2} mm)",
            r * 1e3,
            2e3 * deposition.line_width
        ));
    }
    for (path, _) in &results {
        let off = steps_off_face(&cloud, &path.order, &|u, v| surface.contains(u, v));
        if off > 0 {
            warnings.push(format!(
                "{off} steps of the {} path would leave the face (over a hole or a notch of its trim): written as travels lifted {:.1} mm, no bead",
                path.algorithm.name(),
                deposition.lift() * 1e3
            ));
        }
    }
    for (path, contacts) in &results {
        let crossings = contacts.iter().filter(|c| c.kind == ContactKind::Proper).count();
        if crossings > 0 {
            warnings.push(format!(
                "the {} path crosses itself {crossings} times in (u, v): the bead would be laid over itself (weighted greedy keeps to rows)",
                path.algorithm.name()
            ));
        }
    }
    if let Some(file) = &args.output {
        let (path, _) = &results[0];
        let segs = layered_segments(&cloud, &path.order, &deposition, args.layers, &|u, v| surface.contains(u, v));
        let source = match &choice {
            Some(c) => format!(
                "--step {} --face {} (entity #{}, {}, {:.3} mm²), placement {}: offset [{:.6}, {:.6}, {:.6}] m from the model frame",
                c.file,
                c.index,
                c.entity,
                c.kind,
                c.area_m2 * 1e6,
                args.place.name(),
                c.offset.x,
                c.offset.y,
                c.offset.z
            ),
            None => format!("--shape {name}"),
        };
        let note = format!(
            "strand-plan surface {source} --spacing {} --algorithm {} --layers {} ({} samples, {:.4} m a layer)",
            args.spacing,
            path.algorithm.name(),
            args.layers,
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
    let check = match (&args.output, args.check) {
        (Some(file), true) => Some(check_path(file, args.config.as_deref())?),
        _ => None,
    };
    if args.json {
        let mut algos = serde_json::Map::new();
        for (path, contacts) in &results {
            let report = AlgorithmReport::new(path, contacts);
            algos.insert(path.algorithm.name().to_string(), serde_json::to_value(report).expect("a report serialises"));
        }
        let mut out = serde_json::json!({
            "shape": name,
            "spacing_m": args.spacing,
            "sampling": match args.sampling { SamplingMode::Paper => "paper", SamplingMode::Robust => "robust" },
            "samples": cloud.samples.len(),
            "sampling_s": sampling_s,
            "algorithms": algos,
            "layers": args.layers,
            "min_concave_radius_m": bend.min_concave_radius_m,
            "min_convex_radius_m": bend.min_convex_radius_m,
            "warnings": warnings,
        });
        if let Some(c) = &choice {
            out["step"] = serde_json::json!({
                "file": c.file, "face": c.index, "entity": c.entity, "type": c.kind, "area_m2": c.area_m2,
                "placement": args.place.name(), "offset_m": [c.offset.x, c.offset.y, c.offset.z],
            });
        }
        if let Some(report) = &check {
            out["check"] = serde_json::to_value(report).expect("a check report serialises");
        }
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
        for w in &warnings {
            println!("  warning: {w}");
        }
        if let Some(f) = &args.output {
            println!("  wrote {}", f.display());
        }
        if let Some(f) = &args.png {
            println!("  wrote {}", f.display());
        }
        if let Some(report) = &check {
            println!("{}", report.summary().trim_end());
        }
    }
    match check {
        Some(report) if !report.clean => Err(ToolError::Refused(format!(
            "{}: the check on {} refused the path ({}; see the report)",
            args.output.as_ref().expect("checked a written path").display(),
            report.robot,
            report.outcome
        ))),
        _ => Ok(()),
    }
}

/// Runs the written segment file through `strand check-job`'s check: the same controller, the same
/// loading as strand-feed (the config's bed), reach, limits and singular stretches.
fn check_path(file: &std::path::Path, config: Option<&std::path::Path>) -> Result<strand::check::CheckReport> {
    let config = config.ok_or_else(|| ToolError::Usage("--check needs the robot's config: give --config C".to_string()))?;
    let cfg = strand::config::Config::load(config)?;
    let job = strand_feed::load_gcode(file, &cfg, None)?;
    let name = file.display().to_string();
    let check_job = strand::check::CheckJob { file: &name, segments: &job.segments, layers: &job.layers };
    Ok(strand::check::check_with_trajectory(&check_job, &cfg, None, None)?)
}

fn shape_sampling(args: &SurfaceOptions) -> &'static str {
    match args.sampling {
        SamplingMode::Paper => "paper",
        SamplingMode::Robust => "robust",
    }
}

/// Fixtures shared by the submodules' unit tests.
#[cfg(test)]
mod fixtures {
    use super::*;
    use nalgebra::Vector3;

    pub(super) const D: f64 = 0.01;

    pub(super) fn robust(tolerance: f64) -> Sampling {
        Sampling { spacing_u: D, spacing_v: D, tolerance, mode: SamplingMode::Robust }
    }

    pub(super) fn paper() -> Sampling {
        Sampling { spacing_u: D, spacing_v: D, tolerance: 0.01, mode: SamplingMode::Paper }
    }

    pub(super) fn curved() -> CurvedRect {
        CurvedRect { width: 0.1, radius: 0.05, bend: 2.0 * PI / 3.0 }
    }

    pub(super) fn bump() -> Bump {
        Bump { length: 0.1, width: 0.1, height: 3.0e-3, beta: 18.0e-3 }
    }

    pub(super) fn cylinder() -> Cylinder {
        Cylinder { radius: 0.05, length: 0.1, sweep: 2.0 * PI / 3.0 }
    }

    pub(super) fn blade() -> Blade {
        Blade { hub_radius: 0.03, tip_radius: 0.15, chord: 0.06, pitch: 0.2, camber: 0.1, lift: 0.06 }
    }

    /// A cloud from (u, v) points on the plane z = 0.
    pub(super) fn cloud_of(uv: &[(f64, f64)]) -> PointCloud {
        let samples = uv.iter().map(|&(u, v)| Sample { u, v, point: Vector3::new(u, v, 0.0), normal: Vector3::z() }).collect();
        PointCloud { samples, step_u: 1.0, step_v: 1.0, evaluations: 0, periods: [None; 2] }
    }

    pub(super) fn identity(n: usize) -> Vec<usize> {
        (0..n).collect()
    }
}
