// The command line every driver binary shares (included by each with `#[path]`): a thin main
// around `strand_driver::bridge::run` (the robot sends first: `--bind`) or
// `strand_driver::paced::run` (the driver connects: `--robot`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use strand::config::driver::DriverProtocol;
use strand::config::{Config, locate};
use strand_driver::bridge::{BridgeOptions, BridgeReport, run};
use strand_driver::paced::{Handshake, PacedOptions, StreamEnd, run as paced_run};
use strand_driver::protocol::RobotProtocol;

#[derive(Parser)]
#[command(version)]
struct Cli {
    /// Service configuration with a `[driver]` section: a file or a NAME (`irb140`, `kr6r900`), by
    /// the search order ($STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, the built-in
    /// copy).
    #[arg(long)]
    config: PathBuf,
    /// Listen here instead of `[driver] bind` (IP:PORT; port 0: any free port, printed): the
    /// drivers the robot sends to first (EGM, RSI, FRI).
    #[arg(long)]
    bind: Option<String>,
    /// The robot controller instead of `[driver] robot` (IP:PORT, or IP with the protocol's
    /// port): for the drivers that connect (b-CAP, the Meca500's control port); for the others the
    /// only sender accepted.
    #[arg(long)]
    robot: Option<String>,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Override a config key (repeatable), e.g. `--set driver.reply_deadline=0.001`.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
    /// Write the counters and the receive → reply latency as JSON to this file at exit.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// SCHED_FIFO at this priority and locked memory (needs the privilege).
    #[arg(long)]
    rt: Option<u32>,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

#[allow(dead_code)]
pub(crate) fn main_for<P: RobotProtocol>(protocol: DriverProtocol, make: fn() -> P) -> ExitCode {
    let cli = Cli::parse();
    let name = P::NAME;
    let mut set = cli.set.clone();
    if let Some(b) = &cli.bind {
        set.push(format!("driver.bind=\"{b}\""));
    }
    if let Some(r) = &cli.robot {
        set.push(format!("driver.robot=\"{r}\""));
    }
    let setup = || -> Result<_, String> {
        let path = locate::service_config(Some(&cli.config)).map_err(|e| e.to_string())?;
        let cfg = Config::load_with(&path, &set).map_err(|e| e.to_string())?;
        let d = strand_driver::driver_config(&cfg, protocol).map_err(|e| e.to_string())?;
        let session = strand_driver::session(&cfg, &d, make()).map_err(|e| e.to_string())?;
        let opts = BridgeOptions {
            bind: d.bind_address().map_err(|e| e.to_string())?,
            prefix: cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone()),
            period: 1.0 / cfg.controller.rate_hz,
            max_packets: 0,
            unit_bind: d.unit_address().map_err(|e| e.to_string())?,
        };
        if !opts.bind.ip().is_loopback() {
            eprintln!("strand-{name}: note: listening on {}, not the loopback address ([driver] bind)", opts.bind);
        }
        Ok((session, opts))
    };
    let (mut session, opts) = match setup() {
        Ok(x) => x,
        Err(e) => {
            eprintln!("strand-{name}: {e}");
            return ExitCode::from(2);
        }
    };
    set_rt(name, cli.rt);
    on_signals();
    match run(&mut session, &opts, &STOP) {
        Ok(report) => finish(name, &report, cli.stats.as_deref(), None),
        Err(e) => {
            eprintln!("strand-{name}: {e}");
            ExitCode::from(1)
        }
    }
}

fn set_rt(name: &str, rt: Option<u32>) {
    if let Some(priority) = rt {
        let rt = strand::io::rt::RealtimeConfig { fifo_priority: priority, lock_memory: true, ..Default::default() };
        let report = strand::io::rt::apply(&rt);
        for w in report.warnings() {
            eprintln!("strand-{name}: warning: --rt: {w}");
        }
    }
}

fn on_signals() {
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
}

/// Prints the counters (and writes `--stats`); `ended` says why the robot ended the stream, if it
/// did (then the exit code is 1).
fn finish(name: &str, report: &BridgeReport, stats: Option<&std::path::Path>, ended: Option<&str>) -> ExitCode {
    let c = &report.counters;
    let l = &report.latency;
    eprintln!(
        "strand-{name}: {} packets, {} answered in time, {} late, {} held, {} clamped, {} faults; dropped {} foreign, {} malformed, {} oversized, {} duplicate, {} out of order; receive → reply p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        c.packets,
        c.in_time,
        c.late,
        c.held,
        c.clamped,
        c.faults,
        c.foreign,
        c.malformed,
        c.oversized,
        c.duplicate,
        c.out_of_order,
        l.percentile(50.0) as f64 * 1e-3,
        l.percentile(99.0) as f64 * 1e-3,
        l.max() as f64 * 1e-3
    );
    if let Some(u) = &report.unit {
        eprintln!(
            "strand-{name}: the external axes' own channel: {} packets, {} answered with the robot's answer, {} alone (no robot packet by the deadline), {} superseded; dropped {} foreign, {} malformed, {} out of order; {} robot packets waited for the unit's ({} in vain)",
            u.packets,
            u.answered_with_robot,
            u.answered_alone,
            u.superseded,
            u.foreign,
            u.malformed,
            u.out_of_order,
            u.waited,
            u.wait_missed
        );
    }
    if let Some(p) = stats {
        let json = serde_json::json!({
            "protocol": name,
            "counters": c,
            "stale": report.stale,
            "final_state": report.final_state,
            "unit": report.unit,
            "robot_ended": ended,
            "latency": {
                "samples": l.count(),
                "p50_ns": l.percentile(50.0),
                "p99_ns": l.percentile(99.0),
                "p999_ns": l.percentile(99.9),
                "max_ns": l.max(),
            },
        });
        if let Err(e) = std::fs::write(p, format!("{json:#}\n")) {
            eprintln!("strand-{name}: {}: {e}", p.display());
            return ExitCode::from(1);
        }
    }
    if ended.is_some() { ExitCode::from(1) } else { ExitCode::SUCCESS }
}

/// A driver that connects to the robot controller: `open` connects and sets the robot up, and
/// gives the first answer to send once the service's ports are open (empty if none), `close` gives it back (what failed, named). Ctrl-C holds the robot to rest
/// first; an error the robot reports ends the stream, the service is told, and the robot is given
/// back all the same.
#[allow(dead_code)]
pub(crate) fn main_connecting<P: RobotProtocol, L: Handshake<P>>(protocol: DriverProtocol, make: fn() -> P) -> ExitCode {
    let cli = Cli::parse();
    let name = P::NAME;
    let mut set = cli.set.clone();
    if let Some(r) = &cli.robot {
        set.push(format!("driver.robot=\"{r}\""));
    }
    if cli.bind.is_some() {
        eprintln!("strand-{name}: --bind: this driver connects to the robot controller; give it with --robot IP:PORT");
        return ExitCode::from(2);
    }
    let setup = || -> Result<_, String> {
        let path = locate::service_config(Some(&cli.config)).map_err(|e| e.to_string())?;
        let cfg = Config::load_with(&path, &set).map_err(|e| e.to_string())?;
        let d = strand_driver::driver_config(&cfg, protocol).map_err(|e| e.to_string())?;
        let session = strand_driver::session(&cfg, &d, make()).map_err(|e| e.to_string())?;
        let period = 1.0 / cfg.controller.rate_hz;
        let opts = PacedOptions {
            prefix: cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone()),
            period,
            state_timeout: (8.0 * period).max(0.2),
            max_packets: 0,
        };
        Ok((cfg, d, session, opts))
    };
    let (cfg, d, mut session, opts) = match setup() {
        Ok(x) => x,
        Err(e) => {
            eprintln!("strand-{name}: {e}");
            return ExitCode::from(2);
        }
    };
    on_signals();
    eprintln!("strand-{name}: connecting to the robot controller at {}", d.robot_address().map(|a| a.to_string()).unwrap_or_default());
    let (mut link, first) = match L::handshake(&cfg, &d, &mut session) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("strand-{name}: {e}");
            return ExitCode::from(1);
        }
    };
    set_rt(name, cli.rt);
    match paced_run(&mut session, &mut link, &first, &opts, &STOP) {
        Ok((report, ended)) => {
            for problem in &ended.release_failed {
                eprintln!("strand-{name}: giving the robot back: {problem}");
            }
            let ended = match &ended.end {
                StreamEnd::Stopped => None,
                StreamEnd::Robot(why) => Some(why.as_str()),
            };
            finish(name, &report, cli.stats.as_deref(), ended)
        }
        Err(e) => {
            for problem in link.finish() {
                eprintln!("strand-{name}: giving the robot back: {problem}");
            }
            eprintln!("strand-{name}: {e}");
            ExitCode::from(1)
        }
    }
}
