//! `strand-bench tick`: what one controller tick costs, stage by stage, while it prints 004's box:
//! path sample (the path engine's step), base correction (the base estimate at the tick and the
//! world → base map of the target), FK + task Jacobian, the CLIK solve (damped SVD inverse, null
//! space, limits; it does its own FK and Jacobian, counted again here), extrusion, and the log
//! enqueue; and `Controller::step` whole. The stages are the controller's own parts driven in the
//! controller's order on the same job; the whole step runs a real `Controller` beside them.
//! Allocations are counted per stage by the binary's counting allocator: the aim is 0.

use std::path::PathBuf;

use nalgebra::UnitQuaternion;
use serde::Serialize;
use strand::config::Config;
use strand::io::clock::monotonic_ns;
use strand::io::histogram::Histogram;
use strand::io::runner::{StatusEvent, segments_per_tick, take_controls, take_segments};
use strand::log::messages::TickTiming;
use strand::log::writer::{LogContext, Logger};
use strand_core::BaseEstimator;
use strand_core::Extruder;
use strand_core::kin::{ChainState, Clik, PathVelocity, TaskJacobian, TcpTarget};
use strand_core::{Controller, MAX_SEGMENTS_PER_TICK, TickInput};
use strand_core::{PathEngine, Segment};
use strand_ipc as ipc;

use super::{BENCH_JOB, Dist, bench_job};
use strand_cli::error::{Result, ToolError};
use strand_feed::load_segments;

/// What to run.
#[derive(Clone, Debug)]
pub struct TickOptions {
    /// Service config (robot, controller, path, base, extruder, log).
    pub config: PathBuf,
    /// Ticks to measure.
    pub iterations: u64,
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
    /// `Controller::step`, whole (ns).
    #[serde(flatten)]
    pub total: Dist,
    /// Allocations in `Controller::step` over all ticks (count; must be 0).
    pub allocations: u64,
    /// Per stage, in the controller's order.
    pub stages: Vec<Stage>,
    /// Allocations over whole runner ticks, receive and publish included, after the first (count; with
    /// `--shell`; the first tick's, when the ports connect, are `shell.first_tick_allocations`).
    pub runner_allocations: Option<u64>,
    /// The shell's stages (with `--shell`).
    pub shell: Option<ShellReport>,
    /// The histograms (whole step, then the stages), for the plot (not printed).
    #[serde(skip)]
    pub histograms: Vec<(String, Histogram)>,
}

/// Runs the stages and the whole step for `iterations` ticks.
pub fn run(opts: &TickOptions) -> Result<TickReport> {
    let cfg = Config::load(&opts.config)?;
    let model = cfg.robot.build_model()?;
    let n = model.dof();
    let dt = 1.0 / cfg.controller.rate_hz;
    let dt_ns = (dt * 1e9).round() as u64;
    let alloc = opts.allocations;

    // The stages, set up as the controller sets them up.
    let mut q = model.middle_configuration();
    for (i, v) in cfg.service.initial_joints.iter().enumerate().take(n) {
        q[i] = *v;
    }
    let estimator = BaseEstimator::new(&cfg.base);
    let start_b = model.forward_kinematics(&q);
    let (start_w, start_q) =
        estimator.at(0).base_to_world(&start_b.translation.vector, &UnitQuaternion::from_rotation_matrix(&start_b.rotation));
    let mut engine = PathEngine::new(&cfg.path, dt, start_w, start_q)?;
    let mut clik = Clik::new(cfg.clik)?;
    let mut extruder = Extruder::new(&cfg.extruder, dt)?;
    let mut state = ChainState::new(n);
    let (segments, _) = load_segments(&opts.root.join(BENCH_JOB), &cfg.bed_transform()?)?;
    let segments: Vec<Segment> = segments.into_iter().map(|(s, _)| s).collect();
    let mut next_core = 0usize;

    // The whole controller, on the same job over the wire types, with its log.
    let mut ctl = Controller::new(&cfg.controller_settings(), model.clone())?;
    let job = bench_job(&opts.root, &cfg)?;
    let log_path = std::env::temp_dir().join(format!("strand-bench-tick-{}.mcap", std::process::id()));
    let logger = Logger::start_at(&cfg.log, LogContext::new(&cfg, &model), &log_path)?;
    let mut input = TickInput::new(0, 0);
    let mut q_ctl = [0.0; ipc::MAX_JOINTS];
    q_ctl[..n].copy_from_slice(&q.as_slice()[..n]);
    let (mut next_wire, mut free) = (0usize, 0u32);

    const NAMES: [&str; 6] =
        ["path sample", "base correction", "FK + Jacobian", "CLIK (own FK, SVD, null space, limits)", "extrusion", "log enqueue"];
    let mut cost: [Histogram; 6] = Default::default();
    let mut allocs = [0u64; 6];
    let mut total = Histogram::new();
    let mut total_allocs = 0u64;
    let mut scale = 1.0;
    let mut running_ticks = 0u64;
    let mut time_ns = 0u64;
    for tick in 0..opts.iterations {
        time_ns += dt_ns;
        // Keep the engine fed (outside the measurement), as the controller's intake does.
        while next_core < segments.len() && engine.free_space() > 0 {
            engine.push(&segments[next_core]).map_err(|e| ToolError::Measurement(format!("segment {}: {e:?}", segments[next_core].seq)))?;
            next_core += 1;
        }
        let mut stage = 0;
        let mut t = monotonic_ns();
        let mut a = alloc();
        let mut lap = |stage: &mut usize, t: &mut u64, a: &mut u64| {
            let (now, count) = (monotonic_ns(), alloc());
            cost[*stage].record(now - *t);
            allocs[*stage] += count - *a;
            *stage += 1;
            (*t, *a) = (monotonic_ns(), alloc());
        };
        // The job's heat waits: no heaters in this bench, released at once.
        engine.release_wait();
        let sample = engine.step(scale);
        lap(&mut stage, &mut t, &mut a);
        let base = estimator.at(time_ns + dt_ns);
        let target_w = TcpTarget {
            position: sample.position,
            orientation: sample.orientation,
            linear_velocity: sample.velocity,
            angular_velocity: sample.angular_velocity,
        };
        let target_b = base.world_to_base(&target_w);
        let r_bw = base.orientation.inverse();
        let path_b = PathVelocity { linear: r_bw * sample.velocity, angular: r_bw * sample.angular_velocity };
        lap(&mut stage, &mut t, &mut a);
        model.kinematics(&q, &mut state);
        std::hint::black_box(TaskJacobian::new(&state, cfg.clik.task));
        lap(&mut stage, &mut t, &mut a);
        let step = clik.step_on_path(&model, &q, &target_b, &path_b, dt);
        lap(&mut stage, &mut t, &mut a);
        std::hint::black_box(extruder.step(&sample));
        lap(&mut stage, &mut t, &mut a);
        scale = step.path_scale;
        q = step.q;

        // The whole step, then its log record.
        input.reset(tick, time_ns);
        input.joint_state =
            Some(ipc::JointState { seq: tick + 1, stamp_ns: time_ns, dof: n as u32, position: q_ctl, ..Default::default() });
        if tick == 0 {
            input.push_control(&ipc::Control { seq: 1, stamp_ns: time_ns, command: ipc::Command::Start as u32, value: 0.0, _reserved: 0 });
            free = 64;
        }
        while free > 0 && next_wire < job.segments.len() && (input.segment_count as usize) < MAX_SEGMENTS_PER_TICK {
            input.push_segment(&job.segments[next_wire]);
            next_wire += 1;
            free -= 1;
        }
        let (t0, a0) = (monotonic_ns(), alloc());
        let out = ctl.step(&input);
        let (t1, a1) = (monotonic_ns(), alloc());
        total.record(t1 - t0);
        total_allocs += a1 - a0;
        let (t, a) = (monotonic_ns(), alloc());
        logger.push(&input, &out, &TickTiming { wake_lateness_ns: 0, step_ns: t1 - t0, tick_ns: t1 - t0 });
        cost[5].record(monotonic_ns() - t);
        allocs[5] += alloc() - a;
        if out.joint_command.valid == 1 {
            q_ctl = out.joint_command.position;
        }
        free = out.status.queue_free.saturating_sub(64);
        running_ticks += (out.status.run_state == ipc::RunState::Running as u32) as u64;
    }
    discard(logger);
    let shell = if opts.shell { Some(shell(opts, &cfg, &model)?) } else { None };
    let mut histograms = vec![("Controller::step".to_string(), total.clone())];
    histograms.extend(NAMES.iter().zip(cost.iter()).map(|(n, h)| (n.to_string(), h.clone())));
    Ok(TickReport {
        histograms,
        mode: "tick",
        robot: model.name().to_string(),
        dof: n,
        iterations: opts.iterations,
        running_ticks,
        total: Dist::of(&total),
        allocations: total_allocs,
        stages: stages(&NAMES, &cost, &allocs),
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
        logger.push(&input, &out, &TickTiming { wake_lateness_ns: 0, step_ns, tick_ns: t - begin });
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

/// Writes the report as a table.
impl TickReport {
    /// The benchmark's rules: sane distributions and no allocation in `Controller::step` or any
    /// stage (the tick path must not allocate).
    pub fn check(&self) -> Result<()> {
        self.total.check("Controller::step")?;
        let allocating: Vec<&str> = self.stages.iter().filter(|s| s.allocations > 0).map(|s| s.name.as_str()).collect();
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
    println!("{} {:>7}", Dist::header("stage"), "allocs");
    for s in &r.stages {
        println!("{} {:>7}", s.cost.row(&s.name), s.allocations);
    }
    println!("{} {:>7}", r.total.row("Controller::step (whole)"), r.allocations);
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
