//! strand: the service binary. `strand run` loads the configuration, builds the robot and the
//! controller and runs the cycle over iceoryx2 until interrupted; `strand check-config` validates a
//! configuration and reports the chain it would drive.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Parser, Subcommand};
use strand::config::{Config, locate};
use strand::io::clock::ClockMode;
use strand::io::runner::{JointFeedback, NullSink, Runner, StopWhen};
use strand::log::writer::{LogContext, Logger};

#[derive(Parser)]
#[command(name = "strand", version, about = "Real-time streaming motion controller for robot-arm additive manufacturing")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the controller service until Ctrl-C (or until a job ends, with --exit-when-done).
    Run {
        /// The service configuration: a file, or a NAME (`iiwa7`, `free-flyer`) found like the
        /// default (default.toml: $STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, then
        /// the built-in copy).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Override `[service] prefix` (service names).
        #[arg(long)]
        prefix: Option<String>,
        /// Override `[service] clock`: timer, robot or free-run.
        #[arg(long, value_parser = parse_clock)]
        clock: Option<ClockMode>,
        /// Echo commands as joint state (no robot driver).
        #[arg(long)]
        echo: bool,
        /// Stop after this many ticks.
        #[arg(long)]
        ticks: Option<u64>,
        /// Exit when a job has ended (finished, stopped or faulted).
        #[arg(long)]
        exit_when_done: bool,
        /// Write the MCAP log to this file (overrides `[log] dir` and `name`).
        #[arg(long, conflicts_with = "no_log")]
        log: Option<PathBuf>,
        /// Do not write a log (overrides `[log] enabled`).
        #[arg(long)]
        no_log: bool,
        /// Serve the live view (overrides `[view] enabled`): open ws://127.0.0.1:8765 in Foxglove.
        #[arg(long)]
        view: bool,
        /// Override one config key, e.g. `--set base.estimator=moving-average` (repeatable; the
        /// value is TOML, or else a string). The log's effective config records the result.
        #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
        set: Vec<String>,
    },
    /// Check a job (G-code or segment file) against the robot before printing: the whole job
    /// through the controller in virtual time. Exit 0: clean; 3: it would fault, leave its path or
    /// hit a limit; 2: bad input.
    CheckJob {
        /// The job: G-code or a segment file.
        file: PathBuf,
        /// The service configuration (a file or a NAME, found like `run`'s).
        #[arg(long)]
        config: Option<PathBuf>,
        /// One JSON object on stdout instead of the summary.
        #[arg(long)]
        json: bool,
        /// Write joints.png (positions against limits) and tcp_error.png into this folder.
        #[arg(long, value_name = "DIR")]
        png: Option<PathBuf>,
        /// The planned base trajectory (CSV with t, base_x, base_y[, base_theta], as `strand-plan
        /// base --trajectory` writes it) for a tracked base; without it the base is assumed still.
        #[arg(long, value_name = "CSV")]
        base_trajectory: Option<PathBuf>,
        /// Override one config key (repeatable), as `run --set`.
        #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
        set: Vec<String>,
    },
    /// Control a running service: status, pause, resume, stop, estop, clear-fault, feed, flow.
    /// Each command waits for the service to acknowledge it in its Status; exit 0: done, 3:
    /// refused or not acknowledged (the reason on stderr), 1: no service.
    Ctl {
        /// The service prefix (`[service] prefix` of the running service).
        #[arg(long, default_value = strand_ipc::DEFAULT_PREFIX)]
        prefix: String,
        /// Longest wait for the service and its acknowledgement (s).
        #[arg(long, default_value_t = 3.0)]
        timeout: f64,
        #[command(subcommand)]
        verb: CtlCommand,
    },
    /// Calibrate the cell from touched points: the tool, the bed frame, the tracked base, the
    /// extruder. The joints come from --snapshots FILE or, without it, from the live JointState on
    /// each Enter. Exit 0: an answer; 3: the touches cannot determine it (the reason on stderr);
    /// 2: bad input or config; 1: no service for a live reading.
    Calibrate {
        #[command(subcommand)]
        verb: CalibrateCommand,
    },
    /// Load and validate a configuration and the robot it names; print what it describes.
    CheckConfig {
        /// The service configuration: a file, or a NAME (`iiwa7`, `free-flyer`) found like the
        /// default (default.toml: $STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, then
        /// the built-in copy).
        config: Option<PathBuf>,
    },
}

/// What every `calibrate` verb takes.
#[derive(clap::Args)]
struct CalibrateArgs {
    /// The service configuration (a file or a NAME, found like `run`'s).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Joint snapshots, one per line: joint angles in rad in chain order, comma-separated, `#`
    /// comments allowed (`base`: the pairs file, see the README). Without it: live, one per Enter.
    #[arg(long, value_name = "FILE")]
    snapshots: Option<PathBuf>,
    /// One JSON object on stdout instead of the text.
    #[arg(long)]
    json: bool,
    /// Write the answer into this config, keeping its comments (`tool`: into the robot file it names).
    #[arg(long, value_name = "CONFIG")]
    write: Option<PathBuf>,
    /// The service prefix for a live reading (default: the config's `[service] prefix`).
    #[arg(long)]
    prefix: Option<String>,
}

#[derive(Subcommand)]
enum CalibrateCommand {
    /// `[tool] xyz` from the nozzle tip on one fixed point from 4 or more orientations.
    Tool {
        #[command(flatten)]
        args: CalibrateArgs,
        /// Also find the nozzle axis (`[tool] rpy`) from two touches further up the nozzle.
        #[arg(long)]
        axis: bool,
        /// The axis touches' snapshots (with --snapshots; implies --axis).
        #[arg(long, value_name = "FILE")]
        axis_snapshots: Option<PathBuf>,
    },
    /// `[bed] frame` from 3 touched points (origin, +x, +y side) or more (a least-squares plane).
    Frame {
        #[command(flatten)]
        args: CalibrateArgs,
    },
    /// `[bed.mesh]`: the bed's surface from heights on a grid (nozzle touches, or a probe's points).
    Mesh {
        #[command(flatten)]
        args: CalibrateArgs,
        /// Probed points instead of touches: x, y, z per line in the bed frame (m), `#` comments allowed.
        #[arg(long, value_name = "FILE")]
        points: Option<PathBuf>,
        /// Nodes along x and y, e.g. `5x5` (default: the config's [bed.mesh] grid).
        #[arg(long, value_name = "NXxNY", value_parser = parse_grid)]
        grid: Option<[usize; 2]>,
        /// The grid's lower corner in the bed frame, `X,Y` in mm (default: the touches' extent).
        #[arg(long, value_name = "X,Y", value_parser = parse_xy_mm, requires = "max")]
        min: Option<[f64; 2]>,
        /// The grid's upper corner in the bed frame, `X,Y` in mm.
        #[arg(long, value_name = "X,Y", value_parser = parse_xy_mm, requires = "min")]
        max: Option<[f64; 2]>,
        /// Interpolation between the heights: bicubic or bilinear (default: the config's, else bicubic).
        #[arg(long, value_parser = ["bicubic", "bilinear"])]
        algorithm: Option<String>,
    },
    /// `[base] mount` by hand-eye calibration (AX = XB, Park-Martin) from arm and tracker poses.
    Base {
        #[command(flatten)]
        args: CalibrateArgs,
    },
    /// `[extruder] drive_wheel_radius` from a commanded and a measured filament length.
    Extruder {
        #[command(flatten)]
        args: CalibrateArgs,
        /// Filament length to extrude (mm).
        #[arg(long, default_value_t = 50.0)]
        commanded: f64,
        /// The length that went in (mm); without it the service extrudes --commanded and asks.
        #[arg(long)]
        measured: Option<f64>,
        /// Filament speed of the extrusion (mm/s).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
    },
}

#[derive(Subcommand)]
enum CtlCommand {
    /// Print the state, job progress (layer, line, path), queue, overrides and faults.
    Status {
        /// Keep printing, as a live line on a terminal, until Ctrl-C.
        #[arg(long)]
        watch: bool,
        /// JSON instead of the text line.
        #[arg(long)]
        json: bool,
    },
    /// Pause the job: it stops on the path within the jerk limits and retracts.
    Pause,
    /// Resume a paused job: it primes and continues where it stopped.
    Resume,
    /// Stop the job: it brakes on the path and ends Stopped.
    Stop,
    /// Emergency stop: a latched fault.
    Estop,
    /// Clear a latched fault.
    ClearFault,
    /// Feed override in percent (1 to 200).
    Feed {
        /// Percent of the programmed feed.
        percent: f64,
    },
    /// Flow override in percent (0 to 200).
    Flow {
        /// Percent of the programmed extrusion.
        percent: f64,
    },
}

impl From<CtlCommand> for strand::ctl::CtlVerb {
    fn from(c: CtlCommand) -> Self {
        use strand::ctl::CtlVerb;
        match c {
            CtlCommand::Status { watch, json } => CtlVerb::Status { watch, json },
            CtlCommand::Pause => CtlVerb::Pause,
            CtlCommand::Resume => CtlVerb::Resume,
            CtlCommand::Stop => CtlVerb::Stop,
            CtlCommand::Estop => CtlVerb::EmergencyStop,
            CtlCommand::ClearFault => CtlVerb::ClearFault,
            CtlCommand::Feed { percent } => CtlVerb::Feed(percent),
            CtlCommand::Flow { percent } => CtlVerb::Flow(percent),
        }
    }
}

fn parse_clock(s: &str) -> Result<ClockMode, String> {
    match s {
        "timer" => Ok(ClockMode::Timer),
        "robot" => Ok(ClockMode::Robot),
        "free-run" => Ok(ClockMode::FreeRun),
        _ => Err(format!("unknown clock {s:?}: timer, robot or free-run")),
    }
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Command::Run { config, prefix, clock, echo, ticks, exit_when_done, log, no_log, view, set } => {
            tracing_subscriber::fmt()
                .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
                .with_writer(std::io::stderr)
                .init();
            let mut cfg = match locate::service_config(config.as_deref()).and_then(|c| Config::load_with(&c, &set)) {
                Ok(c) => c,
                Err(e) => {
                    eprintln!("strand: {e}");
                    return ExitCode::from(2);
                }
            };
            if let Some(p) = prefix {
                cfg.service.prefix = p;
            }
            if let Some(c) = clock {
                cfg.service.clock = c;
            }
            if echo {
                cfg.service.joint_feedback = JointFeedback::Echo;
            }
            if no_log {
                cfg.log.enabled = false;
            }
            if view {
                cfg.view.enabled = true;
            }
            if log.is_some() {
                cfg.log.enabled = true;
            }
            run(&cfg, log.as_deref(), StopWhen { max_ticks: ticks, job_done: exit_when_done })
        }
        Command::CheckJob { file, config, json, png, base_trajectory, set } => {
            // SAFETY: as for check-config.
            unsafe {
                libc::signal(libc::SIGPIPE, libc::SIG_DFL);
            }
            check_job(&file, config.as_deref(), &set, json, png.as_deref(), base_trajectory.as_deref())
        }
        Command::Ctl { prefix, timeout, verb } => ctl(&prefix, timeout, verb.into()),
        Command::Calibrate { verb } => calibrate(verb),
        Command::CheckConfig { config } => {
            // A closed pipe (`strand check-config | head`) ends it quietly instead of a panic.
            // SAFETY: setting a signal's disposition to the default; no other thread runs yet.
            unsafe {
                libc::signal(libc::SIGPIPE, libc::SIG_DFL);
            }
            check_config(config.as_deref())
        }
    }
}

fn ctl(prefix: &str, timeout: f64, verb: strand::ctl::CtlVerb) -> ExitCode {
    use strand::ctl::{CtlError, CtlVerb};
    // SAFETY: as for check-config; the handler only stores to an atomic. Only `status --watch`
    // catches Ctrl-C (to end its line); a command waiting for its acknowledgement ends at once.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        if matches!(verb, CtlVerb::Status { watch: true, .. }) {
            libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        }
    }
    let timeout = std::time::Duration::from_secs_f64(if timeout.is_finite() { timeout.clamp(0.05, 3600.0) } else { 3.0 });
    let result = match verb {
        CtlVerb::Status { watch: true, json } => strand::ctl::watch(prefix, json, timeout, &STOP).map(|()| None),
        CtlVerb::Status { watch: false, .. } => strand::ctl::status(prefix, timeout).map(Some),
        v => strand::ctl::run(prefix, v, timeout).map(|s| Some((s, None))),
    };
    match result {
        Ok(Some((s, progress))) => {
            match verb {
                CtlVerb::Status { json: true, .. } => println!("{}", strand::ctl::status_json(&s, progress.as_ref())),
                _ => println!("{}", strand::ctl::status_line(&s, progress.as_ref())),
            }
            ExitCode::SUCCESS
        }
        Ok(None) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand ctl: {e}");
            match e {
                CtlError::NoService { .. } | CtlError::Port(_) => ExitCode::from(1),
                _ => ExitCode::from(3),
            }
        }
    }
}

/// `--grid 5x5`: nodes along x and y.
fn parse_grid(s: &str) -> Result<[usize; 2], String> {
    let (x, y) = s.split_once(['x', 'X', ',']).ok_or_else(|| format!("{s:?}: write the grid as NXxNY, e.g. 5x5"))?;
    let n = |v: &str| v.trim().parse::<usize>().map_err(|_| format!("{s:?}: {v:?} is not a whole number of nodes"));
    Ok([n(x)?, n(y)?])
}

/// `--min 10,20`: a bed point in mm, as m.
fn parse_xy_mm(s: &str) -> Result<[f64; 2], String> {
    let (x, y) = s.split_once(',').ok_or_else(|| format!("{s:?}: write X,Y in mm, e.g. 10,20"))?;
    let n = |v: &str| v.trim().parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| format!("{s:?}: {v:?} is not a number"));
    Ok([n(x)? * 1e-3, n(y)? * 1e-3])
}

fn calibrate(verb: CalibrateCommand) -> ExitCode {
    use strand::calibrate::{CalibrateOptions, CalibrateVerb};
    use strand_core::MeshAlgorithm;
    let (args, verb) = match verb {
        CalibrateCommand::Tool { args, axis, axis_snapshots } => (args, CalibrateVerb::Tool { axis, axis_snapshots }),
        CalibrateCommand::Frame { args } => (args, CalibrateVerb::Frame),
        CalibrateCommand::Mesh { args, points, grid, min, max, algorithm } => {
            let algorithm = algorithm.map(|a| if a == "bilinear" { MeshAlgorithm::Bilinear } else { MeshAlgorithm::Bicubic });
            let bounds = min.zip(max);
            (args, CalibrateVerb::Mesh(strand::calibrate::MeshOptions { points, grid, bounds, algorithm }))
        }
        CalibrateCommand::Base { args } => (args, CalibrateVerb::Base),
        CalibrateCommand::Extruder { args, commanded, measured, speed } => {
            (args, CalibrateVerb::Extruder { commanded: commanded * 1e-3, measured: measured.map(|m| m * 1e-3), speed: speed * 1e-3 })
        }
    };
    let config = match locate::service_config(args.config.as_deref()) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand calibrate: {e}");
            return ExitCode::from(2);
        }
    };
    let opts = CalibrateOptions { config, snapshots: args.snapshots, json: args.json, write: args.write, prefix: args.prefix };
    match strand::calibrate::run(&verb, &opts, &mut std::io::stdin().lock()) {
        Ok(text) => {
            print!("{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("strand calibrate: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

fn check_config(config: Option<&Path>) -> ExitCode {
    let loaded = locate::service_config(config)
        .and_then(|c| Config::load(&c))
        .and_then(|c| c.robot.build_model().map(|m| (c, m)))
        .and_then(|(c, m)| c.robot.build_positioner().map(|p| (c, m, p)));
    match loaded {
        Ok((cfg, model, positioner)) => {
            println!("{}: ok", cfg.file.display());
            println!(
                "robot {} from {}: {} → {}, {} joints",
                model.name(),
                model.source(),
                model.root_link(),
                model.tip_link(),
                model.dof()
            );
            if let (Some(p), Some((section, settings))) = (&positioner, cfg.robot.external_axes()) {
                let axes: Vec<String> = p.model().joints().iter().map(|j| format!("{} ({:?})", j.name, j.kind)).collect();
                println!(
                    "{section}: {} → {}, carries the {}, {} axes after the arm's: {}; G-code words {:?}",
                    p.model().root_link(),
                    p.model().tip_link(),
                    if p.carries() == strand_core::Carries::Work { "part" } else { "robot" },
                    p.dof(),
                    axes.join(", "),
                    settings.gcode_words
                );
            }
            println!("clik: task {:?}, gains {:?} 1/s, damping below σ = {}", cfg.clik.task, cfg.clik.gains, cfg.clik.sigma_threshold);
            println!(
                "service: prefix {}, clock {:?}, {} Hz, base {:?}",
                cfg.service.prefix, cfg.service.clock, cfg.controller.rate_hz, cfg.base.mode
            );
            if let Some(b) = &cfg.extruder_board {
                println!(
                    "extruder board (strand-mcu): {}, step {} dir {}, {} microsteps, {:.4} mm/turn; heater {} thermistor {}, max {} °C; temperatures {}",
                    b.serial.display(),
                    b.step_pin,
                    b.dir_pin,
                    b.microsteps,
                    b.rotation_distance * 1e3,
                    b.heater_pin,
                    b.thermistor_pin,
                    b.max_temp,
                    if cfg.extruder.heater == strand_core::HeaterSource::Wire {
                        "acted on"
                    } else {
                        "NOT acted on: set [extruder] heater = \"wire\""
                    }
                );
            }
            if let Some(m) = &cfg.bed.mesh {
                println!("bed mesh: {}", m.summary());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("strand: {e}");
            ExitCode::from(2)
        }
    }
}

fn check_job(file: &Path, config: Option<&Path>, set: &[String], json: bool, png: Option<&Path>, trajectory: Option<&Path>) -> ExitCode {
    let started = std::time::Instant::now();
    let bad = |e: String| {
        eprintln!("strand check-job: {e}");
        ExitCode::from(2)
    };
    let cfg = match locate::service_config(config).and_then(|c| Config::load_with(&c, set)) {
        Ok(c) => c,
        Err(e) => return bad(e.to_string()),
    };
    let (all, warnings) = match cfg
        .bed_transform()
        .map_err(|e| e.to_string())
        .and_then(|bed| strand_job::load_segments_with(file, &bed, cfg.gcode_options()).map_err(|e| e.to_string()))
    {
        Ok(j) => j,
        Err(e) => return bad(e),
    };
    let (segments, layers) = strand_job::wire_job(&all);
    let name = file.display().to_string();
    let job = strand::check::CheckJob { file: &name, segments: &segments, layers: &layers };
    let mut series = png.map(|_| strand::check::CheckSeries::default());
    let report = match strand::check::check_with_trajectory(&job, &cfg, trajectory, series.as_mut()) {
        Ok(r) => r,
        Err(e) => return bad(e.to_string()),
    };
    let wall = started.elapsed().as_secs_f64();
    if json {
        let mut value = serde_json::to_value(&report).expect("the report serialises");
        value["wall_s"] = serde_json::json!(wall);
        value["warnings"] = serde_json::json!(warnings);
        println!("{value}");
    } else {
        for w in &warnings {
            eprintln!("{w}");
        }
        println!("{}", report.summary());
        println!("  checked in {wall:.1} s");
    }
    if let (Some(dir), Some(series)) = (png, &series) {
        let model = match cfg.robot.build_model() {
            Ok(m) => m,
            Err(e) => return bad(e.to_string()),
        };
        let limits: Vec<_> = (0..model.dof()).map(|i| *model.limits(i)).collect();
        let names: Vec<String> = model.joints().iter().map(|j| j.name.clone()).collect();
        match strand::check::plot::write(dir, &report, series, &limits, &names, cfg.controller.tcp_error_limit) {
            Ok(files) => {
                for f in files {
                    eprintln!("wrote {}", f.display());
                }
            }
            Err(e) => return bad(e.to_string()),
        }
    }
    if report.clean { ExitCode::SUCCESS } else { ExitCode::from(3) }
}

/// Starts the live view (`[view]`): warns when it listens beyond this machine or takes control.
fn start_view(cfg: &Config, model: &strand_core::kin::RobotModel) -> Result<strand_view::LiveView, String> {
    let address = cfg.view.socket_addr().map_err(|e| format!("{}: {e}", cfg.file.display()))?;
    if cfg.view.exposed() {
        tracing::warn!(
            "live view listens on {address}, beyond this machine: anyone who reaches it sees the cell{}",
            if cfg.view.allow_control { " and can pause, stop or change the overrides" } else { "" }
        );
    }
    let options = strand_view::ViewOptions {
        address,
        name: format!("strand {} · {} · {}", env!("CARGO_PKG_VERSION"), model.name(), cfg.service.prefix),
        control: cfg.view.allow_control.then(|| strand_ipc::ServiceNames::new(&cfg.service.prefix)),
    };
    let view = strand_view::LiveView::start(&options).map_err(|e| e.to_string())?;
    tracing::info!(
        "live view on ws://{} ({}): open it in Foxglove with the layout tools/foxglove/strand.json",
        view.address(),
        if cfg.view.allow_control { "control allowed" } else { "read-only" }
    );
    Ok(view)
}

fn run(cfg: &Config, log_path: Option<&Path>, when: StopWhen) -> ExitCode {
    // SAFETY: the handler only stores to an atomic; SIG_IGN is always valid. A log file that
    // reaches the file-size limit must fail its write (EFBIG, handled: logging stops), not kill the
    // controller with SIGXFSZ.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let model = match cfg.robot.build_model() {
        Ok(m) => m,
        Err(e) => {
            eprintln!("strand: {e}");
            return ExitCode::from(2);
        }
    };
    let live = if cfg.view.enabled {
        match start_view(cfg, &model) {
            Ok(v) => Some(v),
            Err(e) => {
                eprintln!("strand: {e}");
                return ExitCode::from(2);
            }
        }
    } else {
        None
    };
    let logger = if cfg.log.enabled || live.is_some() {
        let ctx = LogContext::new(cfg, &model);
        let file = match (cfg.log.enabled, log_path) {
            (false, _) => Ok(None),
            (true, Some(p)) => Ok(Some(p.to_path_buf())),
            (true, None) => Logger::new_file_path(&cfg.log).map(Some),
        };
        match file.and_then(|f| Logger::start_with(&cfg.log, ctx, f.as_deref(), live)) {
            Ok(l) => {
                if l.records() {
                    tracing::info!("logging every tick to {}", l.path().display());
                }
                Some(l)
            }
            Err(e) => {
                eprintln!("strand: log: {e}");
                return ExitCode::from(2);
            }
        }
    } else {
        None
    };
    let controller = match cfg.robot.build_controller(&cfg.controller_settings()) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand: {}: {e}", cfg.file.display());
            return ExitCode::from(2);
        }
    };
    let mut runner = match Runner::new(controller, &cfg.service, cfg.controller.joint_state_timeout, cfg.controller.rate_hz) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("strand: {e}");
            return ExitCode::from(1);
        }
    };
    runner.set_log_waits(cfg.log.wait_when_full);
    tracing::info!(
        "strand {}: {} ({} joints) at {} Hz, clock {:?}, services under {}",
        env!("CARGO_PKG_VERSION"),
        runner.controller().model().name(),
        runner.controller().model().dof(),
        cfg.controller.rate_hz,
        cfg.service.clock,
        cfg.service.prefix
    );
    let mut logger = logger;
    let result = match logger.as_mut() {
        Some(l) => runner.run(&cfg.realtime, &STOP, when, l),
        None => runner.run(&cfg.realtime, &STOP, when, &mut NullSink),
    };
    if let Some(l) = logger {
        let records = l.records();
        let r = l.finish();
        let files: Vec<String> = r.files.iter().map(|f| f.display().to_string()).collect();
        eprintln!(
            "log {}{} | {} ticks, {} dropped, {:.1} MB | writer CPU {:.2} s of {:.2} s{}",
            if records { "" } else { "(none, live view only)" },
            files.join(" "),
            r.ticks_written,
            r.drops,
            r.bytes as f64 / 1e6,
            r.writer_cpu_s,
            r.writer_wall_s,
            r.error.map_or(String::new(), |e| format!(" | STOPPED: {e}"))
        );
        if cfg.view.enabled {
            eprintln!("live view | {} messages, {:.1} MB sent to clients", r.live_sent.0, r.live_sent.1 as f64 / 1e6);
        }
    }
    match result {
        Ok(s) => {
            let us = |ns: u64| ns as f64 / 1e3;
            let st = &s.status;
            eprintln!(
                "ticks {} | step p50 {:.1} µs p99 {:.1} µs max {:.1} µs | tick p50 {:.1} µs p99 {:.1} µs | lateness p50 {:.1} µs p99 {:.1} µs max {:.1} µs | late {} overruns {}",
                s.ticks,
                us(s.step_cost.percentile(50.0)),
                us(s.step_cost.percentile(99.0)),
                us(s.step_cost.max()),
                us(s.tick_cost.percentile(50.0)),
                us(s.tick_cost.percentile(99.0)),
                us(s.lateness.percentile(50.0)),
                us(s.lateness.percentile(99.0)),
                us(s.lateness.max()),
                s.cycle.late_wakeups,
                s.cycle.overruns
            );
            eprintln!(
                "state {:?} fault {:?} job {:?} | segments {} rejected {} underruns {} clamps {} | log {:?}, {} ticks not logged",
                strand_ipc::RunState::from_u32(st.run_state),
                strand_ipc::FaultCode::from_u32(st.fault),
                strand_ipc::JobOutcome::from_u32(st.job_outcome),
                st.segments_accepted,
                st.rejected,
                st.underruns,
                st.clamps,
                strand_ipc::LogState::from_u32(st.log_state),
                st.log_drops
            );
            if st.fault != 0 { ExitCode::from(3) } else { ExitCode::SUCCESS }
        }
        Err(e) => {
            eprintln!("strand: {e}");
            ExitCode::from(1)
        }
    }
}
