//! strand-mcu: a thin main around `strand_mcu::process::run` — the service config's
//! `[extruder.board]`, `--serial`, `--prefix`, `--set`, and the counters at exit; `--identify` only
//! connects and says what the board is, to check a cell's wiring.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use strand::config::{Config, locate};
use strand_mcu::mcu::{ConnectOptions, Mcu};
use strand_mcu::process::{RunOptions, run};

#[derive(Parser)]
#[command(version, about = "The extruder and the hot end on a stock-Klipper board, for the strand service")]
struct Cli {
    /// Service configuration with an `[extruder.board]` section: a file or a NAME, by the search
    /// order ($STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, the built-in copy).
    #[arg(long, required_unless_present = "serial")]
    config: Option<PathBuf>,
    /// The board's serial port instead of `[extruder.board] serial`.
    #[arg(long)]
    serial: Option<PathBuf>,
    /// Baud rate for `--identify` without a config (bit/s; USB boards ignore it).
    #[arg(long, default_value_t = 250_000)]
    baud: u32,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Override a config key (repeatable), e.g. `--set extruder.motion_delay=0.02`.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
    /// Connect, print what the board is (MCU, firmware, clock) and exit.
    #[arg(long)]
    identify: bool,
    /// Write the counters as JSON to this file at exit.
    #[arg(long)]
    stats: Option<PathBuf>,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let setup = || -> Result<_, String> {
        let Some(config) = &cli.config else { return Ok(None) };
        let path = locate::service_config(Some(config)).map_err(|e| e.to_string())?;
        let cfg = Config::load_with(&path, &cli.set).map_err(|e| e.to_string())?;
        let mut board = cfg.extruder_board.clone().ok_or_else(|| format!("{}: no [extruder.board] section", path.display()))?;
        if let Some(s) = &cli.serial {
            board.serial = s.clone();
        }
        let prefix = cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
        Ok(Some((board, prefix)))
    };
    let setup = match setup() {
        Ok(x) => x,
        Err(e) => {
            eprintln!("strand-mcu: {e}");
            return ExitCode::from(2);
        }
    };
    if cli.identify {
        let (serial, baud) = match (&setup, &cli.serial) {
            (Some((b, _)), _) => (b.serial.clone(), b.baud),
            (None, Some(s)) => (s.clone(), cli.baud),
            (None, None) => unreachable!("clap requires --config or --serial"),
        };
        return identify(&serial, baud);
    }
    let Some((board, prefix)) = setup else {
        eprintln!("strand-mcu: --config names the board and the service (only --identify works with --serial alone)");
        return ExitCode::from(2);
    };
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    let opts = RunOptions { prefix, stop: &STOP, connect: ConnectOptions::default() };
    match run(&board, &opts, &mut |line| eprintln!("strand-mcu: {line}")) {
        Ok(report) => {
            eprintln!(
                "strand-mcu: {} commands ({} out of order), {} steps, {} temperatures{}",
                report.commands,
                report.out_of_order,
                report.steps,
                report.readings,
                report.fault.as_deref().map(|f| format!("; FAULT: {f}")).unwrap_or_default()
            );
            if let Some(p) = &cli.stats
                && let Err(e) = std::fs::write(p, format!("{:#}\n", serde_json::json!(report)))
            {
                eprintln!("strand-mcu: {}: {e}", p.display());
                return ExitCode::from(1);
            }
            if report.fault.is_some() { ExitCode::from(3) } else { ExitCode::SUCCESS }
        }
        Err(e) => {
            eprintln!("strand-mcu: {e}");
            ExitCode::from(1)
        }
    }
}

fn identify(serial: &std::path::Path, baud: u32) -> ExitCode {
    match Mcu::connect(serial, baud, ConnectOptions::default()) {
        Ok(m) => {
            let c = |k: &str| m.dict.constant_str(k).unwrap_or_else(|_| "?".into());
            println!("mcu: {}", c("MCU"));
            println!("version: {}", m.dict.version);
            println!("build: {}", m.dict.build_versions);
            println!("clock_freq: {} Hz", c("CLOCK_FREQ"));
            if let Some(cs) = &m.clock {
                println!("measured clock: {:.0} Hz", cs.freq());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("strand-mcu: {e}");
            ExitCode::FAILURE
        }
    }
}
