//! The cycle runner: waits for each tick (timer, robot or free-run clock), drains the iceoryx2
//! subscribers into a `TickInput`, calls `Controller::step`, publishes the commands and Status, and
//! hands the tick's record to a [`TickSink`] (the MCAP logger's seam).
//!
//! Nothing in the cycle allocates, locks or logs — the iceoryx2 ports included (`tests/alloc.rs`
//! counts whole runner ticks); the events a tick returns are logged through `tracing` after
//! publishing. Forgetting crashed peers, which lists iceoryx2's nodes, is a housekeeping thread's.

use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};
use strand_ipc as ipc;
use strand_ipc::{JobOutcome, RunState, ServiceNames};

use super::clock::{ClockMode, CycleStats, TimerClock, monotonic_ns};
use super::histogram::Histogram;
use super::rt::{self, RealtimeConfig};
use strand_core::InvalidSetting;
use strand_core::{Controller, Event, TickInput, TickOutput};
use strand_ipc::ports::{PortError, ServicePorts};

/// Where the controller learns the joint positions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum JointFeedback {
    /// From the robot driver's JointState (the real thing).
    #[default]
    Driver,
    /// The last command is taken as the state (a robot that follows exactly): for CI, dry runs and
    /// clients tested without a driver. The first state is `initial_joints`.
    Echo,
}

/// `[service]`: how the service meets the outside world.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    /// Prefix of every service name, e.g. `strand/cell`.
    pub prefix: String,
    /// What starts a tick.
    pub clock: ClockMode,
    /// Busy-wait before each timer deadline (s), 0 to 0.0005.
    pub spin: f64,
    /// A wake-up later than this (s) counts as late.
    pub late_threshold: f64,
    /// Joint positions from the driver, or echoed commands.
    pub joint_feedback: JointFeedback,
    /// Joint positions (rad or m) the echo starts from; empty: the middle of each range.
    pub initial_joints: Vec<f64>,
    /// Longest time (s) between two wake-ups of the status event's waiters. Status is published every
    /// tick, but waking a waiting process is the costly part of a publish (µs: the kernel switches to
    /// it, or interrupts another CPU), so waiters are woken at once only when the run state, the job's
    /// outcome, the fault, an override or the layer changes, and otherwise at this period. 0: every tick.
    pub status_notify_period: f64,
    /// Most segments taken into the path queue per second (segments/s), spread evenly over the
    /// ticks: at least one a tick, at most `rate / tick rate` rounded up. Taking a segment in
    /// (blending, the backward pass) costs microseconds, so a feeder's 64-segment batch taken in one
    /// tick would overrun a 125 µs tick; the rest of a batch waits in the shell for the next ticks.
    /// 8,000/s is more than any G-code stream needs (300 mm/s in 0.05 mm segments is 6,000/s).
    pub segment_intake_rate: f64,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        ServiceConfig {
            prefix: ipc::DEFAULT_PREFIX.to_string(),
            clock: ClockMode::Timer,
            spin: 0.0,
            late_threshold: 50e-6,
            joint_feedback: JointFeedback::Driver,
            initial_joints: Vec::new(),
            status_notify_period: 0.01,
            segment_intake_rate: 8000.0,
        }
    }
}

impl ServiceConfig {
    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if self.prefix.is_empty() || self.prefix.len() > 200 || self.prefix.contains(char::is_whitespace) {
            return Err(InvalidSetting::new(
                "service",
                format!("[service] prefix = {:?}: must be 1 to 200 characters without spaces", self.prefix),
            ));
        }
        if !(self.spin.is_finite() && (0.0..=0.0005).contains(&self.spin)) {
            return Err(InvalidSetting::new("service", format!("[service] spin = {}: must lie in [0, 0.0005] s", self.spin)));
        }
        if !(self.late_threshold.is_finite() && self.late_threshold > 0.0 && self.late_threshold <= 1.0) {
            return Err(InvalidSetting::new(
                "service",
                format!("[service] late_threshold = {}: must lie in (0, 1] s", self.late_threshold),
            ));
        }
        if !(self.status_notify_period.is_finite() && (0.0..=1.0).contains(&self.status_notify_period)) {
            return Err(InvalidSetting::new(
                "service",
                format!("[service] status_notify_period = {}: must lie in [0, 1] s", self.status_notify_period),
            ));
        }
        if !(self.segment_intake_rate.is_finite() && self.segment_intake_rate >= 1.0) {
            return Err(InvalidSetting::new(
                "service",
                format!("[service] segment_intake_rate = {}: must be at least 1 segment/s", self.segment_intake_rate),
            ));
        }
        if self.initial_joints.iter().any(|v| !v.is_finite()) {
            return Err(InvalidSetting::new("service", "[service] initial_joints: values must be finite".to_string()));
        }
        Ok(())
    }
}

/// How long a tick took, measured by the shell (not an input: it changes nothing the controller
/// does, so replay ignores it; plots and `info` use it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickTiming {
    /// Wake-up lateness against the timer deadline (ns; 0 in robot and free-run clock modes).
    pub wake_lateness_ns: u64,
    /// Cost of `Controller::step` (ns).
    pub step_ns: u64,
    /// Wake-up to last publish (ns).
    pub tick_ns: u64,
    /// Wake-up to every input drained: the receives (ns).
    pub receive_ns: u64,
    /// Wake-up to the joint command published, its event's notify included (ns; 0: no command).
    /// On the robot clock a driver that outranks the service runs inside that notify.
    pub command_ns: u64,
}

/// Receives every tick's input and output after publishing (the logger). Must not block,
/// allocate or lock.
pub trait TickSink {
    /// One tick and what it cost.
    fn record(&mut self, input: &TickInput, output: &TickOutput, timing: &TickTiming);
    /// Records the sink could not take so far (reported in Status).
    fn drops(&self) -> u64 {
        0
    }
    /// [`ipc::LogState`] as u32 (reported in Status).
    fn log_state(&self) -> u32 {
        ipc::LogState::Off as u32
    }
    /// Waits until the next record would be taken. Only the free-run clock calls this: there the
    /// ticks are not paced by time, so a complete log matters more than a tick's wall-clock time.
    fn wait_for_room(&self) {}
}

/// A sink that keeps nothing.
pub struct NullSink;

impl TickSink for NullSink {
    fn record(&mut self, _: &TickInput, _: &TickOutput, _: &TickTiming) {}
}

/// When the runner returns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StopWhen {
    /// After this many ticks.
    pub max_ticks: Option<u64>,
    /// When a job has ended (finished, stopped or faulted) and the controller is at rest.
    pub job_done: bool,
}

/// What a run measured.
pub struct RunSummary {
    /// Ticks run.
    pub ticks: u64,
    /// Timing counters.
    pub cycle: CycleStats,
    /// Wake-up lateness per tick (ns; timer mode).
    pub lateness: Histogram,
    /// Controller step cost per tick (ns).
    pub step_cost: Histogram,
    /// Wake-up to last publish per tick (ns).
    pub tick_cost: Histogram,
    /// The last Status.
    pub status: ipc::Status,
    /// What the real-time set-up did.
    pub realtime: rt::RealtimeReport,
}

/// Why the runner could not run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Opening or using a port failed.
    #[error("{0}")]
    Port(#[from] PortError),
}

/// The cycle runner. See the module documentation.
pub struct Runner {
    ports: ServicePorts,
    controller: Controller,
    service: ServiceConfig,
    dt_ns: u64,
    joint_state_timeout_ns: u64,
    /// Segments of a batch that did not fit in the last tick.
    carry: Option<(ipc::SegmentBatch, usize)>,
    /// Most segments taken in per tick (count; from `segment_intake_rate`).
    segments_per_tick: usize,
    echo_state: ipc::JointState,
    /// Robot clock: wait for a log slot rather than drop (`[log] wait_when_full`).
    log_waits: bool,
}

impl Runner {
    /// Opens the ports under the configured prefix. `node_name` names this process to iceoryx2.
    pub fn new(controller: Controller, service: &ServiceConfig, joint_state_timeout: f64, rate_hz: f64) -> Result<Self, RunError> {
        let _ = strand_ipc::ports::cleanup_dead_nodes();
        let ports = ServicePorts::open(&ServiceNames::new(&service.prefix), "strand")?;
        // The arm's joints, then a positioner's axes (at home, 0, unless `initial_joints` says).
        let n = controller.cell_dof();
        let mut echo_state = ipc::JointState { dof: n as u32, ..Default::default() };
        let middle = controller.model().middle_configuration();
        let arm = controller.model().dof();
        for i in 0..n {
            echo_state.position[i] = service.initial_joints.get(i).copied().unwrap_or(if i < arm { middle[i] } else { 0.0 });
        }
        Ok(Runner {
            ports,
            controller,
            service: service.clone(),
            dt_ns: (1e9 / rate_hz).round() as u64,
            joint_state_timeout_ns: (joint_state_timeout * 1e9) as u64,
            carry: None,
            segments_per_tick: segments_per_tick(service.segment_intake_rate, rate_hz),
            echo_state,
            log_waits: false,
        })
    }

    /// With the robot clock, wait for a free log slot instead of dropping a record
    /// (`[log] wait_when_full`: for simulators running faster than real time).
    pub fn set_log_waits(&mut self, wait: bool) {
        self.log_waits = wait;
    }

    /// The controller (for its model and counters).
    pub fn controller(&self) -> &Controller {
        &self.controller
    }

    /// Runs ticks until `stop` is set or `when` says so. Real-time settings are applied to the
    /// calling thread first (refusals are logged as one-line warnings and the run goes on).
    pub fn run(
        &mut self,
        realtime: &RealtimeConfig,
        stop: &AtomicBool,
        when: StopWhen,
        sink: &mut dyn TickSink,
    ) -> Result<RunSummary, RunError> {
        // The housekeeper is started before the real-time set-up, so it keeps the default policy
        // and affinity rather than inheriting the cycle thread's.
        let done = AtomicBool::new(false);
        std::thread::scope(|scope| {
            let housekeeper =
                std::thread::Builder::new().name("strand-housekeeper".into()).spawn_scoped(scope, || forget_dead_peers(&done)).ok();
            if housekeeper.is_none() {
                tracing::warn!("no housekeeping thread: a crashed peer counts as present until restart");
            }
            let result = self.cycle(realtime, stop, when, sink);
            done.store(true, Ordering::Relaxed);
            if let Some(h) = &housekeeper {
                h.thread().unpark();
            }
            result
        })
    }

    /// The cycle itself, on the calling thread (see [`Runner::run`]).
    fn cycle(
        &mut self,
        realtime: &RealtimeConfig,
        stop: &AtomicBool,
        when: StopWhen,
        sink: &mut dyn TickSink,
    ) -> Result<RunSummary, RunError> {
        let report = rt::apply(realtime);
        for w in report.warnings() {
            tracing::warn!("real-time: {w}");
        }
        tracing::info!("real-time: {report}");
        let mut input = TickInput::new(0, 0);
        let mut summary = RunSummary {
            ticks: 0,
            cycle: CycleStats::default(),
            lateness: Histogram::new(),
            step_cost: Histogram::new(),
            tick_cost: Histogram::new(),
            status: ipc::Status::default(),
            realtime: report,
        };
        let late_ns = (self.service.late_threshold * 1e9) as u64;
        let mut timer = TimerClock::new(self.dt_ns, (self.service.spin * 1e9) as u64, late_ns);
        let t0 = monotonic_ns();
        timer.start(t0);
        let mut job_seen = false;
        let mut tick: u64 = 0;
        let mut robot_time = RobotTime::default();
        let mut status_event = StatusEvent::new(self.service.status_notify_period);
        // The first tick's inputs that are not on its critical path (see `drain_ahead`).
        self.drain_ahead(&mut input)?;
        while !stop.load(Ordering::Relaxed) {
            // 1. Wait for the tick.
            let mut wake_lateness_ns = 0;
            let now = match self.service.clock {
                ClockMode::Timer => {
                    let wake = timer.wait();
                    summary.cycle.record_wake(&wake, late_ns);
                    summary.lateness.record(wake.lateness_ns);
                    wake_lateness_ns = wake.lateness_ns;
                    wake.deadline_ns
                }
                ClockMode::Robot => {
                    // One tick per joint state; past the timeout, tick anyway so the controller
                    // can notice the silence. The tick's time is set from the state after draining.
                    let timeout = self.joint_state_timeout_ns.max(2 * self.dt_ns);
                    self.ports.wait_joint_state(timeout)?;
                    summary.cycle.ticks += 1;
                    monotonic_ns()
                }
                ClockMode::FreeRun => {
                    summary.cycle.ticks += 1;
                    t0 + tick * self.dt_ns
                }
            };
            let woke = monotonic_ns();
            // 2. Drain the subscribers: what the command waits for now (the segments, controls,
            // heater states and the lost-feeder check were taken at the end of the last tick).
            input.tick = tick;
            input.time_ns = now;
            self.drain_now(&mut input)?;
            let drained = monotonic_ns();
            if self.service.clock == ClockMode::Robot {
                input.time_ns = robot_time.advance(input.joint_state.as_ref(), woke);
            }
            input.cycle.overruns = summary.cycle.overruns;
            input.cycle.late_wakeups = summary.cycle.late_wakeups;
            input.cycle.worst_lateness_ns = summary.cycle.worst_lateness_ns;
            input.cycle.log_drops = sink.drops();
            input.cycle.log_state = sink.log_state();
            // 3. Step.
            let before = monotonic_ns();
            let out = self.controller.step(&input);
            let after = monotonic_ns();
            // 4. Publish.
            let mut command_out = woke;
            if out.joint_command.valid == 1 {
                self.ports.publish_joint_command(&out.joint_command)?;
                command_out = monotonic_ns();
                if self.service.joint_feedback == JointFeedback::Echo {
                    self.echo_state.position = out.joint_command.position;
                    self.echo_state.velocity = out.joint_command.velocity;
                }
            }
            self.ports.publish_extruder_command(&out.extruder)?;
            self.ports.publish_heater_command(&out.heater)?;
            if out.base_command.valid == 1 {
                self.ports.publish_base_command(&out.base_command)?;
            }
            self.ports.publish_status_quietly(&out.status)?;
            let published = monotonic_ns();
            // The status event: its waiters are woken at once by a change they wait for, else at the
            // period (the commands above are out already, so a woken process delays nothing of them).
            if status_event.due(published, &out.status) {
                self.ports.notify_status()?;
            }
            summary.step_cost.record(after - before);
            summary.tick_cost.record(published - woke);
            if self.service.clock == ClockMode::Timer {
                summary.cycle.record_work_end(monotonic_ns(), timer.next_deadline_ns());
            }
            let timing = TickTiming {
                wake_lateness_ns,
                step_ns: after - before,
                tick_ns: published - woke,
                receive_ns: drained - woke,
                command_ns: command_out - woke,
            };
            if self.service.clock == ClockMode::FreeRun || (self.service.clock == ClockMode::Robot && self.log_waits) {
                sink.wait_for_room();
            }
            sink.record(&input, &out, &timing);
            // The next tick's inputs that no command waits for, off this tick's critical path.
            input.reset(tick + 1, 0);
            job_seen |= out.status.job_outcome == JobOutcome::InProgress as u32;
            input.feeder_lost = job_seen_open(&out.status) && self.ports.segment_publishers() == 0;
            self.drain_ahead(&mut input)?;
            // 5. Off the tick: tell humans what happened (dead peers are the housekeeper's).
            log_events(&out);
            summary.status = out.status;
            summary.ticks += 1;
            tick += 1;
            if when.max_ticks.is_some_and(|m| tick >= m) {
                break;
            }
            if when.job_done && job_seen && job_ended(&out.status) {
                break;
            }
        }
        Ok(summary)
    }

    /// What a tick's command waits for, taken when the tick wakes: the joint state (the robot
    /// clock's own event) and the tracking samples (the base's latest pose).
    fn drain_now(&mut self, input: &mut TickInput) -> Result<(), RunError> {
        while let Some(js) = self.ports.receive_joint_state()? {
            input.joint_state = Some(js);
        }
        if self.service.joint_feedback == JointFeedback::Echo {
            self.echo_state.seq += 1;
            self.echo_state.stamp_ns = input.time_ns;
            input.joint_state = Some(self.echo_state);
        }
        while let Some(p) = self.ports.receive_base_pose()? {
            input.push_base_pose(&p);
        }
        Ok(())
    }

    /// What no command waits for, taken for the next tick right after this one's record: the
    /// feeder's segments (queued seconds ahead), controls (a pause or a stop a tick later is
    /// nothing; the E-stop is wired) and heater states (a thermal time constant of seconds). Off
    /// the critical path, the wake → command time is the joint state's receive, the step and the
    /// publish. (The input's tick and time are set when its tick wakes.)
    fn drain_ahead(&mut self, input: &mut TickInput) -> Result<(), RunError> {
        take_segments(&self.ports, &mut self.carry, input, self.segments_per_tick)?;
        take_controls(&self.ports, input)?;
        while let Some(h) = self.ports.receive_heater_state()? {
            input.heater_state = Some(h);
        }
        Ok(())
    }
}

/// The robot clock's time line: a tick's time is the stamp of the JointState that started it (the
/// robot's, or a simulator's, time: a simulation may run faster than real time and the controller
/// follows it). A tick without a state (the driver went silent) extrapolates the last stamp by the
/// wall time since it arrived, so the joint-state timeout still fires. Never goes backwards.
/// Before the first state the time is 0.
#[derive(Default)]
struct RobotTime {
    /// (stamp of the last state, monotonic time it arrived), ns.
    last: Option<(u64, u64)>,
    /// The last tick's time, ns.
    time_ns: u64,
}

impl RobotTime {
    fn advance(&mut self, state: Option<&ipc::JointState>, wall_ns: u64) -> u64 {
        let t = match (state, self.last) {
            (Some(js), _) => {
                self.last = Some((js.stamp_ns, wall_ns));
                js.stamp_ns
            }
            (None, Some((stamp, at))) => stamp + wall_ns.saturating_sub(at),
            // Before the robot's first state there is no robot time: stay at 0 rather than mix in
            // the wall clock (a simulator's clock may be far behind or ahead of it).
            (None, None) => 0,
        };
        self.time_ns = t.max(self.time_ns);
        self.time_ns
    }
}

/// Moves the segments of the waiting batches into `input`: what is left of the last batch first
/// (`carry`), then new batches, until `input` holds `max` segments (or is full); the rest of a batch
/// is carried to the next tick. Tick-path safe.
pub fn take_segments(
    ports: &ServicePorts,
    carry: &mut Option<(ipc::SegmentBatch, usize)>,
    input: &mut TickInput,
    max: usize,
) -> Result<(), PortError> {
    loop {
        let (batch, from) = match carry.take() {
            Some(c) => c,
            None => match ports.receive_segments()? {
                Some(b) => (b, 0),
                None => return Ok(()),
            },
        };
        let segments = batch.as_slice();
        let mut k = from;
        while k < segments.len() && (input.segment_count as usize) < max && input.push_segment(&segments[k]) {
            k += 1;
        }
        if k < segments.len() {
            *carry = Some((batch, k));
            return Ok(());
        }
    }
}

/// Moves the waiting controls into `input`, as many as a tick takes. Tick-path safe.
pub fn take_controls(ports: &ServicePorts, input: &mut TickInput) -> Result<(), PortError> {
    while input.control_count < strand_core::MAX_CONTROLS_PER_TICK as u32 {
        match ports.receive_control()? {
            Some(c) => {
                input.push_control(&c);
            }
            None => break,
        }
    }
    Ok(())
}

/// When to wake the status event's waiters (`[service] status_notify_period`): at once on news, else
/// at the period. Status itself is published every tick.
pub struct StatusEvent {
    period_ns: u64,
    last: Option<(u64, ipc::Status)>,
}

impl StatusEvent {
    /// Waiters woken at least every `period` (s); 0: every tick.
    pub fn new(period: f64) -> StatusEvent {
        StatusEvent { period_ns: (period * 1e9) as u64, last: None }
    }

    /// True if the waiters are to be woken for `status`, published at `now_ns` (and then it is taken
    /// as the last one they were woken for).
    pub fn due(&mut self, now_ns: u64, status: &ipc::Status) -> bool {
        let due = match &self.last {
            None => true,
            Some((at, last)) => now_ns.saturating_sub(*at) >= self.period_ns || status_news(last, status),
        };
        if due {
            self.last = Some((now_ns, *status));
        }
        due
    }
}

/// A change of `now` against the last status its waiters were woken for that one of them waits on:
/// the run state, the job's outcome, the fault, a refusal, the overrides, the executing layer.
fn status_news(last: &ipc::Status, now: &ipc::Status) -> bool {
    (last.run_state, last.job_outcome, last.fault, last.executing_layer, last.rejected)
        != (now.run_state, now.job_outcome, now.fault, now.executing_layer, now.rejected)
        || last.feed_override != now.feed_override
        || last.flow_override != now.flow_override
}

fn job_seen_open(status: &ipc::Status) -> bool {
    status.job_outcome == JobOutcome::InProgress as u32
        && matches!(
            RunState::from_u32(status.run_state),
            Some(RunState::Approaching | RunState::Running | RunState::Pausing | RunState::Paused)
        )
}

fn job_ended(status: &ipc::Status) -> bool {
    let outcome = JobOutcome::from_u32(status.job_outcome);
    let state = RunState::from_u32(status.run_state);
    matches!(outcome, Some(JobOutcome::Finished | JobOutcome::Stopped | JobOutcome::Faulted))
        && matches!(state, Some(RunState::Idle | RunState::Fault))
}

/// Most segments a tick takes in at `intake_rate` (segments/s) and `rate_hz` ticks/s: at least one.
pub fn segments_per_tick(intake_rate: f64, rate_hz: f64) -> usize {
    ((intake_rate / rate_hz).ceil() as usize).clamp(1, strand_core::MAX_SEGMENTS_PER_TICK)
}

/// How often the housekeeper lets iceoryx2 forget dead peers (s).
const DEAD_PEER_PERIOD: std::time::Duration = std::time::Duration::from_millis(250);

/// The housekeeper: every [`DEAD_PEER_PERIOD`] until `done`, lets iceoryx2 forget peers that died (a
/// crashed feeder or driver counts as a publisher until then, and the runner reads a feeder's loss
/// from that count). Not on the cycle thread: listing the nodes reads directories and allocates, and
/// it needs none of the cycle's ports.
fn forget_dead_peers(done: &AtomicBool) {
    while !done.load(Ordering::Relaxed) {
        let _ = strand_ipc::ports::cleanup_dead_nodes();
        std::thread::park_timeout(DEAD_PEER_PERIOD);
    }
}

fn log_events(out: &TickOutput) {
    for e in out.events() {
        match e {
            Event::SegmentRejected { seq, reason, field } => tracing::warn!("segment {seq} rejected: {reason:?} {field}"),
            Event::ControlRejected { command, reason } => tracing::warn!("control {command} rejected: {reason:?}"),
            Event::JointStateRejected { seq, reason } => tracing::warn!("joint state {seq} rejected: {reason:?}"),
            Event::BasePoseRejected { seq } => tracing::warn!("base pose {seq} rejected"),
            Event::StateChanged { from, to } => tracing::info!("state {from:?} -> {to:?}"),
            Event::Fault { code, seq, line, value } => {
                tracing::error!("fault: {code:?} at segment {seq} (source line {line}), value {value:.6}")
            }
            Event::JobEnded { outcome, last_seq } => tracing::info!("job ended: {outcome:?} (last segment {last_seq})"),
            Event::Clamped { joint } => tracing::warn!("final stage clamped joint {joint}"),
            Event::HeatWaitSkipped { seq } => {
                tracing::warn!("heat wait (segment {seq}) skipped: no temperature source ([extruder] heater = \"none\")")
            }
            Event::HeaterStateRejected { seq } => {
                tracing::warn!("heater state {seq} rejected: a temperature not finite or outside -60..1000 degC")
            }
        }
    }
    if out.events_dropped > 0 {
        tracing::warn!("{} events not reported (more than fit in one tick)", out.events_dropped);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_waiters_are_woken_on_news_at_once_and_else_at_the_period() {
        let mut event = StatusEvent::new(0.01);
        let mut s = ipc::Status { run_state: RunState::Running as u32, queue_free: 100, ..Default::default() };
        assert!(event.due(0, &s), "the first status wakes");
        // Progress alone (the queue, the path) waits for the period: 10 ms.
        for t in 1..10 {
            s.queue_free -= 1;
            s.path_position += 0.001;
            assert!(!event.due(t * 1_000_000, &s), "{t} ms");
        }
        assert!(event.due(10_000_000, &s));
        // News wakes at once, each kind of it.
        let news: [fn(&mut ipc::Status); 7] = [
            |s| s.run_state = RunState::Paused as u32,
            |s| s.job_outcome = JobOutcome::Finished as u32,
            |s| s.fault = 3,
            |s| s.rejected += 1,
            |s| s.feed_override = 0.5,
            |s| s.flow_override = 0.9,
            |s| s.executing_layer += 1,
        ];
        for (k, change) in news.iter().enumerate() {
            change(&mut s);
            assert!(event.due(10_000_001 + k as u64, &s), "news {k}");
            assert!(!event.due(10_000_001 + k as u64, &s), "news {k} wakes once");
        }
        // Period 0: every tick.
        let mut every = StatusEvent::new(0.0);
        assert!((0..5).all(|t| every.due(t, &s)));
    }
}
