//! strand-fake-robot: a fake ABB IRC5 (EGM), KUKA KR C4 (RSI), KUKA Sunrise cabinet (FRI), DENSO
//! RC8 (b-CAP), Mecademic Meca500 or Universal Robots e-Series for testing the drivers where no robot is. For EGM, RSI and FRI
//! it sends the controller's packets every 4 ms on absolute deadlines to `--driver`, integrates the
//! answers into its actual axes (with an optional drive lag), and reports the cycles answered in
//! time, late and missing, and the actual axes' largest speed and acceleration. For b-CAP and the
//! Meca500 it listens (`--listen`; the Meca500's monitoring port is the next one) for the driver to
//! connect, runs the controller's cycle, and reports at Ctrl-C what it saw: cycles, commands, the
//! errors it raised. The protocols are `strand_driver::fake`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Parser, ValueEnum};
use strand_driver::fake::egm::FakeEgm;
use strand_driver::fake::fri::{FakeFri, FriOptions};
use strand_driver::fake::rsi::FakeRsi;
use strand_driver::fake::{FakeChannel, FakeOptions, FakeProtocol, run, run_channels};

#[derive(Clone, Copy, ValueEnum)]
enum Protocol {
    Egm,
    Rsi,
    Fri,
    Bcap,
    Meca,
    Ur,
}

#[derive(Parser)]
#[command(
    name = "strand-fake-robot",
    version,
    about = "A fake robot controller speaking EGM, RSI, FRI, b-CAP, the Meca500's TCP API or UR's RTDE, for testing the drivers"
)]
struct Cli {
    /// The interface to fake.
    #[arg(long, value_enum)]
    protocol: Protocol,
    /// The driver's address (IP:PORT): EGM, RSI and FRI, where the robot sends first.
    #[arg(long, required_if_eq_any = [("protocol", "egm"), ("protocol", "rsi"), ("protocol", "fri")])]
    driver: Option<SocketAddr>,
    /// EGM: the driver's address for the external axes' own channel (`[driver] external_axes_bind`):
    /// the fake is then a MultiMove controller whose axes after the six are a mechanical unit in a
    /// motion task of its own, streaming EGM from a second socket (`feedBack.externalJoints` only).
    #[arg(long, requires = "driver")]
    unit_driver: Option<SocketAddr>,
    /// Where to listen for the driver (IP:PORT): b-CAP (5007 on an RC8), the Meca500's control
    /// port (10000; its monitoring port is the next one), UR's RTDE port (30004; the script port
    /// is the next one).
    #[arg(long, default_value = "127.0.0.1:0")]
    listen: SocketAddr,
    /// Axes at the start (degrees, comma-separated: six; seven for FRI; for EGM and RSI six and then
    /// the external axes, up to two, degrees or mm for a linear one: the fake sends them in
    /// `externalJoints` / `EIPos` and follows their targets). Default: KUKA's RSI start pose
    /// (0,-90,90,0,90,0), or the LBR iiwa's start posture of config/iiwa7.toml for FRI, or the
    /// start postures of config/vp6242.toml (b-CAP) and config/meca500.toml (the Meca500).
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

/// b-CAP and the Meca500: the fake is a server; it runs until Ctrl-C.
fn serve(cli: &Cli) -> ExitCode {
    use strand_driver::fake::bcap::{BcapOptions, FakeBcap};
    use strand_driver::fake::meca::{FakeMeca, MecaOptions};
    let start = cli.start.clone();
    let wait = || {
        while !STOP.load(Ordering::Relaxed) {
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
    };
    let (report, json): (strand_driver::fake::FakeReport, serde_json::Value) = if matches!(cli.protocol, Protocol::Bcap) {
        let opts =
            BcapOptions { bind: cli.listen, cycle: cli.period, start_deg: start, lag: cli.lag, rt_priority: cli.rt, ..Default::default() };
        let fake = match FakeBcap::spawn(opts) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("strand-fake-robot: {}: {e}", cli.listen);
                return ExitCode::from(1);
            }
        };
        eprintln!("strand-fake-robot: a DENSO RC8 (b-CAP) listening on {}", fake.addr());
        wait();
        let r = fake.stop();
        let errors: Vec<String> = r.errors.iter().map(|e| format!("{e:#010x}")).collect();
        let json = serde_json::json!({ "report": &r.report, "errors": errors, "slv_moves": r.slv_moves, "released": r.released, "calls": r.calls });
        (r.report, json)
    } else if matches!(cli.protocol, Protocol::Ur) {
        use strand_driver::fake::ur::{FakeUr, UrOptions};
        let primary = SocketAddr::new(cli.listen.ip(), if cli.listen.port() == 0 { 0 } else { cli.listen.port() + 1 });
        let start_q = std::array::from_fn(|k| start[k].to_radians());
        let opts = UrOptions { rtde: cli.listen, primary, start_q, rt_priority: cli.rt, ..Default::default() };
        let fake = match FakeUr::spawn(opts) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("strand-fake-robot: {}: {e}", cli.listen);
                return ExitCode::from(1);
            }
        };
        eprintln!("strand-fake-robot: a UR e-Series controller: RTDE on {}, script port {}", fake.rtde_addr(), fake.primary_addr());
        wait();
        let r = fake.stop();
        let json = serde_json::json!({ "report": &r.report, "errors": [], "timeouts": r.timeouts, "violations": r.violations, "clean_stops": r.clean_stops, "scripts": r.scripts.len() });
        (r.report, json)
    } else {
        let mut start_deg = [0.0; 6];
        start_deg.copy_from_slice(&start[..6]);
        let monitor = SocketAddr::new(cli.listen.ip(), if cli.listen.port() == 0 { 0 } else { cli.listen.port() + 1 });
        let opts = MecaOptions { control: cli.listen, monitor, start_deg, rt_priority: cli.rt, ..Default::default() };
        let fake = match FakeMeca::spawn(opts) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("strand-fake-robot: {}: {e}", cli.listen);
                return ExitCode::from(1);
            }
        };
        eprintln!("strand-fake-robot: a Meca500 listening on {} (monitoring {})", fake.control_addr(), fake.monitor_addr());
        wait();
        let r = fake.stop();
        let json = serde_json::json!({ "report": &r.report, "errors": r.errors, "timeouts": r.timeouts, "move_joints_vel": r.move_joints_vel, "commands": r.commands });
        (r.report, json)
    };
    eprintln!(
        "strand-fake-robot: {} cycles, {} with a fresh command, {} without; {}",
        report.cycles, report.in_time, report.missing, json["errors"]
    );
    if let Some(p) = &cli.stats
        && let Err(e) = std::fs::write(p, format!("{json:#}\n"))
    {
        eprintln!("strand-fake-robot: {}: {e}", p.display());
        return ExitCode::from(1);
    }
    ExitCode::SUCCESS
}

fn main() -> ExitCode {
    let mut cli = Cli::parse();
    let axes = if matches!(cli.protocol, Protocol::Fri) { 7 } else { 6 };
    // EGM and RSI carry external axes after the arm's six (as many as a joint command holds).
    let most = if matches!(cli.protocol, Protocol::Egm | Protocol::Rsi) { strand_ipc::MAX_JOINTS } else { axes };
    if cli.start.is_empty() {
        let deg = |q: &[f64]| q.iter().map(|q| q.to_degrees()).collect();
        cli.start = match cli.protocol {
            Protocol::Fri => deg(&[0.0f64, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0]),
            Protocol::Bcap => deg(&[0.0, 0.649, 2.048, 0.0, 0.445, 0.0]),
            Protocol::Meca => deg(&[0.0, 0.121, 0.459, 0.0, 0.991, 0.0]),
            Protocol::Ur => deg(&[0.0, -std::f64::consts::FRAC_PI_2, 0.0, -std::f64::consts::FRAC_PI_2, 0.0, 0.0]),
            _ => vec![0.0, -90.0, 90.0, 0.0, 90.0, 0.0],
        };
    }
    if !(axes..=most).contains(&cli.start.len()) || cli.start.iter().any(|x| !x.is_finite()) {
        let count = if most > axes { format!("{axes} to {most}") } else { axes.to_string() };
        eprintln!("strand-fake-robot: --start needs {count} finite angles (degrees; mm for a linear external axis)");
        return ExitCode::from(2);
    }
    if matches!(cli.protocol, Protocol::Bcap | Protocol::Meca | Protocol::Ur) {
        // SAFETY: the handler only stores to an atomic.
        unsafe {
            libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
            libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
        }
        if matches!(cli.protocol, Protocol::Bcap) && cli.period == 0.004 {
            // The RC8's slave-mode cycle, unless one is given.
            cli.period = 0.008;
        }
        return serve(&cli);
    }
    let Some(driver) = cli.driver else {
        eprintln!("strand-fake-robot: --driver IP:PORT is needed for EGM, RSI and FRI");
        return ExitCode::from(2);
    };
    let period_ms = (cli.period * 1e3).round() as u64;
    let mut protocol: Box<dyn FakeProtocol> = match cli.protocol {
        Protocol::Egm => Box::new(FakeEgm::new(cli.stopped_cycles, period_ms as u32)),
        Protocol::Rsi => Box::new(FakeRsi::new(&cli.start, period_ms)),
        Protocol::Bcap | Protocol::Meca | Protocol::Ur => unreachable!("served above"),
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
        driver,
        bind: SocketAddr::from(([127, 0, 0, 1], 0)),
        period: cli.period,
        start_deg: cli.start.clone(),
        lag: cli.lag,
        cycles: cli.cycles,
        give_up_after: cli.give_up_after,
        rt_priority: cli.rt,
    };
    let run = match cli.unit_driver {
        Some(unit_driver) => {
            if !matches!(cli.protocol, Protocol::Egm) || cli.start.len() <= 6 {
                eprintln!("strand-fake-robot: --unit-driver: an EGM controller with external axes (--start with more than six values)");
                return ExitCode::from(2);
            }
            let mut unit = FakeEgm::unit(cli.stopped_cycles, period_ms as u32);
            let mut channels = [
                FakeChannel { protocol: protocol.as_mut(), driver, axes: 0..6 },
                FakeChannel { protocol: &mut unit, driver: unit_driver, axes: 6..cli.start.len() },
            ];
            run_channels(&mut channels, &opts, &STOP)
        }
        None => run(protocol.as_mut(), &opts, &STOP),
    };
    let report = match run {
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
