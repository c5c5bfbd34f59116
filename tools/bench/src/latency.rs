//! `strand-bench latency`: the service on the robot clock, end to end. This process is the robot
//! driver: each period it publishes a JointState stamped with the monotonic clock and waits for the
//! JointCommand that answers it (`state_seq`); state in → command out is the difference. The service
//! runs as its own process (`strand run --clock robot`), printing 004's box fed by this process, and
//! logs every tick, so its own tick cost (wake → publish) comes from the same run.
//!
//! The baseline, in the same run and the same driver code: `strand-bench pong`, a second process
//! that answers each JointState at once over the same iceoryx2 services (publish-subscribe plus an
//! event, as the service does) with no controller behind it. So latency − ping-pong is what the
//! service adds, and the aim is that it stays within the tick's own cost plus a few microseconds.
//!
//! `--rt P` runs it as a cell runs: the service's tick thread SCHED_FIFO P with its memory locked
//! and PM QoS at 0 (`[realtime]`), the ping-pong process the same, and this driver's thread FIFO
//! P + 1 — a robot driver outranks the controller, as the README's set-up advice says. (With the
//! driver left SCHED_OTHER, a command's wake-up of the driver waits behind the rest of the
//! service's tick whenever the two share a CPU, which measures the bench's priorities, not strand.)

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;
use strand::config::Config;
use strand::io::clock::{TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand::log::reader::LogFile;
use strand_ipc as ipc;
use strand_ipc::ServiceNames;
use strand_ipc::ports::{ClientPorts, ClientRoles, ServicePorts};

use super::{Dist, bench_job, stream_job};
use strand_cli::child::Reaped;
use strand_cli::error::{Result, ToolError};

/// What to run.
#[derive(Clone, Debug)]
pub struct LatencyOptions {
    /// Robot rate: JointStates per second (Hz).
    pub rate_hz: f64,
    /// Duration of each of the two runs (s).
    pub seconds: f64,
    /// Service config (robot, controller).
    pub config: PathBuf,
    /// Repository root (the job).
    pub root: PathBuf,
    /// The strand and strand-bench binaries' folder.
    pub bin_dir: PathBuf,
    /// SCHED_FIFO priority of the service and the ping-pong (the driver gets one more); none: all
    /// SCHED_OTHER.
    pub rt_priority: Option<u32>,
    /// Pin the service's tick thread, the ping-pong and this driver to this CPU (with `rt_priority`:
    /// the driver then preempts the service the moment its command is out, with no other CPU to wake).
    pub cpu: Option<usize>,
}

/// The report; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize)]
pub struct LatencyReport {
    /// "latency".
    pub mode: &'static str,
    /// Robot rate (Hz).
    pub rate_hz: f64,
    /// Duration of each run (s).
    pub seconds: f64,
    /// The robot.
    pub robot: String,
    /// State in → command out through the service (ns).
    #[serde(flatten)]
    pub latency: Dist,
    /// States the service did not answer within a period (count).
    pub missed: u64,
    /// The same driver against the ping-pong process (ns).
    pub baseline: Dist,
    /// States the ping-pong did not answer within a period (count).
    pub baseline_missed: u64,
    /// The service's own tick, wake → last publish, from its log of this run (ns).
    pub tick: Dist,
    /// The controller step alone, from the same log (ns).
    pub step: Dist,
    /// The service's tick less its step: the shell on the robot clock (ns).
    pub shell: Dist,
    /// Of the shell: wake → every input drained, the receives (ns).
    pub receive: Dist,
    /// Of the shell: drained → the joint command out, less the step: the lost-feeder check, the
    /// counters and the command's publish and notify (with a driver that outranks the service on
    /// its CPU, the driver's own reaction runs inside that notify) (ns).
    pub command: Dist,
    /// Of the shell: the joint command out → the last publish: the extruder, heater and base
    /// commands and Status (ns).
    pub after_command: Dist,
    /// Ping-pong p99 + tick p99 (ns): what the aim allows before "a few microseconds".
    pub budget_p99_ns: u64,
    /// Latency p99 − budget (ns; negative: within it).
    pub excess_p99_ns: i64,
    /// [RT]'s aim for the p99: ping-pong p99 + step p99 + 5 µs (ns).
    pub aim_p99_ns: u64,
    /// The SCHED_FIFO priority of the service and the ping-pong (`--rt`; the driver one more).
    pub rt_priority: Option<u32>,
    /// The CPU all three were pinned to (`--cpu`).
    pub cpu: Option<usize>,
    /// The histograms, for the plot (not printed).
    #[serde(skip)]
    pub histograms: Vec<(String, Histogram)>,
}

/// Ping-pong, then the service; see the module docs.
pub fn run(opts: &LatencyOptions) -> Result<LatencyReport> {
    let cfg = Config::load(&opts.config)?;
    let model = cfg.robot.build_model()?;
    let dof = model.dof();
    let mut q0 = [0.0; ipc::MAX_JOINTS];
    let middle = model.middle_configuration();
    for (i, q) in q0.iter_mut().enumerate().take(dof) {
        *q = cfg.service.initial_joints.get(i).copied().unwrap_or(middle[i]);
    }
    let pid = std::process::id();

    // 1. The baseline: the driver against `strand-bench pong`.
    let pong_prefix = format!("strand/bench-pong-{pid}");
    let mut pong = Command::new(opts.bin_dir.join("strand-bench"));
    pong.args(["pong", "--prefix", &pong_prefix, "--seconds"]).arg(format!("{}", opts.seconds + 30.0));
    if let Some(p) = opts.rt_priority {
        pong.args(["--rt", &p.to_string()]);
    }
    if let Some(c) = opts.cpu {
        pong.args(["--cpu", &c.to_string()]);
    }
    let pong = pong.stdin(Stdio::null()).spawn().map_err(|e| ToolError::Measurement(format!("cannot start strand-bench pong: {e}")))?;
    let mut pong = Reaped(pong);
    let driver_rt = Realtime { priority: opts.rt_priority.map(|p| p + 1), cpu: opts.cpu };
    let (baseline, baseline_missed) =
        std::thread::scope(|scope| scope.spawn(|| drive(&pong_prefix, dof, q0, opts.rate_hz, opts.seconds, false, driver_rt)).join())
            .map_err(|_| ToolError::Measurement("the driver thread panicked".to_string()))??;
    pong.wait_until(Instant::now() + Duration::from_secs(3));

    // 2. The service on the robot clock, printing the box.
    let prefix = format!("strand/bench-latency-{pid}");
    let log = std::env::temp_dir().join(format!("strand-bench-latency-{pid}.mcap"));
    let mut service = Command::new(opts.bin_dir.join("strand"));
    service.args(["run", "--clock", "robot", "--exit-when-done", "--prefix", &prefix]);
    if let Some(p) = opts.rt_priority {
        for set in [format!("realtime.fifo_priority={p}"), "realtime.lock_memory=true".into(), "realtime.cpu_dma_latency_us=0".into()] {
            service.args(["--set", &set]);
        }
    }
    if let Some(c) = opts.cpu {
        service.args(["--set", &format!("realtime.cpu={c}")]);
    }
    let service = service
        .arg("--config")
        .arg(&opts.config)
        .arg("--log")
        .arg(&log)
        .env("RUST_LOG", "error")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| ToolError::Measurement(format!("cannot start strand: {e}")))?;
    let mut service = Reaped(service);
    let job = bench_job(&opts.root, &cfg)?;
    let stop_feed = AtomicBool::new(false);
    let driven = std::thread::scope(|scope| {
        let feeder = scope.spawn(|| stream_job(&prefix, &job, &stop_feed));
        let driven = scope
            .spawn(|| drive(&prefix, dof, q0, opts.rate_hz, opts.seconds, true, driver_rt))
            .join()
            .unwrap_or_else(|_| Err(ToolError::Measurement("the driver thread panicked".to_string())));
        stop_feed.store(true, Ordering::Relaxed);
        let fed = feeder.join().map_err(|_| ToolError::Measurement("feeder panicked".to_string())).and_then(|r| r);
        driven.and_then(|d| fed.map(|_| d))
    });
    // The driver has stopped: the service faults (JointStateLost), the job ends, it exits.
    service.wait_until(Instant::now() + Duration::from_secs(10));
    let (latency, missed) = driven?;
    let costs = tick_costs(&log);
    let (tick, step) = (&costs[0], &costs[1]);
    let _ = std::fs::remove_file(&log);

    let (lat, base, tick_d) = (Dist::of(&latency), Dist::of(&baseline), Dist::of(tick));
    let budget = base.p99_ns + tick_d.p99_ns;
    Ok(LatencyReport {
        mode: "latency",
        rate_hz: opts.rate_hz,
        seconds: opts.seconds,
        robot: model.name().to_string(),
        latency: lat,
        missed,
        baseline: base,
        baseline_missed,
        tick: tick_d,
        step: Dist::of(step),
        shell: Dist::of(&costs[2]),
        receive: Dist::of(&costs[3]),
        command: Dist::of(&costs[4]),
        after_command: Dist::of(&costs[5]),
        budget_p99_ns: budget,
        excess_p99_ns: lat.p99_ns as i64 - budget as i64,
        aim_p99_ns: base.p99_ns + Dist::of(step).p99_ns + 5_000,
        rt_priority: opts.rt_priority,
        cpu: opts.cpu,
        histograms: vec![("state → command via strand".to_string(), latency), ("iceoryx2 ping-pong".to_string(), baseline)],
    })
}

/// From the service's log (its timings need no replay), ns: the tick (wake → publish), the step,
/// the shell (tick − step), and the shell's parts: receive, step to command out (less the step),
/// command out to the last publish. Ticks without a joint command count in the first three only.
fn tick_costs(log: &Path) -> [Histogram; 6] {
    let mut h: [Histogram; 6] = std::array::from_fn(|_| Histogram::new());
    if let Ok(file) = LogFile::open(log) {
        for r in file.records().flatten() {
            let t = &r.timing;
            h[0].record(t.tick_ns);
            h[1].record(t.step_ns);
            h[2].record(t.tick_ns.saturating_sub(t.step_ns));
            if t.command_ns > 0 {
                h[3].record(t.receive_ns);
                h[4].record(t.command_ns.saturating_sub(t.receive_ns + t.step_ns));
                h[5].record(t.tick_ns.saturating_sub(t.command_ns));
            }
        }
    }
    h
}

/// The robot driver: publishes a stamped JointState every period at `rate_hz` for `seconds` and waits
/// (until the next period) for the JointCommand answering it. `follow`: the next state is the last
/// command (a robot that follows exactly, so the job moves). Waits up to 10 s for the first answer
/// before it measures. Returns the round trips (ns) and the states not answered in time. `rt`: the
/// calling thread's real-time set-up (run it on a thread of its own).
fn drive(
    prefix: &str,
    dof: usize,
    q0: [f64; ipc::MAX_JOINTS],
    rate_hz: f64,
    seconds: f64,
    follow: bool,
    rt: Realtime,
) -> Result<(Histogram, u64)> {
    rt.apply()?;
    let ports = ClientPorts::open(
        &ServiceNames::new(prefix),
        &format!("strand-bench-driver-{}", std::process::id()),
        ClientRoles { driver: true, ..Default::default() },
    )?;
    let period_ns = (1e9 / rate_hz).round() as u64;
    let mut q = q0;
    let mut seq = 0u64;
    let exchange = |seq: u64, q: &mut [f64; ipc::MAX_JOINTS], wait_ns: u64| -> Result<Option<u64>> {
        let stamp = monotonic_ns();
        let state = ipc::JointState { seq, stamp_ns: stamp, dof: dof as u32, position: *q, ..Default::default() };
        ports.send_joint_state(&state)?;
        let until = stamp + wait_ns;
        loop {
            while let Some(cmd) = ports.receive_joint_command()? {
                if cmd.state_seq == seq {
                    let round_trip = monotonic_ns() - stamp;
                    if follow && cmd.valid == 1 {
                        *q = cmd.position;
                    }
                    return Ok(Some(round_trip));
                }
            }
            let now = monotonic_ns();
            if now >= until {
                return Ok(None);
            }
            ports.wait_joint_command(until - now)?;
        }
    };
    // Until the other side answers (it may still be starting).
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        seq += 1;
        if exchange(seq, &mut q, 10_000_000)?.is_some() {
            break;
        }
        if Instant::now() > deadline {
            return Err(ToolError::Measurement(format!("nothing answered the JointStates under {prefix} within 10 s")));
        }
    }
    let mut h = Histogram::new();
    let mut missed = 0;
    let mut clock = TimerClock::new(period_ns, 0, u64::MAX);
    clock.start(monotonic_ns());
    for _ in 0..(seconds * rate_hz).round().max(1.0) as u64 {
        clock.wait();
        seq += 1;
        match exchange(seq, &mut q, period_ns.saturating_sub(period_ns / 10))? {
            Some(ns) => h.record(ns),
            None => missed += 1,
        }
    }
    Ok((h, missed))
}

/// `strand-bench pong`: answers every JointState under `prefix` with a JointCommand at once, over the
/// service's own ports (the baseline of `latency`). Ends `seconds` after it starts, or 2 s after the
/// last state once states have come.
pub fn pong(prefix: &str, seconds: f64, rt: Realtime) -> Result<()> {
    rt.apply()?;
    let ports = ServicePorts::open(&ServiceNames::new(prefix), "strand-bench-pong")?;
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    let mut last_state: Option<Instant> = None;
    let mut seq = 0;
    while Instant::now() < end && last_state.is_none_or(|t| t.elapsed() < Duration::from_secs(2)) {
        ports.wait_joint_state(100_000_000)?;
        while let Some(js) = ports.receive_joint_state()? {
            seq += 1;
            let cmd = ipc::JointCommand {
                seq,
                stamp_ns: monotonic_ns(),
                tick: seq,
                state_seq: js.seq,
                state_stamp_ns: js.stamp_ns,
                dof: js.dof,
                valid: 1,
                position: js.position,
                ..Default::default()
            };
            ports.publish_joint_command(&cmd)?;
            last_state = Some(Instant::now());
        }
    }
    Ok(())
}

/// A bench thread's real-time set-up.
#[derive(Clone, Copy, Debug, Default)]
pub struct Realtime {
    /// SCHED_FIFO priority, with locked memory and PM QoS 0; none: SCHED_OTHER.
    pub priority: Option<u32>,
    /// The CPU to pin the thread to.
    pub cpu: Option<usize>,
}

impl Realtime {
    /// Applies it to the calling thread; an error if a step is refused (the figures would not be
    /// what they say).
    fn apply(self) -> Result<()> {
        if self.priority.is_none() && self.cpu.is_none() {
            return Ok(());
        }
        let report = strand::io::rt::apply(&strand::io::rt::RealtimeConfig {
            fifo_priority: self.priority.unwrap_or(0),
            lock_memory: self.priority.is_some(),
            cpu_dma_latency_us: self.priority.map(|_| 0),
            cpu: self.cpu,
            ..Default::default()
        });
        match report.warnings().next() {
            Some(w) => Err(ToolError::Measurement(format!("real-time set-up refused: {w}"))),
            None => Ok(()),
        }
    }
}

/// Writes the report as a table.
pub fn print(r: &LatencyReport) {
    println!("strand-bench latency: {} at {} Hz for {} s per run (robot clock, printing 004's box)", r.robot, r.rate_hz, r.seconds);
    println!("{}", Dist::header("round trip"));
    println!("{}", r.latency.row("state → command via strand"));
    println!("{}", r.baseline.row("iceoryx2 ping-pong (baseline)"));
    println!("{}", r.tick.row("service tick, wake → publish"));
    println!("{}", r.step.row("controller step"));
    println!("{}", r.shell.row("shell: tick − step"));
    println!("{}", r.receive.row("  wake → inputs drained"));
    println!("{}", r.command.row("  → joint command out (− step)"));
    println!("{}", r.after_command.row("  → last publish"));
    println!("unanswered: {} via strand, {} ping-pong", r.missed, r.baseline_missed);
    println!(
        "p99: {:.1} µs against ping-pong + tick = {:.1} µs ({:+.1} µs)",
        r.latency.p99_ns as f64 * 1e-3,
        r.budget_p99_ns as f64 * 1e-3,
        r.excess_p99_ns as f64 * 1e-3
    );
    println!(
        "[RT]'s aim, ping-pong p99 + step p99 + 5 µs: {:.1} µs ({})",
        r.aim_p99_ns as f64 * 1e-3,
        match (r.rt_priority, r.cpu) {
            (Some(p), None) => format!("service and ping-pong SCHED_FIFO {p}, driver {}", p + 1),
            (Some(p), Some(c)) => format!("service and ping-pong SCHED_FIFO {p}, driver {}, all on CPU {c}", p + 1),
            (None, Some(c)) => format!("all SCHED_OTHER on CPU {c}"),
            (None, None) => "all SCHED_OTHER".to_string(),
        }
    );
}

/// Draws the report's histograms.
pub fn plot(r: &LatencyReport, path: &Path) -> Result<()> {
    let series: Vec<(&str, &Histogram)> = r.histograms.iter().map(|(n, h)| (n.as_str(), h)).collect();
    super::plot_histograms(path, &format!("state in → command out at {} Hz", r.rate_hz), &series)
}
