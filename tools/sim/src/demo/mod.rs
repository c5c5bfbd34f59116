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

//!
//! The bin's main only parses the command line into [`DemoOptions`]; [`run`] is the demo. Its parts:
//! `children` (start, watch and stop the three processes), `summary` (the log joined with the
//! sim's truth: [`Report`]) and `table` (the summary printed).

mod children;
mod operator;
mod summary;
mod table;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use strand::config::{Config, locate};
use strand_core::BaseMode;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{RunState, ServiceNames};

use strand_replay::truth::read_truth;
pub use summary::{Report, Spread, report};

use crate::config::SimConfig;
use children::{Proc, program, report_child, sibling, tail};
use operator::Operator;
pub use operator::OperatorAction;
use strand_cli::error::{Result, ToolError};
use strand_cli::jobs;
use table::print_table;

/// What to run, as `strand-demo`'s options say it.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// Service configuration file or NAME (None: default.toml, or `<robot>.toml` with `robot`).
    pub config: Option<PathBuf>,
    /// A robot by name (uses `<robot>.toml`).
    pub robot: Option<String>,
    /// The job (None: the first layers of the 35 mm box; the 200 mm truss for a tracked base; the
    /// helix cylinder for a cell with a rotary table).
    pub gcode: Option<PathBuf>,
    /// Stream only the first N layers (None: 3 of the box; all of any other job).
    pub layers: Option<usize>,
    /// Plant configuration for strand-sim (None: found beside the service config).
    pub sim: Option<PathBuf>,
    /// Seed of the plant's noise.
    pub seed: Option<u64>,
    /// Service config overrides, `SECTION.KEY=VALUE`.
    pub set: Vec<String>,
    /// Stream without the job check.
    pub no_check: bool,
    /// Folder for the run's files (None: `logs/demo-<UTC time>`).
    pub out: Option<PathBuf>,
    /// The summary as one JSON object instead of a table.
    pub json: bool,
    /// Give up after this long (s, wall).
    pub timeout: f64,
    /// Serve the live view (`[view]`, ws://127.0.0.1:8765 by default) and run the plant at the
    /// robot's real rate, so a viewer sees the print at its real speed.
    pub view: bool,
    /// The operator's actions (pause, resume, overrides) at robot times into the job.
    pub operator: Vec<OperatorAction>,
}

/// Runs the demo: the cell on `opts`' job until it ends, then the summary. Ok(true) when the job
/// finished and its replay is identical; Ok(false) when it did not, was refused by the check, or a
/// child failed (already reported on stderr); an error for a problem the demo finds itself.
pub fn run(opts: &DemoOptions) -> Result<bool> {
    let config = match (&opts.config, &opts.robot) {
        (Some(c), _) => locate::service_config(Some(c)),
        (None, Some(r)) => locate::find(&format!("{r}.toml")),
        (None, None) => locate::find(locate::DEFAULT),
    }?;
    let mut cfg = Config::load_with(&config, &opts.set)?;
    let tracked = cfg.base.mode == BaseMode::Tracked;
    let (gcode, layers) = match &opts.gcode {
        Some(g) => (locate::explicit(g)?, opts.layers),
        None if tracked => (jobs::root()?.join(jobs::DEMO_TRUSS), opts.layers),
        None if cfg.robot.positioner.is_some() => (jobs::root()?.join(jobs::DEMO_HELIX), opts.layers),
        None => (jobs::root()?.join(jobs::DEMO_BOX), Some(opts.layers.unwrap_or(3))),
    };
    // The demo's sim owns the heaters: a job that sets temperatures (the box's M190/M104/M109)
    // runs with the service acting on them (`[extruder] heater = "wire"`: waits hold, a cold hot
    // end faults), unless the operator set `extruder.heater`. A job without any keeps the config's.
    let mut set = opts.set.clone();
    if !set.iter().any(|s| s.trim_start().starts_with("extruder.heater")) && job_sets_temperatures(&gcode, &cfg)? {
        set.insert(0, "extruder.heater=\"wire\"".to_string());
        cfg = Config::load_with(&config, &set)?;
    }
    let sim_cfg = match &opts.sim {
        Some(s) => locate::explicit(s)?,
        None => SimConfig::default_path(&cfg)?,
    };
    let out = match &opts.out {
        Some(o) => o.clone(),
        None => PathBuf::from("logs").join(format!("demo-{}", strand::log::utc_stamp(strand::log::unix_now_ns()))),
    };
    std::fs::create_dir_all(&out).map_err(ToolError::file(&out))?;
    let (strand_bin, sim_bin, feed_bin) = (sibling("strand")?, sibling("strand-sim")?, sibling("strand-feed")?);
    let prefix = format!("strand/demo-{}", std::process::id());
    let log = out.join("run.mcap");
    let truth = out.join("truth.csv");
    let stats = out.join("sim-stats.json");
    let job_name = gcode.file_name().map_or("?".into(), |n| n.to_string_lossy().to_string());
    if !opts.json {
        println!(
            "strand-demo: {} on the robot clock, strand-sim in lockstep ({}), job {job_name}{}; files in {}",
            config.display(),
            sim_cfg.display(),
            layers.map_or(String::new(), |n| format!(" (first {n} layers)")),
            out.display()
        );
    }
    let started = Instant::now();
    let deadline = started + Duration::from_secs_f64(opts.timeout);
    // The job check, here and not in the feeder: the sim's clock (and a free flyer's planned
    // trajectory) starts with the sim, so seconds of checking would put the base's plan ahead of
    // the job. Same job as the feeder will send, same controller as the service will run.
    let predicted = if opts.no_check {
        eprintln!("strand-demo: WARNING: --no-check: the job was not checked against the robot");
        None
    } else {
        match check(&gcode, layers, &cfg, tracked, &sim_cfg)? {
            report if report.clean => {
                if !opts.json {
                    println!(
                        "strand-demo: check-job: clean ({} segments, predicted {:.1} s, max TCP error {:.3} mm)",
                        report.segments,
                        report.time.total_s,
                        report.max_tcp_error_m * 1e3
                    );
                }
                Some(report.time.total_s)
            }
            report => {
                eprintln!("{}", report.summary());
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
    for s in &set {
        svc.args(["--set", s]);
    }
    if opts.view {
        svc.arg("--view").env("RUST_LOG", "warn,strand=info");
    }
    let mut service = Proc::spawn("service", svc, &out)?;
    if opts.view {
        println!(
            "strand-demo: live view on ws://{} — open Foxglove, \"Open connection\" → Foxglove WebSocket, and import the layout tools/foxglove/strand.json",
            cfg.view.address
        );
    }
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
    // The service's overrides, so that both agree on the rate, the robot and the base.
    for o in &set {
        sim.args(["--set", o]);
    }
    if let Some(s) = opts.seed {
        sim.args(["--seed", &s.to_string()]);
    }
    if opts.view {
        sim.arg("--realtime");
    }
    let mut sim = Proc::spawn("sim", sim, &out)?;
    // Start the job once the sim clocks the service (and tracking has arrived): 200 ticks.
    let roles = ClientRoles { monitor: true, control: !opts.operator.is_empty(), ..Default::default() };
    let ports = ClientPorts::open(&ServiceNames::new(&prefix), "strand-demo", roles)?;
    let mut operator = Operator::new(opts.operator.clone());
    let mut operator_sent: Vec<String> = Vec::new();
    let begin = deadline.min(Instant::now() + Duration::from_secs(60));
    if let Err(e) = wait_for_ticks(&ports, &prefix, 200, begin, &mut [&mut service, &mut sim], &out) {
        return fail(e, &mut [&mut service, &mut sim], &[&log, &truth]);
    }
    let mut feed = Command::new(&feed_bin);
    feed.arg(&gcode).arg("--config").arg(&config).args(["--prefix", &prefix, "--quiet", "--wait-service", "20"]);
    for o in &set {
        feed.args(["--set", o]);
    }
    if let Some(n) = layers {
        feed.args(["--layers", &n.to_string()]);
    }
    // The demo checked the job itself, before the sim's clock started (see `check`).
    feed.arg("--no-check");
    let mut feeder = Proc::spawn("feed", feed, &out)?;

    // Watch all three until the feeder ends: a child that fails stops the demo at once.
    let mut job_began = false;
    let watched = loop {
        let status = ports.latest_status();
        job_began |= status.is_some_and(|s| s.segments_accepted > 0);
        if let Some(s) = status {
            // The job's clock starts when its path does (after the approach).
            for (action, control) in operator.due(s.stamp_ns, s.run_state == RunState::Running as u32 && s.executing_seq > 0) {
                // A service that is gone is noticed below, by its exit.
                if let Err(e) = ports.send_control(&control) {
                    eprintln!("strand-demo: operator at {action}: {e}");
                }
                if !opts.json {
                    println!("strand-demo: operator at {action}");
                }
                operator_sent.push(action.to_string());
            }
        }
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
            eprintln!("strand-demo: the job did not end within {} s; stopping", opts.timeout);
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
    let features = strand_replay::bead::Features::of_gcode(&gcode)?;
    let rep = report(&log, &truth_rows, tracked, Some(&features))?;
    rep.bead.write_bins_csv(&out.join("bead.csv"))?;
    let round_trip = std::fs::read_to_string(&stats).ok().and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
    let log_bytes = std::fs::metadata(&log).map(|m| m.len()).unwrap_or(0);
    let ok = rep.job_outcome == "Finished" && rep.identical;
    let mut json = serde_json::to_value(&rep).expect("a report serialises");
    json["wall_s"] = wall.into();
    json["log"] = log.display().to_string().into();
    json["log_bytes"] = log_bytes.into();
    json["truth"] = truth.display().to_string().into();
    json["job"] = gcode.display().to_string().into();
    json["sim"] = round_trip.clone().unwrap_or(serde_json::Value::Null);
    json["ok"] = ok.into();
    json["predicted_s"] = predicted.into();
    json["operator"] = operator_sent.into();
    let summary = out.join("summary.json");
    std::fs::write(&summary, format!("{json:#}\n")).map_err(ToolError::file(&summary))?;
    if opts.json {
        println!("{json}");
    } else {
        print_table(&rep, wall, &log, log_bytes, round_trip.as_ref());
    }
    Ok(ok)
}

/// Whether the job has a heat segment (`M104`, `M109`, `M140`, `M190`, Klipper's heater commands).
fn job_sets_temperatures(job: &Path, cfg: &Config) -> Result<bool> {
    let loaded = strand_feed::load_gcode(job, cfg, None)?;
    Ok(loaded.segments.iter().any(|s| s.kind == strand_ipc::SegmentKind::Heat as u32))
}

/// Checks the job the feeder will send (`strand::check`), same job and same controller as the
/// service will run: the report (`clean` says whether it passed); an error for a job or config
/// that cannot be read.
pub(crate) fn check(job: &Path, layers: Option<usize>, cfg: &Config, tracked: bool, sim_cfg: &Path) -> Result<strand::check::CheckReport> {
    let mut loaded = strand_feed::load_gcode(job, cfg, None)?;
    if let Some(n) = layers {
        loaded = loaded.first_layers(n);
    }
    // Only a tracked base reads the plant's flyer; a bad plant file is the sim's to report.
    let flyer = if tracked { SimConfig::load(sim_cfg).ok().and_then(|s| s.flyer) } else { None };
    let trajectory = flyer.map(|f| f.trajectory).filter(|t| !t.as_os_str().is_empty());
    let name = job.display().to_string();
    let check_job = strand::check::CheckJob { file: &name, segments: &loaded.segments, layers: &loaded.layers };
    Ok(strand::check::check_with_trajectory(&check_job, cfg, trajectory.as_deref(), None)?)
}

/// A failure before the job began: stops the children, removes the idle files and returns the
/// error (the child's own message is in it).
fn fail(e: ToolError, children: &mut [&mut Proc], idle: &[&Path]) -> Result<bool> {
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
fn wait_for_ticks(ports: &ClientPorts, prefix: &str, ticks: u64, deadline: Instant, children: &mut [&mut Proc], out: &Path) -> Result<()> {
    loop {
        if ports.latest_status().is_some_and(|s| s.tick >= ticks) {
            return Ok(());
        }
        for c in children.iter_mut() {
            if let Some(code) = c.exited() {
                let how = if code < 0 { "was killed".to_string() } else { format!("exited with {code}") };
                return Err(ToolError::Process(format!(
                    "the {} ({}) {how} before the job began:\n  {}\nstrand-demo: its whole output: {}",
                    c.name,
                    program(c.name),
                    tail(out, c.name, 20).join("\n  "),
                    out.join(format!("{}.log", c.name)).display()
                )));
            }
        }
        if Instant::now() >= deadline {
            return Err(ToolError::Process(format!(
                "the service under {prefix} was not clocked by the sim ({ticks} ticks) in time; see the service and sim logs in {}",
                out.display()
            )));
        }
        let _ = ports.wait_status(20_000_000);
    }
}
