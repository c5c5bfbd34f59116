//! `strand-bench tick`: what one controller tick costs, stage by stage, while it prints 004's box.
//!
//! The stages are the controller's own ([`TickStage`]: intake, supervision, base estimate, path
//! sample, base correction, CLIK, command limits, heat, run state, base setpoint, the command's FK
//! and Jacobian, the following-error watchdog, extrusion, outputs), timed inside a real
//! `Controller::step` by the probe it calls as each one ends ([`Controller::step_probed`]): every
//! piece of the tick's work is in one of them. `Controller::step` whole runs unprobed in a second
//! controller given the same inputs (the two must decide the same to the bit, or the run fails), and
//! the remainder — the whole step's p50 less the stages' p50s, each net of the probe's own cost (an
//! empty lap's p50) — is printed, so that nothing can hide in "the rest". The log enqueue, after
//! the step, is timed on its own. Allocations are counted per stage by the binary's counting
//! allocator: the aim is 0. With `--pinocchio` and `--kdl` the baselines' CLIK ticks run between
//! rounds of ours, and the ratios are the medians of the rounds'.

use std::path::PathBuf;

use serde::Serialize;
use strand::config::Config;
use strand::io::clock::monotonic_ns;
use strand::io::histogram::Histogram;
use strand::io::runner::{StatusEvent, segments_per_tick, take_controls, take_segments};
use strand::log::messages::TickTiming;
use strand::log::writer::{LogContext, Logger};
use strand_core::{Controller, MAX_SEGMENTS_PER_TICK, TickInput, TickOutput, TickProbe, TickStage};
use strand_ipc as ipc;

use super::clik::{Round, baseline_round, median};
use super::{Dist, bench_job};
use strand_cli::error::{Result, ToolError};

/// What to run.
#[derive(Clone, Debug)]
pub struct TickOptions {
    /// Service config (robot, controller, path, base, extruder, log).
    pub config: PathBuf,
    /// Ticks to measure.
    pub iterations: u64,
    /// Rounds the ticks are split into, with the baselines' benches run between them (count).
    pub rounds: usize,
    /// Repository root (the job).
    pub root: PathBuf,
    /// Reads the calling thread's allocation count (the binary's counting allocator).
    pub allocations: fn() -> u64,
    /// Also run the shell: the runner's receive, step, publish and log push over real iceoryx2
    /// ports, each stage timed and its allocations counted ([`ShellReport`]).
    pub shell: bool,
    /// Pace the shell's ticks at this rate (Hz), sleeping between them as the runner does, so each
    /// tick starts with the caches its sleep left; 0: back to back (everything hot).
    pub shell_rate: f64,
    /// Pinocchio's DLS CLIK bench (`benches/pinocchio/build.sh`): the CLIK stage's baseline.
    pub pinocchio: Option<PathBuf>,
    /// KDL's CLIK bench (`benches/kdl/build.sh`): the whole step's baseline.
    pub kdl: Option<PathBuf>,
}

/// One stage's cost and allocations.
#[derive(Clone, Debug, Serialize)]
pub struct Stage {
    /// What the stage is.
    pub name: String,
    /// The cost per tick (ns).
    #[serde(flatten)]
    pub cost: Dist,
    /// Allocations over all measured ticks (count; must be 0).
    pub allocations: u64,
}

/// A baseline's CLIK tick, run between our rounds.
#[derive(Clone, Debug, Serialize)]
pub struct Baseline {
    /// The library and its version.
    pub name: String,
    /// Its rounds.
    pub rounds: Vec<Round>,
    /// The median over the rounds of (ours / its) at p50, for what it is compared with (the whole
    /// step for KDL; the CLIK stage, and the CLIK stage with the command's FK and Jacobian, for
    /// Pinocchio).
    pub p50_ratio: f64,
    /// For Pinocchio: the same with the command's FK + Jacobian stage added to the CLIK stage (what
    /// Pinocchio's tick does itself). None for KDL.
    pub p50_ratio_with_fk: Option<f64>,
}

/// The report; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize)]
pub struct TickReport {
    /// "tick".
    pub mode: &'static str,
    /// The robot.
    pub robot: String,
    /// Joints.
    pub dof: usize,
    /// Ticks measured.
    pub iterations: u64,
    /// Ticks of them on the path (printing or travelling).
    pub running_ticks: u64,
    /// `Controller::step`, whole, unprobed (ns).
    #[serde(flatten)]
    pub total: Dist,
    /// Allocations in `Controller::step` over all ticks (count; must be 0).
    pub allocations: u64,
    /// Per stage, in the controller's order ([`TickStage::ALL`]), from the probed step (ns; each
    /// with one lap of the probe in it).
    pub stages: Vec<Stage>,
    /// What one lap of the probe costs by itself: the p50 of empty laps (ns).
    pub probe_lap_ns: u64,
    /// The stages' p50s added up, each less `probe_lap_ns` (ns).
    pub stage_sum_ns: i64,
    /// The whole step's p50 less `stage_sum_ns` (ns): what no stage accounts for.
    pub remainder_ns: i64,
    /// The log enqueue after the step (`Logger::push`; ns).
    pub log_enqueue: Stage,
    /// KDL's CLIK tick against the whole step (with `--kdl`).
    pub kdl: Option<Baseline>,
    /// Pinocchio's DLS tick against the CLIK stage (with `--pinocchio`).
    pub pinocchio: Option<Baseline>,
    /// Allocations over whole runner ticks, receive and publish included, after the first (count; with
    /// `--shell`; the first tick's, when the ports connect, are `shell.first_tick_allocations`).
    pub runner_allocations: Option<u64>,
    /// The shell's stages (with `--shell`).
    pub shell: Option<ShellReport>,
    /// The histograms (whole step, then the stages), for the plot (not printed).
    #[serde(skip)]
    pub histograms: Vec<(String, Histogram)>,
}

/// The bench's [`TickProbe`]: the time (ns) and allocations of each stage of one tick.
struct StageClock {
    allocations: fn() -> u64,
    last_ns: u64,
    last_allocations: u64,
    ns: [u64; STAGES],
    allocated: [u64; STAGES],
    ended: [bool; STAGES],
}

/// The controller's stages (count).
const STAGES: usize = TickStage::ALL.len();

impl StageClock {
    fn new(allocations: fn() -> u64) -> Self {
        StageClock { allocations, last_ns: 0, last_allocations: 0, ns: [0; STAGES], allocated: [0; STAGES], ended: [false; STAGES] }
    }

    /// A tick begins now.
    fn start(&mut self) {
        (self.ns, self.allocated, self.ended) = ([0; STAGES], [0; STAGES], [false; STAGES]);
        self.last_allocations = (self.allocations)();
        self.last_ns = monotonic_ns();
    }
}

impl TickProbe for StageClock {
    fn stage_done(&mut self, stage: TickStage) {
        let now = monotonic_ns();
        let count = (self.allocations)();
        let i = stage.index();
        self.ns[i] += now - self.last_ns;
        self.allocated[i] += count - self.last_allocations;
        self.ended[i] = true;
        (self.last_ns, self.last_allocations) = (now, count);
    }
}

/// The probe's own cost: the p50 of laps with no work between them (ns).
fn empty_lap_ns(allocations: fn() -> u64) -> u64 {
    let mut clock = StageClock::new(allocations);
    let mut laps = Histogram::new();
    for _ in 0..20_000 {
        clock.start();
        for stage in TickStage::ALL {
            clock.stage_done(stage);
        }
        for i in 0..STAGES {
            laps.record(clock.ns[i]);
        }
    }
    laps.percentile(50.0)
}

/// The two controllers decided the same (joint command, extruder, status, diagnostics), to the bit.
fn same_decisions(a: &TickOutput, b: &TickOutput) -> bool {
    let bits = |o: &TickOutput| {
        let (j, e, d) = (&o.joint_command, &o.extruder, &o.diagnostics);
        let mut v: Vec<u64> = j.position.iter().chain(&j.velocity).chain(&j.acceleration).map(|x| x.to_bits()).collect();
        v.extend([e.motor_speed, e.filament_rate, o.status.tcp_error, d.tcp_error, d.sigma_min].map(f64::to_bits));
        v.extend(d.tcp_command_world.iter().chain(d.tcp_target_world.iter()).map(|x| x.to_bits()));
        v.extend([o.status.run_state as u64, o.status.fault as u64, o.event_count as u64]);
        v
    };
    bits(a) == bits(b)
}

/// Runs the stages and the whole step for `iterations` ticks, in rounds with the baselines.
pub fn run(opts: &TickOptions) -> Result<TickReport> {
    let cfg = Config::load(&opts.config)?;
    let model = cfg.robot.build_model()?;
    let n = model.dof();
    let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
    let alloc = opts.allocations;
    let urdf = cfg.robot.urdf_path();

    // Two controllers on the same job over the wire types: one timed whole, one by stage.
    let mut ctl = Controller::new(&cfg.controller_settings(), model.clone())?;
    let mut probed = Controller::new(&cfg.controller_settings(), model.clone())?;
    let job = bench_job(&opts.root, &cfg)?;
    let log_path = std::env::temp_dir().join(format!("strand-bench-tick-{}.mcap", std::process::id()));
    let logger = Logger::start_at(&cfg.log, LogContext::new(&cfg, &model), &log_path)?;
    let mut input = TickInput::new(0, 0);
    let start = model.middle_configuration();
    let mut q_ctl = [0.0; ipc::MAX_JOINTS];
    for (i, v) in q_ctl.iter_mut().enumerate().take(n) {
        *v = cfg.service.initial_joints.get(i).copied().unwrap_or(start[i]);
    }
    let (mut next_wire, mut free) = (0usize, 0u32);

    let mut cost: [Histogram; STAGES] = Default::default();
    let mut allocs = [0u64; STAGES];
    let mut clock = StageClock::new(alloc);
    let (mut total, mut log_cost) = (Histogram::new(), Histogram::new());
    let (mut total_allocs, mut log_allocs) = (0u64, 0u64);
    let mut running_ticks = 0u64;
    let mut time_ns = 0u64;
    let rounds = opts.rounds.max(1);
    let per_round = opts.iterations.div_ceil(rounds as u64);
    // Per round: the whole step's and the CLIK's p50 (ours), and the baselines' rounds.
    let (mut step_p50, mut clik_p50, mut clik_fk_p50) = (Vec::new(), Vec::new(), Vec::new());
    let (mut kdl, mut pinocchio) = ((String::new(), Vec::new()), (String::new(), Vec::new()));
    let mut tick = 0u64;
    for _ in 0..rounds {
        let (mut round_step, mut round_clik, mut round_clik_fk) = (Histogram::new(), Histogram::new(), Histogram::new());
        while tick < opts.iterations && tick < per_round * (step_p50.len() as u64 + 1) {
            time_ns += dt_ns;
            input.reset(tick, time_ns);
            input.joint_state =
                Some(ipc::JointState { seq: tick + 1, stamp_ns: time_ns, dof: n as u32, position: q_ctl, ..Default::default() });
            if tick == 0 {
                input.push_control(&ipc::Control {
                    seq: 1,
                    stamp_ns: time_ns,
                    command: ipc::Command::Start as u32,
                    value: 0.0,
                    _reserved: 0,
                });
                free = 64;
            }
            while free > 0 && next_wire < job.segments.len() && (input.segment_count as usize) < MAX_SEGMENTS_PER_TICK {
                input.push_segment(&job.segments[next_wire]);
                next_wire += 1;
                free -= 1;
            }
            // The stages, then the whole step on the same input.
            clock.start();
            let staged = probed.step_probed(&input, &mut clock);
            for i in 0..STAGES {
                if clock.ended[i] {
                    cost[i].record(clock.ns[i]);
                    allocs[i] += clock.allocated[i];
                }
            }
            let ci = TickStage::Clik.index();
            if clock.ended[TickStage::PathSample.index()] {
                round_clik.record(clock.ns[ci]);
                round_clik_fk.record(clock.ns[ci] + clock.ns[TickStage::CommandKinematics.index()]);
            }
            let (t0, a0) = (monotonic_ns(), alloc());
            let out = ctl.step(&input);
            let (t1, a1) = (monotonic_ns(), alloc());
            total.record(t1 - t0);
            round_step.record(t1 - t0);
            total_allocs += a1 - a0;
            if !same_decisions(&out, &staged) {
                return Err(ToolError::Measurement(format!("tick {tick}: the probed step decided otherwise than the step")));
            }
            let (t, a) = (monotonic_ns(), alloc());
            logger.push(&input, &out, &TickTiming { step_ns: t1 - t0, tick_ns: t1 - t0, ..TickTiming::default() });
            log_cost.record(monotonic_ns() - t);
            log_allocs += alloc() - a;
            if out.joint_command.valid == 1 {
                q_ctl = out.joint_command.position;
            }
            free = out.status.queue_free.saturating_sub(64);
            running_ticks += (out.status.run_state == ipc::RunState::Running as u32) as u64;
            tick += 1;
        }
        step_p50.push(round_step.percentile(50.0) as f64);
        clik_p50.push(round_clik.percentile(50.0) as f64);
        clik_fk_p50.push(round_clik_fk.percentile(50.0) as f64);
        let baseline_ticks = per_round.clamp(1, 200_000) as usize;
        for (bin, (version, rounds)) in [(&opts.kdl, &mut kdl), (&opts.pinocchio, &mut pinocchio)] {
            if let Some(bin) = bin {
                let (round, v) = baseline_round(bin, &urdf, baseline_ticks)?;
                rounds.push(round);
                *version = v;
            }
        }
    }
    discard(logger);
    let ratio = |ours: &[f64], theirs: &[Round]| median(ours.iter().zip(theirs).map(|(a, b)| a / b.cost.p50_ns as f64).collect());
    let kdl = opts.kdl.as_ref().map(|_| Baseline {
        name: format!("KDL {}", kdl.0),
        p50_ratio: ratio(&step_p50, &kdl.1).unwrap_or(f64::NAN),
        p50_ratio_with_fk: None,
        rounds: kdl.1.clone(),
    });
    let pinocchio = opts.pinocchio.as_ref().map(|_| Baseline {
        name: format!("Pinocchio {}", pinocchio.0),
        p50_ratio: ratio(&clik_p50, &pinocchio.1).unwrap_or(f64::NAN),
        p50_ratio_with_fk: ratio(&clik_fk_p50, &pinocchio.1),
        rounds: pinocchio.1.clone(),
    });
    let shell = if opts.shell { Some(shell(opts, &cfg, &model)?) } else { None };
    let names: Vec<&str> = TickStage::ALL.iter().map(|s| s.name()).collect();
    let mut histograms = vec![("Controller::step".to_string(), total.clone())];
    histograms.extend(names.iter().zip(cost.iter()).map(|(n, h)| (n.to_string(), h.clone())));
    let stages = stages(&names, &cost, &allocs);
    let probe_lap_ns = empty_lap_ns(alloc);
    let stage_sum_ns = stages.iter().map(|s| s.cost.p50_ns as i64 - probe_lap_ns as i64).sum::<i64>();
    let total = Dist::of(&total);
    Ok(TickReport {
        histograms,
        mode: "tick",
        robot: model.name().to_string(),
        dof: n,
        iterations: opts.iterations,
        running_ticks,
        remainder_ns: total.p50_ns as i64 - stage_sum_ns,
        total,
        allocations: total_allocs,
        stages,
        probe_lap_ns,
        stage_sum_ns,
        log_enqueue: Stage { name: "log enqueue (after the step)".to_string(), cost: Dist::of(&log_cost), allocations: log_allocs },
        kdl,
        pinocchio,
        runner_allocations: shell.as_ref().map(|s| s.allocations),
        shell,
    })
}

/// The shell around `Controller::step`, stage by stage: what the runner does each tick besides the
/// step, over real iceoryx2 ports to a feeder and a driver in the same process (the peers' work is
/// not timed).
#[derive(Clone, Debug, Serialize)]
pub struct ShellReport {
    /// Ticks measured.
    pub iterations: u64,
    /// The pace of the ticks (Hz; 0: back to back).
    pub rate_hz: f64,
    /// The runner's tick without its wait: first receive to the end of the log push (ns).
    #[serde(flatten)]
    pub tick: Dist,
    /// Allocations over all those ticks but the first (count), every stage included: the steady state.
    pub allocations: u64,
    /// Allocations in the first tick (count): iceoryx2 connecting the ports to the peers that opened
    /// before it (mapping their shared memory), once per peer port. Not in `allocations` or the stages'.
    pub first_tick_allocations: u64,
    /// Per stage, in the runner's order (allocations from the second tick on).
    pub stages: Vec<Stage>,
}

/// The runner's stages, in its order (src/io/runner.rs).
const SHELL_STAGES: [&str; 12] = [
    "clock read (monotonic_ns)",
    "receive segments",
    "receive control",
    "receive joint state",
    "receive base pose",
    "segment publishers (feeder lost?)",
    "Controller::step",
    "publish joint command",
    "publish extruder command",
    "publish status (quietly)",
    "notify status waiters (when due)",
    "log push",
];

/// Runs [`ShellReport`]'s ticks: the bench job streamed by a feeder within its credit, the driver
/// echoing each command as the next joint state, the service side receiving, stepping, publishing
/// and logging as the runner does.
fn shell(opts: &TickOptions, cfg: &Config, model: &strand_core::kin::RobotModel) -> Result<ShellReport> {
    use strand_ipc::ServiceNames;
    use strand_ipc::ports::{ClientPorts, ClientRoles, ServicePorts};
    let alloc = opts.allocations;
    let n = model.dof();
    let prefix = format!("strand-bench-shell-{}", std::process::id());
    let names = ServiceNames::new(&prefix);
    let service = ServicePorts::open(&names, &format!("{prefix}-service"))?;
    let peer = ClientPorts::open(
        &names,
        &format!("{prefix}-peers"),
        ClientRoles { feeder: true, driver: true, monitor: true, ..Default::default() },
    )?;
    let mut ctl = Controller::new(&cfg.controller_settings(), model.clone())?;
    let job = bench_job(&opts.root, cfg)?;
    let log_path = std::env::temp_dir().join(format!("strand-bench-shell-{}.mcap", std::process::id()));
    let logger = Logger::start_at(&cfg.log, LogContext::new(cfg, model), &log_path)?;
    let mut q = [0.0; ipc::MAX_JOINTS];
    let start = model.middle_configuration();
    for (i, v) in q.iter_mut().enumerate().take(n) {
        *v = cfg.service.initial_joints.get(i).copied().unwrap_or(start[i]);
    }
    let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
    let (first, last) = (job.segments[0].seq, job.segments[job.segments.len() - 1].seq);
    let (mut sent, mut started, mut batch_seq) = (0usize, false, 0u64);
    let mut status = ipc::Status::default();
    let mut cost: [Histogram; 12] = Default::default();
    let mut allocs = [0u64; 12];
    let mut status_event = StatusEvent::new(cfg.service.status_notify_period);
    let per_tick = segments_per_tick(cfg.service.segment_intake_rate, cfg.controller.rate_hz);
    let (mut whole, mut whole_allocs, mut first_tick_allocs) = (Histogram::new(), 0u64, 0u64);
    let mut input = TickInput::new(0, 0);
    let mut carry: Option<(ipc::SegmentBatch, usize)> = None;
    let mut time_ns = 0u64;
    let period_ns = if opts.shell_rate > 0.0 { (1e9 / opts.shell_rate) as u64 } else { 0 };
    let mut deadline = monotonic_ns();
    for tick in 0..opts.iterations {
        time_ns += dt_ns;
        if period_ns > 0 {
            deadline += period_ns;
            let now = monotonic_ns();
            if deadline > now {
                std::thread::sleep(std::time::Duration::from_nanos(deadline - now));
            }
        }
        // The peers (not timed): the driver's joint state, the feeder's batches within the credit
        // of the last Status, and Start once the first batch is out.
        peer.send_joint_state(&ipc::JointState { seq: tick + 1, stamp_ns: time_ns, dof: n as u32, position: q, ..Default::default() })?;
        let allowed = (strand_feed::credit(&status, first, last, started) as usize).min(job.segments.len());
        while sent < allowed {
            let k = (allowed - sent).min(ipc::SEGMENT_BATCH_CAPACITY);
            batch_seq += 1;
            if peer.send_segments(&strand_feed::batch(&job.segments[sent..sent + k], batch_seq))? == 0 {
                break;
            }
            sent += k;
        }
        if !started && sent > 0 {
            peer.send_control(&ipc::Control {
                seq: 1,
                stamp_ns: monotonic_ns(),
                command: ipc::Command::Start as u32,
                value: 0.0,
                _reserved: 0,
            })?;
            started = true;
        }
        // The service's tick, as the runner runs it.
        let (begin, a_begin) = (monotonic_ns(), alloc());
        let (mut t, mut a) = (begin, a_begin);
        let mut stage = 0usize;
        let mut lap = |stage: &mut usize, t: &mut u64, a: &mut u64| {
            let (now, count) = (monotonic_ns(), alloc());
            cost[*stage].record(now - *t);
            allocs[*stage] += count - *a;
            *stage += 1;
            (*t, *a) = (now, count);
        };
        // The clock: what a read costs (two reads back to back).
        std::hint::black_box(monotonic_ns());
        lap(&mut stage, &mut t, &mut a);
        input.reset(tick, time_ns);
        take_segments(&service, &mut carry, &mut input, per_tick)?;
        lap(&mut stage, &mut t, &mut a);
        take_controls(&service, &mut input)?;
        lap(&mut stage, &mut t, &mut a);
        while let Some(js) = service.receive_joint_state()? {
            input.joint_state = Some(js);
        }
        lap(&mut stage, &mut t, &mut a);
        while let Some(p) = service.receive_base_pose()? {
            input.push_base_pose(&p);
        }
        lap(&mut stage, &mut t, &mut a);
        // The runner asks every tick whether a feeder is still there.
        input.feeder_lost = started && service.segment_publishers() == 0;
        lap(&mut stage, &mut t, &mut a);
        let before_step = t;
        let out = ctl.step(&input);
        lap(&mut stage, &mut t, &mut a);
        let step_ns = t - before_step;
        if out.joint_command.valid == 1 {
            service.publish_joint_command(&out.joint_command)?;
        }
        lap(&mut stage, &mut t, &mut a);
        service.publish_extruder_command(&out.extruder)?;
        lap(&mut stage, &mut t, &mut a);
        service.publish_status_quietly(&out.status)?;
        lap(&mut stage, &mut t, &mut a);
        if status_event.due(t, &out.status) {
            service.notify_status()?;
        }
        lap(&mut stage, &mut t, &mut a);
        logger.push(&input, &out, &TickTiming { step_ns, tick_ns: t - begin, ..TickTiming::default() });
        lap(&mut stage, &mut t, &mut a);
        whole.record(t - begin);
        whole_allocs += a - a_begin;
        if tick == 0 {
            // iceoryx2 connected the ports to the peers here: once, not a tick's cost.
            first_tick_allocs = std::mem::take(&mut whole_allocs);
            allocs = [0; 12];
        }
        // The peers take what was published (not timed).
        while let Some(cmd) = peer.receive_joint_command()? {
            if cmd.valid == 1 {
                q = cmd.position;
            }
        }
        while peer.receive_extruder_command()?.is_some() {}
        if let Some(s) = peer.latest_status() {
            status = s;
        }
    }
    discard(logger);
    Ok(ShellReport {
        iterations: opts.iterations,
        rate_hz: opts.shell_rate,
        tick: Dist::of(&whole),
        allocations: whole_allocs,
        first_tick_allocations: first_tick_allocs,
        stages: stages(&SHELL_STAGES, &cost, &allocs),
    })
}

/// The stages' report rows: each name with its cost and allocations.
fn stages(names: &[&str], cost: &[Histogram], allocs: &[u64]) -> Vec<Stage> {
    names
        .iter()
        .zip(cost.iter().zip(allocs))
        .map(|(name, (h, a))| Stage { name: name.to_string(), cost: Dist::of(h), allocations: *a })
        .collect()
}

/// Ends a bench's log and removes its files: the logger ran for its cost, not its record.
fn discard(logger: Logger) {
    for f in &logger.finish().files {
        let _ = std::fs::remove_file(f);
    }
}

impl TickReport {
    /// The benchmark's rules: sane distributions and no allocation in `Controller::step`, any stage
    /// or the log enqueue (the tick path must not allocate).
    pub fn check(&self) -> Result<()> {
        self.total.check("Controller::step")?;
        let allocating: Vec<&str> =
            self.stages.iter().chain([&self.log_enqueue]).filter(|s| s.allocations > 0).map(|s| s.name.as_str()).collect();
        if self.allocations > 0 || !allocating.is_empty() {
            return Err(ToolError::Measurement(format!(
                "the tick allocated: Controller::step {} times; stages {allocating:?}",
                self.allocations
            )));
        }
        Ok(())
    }
}

/// Prints the report as a table.
pub fn print(r: &TickReport) {
    println!(
        "strand-bench tick: {} ({} joints), {} ticks of 004's box, {} of them on the path",
        r.robot, r.dof, r.iterations, r.running_ticks
    );
    println!("{} {:>7}", Dist::header("stage of Controller::step (probed)"), "allocs");
    for s in &r.stages {
        println!("{} {:>7}", s.cost.row(&s.name), s.allocations);
    }
    println!("{} {:>7}", r.total.row("Controller::step (whole, unprobed)"), r.allocations);
    println!(
        "stages' p50s added up, each less the probe's own lap ({} ns): {:.2} µs; the step's p50 {:.2} µs; remainder {:+.2} µs",
        r.probe_lap_ns,
        r.stage_sum_ns as f64 * 1e-3,
        r.total.p50_ns as f64 * 1e-3,
        r.remainder_ns as f64 * 1e-3
    );
    println!("{} {:>7}", r.log_enqueue.cost.row(&r.log_enqueue.name), r.log_enqueue.allocations);
    for (b, what) in [(&r.kdl, "Controller::step"), (&r.pinocchio, "CLIK stage")] {
        if let Some(b) = b {
            let p50s: Vec<String> = b.rounds.iter().map(|x| format!("{:.2}", x.cost.p50_ns as f64 * 1e-3)).collect();
            print!("{} CLIK tick p50 by round: {} µs; {what} / it: {:.2}×", b.name, p50s.join(", "), b.p50_ratio);
            if let Some(fk) = b.p50_ratio_with_fk {
                print!(" ({fk:.2}× with the command's FK + Jacobian, which its tick does itself)");
            }
            println!(" (median of the rounds)");
            if let Some(first) = b.rounds.first().filter(|r| r.solvers.len() > 1) {
                let each: Vec<String> = first
                    .solvers
                    .iter()
                    .map(|(name, p50)| format!("{name} {:.2} µs ({:.2}×)", *p50 as f64 * 1e-3, r.total.p50_ns as f64 / *p50 as f64))
                    .collect();
                println!("  its solvers in the first round (p50, and {what}'s p50 over all rounds against it): {}", each.join(", "));
            }
        }
    }
    if let Some(sh) = &r.shell {
        let pace = if sh.rate_hz > 0.0 { format!("paced at {} Hz", sh.rate_hz) } else { "back to back".to_string() };
        println!("shell: the runner's tick over iceoryx2 ports, {} ticks {pace} (a feeder and a driver in this process)", sh.iterations);
        println!("{} {:>7}", Dist::header("stage"), "allocs");
        for s in &sh.stages {
            println!("{} {:>7}", s.cost.row(&s.name), s.allocations);
        }
        println!("{} {:>7}", sh.tick.row("runner tick (receive → log push)"), sh.allocations);
        println!(
            "runner allocations: {} over {} ticks after the first ({:.2} a tick); {} in the first, connecting the ports to their peers",
            sh.allocations,
            sh.iterations.saturating_sub(1),
            sh.allocations as f64 / sh.iterations.saturating_sub(1).max(1) as f64,
            sh.first_tick_allocations
        );
    }
}

/// Draws the whole step's histogram with the stages'.
pub fn plot(r: &TickReport, path: &std::path::Path) -> Result<()> {
    let series: Vec<(&str, &Histogram)> = r.histograms.iter().map(|(n, h)| (n.as_str(), h)).collect();
    super::plot_histograms(path, &format!("tick cost, {}", r.robot), &series)
}
