//! strand-bench: measurements with distributions, not averages. This first mode, `log`, measures
//! the MCAP logger at a control rate: a real controller prints an endless square job on a robot
//! that follows its commands, paced by the service's own timer clock, and every tick goes through
//! `Logger::push` to the writer thread. It reports the enqueue cost per record (p50 … max), drops
//! (the aim is 0), the writer thread's CPU share and the bytes written per second.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand::config::Config;
use strand::core::controller::{Controller, MAX_SEGMENTS_PER_TICK, TickInput};
use strand::io::clock::{TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand::log::messages::TickTiming;
use strand::log::writer::{LogContext, Logger, thread_cpu_s};
use strand_ipc as ipc;

#[derive(Parser)]
#[command(name = "strand-bench", version, about = "Benchmarks: distributions of cost, jitter and throughput")]
struct Cli {
    #[command(subcommand)]
    command: Mode,
}

#[derive(Subcommand)]
enum Mode {
    /// Logger throughput at a control rate: enqueue cost, drops, writer CPU share, bytes/s.
    Log {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 4000.0)]
        rate: f64,
        /// Duration (s).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Service configuration (robot, controller, `[log]`).
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
        /// Log file (default: a temporary file, removed afterwards).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
    },
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

fn log_mode(rate: f64, seconds: f64, config: PathBuf, out: Option<PathBuf>, json: bool) -> Result<(), String> {
    let mut cfg = Config::load(&config).map_err(|e| e.to_string())?;
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
    let result = match Cli::parse().command {
        Mode::Log { rate, seconds, config, out, json } => log_mode(rate, seconds, config, out, json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-bench: {e}");
            ExitCode::from(1)
        }
    }
}
