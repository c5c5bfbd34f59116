//! strand-bench: measurements with distributions, not averages, each next to a baseline from the
//! same run where there is one: `jitter` (wake-up lateness of the cycle runner against an empty
//! TimerClock loop and cyclictest), `latency` (state in → command out on the robot clock against an
//! iceoryx2 ping-pong), `tick` (cost per stage, allocations counted), `clik` (our CLIK step against
//! Pinocchio's DLS tick) and `log` (args.rs); the modes are in `strand_bench`. `--json`
//! prints one object per mode with `samples, p50_ns, p99_ns, p999_ns, p9999_ns, max_ns`; `--png
//! FILE` draws the histograms.
//!
//! The `log` mode measures the MCAP logger at a control rate (enqueue cost, drops, writer CPU,
//! bytes per second). This main owns the command line and the counting allocator; the
//! measurements are `strand_bench`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod args;

use args::{Cli, Mode};
use clap::Parser;
use strand::config::locate;
use strand::io::alloc_count::{self, Counting};
use strand_bench::{clik, driver, jitter, latency, log, tick};
use strand_cli::error::Result;

/// Counts allocations, for `tick` (the tick path must not allocate).
#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    alloc_count::allocations() as u64
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
                    root: strand_bench::repo_root()?,
                };
                let r = jitter::run(&opts)?;
                emit(json, &r, jitter::print, png.as_deref(), jitter::plot)?;
                r.lateness.check("lateness")?;
                r.baseline.check("baseline")
            }
            Mode::Latency { seconds, json, png, driver: Some(protocol), rt, .. } => {
                let bin_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(PathBuf::from)).unwrap_or_default();
                let robot = match protocol.as_str() {
                    "egm" => "irb140",
                    "fri" => "iiwa7",
                    "bcap" => "vp6242",
                    "meca" => "meca500",
                    "ur" => "ur5e",
                    _ => "kr6r900",
                };
                let opts = driver::DriverOptions {
                    protocol,
                    seconds,
                    config: robot_config(robot)?,
                    root: strand_bench::repo_root()?,
                    bin_dir,
                    rt_priority: rt,
                };
                let r = driver::run(&opts)?;
                emit(json, &r, driver::print, png.as_deref(), driver::plot)?;
                r.round_trip.check("round trip")
            }
            Mode::Latency { rate, seconds, robot, json, png, rt, cpu, .. } => {
                let bin_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(PathBuf::from)).unwrap_or_default();
                let opts = latency::LatencyOptions {
                    rate_hz: rate,
                    seconds,
                    config: robot_config(&robot)?,
                    root: strand_bench::repo_root()?,
                    bin_dir,
                    rt_priority: rt,
                    cpu,
                };
                let r = latency::run(&opts)?;
                emit(json, &r, latency::print, png.as_deref(), latency::plot)?;
                r.latency.check("latency")?;
                r.baseline.check("ping-pong")
            }
            Mode::Tick { robot, iterations, rounds, pinocchio, kdl, json, png, shell, shell_rate } => {
                let opts = tick::TickOptions {
                    config: robot_config(&robot)?,
                    iterations,
                    rounds,
                    pinocchio,
                    kdl,
                    root: strand_bench::repo_root()?,
                    allocations,
                    shell,
                    shell_rate,
                };
                let r = tick::run(&opts)?;
                emit(json, &r, tick::print, png.as_deref(), tick::plot)?;
                r.check()
            }
            Mode::Clik { robot, ticks, rounds, pinocchio, json } => {
                let opts = clik::ClikOptions { config: robot_config(&robot)?, ticks, rounds, pinocchio };
                let r = clik::run(&opts)?;
                emit(json, &r, clik::print, None, |_, _| Ok(()))?;
                r.check()
            }
            Mode::Pong { prefix, seconds, rt, cpu } => latency::pong(&prefix, seconds, latency::Realtime { priority: rt, cpu }),
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
