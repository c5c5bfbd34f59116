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

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use clap::Parser;
use strand::config::{Config, locate};
use strand::core::BaseMode;
use strand_ipc::ServiceNames;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_tools::demo::{Report, Spread, read_truth, report};
use strand_tools::jobs;
use strand_tools::sim::config::SimConfig;

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
    /// The job (default: the first layers of the 35 mm box; the 200 mm 1D truss for a tracked base).
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
}

fn sibling(name: &str) -> Result<PathBuf, String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let p = exe.with_file_name(name);
    if p.is_file() {
        Ok(p)
    } else {
        Err(format!("{} not found next to strand-demo: build everything first (cargo build --release --workspace)", p.display()))
    }
}

struct Proc {
    name: &'static str,
    child: Child,
}

impl Proc {
    fn spawn(name: &'static str, mut cmd: Command, out: &Path) -> Result<Proc, String> {
        let log = File::create(out.join(format!("{name}.log"))).map_err(|e| e.to_string())?;
        let child = cmd
            .stdin(Stdio::null())
            .stdout(log.try_clone().map_err(|e| e.to_string())?)
            .stderr(log)
            .spawn()
            .map_err(|e| format!("cannot start {name}: {e}"))?;
        Ok(Proc { name, child })
    }

    /// Its exit code if it has exited (-1: killed by a signal).
    fn exited(&mut self) -> Option<i32> {
        match self.child.try_wait() {
            Ok(Some(s)) => Some(s.code().unwrap_or(-1)),
            _ => None,
        }
    }

    fn wait_until(&mut self, deadline: Instant) -> Option<i32> {
        loop {
            if let Ok(Some(s)) = self.child.try_wait() {
                return Some(s.code().unwrap_or(-1));
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGTERM, then SIGKILL after `grace`; its exit code (-9 if it had to be killed).
    fn stop(&mut self, grace: Duration) -> i32 {
        if let Some(c) = self.exited() {
            return c;
        }
        // SAFETY: kill(2) on our own child's pid.
        unsafe {
            libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM);
        }
        match self.wait_until(Instant::now() + grace) {
            Some(c) => c,
            None => {
                let _ = self.child.kill();
                let _ = self.child.wait();
                -9
            }
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(ok) => {
            if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            }
        }
        Err(e) => {
            eprintln!("strand-demo: {e}");
            ExitCode::from(2)
        }
    }
}

/// The program a child runs, for messages.
fn program(name: &str) -> &'static str {
    match name {
        "service" => "strand",
        "sim" => "strand-sim",
        _ => "strand-feed",
    }
}

/// The last `n` lines a child wrote (its stdout and stderr go to `<out>/<name>.log`).
fn tail(out: &Path, name: &str, n: usize) -> Vec<String> {
    let text = std::fs::read(out.join(format!("{name}.log"))).map(|b| String::from_utf8_lossy(&b).to_string()).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(n)..].iter().map(|l| l.to_string()).collect()
}

/// A child that failed: its name, program, exit code and its own last words, on stderr.
fn report_child(out: &Path, name: &str, code: i32) {
    let how = if code < 0 { "was killed".to_string() } else { format!("exited with {code}") };
    eprintln!("strand-demo: the {name} ({}) {how}:", program(name));
    for l in tail(out, name, 20) {
        eprintln!("  {l}");
    }
    eprintln!("strand-demo: its whole output: {}", out.join(format!("{name}.log")).display());
}

fn run(cli: &Cli) -> Result<bool, String> {
    let config = match (&cli.config, &cli.robot) {
        (Some(c), _) => locate::service_config(Some(c)),
        (None, Some(r)) => locate::find(&format!("{r}.toml")),
        (None, None) => locate::find(locate::DEFAULT),
    }
    .map_err(|e| e.to_string())?;
    let cfg = Config::load_with(&config, &cli.set).map_err(|e| e.to_string())?;
    let tracked = cfg.base.mode == BaseMode::Tracked;
    let (gcode, layers) = match &cli.gcode {
        Some(g) => (locate::explicit(g).map_err(|e| e.to_string())?, cli.layers),
        None if tracked => (jobs::root()?.join(jobs::DEMO_TRUSS), cli.layers),
        None => (jobs::root()?.join(jobs::DEMO_BOX), Some(cli.layers.unwrap_or(3))),
    };
    let sim_cfg = match &cli.sim {
        Some(s) => locate::explicit(s).map_err(|e| e.to_string())?,
        None => SimConfig::default_path(&cfg)?,
    };
    let out = match &cli.out {
        Some(o) => o.clone(),
        None => PathBuf::from("logs").join(format!("demo-{}", strand::log::utc_stamp(strand::log::unix_now_ns()))),
    };
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    let (strand_bin, sim_bin, feed_bin) = (sibling("strand")?, sibling("strand-sim")?, sibling("strand-feed")?);
    let prefix = format!("strand/demo-{}", std::process::id());
    let log = out.join("run.mcap");
    let truth = out.join("truth.csv");
    let stats = out.join("sim-stats.json");
    let job_name = gcode.file_name().map_or("?".into(), |n| n.to_string_lossy().to_string());
    if !cli.json {
        println!(
            "strand-demo: {} on the robot clock, strand-sim in lockstep ({}), job {job_name}{}; files in {}",
            config.display(),
            sim_cfg.display(),
            layers.map_or(String::new(), |n| format!(" (first {n} layers)")),
            out.display()
        );
    }
    let started = Instant::now();
    let deadline = started + Duration::from_secs_f64(cli.timeout);
    // The job check, here and not in the feeder: the sim's clock (and a free flyer's planned
    // trajectory) starts with the sim, so seconds of checking would put the base's plan ahead of
    // the job. Same job as the feeder will send, same controller as the service will run.
    let predicted = if cli.no_check {
        eprintln!("strand-demo: WARNING: --no-check: the job was not checked against the robot");
        None
    } else {
        match check(&gcode, layers, &cfg, tracked, &sim_cfg)? {
            Ok(report) => {
                if !cli.json {
                    println!(
                        "strand-demo: check-job: clean ({} segments, predicted {:.1} s, max TCP error {:.3} mm)",
                        report.segments,
                        report.time.total_s,
                        report.max_tcp_error_m * 1e3
                    );
                }
                Some(report.time.total_s)
            }
            Err(summary) => {
                eprintln!("{summary}");
                eprintln!("strand-demo: refused: the job check fails (run it anyway with --no-check)");
                return Ok(false);
            }
        }
    };

    let mut svc = Command::new(&strand_bin);
    svc.args(["run", "--clock", "robot", "--exit-when-done", "--set", "log.wait_when_full=true", "--prefix", &prefix])
        .arg("--config")
        .arg(&config)
        .arg("--log")
        .arg(&log)
        .env("RUST_LOG", "warn");
    for s in &cli.set {
        svc.args(["--set", s]);
    }
    let mut service = Proc::spawn("service", svc, &out)?;
    let mut sim = Command::new(&sim_bin);
    sim.arg("--config")
        .arg(&config)
        .arg("--sim")
        .arg(&sim_cfg)
        .args(["--prefix", &prefix])
        .arg("--truth")
        .arg(&truth)
        .arg("--stats")
        .arg(&stats);
    if let Some(s) = cli.seed {
        sim.args(["--seed", &s.to_string()]);
    }
    let mut sim = Proc::spawn("sim", sim, &out)?;
    // Start the job once the sim clocks the service (and tracking has arrived): 200 ticks.
    let ports = ClientPorts::open(&ServiceNames::new(&prefix), "strand-demo", ClientRoles { monitor: true, ..Default::default() })
        .map_err(|e| e.to_string())?;
    let begin = deadline.min(Instant::now() + Duration::from_secs(60));
    if let Err(e) = wait_for_ticks(&ports, &prefix, 200, begin, &mut [&mut service, &mut sim], &out) {
        return fail(e, &mut [&mut service, &mut sim], &[&log, &truth]);
    }
    let mut feed = Command::new(&feed_bin);
    feed.arg(&gcode).arg("--config").arg(&config).args(["--prefix", &prefix, "--quiet", "--wait-service", "20"]);
    if let Some(n) = layers {
        feed.args(["--layers", &n.to_string()]);
    }
    // The demo checked the job itself, before the sim's clock started (see `check`).
    feed.arg("--no-check");
    let mut feeder = Proc::spawn("feed", feed, &out)?;

    // Watch all three until the feeder ends: a child that fails stops the demo at once.
    let mut job_began = false;
    let watched = loop {
        job_began |= ports.latest_status().is_some_and(|s| s.segments_accepted > 0);
        if let Some(c) = feeder.exited() {
            // 0 finished, 4 faulted, 6 stopped: the job ended, and the summary says how.
            break if matches!(c, 0 | 4 | 6) { Ok(()) } else { Err(("feed", c)) };
        }
        // The service leaves by itself once the job has ended (exit 0, or 3 when it ended in a
        // fault), maybe just before the feeder sees it; any other exit is a failure.
        if let Some(c) = service.exited().filter(|c| !matches!(c, 0 | 3)) {
            break Err(("service", c));
        }
        if let Some(c) = sim.exited() {
            break Err(("sim", c));
        }
        if Instant::now() >= deadline {
            eprintln!("strand-demo: the job did not end within {} s; stopping", cli.timeout);
            break Err(("feed", feeder.stop(Duration::from_secs(5))));
        }
        let _ = ports.wait_status(20_000_000);
    };
    if let Err((name, code)) = watched {
        // Stop the others: the feeder first (a controlled stop of a job in progress), then the
        // service (it closes its log), then the sim.
        feeder.stop(Duration::from_secs(5));
        service.stop(Duration::from_secs(10));
        sim.stop(Duration::from_secs(5));
        job_began |= ports.latest_status().is_some_and(|s| s.segments_accepted > 0);
        report_child(&out, name, code);
        if job_began {
            eprintln!("strand-demo: the run's log: {} (strand-replay info/plot read it)", log.display());
        } else {
            // Nothing ran: the log and the truth only hold idle ticks.
            let _ = std::fs::remove_file(&log);
            let _ = std::fs::remove_file(&truth);
        }
        return Ok(false);
    }
    // The service exits by itself once the job has ended; give it time to close the log.
    let service_code = match service.wait_until(Instant::now() + Duration::from_secs(30)) {
        Some(c) => c,
        None => service.stop(Duration::from_secs(10)),
    };
    let sim_code = sim.stop(Duration::from_secs(10));
    let wall = started.elapsed().as_secs_f64();
    for (p, code) in [(&service, service_code), (&sim, sim_code)] {
        if code != 0 && !(p.name == "service" && code == 3) {
            report_child(&out, p.name, code);
        }
    }
    let truth_rows = read_truth(&truth)?;
    let rep = report(&log, &truth_rows, tracked)?;
    let round_trip = std::fs::read_to_string(&stats).ok().and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
    let log_bytes = std::fs::metadata(&log).map(|m| m.len()).unwrap_or(0);
    let ok = rep.job_outcome == "Finished" && rep.identical;
    let mut json = serde_json::to_value(&rep).map_err(|e| e.to_string())?;
    json["wall_s"] = wall.into();
    json["log"] = log.display().to_string().into();
    json["log_bytes"] = log_bytes.into();
    json["truth"] = truth.display().to_string().into();
    json["job"] = gcode.display().to_string().into();
    json["sim"] = round_trip.clone().unwrap_or(serde_json::Value::Null);
    json["ok"] = ok.into();
    json["predicted_s"] = predicted.into();
    std::fs::write(out.join("summary.json"), format!("{json:#}\n")).map_err(|e| e.to_string())?;
    if cli.json {
        println!("{json}");
    } else {
        print_table(&rep, wall, &log, log_bytes, round_trip.as_ref());
    }
    Ok(ok)
}

/// Checks the job the feeder will send (`strand::check`): Ok(report) when clean, Err(summary)
/// when not; the outer error is a job or config that cannot be read.
fn check(
    job: &Path,
    layers: Option<usize>,
    cfg: &Config,
    tracked: bool,
    sim_cfg: &Path,
) -> Result<Result<strand::check::CheckReport, String>, String> {
    let mut loaded = strand_tools::feed::load_gcode(job, cfg, None)?;
    if let Some(n) = layers {
        loaded = loaded.first_layers(n);
    }
    // Only a tracked base reads the plant's flyer; a bad plant file is the sim's to report.
    let flyer = if tracked { SimConfig::load(sim_cfg).ok().and_then(|s| s.flyer) } else { None };
    let trajectory = flyer.map(|f| f.trajectory).filter(|t| !t.as_os_str().is_empty());
    let name = job.display().to_string();
    let check_job = strand::check::CheckJob { file: &name, segments: &loaded.segments, layers: &loaded.layers };
    let report = strand::check::check_with_trajectory(&check_job, cfg, trajectory.as_deref(), None).map_err(|e| e.to_string())?;
    Ok(if report.clean { Ok(report) } else { Err(report.summary()) })
}

/// A failure before the job began: stops the children, removes the idle files and returns the
/// error (the child's own message is in it).
fn fail(e: String, children: &mut [&mut Proc], idle: &[&Path]) -> Result<bool, String> {
    for c in children.iter_mut() {
        c.stop(Duration::from_secs(5));
    }
    for f in idle {
        let _ = std::fs::remove_file(f);
    }
    Err(e)
}

/// Waits until the service's Status reports `ticks` ticks. A child that exits meanwhile ends the wait
/// at once, with its last lines (a bad config, a missing binary...).
fn wait_for_ticks(
    ports: &ClientPorts,
    prefix: &str,
    ticks: u64,
    deadline: Instant,
    children: &mut [&mut Proc],
    out: &Path,
) -> Result<(), String> {
    loop {
        if ports.latest_status().is_some_and(|s| s.tick >= ticks) {
            return Ok(());
        }
        for c in children.iter_mut() {
            if let Some(code) = c.exited() {
                let how = if code < 0 { "was killed".to_string() } else { format!("exited with {code}") };
                return Err(format!(
                    "the {} ({}) {how} before the job began:\n  {}\nstrand-demo: its whole output: {}",
                    c.name,
                    program(c.name),
                    tail(out, c.name, 20).join("\n  "),
                    out.join(format!("{}.log", c.name)).display()
                ));
            }
        }
        if Instant::now() >= deadline {
            return Err(format!(
                "the service under {prefix} was not clocked by the sim ({ticks} ticks) in time; see the service and sim logs in {}",
                out.display()
            ));
        }
        let _ = ports.wait_status(20_000_000);
    }
}

fn mm(s: &Spread) -> String {
    format!("mean {:.3} mm, p99 {:.3} mm, max {:.3} mm", s.mean * 1e3, s.p99 * 1e3, s.max * 1e3)
}

fn us(s: &Spread) -> String {
    format!("p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs", s.p50 * 1e6, s.p99 * 1e6, s.max * 1e6)
}

fn print_table(r: &Report, wall: f64, log: &Path, log_bytes: u64, sim: Option<&serde_json::Value>) {
    let mut rows: Vec<(String, String)> = vec![
        ("robot".into(), format!("{} at {} Hz", r.robot, r.rate_hz)),
        (
            "job".into(),
            match r.job_outcome.as_str() {
                "Faulted" => format!(
                    "FAULTED: {} after {:.1} s of robot time",
                    r.faults.first().map_or("fault not in the log".to_string(), |(t, c)| format!("{c} at tick {t}")),
                    r.job_time_s
                ),
                outcome => format!(
                    "{}{}, {:.1} s of robot time in {wall:.1} s wall ({:.1}× real time)",
                    if outcome == "Finished" { "" } else { "NOT FINISHED: " },
                    outcome,
                    r.job_time_s,
                    r.job_time_s / wall.max(1e-9)
                ),
            },
        ),
        ("segments".into(), format!("{} accepted, {} rejected, {} underruns", r.segments_accepted, r.segments_rejected, r.underruns)),
        ("TCP error (sim truth)".into(), format!("{} over {} ticks", mm(&r.tcp_error_m), r.tcp_error_m.samples)),
        ("TCP error (controller's view)".into(), mm(&r.tcp_error_estimated_m)),
        (
            "TCP error watchdog".into(),
            format!(
                "max {:.3} mm = {:.0} % of tcp_error_limit {:.1} mm",
                r.tcp_error_fault_m * 1e3,
                100.0 * r.tcp_error_fault_m / r.tcp_error_limit_m.max(1e-12),
                r.tcp_error_limit_m * 1e3
            ),
        ),
    ];
    if let Some(b) = &r.base_error_m {
        rows.push(("base vs its plan".into(), mm(b)));
    }
    rows.push((
        "flow error".into(),
        format!(
            "mean {:.1} %, p99 {:.1} % of the mean flow {:.2} mm³/s; deposited {:.1} % of commanded",
            100.0 * r.flow_error_m3s.mean / r.flow_mean_m3s.max(1e-30),
            100.0 * r.flow_error_m3s.p99 / r.flow_mean_m3s.max(1e-30),
            r.flow_mean_m3s * 1e9,
            100.0 * r.volume_ratio
        ),
    ));
    rows.push(("controller step".into(), us(&r.step_s)));
    rows.push(("tick (wake → publish)".into(), us(&r.tick_s)));
    if let Some(rt) = sim.and_then(|s| s.get("round_trip")) {
        let f = |k: &str| rt.get(k).and_then(|v| v.as_f64()).unwrap_or(0.0) * 1e-3;
        rows.push((
            "state → command (sim)".into(),
            format!("p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs", f("p50_ns"), f("p99_ns"), f("max_ns")),
        ));
    }
    rows.push(("lateness".into(), format!("{} (robot clock: the tick waits for the robot)", us(&r.lateness_s))));
    rows.push(("overruns / late / clamps".into(), format!("{} / {} / {}", r.overruns, r.late_wakeups, r.clamps)));
    rows.push((
        "faults".into(),
        if r.faults.is_empty() {
            "none".into()
        } else {
            r.faults.iter().map(|(t, c)| format!("{c} at tick {t}")).collect::<Vec<_>>().join(", ")
        },
    ));
    rows.push(("log".into(), format!("{} ({} ticks, {:.1} MB, {} dropped)", log.display(), r.ticks, log_bytes as f64 / 1e6, r.log_drops)));
    rows.push(("strand-replay verify".into(), r.verify.clone()));
    let w = rows.iter().map(|(k, _)| k.chars().count()).max().unwrap_or(0);
    println!();
    for (k, v) in rows {
        println!("  {k:<w$}  {v}");
    }
}
