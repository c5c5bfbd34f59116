//! `strand-bench jitter`: wake-up lateness of the service's own cycle runner in timer mode (idle, or
//! with a controller printing 004's box), next to two baselines from the same run: the same
//! `TimerClock` in a loop that does nothing (what the OS gives this timing code at all), and, when it
//! is installed, `cyclictest` (rt-tests) with the same period, priority and memory locking. The three
//! take turns in rounds of a second, never together (two cores), so each sees the machine alike.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};

use serde::Serialize;
use strand::config::Config;
use strand::io::clock::{ClockMode, TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand::io::rt::{self, RealtimeConfig};
use strand::io::runner::{JointFeedback, NullSink, Runner, StopWhen};
use strand_core::Controller;

use super::{Dist, bench_job, ratio, stream_job};
use strand_cli::error::{Result, ToolError};

/// What to run.
#[derive(Clone, Debug)]
pub struct JitterOptions {
    /// Tick rate (Hz).
    pub rate_hz: f64,
    /// Duration of each of the runs (s).
    pub seconds: f64,
    /// SCHED_FIFO at `priority` and mlockall, for the runner and every baseline.
    pub rt: bool,
    /// SCHED_FIFO priority with `rt` (1..=99).
    pub priority: u32,
    /// Service config of a robot whose controller prints the box during the run; None: idle.
    pub with_controller: Option<PathBuf>,
    /// Also run cyclictest (if installed).
    pub cyclictest: bool,
    /// Repository root (configs, the job).
    pub root: PathBuf,
}

/// The report; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize)]
pub struct JitterReport {
    /// "jitter".
    pub mode: &'static str,
    /// Tick rate (Hz).
    pub rate_hz: f64,
    /// Duration of each run (s).
    pub seconds: f64,
    /// The robot whose controller ran (None: idle runner).
    pub controller: Option<String>,
    /// What the real-time set-up achieved (the OS may refuse FIFO or mlockall).
    pub realtime: String,
    /// Wake-up lateness of the cycle runner (ns).
    #[serde(flatten)]
    pub lateness: Dist,
    /// Ticks that ended after the next deadline (count).
    pub overruns: u64,
    /// Wake-ups later than the service's late threshold (count).
    pub late_wakeups: u64,
    /// The runner's tick, wake → last publish (ns).
    pub tick: Dist,
    /// `Controller::step` alone (ns).
    pub step: Dist,
    /// The same TimerClock in an empty loop (ns).
    pub baseline: Dist,
    /// cyclictest at the same period (ns; µs resolution), if it ran.
    pub cyclictest: Option<Dist>,
    /// Why cyclictest did not run, if it was asked for.
    pub cyclictest_note: Option<String>,
    /// Runner p99.9 / baseline p99.9.
    pub ratio_p999_baseline: f64,
    /// Runner p99.9 / cyclictest p99.9.
    pub ratio_p999_cyclictest: Option<f64>,
    /// Runner p99 / cyclictest p99 ([RT]'s aim: at most 1.2).
    pub ratio_p99_cyclictest: Option<f64>,
    /// The histograms, for the plot (not printed).
    #[serde(skip)]
    pub histograms: Vec<(String, Histogram)>,
}

fn realtime(opts: &JitterOptions) -> RealtimeConfig {
    if opts.rt {
        RealtimeConfig {
            fifo_priority: opts.priority,
            lock_memory: true,
            prefault_stack_bytes: 256 * 1024,
            cpu_dma_latency_us: Some(0),
            ..RealtimeConfig::default()
        }
    } else {
        RealtimeConfig::default()
    }
}

/// Runs the cycle runner, then the empty-loop baseline, then cyclictest.
pub fn run(opts: &JitterOptions) -> Result<JitterReport> {
    let config = match &opts.with_controller {
        Some(c) => c.clone(),
        None => strand::config::locate::find(strand::config::locate::DEFAULT)?,
    };
    let mut cfg = Config::load(&config)?;
    cfg.controller.rate_hz = opts.rate_hz;
    cfg.controller.validate()?;
    let prefix = format!("strand/bench-jitter-{}", std::process::id());
    cfg.service.prefix = prefix.clone();
    cfg.service.clock = ClockMode::Timer;
    cfg.service.joint_feedback = JointFeedback::Echo;
    let rt_cfg = realtime(opts);
    // With --rt the runner's set-up holds /dev/cpu_dma_latency at 0 for the rest of the process (as
    // cyclictest does for itself), so the baselines after it run under the same PM QoS.
    let ticks = (opts.seconds * opts.rate_hz).round().max(1.0) as u64;
    let model = cfg.robot.build_model()?;
    let robot = model.name().to_string();
    let controller = Controller::new(&cfg.controller_settings(), model)?;
    let mut runner = Runner::new(controller, &cfg.service, cfg.controller.joint_state_timeout, opts.rate_hz)?;

    let stop_feed = AtomicBool::new(false);
    let stop_runner = AtomicBool::new(false);
    let job = match &opts.with_controller {
        Some(_) => Some(bench_job(&opts.root, &cfg)?),
        None => None,
    };
    // Interleaved rounds of one second (runner, empty loop, cyclictest), so a noisy phase of a shared
    // machine falls on all three alike rather than on whichever ran then.
    let period_ns = (1e9 / opts.rate_hz).round() as u64;
    let rounds = opts.seconds.round().max(1.0) as u64;
    let ticks_per_round = ticks.div_ceil(rounds);
    let spin_ns = (cfg.service.spin * 1e9) as u64;
    let (mut lateness_h, mut baseline, mut cyclictest) = (Histogram::new(), Histogram::new(), opts.cyclictest.then(Histogram::new));
    let (mut overruns, mut late_wakeups, mut realtime, mut cyclictest_note) = (0, 0, String::new(), None);
    let (mut tick, mut step) = (Histogram::new(), Histogram::new());
    std::thread::scope(|scope| {
        let feeder = job.as_ref().map(|job| scope.spawn(|| stream_job(&prefix, job, &stop_feed)));
        let mut result = Ok(());
        for _ in 0..rounds {
            let when = StopWhen { max_ticks: Some(ticks_per_round), job_done: false };
            match runner.run(&rt_cfg, &stop_runner, when, &mut NullSink) {
                Ok(summary) => {
                    lateness_h.merge(&summary.lateness);
                    tick.merge(&summary.tick_cost);
                    step.merge(&summary.step_cost);
                    overruns += summary.cycle.overruns;
                    late_wakeups += summary.cycle.late_wakeups;
                    realtime = summary.realtime.to_string();
                }
                Err(e) => {
                    result = Err(ToolError::from(e));
                    break;
                }
            }
            baseline.merge(&empty_loop(period_ns, spin_ns, ticks_per_round, &rt_cfg));
            if let Some(h) = cyclictest.as_mut() {
                match run_cyclictest(period_ns, 1.0, opts.rt.then_some(opts.priority)) {
                    Ok(round) => h.merge(&round),
                    Err(e) => cyclictest_note = Some(e.to_string()),
                }
            }
        }
        stop_feed.store(true, Ordering::Relaxed);
        if let Some(f) = feeder {
            match f.join() {
                Ok(Err(e)) => return Err(ToolError::Measurement(format!("feeder: {e}"))),
                Err(_) => return Err(ToolError::Measurement("feeder panicked".to_string())),
                Ok(Ok(_)) => {}
            }
        }
        result
    })?;
    if cyclictest_note.is_some() {
        cyclictest = None;
    }
    let lateness = Dist::of(&lateness_h);
    let base = Dist::of(&baseline);
    let ct = cyclictest.as_ref().map(Dist::of);
    let mut histograms = vec![("strand runner".to_string(), lateness_h), ("empty TimerClock loop".to_string(), baseline)];
    if let Some(h) = cyclictest {
        histograms.push(("cyclictest".to_string(), h));
    }
    Ok(JitterReport {
        mode: "jitter",
        rate_hz: opts.rate_hz,
        seconds: opts.seconds,
        controller: opts.with_controller.as_ref().map(|_| robot),
        realtime,
        lateness,
        overruns,
        late_wakeups,
        tick: Dist::of(&tick),
        step: Dist::of(&step),
        baseline: base,
        ratio_p999_baseline: ratio(lateness.p999_ns, base.p999_ns),
        ratio_p999_cyclictest: ct.map(|c| ratio(lateness.p999_ns, c.p999_ns)),
        ratio_p99_cyclictest: ct.map(|c| ratio(lateness.p99_ns, c.p99_ns)),
        cyclictest: ct,
        cyclictest_note,
        histograms,
    })
}

/// The baseline: the service's TimerClock at the same period and spin, on a thread with the same
/// real-time settings, doing nothing between wake-ups.
fn empty_loop(period_ns: u64, spin_ns: u64, ticks: u64, rt_cfg: &RealtimeConfig) -> Histogram {
    std::thread::scope(|scope| {
        scope
            .spawn(|| {
                let _ = rt::apply(rt_cfg);
                let mut clock = TimerClock::new(period_ns, spin_ns, u64::MAX);
                let mut h = Histogram::new();
                clock.start(monotonic_ns());
                for _ in 0..ticks {
                    h.record(clock.wait().lateness_ns);
                }
                h
            })
            .join()
            .unwrap_or_default()
    })
}

/// Runs `cyclictest` (one thread, CLOCK_MONOTONIC, absolute sleeps, like the runner) for `seconds`
/// and reads its histogram (µs buckets) into a histogram of ns.
pub(crate) fn run_cyclictest(period_ns: u64, seconds: f64, priority: Option<u32>) -> Result<Histogram> {
    let interval_us = (period_ns / 1000).max(1);
    let mut cmd = Command::new("cyclictest");
    cmd.args(["--threads=1", "--clock=0", "--quiet", "--histogram=10000"])
        .arg(format!("--interval={interval_us}"))
        .arg(format!("--duration={}", seconds.ceil().max(1.0) as u64));
    if let Some(p) = priority {
        cmd.arg(format!("--priority={p}")).arg("--mlockall");
    }
    let out = cmd
        .output()
        .map_err(|e| ToolError::Measurement(format!("cyclictest did not run ({e}); install it with `apt-get install rt-tests`")))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(ToolError::Measurement(format!("cyclictest failed ({}): {}", out.status, String::from_utf8_lossy(&out.stderr).trim())));
    }
    parse_cyclictest_histogram(&text)
}

/// cyclictest's `--histogram` output: `NNNNNN CCCCCC` lines (latency in µs, count), then `# ...`
/// summary lines, among them `# Max Latencies: NNNNN` and `# Histogram Overflows: NNNNN`. Each
/// count is recorded at the bucket's upper edge (µs + 1 − 1 ns), so a percentile never reads low.
pub(crate) fn parse_cyclictest_histogram(text: &str) -> Result<Histogram> {
    let mut h = Histogram::new();
    let mut max_us: Option<u64> = None;
    let mut overflows = 0u64;
    for line in text.lines() {
        let line = line.trim();
        if let Some(rest) = line.strip_prefix("# Max Latencies:") {
            max_us = rest.split_whitespace().next().and_then(|v| v.parse().ok());
            continue;
        }
        if let Some(rest) = line.strip_prefix("# Histogram Overflows:") {
            overflows = rest.split_whitespace().next().and_then(|v| v.parse().ok()).unwrap_or(0);
            continue;
        }
        if line.starts_with('#') || line.is_empty() {
            continue;
        }
        let mut f = line.split_whitespace();
        let (Some(us), Some(count)) = (f.next().and_then(|v| v.parse::<u64>().ok()), f.next().and_then(|v| v.parse::<u64>().ok())) else {
            continue;
        };
        for _ in 0..count {
            h.record(us * 1000 + 999);
        }
    }
    if let Some(m) = max_us {
        for _ in 0..overflows {
            h.record(m * 1000 + 999);
        }
    }
    if h.count() == 0 {
        return Err(ToolError::Measurement("cyclictest printed no histogram".to_string()));
    }
    Ok(h)
}

/// Writes the report as a table.
pub fn print(r: &JitterReport) {
    println!(
        "strand-bench jitter: {} Hz for {} s, {} ({})",
        r.rate_hz,
        r.seconds,
        r.controller.as_deref().map_or("idle runner".to_string(), |c| format!("runner with the {c} controller printing")),
        r.realtime.lines().next().unwrap_or("")
    );
    println!("{}", Dist::header("wake-up lateness"));
    println!("{}", r.lateness.row("strand runner (timer mode)"));
    println!("{}", r.baseline.row("empty TimerClock loop (baseline)"));
    match (&r.cyclictest, &r.cyclictest_note) {
        (Some(c), _) => println!("{}", c.row("cyclictest (µs resolution)")),
        (None, Some(note)) => println!("cyclictest: {note}"),
        _ => {}
    }
    println!("overruns {}, late wake-ups {}", r.overruns, r.late_wakeups);
    println!("{}", Dist::header("the runner's tick"));
    println!("{}", r.tick.row("wake → last publish"));
    println!("{}", r.step.row("Controller::step"));
    print!("p99.9 ratio: {:.2}× the empty loop", r.ratio_p999_baseline);
    if let Some(c) = r.ratio_p999_cyclictest {
        print!(", {c:.2}× cyclictest");
    }
    if let Some(c) = r.ratio_p99_cyclictest {
        print!("; p99 ratio: {c:.2}× cyclictest");
    }
    println!();
}

/// Draws the report's histograms.
pub fn plot(r: &JitterReport, path: &Path) -> Result<()> {
    let series: Vec<(&str, &Histogram)> = r.histograms.iter().map(|(n, h)| (n.as_str(), h)).collect();
    super::plot_histograms(path, &format!("wake-up lateness at {} Hz", r.rate_hz), &series)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cyclictest_histogram_is_read() {
        let text = "# /dev/cpu_dma_latency set to 0us\n000000 000000\n000001 000010\n000002 000080\n000003 000009\n000004 000001\n# Total: 000000100\n# Min Latencies: 00001\n# Avg Latencies: 00002\n# Max Latencies: 00004\n# Histogram Overflows: 00000\n";
        let h = parse_cyclictest_histogram(text).unwrap();
        assert_eq!(h.count(), 100);
        let d = Dist::of(&h);
        assert!((2_000..=3_100).contains(&d.p50_ns), "{d:?}");
        assert!((3_000..=4_100).contains(&d.p99_ns), "{d:?}");
        assert!(d.max_ns >= 4_000 && d.max_ns < 5_100, "{d:?}");
        assert!(parse_cyclictest_histogram("# nothing\n").is_err());
    }
}
