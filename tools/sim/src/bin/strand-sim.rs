//! strand-sim: a separate process that is the robot, its base, the base's tracker and the
//! extruder, talking to the service over iceoryx2 as the real drivers would. Its JointStates drive
//! the service's `robot` clock; `--lockstep` (the default) answers each command as soon as it
//! arrives, so a job runs as fast as the two processes can exchange messages — usually many times
//! faster than real time — with every stamp on the sim's own clock. `--realtime` paces it at the
//! robot's rate instead. It writes the truth (actual nozzle, base, melt flow) as CSV for the demo.
//! The loop is `strand_sim::process`; this main owns the command line.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use strand::config::{Config, locate};
use strand_sim::config::SimConfig;
use strand_sim::process::{SimOptions, run};

#[derive(Parser)]
#[command(name = "strand-sim", version, about = "Simulated robot, free-flying base, tracker and extruder for the strand service")]
struct Cli {
    /// Service configuration: robot, rate, base mode and mount, prefix. A file or a NAME (`iiwa7`);
    /// default: default.toml by the search order ($STRAND_CONFIG_DIR, ./config,
    /// <prefix>/share/strand/config, the built-in copy).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override a service config key (repeatable), as `strand run --set` does: give the sim the same
    /// overrides as the service (the rate above all), or the two disagree on the time a tick is.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
    /// Plant configuration (lags, noise, tracker, flyer); default: sim/free-flyer.toml for a
    /// tracked base, sim/default.toml otherwise, next to --config's folder or else by the search
    /// order.
    #[arg(long)]
    sim: Option<PathBuf>,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Write one truth row per cycle to this CSV.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Pace at the robot's rate (clock_nanosleep) instead of answering in lockstep.
    #[arg(long)]
    realtime: bool,
    /// Write the run's counters and the state → command round trip as JSON to this file.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Seed of the plant's noise (overrides the sim config's).
    #[arg(long)]
    seed: Option<u64>,
    /// Exit after this many seconds without a command once commands have come (the service has
    /// gone); 0: never.
    #[arg(long, default_value_t = 2.0)]
    exit_after_silence: f64,
    /// Lockstep: longest wait for the answer to one JointState before cycling on (s).
    #[arg(long, default_value_t = 0.05)]
    answer_timeout: f64,
    /// Be OptiTrack: serve the base's true pose over NatNet (unicast, 127.0.0.1, this command
    /// port) for strand-natnet, instead of publishing base poses. Needs --realtime.
    #[arg(long, value_name = "PORT", requires = "realtime")]
    motive: Option<u16>,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let cfg = match locate::service_config(cli.config.as_deref()).and_then(|c| Config::load_with(&c, &cli.set)) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-sim: {e}");
            return ExitCode::from(2);
        }
    };
    let sim_path = match &cli.sim {
        Some(p) => locate::explicit(p),
        None => SimConfig::default_path(&cfg),
    };
    let mut sim_cfg = match sim_path.map_err(|e| e.to_string()).and_then(|p| SimConfig::load(&p).map_err(|e| e.to_string())) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-sim: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(s) = cli.seed {
        sim_cfg.seed = s;
    }
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    let opts = SimOptions {
        prefix: cli.prefix,
        truth: cli.truth,
        realtime: cli.realtime,
        stats: cli.stats,
        exit_after_silence: cli.exit_after_silence,
        answer_timeout: cli.answer_timeout,
        motive: cli.motive,
    };
    match run(&opts, &cfg, &sim_cfg, &STOP) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-sim: {e}");
            ExitCode::from(1)
        }
    }
}
