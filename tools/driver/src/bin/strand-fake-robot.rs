//! strand-fake-robot: a fake ABB IRC5 (EGM), KUKA KR C4 (RSI) or KUKA Sunrise cabinet (FRI) for
//! testing strand-egm, strand-rsi and strand-fri where no robot is. It sends the controller's packets every 4 ms on absolute deadlines,
//! integrates the answers into its actual axes (with an optional drive lag), and reports the cycles
//! answered in time, late and missing, and the actual axes' largest speed and acceleration. The
//! protocols are `strand_driver::fake`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Parser, ValueEnum};
use strand_driver::fake::egm::FakeEgm;
use strand_driver::fake::fri::{FakeFri, FriOptions};
use strand_driver::fake::rsi::FakeRsi;
use strand_driver::fake::{FakeOptions, FakeProtocol, run};

#[derive(Clone, Copy, ValueEnum)]
enum Protocol {
    Egm,
    Rsi,
    Fri,
}

#[derive(Parser)]
#[command(name = "strand-fake-robot", version, about = "A fake robot controller speaking EGM, RSI or FRI, for testing the drivers")]
struct Cli {
    /// The interface to fake.
    #[arg(long, value_enum)]
    protocol: Protocol,
    /// The driver's address (IP:PORT).
    #[arg(long)]
    driver: SocketAddr,
    /// Axes at the start (degrees, comma-separated: six; seven for FRI). Default: KUKA's RSI start
    /// pose (0,-90,90,0,90,0), or the LBR iiwa's start posture of config/iiwa7.toml for FRI.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    start: Vec<f64>,
    /// The cycle (s).
    #[arg(long, default_value_t = 0.004)]
    period: f64,
    /// First-order lag of the drives (s).
    #[arg(long, default_value_t = 0.0)]
    lag: f64,
    /// Cycles to run (0: until Ctrl-C).
    #[arg(long, default_value_t = 0)]
    cycles: u64,
    /// FRI: cycles in MONITORING_READY before the Sunrise application starts its joint overlay,
    /// and cycles of COMMANDING_WAIT before COMMANDING_ACTIVE.
    #[arg(long, default_value_t = 10)]
    overlay_after: u64,
    /// EGM: cycles in MCI_STOPPED before MCI_RUNNING.
    #[arg(long, default_value_t = 25)]
    stopped_cycles: u64,
    /// Give up after this many cycles without an answer once answers have come (RSI's timeout: 100).
    #[arg(long, default_value_t = 100)]
    give_up_after: u64,
    /// Run the fake's loop with SCHED_FIFO at this priority (as a controller's is real-time).
    #[arg(long)]
    rt: Option<i32>,
    /// Write the report as JSON here.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Write the actual axes of every cycle (degrees) as CSV here.
    #[arg(long)]
    axes_csv: Option<PathBuf>,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let mut cli = Cli::parse();
    let axes = if matches!(cli.protocol, Protocol::Fri) { 7 } else { 6 };
    if cli.start.is_empty() {
        cli.start = if axes == 7 {
            [0.0f64, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0].iter().map(|q| q.to_degrees()).collect()
        } else {
            vec![0.0, -90.0, 90.0, 0.0, 90.0, 0.0]
        };
    }
    if cli.start.len() != axes || cli.start.iter().any(|x| !x.is_finite()) {
        eprintln!("strand-fake-robot: --start needs {axes} finite angles (degrees)");
        return ExitCode::from(2);
    }
    let period_ms = (cli.period * 1e3).round() as u64;
    let mut protocol: Box<dyn FakeProtocol> = match cli.protocol {
        Protocol::Egm => Box::new(FakeEgm::new(cli.stopped_cycles, period_ms as u32)),
        Protocol::Rsi => Box::new(FakeRsi::new(&cli.start, period_ms)),
        Protocol::Fri => {
            let opts = FriOptions {
                send_period_ms: period_ms as u32,
                overlay_after: cli.overlay_after,
                wait_cycles: cli.overlay_after,
                ..Default::default()
            };
            Box::new(FakeFri::new(opts).0)
        }
    };
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    let opts = FakeOptions {
        driver: cli.driver,
        bind: SocketAddr::from(([127, 0, 0, 1], 0)),
        period: cli.period,
        start_deg: cli.start.clone(),
        lag: cli.lag,
        cycles: cli.cycles,
        give_up_after: cli.give_up_after,
        rt_priority: cli.rt,
    };
    let report = match run(protocol.as_mut(), &opts, &STOP) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("strand-fake-robot: {e}");
            return ExitCode::from(1);
        }
    };
    let (v, a) = report.max_rates(cli.period, cli.lag);
    eprintln!(
        "strand-fake-robot: {} cycles, {} answered in time ({:.3} %), {} late, {} missing, {} garbage{}",
        report.cycles,
        report.in_time,
        100.0 * report.in_time_share(),
        report.late,
        report.missing,
        report.garbage,
        if report.gave_up { "; gave up (no answers)" } else { "" }
    );
    if let Some(p) = &cli.stats {
        let json = serde_json::json!({ "report": &report, "max_speed_deg_s": v, "max_acceleration_deg_s2": a });
        if let Err(e) = std::fs::write(p, format!("{json:#}\n")) {
            eprintln!("strand-fake-robot: {}: {e}", p.display());
            return ExitCode::from(1);
        }
    }
    if let Some(p) = &cli.axes_csv {
        let header: Vec<String> = (1..=cli.start.len()).map(|k| format!("a{k}")).collect();
        let mut text = format!("cycle,{}\n", header.join(","));
        for (k, row) in report.axes.iter().enumerate() {
            text += &format!("{k},{}\n", row.iter().map(|x| format!("{x:.6}")).collect::<Vec<_>>().join(","));
        }
        if let Err(e) = std::fs::write(p, text) {
            eprintln!("strand-fake-robot: {}: {e}", p.display());
            return ExitCode::from(1);
        }
    }
    ExitCode::SUCCESS
}
