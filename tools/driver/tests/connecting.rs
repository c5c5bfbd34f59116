//! The drivers that connect to the robot controller, end to end: the service on the robot clock,
//! strand-bcap (a DENSO RC8's b-CAP slave mode, the VP6242), strand-meca (a Meca500's TCP API) or
//! strand-ur (a UR5e's RTDE and reverse interface), a fake controller written from the public
//! description only (`tools/driver/src/fake/bcap/`, `fake/meca/`, `fake/ur/`, in this process
//! on their own threads, absolute deadlines), and strand-feed
//! streaming the shared squares (`STRAND_DEMO_JOB=1`: the demo's job, the 35 mm box's first layer,
//! for the job tests). The job must finish with the controller never stopping the arm (no
//! b-CAP HRESULT: no empty command buffer, no command too fast; no Meca500 error and no velocity
//! timeout while streaming), the arm within its limits, and the robot given back cleanly at the
//! end; a killed service must leave the arm held without a jump; an error the controller reports
//! must end the stream, named, with the service told and the robot given back.
//!
//! Needs the workspace's binaries (`cargo build --workspace`, as the README's test command does).
//! The jobs and the killed services run optimised (`cargo test --release --test connecting`, a CI
//! stage of its own) or with `STRAND_DEBUG_CELLS=1` ([`common::cells_run_here`]); the controller's
//! errors run in both.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

use common::{DRIVER_RT, SERVICE_RT_SETTING, cell_job, cells_run_here, wait_for};
use strand::config::Config;
use strand_driver::fake::FakeReport;
use strand_driver::fake::bcap::{BcapOptions, BcapReport, BcapWatch, FakeBcap};
use strand_driver::fake::meca::{FakeMeca, MecaOptions, MecaReport, MecaWatch};
use strand_driver::fake::ur::{FakeUr, UrOptions, UrReport, UrWatch};
use strand_testkit::{Reaped, bin, root};

/// One cell at a time (a real-time loop in three processes on a 2-core machine).
static ONE_CELL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The robot controller of a cell.
enum Fake {
    Bcap(FakeBcap),
    Meca(FakeMeca),
    Ur(FakeUr),
}

/// What the fake saw.
enum Seen {
    Bcap(BcapReport),
    Meca(MecaReport),
    Ur(UrReport),
}

impl Seen {
    fn report(&self) -> &FakeReport {
        match self {
            Seen::Bcap(r) => &r.report,
            Seen::Meca(r) => &r.report,
            Seen::Ur(r) => &r.report,
        }
    }
}

/// The robot and its cycle for a protocol: the VP6242 on the RC8's 8 ms; the Meca500 on a 4 ms
/// driver tick; the UR5e on RTDE's 2 ms.
fn robot_of(protocol: &str) -> (&'static str, f64) {
    match protocol {
        "bcap" => ("vp6242", 125.0),
        "ur" => ("ur5e", 500.0),
        _ => ("meca500", 250.0),
    }
}

struct Cell {
    _one: std::sync::MutexGuard<'static, ()>,
    dir: PathBuf,
    config: PathBuf,
    prefix: String,
    rate_hz: f64,
    service: Reaped,
    driver: Reaped,
    fake: Option<Fake>,
}

/// Degrees of a config's limits: (lower, upper, velocity, acceleration) per joint.
fn limits_deg(config: &Path) -> Vec<[f64; 4]> {
    let cfg = Config::load(config).unwrap();
    let model = cfg.robot.build_model().unwrap();
    model
        .joints()
        .iter()
        .map(|j| {
            [j.limits.lower.to_degrees(), j.limits.upper.to_degrees(), j.limits.velocity.to_degrees(), j.limits.acceleration.to_degrees()]
        })
        .collect()
}

impl Cell {
    fn start(protocol: &str, name: &str) -> Cell {
        let one = ONE_CELL.lock().unwrap_or_else(|e| e.into_inner());
        let (robot, rate_hz) = robot_of(protocol);
        let dir = strand_testkit::temp_dir("driver", &format!("connect-{name}"));
        let config = root().join(format!("config/{robot}.toml"));
        let prefix = format!("strand/cntest-{}-{name}", std::process::id());
        let cfg = Config::load(&config).unwrap();
        let start_deg: Vec<f64> = cfg.service.initial_joints.iter().map(|q| q.to_degrees()).collect();
        let limits = limits_deg(&config);
        let rate = format!("controller.rate_hz={rate_hz}");
        let service = Reaped(
            Command::new(bin("strand"))
                .args(["run", "--clock", "robot", "--no-log", "--prefix", &prefix, "--set", &rate, "--set", SERVICE_RT_SETTING, "--config"])
                .arg(&config)
                .env("RUST_LOG", "warn")
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.join("service.log")).unwrap())
                .spawn()
                .unwrap(),
        );
        // The controller: it stops the arm (an error) on a command faster than the robot's limits
        // (the URDF's speeds, the robot file's accelerations, 1 % over for rounding).
        let (fake, robot_addr, extra) = match protocol {
            "bcap" => {
                let fake = FakeBcap::spawn(BcapOptions {
                    cycle: 1.0 / rate_hz,
                    start_deg: start_deg.clone(),
                    speed_limit_deg: limits.iter().map(|l| l[2] * 1.01).collect(),
                    accel_limit_deg: limits.iter().map(|l| l[3] * 1.01).collect(),
                    lag: 0.0,
                    rt_priority: Some(90),
                    motor_on_time: 0.5,
                    ..Default::default()
                })
                .unwrap();
                let addr = fake.addr();
                (Fake::Bcap(fake), addr, Vec::new())
            }
            "ur" => {
                let fake = FakeUr::spawn(UrOptions {
                    start_q: std::array::from_fn(|k| cfg.service.initial_joints[k]),
                    speed_limit: std::array::from_fn(|k| limits[k][2].to_radians()),
                    rt_priority: Some(90),
                    ..Default::default()
                })
                .unwrap();
                let (r, p) = (fake.rtde_addr(), fake.primary_addr());
                // The program connects back to any free port; a shared machine's stall is not the
                // driver stopping: the read timeout the program gets is 0.2 s (a cell's: 0.02).
                let extra = [
                    "driver.reverse_port=0".to_string(),
                    format!("driver.script_port={}", p.port()),
                    "driver.read_timeout=0.2".to_string(),
                ];
                (Fake::Ur(fake), r, extra.iter().flat_map(|e| ["--set".to_string(), e.clone()]).collect())
            }
            _ => {
                let mut start = [0.0; 6];
                start.copy_from_slice(&start_deg);
                let fake = FakeMeca::spawn(MecaOptions {
                    start_deg: start,
                    // Twice the robot file's: the arm follows the driver's velocities, whose
                    // changes keep the robot file's acceleration limits.
                    accel_deg: std::array::from_fn(|k| limits[k][3] * 2.0),
                    home_time: 0.3,
                    rt_priority: Some(90),
                    ..Default::default()
                })
                .unwrap();
                let (c, m) = (fake.control_addr(), fake.monitor_addr());
                (Fake::Meca(fake), c, vec!["--set".to_string(), format!("driver.monitor_port={}", m.port())])
            }
        };
        let mut driver = Command::new(bin(&format!("strand-{protocol}")));
        if cfg!(debug_assertions) {
            // Unoptimised, the service's tick costs ten times more: more late cycles before a
            // fault, so that the tests check behaviour, not the build.
            driver.args(["--set", "driver.max_late_cycles=10"]);
        }
        let driver = Reaped(
            driver
                .args(["--prefix", &prefix, "--rt", DRIVER_RT, "--set", &rate, "--robot", &robot_addr.to_string(), "--config"])
                .arg(&config)
                .args(&extra)
                .arg("--stats")
                .arg(dir.join("driver.json"))
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.join("driver.log")).unwrap())
                .spawn()
                .unwrap(),
        );
        let cell = Cell { _one: one, dir, config, prefix, rate_hz, service, driver, fake: Some(fake) };
        wait_for(&cell.dir.join("driver.log"), "Holding", Duration::from_secs(30));
        cell
    }

    fn feed(&self, job: &Path) -> Command {
        let mut c = Command::new(bin("strand-feed"));
        c.arg(job).args(["--prefix", &self.prefix, "--quiet", "--wait-service", "20", "--config"]).arg(&self.config);
        c.args(["--set", &format!("controller.rate_hz={}", self.rate_hz)]);
        c
    }

    fn logs(&self) -> String {
        let fake = match &self.fake {
            Some(Fake::Bcap(f)) => format!("--- the controller latched {:x?}", f.watch().errors()),
            Some(Fake::Meca(f)) => format!("--- the robot's status {:?}", f.watch().status()),
            Some(Fake::Ur(f)) => {
                let w = f.watch();
                format!("--- the robot: mode {}, safety {}, runtime {}", w.robot_mode(), w.safety_mode(), w.runtime_state())
            }
            None => String::new(),
        };
        ["service.log", "driver.log", "feed.log"]
            .iter()
            .map(|f| format!("--- {f}:\n{}", std::fs::read_to_string(self.dir.join(f)).unwrap_or_default()))
            .chain([fake])
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn bcap(&self) -> BcapWatch {
        match &self.fake {
            Some(Fake::Bcap(f)) => f.watch(),
            _ => panic!("not a b-CAP cell"),
        }
    }

    fn meca(&self) -> MecaWatch {
        match &self.fake {
            Some(Fake::Meca(f)) => f.watch(),
            _ => panic!("not a Meca500 cell"),
        }
    }

    fn ur(&self) -> UrWatch {
        match &self.fake {
            Some(Fake::Ur(f)) => f.watch(),
            _ => panic!("not a UR cell"),
        }
    }

    /// SIGTERM to the driver (it holds the arm to rest, gives the robot back and exits); its exit
    /// code, its stats and log, and what the fake saw.
    fn finish(mut self) -> (Option<i32>, serde_json::Value, String, Seen) {
        self.driver.signal(libc::SIGTERM);
        let code = self.driver.wait_until(Instant::now() + Duration::from_secs(20));
        self.collect(code)
    }

    fn collect(&mut self, code: Option<i32>) -> (Option<i32>, serde_json::Value, String, Seen) {
        let log = std::fs::read_to_string(self.dir.join("driver.log")).unwrap_or_default();
        let stats =
            std::fs::read_to_string(self.dir.join("driver.json")).ok().and_then(|t| serde_json::from_str(&t).ok()).unwrap_or_default();
        // The controller sees the driver's connection close (b-CAP, the Meca500) or its program end
        // with the reverse socket (UR) before it is stopped and asked what it saw.
        let gone = || match &self.fake {
            Some(Fake::Bcap(f)) => !f.watch().connected(),
            Some(Fake::Meca(f)) => !f.watch().connected(),
            Some(Fake::Ur(f)) => !f.watch().program_running(),
            None => true,
        };
        let until = Instant::now() + Duration::from_secs(5);
        while !gone() && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(5));
        }
        let seen = match self.fake.take().unwrap() {
            Fake::Bcap(f) => Seen::Bcap(f.stop()),
            Fake::Meca(f) => Seen::Meca(f.stop()),
            Fake::Ur(f) => Seen::Ur(f.stop()),
        };
        let _ = strand_ipc::ports::cleanup_dead_nodes();
        (code, stats, log, seen)
    }
}

fn job(dir: &Path) -> PathBuf {
    let p = dir.join("squares.gcode");
    std::fs::write(&p, common::squares_gcode()).unwrap();
    p
}

/// The arm's speed and acceleration over the run (deg/s, deg/s²) against the robot's limits: the
/// rows of the fake's report are its cycles (b-CAP) or monitoring intervals (the Meca500).
fn assert_within_limits(protocol: &str, config: &Path, report: &FakeReport, row_period: f64) {
    let (v, a) = report.max_rates(row_period, 0.0);
    for (k, l) in limits_deg(config).iter().enumerate() {
        assert!(v[k] <= l[2] * 1.01, "{protocol}: J{} at {:.1} deg/s, limit {:.1}", k + 1, v[k], l[2]);
        // The Meca500 ramps its velocity at its own acceleration: judged on the velocity alone.
        if protocol == "bcap" {
            assert!(a[k] <= l[3] * 1.01, "{protocol}: J{} at {:.1} deg/s², limit {:.1}", k + 1, a[k], l[3]);
        }
    }
    let first = report.axes.first().unwrap();
    for row in &report.axes {
        for (k, l) in limits_deg(config).iter().enumerate() {
            assert!(row[k] >= l[0] - 0.5 && row[k] <= l[1] + 0.5, "{protocol}: J{} at {:.2} deg, limits {:?}", k + 1, row[k], l);
        }
    }
    let moved = first.iter().zip(report.axes.last().unwrap()).any(|(a, b)| (a - b).abs() > 1.0)
        || report.axes.iter().any(|r| r.iter().zip(first).any(|(a, b)| (a - b).abs() > 1.0));
    assert!(moved, "{protocol}: the arm moved to the job");
}

/// The job ([`cell_job`]: the squares, or the demo's) through the driver: it finishes, the controller never stopped
/// the arm, the arm kept its limits, the robot was given back cleanly.
fn a_job_streams_through(protocol: &str) {
    let cell = Cell::start(protocol, &format!("job-{protocol}"));
    let feed_log = cell.dir.join("feed.log");
    let (job, args) = cell_job(&cell.dir);
    let mut feed =
        Reaped(cell.feed(&job).args(args).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    let code = feed.wait_until(Instant::now() + Duration::from_secs(300));
    if code != Some(0) {
        panic!("{protocol}: strand-feed ended {code:?}\n{}", cell.logs());
    }
    let config = cell.config.clone();
    let (code, stats, log, seen) = cell.finish();
    assert_eq!(code, Some(0), "{protocol}: the driver exits cleanly on SIGTERM:\n{log}");
    eprintln!("{protocol}: {:?}\ndriver: {stats}", seen.report());
    assert_eq!(stats["counters"]["faults"], 0, "{stats}");
    assert_eq!(stats["counters"]["robot_errors"], 0, "{stats}");
    match &seen {
        Seen::Bcap(r) => {
            // The controller never stopped the arm: no empty buffer, no command too fast.
            let empty: Vec<usize> = r.report.fresh.iter().enumerate().filter(|(_, f)| !**f).map(|(i, _)| i).collect();
            assert!(
                r.errors.is_empty(),
                "the controller latched {:x?} (cycles without a command: {empty:?} of {}; calls {:?})\n{log}",
                r.errors,
                r.report.cycles,
                r.calls
            );
            assert!(r.released, "the arm was not given back cleanly: {:?}", r.calls);
            assert!(r.report.cycles > 500, "{:?}", r.report);
            // Every controller cycle in slave mode took a command from the buffer.
            assert_eq!(r.report.missing, 0, "{:?}", r.report);
            assert_within_limits(protocol, &config, &r.report, 0.008);
        }
        Seen::Meca(r) => {
            assert!(r.errors.is_empty(), "the robot sent errors {:?}\n{log}", r.errors);
            // The velocity timeout never stopped the arm while strand streamed (the driver ends
            // with a zero velocity, whose lapse is not counted).
            assert_eq!(r.timeouts, 0, "{r:?}");
            assert!(r.commands.iter().any(|c| c.eq_ignore_ascii_case("ActivateRobot")), "{:?}", r.commands);
            assert!(r.commands.iter().any(|c| c.eq_ignore_ascii_case("Home")), "{:?}", r.commands);
            assert!(r.move_joints_vel > 1000, "{r:?}");
            assert_within_limits(protocol, &config, &r.report, 0.002);
        }
        Seen::Ur(r) => ur_ran_cleanly(r, &log, &config),
    }
}

/// A UR run: one program, never stopped by its read timeout, no setpoint too fast, ended by the
/// driver's STOPPED message, the arm within its limits.
fn ur_ran_cleanly(r: &UrReport, log: &str, config: &Path) {
    assert_eq!(r.scripts.len(), 1, "{:?}", r.scripts);
    assert_eq!(r.timeouts, 0, "the program timed out: {:?}\n{log}", r.report);
    assert_eq!(r.violations, 0, "{:?}", r.report);
    assert_eq!(r.clean_stops, 1, "the driver ended the program cleanly: {:?}\n{log}", r.report);
    assert!(r.report.cycles > 1000, "{:?}", r.report);
    assert_within_limits("ur", config, &r.report, 0.002);
}

#[test]
fn a_job_streams_through_strand_bcap_to_a_denso_and_finishes() {
    if !cells_run_here("a_job_streams_through_strand_bcap_to_a_denso_and_finishes") {
        return;
    }
    a_job_streams_through("bcap");
}

#[test]
fn a_job_streams_through_strand_meca_to_a_meca500_and_finishes() {
    if !cells_run_here("a_job_streams_through_strand_meca_to_a_meca500_and_finishes") {
        return;
    }
    a_job_streams_through("meca");
}

#[test]
fn a_job_streams_through_strand_ur_to_a_ur5e_and_finishes() {
    if !cells_run_here("a_job_streams_through_strand_ur_to_a_ur5e_and_finishes") {
        return;
    }
    a_job_streams_through("ur");
}

/// The robot's speed slider at 40 % mid-job, under an operator's feed override of 80 %: the driver
/// tells the service, whose path slows to 32 % (the job still finishes, with the arm never asked
/// for more than the robot gives), and the operator's override stays 80 % (the robot's scaling is
/// its own command, `RobotSpeedScaling`, not a feed override that would overwrite the operator's).
#[test]
fn the_ur_speed_slider_slows_the_services_path() {
    if !cells_run_here("the_ur_speed_slider_slows_the_services_path") {
        return;
    }
    let cell = Cell::start("ur", "slider-ur");
    let job = job(&cell.dir);
    let feed_log = cell.dir.join("feed.log");
    let mut feed = Reaped(cell.feed(&job).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    wait_for(&cell.dir.join("driver.log"), "Holding → Following", Duration::from_secs(30));
    let ctl = |args: &[&str]| {
        let out = Command::new(bin("strand")).args(["ctl", "--prefix", &cell.prefix, "--timeout", "5"]).args(args).output().unwrap();
        assert!(out.status.success(), "strand ctl {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    ctl(&["feed", "80"]);
    std::thread::sleep(Duration::from_millis(1500));
    cell.ur().set_speed_scaling(0.4);
    wait_for(&cell.dir.join("driver.log"), "speed scaling 40 %", Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(100));
    let status: serde_json::Value = serde_json::from_str(ctl(&["status", "--json"]).lines().next().unwrap()).unwrap();
    assert_eq!(status["feed_override"].as_f64(), Some(0.8), "the operator's override stays: {status}");
    let code = feed.wait_until(Instant::now() + Duration::from_secs(240));
    let logs = cell.logs();
    assert_eq!(code, Some(0), "the job finishes at 40 %:\n{logs}");
    assert!(logs.contains("speed scaling 40 %"), "the driver told the service:\n{logs}");
    let config = cell.config.clone();
    let (code, _, log, seen) = cell.finish();
    assert_eq!(code, Some(0), "{log}");
    if let Seen::Ur(r) = &seen {
        ur_ran_cleanly(r, &log, &config);
    }
}

/// Kills the service once the job runs: the driver must go on commanding the arm (a b-CAP buffer
/// that ran dry, or a Meca500 left to its velocity timeout, would stop it with an error), hold it
/// without a jump, and fault.
fn killed_service(protocol: &str) {
    let mut cell = Cell::start(protocol, &format!("kill-{protocol}"));
    let job = job(&cell.dir);
    let feed_log = cell.dir.join("feed.log");
    let _feed = Reaped(cell.feed(&job).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    wait_for(&cell.dir.join("driver.log"), "Holding → Following", Duration::from_secs(30));
    std::thread::sleep(Duration::from_millis(3000));
    cell.service.signal(libc::SIGKILL);
    wait_for(&cell.dir.join("driver.log"), "HeldAfterFault", Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(1000));
    let config = cell.config.clone();
    let (code, stats, log, seen) = cell.finish();
    assert_eq!(code, Some(0), "{protocol}: the driver exits cleanly on SIGTERM:\n{log}");
    assert!(stats["counters"]["faults"].as_u64().unwrap() >= 1, "{stats}");
    match &seen {
        Seen::Bcap(r) => {
            assert!(r.errors.is_empty(), "the controller latched {:x?}\n{log}", r.errors);
            assert!(r.released, "{:?}", r.calls);
            assert_eq!(r.report.missing, 0, "{:?}", r.report);
            assert_within_limits(protocol, &config, &r.report, 0.008);
        }
        Seen::Meca(r) => {
            assert!(r.errors.is_empty(), "the robot sent errors {:?}\n{log}", r.errors);
            assert_eq!(r.timeouts, 0, "{r:?}");
            assert_within_limits(protocol, &config, &r.report, 0.002);
        }
        Seen::Ur(r) => ur_ran_cleanly(r, &log, &config),
    }
}

#[test]
fn a_killed_service_leaves_the_ur5e_held_without_a_jump() {
    if !cells_run_here("a_killed_service_leaves_the_ur5e_held_without_a_jump") {
        return;
    }
    killed_service("ur");
}

#[test]
fn a_killed_service_leaves_the_denso_held_over_bcap_without_a_jump() {
    if !cells_run_here("a_killed_service_leaves_the_denso_held_over_bcap_without_a_jump") {
        return;
    }
    killed_service("bcap");
}

#[test]
fn a_killed_service_leaves_the_meca500_held_without_a_jump() {
    if !cells_run_here("a_killed_service_leaves_the_meca500_held_without_a_jump") {
        return;
    }
    killed_service("meca");
}

/// strand-meca's process stalls mid-job (SIGSTOP for 20 ms, three times: five ticks of its 4 ms
/// clock each): the Meca500 runs on at its last velocity meanwhile, so the driver owes the service
/// the ticks it missed (`owed_ticks`), and the job finishes without a fault, an error, a velocity
/// timeout or a joint past its limits.
#[test]
fn a_stalled_strand_meca_pays_the_service_the_ticks_the_meca500_ran_on() {
    if !cells_run_here("a_stalled_strand_meca_pays_the_service_the_ticks_the_meca500_ran_on") {
        return;
    }
    let mut cell = Cell::start("meca", "stall-meca");
    let job = job(&cell.dir);
    let feed_log = cell.dir.join("feed.log");
    let mut feed = Reaped(cell.feed(&job).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    wait_for(&cell.dir.join("driver.log"), "Holding → Following", Duration::from_secs(30));
    for _ in 0..3 {
        std::thread::sleep(Duration::from_millis(1000));
        cell.driver.signal(libc::SIGSTOP);
        std::thread::sleep(Duration::from_millis(20));
        cell.driver.signal(libc::SIGCONT);
    }
    let code = feed.wait_until(Instant::now() + Duration::from_secs(180));
    if code != Some(0) {
        panic!("strand-feed ended {code:?}\n{}", cell.logs());
    }
    let config = cell.config.clone();
    let (code, stats, log, seen) = cell.finish();
    assert_eq!(code, Some(0), "the driver exits cleanly on SIGTERM:\n{log}");
    eprintln!("driver: {stats}");
    let counters = &stats["counters"];
    assert_eq!((counters["faults"].as_u64(), counters["robot_errors"].as_u64()), (Some(0), Some(0)), "{stats}");
    assert!(counters["owed_ticks"].as_u64().unwrap() >= 3, "three stalls owe ticks: {stats}");
    assert!(counters["lost_cycles"].as_u64().unwrap() >= counters["owed_ticks"].as_u64().unwrap(), "{stats}");
    let Seen::Meca(r) = &seen else { unreachable!() };
    assert!(r.errors.is_empty(), "the robot sent errors {:?}\n{log}", r.errors);
    assert_eq!(r.timeouts, 0, "{r:?}");
    assert_within_limits("meca", &config, &r.report, 0.002);
}

/// The controller stops the arm with an error mid-job: the driver names it, tells the service
/// (which faults, so strand-feed fails), gives the robot back, and exits with 1.
fn robot_error(protocol: &str, code: u32, named: &[&str]) {
    let mut cell = Cell::start(protocol, &format!("error-{protocol}"));
    let job = job(&cell.dir);
    let feed_log = cell.dir.join("feed.log");
    let mut feed = Reaped(cell.feed(&job).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    wait_for(&cell.dir.join("driver.log"), "Holding → Following", Duration::from_secs(30));
    std::thread::sleep(Duration::from_millis(2000));
    match protocol {
        "bcap" => cell.bcap().inject_error(code),
        "ur" => cell.ur().protective_stop(),
        _ => cell.meca().inject_error(code),
    }
    let exit = cell.driver.wait_until(Instant::now() + Duration::from_secs(20));
    let fed = feed.wait_until(Instant::now() + Duration::from_secs(30));
    let logs = cell.logs();
    let (_, stats, log, seen) = cell.collect(exit);
    assert_eq!(exit, Some(1), "{protocol}: the driver exits with 1 when the robot stops it:\n{logs}");
    assert!(named.iter().any(|n| log.contains(n)), "{protocol}: the error is named ({named:?}):\n{log}");
    assert!(log.contains("the stream ended"), "{log}");
    assert_ne!(fed, Some(0), "the job did not report success:\n{logs}");
    assert!(stats["robot_ended"].as_str().is_some(), "{stats}");
    if let Seen::Bcap(r) = &seen {
        // Given back: slave mode off (the controller left it), motor off, the arm given back.
        assert!(r.calls.iter().any(|c| c.contains("GiveArm")), "{:?}", r.calls);
        assert!(r.calls.iter().any(|c| c.contains("Service_Stop")), "{:?}", r.calls);
    }
}

#[test]
fn a_denso_that_stops_with_an_error_ends_the_stream_named() {
    // The controller answers the error itself to a slvMove it held when the error came, and
    // "slave mode off" to the next one otherwise: either is named.
    robot_error("bcap", 0x8420_4051, &["0x84204051 (command speed too large, J1)", "0x83500121 (slvMove while slave mode is off"]);
}

#[test]
fn a_ur5e_in_a_protective_stop_ends_the_stream_named() {
    robot_error("ur", 0, &["PROTECTIVE_STOP (3)"]);
}

#[test]
fn a_meca500_that_stops_with_an_error_ends_the_stream_named() {
    robot_error("meca", 3005, &["[3005] motion error"]);
}
