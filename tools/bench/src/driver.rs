//! `strand-bench latency --driver egm|rsi|fri|bcap|meca`: a robot driver end to end, through the
//! fake robot controller of `strand_driver::fake`. The service runs on the robot clock (`strand run
//! --clock robot`) printing the benchmark job, the driver bridges it to the fake, and the fake runs
//! in this process on absolute deadlines.
//!
//! Where the robot sends first (EGM, RSI, FRI) the fake sends a packet every cycle (4 ms; FRI the
//! iiwa 7's 1 ms) and times each to its answer. Where the driver connects (b-CAP: the RC8's 8 ms
//! slave-mode cycle; the Meca500: a 4 ms driver tick; UR: RTDE's 2 ms) the driver's state receipt →
//! answer is the round trip, an answer in time is one that left within the cycle, and the fake
//! counts what the robot saw: cycles whose command buffer ran dry (b-CAP), velocity or read
//! timeouts, errors and setpoints refused (UR). The
//! driver's own receive → reply figure comes from its `--stats`; both are reported against the
//! cycle, with the share of cycles answered in time.

use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use serde::Serialize;
use strand::config::Config;
use strand::io::histogram::Histogram;
use strand_driver::fake::bcap::{BcapOptions, FakeBcap};
use strand_driver::fake::egm::FakeEgm;
use strand_driver::fake::fri::{FakeFri, FriOptions};
use strand_driver::fake::meca::{FakeMeca, MecaOptions};
use strand_driver::fake::rsi::FakeRsi;
use strand_driver::fake::ur::{FakeUr, UrOptions};
use strand_driver::fake::{FakeOptions, FakeProtocol};

use super::{Dist, bench_job, stream_job};
use strand_cli::child::Reaped;
use strand_cli::error::{Result, ToolError};

/// What to run.
#[derive(Clone, Debug)]
pub struct DriverOptions {
    /// `egm`, `rsi`, `fri`, `bcap`, `meca` or `ur`.
    pub protocol: String,
    /// Duration (s).
    pub seconds: f64,
    /// Service config with the matching `[driver]` (irb140 for EGM, kr6r900 for RSI, iiwa7 for FRI,
    /// vp6242 for b-CAP, meca500 for the Meca500, ur5e for UR).
    pub config: PathBuf,
    /// Repository root (the job).
    pub root: PathBuf,
    /// The strand, strand-egm and strand-rsi binaries' folder.
    pub bin_dir: PathBuf,
    /// SCHED_FIFO priority for the driver (`--rt`), if any.
    pub rt_priority: Option<u32>,
}

/// The report; `--json` prints it as one object (the round trip at the top level).
#[derive(Clone, Debug, Serialize)]
pub struct DriverReport {
    /// "latency-driver".
    pub mode: &'static str,
    /// `egm`, `rsi` or `fri`.
    pub protocol: String,
    /// The robot.
    pub robot: String,
    /// Duration (s).
    pub seconds: f64,
    /// The robot's cycle (s).
    pub cycle_s: f64,
    /// Whether the driver ran with SCHED_FIFO.
    pub rt: bool,
    /// Packet sent → answer received at the fake, answers in time (ns).
    #[serde(flatten)]
    pub round_trip: Dist,
    /// The driver's receive → reply (ns), from its stats.
    pub driver: Dist,
    /// Cycles.
    pub cycles: u64,
    /// Cycles answered in time.
    pub in_time: u64,
    /// Share answered in time.
    pub in_time_share: f64,
    /// Answers after their cycle.
    pub late: u64,
    /// Cycles without an answer (the drivers that connect: cycles the robot ran without a command
    /// — a b-CAP buffer run dry, a Meca500 velocity timeout — and errors it reported).
    pub missing: u64,
    /// Segments the job streamed.
    pub segments_sent: usize,
    /// The histograms, for the plot.
    #[serde(skip)]
    pub histograms: Vec<(String, Histogram)>,
}

/// Runs the service, the driver and the fake for `opts.seconds` with the job printing.
pub fn run(opts: &DriverOptions) -> Result<DriverReport> {
    if matches!(opts.protocol.as_str(), "bcap" | "meca" | "ur") {
        return run_connecting(opts);
    }
    let cfg = Config::load(&opts.config)?;
    let model = cfg.robot.build_model()?;
    let cycle = 1.0 / cfg.controller.rate_hz;
    let pid = std::process::id();
    let prefix = format!("strand/bench-driver-{}-{pid}", opts.protocol);
    let stats = std::env::temp_dir().join(format!("strand-bench-driver-{pid}.json"));
    let port = UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map_err(|e| ToolError::Measurement(format!("no free UDP port: {e}")))?
        .port();
    let spawn = |mut c: Command, what: &str| -> Result<Reaped> {
        c.stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null());
        c.spawn().map(Reaped).map_err(|e| ToolError::Process(format!("cannot start {what}: {e}")))
    };
    let mut service = Command::new(opts.bin_dir.join("strand"));
    service.args(["run", "--clock", "robot", "--no-log", "--prefix", &prefix, "--config"]).arg(&opts.config).env("RUST_LOG", "error");
    let service = spawn(service, "strand")?;
    let driver_bin = opts.bin_dir.join(format!("strand-{}", opts.protocol));
    let mut driver = Command::new(&driver_bin);
    driver.args(["--prefix", &prefix, "--bind", &format!("127.0.0.1:{port}"), "--config"]).arg(&opts.config).arg("--stats").arg(&stats);
    if let Some(p) = opts.rt_priority {
        driver.args(["--rt", &p.to_string()]);
    }
    let mut driver = spawn(driver, &driver_bin.display().to_string())?;
    std::thread::sleep(Duration::from_millis(500));
    let start_deg: Vec<f64> = cfg.service.initial_joints.iter().map(|q| q.to_degrees()).collect();
    let period_ms = (cycle * 1e3).round() as u64;
    let mut protocol: Box<dyn FakeProtocol + Send> = match opts.protocol.as_str() {
        "egm" => Box::new(FakeEgm::new(25, period_ms as u32)),
        "rsi" => Box::new(FakeRsi::new(&start_deg, period_ms)),
        "fri" => Box::new(FakeFri::new(FriOptions { send_period_ms: period_ms as u32, ..Default::default() }).0),
        other => return Err(ToolError::Usage(format!("--driver {other}: egm, rsi or fri"))),
    };
    let fake_opts = FakeOptions {
        driver: SocketAddr::from(([127, 0, 0, 1], port)),
        bind: SocketAddr::from(([127, 0, 0, 1], 0)),
        period: cycle,
        start_deg,
        lag: 0.0,
        cycles: (opts.seconds / cycle).round() as u64,
        give_up_after: 0,
        rt_priority: Some(90),
    };
    let job = bench_job(&opts.root, &cfg)?;
    let (stop_fake, stop_feed) = (AtomicBool::new(false), AtomicBool::new(false));
    let (report, sent) = std::thread::scope(|scope| {
        let fake = scope.spawn(|| strand_driver::fake::run(protocol.as_mut(), &fake_opts, &stop_fake));
        // The job once the driver holds the robot (the service then ticks).
        std::thread::sleep(Duration::from_millis(300));
        let feeder = scope.spawn(|| stream_job(&prefix, &job, &stop_feed));
        let report = fake.join();
        stop_feed.store(true, Ordering::Relaxed);
        (report, feeder.join())
    });
    let report = report
        .map_err(|_| ToolError::Measurement("the fake robot panicked".into()))?
        .map_err(|e| ToolError::Measurement(format!("the fake robot: {e}")))?;
    let sent = sent.map_err(|_| ToolError::Measurement("the feeder panicked".into()))??;
    // The driver's own figures: it writes them at exit.
    driver.stop(Duration::from_secs(10));
    drop(service);
    let text = std::fs::read_to_string(&stats).map_err(ToolError::file(&stats))?;
    let _ = std::fs::remove_file(&stats);
    let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| ToolError::Content(format!("{}: {e}", stats.display())))?;
    let l = &json["latency"];
    let field = |k: &str| l[k].as_u64().unwrap_or(0);
    let driver_dist = Dist {
        samples: field("samples"),
        p50_ns: field("p50_ns"),
        p99_ns: field("p99_ns"),
        p999_ns: field("p999_ns"),
        p9999_ns: field("max_ns"),
        max_ns: field("max_ns"),
    };
    Ok(DriverReport {
        mode: "latency-driver",
        protocol: opts.protocol.clone(),
        robot: model.name().to_string(),
        seconds: opts.seconds,
        cycle_s: cycle,
        rt: opts.rt_priority.is_some(),
        round_trip: Dist::of(&report.round_trip),
        driver: driver_dist,
        cycles: report.cycles,
        in_time: report.in_time,
        in_time_share: report.in_time_share(),
        late: report.late,
        missing: report.missing,
        segments_sent: sent,
        histograms: vec![("packet → answer (fake)".into(), report.round_trip.clone())],
    })
}

/// The controller a connecting driver talks to.
enum Controller {
    Bcap(FakeBcap),
    Meca(FakeMeca),
    Ur(FakeUr),
}

/// The drivers that connect (b-CAP, the Meca500): the fake is a server, the driver dials it.
fn run_connecting(opts: &DriverOptions) -> Result<DriverReport> {
    // The robot's cycle: the RC8's 8 ms; the Meca500's driver tick 4 ms; RTDE's 2 ms.
    let rate_hz = match opts.protocol.as_str() {
        "bcap" => 125.0,
        "ur" => 500.0,
        _ => 250.0,
    };
    let rate = format!("controller.rate_hz={rate_hz}");
    let cfg = Config::load_with(&opts.config, std::slice::from_ref(&rate))?;
    let model = cfg.robot.build_model()?;
    let cycle = 1.0 / rate_hz;
    let pid = std::process::id();
    let prefix = format!("strand/bench-driver-{}-{pid}", opts.protocol);
    let stats = std::env::temp_dir().join(format!("strand-bench-driver-{pid}.json"));
    let start_deg: Vec<f64> = cfg.service.initial_joints.iter().map(|q| q.to_degrees()).collect();
    let io = |e: std::io::Error| ToolError::Measurement(format!("the fake robot: {e}"));
    let (fake, robot, extra) = if opts.protocol == "bcap" {
        let fake = FakeBcap::spawn(BcapOptions { cycle, start_deg, rt_priority: Some(90), ..Default::default() }).map_err(io)?;
        let a = fake.addr();
        (Controller::Bcap(fake), a, Vec::new())
    } else if opts.protocol == "ur" {
        let start_q = std::array::from_fn(|k| cfg.service.initial_joints.get(k).copied().unwrap_or(0.0));
        let fake = FakeUr::spawn(UrOptions { start_q, rt_priority: Some(90), ..Default::default() }).map_err(io)?;
        let (r, p) = (fake.rtde_addr(), fake.primary_addr());
        let extra = ["driver.reverse_port=0".to_string(), format!("driver.script_port={}", p.port())];
        (Controller::Ur(fake), r, extra.iter().flat_map(|e| ["--set".to_string(), e.clone()]).collect())
    } else {
        let mut start = [0.0; 6];
        for (s, q) in start.iter_mut().zip(&start_deg) {
            *s = *q;
        }
        let fake =
            FakeMeca::spawn(MecaOptions { start_deg: start, home_time: 0.2, rt_priority: Some(90), ..Default::default() }).map_err(io)?;
        let (c, m) = (fake.control_addr(), fake.monitor_addr());
        (Controller::Meca(fake), c, vec!["--set".to_string(), format!("driver.monitor_port={}", m.port())])
    };
    let spawn = |mut c: Command, what: &str| -> Result<Reaped> {
        c.stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null());
        c.spawn().map(Reaped).map_err(|e| ToolError::Process(format!("cannot start {what}: {e}")))
    };
    let mut service = Command::new(opts.bin_dir.join("strand"));
    service
        .args(["run", "--clock", "robot", "--no-log", "--prefix", &prefix, "--set", &rate, "--config"])
        .arg(&opts.config)
        .env("RUST_LOG", "error");
    let service = spawn(service, "strand")?;
    let driver_bin = opts.bin_dir.join(format!("strand-{}", opts.protocol));
    let mut driver = Command::new(&driver_bin);
    driver
        .args(["--prefix", &prefix, "--set", &rate, "--robot", &robot.to_string(), "--config"])
        .arg(&opts.config)
        .args(&extra)
        .arg("--stats")
        .arg(&stats);
    if let Some(p) = opts.rt_priority {
        driver.args(["--rt", &p.to_string()]);
    }
    let mut driver = spawn(driver, &driver_bin.display().to_string())?;
    let job = bench_job(&opts.root, &cfg)?;
    let stop_feed = AtomicBool::new(false);
    let sent = std::thread::scope(|scope| {
        // The job once the driver has set the robot up (the service then ticks).
        std::thread::sleep(Duration::from_millis(1000));
        let feeder = scope.spawn(|| stream_job(&prefix, &job, &stop_feed));
        std::thread::sleep(Duration::from_secs_f64(opts.seconds));
        stop_feed.store(true, Ordering::Relaxed);
        feeder.join()
    });
    let sent = sent.map_err(|_| ToolError::Measurement("the feeder panicked".into()))??;
    driver.stop(Duration::from_secs(20));
    drop(service);
    let (missing, errors) = match fake {
        Controller::Bcap(f) => {
            let r = f.stop();
            (r.report.missing, r.errors.len() as u64)
        }
        Controller::Meca(f) => {
            let r = f.stop();
            (r.timeouts, r.errors.len() as u64)
        }
        Controller::Ur(f) => {
            let r = f.stop();
            (r.timeouts, r.violations)
        }
    };
    let text = std::fs::read_to_string(&stats).map_err(ToolError::file(&stats))?;
    let _ = std::fs::remove_file(&stats);
    let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| ToolError::Content(format!("{}: {e}", stats.display())))?;
    if let Some(why) = json["robot_ended"].as_str() {
        return Err(ToolError::Measurement(format!("strand-{}: the robot ended the stream: {why}", opts.protocol)));
    }
    let l = &json["latency"];
    let field = |k: &str| l[k].as_u64().unwrap_or(0);
    let driver_dist = Dist {
        samples: field("samples"),
        p50_ns: field("p50_ns"),
        p99_ns: field("p99_ns"),
        p999_ns: field("p999_ns"),
        p9999_ns: field("max_ns"),
        max_ns: field("max_ns"),
    };
    let c = &json["counters"];
    let count = |k: &str| c[k].as_u64().unwrap_or(0);
    let cycles = count("packets");
    let late = count("missed_cycle");
    let in_time = cycles.saturating_sub(late);
    Ok(DriverReport {
        mode: "latency-driver",
        protocol: opts.protocol.clone(),
        robot: model.name().to_string(),
        seconds: opts.seconds,
        cycle_s: cycle,
        rt: opts.rt_priority.is_some(),
        round_trip: driver_dist,
        driver: driver_dist,
        cycles,
        in_time,
        in_time_share: if cycles == 0 { 0.0 } else { in_time as f64 / cycles as f64 },
        late,
        missing: missing + errors,
        segments_sent: sent,
        histograms: Vec::new(),
    })
}

/// Prints the report as a table.
pub fn print(r: &DriverReport) {
    println!(
        "strand-bench latency --driver {}: {} at a {:.0} ms cycle for {} s{}, printing 004's box ({} segments sent)",
        r.protocol,
        r.robot,
        r.cycle_s * 1e3,
        r.seconds,
        if r.rt { ", driver SCHED_FIFO" } else { "" },
        r.segments_sent
    );
    println!("{}", Dist::header("round trip"));
    if r.histograms.is_empty() {
        // A driver that connects: its own state → answer is the round trip.
        println!("{}", r.driver.row("state → answer (driver)"));
    } else {
        println!("{}", r.round_trip.row("packet → answer (fake robot)"));
        println!("{}", r.driver.row("receive → reply (driver)"));
    }
    println!("cycles {}: {} in time ({:.3} %), {} late, {} missing", r.cycles, r.in_time, 100.0 * r.in_time_share, r.late, r.missing);
}

/// Draws the round-trip histogram into a PNG.
pub fn plot(r: &DriverReport, path: &std::path::Path) -> Result<()> {
    let series: Vec<(&str, &Histogram)> = r.histograms.iter().map(|(n, h)| (n.as_str(), h)).collect();
    super::plot_histograms(path, &format!("{} round trip at a {:.0} ms cycle", r.protocol, r.cycle_s * 1e3), &series)
}
