//! strand-plan's command line: the clap arguments of each planner, and their conversion into the
//! plain options structs of `strand_plan` (which know nothing of clap). The defaults here are
//! pinned to the planners' own `Default`s by a test.

use std::path::PathBuf;

use clap::ValueEnum;
use strand_plan::{base, finish, strips, surface, tilt};

/// How the job's path becomes a time series.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Timing {
    /// The controller's own path engine (junction blending, jerk-limited time scaling).
    Controller,
    /// Each segment at its programmed feed (000's constant speed).
    Constant,
}

/// Direction the strips are measured along.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Axis {
    X,
    Y,
}

/// The surfaces `strand-plan surface` knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
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

/// Where a STEP face's points go in the segment file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Placement {
    /// The model's own frame (m): where the CAD put the part relative to its origin.
    Model,
    /// The face's bounding box moved to start at the bed origin.
    Origin,
    /// The face's bounding box centred on the bed origin in x and y, its lowest point at z = 0.
    Centre,
}

/// Which version of Algorithm 1 to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
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

/// The profile of Eq. 20 and the raster laid over it (SI units).
#[derive(Clone, Debug, clap::Args)]
pub struct FinishParams {
    /// Height z₀ of the profile (m; 002: 3 mm).
    #[arg(long, default_value_t = 3e-3)]
    pub z0: f64,
    /// Width β of the profile (m; 002: 18 mm).
    #[arg(long, default_value_t = 18e-3)]
    pub beta: f64,
    /// The layer covers y from −half_length to +half_length (m).
    #[arg(long, default_value_t = 45e-3)]
    pub half_length: f64,
    /// Width of the part along x (m); paths run from x = 0 to this.
    #[arg(long, default_value_t = 20e-3)]
    pub width: f64,
    /// Distance between neighbouring paths along x (m): the strand width.
    #[arg(long, default_value_t = 0.45e-3)]
    pub spacing: f64,
    /// Length of the chords that make up a path (m).
    #[arg(long, default_value_t = 0.5e-3)]
    pub step: f64,
    /// Layer thickness (m): the nozzle runs this far from the surface along its normal.
    #[arg(long, default_value_t = 0.2e-3)]
    pub layer_height: f64,
    /// Filament diameter (m).
    #[arg(long, default_value_t = 1.75e-3)]
    pub filament: f64,
    /// Print speed (m/s).
    #[arg(long, default_value_t = 0.01)]
    pub feed: f64,
    /// Height of the profile's foot above the bed (m).
    #[arg(long, default_value_t = 0.0)]
    pub z_base: f64,
}

/// `strand-plan finish`.
#[derive(Clone, Debug, clap::Args)]
pub struct FinishArgs {
    /// The profile and the raster.
    #[command(flatten)]
    pub finish: FinishParams,
    /// The segment file to write.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Print a JSON summary.
    #[arg(long)]
    pub json: bool,
}

/// `strand-plan tilt`.
#[derive(Clone, Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("angle_source").required(true).args(["angle_deg", "bolt_height"])))]
pub struct TiltArgs {
    /// The G-code job, in the bed's own frame.
    pub job: PathBuf,
    /// Tilt α of the bed about its x axis (degrees, 0 ≤ α < 90; 004 printed at 10, 45, 60, 80).
    #[arg(long = "angle")]
    pub angle_deg: Option<f64>,
    /// Eq. 7: the adjustable bolt's height h (m) …
    #[arg(long, requires = "bolt_distance")]
    pub bolt_height: Option<f64>,
    /// … over the distance d between the bolts (m): α = atan(h / d).
    #[arg(long)]
    pub bolt_distance: Option<f64>,
    /// The segment file to write.
    #[arg(long, short)]
    pub output: PathBuf,
}

/// `strand-plan base`.
#[derive(Clone, Debug, clap::Args)]
pub struct BaseArgs {
    /// The G-code job (its frame: x along the job, the base beside it).
    pub job: PathBuf,
    /// Nominal reach r_nom (m): the arm's extension at the print origin (000: 230 mm).
    #[arg(long, default_value_t = 0.23)]
    pub r_nom: f64,
    /// Reach limit (m): Algorithm 1 stops when the reach would exceed it (000: 270 mm).
    #[arg(long, default_value_t = 0.27)]
    pub reach_limit: f64,
    /// Direction from the base to the print (degrees from +x towards +y; 90: the base on the −y side).
    #[arg(long, default_value_t = 90.0, allow_negative_numbers = true)]
    pub direction_deg: f64,
    /// Sample period of the trajectory (s; 000: 60 ms, its position update rate).
    #[arg(long, default_value_t = 0.06)]
    pub dt: f64,
    /// First cut-off tried (Hz).
    #[arg(long, default_value_t = 0.01)]
    pub fc_start: f64,
    /// Step Δf_c by which the cut-off is lowered (Hz).
    #[arg(long, default_value_t = 1e-4)]
    pub fc_step: f64,
    /// Base mass for W_FF (kg; the sim's free flyer).
    #[arg(long, default_value_t = 266.7)]
    pub mass: f64,
    /// How the path becomes a time series.
    #[arg(long, value_enum, default_value_t = Timing::Controller)]
    pub timing: Timing,
    /// Service config whose [path] limits and rate time the job (`--timing controller`): a file or
    /// a NAME; default: free-flyer.toml by the search order ($STRAND_CONFIG_DIR, ./config,
    /// <prefix>/share/strand/config, the built-in copy).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Write t, tcp_x, tcp_y, base_x, base_y, s (s, m; s the print's progress) at the chosen cut-off.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write the base trajectory for strand-sim (t, base_x, base_y in W, from the --config's mount).
    #[arg(long)]
    pub trajectory: Option<PathBuf>,
    /// With --trajectory: hold the mount this long before following the job (s; the approach).
    #[arg(long, default_value_t = 0.0)]
    pub start_delay: f64,
    /// Write the base's plan by the print's progress for the service's `[base] plan_file` (s,
    /// base_x, base_y: m of path from the job's first point, m in W from the --config's mount): the
    /// base then follows the nozzle through pauses and overrides, not the clock.
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Also tabulate a_max, r_max and W_FF over cut-offs from --fc-step to --fc-start (000 Fig. 4).
    #[arg(long)]
    pub sweep: bool,
    /// PNG: with --sweep 000's Fig. 4, otherwise the paths of Fig. 5 at the chosen cut-off.
    #[arg(long)]
    pub png: Option<PathBuf>,
}

/// Strip widths: one for all strips, or one per strip.
#[derive(Clone, Debug, clap::Args)]
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
#[derive(Clone, Debug, clap::Args)]
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
    /// A face of this STEP model (AP203/AP214 B-rep; its unit, mm by default, becomes m) instead of
    /// --shape.
    #[arg(long, value_name = "FILE")]
    pub step: Option<PathBuf>,
    /// The STEP face by index, from 0 (--list-faces shows them); not needed for a one-face model.
    #[arg(long, value_name = "N")]
    pub face: Option<usize>,
    /// The STEP face by its name (the face entity's label).
    #[arg(long, value_name = "NAME")]
    pub face_name: Option<String>,
    /// List the STEP model's faces (index, entity, type, area, bounding box) and stop; with --json one
    /// JSON array.
    #[arg(long)]
    pub list_faces: bool,
    /// Print the STEP face from its other side (its normal points out of a solid, or as the file has it
    /// for a loose face; the nozzle comes from the normal's side).
    #[arg(long)]
    pub flip_normal: bool,
    /// Where the STEP face's points go in the segment file (the header records the offset).
    #[arg(long, value_enum, default_value = "model")]
    pub place: Placement,
    /// Layers, each one layer height further out along the normal, every other one backwards.
    #[arg(long, default_value_t = 1)]
    pub layers: usize,
    /// Check the written path on the robot before it runs (strand check-job: reach, joint limits,
    /// singular stretches); exit 3 if it is refused. Needs --output.
    #[arg(long)]
    pub check: bool,
    /// Service config for --check: a file or a NAME (`iiwa7`); default default.toml by the search order.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

impl From<Timing> for base::Timing {
    fn from(v: Timing) -> Self {
        match v {
            Timing::Controller => base::Timing::Controller,
            Timing::Constant => base::Timing::Constant,
        }
    }
}

impl From<Axis> for strips::Axis {
    fn from(v: Axis) -> Self {
        match v {
            Axis::X => strips::Axis::X,
            Axis::Y => strips::Axis::Y,
        }
    }
}

impl From<Shape> for surface::Shape {
    fn from(v: Shape) -> Self {
        match v {
            Shape::CurvedRect => surface::Shape::CurvedRect,
            Shape::Plane => surface::Shape::Plane,
            Shape::Cylinder => surface::Shape::Cylinder,
            Shape::Bump => surface::Shape::Bump,
            Shape::Blade => surface::Shape::Blade,
        }
    }
}

impl From<AlgorithmChoice> for surface::AlgorithmChoice {
    fn from(v: AlgorithmChoice) -> Self {
        match v {
            AlgorithmChoice::Greedy => surface::AlgorithmChoice::Greedy,
            AlgorithmChoice::WeightedU => surface::AlgorithmChoice::WeightedU,
            AlgorithmChoice::WeightedV => surface::AlgorithmChoice::WeightedV,
            AlgorithmChoice::Tsp => surface::AlgorithmChoice::Tsp,
            AlgorithmChoice::All => surface::AlgorithmChoice::All,
        }
    }
}

impl From<SamplingMode> for surface::SamplingMode {
    fn from(v: SamplingMode) -> Self {
        match v {
            SamplingMode::Paper => surface::SamplingMode::Paper,
            SamplingMode::Robust => surface::SamplingMode::Robust,
        }
    }
}

impl From<FinishParams> for finish::Finish {
    fn from(a: FinishParams) -> Self {
        finish::Finish {
            z0: a.z0,
            beta: a.beta,
            half_length: a.half_length,
            width: a.width,
            spacing: a.spacing,
            step: a.step,
            layer_height: a.layer_height,
            filament: a.filament,
            feed: a.feed,
            z_base: a.z_base,
        }
    }
}

impl From<FinishArgs> for finish::FinishOptions {
    fn from(a: FinishArgs) -> Self {
        finish::FinishOptions { finish: a.finish.into(), output: a.output, json: a.json }
    }
}

impl From<TiltArgs> for tilt::TiltOptions {
    fn from(a: TiltArgs) -> Self {
        tilt::TiltOptions {
            job: a.job,
            angle_deg: a.angle_deg,
            bolt_height: a.bolt_height,
            bolt_distance: a.bolt_distance,
            output: a.output,
        }
    }
}

impl From<BaseArgs> for base::BaseOptions {
    fn from(a: BaseArgs) -> Self {
        base::BaseOptions {
            job: a.job,
            r_nom: a.r_nom,
            reach_limit: a.reach_limit,
            direction_deg: a.direction_deg,
            dt: a.dt,
            fc_start: a.fc_start,
            fc_step: a.fc_step,
            mass: a.mass,
            timing: a.timing.into(),
            config: a.config,
            json: a.json,
            csv: a.csv,
            trajectory: a.trajectory,
            start_delay: a.start_delay,
            plan: a.plan,
            sweep: a.sweep,
            png: a.png,
        }
    }
}

impl From<WidthArgs> for strips::StripWidths {
    fn from(a: WidthArgs) -> Self {
        strips::StripWidths { width: a.width, widths: a.widths }
    }
}

impl From<StripsArgs> for strips::StripsOptions {
    fn from(a: StripsArgs) -> Self {
        strips::StripsOptions {
            job: a.job,
            width: a.width.into(),
            overlap: a.overlap,
            reach: a.reach,
            axis: a.axis.into(),
            origin: a.origin,
            start: a.start,
            join_tolerance: a.join_tolerance,
            arc_tolerance: a.arc_tolerance,
            keep_skirt: a.keep_skirt,
            travel_speed: a.travel_speed,
            retract: a.retract,
            retract_speed: a.retract_speed,
            z_hop: a.z_hop,
            output: a.output,
            png: a.png,
            json: a.json,
        }
    }
}

impl From<SurfaceArgs> for surface::SurfaceOptions {
    fn from(a: SurfaceArgs) -> Self {
        surface::SurfaceOptions {
            shape: a.shape.into(),
            spacing: a.spacing,
            tolerance: a.tolerance,
            sampling: a.sampling.into(),
            algorithm: a.algorithm.into(),
            weight: a.weight,
            neighbours: a.neighbours,
            length: a.length,
            width: a.width,
            radius: a.radius,
            sweep: a.sweep,
            height: a.height,
            beta: a.beta,
            hub_radius: a.hub_radius,
            tip_radius: a.tip_radius,
            chord: a.chord,
            pitch: a.pitch,
            camber: a.camber,
            line_width: a.line_width,
            layer_height: a.layer_height,
            filament_diameter: a.filament_diameter,
            speed: a.speed,
            travel_speed: a.travel_speed,
            standoff: a.standoff,
            output: a.output,
            png: a.png,
            json: a.json,
            step: a.step,
            face: a.face,
            face_name: a.face_name,
            list_faces: a.list_faces,
            flip_normal: a.flip_normal,
            place: match a.place {
                Placement::Model => surface::Placement::Model,
                Placement::Origin => surface::Placement::Origin,
                Placement::Centre => surface::Placement::Centre,
            },
            layers: a.layers,
            check: a.check,
            config: a.config,
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        command: Planner,
    }

    #[derive(clap::Subcommand)]
    #[allow(clippy::large_enum_variant, reason = "the test's command line, parsed once per case")]
    enum Planner {
        Surface(SurfaceArgs),
        Finish(FinishArgs),
    }

    fn surface(line: &[&str]) -> surface::SurfaceOptions {
        match Cli::try_parse_from(["strand-plan", "surface"].into_iter().chain(line.iter().copied())).unwrap().command {
            Planner::Surface(a) => a.into(),
            Planner::Finish(_) => unreachable!("parsed as surface"),
        }
    }

    #[test]
    fn no_flag_means_the_planners_defaults() {
        // The defaults are written twice (clap's attributes here, the planners' `Default`): pinned.
        assert_eq!(surface(&[]), surface::SurfaceOptions::default());
        let Planner::Finish(f) = Cli::try_parse_from(["strand-plan", "finish", "-o", "x.jsonl"]).unwrap().command else {
            unreachable!("parsed as finish")
        };
        assert_eq!(finish::Finish::from(f.finish), finish::Finish::default());
    }

    #[test]
    fn flags_are_checked_by_name() {
        assert!(surface(&["--spacing=-0.01"]).sampling().unwrap_err().to_string().contains("--spacing = -0.01"));
        assert!(surface(&["--tolerance", "2"]).sampling().unwrap_err().to_string().contains("--tolerance"));
        assert!(surface(&["--shape", "cylinder", "--sweep", "7"]).surface().err().unwrap().to_string().contains("--sweep = 7"));
        assert!(surface(&["--shape", "blade", "--tip-radius", "0.01"]).surface().err().unwrap().to_string().contains("--tip-radius"));
        assert!(surface(&["--shape", "bump", "--beta", "0"]).surface().err().unwrap().to_string().contains("--beta = 0"));
        assert!(surface(&["--line-width", "0.1e-3"]).deposition().unwrap_err().to_string().contains("--layer-height"));
        let run = |line: &[&str]| surface::run(&surface(line)).unwrap_err().to_string();
        assert!(run(&["--output", "/nonexistent/x.jsonl"]).contains("--output"));
        assert!(run(&["--neighbours", "0"]).contains("--neighbours"));
        assert!(run(&["--weight=-1"]).contains("--weight = -1"));
        // Defaults are 003's and 002's.
        let a = surface(&["--shape", "bump"]);
        assert_eq!(a.spacing, 0.01);
        let d = a.deposition().unwrap();
        assert_eq!((d.line_width, d.layer_height, d.filament_diameter, d.standoff), (0.45e-3, 0.2e-3, 1.75e-3, 0.2e-3));
        let s = a.surface().unwrap();
        assert!((s.point(0.0, 0.0).z - 3.0e-3).abs() < 1e-15 && (s.point(0.0, 0.018).z - 3.0e-3 / 1f64.exp()).abs() < 1e-15);
    }
}
