//! The cell end to end, as separate processes over iceoryx2: the service on the robot clock,
//! strand-sim as the robot (and the free flyer), strand-feed streaming G-code, and strand-demo
//! running all three.
//!
//! - the demo runs a short job to the end; the sim's truth puts the nozzle within a stated bound of
//!   the path; the MCAP log replays identically; nothing was dropped or rejected;
//! - the feeder killed mid-job → a controlled stop on the path, no fault;
//! - the sim killed mid-job → the service faults (JointStateLost);
//! - the free flyer prints a small truss on its drifting, tracked base within a stated bound;
//! - a bad job stops the demo before anything starts, naming file and line; a child that fails
//!   (the sim refusing its plant) stops the demo at once with that child's own message, and no log
//!   of idle ticks is left behind.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use strand_testkit::{Reaped, bin, json_f64, root, square_program, temp_dir};

use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{FaultCode, JobOutcome, RunState, ServiceNames, Status};

/// The approach at full joint speed: seconds of robot time saved in every test (debug builds are slow).
const FAST_APPROACH: &str = "controller.approach_speed_fraction=1.0";

fn demo(dir: &Path, args: &[&str]) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_strand-demo"))
        .args(args)
        .arg("--json")
        .arg("--out")
        .arg(dir.join("demo"))
        .current_dir(root())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "stdout: {stdout}\nstderr: {stderr}");
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

#[test]
fn the_demo_prints_a_short_job_within_bounds_and_its_log_replays_identically() {
    let dir = temp_dir("sim", "demo");
    let program = square_program(&dir, 2, 3, 2400.0);
    let r = demo(&dir, &["--gcode", program.to_str().unwrap(), "--set", FAST_APPROACH]);
    assert_eq!(r["job_outcome"], "Finished", "{r}");
    assert_eq!(r["identical"], true, "{r}");
    assert!(r["verify"].as_str().unwrap().starts_with("identical"));
    // 2 × (travel + 12 lines) = 26 segments, every one accepted.
    assert_eq!(json_f64(&r, &["segments_accepted"]), 26.0);
    assert_eq!(json_f64(&r, &["segments_rejected"]), 0.0);
    assert_eq!(json_f64(&r, &["log_drops"]), 0.0);
    assert_eq!(json_f64(&r, &["unmatched"]), 0.0, "every target has its truth row (lockstep)");
    assert!(r["faults"].as_array().unwrap().is_empty());
    // The bound: the sim's 1-cycle dead time and 2 ms lag at 40 mm/s are about 0.12 mm of path;
    // corners add the CLIK's transient. Mean under 0.2 mm, worst under 0.5 mm.
    let ticks = json_f64(&r, &["tcp_error_m", "samples"]);
    assert!(ticks > 1500.0, "{ticks} ticks on the path");
    assert!(json_f64(&r, &["tcp_error_m", "mean"]) < 0.2e-3, "{r}");
    assert!(json_f64(&r, &["tcp_error_m", "max"]) < 0.5e-3, "{r}");
    // Extrusion reached the nozzle: deposited within 5 % of commanded (the melt lag's tail is cut).
    let v = json_f64(&r, &["volume_ratio"]);
    assert!((0.95..=1.001).contains(&v), "volume ratio {v}");
    // The bead is measured and reported (its figures are judged in the closed-loop test,
    // `bead::bead_tests`: here, in a debug build on a loaded machine, a late extruder command
    // makes the sim run a cycle on the one before, and a pressure-advance push goes missing).
    assert!(json_f64(&r, &["bead", "all", "bins"]) > 200.0, "{}", r["bead"]);
    assert!(json_f64(&r, &["bead", "all", "p50"]) < 0.02, "{}", r["bead"]);
    assert!(json_f64(&r, &["bead", "blob_m3"]) < 0.002 * json_f64(&r, &["bead", "melt_m3"]), "{}", r["bead"]);
    assert!(Path::new(r["log"].as_str().unwrap()).is_file());
}

#[test]
fn the_free_flyer_prints_a_truss_while_its_base_drifts() {
    // 000's cell: the Meca500 on the air-bearing base, tracked at 120 Hz with noise and dropouts, the
    // base pushed by the residual field, the arm's reaction and the filament tension while its PID
    // holds station. A small truss (one 20 mm panel, 210 mm of strand at 20 mm/s) made by strand-plan.
    let dir = temp_dir("sim", "free-flyer");
    let job = small_truss(&dir);
    // The cell's own approach speed (0.3 of the joint limits), not the other tests' FAST_APPROACH: at full
    // speed the arm's reaction kicks the floating base 1.7 mm, and the alpha-beta estimate (alpha 0.04 at
    // 120 Hz) overshoots it by 0.4 mm for a second into the path: 0.58 mm worst, 0.60 on a loaded CI
    // machine. At 0.3 the worst is 0.46 mm.
    let r = demo(&dir, &["--config", "config/free-flyer.toml", "--gcode", job.to_str().unwrap()]);
    assert_eq!(r["job_outcome"], "Finished", "{r}");
    assert_eq!(r["identical"], true, "{r}");
    assert_eq!(json_f64(&r, &["segments_rejected"]), 0.0);
    assert_eq!(json_f64(&r, &["unmatched"]), 0.0);
    assert!(r["faults"].as_array().unwrap().is_empty(), "{r}");
    // The base really moved under the arm: it strays from its planned pose by millimetres.
    assert!(json_f64(&r, &["base_error_m", "max"]) > 0.5e-3, "{r}");
    // ... and the nozzle stays on the path: the sim's 1-cycle dead time and 2 ms lag at 20 mm/s are
    // 0.06 mm; tracking noise (0.15 mm, 0.5 mrad) filtered by the estimator adds about as much.
    // Mean under 0.2 mm, worst under 0.6 mm (000 reports 0.26 mm dry, 0.75 mm printing).
    assert!(json_f64(&r, &["tcp_error_m", "samples"]) > 9000.0, "{r}");
    assert!(json_f64(&r, &["tcp_error_m", "mean"]) < 0.2e-3, "{r}");
    assert!(json_f64(&r, &["tcp_error_m", "max"]) < 0.6e-3, "{r}");
    // Job time near the feed-rate bound: 210 mm at 20 mm/s is 10.5 s; corners and the start cost a little.
    let t = json_f64(&r, &["job_time_s"]);
    assert!((10.5..14.0).contains(&t), "job time {t} s");
}

/// The 200 mm truss at 20 mm/s (72 s of robot time) on the free flyer, its base planned by
/// `strand-plan base --plan` (000's Algorithm 1 with a 250 mm reach limit) and commanded by the
/// service at the print's progress. The operator pauses it for 30 s where the arm reaches furthest
/// and resumes it at half the feed. A base on its planned *time* ran on during both and left the
/// arm's reach (the 100 cm truss faulted on one override); by progress the base stops and slows
/// with the nozzle, and the print finishes on its path.
#[test]
fn a_moving_base_print_survives_a_pause_and_a_feed_override_where_the_arm_reaches_furthest() {
    // 150 s of robot time and its replay: 13 s optimised, 220 s unoptimised. CI runs it in its
    // release stage; a debug build runs it with STRAND_DEBUG_CELLS=1.
    if skipped_in_debug("a_moving_base") {
        return;
    }
    let dir = temp_dir("sim", "moving-base-operator");
    let job = dir.join("truss.gcode");
    let run = |args: &[&str]| {
        let out = Command::new(bin("strand-plan")).args(args).current_dir(root()).output().unwrap();
        assert!(out.status.success(), "strand-plan {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        out
    };
    run(&["truss", "--length", "0.2", "--width", "0.04", "--speed", "0.02", "-o", job.to_str().unwrap()]);
    let (plan, series) = (dir.join("plan.csv"), dir.join("series.csv"));
    let (r_nom, direction_deg) = (0.2326, -115.46f64);
    run(&[
        "base",
        job.to_str().unwrap(),
        "--config",
        "config/free-flyer.toml",
        "--r-nom",
        &r_nom.to_string(),
        "--direction-deg",
        &direction_deg.to_string(),
        "--reach-limit",
        "0.25",
        "--fc-start",
        "0.5",
        "--fc-step",
        "0.005",
        "--plan",
        plan.to_str().unwrap(),
        "--csv",
        series.to_str().unwrap(),
    ]);
    // Where the plan has the arm reach furthest: its time into the path at the planned timing.
    let text = std::fs::read_to_string(&series).unwrap();
    let rows: Vec<Vec<f64>> = text.lines().skip(1).map(|l| l.split(',').map(|x| x.parse().unwrap()).collect()).collect();
    let offset = [-r_nom * direction_deg.to_radians().cos(), -r_nom * direction_deg.to_radians().sin()];
    let reach = |r: &Vec<f64>| (r[1] - r[3] - offset[0]).hypot(r[2] - r[4] - offset[1]);
    let start = rows.iter().find(|r| r[5] >= 0.0).unwrap()[0];
    let worst = rows.iter().filter(|r| r[5] >= 0.0).max_by(|a, b| reach(a).total_cmp(&reach(b))).unwrap();
    let at = (worst[0] - start).max(1.0);
    let base_moves = rows.iter().map(|r| (r[3] - rows[0][3]).hypot(r[4] - rows[0][4])).fold(0.0, f64::max);
    assert!(base_moves > 0.05, "the plan moves the base {:.1} mm: too little to test", base_moves * 1e3);
    let plan_set = format!("base.plan_file={}", plan.display());
    let (pause, resume, slow) = (format!("{at:.1}:pause"), format!("{:.1}:resume", at + 30.0), format!("{:.1}:feed 50", at + 30.0));
    let r = demo(
        &dir,
        &[
            "--config",
            "config/free-flyer.toml",
            "--gcode",
            job.to_str().unwrap(),
            "--set",
            &plan_set,
            "--operator",
            &pause,
            "--operator",
            &resume,
            "--operator",
            &slow,
            "--timeout",
            "900",
        ],
    );
    eprintln!("{r:#}");
    assert_eq!(r["job_outcome"], "Finished", "{r}");
    assert_eq!(r["identical"], true, "{r}");
    assert_eq!(r["operator"].as_array().unwrap().len(), 3, "{r}");
    assert!(r["faults"].as_array().unwrap().is_empty(), "{r}");
    // The pause and the half feed cost their time: 72 s at the full feed.
    let t = json_f64(&r, &["job_time_s"]);
    assert!(t > 72.0 + 30.0 + 10.0, "job time {t} s");
    // The setpoint kept to its plan within millimetres (3.9 mm measured: the path's stops and
    // starts ask more of the base than its 20 mm/s² give; the flyer itself strays up to 31 mm
    // from the setpoint, its PID being 000's).
    assert!(json_f64(&r, &["base_lag_m", "max"]) < 6e-3, "{r}");
    // The arm stayed near the plan's 250 mm reach limit (251.1 mm measured; on the planned time
    // the same print without an operator reached 261 mm, and with one it faulted).
    assert!(json_f64(&r, &["reach_m", "max"]) < 0.255, "{r}");
    // ... and the nozzle on its path: 0.20 mm mean, 1.36 mm worst measured (by the clock, without
    // the pause: 0.40 / 1.32 mm). The base moves at up to 14 mm/s, and the estimate (α 0.04)
    // trails it.
    assert!(json_f64(&r, &["tcp_error_m", "mean"]) < 0.3e-3, "{r}");
    assert!(json_f64(&r, &["tcp_error_m", "max"]) < 1.7e-3, "{r}");
}

#[test]
fn the_turntable_cell_prints_the_helix_cylinder_through_a_pause_and_a_feed_override_with_the_bead_on_the_part() {
    // 360 s of robot time and its replay: 8 s optimised, minutes unoptimised. CI runs it in
    // its release stage; a debug build runs it with STRAND_DEBUG_CELLS=1.
    if skipped_in_debug("the_turntable") {
        return;
    }
    // cells/kr6-turntable: the KR 6 beside a rotary table, its default job the 600 mm cylinder as
    // one helix of 4 turns (1,443 segments, each with the table's C; its far side out of the arm's
    // reach), the nozzle staying beside the table while the part turns under it. The operator
    // pauses 30 s in for 10 s, then halves the feed.
    let dir = temp_dir("sim", "turntable");
    let r = demo(
        &dir,
        &[
            "--config",
            "config/cells/kr6-turntable.toml",
            "--operator",
            "30:pause",
            "--operator",
            "40:resume",
            "--operator",
            "40:feed 50",
            "--timeout",
            "600",
        ],
    );
    eprintln!("{r:#}");
    assert_eq!(r["job_outcome"], "Finished", "{r}");
    assert_eq!(r["identical"], true, "{r}");
    assert!(r["faults"].as_array().unwrap().is_empty(), "{r}");
    assert_eq!(json_f64(&r, &["segments_accepted"]), 1443.0);
    // 188.5 s of helix at 40 mm/s: 30 s of it, the 10 s pause, the rest at half speed (317 s);
    // measured 362.1 s.
    let t = json_f64(&r, &["job_time_s"]);
    assert!(t > 340.0 && t < 385.0, "job time {t} s");
    // On the part (the target brought back by the commanded table angle, the nozzle by the
    // actual one): the table's dead time and lag at 40 mm/s over the part put the nozzle 0.18 mm
    // behind, half that at half the feed (measured 0.099 mm mean, 0.185 mm worst); the fixed box on
    // the same arm measures 0.14 / 0.56 mm. Bounds: those of the box demo above.
    assert!(json_f64(&r, &["tcp_error_m", "mean"]) < 0.2e-3, "{r}");
    assert!(json_f64(&r, &["tcp_error_m", "max"]) < 0.5e-3, "{r}");
    // The bead, measured on the part along the helix (1.885 m a turn: over 7,000 bins of 1 mm):
    // the box's aims (p50 within 2 %, under 4 % of bins beyond ±10 %, no blobs to speak of).
    assert!(json_f64(&r, &["bead", "all", "bins"]) > 7000.0, "{}", r["bead"]);
    assert!(json_f64(&r, &["bead", "all", "p50"]) < 0.02, "{}", r["bead"]);
    assert!(json_f64(&r, &["bead", "all", "beyond_10pct"]) < 0.04, "{}", r["bead"]);
    assert!(json_f64(&r, &["bead", "blob_m3"]) < 0.002 * json_f64(&r, &["bead", "melt_m3"]), "{}", r["bead"]);
}

/// CELL item 5: the bundled cell `config/cells/free-flyer-optitrack.toml` with every process of
/// it — the service on the robot's clock, strand-sim as the arm and the free flyer *and* as Motive
/// (`--motive`: a NatNet server streaming the flyer's true pose; the sim publishes no base pose of
/// its own), strand-natnet publishing what Motive streams, strand-feed — on the truss of the
/// free-flyer test above, in real time (NatNet's stamps are the wall's clock). The job finishes on
/// the poses strand-natnet published, and the bead (the demo's metric, the sim's truth) holds.
#[test]
fn the_free_flyer_cell_prints_on_the_base_pose_optitrack_streams() {
    if skipped_in_debug("the_free_flyer_cell") {
        return;
    }
    let dir = temp_dir("sim", "free-flyer-optitrack");
    let job = small_truss(&dir);
    let config = "config/cells/free-flyer-optitrack.toml";
    let prefix = format!("strand/optitrack-{}", std::process::id());
    let port = std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let logged = |c: &mut Command, name: &str| {
        c.current_dir(root()).env("RUST_LOG", "warn").stdout(Stdio::null()).stderr(std::fs::File::create(dir.join(name)).unwrap());
    };
    let log = dir.join("run.mcap");
    let mut service = Command::new(bin("strand"));
    service.args(["run", "--clock", "robot", "--config", config, "--prefix", &prefix, "--log"]).arg(&log);
    logged(&mut service, "service.log");
    let mut service = Reaped(service.spawn().unwrap());
    let monitor =
        ClientPorts::open(&ServiceNames::new(&prefix), "test-monitor", ClientRoles { monitor: true, ..Default::default() }).unwrap();
    wait_for(&monitor, 30, "the service ticking without a robot", |s| s.tick > 3);
    let truth = dir.join("truth.csv");
    let mut sim = Command::new(bin("strand-sim"));
    sim.args(["--config", config, "--sim", "config/sim/free-flyer.toml", "--prefix", &prefix, "--realtime", "--motive"])
        .arg(port.to_string())
        .arg("--truth")
        .arg(&truth);
    logged(&mut sim, "sim.log");
    let mut sim = Reaped(sim.spawn().unwrap());
    let mut natnet = Command::new(bin("strand-natnet"));
    natnet
        .args(["--config", config, "--prefix", &prefix, "--set", &format!("tracker.command_port={port}"), "--stats"])
        .arg(dir.join("natnet.json"));
    logged(&mut natnet, "natnet.log");
    let mut natnet = Reaped(natnet.spawn().unwrap());
    let said = |dir: &Path| {
        ["service.log", "sim.log", "natnet.log", "feed.log"]
            .iter()
            .map(|f| format!("--- {f}:\n{}", std::fs::read_to_string(dir.join(f)).unwrap_or_default()))
            .collect::<Vec<_>>()
            .join("\n")
    };
    let mut feed = Command::new(bin("strand-feed"));
    feed.arg(&job).args(["--config", config, "--prefix", &prefix, "--quiet", "--wait-service", "20"]);
    logged(&mut feed, "feed.log");
    let mut feed = Reaped(feed.spawn().unwrap());
    let code = exit_code_within(&mut feed, 120, &monitor);
    let status = monitor.latest_status();
    assert_eq!(code, Some(0), "strand-feed: {status:?}\n{}", said(&dir));
    natnet.signal(libc::SIGTERM);
    assert_eq!(natnet.wait_until(Instant::now() + Duration::from_secs(10)), Some(0), "{}", said(&dir));
    service.signal(libc::SIGTERM);
    let _ = service.wait_until(Instant::now() + Duration::from_secs(20));
    sim.signal(libc::SIGTERM);
    let _ = sim.wait_until(Instant::now() + Duration::from_secs(10));
    let stats: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("natnet.json")).unwrap()).unwrap();
    let published = stats["counters"]["published"].as_u64().unwrap();
    let log = strand::log::reader::LogFile::open(&log).unwrap();
    let truth = strand_replay::truth::read_truth(&truth).unwrap();
    let bead = strand_replay::bead::measure(&log, &truth, None).unwrap();
    // The base's poses came from Motive through strand-natnet: as many as the tracker's rate.
    let mut poses = 0u64;
    let mut outcome = None;
    for tick in log.ticks() {
        let tick = tick.unwrap();
        poses += tick.input.base_poses().len() as u64;
        if tick.output.status.job_outcome == JobOutcome::Finished as u32 {
            outcome = Some(JobOutcome::Finished);
        }
    }
    let base_moved = truth.iter().map(|t| (t.base[0] - truth[0].base[0]).hypot(t.base[1] - truth[0].base[1])).fold(0.0, f64::max);
    eprintln!(
        "free-flyer-optitrack: strand-natnet published {published} poses, the service took {poses}; the base moved {:.2} mm; bead {} bins: \
         p50 {:.1} %, p95 {:.1} %, {:.2} % beyond ±10 %; natnet {}",
        base_moved * 1e3,
        bead.all.bins,
        100.0 * bead.all.p50,
        100.0 * bead.all.p95,
        100.0 * bead.all.beyond_10pct,
        stats
    );
    assert_eq!(outcome, Some(JobOutcome::Finished), "{}", said(&dir));
    assert!(published > 1000 && poses > 1000, "{published} published, {poses} taken");
    assert!(base_moved > 0.5e-3, "the base moved under the arm: {base_moved}");
    assert!(bead.all.bins > 150, "{} bins", bead.all.bins);
    assert!(bead.all.p50 < 0.03, "bead p50 {}", bead.all.p50);
    assert!(bead.all.beyond_10pct < 0.10, "{} of the bins beyond ±10 %", bead.all.beyond_10pct);
}

/// A cell test that only an optimised build runs in real time (CI's release stage): true, saying
/// so, in a debug build unless `STRAND_DEBUG_CELLS=1`.
fn skipped_in_debug(filter: &str) -> bool {
    let skip = cfg!(debug_assertions) && std::env::var_os("STRAND_DEBUG_CELLS").is_none_or(|v| v != "1");
    if skip {
        eprintln!("skipped in a debug build (cargo test --release -p strand-sim --test sim {filter}, or STRAND_DEBUG_CELLS=1)");
    }
    skip
}

/// A small truss made by strand-plan (one 20 mm panel, 210 mm of strand at 20 mm/s), in `dir`.
fn small_truss(dir: &Path) -> std::path::PathBuf {
    let job = dir.join("truss.gcode");
    let out = Command::new(bin("strand-plan"))
        .args(["truss", "--length", "0.02", "--width", "0.02", "--pitch", "0.02", "--speed", "0.02", "-o"])
        .arg(&job)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    job
}

fn spawn(mut c: Command) -> Reaped {
    Reaped(c.current_dir(root()).env("RUST_LOG", "warn").stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap())
}

/// Service on the robot clock + sim + feeder with a long job, running on the path.
fn cell(prefix: &str, dir: &Path) -> (Reaped, Reaped, Reaped, ClientPorts) {
    let program = square_program(dir, 1, 400, 2400.0);
    let (svc, monitor) = service_without_robot(prefix);
    let sim = spawn({
        let mut c = Command::new(bin("strand-sim"));
        c.args(["--config", "config/default.toml", "--prefix", prefix]);
        c
    });
    wait_for(&monitor, 30, "the sim clocking the service", |s| s.tick > 100);
    let feeder = spawn({
        let mut c = Command::new(bin("strand-feed"));
        // Unchecked: these tests kill a process under a running job; checking 400 loops in a debug
        // build would take longer than the wait for the path.
        c.arg(&program).args(["--config", "config/default.toml", "--prefix", prefix, "--quiet", "--no-check"]);
        c
    });
    wait_for(&monitor, 120, "the job on the path", |s| s.run_state == RunState::Running as u32 && s.path_speed > 0.0);
    (svc, sim, feeder, monitor)
}

/// The service on the robot clock with no robot (it ticks on its joint-state timeout), and a monitor
/// that has seen it tick.
fn service_without_robot(prefix: &str) -> (Reaped, ClientPorts) {
    let svc = spawn({
        let mut c = Command::new(bin("strand"));
        c.args(["run", "--config", "config/default.toml", "--clock", "robot", "--no-log", "--prefix", prefix, "--set", FAST_APPROACH]);
        c
    });
    let monitor =
        ClientPorts::open(&ServiceNames::new(prefix), "test-monitor", ClientRoles { monitor: true, ..Default::default() }).unwrap();
    wait_for(&monitor, 30, "the service ticking without a robot", |s| s.tick > 3);
    (svc, monitor)
}

/// The child's exit code, waiting at most `seconds` (the test fails, with the last Status, past it).
fn exit_code_within(child: &mut Reaped, seconds: u64, m: &ClientPorts) -> Option<i32> {
    let deadline = Instant::now() + Duration::from_secs(seconds);
    loop {
        if let Some(status) = child.0.try_wait().unwrap() {
            return status.code();
        }
        assert!(Instant::now() < deadline, "still running after {seconds} s: {:?}", m.latest_status());
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn wait_for(m: &ClientPorts, seconds: u64, what: &str, until: impl Fn(&Status) -> bool) -> Status {
    strand_testkit::wait_for_status(m, seconds, what, until)
}

#[test]
fn a_killed_feeder_stops_the_job_under_the_sim() {
    let dir = temp_dir("sim", "feeder");
    let prefix = format!("strand/simtest-feeder-{}", std::process::id());
    let (_svc, _sim, mut feeder, m) = cell(&prefix, &dir);
    feeder.0.kill().unwrap();
    feeder.0.wait().unwrap();
    let s = wait_for(&m, 30, "a controlled stop", |s| s.job_outcome == JobOutcome::Stopped as u32 && s.run_state == RunState::Idle as u32);
    assert_eq!(s.fault, FaultCode::None as u32, "{s:?}");
    assert_eq!(s.clamps, 0);
}

#[test]
fn a_killed_sim_faults_the_service() {
    let dir = temp_dir("sim", "driver");
    let prefix = format!("strand/simtest-driver-{}", std::process::id());
    let (_svc, mut sim, _feeder, m) = cell(&prefix, &dir);
    sim.0.kill().unwrap();
    sim.0.wait().unwrap();
    let s = wait_for(&m, 10, "a fault", |s| s.run_state == RunState::Fault as u32);
    assert_eq!(s.fault, FaultCode::JointStateLost as u32, "{s:?}");
    assert_eq!(s.job_outcome, JobOutcome::Faulted as u32);
}

/// A job sent before the robot streams (the sim started late, as an operator may start EGM or RSI
/// after strand-feed): the controller refuses its Start (NotReady: where the robot is, it does not
/// know yet) and holds the job open. strand-feed asks again until the job starts, and it finishes
/// once the robot comes. It used to wait on the open job for ever.
#[test]
fn a_job_sent_before_the_robot_streams_starts_when_it_comes() {
    let dir = temp_dir("sim", "early");
    let prefix = format!("strand/simtest-early-{}", std::process::id());
    let program = square_program(&dir, 1, 2, 2400.0);
    let (_svc, monitor) = service_without_robot(&prefix);
    let mut feeder = spawn({
        let mut c = Command::new(bin("strand-feed"));
        c.arg(&program).args(["--config", "config/default.toml", "--prefix", &prefix, "--quiet", "--no-check"]);
        c
    });
    let refused = wait_for(&monitor, 60, "the start refused", |s| {
        s.job_outcome == JobOutcome::InProgress as u32 && s.rejected > 0 && s.run_state == RunState::Idle as u32
    });
    assert_eq!(refused.last_reject_reason, strand_ipc::RejectReason::NotReady as u32, "{refused:?}");
    // A second in which the feeder asks again and is refused again.
    std::thread::sleep(Duration::from_secs(1));
    let _sim = spawn({
        let mut c = Command::new(bin("strand-sim"));
        c.args(["--config", "config/default.toml", "--prefix", &prefix]);
        c
    });
    let code = exit_code_within(&mut feeder, 180, &monitor);
    assert_eq!(code, Some(0), "the job finished: {:?}", monitor.latest_status());
    let s = monitor.latest_status().unwrap();
    assert_eq!(s.job_outcome, JobOutcome::Finished as u32, "{s:?}");
}

/// A service that stops ticking with a job open (frozen here with SIGSTOP: hung, or stopped in a
/// debugger) keeps its Status publisher, so the feeder cannot see it go away. The feeder must end
/// anyway, saying why, rather than wait on the job for ever.
#[test]
fn a_service_that_stops_ticking_ends_the_feeder_with_a_named_error() {
    let dir = temp_dir("sim", "frozen");
    let prefix = format!("strand/simtest-frozen-{}", std::process::id());
    let program = square_program(&dir, 1, 2, 2400.0);
    let (mut svc, monitor) = service_without_robot(&prefix);
    let stderr = dir.join("feed.err");
    let mut feeder = Reaped(
        Command::new(bin("strand-feed"))
            .current_dir(root())
            .arg(&program)
            .args(["--config", "config/default.toml", "--prefix", &prefix, "--quiet", "--no-check"])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap(),
    );
    // The job open (its Start refused: no robot streams), the feeder asking again.
    wait_for(&monitor, 60, "the job open", |s| s.job_outcome == JobOutcome::InProgress as u32);
    // The guard's drop kills it (SIGKILL ends a stopped process).
    svc.signal(libc::SIGSTOP);
    let frozen = Instant::now();
    let code = exit_code_within(&mut feeder, 30, &monitor);
    let waited = frozen.elapsed().as_secs_f64();
    let said = std::fs::read_to_string(&stderr).unwrap();
    assert_eq!(code, Some(1), "{said}");
    assert!(said.contains("stopped ticking"), "{said}");
    // It gave the service its 5 s, and not much more.
    assert!((4.5..15.0).contains(&waited), "ended {waited:.1} s after the freeze: {said}");
}

/// strand-demo run from a scratch folder outside the repository (the built-in config).
fn demo_elsewhere(dir: &Path, args: &[&str]) -> (std::process::Output, Duration) {
    let work = dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    let started = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_strand-demo"))
        .args(args)
        .arg("--out")
        .arg(dir.join("demo"))
        .current_dir(&work)
        .env_remove("STRAND_CONFIG_DIR")
        .env("XDG_CACHE_HOME", dir.join("cache"))
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    (out, started.elapsed())
}

#[test]
fn the_demo_stops_at_once_on_a_bad_job() {
    let dir = temp_dir("sim", "demo-bad-job");
    let job = dir.join("bad.gcode");
    std::fs::write(&job, "G21\nG1 X1 Y1 F1200\nG1 X nan\n").unwrap();
    let (out, took) = demo_elsewhere(&dir, &["--gcode", job.to_str().unwrap()]);
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    // The demo reads (and checks) the job before it starts anything: exit 2, a bad input.
    assert_eq!(out.status.code(), Some(2), "stdout: {stdout}\nstderr: {stderr}");
    assert!(took < Duration::from_secs(20), "took {took:?}: the demo waited for something");
    assert!(stderr.contains(&format!("{}:3:", job.display())), "the parser's message, with file and line: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!stdout.contains("TCP error"), "no summary of an empty run: {stdout}");
    // Nothing ran: no log of idle ticks, no truth.
    assert!(!dir.join("demo/run.mcap").exists());
    assert!(!dir.join("demo/truth.csv").exists());
}

#[test]
fn the_demo_stops_at_once_when_the_sim_refuses_its_plant() {
    let dir = temp_dir("sim", "demo-bad-plant");
    let plant = dir.join("plant.toml");
    std::fs::write(&plant, "[joints]\nlag = nan\n").unwrap();
    // Unchecked: the job check of the default job takes a minute in a debug build (a second in
    // release), and this is about the sim refusing its plant at once.
    let (out, took) = demo_elsewhere(&dir, &["--sim", plant.to_str().unwrap(), "--no-check"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(took < Duration::from_secs(20), "took {took:?}");
    assert!(stderr.contains("the sim (strand-sim) exited with 2"), "{stderr}");
    assert!(stderr.contains("plant.toml: joints.lag = NaN"), "the sim's own message: {stderr}");
    assert!(!dir.join("demo/run.mcap").exists());
}

#[test]
fn the_sim_takes_the_services_overrides_and_names_a_bad_one() {
    // strand-demo hands its --set to both processes, so the sim and the service agree on the rate.
    let out = Command::new(bin("strand-sim")).args(["--set", "controller.rate_hz=-5", "--prefix", "strand/sim-set-test"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("[controller] rate_hz = -5"), "{err}");
}

/// `strand calibrate extruder` without `--measured`: it extrudes the commanded length through a
/// running service (a one-segment dwell where the arm stands, under the sim), then asks for the
/// measured length on stdin and rescales the drive wheel.
#[test]
fn calibrate_extruder_extrudes_through_the_service_then_asks() {
    use std::io::Write;
    let prefix = format!("strand/simtest-calibrate-{}", std::process::id());
    let (_svc, m) = service_without_robot(&prefix);
    let _sim = spawn({
        let mut c = Command::new(bin("strand-sim"));
        c.args(["--config", "config/default.toml", "--prefix", &prefix]);
        c
    });
    wait_for(&m, 30, "the sim clocking the service", |s| s.tick > 100);
    let mut child = Command::new(bin("strand"))
        .args(["calibrate", "extruder", "--config", "config/default.toml", "--prefix", &prefix])
        .args(["--commanded", "4", "--speed", "4", "--json"])
        .current_dir(root())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The answer is read only after the extrusion: written now, it waits in the pipe.
    writeln!(child.stdin.take().unwrap(), "3.92").unwrap();
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "exit {:?}: {err}", out.status.code());
    assert!(err.contains("extruding 4.0 mm") && err.contains("how many mm went in?"), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!((json_f64(&v, &["ratio"]) - 0.98).abs() < 1e-12, "{v}");
    assert!((json_f64(&v, &["drive_wheel_radius"]) - 0.98 * json_f64(&v, &["previous"])).abs() < 1e-12, "{v}");
    // The service ran the extrusion as a job to its end: finished, no fault, no clamp.
    let s = wait_for(&m, 10, "the service idle again", |s| s.run_state == RunState::Idle as u32);
    assert_eq!((s.job_outcome, s.fault, s.clamps), (JobOutcome::Finished as u32, FaultCode::None as u32, 0), "{s:?}");
    assert_eq!(s.segments_accepted, 1, "{s:?}");
}
