//! strand-demo: the whole cell in one command. It starts the service on the robot clock, strand-sim
//! as the robot (and, for a tracked base, the free flyer, its tracker and the extruder), and
//! strand-feed with a bundled job; waits for the job to end; then joins the service's MCAP log with
//! the sim's truth and prints a summary: job time, segments, TCP error (mean, p99, max), flow
//! error, tick cost, round trip, overruns, faults, the log's path — and whether
//! `strand-replay verify` reproduces the log to the bit. Exit 0 only if the job finished and the
//! replay is identical; a job that faulted or was stopped still gets its summary (the job line says
//! FAULTED, the fault and where) and exit 1. A child that fails (the feeder refusing the job — its
//! own check, or a bad file —, the sim its plant, the
//! service its config) stops the demo at once: the others are stopped, the child's name, exit code
//! and last lines of output are printed, a log that holds only idle ticks is removed, and the exit
//! code is 1 (2 for a problem the demo finds itself). Configs and the default jobs are found as
//! `strand::config::locate` says, so it runs from any folder.

//!
//! The demo itself is `strand_sim::demo`; this main owns the command line and the exit code.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use strand_sim::demo::{DemoOptions, OperatorAction, run};

#[derive(Parser)]
#[command(name = "strand-demo", version, about = "Service + simulated robot + feeder on a bundled job, with a summary and a replay check")]
struct Cli {
    /// Service configuration: a file or a NAME (default: default.toml, or <robot>.toml with --robot,
    /// by the search order: $STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, the
    /// built-in copy).
    #[arg(long)]
    config: Option<PathBuf>,
    /// A robot by name: iiwa7, iiwa14, vp6242, meca500, irb140 (uses <robot>.toml, found as above).
    #[arg(long, conflicts_with = "config")]
    robot: Option<String>,
    /// The job (default: the first layers of the 35 mm box; the 200 mm 1D truss for a tracked base;
    /// the helix cylinder for a cell with a rotary table).
    #[arg(long)]
    gcode: Option<PathBuf>,
    /// Stream only the first N layers (default: 3 of the box; all of any other job).
    #[arg(long)]
    layers: Option<usize>,
    /// Plant configuration for strand-sim (default: sim/default.toml, or sim/free-flyer.toml for a
    /// tracked base, beside the service config or else found as above).
    #[arg(long)]
    sim: Option<PathBuf>,
    /// Seed of the plant's noise.
    #[arg(long)]
    seed: Option<u64>,
    /// Override a service config key (repeatable), e.g. `--set base.estimator=moving-average`.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
    /// Let the feeder stream without its job check (strand-feed --no-check): to see the run-time
    /// faults a checked job never meets.
    #[arg(long)]
    no_check: bool,
    /// Folder for this run's files (log, truth, process output); default logs/demo-<UTC time> in the
    /// working directory.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the summary as one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Give up after this many seconds (wall).
    #[arg(long, default_value_t = 600.0)]
    timeout: f64,
    /// Watch it live: serve the Foxglove view on ws://127.0.0.1:8765 (the config's `[view]
    /// address`) and run the plant in real time. Open Foxglove, connect, and import the layout
    /// tools/foxglove/strand.json.
    #[arg(long)]
    view: bool,
    /// An operator's action at a robot time into the job (repeatable): `T:pause`, `T:resume`,
    /// `T:stop`, `T:feed PERCENT`, `T:flow PERCENT` (T: seconds since the job's path started),
    /// e.g. `--operator "250:feed 50"`.
    #[arg(long, value_name = "T:ACTION")]
    operator: Vec<OperatorAction>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let opts = DemoOptions {
        config: cli.config,
        robot: cli.robot,
        gcode: cli.gcode,
        layers: cli.layers,
        sim: cli.sim,
        seed: cli.seed,
        set: cli.set,
        no_check: cli.no_check,
        out: cli.out,
        json: cli.json,
        timeout: cli.timeout,
        view: cli.view,
        operator: cli.operator,
    };
    match run(&opts) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("strand-demo: {e}");
            ExitCode::from(2)
        }
    }
}
