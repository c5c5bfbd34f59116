//! strand-bench: measurements with distributions, not averages, each next to a baseline from the
//! same run where there is one: `jitter` (wake-up lateness of the cycle runner against an empty
//! TimerClock loop and cyclictest), `latency` (state in → command out on the robot clock against an
//! iceoryx2 ping-pong), `tick` (cost per stage, allocations counted) and `log`, below; the modes are
//! in `strand_tools::bench`. `--json` prints one object per mode with `samples, p50_ns, p99_ns,
//! p999_ns, p9999_ns, max_ns`; `--png FILE` draws the histograms.
//!
//! The `log` mode measures the MCAP logger at a control rate: a real controller prints an endless square job on a robot
//! that follows its commands, paced by the service's own timer clock, and every tick goes through
//! `Logger::push` to the writer thread. It reports the enqueue cost per record (p50 … max), drops
//! (the aim is 0), the writer thread's CPU share and the bytes written per second.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand::config::{Config, locate};
use strand::core::{Controller, MAX_SEGMENTS_PER_TICK, TickInput};
use strand::io::alloc_count::{self, Counting};
use strand::io::clock::{TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand::log::messages::TickTiming;
use strand::log::writer::{LogContext, Logger, thread_cpu_s};
use strand_ipc as ipc;
use strand_tools::bench::{self, Dist, jitter, latency, tick};

/// Counts allocations, for `tick` (the tick path must not allocate).
#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    alloc_count::allocations() as u64
}

#[derive(Parser)]
#[command(name = "strand-bench", version, about = "Benchmarks: distributions of cost, jitter and throughput")]
struct Cli {
    #[command(subcommand)]
    command: Mode,
}

#[derive(Subcommand)]
enum Mode {
    /// Wake-up lateness of the cycle runner (timer mode), idle or with a controller printing, next
    /// to an empty TimerClock loop and (with --cyclictest) cyclictest at the same period.
    Jitter {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Duration of each run (s).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// SCHED_FIFO (at --priority) and mlockall for the runner and the baselines.
        #[arg(long)]
        rt: bool,
        /// SCHED_FIFO priority with --rt.
        #[arg(long, default_value_t = 80)]
        priority: u32,
        /// Run the controller of this robot (a name under config/, or a config file), printing 004's box.
        #[arg(long, value_name = "ROBOT")]
        with_controller: Option<String>,
        /// Also run cyclictest (rt-tests) with the same period, priority and memory locking.
        #[arg(long)]
        cyclictest: bool,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// State in → command out on the robot clock (a driver here, the service as its own process
    /// printing the box), next to an iceoryx2 ping-pong between two processes.
    Latency {
        /// Robot rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Duration of each run (s).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// The robot (a name under config/, or a config file).
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// Cost per stage of a controller tick printing the box (path sample, base correction, FK +
    /// Jacobian, CLIK, extrusion, log enqueue) and of the whole step; allocations counted (must be 0).
    Tick {
        /// The robot (a name under config/, or a config file).
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Ticks to measure.
        #[arg(long, default_value_t = 100_000)]
        iterations: u64,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) of the whole step and the stages into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// The ping-pong end of `latency` (started by it).
    #[command(hide = true)]
    Pong {
        #[arg(long)]
        prefix: String,
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
    },
    /// Logger throughput at a control rate: enqueue cost, drops, writer CPU share, bytes/s.
    Log {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 4000.0)]
        rate: f64,
        /// Duration (s).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Service configuration (robot, controller, `[log]`): a file or a NAME; default:
        /// default.toml by the search order ($STRAND_CONFIG_DIR, ./config,
        /// <prefix>/share/strand/config, the built-in copy).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Log file (default: a temporary file, removed afterwards).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the enqueue-cost histogram (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
}

/// A robot by NAME (`iiwa7` → iiwa7.toml by the search order of `strand::config::locate`), or a
/// config file as it is (which must exist).
fn robot_config(robot: &str) -> Result<PathBuf, String> {
    locate::service_config(Some(Path::new(robot))).map_err(|e| e.to_string())
}

fn emit<T: serde::Serialize>(json: bool, report: &T, table: impl Fn(&T)) -> Result<(), String> {
    if json {
        println!("{}", serde_json::to_string(report).map_err(|e| e.to_string())?);
    } else {
        table(report);
    }
    Ok(())
}

fn check_sane(what: &str, d: &Dist) -> Result<(), String> {
    if d.is_sane() { Ok(()) } else { Err(format!("{what}: implausible distribution {d:?}")) }
}

const DOWN: [f64; 4] = [0.0, 0.0, 1.0, 0.0];

/// The k-th segment of an endless 30 mm square at 30 mm/s (segment 0 is the travel to its corner).
fn square_segment(k: u64) -> ipc::Segment {
    let (x, y, z, side) = (0.45, -0.02, 0.2, 0.03);
    let corners = [[x + side, y, z], [x + side, y + side, z], [x, y + side, z], [x, y, z]];
    let (end, feed, filament, flags) = if k == 0 {
        ([x, y, z], 0.1, 0.0, ipc::segment_flags::TRAVEL)
    } else {
        (corners[((k - 1) % 4) as usize], 0.03, side * 0.033, ipc::segment_flags::EXTRUDE)
    };
    ipc::Segment { seq: k + 1, kind: ipc::SegmentKind::Line as u32, flags, end, orientation: DOWN, feed, filament, ..Default::default() }
}

fn log_mode(
    rate: f64,
    seconds: f64,
    config: Option<PathBuf>,
    out: Option<PathBuf>,
    json: bool,
    png: Option<PathBuf>,
) -> Result<(), String> {
    let mut cfg = locate::service_config(config.as_deref()).and_then(|c| Config::load(&c)).map_err(|e| e.to_string())?;
    cfg.controller.rate_hz = rate;
    cfg.controller.validate().map_err(|e| e.to_string())?;
    let model = cfg.robot.build_model().map_err(|e| e.to_string())?;
    let (path, temporary) = match out {
        Some(p) => (p, false),
        None => (std::env::temp_dir().join(format!("strand-bench-log-{}.mcap", std::process::id())), true),
    };
    let logger = Logger::start_at(&cfg.log, LogContext::new(&cfg, &model), &path).map_err(|e| e.to_string())?;
    let mut ctl = Controller::new(&cfg.controller_settings(), model.clone()).map_err(|e| e.to_string())?;
    let dt_ns = (1e9 / rate).round() as u64;
    let ticks = (seconds * rate).round() as u64;
    let mut clock = TimerClock::new(dt_ns, 0, 50_000);
    let mut q = [0.0; 8];
    let start = [0.0, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0];
    q[..model.dof().min(7)].copy_from_slice(&start[..model.dof().min(7)]);
    let mut enqueue = Histogram::new();
    let mut step = Histogram::new();
    let mut next_segment = 0u64;
    let mut free = 0u32;
    let mut input = TickInput::new(0, 0);
    let mut running_ticks = 0u64;
    let wall0 = monotonic_ns();
    let cpu0 = thread_cpu_s();
    clock.start(monotonic_ns());
    for tick in 0..ticks {
        let wake = clock.wait();
        input.reset(tick, wake.deadline_ns);
        input.cycle.log_drops = logger.dropped();
        input.cycle.log_state = logger.state();
        input.joint_state =
            Some(ipc::JointState { seq: tick + 1, stamp_ns: wake.deadline_ns, dof: model.dof() as u32, position: q, ..Default::default() });
        if tick == 0 {
            input.push_control(&ipc::Control {
                seq: 1,
                stamp_ns: wake.deadline_ns,
                command: ipc::Command::Start as u32,
                value: 0.0,
                _reserved: 0,
            });
            free = 256;
        }
        // Keep the queue fed (credit from the last Status), a batch at a time.
        while free > 0 && input.segment_count < 32.min(MAX_SEGMENTS_PER_TICK as u32) {
            input.push_segment(&square_segment(next_segment));
            next_segment += 1;
            free -= 1;
        }
        let t0 = monotonic_ns();
        let out = ctl.step(&input);
        let t1 = monotonic_ns();
        logger.push(&input, &out, &TickTiming { wake_lateness_ns: wake.lateness_ns, step_ns: t1 - t0, tick_ns: t1 - t0 });
        let t2 = monotonic_ns();
        step.record(t1 - t0);
        enqueue.record(t2 - t1);
        if out.joint_command.valid == 1 {
            q = out.joint_command.position;
        }
        free = out.status.queue_free.saturating_sub(256);
        running_ticks += (out.status.run_state == ipc::RunState::Running as u32) as u64;
    }
    let tick_wall_s = (monotonic_ns() - wall0) as f64 * 1e-9;
    let tick_cpu_s = thread_cpu_s() - cpu0;
    let report = logger.finish();
    let wall = report.writer_wall_s.max(1e-9);
    let ns = |v: u64| v as f64;
    if json {
        println!(
            "{{\"mode\":\"log\",\"rate_hz\":{rate},\"seconds\":{seconds},\"ticks\":{ticks},\"running_ticks\":{running_ticks},\"samples\":{},\"p50_ns\":{},\"p99_ns\":{},\"p999_ns\":{},\"p9999_ns\":{},\"max_ns\":{},\"drops\":{},\"ticks_written\":{},\"bytes\":{},\"bytes_per_s\":{:.0},\"writer_cpu_s\":{:.3},\"writer_wall_s\":{:.3},\"writer_cpu_share\":{:.4},\"tick_thread_cpu_share\":{:.4},\"error\":{}}}",
            enqueue.count(),
            enqueue.percentile(50.0),
            enqueue.percentile(99.0),
            enqueue.percentile(99.9),
            enqueue.percentile(99.99),
            enqueue.max(),
            report.drops,
            report.ticks_written,
            report.bytes,
            report.bytes as f64 / wall,
            report.writer_cpu_s,
            report.writer_wall_s,
            report.writer_cpu_s / wall,
            tick_cpu_s / tick_wall_s,
            report.error.as_ref().map_or("null".to_string(), |e| format!("{e:?}")),
        );
    } else {
        println!("strand-bench log: {ticks} ticks at {rate} Hz ({seconds} s), {running_ticks} of them printing, {} joints", model.dof());
        println!("{:<22} {:>9} {:>9} {:>9} {:>9} {:>9}", "per tick (ns)", "p50", "p99", "p99.9", "p99.99", "max");
        for (name, h) in [("Logger::push", &enqueue), ("Controller::step", &step)] {
            println!(
                "{name:<22} {:>9.0} {:>9.0} {:>9.0} {:>9.0} {:>9.0}",
                ns(h.percentile(50.0)),
                ns(h.percentile(99.0)),
                ns(h.percentile(99.9)),
                ns(h.percentile(99.99)),
                ns(h.max())
            );
        }
        println!("drops                  {}", report.drops);
        println!("ticks written          {}", report.ticks_written);
        println!(
            "bytes                  {} ({:.1} kB/s, {:.0} B/tick)",
            report.bytes,
            report.bytes as f64 / wall / 1e3,
            report.bytes as f64 / ticks.max(1) as f64
        );
        println!(
            "writer CPU             {:.2} s of {:.2} s ({:.1} % of one core)",
            report.writer_cpu_s,
            wall,
            100.0 * report.writer_cpu_s / wall
        );
        println!("tick thread CPU        {:.1} % of one core", 100.0 * tick_cpu_s / tick_wall_s);
        if let Some(e) = &report.error {
            println!("write error            {e}");
        }
    }
    if let Some(png) = png {
        bench::plot_histograms(&png, &format!("Logger::push at {rate} Hz"), &[("Logger::push", &enqueue), ("Controller::step", &step)])?;
    }
    if temporary {
        for f in &report.files {
            let _ = std::fs::remove_file(f);
        }
    } else {
        eprintln!("log: {}", report.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(" "));
    }
    if report.drops > 0 || report.error.is_some() {
        return Err(format!("{} ticks not logged", report.drops));
    }
    Ok(())
}

fn main() -> ExitCode {
    // A closed pipe (`… | head`) ends the process quietly instead of a panic in println!.
    // SAFETY: setting a signal's disposition to the default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let result = (|| match Cli::parse().command {
        Mode::Log { rate, seconds, config, out, json, png } => log_mode(rate, seconds, config, out, json, png),
        Mode::Jitter { rate, seconds, rt, priority, with_controller, cyclictest, json, png } => {
            let opts = jitter::JitterOptions {
                rate_hz: rate,
                seconds,
                rt,
                priority,
                with_controller: with_controller.map(|r| robot_config(&r)).transpose()?,
                cyclictest,
                root: bench::repo_root()?,
            };
            jitter::run(&opts).and_then(|r| {
                emit(json, &r, jitter::print)?;
                if let Some(p) = png {
                    jitter::plot(&r, &p)?;
                }
                check_sane("lateness", &r.lateness)?;
                check_sane("baseline", &r.baseline)
            })
        }
        Mode::Latency { rate, seconds, robot, json, png } => {
            let bin_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(PathBuf::from)).unwrap_or_default();
            let opts =
                latency::LatencyOptions { rate_hz: rate, seconds, config: robot_config(&robot)?, root: bench::repo_root()?, bin_dir };
            latency::run(&opts).and_then(|r| {
                emit(json, &r, latency::print)?;
                if let Some(p) = png {
                    latency::plot(&r, &p)?;
                }
                check_sane("latency", &r.latency)?;
                check_sane("ping-pong", &r.baseline)
            })
        }
        Mode::Tick { robot, iterations, json, png } => {
            let opts = tick::TickOptions { config: robot_config(&robot)?, iterations, root: bench::repo_root()?, allocations };
            tick::run(&opts).and_then(|r| {
                emit(json, &r, tick::print)?;
                if let Some(p) = png {
                    tick::plot(&r, &p)?;
                }
                check_sane("Controller::step", &r.total)?;
                let allocating: Vec<&str> = r.stages.iter().filter(|s| s.allocations > 0).map(|s| s.name.as_str()).collect();
                if r.allocations > 0 || !allocating.is_empty() {
                    return Err(format!("the tick allocated: Controller::step {} times; stages {allocating:?}", r.allocations));
                }
                Ok(())
            })
        }
        Mode::Pong { prefix, seconds } => latency::pong(&prefix, seconds),
    })();
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-bench: {e}");
            ExitCode::from(1)
        }
    }
}
