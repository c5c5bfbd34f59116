//! Streaming a job to the service: never past the credit the controller announces in Status, so
//! nothing is ever dropped; a progress bar (segments, layer, ETA) or a line per 10 %; the caller's
//! Ctrl-C count turned into a controlled stop, then an emergency stop; and the job's end read from
//! Status, as an [`Ending`].

use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use strand::check::CheckReport;
use strand::config::Config;
use strand_ipc as ipc;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{Command, JobOutcome, RunState, SEGMENT_BATCH_CAPACITY, ServiceNames};

use super::{Ending, Job, Key, Keys, batch, credit};
use strand_cli::error::{Result, ToolError};

/// Where and how to stream.
#[derive(Clone, Debug)]
pub struct StreamOptions {
    /// The service prefix.
    pub prefix: String,
    /// How long to wait for the service's first Status (s).
    pub wait_service: f64,
    /// No progress bar: one line per 10 % on stderr instead.
    pub quiet: bool,
    /// The job's name in the progress it publishes for consoles (`strand ctl status`).
    pub name: String,
}

/// The job check before streaming (`strand check-job`'s, with the base trajectory of a tracked
/// base): the report (`clean` says whether the job may stream); an error for a job the check
/// cannot run.
pub fn check(job: &Job, file: &Path, base_trajectory: Option<&Path>, cfg: &Config) -> Result<CheckReport> {
    let name = file.display().to_string();
    let check_job = strand::check::CheckJob { file: &name, segments: &job.segments, layers: &job.layers };
    Ok(strand::check::check_with_trajectory(&check_job, cfg, base_trajectory, None)?)
}

/// Streams `job` to the service under `opts.prefix` within the credit its Status announces, until
/// the job ends (how: the [`Ending`]). Each increment of `interrupts` (the caller's Ctrl-C count)
/// sends a controlled stop, the second an emergency stop. An error: no service, a service in
/// fault or with a job in progress, a service that went away, a port that failed.
///
/// With `keys`, `p` pauses and resumes, `+` / `-` step the feed override by 10 points and `s`
/// stops; the progress line shows the override and the state.
pub fn stream(job: &Job, opts: &StreamOptions, interrupts: &AtomicU32, keys: Option<&Keys>) -> Result<Ending> {
    let prefix = opts.prefix.as_str();
    let names = ServiceNames::new(prefix);
    let ports = ClientPorts::open(&names, "strand-feed", ClientRoles { feeder: true, monitor: true, ..Default::default() })?;
    // Wait for the service.
    let deadline = Instant::now() + Duration::from_secs_f64(opts.wait_service);
    let mut status = loop {
        if let Some(s) = ports.latest_status() {
            break s;
        }
        if Instant::now() >= deadline {
            return Err(ToolError::Measurement(format!("no Status from a service under {prefix} within {} s", opts.wait_service)));
        }
        let _ = ports.wait_status(20_000_000);
    };
    if matches!(RunState::from_u32(status.run_state), Some(RunState::Fault)) {
        return Err(ToolError::Measurement(format!(
            "the controller is in fault {:?}; clear it first",
            ipc::FaultCode::from_u32(status.fault)
        )));
    }
    if status.job_outcome == JobOutcome::InProgress as u32 {
        return Err(ToolError::Measurement("the controller already has a job in progress".to_string()));
    }
    let segments = &job.segments;
    let (first_seq, last_seq) = (segments[0].seq, segments[segments.len() - 1].seq);
    let total_length: f64 = job.lengths.iter().sum();
    let bar = progress_bar(segments.len() as u64, opts.quiet);
    let started_at = Instant::now();
    let mut sent = 0usize;
    let mut started = false;
    let mut job_seen = false;
    let mut batch_seq = 0u64;
    let mut control_seq = 0u64;
    let mut interrupts_handled = 0;
    let mut last_quiet_decile = 0;
    // A heat wait said once in quiet mode (again at the next wait).
    let mut heat_said = false;
    let mut silent_since: Option<Instant> = None;
    let mut progress = ipc::JobProgress {
        first_seq,
        last_seq,
        last_layer: job.layers.iter().flatten().max().copied().unwrap_or(-1),
        ..Default::default()
    };
    progress.set_name(&opts.name);
    let mut progress_sent: Option<Instant> = None;
    let mut stop_sent_at: Option<Instant> = None;
    let mut start_sent_at: Option<Instant> = None;
    let mut start_refusal_said = false;
    // The service's tick count and when it last moved: a service that stops ticking (hung, or
    // stopped by a signal) keeps its Status publisher, so "went away" below never fires for it.
    let mut last_tick = (status.tick, Instant::now());
    let send_control_value = |seq: &mut u64, command: Command, value: f64| {
        *seq += 1;
        let c = ipc::Control { seq: *seq, stamp_ns: strand::io::clock::monotonic_ns(), command: command as u32, value, _reserved: 0 };
        ports.send_control(&c)
    };
    let send_control = |seq: &mut u64, command: Command| send_control_value(seq, command, 0.0);
    loop {
        if let Some(s) = ports.latest_status() {
            status = s;
            silent_since = None;
        }
        // Ctrl-C: first a controlled stop, then an emergency stop.
        let pending = interrupts.load(Ordering::Relaxed);
        while interrupts_handled < pending {
            interrupts_handled += 1;
            let command = if interrupts_handled == 1 { Command::Stop } else { Command::EmergencyStop };
            bar.suspend(|| eprintln!("strand-feed: {command:?} sent"));
            send_control(&mut control_seq, command)?;
            stop_sent_at.get_or_insert_with(Instant::now);
        }
        // Stopped before anything was sent: nothing started, nothing to wait for.
        if interrupts_handled > 0 && !started {
            bar.abandon();
            return Ok(Ending::Stopped);
        }
        // Keys: pause/resume, feed override, stop.
        while let Some(key) = keys.and_then(Keys::next) {
            let state = RunState::from_u32(status.run_state);
            let (command, value) = match key {
                Key::PauseResume if matches!(state, Some(RunState::Pausing | RunState::Paused)) => (Command::Resume, 0.0),
                Key::PauseResume => (Command::Pause, 0.0),
                Key::Faster => (Command::FeedOverride, ((status.feed_override * 10.0).round() + 1.0).min(20.0) / 10.0),
                Key::Slower => (Command::FeedOverride, ((status.feed_override * 10.0).round() - 1.0).max(1.0) / 10.0),
                Key::Stop => {
                    // As a first Ctrl-C (sent at the top of the loop); a Ctrl-C after it escalates.
                    interrupts.fetch_max(1, Ordering::Relaxed);
                    continue;
                }
            };
            bar.suspend(|| {
                eprintln!("strand-feed: {command:?}{} sent", if value > 0.0 { format!(" {:.0} %", value * 100.0) } else { String::new() })
            });
            send_control_value(&mut control_seq, command, value)?;
        }
        // A rejection of one of ours ends the job: stop the rest. After a stop of ours, refusals
        // of what was still in flight are expected (`Stale`, `NotReady`): the stop decides.
        if started
            && stop_sent_at.is_none()
            && status.last_rejected_seq >= first_seq
            && status.last_rejected_seq <= last_seq
            && status.rejected > 0
        {
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
                if ports.send_segments(&batch(&segments[sent..sent + n], batch_seq))? == 0 {
                    break; // nobody subscribed yet: not delivered, so resend later
                }
                sent += n;
                if !started {
                    if job.progress_offset > 0.0 {
                        send_control_value(&mut control_seq, Command::ProgressOffset, job.progress_offset)?;
                    }
                    send_control(&mut control_seq, Command::Start)?;
                    started = true;
                    start_sent_at = Some(Instant::now());
                }
            }
        }
        // Progress.
        job_seen |= started && status.job_outcome == JobOutcome::InProgress as u32;
        // Our job open and the controller idle: our Start was refused (NotReady: the controller
        // does not know where the robot is yet, its driver not streaming). Nothing else will start
        // it; ask again every half second until the job starts (a Start it does not need is
        // refused as NotAllowed, which ends nothing).
        if job_seen
            && stop_sent_at.is_none()
            && status.job_outcome == JobOutcome::InProgress as u32
            && RunState::from_u32(status.run_state) == Some(RunState::Idle)
            && start_sent_at.is_some_and(|t| t.elapsed() >= Duration::from_millis(500))
        {
            if !start_refusal_said {
                start_refusal_said = true;
                bar.suspend(|| {
                    eprintln!(
                        "strand-feed: the controller has not started the job ({:?}); is the robot streaming? asking again",
                        ipc::RejectReason::from_u32(status.last_reject_reason).unwrap_or_default()
                    )
                });
            }
            if job.progress_offset > 0.0 {
                send_control_value(&mut control_seq, Command::ProgressOffset, job.progress_offset)?;
            }
            send_control(&mut control_seq, Command::Start)?;
            start_sent_at = Some(Instant::now());
        }
        let done = if job_seen && status.executing_seq >= first_seq { (status.executing_seq - first_seq) as usize } else { 0 };
        let done_length: f64 = job.lengths[..done.min(job.lengths.len())].iter().sum();
        let layer = job.layers.get(done).copied().flatten().map_or("-".to_string(), |l| l.to_string());
        let fraction = if total_length > 0.0 { done_length / total_length } else { 0.0 };
        bar.set_position(done as u64);
        // The temperatures (strand ctl's words): a heat wait says what it waits for.
        let heat = strand::ctl::heat_text(&status).map_or(String::new(), |h| format!(" | {h}"));
        bar.set_message(format!(
            "layer {layer} | sent {sent} | {:?} | feed {:.0} %{heat}{}{}",
            RunState::from_u32(status.run_state).unwrap_or_default(),
            status.feed_override * 100.0,
            eta(started_at.elapsed(), fraction),
            if keys.is_some() { " | p pause/resume, +/- feed, s stop" } else { "" }
        ));
        // For consoles: about once a second.
        if progress_sent.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
            progress_sent = Some(Instant::now());
            progress.seq += 1;
            progress.stamp_ns = strand::io::clock::monotonic_ns();
            progress.segments_sent = sent as u64;
            progress.layer = job.layers.get(done).copied().flatten().unwrap_or(-1);
            progress.fraction = fraction;
            progress.elapsed_s = started_at.elapsed().as_secs_f64();
            progress.eta_s = eta_s(started_at.elapsed(), fraction).unwrap_or(-1.0);
            // For consoles only: a failed publish must not end the print.
            let _ = ports.send_job_progress(&progress);
        }
        if opts.quiet && status.heat_hold != 0 && !heat_said {
            heat_said = true;
            eprintln!("strand-feed: {}", strand::ctl::heat_text(&status).unwrap_or_default());
        }
        heat_said &= status.heat_hold != 0;
        if opts.quiet && (fraction * 10.0) as u32 > last_quiet_decile {
            last_quiet_decile = (fraction * 10.0) as u32;
            eprintln!("strand-feed: {} % (segment {}, layer {layer})", last_quiet_decile * 10, status.executing_seq);
        }
        // The end. After a stop of ours the job may have started and ended between two of our
        // looks at Status (a stop right after the start): once the service stands idle (or in
        // fault) half a second after our stop went out, the job is over — controls are taken in
        // order, so our start came before it. Whatever Status says of the job then: the
        // controller refuses what we sent before the stop (`Stale`), so a job in progress in Idle
        // is not ours to wait for; should one show, our stop drops its queue.
        let settled_after_stop = stop_sent_at.is_some_and(|t| t.elapsed() > Duration::from_millis(500));
        if settled_after_stop && matches!(RunState::from_u32(status.run_state), Some(RunState::Idle | RunState::Fault)) {
            let outcome = JobOutcome::from_u32(status.job_outcome);
            if outcome == Some(JobOutcome::InProgress) && status.fault == 0 {
                let _ = send_control(&mut control_seq, Command::Stop);
            }
            bar.abandon();
            return Ok(if status.fault != 0 {
                Ending::Faulted { code: status.fault, seq: status.executing_seq, line: status.executing_line }
            } else if job_seen && outcome == Some(JobOutcome::Finished) {
                Ending::Finished
            } else {
                Ending::Stopped
            });
        }
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
        // A service that stopped ticking: every job ends, so the feeder does too, saying why.
        if status.tick != last_tick.0 {
            last_tick = (status.tick, Instant::now());
        } else if last_tick.1.elapsed() > SERVICE_STALL {
            bar.abandon();
            return Err(ToolError::Measurement(format!(
                "the service under {prefix} stopped ticking: no new Status for {} s (tick {}, state {:?}, job {:?})",
                SERVICE_STALL.as_secs(),
                status.tick,
                RunState::from_u32(status.run_state),
                JobOutcome::from_u32(status.job_outcome)
            )));
        }
        // A service that went away.
        if ports.status_publishers() == 0 {
            let since = *silent_since.get_or_insert_with(Instant::now);
            if since.elapsed() > Duration::from_secs(1) {
                bar.abandon();
                return Err(ToolError::Measurement(format!(
                    "the service under {prefix} went away (last state {:?})",
                    RunState::from_u32(status.run_state)
                )));
            }
        }
        let _ = ports.wait_status(10_000_000);
    }
}

/// How long the service's Status tick may stand still before the feeder gives up on it (s). A running
/// service publishes Status every tick, and ticks without a robot too (the robot clock falls back on
/// its joint-state timeout), so 5 s of one tick is a service that no longer runs.
const SERVICE_STALL: Duration = Duration::from_secs(5);

fn eta(elapsed: Duration, fraction: f64) -> String {
    eta_s(elapsed, fraction).map_or(String::new(), |left| format!(" | ETA {left:.0} s"))
}

/// Time left (s) at the pace so far; `None` before 1 % is done.
fn eta_s(elapsed: Duration, fraction: f64) -> Option<f64> {
    (fraction > 0.01).then(|| elapsed.as_secs_f64() * (1.0 - fraction) / fraction)
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
