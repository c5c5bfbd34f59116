//! `strand-plan time`: a G-code program through the same per-tick path and extrusion code the
//! controller uses (`strand_job::timing`), at the configured rate: how long it takes against the
//! feed-rate bound, the limits it reached, its deviation and its flow error.

use std::path::PathBuf;

use strand::config::Config;
use strand_core::PlanningMode;
use strand_job::gcode::{GcodeOptions, parse_file};
use strand_job::timing::time_program;

use strand_cli::error::{Result, ToolError};

/// What to time and how.
#[derive(Clone, Debug)]
pub struct TimeOptions {
    /// The G-code program.
    pub file: PathBuf,
    /// Junction planning mode (None: the config's).
    pub mode: Option<PlanningMode>,
    /// Service config file (path limits, extruder, bed, tick rate).
    pub config: PathBuf,
    /// One JSON object instead of the summary.
    pub json: bool,
}

/// Times the program and prints the report (a table, or one JSON object). An error for a config
/// or program that cannot be read ([`ToolError::Config`], [`ToolError::Gcode`]), a program without
/// motion, or a program the path engine refuses ([`ToolError::Timing`]).
pub fn run(opts: &TimeOptions) -> Result<()> {
    let config = Config::load(&opts.config)?;
    let mut path = config.path.clone();
    if let Some(mode) = opts.mode {
        path.mode = mode;
    }
    let bed = config.bed_transform()?;
    let file = &opts.file;
    let mut parser = parse_file(file, GcodeOptions::for_path(file))?;
    let name = file.display().to_string();
    let mut program = parser.by_ref().peekable();
    // time_program never ends on a program without a segment (strand_job::timing): refuse it here.
    if program.peek().is_none() {
        return Err(ToolError::Usage(format!("{name}: no motion in the program")));
    }
    let mut report = time_program(program, &name, &path, &config.extruder, &bed, config.controller.rate_hz, |_| {})?;
    let mut warnings: Vec<String> = parser.warnings().iter().chain(parser.notes()).map(|w| w.to_string()).collect();
    warnings.append(&mut report.warnings);
    report.warnings = warnings;
    if opts.json {
        println!("{}", serde_json::to_string(&report).expect("a report serialises"));
        return Ok(());
    }
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
    if r.heat_waits > 0 {
        println!("  heat waits {} not timed here (no heaters; strand check-job predicts them with [thermal])", r.heat_waits);
    }
    for w in &r.warnings {
        println!("  warning: {w}");
    }
    Ok(())
}
