//! strand-bench: measurements with distributions, not averages, each next to a baseline from the
//! same run where there is one: `jitter` (wake-up lateness of the cycle runner against an empty
//! TimerClock loop and cyclictest), `latency` (state in → command out on the robot clock against an
//! iceoryx2 ping-pong), `tick` (cost per stage, allocations counted) and `log`, below; the modes are
//! in `strand_tools::bench`. `--json` prints one object per mode with `samples, p50_ns, p99_ns,
//! p999_ns, p9999_ns, max_ns`; `--png FILE` draws the histograms.
//!
//! The `log` mode measures the MCAP logger at a control rate (enqueue cost, drops, writer CPU,
//! bytes per second). This main owns the command line and the counting allocator; the
//! measurements are `strand_tools::bench`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand::config::locate;
use strand::io::alloc_count::{self, Counting};
use strand_tools::bench::{self, driver, jitter, latency, log, tick};
use strand_tools::error::Result;

/// Counts allocations, for `tick` (the tick path must not allocate).
#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    alloc_count::allocations() as u64
}

#[derive(Parser)]
#[command(name = "strand-bench", version, about = "Benchmarks: distributions of cost, jitter and throughput")]
struct Cli {
    #[command(subcommand)]
    command: Mode,
}

#[derive(Subcommand)]
enum Mode {
    /// Wake-up lateness of the cycle runner (timer mode), idle or with a controller printing, next
    /// to an empty TimerClock loop and (with --cyclictest) cyclictest at the same period.
    Jitter {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Duration of each run (s).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// SCHED_FIFO (at --priority) and mlockall for the runner and the baselines.
        #[arg(long)]
        rt: bool,
        /// SCHED_FIFO priority with --rt.
        #[arg(long, default_value_t = 80)]
        priority: u32,
        /// Run the controller of this robot (a name under config/, or a config file), printing 004's box.
        #[arg(long, value_name = "ROBOT")]
        with_controller: Option<String>,
        /// Also run cyclictest (rt-tests) with the same period, priority and memory locking.
        #[arg(long)]
        cyclictest: bool,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// State in → command out on the robot clock (a driver here, the service as its own process
    /// printing the box), next to an iceoryx2 ping-pong between two processes.
    Latency {
        /// Robot rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Duration of each run (s).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// The robot (a name under config/, or a config file).
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Through a robot driver instead: `egm` (strand-egm, irb140) or `rsi` (strand-rsi,
        /// kr6r900) against the fake robot controller, at the robot's 4 ms cycle.
        #[arg(long, value_parser = ["egm", "rsi"])]
        driver: Option<String>,
        /// With --driver: run the driver with SCHED_FIFO at this priority.
        #[arg(long, requires = "driver")]
        rt: Option<u32>,
    },
    /// Cost per stage of a controller tick printing the box (path sample, base correction, FK +
    /// Jacobian, CLIK, extrusion, log enqueue) and of the whole step; allocations counted (must be 0).
    Tick {
        /// The robot (a name under config/, or a config file).
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Ticks to measure.
        #[arg(long, default_value_t = 100_000)]
        iterations: u64,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) of the whole step and the stages into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Also time the shell: the runner's receives, publishes and log push over real iceoryx2
        /// ports (a feeder and a driver in this process), per stage, with `runner_allocations`.
        #[arg(long)]
        shell: bool,
        /// Pace the shell's ticks at this rate (Hz), sleeping between them as the runner does (cold
        /// caches after each sleep); 0: back to back.
        #[arg(long, default_value_t = 0.0)]
        shell_rate: f64,
    },
    /// The ping-pong end of `latency` (started by it).
    #[command(hide = true)]
    Pong {
        #[arg(long)]
        prefix: String,
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
    },
    /// Logger throughput at a control rate: enqueue cost, drops, writer CPU share, bytes/s.
    Log {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 4000.0)]
        rate: f64,
        /// Duration (s).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Service configuration (robot, controller, `[log]`): a file or a NAME; default:
        /// default.toml by the search order ($STRAND_CONFIG_DIR, ./config,
        /// <prefix>/share/strand/config, the built-in copy).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Log file (default: a temporary file, removed afterwards).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the enqueue-cost histogram (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
}

/// A robot by NAME (`iiwa7` → iiwa7.toml by the search order of `strand::config::locate`), or a
/// config file as it is (which must exist).
fn robot_config(robot: &str) -> Result<PathBuf> {
    Ok(locate::service_config(Some(Path::new(robot)))?)
}

/// The report as one JSON line, or as `table` prints it; then its PNG, if asked for.
fn emit<T: serde::Serialize>(json: bool, report: &T, table: fn(&T), png: Option<&Path>, plot: fn(&T, &Path) -> Result<()>) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(report).expect("a report serialises"));
    } else {
        table(report);
    }
    if let Some(path) = png {
        plot(report, path)?;
    }
    Ok(())
}

fn main() -> ExitCode {
    // A closed pipe (`… | head`) ends the process quietly instead of a panic in println!.
    // SAFETY: setting a signal's disposition to the default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let result = (|| -> Result<()> {
        match Cli::parse().command {
            Mode::Log { rate, seconds, config, out, json, png } => {
                let opts = log::LogOptions { rate_hz: rate, seconds, config: locate::service_config(config.as_deref())?, out };
                let r = log::run(&opts)?;
                emit(json, &r, log::print, png.as_deref(), log::plot)?;
                r.check()
            }
            Mode::Jitter { rate, seconds, rt, priority, with_controller, cyclictest, json, png } => {
                let opts = jitter::JitterOptions {
                    rate_hz: rate,
                    seconds,
                    rt,
                    priority,
                    with_controller: with_controller.map(|r| robot_config(&r)).transpose()?,
                    cyclictest,
                    root: bench::repo_root()?,
                };
                let r = jitter::run(&opts)?;
                emit(json, &r, jitter::print, png.as_deref(), jitter::plot)?;
                r.lateness.check("lateness")?;
                r.baseline.check("baseline")
            }
            Mode::Latency { seconds, json, png, driver: Some(protocol), rt, .. } => {
                let bin_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(PathBuf::from)).unwrap_or_default();
                let robot = if protocol == "egm" { "irb140" } else { "kr6r900" };
                let opts = driver::DriverOptions {
                    protocol,
                    seconds,
                    config: robot_config(robot)?,
                    root: bench::repo_root()?,
                    bin_dir,
                    rt_priority: rt,
                };
                let r = driver::run(&opts)?;
                emit(json, &r, driver::print, png.as_deref(), driver::plot)?;
                r.round_trip.check("round trip")
            }
            Mode::Latency { rate, seconds, robot, json, png, .. } => {
                let bin_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(PathBuf::from)).unwrap_or_default();
                let opts =
                    latency::LatencyOptions { rate_hz: rate, seconds, config: robot_config(&robot)?, root: bench::repo_root()?, bin_dir };
                let r = latency::run(&opts)?;
                emit(json, &r, latency::print, png.as_deref(), latency::plot)?;
                r.latency.check("latency")?;
                r.baseline.check("ping-pong")
            }
            Mode::Tick { robot, iterations, json, png, shell, shell_rate } => {
                let opts = tick::TickOptions {
                    config: robot_config(&robot)?,
                    iterations,
                    root: bench::repo_root()?,
                    allocations,
                    shell,
                    shell_rate,
                };
                let r = tick::run(&opts)?;
                emit(json, &r, tick::print, png.as_deref(), tick::plot)?;
                r.check()
            }
            Mode::Pong { prefix, seconds } => latency::pong(&prefix, seconds),
        }
    })();
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-bench: {e}");
            ExitCode::from(1)
        }
    }
}
