//! `strand ctl`: the operator's console. Sends one control command to a running service and waits
//! for the service to acknowledge it in `Status` — the state it asked for, the override it set, or
//! a refusal (the `rejected` count rises, with the reason) — so a script or a person learns at once
//! whether a pause, a stop or an override took. `status` prints the service's state once or, with
//! `--watch`, as a live line.
//!
//! It opens a control-only client (no segment publisher: a console never hides a lost feeder).

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use strand_ipc as ipc;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{Command, FaultCode, HeatHold, JobOutcome, JobProgress, RejectReason, RunState, ServiceNames, Status, heater_flags};

use crate::io::clock::monotonic_ns;

/// How long after sending a command its acknowledgement is looked for: longer than a tick at the
/// slowest rate (250 Hz) with margin for the robot clock's pace.
const SETTLE: Duration = Duration::from_millis(25);

/// What `strand ctl` does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CtlVerb {
    /// Print the status (once, or live).
    Status {
        /// Keep printing (a live line on a terminal) until interrupted.
        watch: bool,
        /// One JSON object per status instead of the text line.
        json: bool,
    },
    /// Pause the job (stops on the path within the jerk limits and retracts).
    Pause,
    /// Resume a paused job (primes, continues where it stopped).
    Resume,
    /// Stop the job (brakes on the path; the job ends Stopped).
    Stop,
    /// Emergency stop (latches a fault).
    EmergencyStop,
    /// Clear a latched fault.
    ClearFault,
    /// Feed override (percent, 1 to 200).
    Feed(f64),
    /// Flow override (percent, 0 to 200).
    Flow(f64),
}

/// Why a command did not take.
#[derive(Debug, thiserror::Error)]
pub enum CtlError {
    /// No service answers under the prefix.
    #[error("no strand service under prefix {prefix:?} (no status within {timeout_s} s): is `strand run` running with this prefix?")]
    NoService {
        /// The prefix.
        prefix: String,
        /// How long it waited (s).
        timeout_s: f64,
    },
    /// The service refused the command.
    #[error("refused by the service: {reason:?} ({why}); state {state:?}")]
    Refused {
        /// The service's reason.
        reason: RejectReason,
        /// What it means for this command.
        why: String,
        /// The state it was in.
        state: RunState,
    },
    /// No acknowledgement in time.
    #[error("not acknowledged within {timeout_s} s: the service is {state:?} (fault {fault:?})")]
    NotAcknowledged {
        /// How long it waited (s).
        timeout_s: f64,
        /// The state it stayed in.
        state: RunState,
        /// Its fault.
        fault: FaultCode,
    },
    /// The ports could not be opened or used.
    #[error("{0}")]
    Port(#[from] ipc::ports::PortError),
}

impl CtlVerb {
    /// The wire command and value (a fraction for the overrides); `None` for `status`.
    pub fn control(self) -> Option<(Command, f64)> {
        Some(match self {
            CtlVerb::Status { .. } => return None,
            CtlVerb::Pause => (Command::Pause, 0.0),
            CtlVerb::Resume => (Command::Resume, 0.0),
            CtlVerb::Stop => (Command::Stop, 0.0),
            CtlVerb::EmergencyStop => (Command::EmergencyStop, 0.0),
            CtlVerb::ClearFault => (Command::ClearFault, 0.0),
            CtlVerb::Feed(p) => (Command::FeedOverride, p / 100.0),
            CtlVerb::Flow(p) => (Command::FlowOverride, p / 100.0),
        })
    }

    /// True when `s` shows the command done (or under way: a pause is acknowledged by Pausing).
    fn acknowledged(self, s: &Status) -> bool {
        let state = RunState::from_u32(s.run_state);
        match self {
            CtlVerb::Status { .. } => true,
            CtlVerb::Pause => matches!(state, Some(RunState::Pausing | RunState::Paused)),
            CtlVerb::Resume => state == Some(RunState::Running),
            CtlVerb::Stop => matches!(state, Some(RunState::Stopping | RunState::Idle)),
            // Stopped in a fault: EmergencyStop, or the fault that was already latched.
            CtlVerb::EmergencyStop => matches!(state, Some(RunState::EmergencyStopping | RunState::Fault)),
            CtlVerb::ClearFault => s.fault == FaultCode::None as u32 && state != Some(RunState::Fault),
            CtlVerb::Feed(p) => (s.feed_override - p / 100.0).abs() < 1e-9,
            CtlVerb::Flow(p) => (s.flow_override - p / 100.0).abs() < 1e-9,
        }
    }

    fn why(self, reason: RejectReason) -> String {
        match (self, reason) {
            (CtlVerb::Feed(_), RejectReason::BadValue) => "the feed override must lie in 1 to 200 %".into(),
            (CtlVerb::Flow(_), RejectReason::BadValue) => "the flow override must lie in 0 to 200 %".into(),
            (CtlVerb::Pause, RejectReason::NotAllowed) => "only a running job can pause".into(),
            (CtlVerb::Resume, RejectReason::NotAllowed) => "only a paused job can resume".into(),
            (CtlVerb::Stop, RejectReason::NotAllowed) => "a fault or an emergency stop is in force: clear-fault first".into(),
            (CtlVerb::ClearFault, RejectReason::NotAllowed) => "there is no fault to clear".into(),
            (_, r) => format!("{r:?}"),
        }
    }
}

/// Connects to the service under `prefix`, sends the verb's command and waits up to `timeout` for
/// its acknowledgement; returns the status that showed it. `status` verbs only read.
pub fn run(prefix: &str, verb: CtlVerb, timeout: Duration) -> Result<Status, CtlError> {
    let names = ServiceNames::new(prefix);
    let roles = ClientRoles { monitor: true, control: verb.control().is_some(), ..ClientRoles::default() };
    let node = format!("strand_ctl_{}", std::process::id());
    let ports = ClientPorts::open(&names, &node, roles)?;
    let no_service = || CtlError::NoService { prefix: prefix.to_string(), timeout_s: timeout.as_secs_f64() };
    let before = wait_status(&ports, timeout)?.ok_or_else(no_service)?;
    let Some((command, value)) = verb.control() else { return Ok(before) };
    let control = ipc::Control { seq: monotonic_ns(), stamp_ns: monotonic_ns(), command: command as u32, _reserved: 0, value };
    if ports.send_control(&control)? == 0 {
        return Err(no_service());
    }
    let deadline = Instant::now() + timeout;
    // A status already on its way when the command went out would show the old state (and a
    // clear-fault with no fault would look done): judge only statuses that arrive SETTLE after
    // the send, when every tick since has seen the command (the queue is drained each time).
    let settle = Instant::now() + SETTLE;
    let mut last = before;
    while Instant::now() < deadline {
        let Some(s) = wait_status(&ports, deadline.saturating_duration_since(Instant::now()))? else { break };
        last = s;
        if Instant::now() < settle {
            continue;
        }
        if s.rejected > before.rejected {
            let reason = RejectReason::from_u32(s.last_reject_reason).unwrap_or(RejectReason::None);
            if matches!(reason, RejectReason::NotAllowed | RejectReason::BadValue | RejectReason::NotReady | RejectReason::UnknownKind) {
                let state = RunState::from_u32(s.run_state).unwrap_or(RunState::Idle);
                return Err(CtlError::Refused { reason, why: verb.why(reason), state });
            }
        }
        if verb.acknowledged(&s) {
            return Ok(s);
        }
    }
    Err(CtlError::NotAcknowledged {
        timeout_s: timeout.as_secs_f64(),
        state: RunState::from_u32(last.run_state).unwrap_or(RunState::Idle),
        fault: FaultCode::from_u32(last.fault).unwrap_or(FaultCode::None),
    })
}

/// The service's status and, while a job runs, the feeder's progress of it (waiting up to 1.2 s
/// for the feeder's next publication: it publishes about once a second).
pub fn status(prefix: &str, timeout: Duration) -> Result<(Status, Option<JobProgress>), CtlError> {
    let names = ServiceNames::new(prefix);
    let roles = ClientRoles { monitor: true, progress: true, ..ClientRoles::default() };
    let ports = ClientPorts::open(&names, &format!("strand_ctl_{}", std::process::id()), roles)?;
    let no_service = || CtlError::NoService { prefix: prefix.to_string(), timeout_s: timeout.as_secs_f64() };
    let mut s = wait_status(&ports, timeout)?.ok_or_else(no_service)?;
    let mut progress = None;
    if s.job_outcome == JobOutcome::InProgress as u32 {
        let deadline = Instant::now() + Duration::from_millis(1200);
        while progress.is_none() && Instant::now() < deadline {
            progress = ports.latest_job_progress();
            if let Some(newer) = wait_status(&ports, Duration::from_millis(50))? {
                s = newer;
            }
        }
    }
    Ok((s, progress.filter(fresh)))
}

/// A progress published in the last 3 s (a feeder that stopped publishing is not streaming).
fn fresh(p: &JobProgress) -> bool {
    monotonic_ns().saturating_sub(p.stamp_ns) < 3_000_000_000
}

/// Prints statuses until `stop` is set: one line a status at most 5 times a second (rewritten in
/// place on a terminal), or one JSON object per line.
pub fn watch(prefix: &str, json: bool, timeout: Duration, stop: &std::sync::atomic::AtomicBool) -> Result<(), CtlError> {
    let names = ServiceNames::new(prefix);
    let roles = ClientRoles { monitor: true, progress: true, ..ClientRoles::default() };
    let ports = ClientPorts::open(&names, &format!("strand_ctl_{}", std::process::id()), roles)?;
    // SAFETY: isatty on fd 1 only reads.
    let tty = unsafe { libc::isatty(1) } == 1;
    let mut progress: Option<JobProgress> = None;
    let mut last_print = Instant::now() - Duration::from_secs(1);
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        let Some(s) = wait_status(&ports, timeout)? else {
            return Err(CtlError::NoService { prefix: prefix.to_string(), timeout_s: timeout.as_secs_f64() });
        };
        if let Some(p) = ports.latest_job_progress() {
            progress = Some(p);
        }
        if last_print.elapsed() < Duration::from_millis(200) {
            continue;
        }
        last_print = Instant::now();
        let p = progress.as_ref().filter(|p| fresh(p) && s.job_outcome == JobOutcome::InProgress as u32);
        if json {
            println!("{}", status_json(&s, p));
        } else if tty {
            print!("\r\x1b[2K{}", status_line(&s, p));
            let _ = std::io::Write::flush(&mut std::io::stdout());
        } else {
            println!("{}", status_line(&s, p));
        }
    }
    if tty && !json {
        println!();
    }
    Ok(())
}

/// The newest status within `timeout` (`None`: none came).
fn wait_status(ports: &ClientPorts, timeout: Duration) -> Result<Option<Status>, CtlError> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(s) = ports.latest_status() {
            return Ok(Some(s));
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(None);
        }
        ports.wait_status(left.min(Duration::from_millis(50)).as_nanos() as u64)?;
    }
}

/// The status as one line: state, job (with the feeder's progress: name, percent, the program's
/// layer, ETA), layer, line, path, queue, overrides, faults.
pub fn status_line(s: &Status, progress: Option<&JobProgress>) -> String {
    let mut out = String::new();
    let state = RunState::from_u32(s.run_state).map_or(format!("state {}", s.run_state), |r| format!("{r:?}"));
    let job = JobOutcome::from_u32(s.job_outcome).map_or(format!("{}", s.job_outcome), |j| format!("{j:?}"));
    let _ = write!(out, "{state} · job {job}");
    if let Some(p) = progress {
        let _ = write!(out, " {} {:.1} %", p.name(), p.fraction * 100.0);
        if p.layer >= 0 {
            let _ = write!(out, " · layer {} of {}", p.layer, p.last_layer);
        }
        if p.eta_s >= 0.0 {
            let eta = p.eta_s.round() as u64;
            let _ = write!(out, " · ETA {}:{:02}:{:02}", eta / 3600, eta / 60 % 60, eta % 60);
        }
    }
    if s.executing_seq > 0 {
        if progress.is_none_or(|p| p.layer < 0) {
            let _ = write!(out, " · layer {}", s.executing_layer);
        }
        let _ = write!(
            out,
            " · line {} · segment {} · {:.3} m at {:.1} mm/s",
            s.executing_line,
            s.executing_seq,
            s.path_position,
            s.path_speed * 1e3
        );
    }
    let used = s.queue_capacity.saturating_sub(s.queue_free);
    let _ =
        write!(out, " · queue {used}/{} · feed {:.0} % flow {:.0} %", s.queue_capacity, s.feed_override * 100.0, s.flow_override * 100.0);
    let _ = write!(out, " · TCP error {:.3} mm", s.tcp_error * 1e3);
    if let Some(heat) = heat_text(s) {
        let _ = write!(out, " · {heat}");
    }
    if s.fault != 0 {
        let _ = write!(out, " · FAULT {:?}", FaultCode::from_u32(s.fault).unwrap_or(FaultCode::None));
    }
    if s.rejected > 0 {
        let reason = RejectReason::from_u32(s.last_reject_reason).unwrap_or(RejectReason::None);
        let _ = write!(out, " · {} rejected (last {reason:?})", s.rejected);
    }
    if s.underruns > 0 || s.overruns > 0 {
        let _ = write!(out, " · underruns {} overruns {}", s.underruns, s.overruns);
    }
    out
}

/// The temperatures as text (°C), for the status line and strand-feed's progress: during a heat
/// wait what it waits for (`HEATING hot end 187.3 °C → 207–213 °C` while outside the band,
/// `… settling 1.2 s` inside it); otherwise each heater with a target or a measurement as
/// measured/target (`hot end 210.1/210 °C · bed 60.0/60 °C`; `--` where nothing is measured).
/// None when there is nothing to say (no target, no measurement).
pub fn heat_text(s: &Status) -> Option<String> {
    let measured = |bit: u32, t: f64| if s.heater_flags & bit != 0 { format!("{t:.1}") } else { "--".to_string() };
    let hot_end = measured(heater_flags::HOT_END, s.hot_end_temperature);
    let bed = measured(heater_flags::BED, s.bed_temperature);
    let [low, high] = s.heat_hold_band;
    let band = if high >= 10_000.0 { format!(">= {low:.0} °C") } else { format!("{low:.0}-{high:.0} °C") };
    let hold = |name: &str, t: &str, v: f64| {
        let inside = v >= low && v <= high && t != "--";
        let settle = s.heat_hold_left;
        if inside {
            format!("HEATING {name} {t} °C in {band}, settling {settle:.1} s")
        } else {
            format!("HEATING {name} {t} °C -> {band}")
        }
    };
    match HeatHold::from_u32(s.heat_hold) {
        Some(HeatHold::HotEnd) => return Some(hold("hot end", &hot_end, s.hot_end_temperature)),
        Some(HeatHold::Bed) => return Some(hold("bed", &bed, s.bed_temperature)),
        _ => {}
    }
    let mut parts = Vec::new();
    if s.hot_end_target > 0.0 || s.heater_flags & heater_flags::HOT_END != 0 {
        parts.push(format!("hot end {hot_end}/{:.0} °C", s.hot_end_target));
    }
    if s.bed_target > 0.0 || s.heater_flags & heater_flags::BED != 0 {
        parts.push(format!("bed {bed}/{:.0} °C", s.bed_target));
    }
    (!parts.is_empty()).then(|| parts.join(" · "))
}

/// The status as a JSON object (names for the enums), with the feeder's progress under `job` when
/// a job runs.
pub fn status_json(s: &Status, progress: Option<&JobProgress>) -> serde_json::Value {
    let name = |v: Option<String>| v.unwrap_or_default();
    let job = progress.map(|p| {
        serde_json::json!({
            "name": p.name(),
            "fraction": p.fraction,
            "layer": p.layer,
            "last_layer": p.last_layer,
            "elapsed_s": p.elapsed_s,
            "eta_s": if p.eta_s >= 0.0 { serde_json::json!(p.eta_s) } else { serde_json::Value::Null },
            "segments_sent": p.segments_sent,
            "first_seq": p.first_seq,
            "last_seq": p.last_seq,
        })
    });
    serde_json::json!({
        "job": job,
        "run_state": name(RunState::from_u32(s.run_state).map(|r| format!("{r:?}"))),
        "fault": name(FaultCode::from_u32(s.fault).map(|r| format!("{r:?}"))),
        "job_outcome": name(JobOutcome::from_u32(s.job_outcome).map(|r| format!("{r:?}"))),
        "last_reject_reason": name(RejectReason::from_u32(s.last_reject_reason).map(|r| format!("{r:?}"))),
        "tick": s.tick,
        "executing_seq": s.executing_seq,
        "executing_line": s.executing_line,
        "executing_layer": s.executing_layer,
        "segments_accepted": s.segments_accepted,
        "rejected": s.rejected,
        "queue_capacity": s.queue_capacity,
        "queue_free": s.queue_free,
        "feed_override": s.feed_override,
        "flow_override": s.flow_override,
        "path_position_m": s.path_position,
        "path_speed_m_s": s.path_speed,
        "tcp_error_m": s.tcp_error,
        "underruns": s.underruns,
        "overruns": s.overruns,
        "heaters": heat_json(s),
    })
}

/// The temperatures as JSON (°C): whether the service acts on them, each heater's measurement
/// (null when none is fresh) and target, and the hold with its band and settle time left.
fn heat_json(s: &Status) -> serde_json::Value {
    let measured = |bit: u32, t: f64| if s.heater_flags & bit != 0 { serde_json::json!(t) } else { serde_json::Value::Null };
    let hold = match HeatHold::from_u32(s.heat_hold) {
        Some(h) if h != HeatHold::None => serde_json::json!({
            "heater": format!("{h:?}"),
            "band_c": s.heat_hold_band,
            "settle_left_s": s.heat_hold_left,
        }),
        _ => serde_json::Value::Null,
    };
    serde_json::json!({
        "acting": s.heater_flags & heater_flags::ACTING != 0,
        "hot_end": { "measured_c": measured(heater_flags::HOT_END, s.hot_end_temperature), "target_c": s.hot_end_target },
        "bed": { "measured_c": measured(heater_flags::BED, s.bed_temperature), "target_c": s.bed_target },
        "hold": hold,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The temperatures in the status line and the JSON: a hold says what it waits for, with the
    /// settle time left once in band; otherwise measured/target per heater; nothing without either.
    #[test]
    fn temperatures_are_shown() {
        let mut s =
            Status { heater_flags: heater_flags::ACTING | heater_flags::HOT_END, hot_end_temperature: 187.34, ..Default::default() };
        s.hot_end_target = 210.0;
        s.heat_hold = HeatHold::HotEnd as u32;
        s.heat_hold_band = [207.0, 213.0];
        s.heat_hold_left = 2.0;
        assert_eq!(heat_text(&s).unwrap(), "HEATING hot end 187.3 °C -> 207-213 °C");
        s.hot_end_temperature = 209.0;
        s.heat_hold_left = 1.25;
        assert_eq!(heat_text(&s).unwrap(), "HEATING hot end 209.0 °C in 207-213 °C, settling 1.2 s");
        assert!(status_line(&s, None).contains("HEATING hot end 209.0 °C"));
        s.heat_hold = 0;
        s.bed_target = 60.0;
        assert_eq!(heat_text(&s).unwrap(), "hot end 209.0/210 °C · bed --/60 °C");
        let j = status_json(&s, None);
        assert_eq!(j["heaters"]["hot_end"]["measured_c"], 209.0);
        assert_eq!(j["heaters"]["bed"]["measured_c"], serde_json::Value::Null);
        assert_eq!(j["heaters"]["bed"]["target_c"], 60.0);
        assert_eq!(j["heaters"]["acting"], true);
        assert_eq!(j["heaters"]["hold"], serde_json::Value::Null);
        assert_eq!(heat_text(&Status::default()), None);
    }
}
