//! strand-feed: streams a job (a G-code program or a `strand_job::segfile` segment file) to the service
//! over iceoryx2. It never sends past the credit the controller announces in Status, so nothing is
//! ever dropped; it shows a progress bar
//! (segments, layer, ETA), turns Ctrl-C into a controlled stop (a second Ctrl-C into an emergency
//! stop), can resume from a segment number, and exits with a code that says how the job ended:
//! 0 finished, 1 no service, 2 a bad program or config, 3 refused by the job check, 4 faulted,
//! 5 a segment rejected, 6 stopped before the end.
//!
//! Before it streams, it runs the job through `strand check-job`'s check (the controller in virtual
//! time, `strand::check`) and refuses a job that would fault, leave its path or hit a limit, with
//! the report; `--no-check` skips that, with a warning.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use strand::config::{Config, locate};
use strand_ipc as ipc;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{Command, JobOutcome, RunState, SEGMENT_BATCH_CAPACITY, ServiceNames};
use strand_tools::feed::{Ending, Job, batch, credit, load_gcode};

#[derive(Parser)]
#[command(
    name = "strand-feed",
    version,
    about = "Stream a G-code program or segment file to the strand service (back-pressure from Status)"
)]
struct Cli {
    /// The job: a G-code program, or a segment file (JSON lines, see strand_job::segfile).
    file: PathBuf,
    /// Service configuration: its `[bed]` places the program in the world, its `[service] prefix`
    /// names the services. A file or a NAME (`iiwa7`); default: default.toml by the search order
    /// ($STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, the built-in copy).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Start at this segment number (as shown in the progress and in Status.executing_seq), with a
    /// travel to where it starts.
    #[arg(long)]
    resume_from: Option<u64>,
    /// Seconds to wait for the service's Status.
    #[arg(long, default_value_t = 10.0)]
    wait_service: f64,
    /// Stream only the program's first N layers (by its layer comments).
    #[arg(long)]
    layers: Option<usize>,
    /// No progress bar (one line per 10 % instead).
    #[arg(long)]
    quiet: bool,
    /// Stream without checking the job against the robot first (prints a warning).
    #[arg(long)]
    no_check: bool,
    /// The planned base trajectory for the check on a tracked base (CSV: t, base_x, base_y[, base_theta]).
    #[arg(long, value_name = "CSV")]
    base_trajectory: Option<PathBuf>,
    /// Override one config key (repeatable), as the service's `run --set`: give the feeder the
    /// service's overrides so that its check runs the service's controller.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
}

static INTERRUPTS: AtomicU32 = AtomicU32::new(0);

extern "C" fn on_interrupt(_: libc::c_int) {
    INTERRUPTS.fetch_add(1, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let cfg = match locate::service_config(cli.config.as_deref()).and_then(|c| Config::load_with(&c, &cli.set)) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-feed: {e}");
            return ExitCode::from(2);
        }
    };
    let job = match load_gcode(&cli.file, &cfg, cli.resume_from) {
        Ok(j) => match cli.layers {
            Some(n) => j.first_layers(n),
            None => j,
        },
        Err(e) => {
            eprintln!("strand-feed: {e}");
            return ExitCode::from(2);
        }
    };
    for w in &job.warnings {
        eprintln!("strand-feed: note: {w}");
    }
    // SAFETY: the handler only increments an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_interrupt as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_interrupt as *const () as libc::sighandler_t);
    }
    if cli.no_check {
        eprintln!("strand-feed: WARNING: --no-check: the job was not checked against the robot (reach, joint limits, bed)");
    } else {
        match check(&job, &cli, &cfg) {
            Ok(None) => {}
            Ok(Some(report)) => {
                eprintln!("{report}");
                eprintln!("strand-feed: refused: the job check fails (stream it anyway with --no-check)");
                return ExitCode::from(3);
            }
            Err(e) => {
                eprintln!("strand-feed: {e}");
                return ExitCode::from(2);
            }
        }
    }
    if INTERRUPTS.load(Ordering::Relaxed) > 0 {
        eprintln!("strand-feed: interrupted before streaming: nothing was sent");
        return ExitCode::from(6);
    }
    let prefix = cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
    match stream(&job, &prefix, &cli) {
        Ok(ending) => {
            let text = match ending {
                Ending::Finished => "finished".to_string(),
                Ending::Stopped => "stopped".to_string(),
                Ending::Faulted { code, seq, line } => {
                    let code = ipc::FaultCode::from_u32(code).map_or(format!("fault {code}"), |c| format!("{c:?}"));
                    format!("FAULTED: {code} at segment {seq} ({}:{line})", cli.file.display())
                }
                Ending::Rejected { seq, reason } => {
                    let line = job.segments.iter().find(|s| s.seq == seq).map_or(0, |s| s.source_line);
                    format!("segment {seq} ({}:{line}) rejected: {:?}", cli.file.display(), ipc::RejectReason::from_u32(reason))
                }
            };
            eprintln!("strand-feed: job {text}");
            ExitCode::from(ending.exit_code())
        }
        Err(e) => {
            eprintln!("strand-feed: {e}");
            ExitCode::from(1)
        }
    }
}

/// The job check before streaming: None when the job is clean, else the report to show.
fn check(job: &Job, cli: &Cli, cfg: &Config) -> Result<Option<String>, String> {
    let started = Instant::now();
    let name = cli.file.display().to_string();
    let check_job = strand::check::CheckJob { file: &name, segments: &job.segments, layers: &job.layers };
    let report = strand::check::check_with_trajectory(&check_job, cfg, cli.base_trajectory.as_deref(), None).map_err(|e| e.to_string())?;
    if !report.clean {
        return Ok(Some(report.summary()));
    }
    eprintln!(
        "strand-feed: check-job: clean ({} segments, predicted {:.1} s, max TCP error {:.3} mm; checked in {:.1} s)",
        report.segments,
        report.time.total_s,
        report.max_tcp_error_m * 1e3,
        started.elapsed().as_secs_f64()
    );
    Ok(None)
}

fn stream(job: &Job, prefix: &str, cli: &Cli) -> Result<Ending, String> {
    let names = ServiceNames::new(prefix);
    let ports = ClientPorts::open(&names, "strand-feed", ClientRoles { feeder: true, monitor: true, ..Default::default() })
        .map_err(|e| e.to_string())?;
    // Wait for the service.
    let deadline = Instant::now() + Duration::from_secs_f64(cli.wait_service);
    let mut status = loop {
        if let Some(s) = ports.latest_status() {
            break s;
        }
        if Instant::now() >= deadline {
            return Err(format!("no Status from a service under {prefix} within {} s", cli.wait_service));
        }
        let _ = ports.wait_status(20_000_000);
    };
    if matches!(RunState::from_u32(status.run_state), Some(RunState::Fault)) {
        return Err(format!("the controller is in fault {:?}; clear it first", ipc::FaultCode::from_u32(status.fault)));
    }
    if status.job_outcome == JobOutcome::InProgress as u32 {
        return Err("the controller already has a job in progress".to_string());
    }
    let segments = &job.segments;
    let (first_seq, last_seq) = (segments[0].seq, segments[segments.len() - 1].seq);
    let total_length: f64 = job.lengths.iter().sum();
    let bar = progress_bar(segments.len() as u64, cli.quiet);
    let started_at = Instant::now();
    let mut sent = 0usize;
    let mut started = false;
    let mut job_seen = false;
    let mut batch_seq = 0u64;
    let mut control_seq = 0u64;
    let mut interrupts_handled = 0;
    let mut last_quiet_decile = 0;
    let mut silent_since: Option<Instant> = None;
    let send_control = |seq: &mut u64, command: Command| {
        *seq += 1;
        let c = ipc::Control { seq: *seq, stamp_ns: strand::io::clock::monotonic_ns(), command: command as u32, value: 0.0, _reserved: 0 };
        ports.send_control(&c)
    };
    loop {
        if let Some(s) = ports.latest_status() {
            status = s;
            silent_since = None;
        }
        // Ctrl-C: first a controlled stop, then an emergency stop.
        let interrupts = INTERRUPTS.load(Ordering::Relaxed);
        while interrupts_handled < interrupts {
            interrupts_handled += 1;
            let command = if interrupts_handled == 1 { Command::Stop } else { Command::EmergencyStop };
            bar.suspend(|| eprintln!("strand-feed: {command:?} sent"));
            send_control(&mut control_seq, command).map_err(|e| e.to_string())?;
        }
        // A rejection of one of ours ends the job: stop the rest.
        if started && status.last_rejected_seq >= first_seq && status.last_rejected_seq <= last_seq && status.rejected > 0 {
            if job_seen && status.job_outcome == JobOutcome::InProgress as u32 {
                let _ = send_control(&mut control_seq, Command::Stop);
            }
            bar.abandon();
            return Ok(Ending::Rejected { seq: status.last_rejected_seq, reason: status.last_reject_reason });
        }
        // Send what the credit allows, a batch at a time.
        if interrupts_handled == 0 {
            let allowed = credit(&status, first_seq, last_seq, started).min(segments.len() as u64) as usize;
            while sent < allowed {
                let n = (allowed - sent).min(SEGMENT_BATCH_CAPACITY);
                batch_seq += 1;
                if ports.send_segments(&batch(&segments[sent..sent + n], batch_seq)).map_err(|e| e.to_string())? == 0 {
                    break; // nobody subscribed yet: not delivered, so resend later
                }
                sent += n;
                if !started {
                    send_control(&mut control_seq, Command::Start).map_err(|e| e.to_string())?;
                    started = true;
                }
            }
        }
        // Progress.
        job_seen |= started && status.job_outcome == JobOutcome::InProgress as u32;
        let done = if job_seen && status.executing_seq >= first_seq { (status.executing_seq - first_seq) as usize } else { 0 };
        let done_length: f64 = job.lengths[..done.min(job.lengths.len())].iter().sum();
        let layer = job.layers.get(done).copied().flatten().map_or("-".to_string(), |l| l.to_string());
        let fraction = if total_length > 0.0 { done_length / total_length } else { 0.0 };
        bar.set_position(done as u64);
        bar.set_message(format!(
            "layer {layer} | sent {sent} | {:?}{}",
            RunState::from_u32(status.run_state).unwrap_or_default(),
            eta(started_at.elapsed(), fraction)
        ));
        if cli.quiet && (fraction * 10.0) as u32 > last_quiet_decile {
            last_quiet_decile = (fraction * 10.0) as u32;
            eprintln!("strand-feed: {} % (segment {}, layer {layer})", last_quiet_decile * 10, status.executing_seq);
        }
        // The end.
        if job_seen {
            let outcome = JobOutcome::from_u32(status.job_outcome);
            let state = RunState::from_u32(status.run_state);
            if matches!(state, Some(RunState::Idle | RunState::Fault)) {
                let ending = match outcome {
                    Some(JobOutcome::Finished) => Some(Ending::Finished),
                    Some(JobOutcome::Stopped) => Some(Ending::Stopped),
                    Some(JobOutcome::Faulted) => {
                        Some(Ending::Faulted { code: status.fault, seq: status.executing_seq, line: status.executing_line })
                    }
                    _ => None,
                };
                if let Some(e) = ending {
                    if e == Ending::Finished {
                        bar.finish();
                    } else {
                        bar.abandon();
                    }
                    return Ok(e);
                }
            }
        }
        // A service that went away.
        if ports.status_publishers() == 0 {
            let since = *silent_since.get_or_insert_with(Instant::now);
            if since.elapsed() > Duration::from_secs(1) {
                bar.abandon();
                return Err(format!("the service under {prefix} went away (last state {:?})", RunState::from_u32(status.run_state)));
            }
        }
        let _ = ports.wait_status(10_000_000);
    }
}

fn eta(elapsed: Duration, fraction: f64) -> String {
    if fraction <= 0.01 {
        return String::new();
    }
    let left = elapsed.as_secs_f64() * (1.0 - fraction) / fraction;
    format!(" | ETA {:.0} s", left)
}

fn progress_bar(len: u64, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} segments | {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}
