//! strand-natnet: a thin main around `strand_natnet::client::run` — the service config's
//! `[tracker]`, `--server`, `--prefix`, `--set`, and the counters and latency at exit.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use strand::config::{Config, locate};
use strand_natnet::client::{Report, RunOptions, run};

#[derive(Parser)]
#[command(version, about = "The robot base's pose from OptiTrack Motive (NatNet 3.x/4.x), published as BasePose")]
struct Cli {
    /// Service configuration with a `[tracker]` section: a file or a NAME (`free-flyer`), by the
    /// search order ($STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, the built-in copy).
    #[arg(long)]
    config: PathBuf,
    /// Motive's address instead of `[tracker] server` (IPv4).
    #[arg(long)]
    server: Option<String>,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Override a config key (repeatable), e.g. `--set tracker.rigid_body=flyer`.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
    /// Write the counters and the arrival → publish latency as JSON to this file at exit.
    #[arg(long)]
    stats: Option<PathBuf>,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let mut set = cli.set.clone();
    if let Some(s) = &cli.server {
        set.push(format!("tracker.server=\"{s}\""));
    }
    let setup = || -> Result<_, String> {
        let path = locate::service_config(Some(&cli.config)).map_err(|e| e.to_string())?;
        let cfg = Config::load_with(&path, &set).map_err(|e| e.to_string())?;
        let tracker = cfg.tracker.clone().ok_or_else(|| {
            format!("{}: no [tracker] section (give one, or --set tracker.rigid_body=NAME and the other keys)", path.display())
        })?;
        let prefix = cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
        Ok((tracker, prefix))
    };
    let (tracker, prefix) = match setup() {
        Ok(x) => x,
        Err(e) => {
            eprintln!("strand-natnet: {e}");
            return ExitCode::from(2);
        }
    };
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    let opts = RunOptions { prefix, stop: &STOP };
    match run(&tracker, &opts, &mut |line| eprintln!("strand-natnet: {line}")) {
        Ok(report) => finish(&report, cli.stats.as_deref()),
        Err(e) => {
            eprintln!("strand-natnet: {e}");
            ExitCode::from(1)
        }
    }
}

fn finish(report: &Report, stats: Option<&std::path::Path>) -> ExitCode {
    let c = &report.counters;
    let l = &report.latency;
    eprintln!(
        "strand-natnet: {} frames, {} poses published, {} untracked, {} without the body, {} invalid, {} out of order, {} malformed, {} before the handshake, {} unstamped; arrival → publish p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        c.frames,
        c.published,
        c.untracked,
        c.missing,
        c.invalid,
        c.out_of_order,
        c.malformed,
        c.early,
        c.unstamped,
        l.percentile(50.0) as f64 * 1e-3,
        l.percentile(99.0) as f64 * 1e-3,
        l.max() as f64 * 1e-3
    );
    if let Some(p) = stats {
        let json = serde_json::json!({
            "counters": c,
            "latency": {
                "samples": l.count(),
                "p50_ns": l.percentile(50.0),
                "p99_ns": l.percentile(99.0),
                "max_ns": l.max(),
            },
        });
        if let Err(e) = std::fs::write(p, format!("{json:#}\n")) {
            eprintln!("strand-natnet: {}: {e}", p.display());
            return ExitCode::from(1);
        }
    }
    ExitCode::SUCCESS
}
