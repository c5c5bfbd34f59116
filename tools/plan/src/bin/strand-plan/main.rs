//! strand-plan: offline planning tools (the planners live in `strand_plan`). `strand-plan time` runs a G-code program through the same
//! per-tick path and extrusion code the controller uses, at the configured rate, and reports how long
//! it takes against the feed-rate bound, the limits it reached, its deviation and its flow error.
//! `strand-plan truss` writes 000's 1D truss; `strand-plan strips` splits a planar job into strips
//! with 000's staggered overlap joint; `strand-plan surface` runs 003's path generation on a parametric
//! surface (sampling, greedy / weighted greedy / TSP) and writes a segment file. This main owns the
//! command line and the exit codes; each subcommand is a module of `strand_plan`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use strand::config::locate;
use strand_cli::error::ToolError;
use strand_core::PlanningMode;
use strand_plan::{base, finish, strips, surface, tilt, time, truss};

mod args;

#[derive(Parser)]
#[command(
    name = "strand-plan",
    version,
    about = "Offline planning: time a job through the path engine; the papers' planners (moving base, strips, surfaces, finishing, tilt)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum Mode {
    StopAndGo,
    #[value(name = "rules-004")]
    KnowledgeRules,
    Lookahead,
}

#[derive(Subcommand)]
enum Command {
    /// Run a program through the path engine tick by tick and report duration, limits, deviation, flow.
    Time {
        /// The G-code program.
        file: PathBuf,
        /// Junction planning mode (default: the config's, normally lookahead).
        #[arg(long, value_enum)]
        mode: Option<Mode>,
        /// Service config (path limits, extruder, bed, tick rate): a file or a NAME (`iiwa7`);
        /// default: default.toml by the search order ($STRAND_CONFIG_DIR, ./config,
        /// <prefix>/share/strand/config, the built-in copy).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Print one JSON object instead of the summary.
        #[arg(long)]
        json: bool,
    },
    /// Write 000's free-form 1D truss (base layer, cross beams, top layer; one continuous
    /// extrusion) as G-code.
    Truss {
        /// Length along x (m).
        #[arg(long, default_value_t = 1.0)]
        length: f64,
        /// Distance between the chords (m).
        #[arg(long, default_value_t = 0.04)]
        width: f64,
        /// Post spacing (m).
        #[arg(long, default_value_t = 0.04)]
        pitch: f64,
        /// Layer height (m).
        #[arg(long, default_value_t = 1.0e-3)]
        layer_height: f64,
        /// Strand (nozzle) diameter (m).
        #[arg(long, default_value_t = 1.2e-3)]
        strand: f64,
        /// Filament diameter (m).
        #[arg(long, default_value_t = 2.85e-3)]
        filament: f64,
        /// Print speed (m/s).
        #[arg(long, default_value_t = 3.33e-3)]
        speed: f64,
        /// Write here instead of standard output.
        #[arg(long, short)]
        output: Option<PathBuf>,
    },
    /// 000's moving base: the job's TCP path low-passed with zero phase into the base trajectory,
    /// the cut-off lowered until the arm's reach limit (Algorithm 1); W_FF (Eq. 1), Fig. 4 sweep.
    Base(args::BaseArgs),
    /// 002's finishing layer over z = z0·exp(−y²/β²) with the tool tilted by Eq. 21, as a segment file.
    Finish(args::FinishArgs),
    /// 004's inclined plane (Eqs. 7-10) applied to a G-code job, as a segment file with orientation.
    Tilt(args::TiltArgs),
    /// Split a planar job into strips the arm can reach (000 Section 3.2): staggered overlap joint,
    /// Eqs. 2-4, lines chained into paths, one G-code job strip after strip.
    Strips(args::StripsArgs),
    /// 003's path generation on a parametric surface: sample it at a spacing (Algorithms 1-2), order
    /// the samples (greedy, weighted greedy, TSP: Algorithms 3-5), report length, self-intersections
    /// and compute time, and write the path as segments with the nozzle along the surface normal.
    Surface(Box<args::SurfaceArgs>),
}

fn main() -> ExitCode {
    // Like other Unix filters: a closed pipe (`strand-plan base … | head`) ends the process quietly
    // instead of a panic in println!.
    // SAFETY: setting a signal's disposition to the default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let (name, result) = match Cli::parse().command {
        Command::Time { file, mode, config, json } => {
            let mode = mode.map(|m| match m {
                Mode::StopAndGo => PlanningMode::StopAndGo,
                Mode::KnowledgeRules => PlanningMode::KnowledgeRules,
                Mode::Lookahead => PlanningMode::Lookahead,
            });
            let run = || -> Result<(), ToolError> {
                let config = locate::service_config(config.as_deref())?;
                time::run(&time::TimeOptions { file, mode, config, json })
            };
            ("time", run())
        }
        Command::Truss { length, width, pitch, layer_height, strand, filament, speed, output } => {
            let t = truss::Truss { length, width, pitch, layer_height, strand, filament, speed };
            ("truss", t.validate().and_then(|()| t.write(output.as_deref())))
        }
        Command::Base(a) => ("base", base::run(&a.into())),
        Command::Finish(a) => ("finish", finish::run(&a.into())),
        Command::Tilt(a) => ("tilt", tilt::run(&a.into())),
        Command::Strips(a) => ("strips", strips::run(&a.into())),
        Command::Surface(a) => {
            let run = || -> Result<(), ToolError> {
                let mut options: surface::SurfaceOptions = (*a).into();
                if options.check {
                    options.config = Some(locate::service_config(options.config.as_deref())?);
                }
                surface::run(&options)
            };
            ("surface", run())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-plan {name}: {e}");
            // 1: the job ran into the path engine's refusal or a file could not be written; 2: a
            // bad flag, config or program (the message names it); 3: a path the check refused (as
            // `strand check-job`).
            ExitCode::from(match e {
                ToolError::Timing(_) | ToolError::File { .. } => 1,
                ToolError::Refused(_) => 3,
                _ => 2,
            })
        }
    }
}
