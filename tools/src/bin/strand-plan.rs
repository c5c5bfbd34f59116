//! strand-plan: offline planning tools (the planners live in `strand_tools::plan`). `strand-plan time` runs a G-code program through the same
//! per-tick path and extrusion code the controller uses, at the configured rate, and reports how long
//! it takes against the feed-rate bound, the limits it reached, its deviation and its flow error.
//! `strand-plan truss` writes 000's 1D truss; `strand-plan strips` splits a planar job into strips
//! with 000's staggered overlap joint; `strand-plan surface` runs 003's path generation on a parametric
//! surface (sampling, greedy / weighted greedy / TSP) and writes a segment file.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use strand::config::{Config, locate};
use strand::core::PlanningMode;
use strand_job::bed::BedTransform;
use strand_job::gcode::{GcodeOptions, parse_file};
use strand_job::timing::time_program;

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
    Base(strand_tools::plan::base::BaseArgs),
    /// 002's finishing layer over z = z0·exp(−y²/β²) with the tool tilted by Eq. 21, as a segment file.
    Finish(strand_tools::plan::finish::FinishArgs),
    /// 004's inclined plane (Eqs. 7-10) applied to a G-code job, as a segment file with orientation.
    Tilt(strand_tools::plan::tilt::TiltArgs),
    /// Split a planar job into strips the arm can reach (000 Section 3.2): staggered overlap joint,
    /// Eqs. 2-4, lines chained into paths, one G-code job strip after strip.
    Strips(strand_tools::plan::strips::StripsArgs),
    /// 003's path generation on a parametric surface: sample it at a spacing (Algorithms 1-2), order
    /// the samples (greedy, weighted greedy, TSP: Algorithms 3-5), report length, self-intersections
    /// and compute time, and write the path as segments with the nozzle along the surface normal.
    Surface(Box<strand_tools::plan::surface::SurfaceArgs>),
}

/// A planner's result as an exit code: 0, or 2 with the message (it names the flag or file).
fn report(name: &str, result: Result<(), String>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-plan {name}: {e}");
            ExitCode::from(2)
        }
    }
}

fn main() -> ExitCode {
    // Like other Unix filters: a closed pipe (`strand-plan base … | head`) ends the process quietly
    // instead of a panic in println!.
    // SAFETY: setting a signal's disposition to the default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let (file, mode, config, json) = match Cli::parse().command {
        Command::Time { file, mode, config, json } => (file, mode, config, json),
        Command::Base(args) => return report("base", strand_tools::plan::base::run(&args)),
        Command::Finish(args) => return report("finish", strand_tools::plan::finish::run(&args)),
        Command::Tilt(args) => return report("tilt", strand_tools::plan::tilt::run(&args)),
        Command::Strips(args) => return report("strips", strand_tools::plan::strips::run(&args)),
        Command::Surface(args) => return report("surface", strand_tools::plan::surface::run(&args)),
        Command::Truss { length, width, pitch, layer_height, strand, filament, speed, output } => {
            let t = strand_tools::plan::truss::Truss { length, width, pitch, layer_height, strand, filament, speed };
            if let Err(e) = t.validate() {
                eprintln!("strand-plan truss: {e}");
                return ExitCode::from(2);
            }
            let text = t.gcode();
            return match output {
                Some(p) => match std::fs::write(&p, text) {
                    Ok(()) => {
                        eprintln!("strand-plan truss: {} ({} panels, {:.3} m of strand)", p.display(), t.panels(), t.path_length());
                        ExitCode::SUCCESS
                    }
                    Err(e) => {
                        eprintln!("strand-plan truss: {}: {e}", p.display());
                        ExitCode::from(1)
                    }
                },
                None => {
                    print!("{text}");
                    ExitCode::SUCCESS
                }
            };
        }
    };
    let config = match locate::service_config(config.as_deref()).and_then(|c| Config::load(&c)) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-plan: {e}");
            return ExitCode::from(2);
        }
    };
    let mut path = config.path.clone();
    if let Some(mode) = mode {
        path.mode = match mode {
            Mode::StopAndGo => PlanningMode::StopAndGo,
            Mode::KnowledgeRules => PlanningMode::KnowledgeRules,
            Mode::Lookahead => PlanningMode::Lookahead,
        };
    }
    let bed = BedTransform::new(&config.bed).expect("validated with the config");
    let mut parser = match parse_file(&file, GcodeOptions::for_path(&file)) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("strand-plan: {e}");
            return ExitCode::from(2);
        }
    };
    let name = file.display().to_string();
    let mut program = parser.by_ref().peekable();
    // time_program never ends on a program without a segment (strand_job::timing): refuse it here.
    if program.peek().is_none() {
        eprintln!("strand-plan: {name}: no motion in the program");
        return ExitCode::from(2);
    }
    let result = time_program(program, &name, &path, &config.extruder, &bed, config.controller.rate_hz, |_| {});
    let mut report = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("strand-plan: {e}");
            return ExitCode::from(1);
        }
    };
    let mut warnings: Vec<String> = parser.warnings().iter().chain(parser.notes()).map(|w| w.to_string()).collect();
    warnings.append(&mut report.warnings);
    report.warnings = warnings;
    if json {
        println!("{}", serde_json::to_string(&report).expect("a report serialises"));
    } else {
        let r = &report;
        println!("{name} ({} mode, {} Hz)", r.mode, config.controller.rate_hz);
        println!("  segments        {}", r.segments);
        println!("  path length     {:.4} m", r.path_length_m);
        println!("  duration        {:.3} s", r.duration_s);
        println!("  lower bound     {:.3} s  (ratio {:.3})", r.lower_bound_s, r.duration_s / r.lower_bound_s);
        println!("  max speed       {:.4} m/s   (limit {})", r.max_speed, path.max_speed);
        println!("  max accel       {:.4} m/s²  (limit {})", r.max_acc, path.max_acceleration);
        println!(
            "  max jerk        {:.1} m/s³  (limit {}{})",
            r.max_jerk,
            path.max_jerk,
            if path.mode == PlanningMode::Lookahead { "" } else { ", not applied in this mode" }
        );
        println!("  max deviation   {:.6} mm (tolerance {} mm)", r.max_deviation_m * 1e3, path.deviation_tolerance * 1e3);
        println!("  max flow error  {:.2e}", r.max_flow_error);
        println!("  filament        {:.4} m commanded, {:.4} m programmed", r.extrude_length_m, r.program_filament_m);
        println!("  underruns {}, forced brakes {}", r.underruns, r.forced_brakes);
        for w in &r.warnings {
            println!("  warning: {w}");
        }
    }
    ExitCode::SUCCESS
}
