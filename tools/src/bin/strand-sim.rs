//! strand-sim: a separate process that is the robot, its base, the base's tracker and the
//! extruder, talking to the service over iceoryx2 as the real drivers would. Its JointStates drive
//! the service's `robot` clock; `--lockstep` (the default) answers each command as soon as it
//! arrives, so a job runs as fast as the two processes can exchange messages — usually many times
//! faster than real time — with every stamp on the sim's own clock. `--realtime` paces it at the
//! robot's rate instead. It writes the truth (actual nozzle, base, melt flow) as CSV for the demo.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use strand::config::{Config, locate};
use strand::io::clock::{TimerClock, monotonic_ns};
use strand::io::histogram::Histogram;
use strand_ipc::ServiceNames;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_tools::sim::config::SimConfig;
use strand_tools::sim::{Sim, Truth};

#[derive(Parser)]
#[command(name = "strand-sim", version, about = "Simulated robot, free-flying base, tracker and extruder for the strand service")]
struct Cli {
    /// Service configuration: robot, rate, base mode and mount, prefix. A file or a NAME (`iiwa7`);
    /// default: default.toml by the search order ($STRAND_CONFIG_DIR, ./config,
    /// <prefix>/share/strand/config, the built-in copy).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Plant configuration (lags, noise, tracker, flyer); default: sim/free-flyer.toml for a
    /// tracked base, sim/default.toml otherwise, next to --config's folder or else by the search
    /// order.
    #[arg(long)]
    sim: Option<PathBuf>,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Write one truth row per cycle to this CSV.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Pace at the robot's rate (clock_nanosleep) instead of answering in lockstep.
    #[arg(long)]
    realtime: bool,
    /// Write the run's counters and the state → command round trip as JSON to this file.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Seed of the plant's noise (overrides the sim config's).
    #[arg(long)]
    seed: Option<u64>,
    /// Exit after this many seconds without a command once commands have come (the service has
    /// gone); 0: never.
    #[arg(long, default_value_t = 2.0)]
    exit_after_silence: f64,
    /// Lockstep: longest wait for the answer to one JointState before cycling on (s).
    #[arg(long, default_value_t = 0.05)]
    answer_timeout: f64,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let cfg = match locate::service_config(cli.config.as_deref()).and_then(|c| Config::load(&c)) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-sim: {e}");
            return ExitCode::from(2);
        }
    };
    let sim_path = match &cli.sim {
        Some(p) => locate::explicit(p).map_err(|e| e.to_string()),
        None => SimConfig::default_path(&cfg),
    };
    let mut sim_cfg = match sim_path.and_then(|p| SimConfig::load(&p).map_err(|e| e.to_string())) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-sim: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(s) = cli.seed {
        sim_cfg.seed = s;
    }
    // SAFETY: the handler only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    match run(&cli, &cfg, &sim_cfg) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-sim: {e}");
            ExitCode::from(1)
        }
    }
}

fn run(cli: &Cli, cfg: &Config, sim_cfg: &SimConfig) -> Result<(), String> {
    let model = cfg.robot.build_model().map_err(|e| e.to_string())?;
    let start: Vec<f64> =
        (0..model.dof()).map(|i| cfg.service.initial_joints.get(i).copied().unwrap_or_else(|| model.limits(i).middle())).collect();
    let start_ns = monotonic_ns();
    let mut sim = Sim::new(cfg, sim_cfg, &start, start_ns)?;
    let prefix = cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
    let ports = ClientPorts::open(
        &ServiceNames::new(&prefix),
        "strand-sim",
        ClientRoles { driver: true, tracker: true, monitor: true, ..Default::default() },
    )
    .map_err(|e| e.to_string())?;
    let mut truth_out = match &cli.truth {
        Some(p) => {
            let f = File::create(p).map_err(|e| format!("{}: {e}", p.display()))?;
            let mut w = BufWriter::with_capacity(1 << 20, f);
            writeln!(w, "{}", Truth::CSV_HEADER).map_err(|e| format!("{}: {e}", p.display()))?;
            Some(w)
        }
        None => None,
    };
    let mut timer = TimerClock::new(sim.dt_ns(), 0, u64::MAX);
    if cli.realtime {
        timer.start(monotonic_ns());
    }
    let answer_timeout = Duration::from_secs_f64(cli.answer_timeout);
    let mut state_seq = 0u64;
    let mut pose_seq = 0u64;
    let mut poses = Vec::new();
    let mut last_command: Option<Instant> = None;
    let (mut cycles, mut answered, mut unanswered) = (0u64, 0u64, 0u64);
    let started = Instant::now();
    let mut round_trip = Histogram::new();
    while !STOP.load(Ordering::Relaxed) {
        // Tracking first: the JointState that follows wakes the service, which then drains both.
        poses.clear();
        sim.base_poses(&mut pose_seq, &mut poses);
        for p in &poses {
            ports.send_base_pose(p).map_err(|e| e.to_string())?;
        }
        state_seq += 1;
        let js = sim.joint_state(state_seq);
        let sent = Instant::now();
        ports.send_joint_state(&js).map_err(|e| e.to_string())?;
        // The answer: lockstep waits for the command that answers this state; real time sleeps
        // to the next cycle and takes whatever came.
        let mut answer_tick = None;
        if cli.realtime {
            timer.wait();
            drain_commands(&ports, &mut sim, state_seq, &mut answer_tick)?;
        } else {
            let deadline = Instant::now() + answer_timeout;
            loop {
                drain_commands(&ports, &mut sim, state_seq, &mut answer_tick)?;
                if answer_tick.is_some() || STOP.load(Ordering::Relaxed) {
                    break;
                }
                let now = Instant::now();
                if now >= deadline {
                    break;
                }
                let _ = ports.wait_joint_command((deadline - now).as_nanos().min(5_000_000) as u64);
            }
        }
        // The extruder command of the same tick is published right after the joint command.
        if let Some(tick) = answer_tick {
            if !cli.realtime {
                round_trip.record(sent.elapsed().as_nanos() as u64);
            }
            answered += 1;
            last_command = Some(Instant::now());
            let until = Instant::now() + Duration::from_millis(2);
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
        let _ = ports.receive_status();
        let truth = sim.step();
        cycles += 1;
        if let Some(w) = truth_out.as_mut() {
            writeln!(w, "{}", truth.csv_row()).map_err(|e| format!("truth: {e}"))?;
        }
        if cli.exit_after_silence > 0.0 && last_command.is_some_and(|t| t.elapsed().as_secs_f64() > cli.exit_after_silence) {
            eprintln!("strand-sim: no command for {} s: the service has gone", cli.exit_after_silence);
            break;
        }
    }
    if let Some(mut w) = truth_out {
        w.flush().map_err(|e| format!("truth: {e}"))?;
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
    if let Some(p) = &cli.stats {
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
        std::fs::write(p, format!("{stats:#}\n")).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    Ok(())
}

/// Applies every joint command that arrived; notes the tick of the one answering `state_seq`.
fn drain_commands(ports: &ClientPorts, sim: &mut Sim, state_seq: u64, answer_tick: &mut Option<u64>) -> Result<(), String> {
    while let Some(cmd) = ports.receive_joint_command().map_err(|e| e.to_string())? {
        sim.command_joints(&cmd);
        if cmd.state_seq >= state_seq {
            *answer_tick = Some(cmd.tick);
        }
    }
    Ok(())
}
