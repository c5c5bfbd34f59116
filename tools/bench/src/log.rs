//! `strand-bench log`: the MCAP logger at a control rate. A real controller prints an endless
//! square job on a robot that follows its commands, paced by the service's own timer clock, and
//! every tick goes through `Logger::push` to the writer thread. It reports the enqueue cost per
//! record (p50 … max), drops (the aim is 0), the writer thread's CPU share and the bytes written per
//! second.

use std::path::{Path, PathBuf};

use serde::Serialize;
use strand::config::Config;
use strand::io::clock::{TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand::log::messages::TickTiming;
use strand::log::writer::{LogContext, Logger, thread_cpu_s};
use strand_core::{Controller, MAX_SEGMENTS_PER_TICK, TickInput};
use strand_ipc as ipc;

use super::Dist;
use strand_cli::error::{Result, ToolError};

/// What to measure.
#[derive(Clone, Debug)]
pub struct LogOptions {
    /// Tick rate (Hz).
    pub rate_hz: f64,
    /// Duration (s).
    pub seconds: f64,
    /// Service config (robot, controller, `[log]`).
    pub config: PathBuf,
    /// Log file to keep (None: a temporary file, removed afterwards).
    pub out: Option<PathBuf>,
}

/// What it measured; `--json` prints it as one object (the enqueue cost's percentiles at the top
/// level, as every mode's main distribution).
#[derive(Clone, Debug, Serialize)]
pub struct LogReport {
    /// Always "log".
    pub mode: &'static str,
    /// Tick rate (Hz).
    pub rate_hz: f64,
    /// Duration (s).
    pub seconds: f64,
    /// Ticks run.
    pub ticks: u64,
    /// Ticks with the controller Running.
    pub running_ticks: u64,
    /// The robot's joints.
    pub dof: usize,
    /// `Logger::push` per tick (ns).
    #[serde(flatten)]
    pub enqueue: Dist,
    /// Records dropped (queue full).
    pub drops: u64,
    /// Ticks the writer wrote.
    pub ticks_written: u64,
    /// Bytes written.
    pub bytes: u64,
    /// Bytes written per second of the writer's wall time (B/s).
    pub bytes_per_s: f64,
    /// The writer thread's CPU time (s).
    pub writer_cpu_s: f64,
    /// The writer thread's wall time (s).
    pub writer_wall_s: f64,
    /// The writer's CPU share of one core.
    pub writer_cpu_share: f64,
    /// The tick thread's CPU share of one core.
    pub tick_thread_cpu_share: f64,
    /// The writer's error, if it met one.
    pub error: Option<String>,
    /// The log's files, when kept.
    pub files: Vec<PathBuf>,
    /// `Logger::push` cost histogram (ns).
    #[serde(skip)]
    pub enqueue_histogram: Histogram,
    /// `Controller::step` cost histogram (ns).
    #[serde(skip)]
    pub step_histogram: Histogram,
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

/// Runs the logger benchmark: a controller printing an endless square for `opts.seconds` at
/// `opts.rate_hz`, every tick through `Logger::push`. The log is removed afterwards unless
/// `opts.out` names it. An error when the logger dropped a record or could not write.
pub fn run(opts: &LogOptions) -> Result<LogReport> {
    let (rate, seconds) = (opts.rate_hz, opts.seconds);
    let mut cfg = Config::load(&opts.config)?;
    cfg.controller.rate_hz = rate;
    cfg.controller.validate()?;
    let model = cfg.robot.build_model()?;
    let (path, temporary) = match &opts.out {
        Some(p) => (p.clone(), false),
        None => (std::env::temp_dir().join(format!("strand-bench-log-{}.mcap", std::process::id())), true),
    };
    let logger = Logger::start_at(&cfg.log, LogContext::new(&cfg, &model), &path)?;
    let mut ctl = Controller::new(&cfg.controller_settings(), model.clone())?;
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
        logger.push(
            &input,
            &out,
            &TickTiming { wake_lateness_ns: wake.lateness_ns, step_ns: t1 - t0, tick_ns: t1 - t0, ..TickTiming::default() },
        );
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
    if temporary {
        for f in &report.files {
            let _ = std::fs::remove_file(f);
        }
    }
    let result = LogReport {
        mode: "log",
        rate_hz: rate,
        seconds,
        ticks,
        running_ticks,
        dof: model.dof(),
        enqueue: Dist::of(&enqueue),
        drops: report.drops,
        ticks_written: report.ticks_written,
        bytes: report.bytes,
        bytes_per_s: report.bytes as f64 / wall,
        writer_cpu_s: report.writer_cpu_s,
        writer_wall_s: report.writer_wall_s,
        writer_cpu_share: report.writer_cpu_s / wall,
        tick_thread_cpu_share: tick_cpu_s / tick_wall_s,
        error: report.error.as_ref().map(|e| e.to_string()),
        files: if temporary { Vec::new() } else { report.files.clone() },
        enqueue_histogram: enqueue,
        step_histogram: step,
    };
    Ok(result)
}

impl LogReport {
    /// An error when a tick was not logged (a drop or a write error): the benchmark's rule.
    pub fn check(&self) -> Result<()> {
        if self.drops > 0 || self.error.is_some() {
            return Err(ToolError::Measurement(format!(
                "{} ticks not logged{}",
                self.drops,
                self.error.as_ref().map_or(String::new(), |e| format!(" (write error: {e})"))
            )));
        }
        Ok(())
    }
}

/// Prints the report as a table.
pub fn print(r: &LogReport) {
    let ns = |v: u64| v as f64;
    let wall = r.writer_wall_s.max(1e-9);
    println!(
        "strand-bench log: {} ticks at {} Hz ({} s), {} of them printing, {} joints",
        r.ticks, r.rate_hz, r.seconds, r.running_ticks, r.dof
    );
    println!("{:<22} {:>9} {:>9} {:>9} {:>9} {:>9}", "per tick (ns)", "p50", "p99", "p99.9", "p99.99", "max");
    for (name, h) in [("Logger::push", &r.enqueue_histogram), ("Controller::step", &r.step_histogram)] {
        println!(
            "{name:<22} {:>9.0} {:>9.0} {:>9.0} {:>9.0} {:>9.0}",
            ns(h.percentile(50.0)),
            ns(h.percentile(99.0)),
            ns(h.percentile(99.9)),
            ns(h.percentile(99.99)),
            ns(h.max())
        );
    }
    println!("drops                  {}", r.drops);
    println!("ticks written          {}", r.ticks_written);
    println!("bytes                  {} ({:.1} kB/s, {:.0} B/tick)", r.bytes, r.bytes_per_s / 1e3, r.bytes as f64 / r.ticks.max(1) as f64);
    println!("writer CPU             {:.2} s of {:.2} s ({:.1} % of one core)", r.writer_cpu_s, wall, 100.0 * r.writer_cpu_s / wall);
    println!("tick thread CPU        {:.1} % of one core", 100.0 * r.tick_thread_cpu_share);
    if let Some(e) = &r.error {
        println!("write error            {e}");
    }
    if !r.files.is_empty() {
        eprintln!("log: {}", r.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(" "));
    }
}

/// Draws the enqueue-cost and step-cost histograms into a PNG.
pub fn plot(r: &LogReport, path: &Path) -> Result<()> {
    super::plot_histograms(
        path,
        &format!("Logger::push at {} Hz", r.rate_hz),
        &[("Logger::push", &r.enqueue_histogram), ("Controller::step", &r.step_histogram)],
    )
}
