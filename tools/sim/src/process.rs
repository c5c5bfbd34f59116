//! The sim as a process: the plant ([`Sim`]) talking to the service over iceoryx2 as the real
//! drivers would. Its JointStates drive the service's `robot` clock; in lockstep (the default) it
//! answers each command as soon as it arrives, so a job runs as fast as the two processes can
//! exchange messages, with every stamp on the sim's own clock; `realtime` paces it at the robot's
//! rate instead. It writes the truth (actual nozzle, base, melt flow) as CSV for the demo.
//!
//! It also owns the heaters: the service config's `[thermal]` plant (hot end and bed, each a
//! first-order block with a lagging thermistor and a feed-forward + P controller, strand-core's
//! `ThermalModel`) heats toward the targets of the latest `HeaterCommand` and publishes what its
//! thermistors read as `HeaterState` every 10 ms of sim time, stamped with the sim's clock — the
//! messages a Klipper extruder board's process will exchange with the service.
//!
//! With `--motive PORT` the base's tracker is OptiTrack: the sim serves the base's true pose over
//! NatNet (strand-natnet's fake Motive, in this process) and `strand-natnet` publishes it, as in a
//! cell with a real Motive.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use strand::config::Config;
use strand::io::clock::{TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand_core::ThermalModel;
use strand_ipc::ServiceNames;
use strand_ipc::ports::{ClientPorts, ClientRoles};

use super::config::SimConfig;
use super::{Sim, Truth};
use strand_cli::error::{Result, ToolError};

/// How the sim runs, as `strand-sim`'s options say it.
#[derive(Clone, Debug)]
pub struct SimOptions {
    /// Service prefix (None: the service config's).
    pub prefix: Option<String>,
    /// Write one truth row per cycle to this CSV.
    pub truth: Option<PathBuf>,
    /// Pace at the robot's rate instead of answering in lockstep.
    pub realtime: bool,
    /// Write the run's counters and the state → command round trip as JSON to this file.
    pub stats: Option<PathBuf>,
    /// Exit after this long without a command once commands have come (s); 0: never.
    pub exit_after_silence: f64,
    /// Lockstep: longest wait for the answer to one JointState before cycling on (s).
    pub answer_timeout: f64,
    /// Be OptiTrack instead of publishing base poses: a NatNet server (unicast, on 127.0.0.1 at
    /// this command port) streams the base's true pose as the service config's `[tracker]
    /// rigid_body` at the sim config's tracker rate and latency, for `strand-natnet` to publish.
    /// Needs `realtime` (NatNet's stamps are `CLOCK_MONOTONIC`, as the sim's clock then is).
    pub motive: Option<u16>,
}

/// The base's true pose as Motive would stream it (Z up, as `[tracker] up_axis = "z"`): a short
/// history on `CLOCK_MONOTONIC` (ns) that the NatNet server reads at each frame's mid-exposure.
type PoseHistory = std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<(u64, [f64; 3], [f64; 4])>>>;

/// Starts the NatNet server of [`SimOptions::motive`] streaming `history`.
fn start_motive(port: u16, cfg: &Config, sim_cfg: &SimConfig, history: &PoseHistory) -> Result<strand_natnet::fake::FakeMotive> {
    use strand_natnet::fake::{FakeConfig, FakeMotive};
    let body = cfg.tracker.as_ref().map_or_else(|| "base".to_string(), |t| t.rigid_body.clone());
    let (h, started) = (history.clone(), monotonic_ns());
    let trajectory = move |t: f64| {
        let at = started + (t.max(0.0) * 1e9) as u64;
        let h = h.lock().unwrap_or_else(|e| e.into_inner());
        // The pose at or just before the frame's mid-exposure (the newest if it is later).
        let i = h.partition_point(|(ns, _, _)| *ns <= at);
        h.get(i.saturating_sub(1)).map_or(([0.0; 3], [0.0, 0.0, 0.0, 1.0]), |(_, p, q)| (*p, *q))
    };
    let fake = FakeConfig {
        version: strand_natnet::protocol::Version([4, 1, 0, 0]),
        bodies: vec![(body, 1)],
        multicast: None,
        rate_hz: sim_cfg.tracker.rate_hz,
        clock_hz: 10_000_000,
        latency: sim_cfg.tracker.latency,
        untracked: 0..0,
        silent: false,
        trajectory: std::sync::Arc::new(trajectory),
    };
    FakeMotive::start(fake, port).map_err(|e| ToolError::Usage(format!("--motive {port}: {e}")))
}

/// Runs the plant against the service named by `opts.prefix` (None: the config's) until `stop` is
/// set or the service has been silent for `opts.exit_after_silence`; writes the truth and the stats
/// as `opts` asks, and prints its counters on stderr.
pub fn run(opts: &SimOptions, cfg: &Config, sim_cfg: &SimConfig, stop: &AtomicBool) -> Result<()> {
    let model = cfg.robot.build_model()?;
    let start: Vec<f64> =
        (0..model.dof()).map(|i| cfg.service.initial_joints.get(i).copied().unwrap_or_else(|| model.limits(i).middle())).collect();
    let start_ns = monotonic_ns();
    let mut sim = Sim::new(cfg, sim_cfg, &start, start_ns)?;
    let prefix = opts.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
    // A flyer without a trajectory by the clock is the base controller the service's
    // `BaseCommand` is for.
    let motive_poses: Option<PoseHistory> = opts.motive.map(|_| Default::default());
    let _motive = match (opts.motive, &motive_poses) {
        (Some(port), Some(h)) => {
            if !opts.realtime {
                return Err(ToolError::Usage("--motive needs --realtime: NatNet's stamps are the wall's monotonic clock".into()));
            }
            Some(start_motive(port, cfg, sim_cfg, h)?)
        }
        _ => None,
    };
    let ports = ClientPorts::open(
        &ServiceNames::new(&prefix),
        "strand-sim",
        ClientRoles {
            driver: true,
            tracker: opts.motive.is_none(),
            monitor: true,
            base: sim.takes_base_commands(),
            heater: true,
            ..Default::default()
        },
    )?;
    let truth_path = opts.truth.clone().unwrap_or_default();
    let mut truth_out = match &opts.truth {
        Some(p) => {
            let f = File::create(p).map_err(ToolError::file(p))?;
            let mut w = BufWriter::with_capacity(1 << 20, f);
            writeln!(w, "{}", Truth::CSV_HEADER).map_err(ToolError::file(p))?;
            Some(w)
        }
        None => None,
    };
    let mut timer = TimerClock::new(sim.dt_ns(), 0, u64::MAX);
    if opts.realtime {
        timer.start(monotonic_ns());
    }
    let answer_timeout = Duration::from_secs_f64(opts.answer_timeout);
    let mut state_seq = 0u64;
    let mut pose_seq = 0u64;
    let mut poses = Vec::new();
    let mut last_command: Option<Instant> = None;
    let (mut cycles, mut answered, mut unanswered) = (0u64, 0u64, 0u64);
    let started = Instant::now();
    let mut round_trip = Histogram::new();
    let mut thermal = ThermalModel::new(&cfg.thermal);
    let (mut hot_end_target, mut bed_target) = (0.0, 0.0);
    let heater_every = (10_000_000 / sim.dt_ns().max(1)).max(1);
    let mut heater_seq = 0u64;
    while !stop.load(Ordering::Relaxed) {
        // The heaters' measurement every 10 ms, before the JointState that wakes the service.
        if cycles.is_multiple_of(heater_every) {
            heater_seq += 1;
            ports.send_heater_state(&thermal.state(heater_seq, sim.time_ns()))?;
        }
        // Tracking first: the JointState that follows wakes the service, which then drains both.
        poses.clear();
        sim.base_poses(&mut pose_seq, &mut poses);
        match &motive_poses {
            None => {
                for p in &poses {
                    ports.send_base_pose(p)?;
                }
            }
            Some(h) => {
                let (p, q) = sim.base_pose();
                let mut h = h.lock().unwrap_or_else(|e| e.into_inner());
                h.push_back((sim.time_ns(), [p.x, p.y, p.z], [q.i, q.j, q.k, q.w]));
                while h.len() > 2000 {
                    h.pop_front();
                }
            }
        }
        state_seq += 1;
        let js = sim.joint_state(state_seq);
        let sent = Instant::now();
        ports.send_joint_state(&js)?;
        // The answer: lockstep waits for the command that answers this state; real time sleeps
        // to the next cycle and takes whatever came.
        let mut answer_tick = None;
        if opts.realtime {
            timer.wait();
            drain_commands(&ports, &mut sim, state_seq, &mut answer_tick)?;
        } else {
            let deadline = Instant::now() + answer_timeout;
            loop {
                drain_commands(&ports, &mut sim, state_seq, &mut answer_tick)?;
                if answer_tick.is_some() || stop.load(Ordering::Relaxed) {
                    break;
                }
                let now = Instant::now();
                if now >= deadline {
                    break;
                }
                let _ = ports.wait_joint_command((deadline - now).as_nanos().min(5_000_000) as u64);
            }
        }
        // The extruder command of the same tick is published right after the joint command: wait
        // for it (in lockstep as long as for the answer itself; paced, 2 ms). A cycle run without it
        // would repeat the last rate and the next would skip one — a velocity-driven drive pushing
        // a tick's filament twice or never, which at a start (pressure advance's short push) shows
        // in the bead as a blob or a gap that is the loaded machine's, not the controller's.
        if let Some(tick) = answer_tick {
            if !opts.realtime {
                round_trip.record(sent.elapsed().as_nanos() as u64);
            }
            answered += 1;
            last_command = Some(Instant::now());
            let until = Instant::now() + if opts.realtime { Duration::from_millis(2) } else { answer_timeout };
            let mut got = false;
            while !got && Instant::now() < until {
                while let Ok(Some(e)) = ports.receive_extruder_command() {
                    sim.command_extruder(&e);
                    got |= e.tick >= tick;
                }
                if !got {
                    std::hint::spin_loop();
                }
            }
        } else {
            unanswered += 1;
            while let Ok(Some(e)) = ports.receive_extruder_command() {
                sim.command_extruder(&e);
            }
        }
        if let Some(b) = ports.latest_base_command() {
            sim.command_base(&b);
        }
        if let Some(h) = ports.latest_heater_command() {
            (hot_end_target, bed_target) = (h.hot_end_target, h.bed_target);
        }
        thermal.step(hot_end_target, bed_target, sim.dt_ns() as f64 * 1e-9);
        let _ = ports.receive_status();
        let truth = sim.step();
        cycles += 1;
        if let Some(w) = truth_out.as_mut() {
            writeln!(w, "{}", truth.csv_row()).map_err(ToolError::file(&truth_path))?;
        }
        if opts.exit_after_silence > 0.0 && last_command.is_some_and(|t| t.elapsed().as_secs_f64() > opts.exit_after_silence) {
            eprintln!("strand-sim: no command for {} s: the service has gone", opts.exit_after_silence);
            break;
        }
    }
    if let Some(mut w) = truth_out {
        w.flush().map_err(ToolError::file(&truth_path))?;
    }
    let wall = started.elapsed().as_secs_f64();
    let sim_s = (sim.time_ns() - start_ns) as f64 * 1e-9;
    eprintln!(
        "strand-sim: {cycles} cycles, {sim_s:.2} s simulated in {wall:.2} s ({:.1}× real time), {answered} answered, {unanswered} without an answer",
        sim_s / wall.max(1e-9)
    );
    if let Some((measured, dropped)) = sim.tracker_counts() {
        eprintln!("strand-sim: tracker {measured} samples, {dropped} dropped");
    }
    if round_trip.count() > 0 {
        eprintln!(
            "strand-sim: JointState → JointCommand round trip p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
            round_trip.percentile(50.0) as f64 * 1e-3,
            round_trip.percentile(99.0) as f64 * 1e-3,
            round_trip.max() as f64 * 1e-3
        );
    }
    if let Some(p) = &opts.stats {
        let (measured, dropped) = sim.tracker_counts().unwrap_or((0, 0));
        let stats = serde_json::json!({
            "cycles": cycles,
            "answered": answered,
            "unanswered": unanswered,
            "sim_s": sim_s,
            "wall_s": wall,
            "tracker_samples": measured,
            "tracker_dropped": dropped,
            "round_trip": {
                "samples": round_trip.count(),
                "p50_ns": round_trip.percentile(50.0),
                "p99_ns": round_trip.percentile(99.0),
                "p999_ns": round_trip.percentile(99.9),
                "max_ns": round_trip.max(),
            },
        });
        std::fs::write(p, format!("{stats:#}\n")).map_err(ToolError::file(p))?;
    }
    Ok(())
}

/// Applies every joint command that arrived; notes the tick of the one answering `state_seq`.
fn drain_commands(ports: &ClientPorts, sim: &mut Sim, state_seq: u64, answer_tick: &mut Option<u64>) -> Result<()> {
    while let Some(cmd) = ports.receive_joint_command()? {
        sim.command_joints(&cmd);
        if cmd.state_seq >= state_seq {
            *answer_tick = Some(cmd.tick);
        }
    }
    Ok(())
}
