//! The drivers end to end: the service on the robot clock, strand-egm or strand-rsi, a fake robot
//! controller speaking the real wire format (in this process, on its own thread, 4 ms absolute
//! deadlines), and strand-feed streaming a small job (`STRAND_DEMO_JOB=1`: the demo's job, the 35 mm
//! box's first layer, for the job tests). The job must finish; the fake's cycles must
//! be answered in time; the axes the fake integrated must keep the robot's speed and acceleration
//! limits; a killed service must leave the robot held (no jump) and the driver faulted; packets of
//! every bad kind must be dropped without harm.
//!
//! Needs the workspace's binaries (`cargo build --workspace`, as the README's test command does).
//!
//! The cells run optimised (`cargo test --release --test drivers`, a CI stage of its own): an
//! unoptimised service, driver and fake sharing two cores miss 4 ms cycles for the build's sake,
//! and the fake FRI cabinet then aborts its overlay on the link's quality, or the fake KR C4
//! records the double step of an answer it took late — failures of the machine, not the driver
//! (seen in 4 of 6 debug runs on 2026-11-27, with one cell at a time). In a debug build they are
//! skipped, saying so, unless `STRAND_DEBUG_CELLS=1`; the bad-packet and axis mapping tests run
//! in both.

use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

mod common;

use common::{DRIVER_RT, SERVICE_RT_SETTING, cell_job, cells_run_here, wait_for};
use strand_testkit::{Reaped, bin, root};

use strand::config::Config;
use strand_driver::fake::egm::FakeEgm;
use strand_driver::fake::fri::{FakeFri, FriOptions, FriWatch};
use strand_driver::fake::rsi::{FakeRsi, OutputValues};
use strand_driver::fake::{FakeChannel, FakeOptions, FakeProtocol, FakeReport, run, run_channels};

fn free_udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The shared job (`common::squares_gcode`), written into `dir`.
fn job(dir: &Path) -> PathBuf {
    let p = dir.join("squares.gcode");
    std::fs::write(&p, common::squares_gcode()).unwrap();
    p
}

/// One cell at a time: each runs a 4 ms real-time loop in three processes, and this machine has
/// two cores.
static ONE_CELL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A running cell: service, driver and the fake on its thread.
struct Cell {
    _one: std::sync::MutexGuard<'static, ()>,
    dir: PathBuf,
    config: PathBuf,
    prefix: String,
    service: Reaped,
    driver: Reaped,
    stop_fake: Arc<AtomicBool>,
    fake: Option<std::thread::JoinHandle<FakeReport>>,
    /// The fake Sunrise cabinet's FRI session (FRI only).
    fri: Option<FriWatch>,
    /// Mutes the external axes' own EGM channel (a MultiMove cell only).
    unit_mute: Option<Arc<AtomicBool>>,
    /// RSI: the extruder's tags the fake KR C4 received per cycle (`RSI_EXTRUDER_TAGS`), and the
    /// service's extruder commands (tick, volumetric m³/s, flags) as a monitor saw them.
    rsi_extruder: Option<(ExtruderTags, ExtruderCommands, std::thread::JoinHandle<()>)>,
}

/// What the fake KR C4 received per cycle on its output tags.
type ExtruderTags = Arc<Mutex<Vec<OutputValues>>>;

/// The service's extruder commands a monitor saw: tick, volumetric flow (m³/s), flags.
type ExtruderCommands = Arc<Mutex<Vec<(u64, f64, u32)>>>;

/// Every RSI cell carries the extruder's command in its answers, on these tags (the analog volts
/// and the enable), scaled as here: V = 0.1 + 0.5 × mm³/s.
const RSI_EXTRUDER_TAGS: [&str; 2] = ["Extruder.Volt", "Extruder.On"];
const RSI_VOLTS_PER_FLOW: f64 = 0.5;
const RSI_VOLTS_OFFSET: f64 = 0.1;

/// Settings every process of a cell takes: FRI's iiwa runs at 1 ms in its config; the tests run
/// every robot at the 4 ms cycle (a 4 ms FRI send period), as the other drivers'.
fn cell_settings(protocol: &str) -> Vec<String> {
    if protocol == "fri" { vec!["controller.rate_hz=250".to_string()] } else { Vec::new() }
}

impl Cell {
    /// A cell of the bundled config `config/<robot>.toml`.
    fn start(protocol: &str, robot: &str, name: &str) -> Cell {
        Cell::start_with(protocol, name, |_| root().join(format!("config/{robot}.toml")))
    }

    /// A cell of the config `config` writes into the cell's folder (or names). The fake robot
    /// starts at `[service] initial_joints`, its external axes (if the robot file has some) at 0.
    fn start_with(protocol: &str, name: &str, config: impl FnOnce(&Path) -> PathBuf) -> Cell {
        Cell::start_cell(protocol, name, config, false)
    }

    /// An EGM cell whose external axes are a mechanical unit of their own (MultiMove): the fake
    /// controller streams them on a second channel, to the driver's `[driver] external_axes_bind`.
    fn start_multimove(name: &str, config: impl FnOnce(&Path) -> PathBuf) -> Cell {
        Cell::start_cell("egm", name, config, true)
    }

    fn start_cell(protocol: &str, name: &str, config: impl FnOnce(&Path) -> PathBuf, multimove: bool) -> Cell {
        Cell::start_full(protocol, name, config, multimove, &[], false)
    }

    /// A cell whose service logs to `<dir>/run.mcap` and takes `service_settings` (`--set`) besides.
    fn start_logged(protocol: &str, name: &str, config: impl FnOnce(&Path) -> PathBuf, service_settings: &[&str]) -> Cell {
        Cell::start_full(protocol, name, config, false, service_settings, true)
    }

    fn start_full(
        protocol: &str,
        name: &str,
        config: impl FnOnce(&Path) -> PathBuf,
        multimove: bool,
        service_settings: &[&str],
        logged: bool,
    ) -> Cell {
        let one = ONE_CELL.lock().unwrap_or_else(|e| e.into_inner());
        let dir = strand_testkit::temp_dir("driver", name);
        let config = config(&dir);
        let prefix = format!("strand/drvtest-{}-{name}", std::process::id());
        let settings: Vec<String> = cell_settings(protocol).iter().flat_map(|s| ["--set".to_string(), s.clone()]).collect();
        let log: Vec<String> =
            if logged { vec!["--log".into(), dir.join("run.mcap").display().to_string()] } else { vec!["--no-log".into()] };
        let service = Reaped(
            Command::new(bin("strand"))
                .args(["run", "--clock", "robot", "--prefix", &prefix, "--set", SERVICE_RT_SETTING, "--config"])
                .arg(&config)
                .args(&log)
                .args(&settings)
                .args(service_settings.iter().flat_map(|s| ["--set", s]))
                .env("RUST_LOG", "warn")
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.join("service.log")).unwrap())
                .spawn()
                .unwrap(),
        );
        let port = free_udp_port();
        let mut driver = Command::new(bin(&format!("strand-{protocol}")));
        if cfg!(debug_assertions) {
            // Unoptimised, the service's tick costs ten times more: a wider deadline, and more
            // late cycles before a fault, so that the tests check behaviour, not the build.
            driver.args(["--set", "driver.reply_deadline=0.003", "--set", "driver.max_late_cycles=10"]);
        } else if protocol == "fri" {
            // The iiwa's config answers within 0.6 ms of its 1 ms cycle and faults after 12 ms of
            // late answers (12 cycles); here the cycle is 4 ms.
            driver.args(["--set", "driver.reply_deadline=0.002", "--set", "driver.max_late_cycles=3"]);
        }
        driver.args(&settings);
        if protocol == "rsi" {
            driver.args(["--set", &format!("driver.extruder_tag=\"{}\"", RSI_EXTRUDER_TAGS[0])]);
            driver.args(["--set", &format!("driver.extruder_enable_tag=\"{}\"", RSI_EXTRUDER_TAGS[1])]);
            driver.args(["--set", &format!("driver.extruder_volts_per_flow={RSI_VOLTS_PER_FLOW}")]);
            driver.args(["--set", &format!("driver.extruder_volts_offset={RSI_VOLTS_OFFSET}")]);
        }
        let unit_port = free_udp_port();
        if multimove {
            driver.args(["--set", &format!("driver.external_axes_bind=\"127.0.0.1:{unit_port}\"")]);
        }
        let driver = Reaped(
            driver
                .args(["--prefix", &prefix, "--rt", DRIVER_RT, "--bind", &format!("127.0.0.1:{port}"), "--config"])
                .arg(&config)
                .arg("--stats")
                .arg(dir.join("driver.json"))
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.join("driver.log")).unwrap())
                .spawn()
                .unwrap(),
        );
        // The driver binds before it opens its ports; give it a moment, then start the robot.
        let cfg = Config::load(&config).unwrap();
        let mut start_deg: Vec<f64> = cfg.service.initial_joints.iter().map(|q| q.to_degrees()).collect();
        start_deg.resize(strand_driver::CellJoints::of(&cfg).unwrap().dof().max(start_deg.len()), 0.0);
        let stop_fake = Arc::new(AtomicBool::new(false));
        let stop = stop_fake.clone();
        let (mut fri, mut fri_watch) = (None, None);
        if protocol == "fri" {
            // The cabinet aborts the overlay on a step faster than the URDF's speed limits.
            let model = cfg.robot.build_model().unwrap();
            let mut velocity_limit = [0.0; 7];
            for (v, j) in velocity_limit.iter_mut().zip(model.joints()) {
                *v = j.limits.velocity;
            }
            let (fake, watch) =
                FakeFri::new(FriOptions { send_period_ms: 4, velocity_limit, restart_after_abort: false, ..Default::default() });
            (fri, fri_watch) = (Some(fake), Some(watch));
        }
        let protocol = protocol.to_string();
        wait_for(&dir.join("driver.log"), "listening on", Duration::from_secs(20));
        let unit_mute = multimove.then(|| Arc::new(AtomicBool::new(false)));
        let mute = unit_mute.clone();
        let mut rsi_extruder = None;
        let mut rsi = (protocol == "rsi").then(|| {
            let mut fake = FakeRsi::new(&start_deg, 4);
            fake.outputs = RSI_EXTRUDER_TAGS.iter().map(|t| t.to_string()).collect();
            let commands = Arc::new(Mutex::new(Vec::new()));
            let (record, stop, prefix) = (commands.clone(), stop_fake.clone(), prefix.clone());
            let monitor = std::thread::spawn(move || {
                use strand_ipc::ports::{ClientPorts, ClientRoles};
                let roles = ClientRoles { monitor: true, ..Default::default() };
                let Ok(ports) = ClientPorts::open(&strand_ipc::ServiceNames::new(&prefix), "extruder-monitor", roles) else { return };
                while !stop.load(Ordering::Relaxed) {
                    while let Ok(Some(e)) = ports.receive_extruder_command() {
                        record.lock().unwrap().push((e.tick, e.volumetric_rate, e.flags));
                    }
                    std::thread::sleep(Duration::from_micros(500));
                }
            });
            rsi_extruder = Some((fake.received.clone(), commands, monitor));
            fake
        });
        let fake = std::thread::spawn(move || {
            let mut p: Box<dyn FakeProtocol> = match (protocol.as_str(), fri) {
                (_, Some(fri)) => Box::new(fri),
                ("egm", _) => Box::new(FakeEgm::new(25, 4)),
                _ => Box::new(rsi.take().unwrap_or_else(|| FakeRsi::new(&start_deg, 4))),
            };
            let opts = FakeOptions {
                driver: SocketAddr::from(([127, 0, 0, 1], port)),
                bind: SocketAddr::from(([127, 0, 0, 1], 0)),
                period: 0.004,
                start_deg,
                lag: 0.008,
                cycles: 0,
                give_up_after: 0,
                rt_priority: Some(90),
            };
            match mute {
                Some(mute) => {
                    let mut unit = FakeEgm::unit(25, 4);
                    unit.mute = mute;
                    let unit_axes = 6..opts.start_deg.len();
                    let unit_driver = SocketAddr::from(([127, 0, 0, 1], unit_port));
                    let mut channels = [
                        FakeChannel { protocol: p.as_mut(), driver: opts.driver, axes: 0..6 },
                        FakeChannel { protocol: &mut unit, driver: unit_driver, axes: unit_axes },
                    ];
                    run_channels(&mut channels, &opts, &stop).unwrap()
                }
                None => run(p.as_mut(), &opts, &stop).unwrap(),
            }
        });
        wait_for(&dir.join("driver.log"), "Holding", Duration::from_secs(20));
        Cell { _one: one, dir, config, prefix, service, driver, stop_fake, fake: Some(fake), fri: fri_watch, unit_mute, rsi_extruder }
    }

    fn feed(&self, job: &Path) -> Command {
        let mut c = Command::new(bin("strand-feed"));
        c.arg(job).args(["--prefix", &self.prefix, "--quiet", "--wait-service", "20", "--config"]).arg(&self.config);
        for s in cell_settings(if self.fri.is_some() { "fri" } else { "" }) {
            c.args(["--set", &s]);
        }
        c
    }

    /// What the service, the driver and the feeder wrote to their logs so far.
    fn logs(&self) -> String {
        ["service.log", "driver.log", "feed.log", "mcu.log"]
            .iter()
            .map(|f| format!("--- {f}:\n{}", std::fs::read_to_string(self.dir.join(f)).unwrap_or_default()))
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// Stops the fake and the driver; the fake's report and the driver's stats.
    fn finish(self) -> (FakeReport, serde_json::Value, String) {
        self.finish_with_extruder().0
    }

    /// [`Cell::finish`], and for RSI what the fake received on the extruder's tags and the
    /// service's extruder commands.
    #[allow(clippy::type_complexity)]
    fn finish_with_extruder(
        mut self,
    ) -> ((FakeReport, serde_json::Value, String), Option<(Vec<(u64, Vec<Option<f64>>)>, Vec<(u64, f64, u32)>)>) {
        let extruder = self.rsi_extruder.take();
        let finished = self.finish_cell();
        let extruder = extruder.map(|(received, commands, monitor)| {
            let _ = monitor.join();
            let received = received.lock().unwrap().clone();
            let commands = commands.lock().unwrap().clone();
            (received, commands)
        });
        (finished, extruder)
    }

    fn finish_cell(&mut self) -> (FakeReport, serde_json::Value, String) {
        self.stop_fake.store(true, Ordering::Relaxed);
        let report = self.fake.take().unwrap().join().unwrap();
        self.driver.signal(libc::SIGTERM);
        let code = self.driver.wait_until(Instant::now() + Duration::from_secs(10));
        let log = std::fs::read_to_string(self.dir.join("driver.log")).unwrap_or_default();
        assert_eq!(code, Some(0), "the driver exits cleanly on SIGTERM:\n{log}");
        let stats: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(self.dir.join("driver.json")).unwrap()).unwrap();
        // A killed service's shared memory, removed (as a restarted service's start-up does)
        // while this cell still holds the machine: left, the next cell's driver removes it when
        // its own service dies, inside the robot's cycle (measured: 1 to 3 answers missing in the
        // RSI kill test after the FRI one).
        let _ = strand_ipc::ports::cleanup_dead_nodes();
        (report, stats, log)
    }
}

/// A test that fails half-way still stops its fake robot: its real-time loop would otherwise run on
/// beside the next test's cell.
impl Drop for Cell {
    fn drop(&mut self) {
        self.stop_fake.store(true, Ordering::Relaxed);
        if let Some(fake) = self.fake.take() {
            let _ = fake.join();
        }
    }
}

/// The cell's limits in degrees: (velocity deg/s, acceleration deg/s²) per joint, the arm's and
/// then its external axes' (all rotary here).
fn limits_deg(config: &Path) -> Vec<(f64, f64)> {
    let cfg = Config::load(config).unwrap();
    let cell = strand_driver::CellJoints::of(&cfg).unwrap();
    cell.joints.iter().map(|j| (j.limits.velocity.to_degrees(), j.limits.acceleration.to_degrees())).collect()
}

/// In-time share the tests demand: a functional floor (a driver that stalls, or answers from the
/// wrong clock, answers far fewer in time), not the 99.9 % aim, which is measured by `strand-bench
/// latency --driver` over 15,000 cycles (README "Performance"). This job is ~2,400 cycles of three
/// processes on a shared 2-core machine with no real-time kernel: unloaded, every cycle is in time;
/// with both cores kept busy by two other spinning processes, release runs answered 99.2-100 % in
/// time (15 late and 19 missing in the worst of four), and one CI run fell under the old 99.5 %
/// floor. The floor is 98 %: what the machine's noise can take away, and no more.
fn in_time_needed() -> f64 {
    0.98
}

fn a_job_streams_through(protocol: &str, robot: &str) {
    let cell = Cell::start(protocol, robot, &format!("job-{protocol}"));
    // Bounded: a feeder that never ends is this test's failure, with what each process said, not a
    // test run that hangs until CI's own limit.
    let feed_log = cell.dir.join("feed.log");
    let (job, args) = cell_job(&cell.dir);
    let mut feed =
        Reaped(cell.feed(&job).args(args).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    let code = feed.wait_until(Instant::now() + Duration::from_secs(300));
    if code.is_none() {
        panic!("{protocol}: strand-feed did not end within 300 s\n{}", cell.logs());
    }
    let config = cell.config.clone();
    let feed_said = std::fs::read_to_string(&feed_log).unwrap_or_default();
    let fri = cell.fri.clone();
    let ((report, stats, log), extruder) = cell.finish_with_extruder();
    if let Some((received, commands)) = extruder {
        the_extruder_rides_with_the_joints(&received, &commands);
    }
    if let Some(fri) = fri {
        // The cabinet never aborted the overlay (no jump, no NaN, the link good), and the job ran
        // in COMMANDING_ACTIVE.
        assert_eq!(fri.aborts(), 0, "the FRI overlay was aborted: {}\n{log}", fri.last_abort());
        assert!(fri.active_cycles() > 1000, "{} cycles in COMMANDING_ACTIVE", fri.active_cycles());
        assert!(log.contains("FRI session MonitoringWait") && log.contains("CommandingActive"), "the session's states are logged:\n{log}");
    }
    assert_eq!(code, Some(0), "strand-feed:\n{feed_said}\ndriver:\n{log}");
    eprintln!("{protocol}: {report:?}\ndriver: {stats}");
    assert!(report.cycles > 1000, "{report:?}");
    let share = report.in_time_share();
    assert!(share >= in_time_needed(), "{protocol}: {:.4} % of {} cycles answered in time: {report:?}", 100.0 * share, report.cycles);
    assert_eq!(stats["counters"]["faults"], 0, "{stats}");
    // The service's commands keep the limits by themselves; only after a hold does the guard catch
    // up with them, time-optimally and without passing them (what those answers do is judged, per
    // robot and for 1, 3 and 10 missed cycles at full speed, in tests/catch_up.rs). A hold is a
    // late cycle, an answer that missed the robot's cycle, or a cycle whose packet the driver
    // never answered (lost, or skipped behind a newer one): the robot stood still each time.
    // A catch-up on these robots ends within 40 cycles there (36 on the IRB 140, 31 on the KR 6):
    // every clamp here must belong to one.
    let count = |k: &str| stats["counters"][k].as_u64().unwrap();
    let (clamped, holds) = (count("clamped"), count("late") + count("missed_cycle") + count("lost_cycles"));
    assert!(clamped <= 40 * holds, "{clamped} answers clamped after {holds} late or missed cycles: {stats}");
    let (v, a) = report.max_rates(0.004, 0.008);
    for (k, (vl, al)) in limits_deg(&config).iter().enumerate() {
        assert!(v[k] <= vl * 1.001, "{protocol}: axis {} at {:.1} deg/s, limit {vl:.1}", k + 1, v[k]);
        assert!(a[k] <= al * 1.001, "{protocol}: axis {} at {:.1} deg/s², limit {al:.1}", k + 1, a[k]);
    }
    // It moved: the job is squares or the box's first layer.
    let moved = report.axes.first().unwrap().iter().zip(report.axes.last().unwrap()).any(|(a, b)| (a - b).abs() > 1.0);
    assert!(moved, "the robot moved to the job and back");
}

/// RSI's extruder outputs (`[driver] extruder_tag`, `extruder_enable_tag`): the volts and the
/// enable the fake KR C4 received each cycle are the service's extruder command of that cycle's
/// tick, or of the tick before (the command goes out with the joints' answer; when it is not
/// published yet the last one is): V = offset + gain × mm³/s, enabled while extruding. The cycle ↔
/// tick offset is found from the first cycles (the service's first tick came some cycles after the
/// fake's first packet) and followed through the run.
fn the_extruder_rides_with_the_joints(received: &[OutputValues], commands: &[(u64, f64, u32)]) {
    use std::collections::HashMap;
    let by_tick: HashMap<u64, (f64, bool)> = commands
        .iter()
        .map(|(tick, vol, flags)| {
            let flow = vol * 1e9;
            let volts = (RSI_VOLTS_OFFSET + RSI_VOLTS_PER_FLOW * flow).clamp(0.0, 10.0);
            (*tick, (volts, flags & strand_ipc::extruder_flags::EXTRUDING != 0 && flow > 0.0))
        })
        .collect();
    // Does cycle `k`'s answer carry the command of tick k − offset (lag 0) or of the tick before
    // (lag 1)? None: the monitor did not see that tick.
    let carries = |(k, v): &OutputValues, offset: i64| -> Option<Option<i64>> {
        let tick = *k as i64 - offset;
        by_tick.get(&(tick as u64))?;
        let (Some(volts), Some(on)) = (v[0], v[1]) else { return Some(None) };
        Some([0, 1].into_iter().find(|lag| {
            by_tick.get(&((tick - lag) as u64)).is_some_and(|(want, want_on)| (volts - want).abs() < 2e-6 && (on == 1.0) == *want_on)
        }))
    };
    // The offset most of the first 500 cycles agree on, then followed through the run: a cycle
    // the service took together with the next (two states in one wake, the driver's answer late)
    // moves it by one; such moves are counted.
    let start = &received[..received.len().min(500)];
    let mut offset = (0..200).max_by_key(|o| start.iter().filter(|r| matches!(carries(r, *o), Some(Some(_)))).count()).unwrap();
    let (mut judged, mut within_one, mut same, mut moves) = (0usize, 0usize, 0usize, 0usize);
    for r in received {
        let Some(lag) = carries(r, offset) else { continue };
        judged += 1;
        let lag = lag.or_else(|| {
            let moved = [offset - 1, offset + 1, offset - 2, offset + 2].into_iter().find(|o| matches!(carries(r, *o), Some(Some(_))))?;
            offset = moved;
            moves += 1;
            carries(r, moved).flatten()
        });
        within_one += usize::from(lag.is_some());
        same += usize::from(lag == Some(0));
    }
    let extruding = received.iter().filter(|(_, v)| v[1] == Some(1.0) && v[0].is_some_and(|volts| volts > RSI_VOLTS_OFFSET + 0.1)).count();
    eprintln!(
        "rsi extruder outputs: {judged} cycles judged: {within_one} carried the command of their tick or the one before, {same} of their own tick; the cycle ↔ tick offset moved {moves} times; {extruding} extruding"
    );
    assert!(judged > 1000 && extruding > 100, "{judged} cycles judged, {extruding} extruding");
    assert!(within_one as f64 >= in_time_needed() * judged as f64, "{within_one} of {judged} cycles carried their tick's extruder command");
    assert!(moves as f64 <= (1.0 - in_time_needed()) * judged as f64, "the offset moved {moves} times in {judged} cycles");
}

#[test]
fn a_job_streams_through_strand_rsi_to_a_kuka_and_finishes() {
    if !cells_run_here("a_job_streams_through_strand_rsi_to_a_kuka_and_finishes") {
        return;
    }
    a_job_streams_through("rsi", "kr6r900");
}

#[test]
fn a_job_streams_through_strand_fri_to_an_iiwa_and_finishes() {
    if !cells_run_here("a_job_streams_through_strand_fri_to_an_iiwa_and_finishes") {
        return;
    }
    a_job_streams_through("fri", "iiwa7");
}

#[test]
fn a_job_streams_through_strand_egm_to_an_abb_and_finishes() {
    if !cells_run_here("a_job_streams_through_strand_egm_to_an_abb_and_finishes") {
        return;
    }
    a_job_streams_through("egm", "irb140");
}

#[test]
fn a_killed_service_leaves_the_robot_held_without_a_jump_and_the_driver_faulted() {
    if !cells_run_here("a_killed_service_leaves_the_robot_held_without_a_jump_and_the_driver_faulted") {
        return;
    }
    killed_service("rsi", "kr6r900");
}

/// The same through FRI: the hold is the guarded answer in COMMANDING_ACTIVE, so the cabinet
/// keeps its overlay (a jump would abort it).
#[test]
fn a_killed_service_leaves_the_iiwa_held_over_fri_without_a_jump() {
    if !cells_run_here("a_killed_service_leaves_the_iiwa_held_over_fri_without_a_jump") {
        return;
    }
    killed_service("fri", "iiwa7");
}

fn killed_service(protocol: &str, robot: &str) {
    let mut cell = Cell::start(protocol, robot, &format!("kill-{protocol}"));
    let job = job(&cell.dir);
    let mut feed = Reaped(cell.feed(&job).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap());
    // Into the job: the arm follows the service's commands (the approach is under way), then the
    // service dies, and the driver holds the arm for a second.
    wait_for(&cell.dir.join("driver.log"), "Holding → Following", Duration::from_secs(30));
    cell.service.signal(libc::SIGKILL);
    wait_for(&cell.dir.join("driver.log"), "HeldAfterFault", Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(1000));
    let _ = feed.wait_until(Instant::now() + Duration::from_secs(5));
    let config = cell.config.clone();
    let fri = cell.fri.clone();
    let (report, stats, log) = cell.finish();
    if let Some(fri) = fri {
        assert_eq!(fri.aborts(), 0, "the FRI overlay was aborted: {}\n{log}", fri.last_abort());
    }
    assert!(log.contains("HeldAfterFault"), "the driver latched the hold:\n{log}");
    assert!(stats["counters"]["faults"].as_u64().unwrap() >= 1, "{stats}");
    // Held to the end; once the fake stopped streaming, its session ended.
    assert!(stats["final_state"] == "HeldAfterFault" || stats["final_state"] == "WaitingForRobot", "{stats}");
    assert!(!log.contains("HeldAfterFault → Following"), "a dead service never released the hold:\n{log}");
    // The robot kept its answers: after the three late cycles that latch the hold, holds are sent
    // before anything else, so they stay in time (RSI's own limit is 100 late cycles).
    assert!(report.missing + report.late <= 50, "answers missing after the kill: {report:?}");
    // Held, the answers go on in time, all but a few: when strand-feed gives up on the dead
    // service (5 s after the kill) and exits, its node's clean-up of the dead service's shared
    // memory holds the driver's next port calls for milliseconds, and one to three of the next
    // cycles go unanswered (seen in one release run of three: cycles 2007, 2013, 2015 of 2030).
    // A robot that gets no answer keeps its target, which is the hold; a driver whose robot loop
    // waits on no port call is the fix (a note for the next session).
    let tail = &report.fresh[report.fresh.len().saturating_sub(100)..];
    let missed: Vec<usize> = report.fresh.iter().enumerate().filter(|(_, f)| !**f).map(|(k, _)| k).collect();
    assert!(tail.iter().filter(|f| !**f).count() <= 5, "answered in time while held: {report:?}; cycles not answered in time: {missed:?}");
    let (v, a) = report.max_rates(0.004, 0.008);
    for (k, (vl, al)) in limits_deg(&config).iter().enumerate() {
        assert!(
            v[k] <= vl * 1.001 && a[k] <= al * 1.001,
            "axis {}: {:.1} deg/s, {:.1} deg/s² (limits {vl:.1}, {al:.1})",
            k + 1,
            v[k],
            a[k]
        );
    }
    // At rest at the end.
    let n = report.axes.len();
    let last: Vec<f64> = report.axes[n - 1].iter().zip(&report.axes[n - 2]).map(|(a, b)| (a - b).abs()).collect();
    assert!(last.iter().all(|d| *d < 1e-6), "still moving after the hold: {last:?}");
}

#[test]
fn bad_packets_are_dropped_and_counted_and_the_driver_goes_on() {
    let cell = Cell::start("rsi", "kr6r900", "bad");
    let driver_port = {
        let log = std::fs::read_to_string(cell.dir.join("driver.log")).unwrap();
        let at = log.find("listening on 127.0.0.1:").unwrap() + "listening on 127.0.0.1:".len();
        log[at..].split(|c: char| !c.is_ascii_digit()).next().unwrap().parse::<u16>().unwrap()
    };
    // From another address than the robot's: refused whatever it holds.
    let other = UdpSocket::bind("127.0.0.1:0").unwrap();
    for packet in [&b"<Rob TYPE=\"KUKA\"><AIPos A1=\"0\"/><IPOC>1</IPOC></Rob>"[..], b"garbage", &[0u8; 8000]] {
        other.send_to(packet, ("127.0.0.1", driver_port)).unwrap();
    }
    std::thread::sleep(Duration::from_millis(1000));
    let (report, stats, _) = cell.finish();
    assert_eq!(stats["counters"]["foreign"], 3, "{stats}");
    assert_eq!(stats["counters"]["faults"], 0, "{stats}");
    // The robot's cycles went on being answered, judged as the job tests judge them: over ~250
    // cycles, not 80, where one late wake-up of this shared machine was 1.25 % (seen once in 9).
    assert!(report.cycles >= 200, "{report:?}");
    assert!(report.in_time_share() >= in_time_needed(), "{report:?}");
}

#[test]
fn every_bundled_robot_with_a_driver_maps_its_axes_both_ways() {
    // Every config with a [driver] section: controller axes → URDF joints → axes is the identity
    // over each joint's whole range, and the mapping is the one the config gives.
    let mut checked = Vec::new();
    for entry in std::fs::read_dir(root().join("config")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let cfg = Config::load(&path).unwrap();
        let Some(d) = cfg.driver.clone() else { continue };
        let model = cfg.robot.build_model().unwrap();
        d.validate(model.dof()).unwrap();
        let map = strand_driver::axes::AxisMap::new(model.dof(), &d.axis_sign, &d.axis_offset);
        for step in 0..=20 {
            let q: Vec<f64> =
                model.joints().iter().map(|j| j.limits.lower + (j.limits.upper - j.limits.lower) * step as f64 / 20.0).collect();
            let axes = map.axes_from_joints(&q);
            let back = map.joints_from_axes(&axes[..q.len()]);
            for k in 0..q.len() {
                assert!((back[k] - q[k]).abs() < 1e-12, "{}: joint {} at {}: back {}", path.display(), k + 1, q[k], back[k]);
                let sign = d.axis_sign.get(k).copied().unwrap_or(1.0);
                let offset = d.axis_offset.get(k).copied().unwrap_or(0.0);
                assert!((axes[k] - (sign * q[k] + offset)).abs() < 1e-12);
            }
        }
        checked.push(path.file_stem().unwrap().to_string_lossy().to_string());
    }
    checked.sort();
    assert_eq!(checked, ["iiwa14", "iiwa7", "irb140", "kr6r900", "meca500", "ur5e", "vp6242"]);
}

/// `cells/kr6-turntable` (a KR 6 with a rotary table, its axis the cell's joint 7) with a
/// `[driver]` section for `protocol` (and `extra` lines in it), written into `dir`.
fn turntable_config(dir: &Path, protocol: &str, extra: &str) -> PathBuf {
    let cell = root().join("config/cells/kr6-turntable.toml");
    let robot = root().join("config/robots/kr6-turntable.toml").canonicalize().unwrap();
    let text = std::fs::read_to_string(&cell).unwrap();
    assert!(text.contains("robot = \"../robots/kr6-turntable.toml\""), "the cell names its robot file as it did");
    let text = text.replace("robot = \"../robots/kr6-turntable.toml\"", &format!("robot = {:?}", robot.display().to_string()));
    let p = dir.join(format!("kr6-turntable-{protocol}.toml"));
    std::fs::write(&p, format!("{text}\n[driver]\nprotocol = \"{protocol}\"\n{extra}\n")).unwrap();
    p
}

/// The table's job: the nozzle writes 60° of a 30 mm circle about the table's axis (at (0.7, 0)
/// m in W, its plate's top 0.25 m up) while the table turns the other way, 0 → 60°, so that the
/// nozzle hardly moves in W: a travel to the circle's start with the table at 0, then six chords
/// of 10°, each ending with the table at k·10° (`segment_flags::AXES`). Points in the work frame
/// at home (src/core/positioner.rs). The table's last angle (rad).
fn turntable_job() -> (Vec<strand_ipc::Segment>, f64) {
    use strand_ipc::segment_flags;
    use strand_testkit::line_with_axes;
    let (centre, r, z) = ([0.7, 0.0], 0.03, 0.26);
    let point = |phi: f64| [centre[0] + r * phi.cos(), centre[1] + r * phi.sin(), z];
    let mut job = vec![line_with_axes(1, point(0.0), [0.0, 0.0], 0.05, 0.0)];
    for k in 1..=6u64 {
        let table = (10.0 * k as f64).to_radians();
        job.push(line_with_axes(k + 1, point(-table), [table, 0.0], 0.02, 1e-4));
    }
    if let Some(last) = job.last_mut() {
        last.flags |= segment_flags::LAST;
    }
    (job, 60f64.to_radians())
}

/// Streams `job` to the service within the credit window its Status announces, sends Start after
/// the first batch, and waits (at most `within`) for the job to end, or to fault; its last Status.
fn stream_job(prefix: &str, job: &[strand_ipc::Segment], within: Duration) -> strand_ipc::Status {
    use strand_ipc::ports::{ClientPorts, ClientRoles};
    use strand_ipc::{Control, JobOutcome, RunState, ServiceNames};
    let ports = ClientPorts::open(
        &ServiceNames::new(prefix),
        "turntable-feeder",
        ClientRoles { feeder: true, monitor: true, ..Default::default() },
    )
    .unwrap();
    let end = Instant::now() + within;
    let (mut next, mut batch_seq, mut started) = (0usize, 0u64, false);
    let mut last = None;
    while Instant::now() < end {
        let Some(status) = ports.latest_status() else {
            std::thread::sleep(Duration::from_millis(2));
            continue;
        };
        last = Some(status);
        if next == job.len() && started {
            if status.job_outcome != JobOutcome::InProgress as u32
                && (status.run_state == RunState::Idle as u32 || status.fault != 0)
                && status.segments_accepted > 0
            {
                return status;
            }
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        let batch = strand_testkit::credit_batch(job, &mut next, &status, batch_seq + 1, strand::io::clock::monotonic_ns());
        if batch.len > 0 {
            batch_seq += 1;
            ports.send_segments(&batch).unwrap();
            let sent = job[next - 1].seq;
            while Instant::now() < end && ports.latest_status().is_none_or(|s| s.last_received_seq < sent && s.rejected == 0) {
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        if !started {
            started = true;
            let start = Control {
                seq: 1,
                stamp_ns: strand::io::clock::monotonic_ns(),
                command: strand_ipc::Command::Start as u32,
                ..Default::default()
            };
            ports.send_control(&start).unwrap();
        }
    }
    panic!("the turntable job did not end within {within:?}; last status {last:?}");
}

/// The turntable cell through `protocol`'s driver to its fake robot with one external axis: the
/// job ends, the fake's table (its E1 / `externalJoints[0]`, degrees) ends where the last segment
/// put it, every axis keeps its limits, and the driver never faulted.
fn a_turntable_job_streams_through(protocol: &str) {
    let cell = Cell::start_with(protocol, &format!("turntable-{protocol}"), |dir| turntable_config(dir, protocol, ""));
    let (job, _) = turntable_job();
    let status = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| stream_job(&cell.prefix, &job, Duration::from_secs(60))))
        .unwrap_or_else(|_| panic!("{protocol}: the turntable job did not end\n{}", cell.logs()));
    the_turntable_job_ended_well(cell, protocol, status);
}

/// The turntable job's checks (see [`a_turntable_job_streams_through`]), once it ended with
/// `status`: the fake's report and the driver's stats.
fn the_turntable_job_ended_well(cell: Cell, protocol: &str, status: strand_ipc::Status) -> (FakeReport, serde_json::Value) {
    let table = turntable_job().1;
    let logs = cell.logs();
    assert_eq!(status.job_outcome, strand_ipc::JobOutcome::Finished as u32, "{protocol}: {status:?}\n{logs}");
    assert_eq!(status.fault, 0, "{status:?}");
    // The table settles before the fake stops: the drives' 8 ms lag, and a catch-up still under
    // way at the job's end. (After a cycle the robot held, the guard catches the table up at part
    // of its 4 rad/s², which the path's own 3.3 rad/s² on the table nearly uses up: seen to take
    // 1.1 s, and to pass the end by 2° before coming back; tools/driver/tests/catch_up.rs judges
    // catch-ups.)
    std::thread::sleep(Duration::from_millis(2000));
    let config = cell.config.clone();
    let (report, stats, log) = cell.finish();
    eprintln!("{protocol} turntable: {report:?}\ndriver: {stats}");
    assert_eq!(stats["counters"]["faults"], 0, "{stats}\n{log}");
    assert_eq!(stats["counters"]["malformed"], 0, "every packet read (EIPos / externalJoints with the table): {stats}");
    assert!(report.in_time_share() >= in_time_needed(), "{protocol}: {report:?}");
    let last = report.axes.last().unwrap();
    assert_eq!(last.len(), 7, "the fake robot has the table as its 7th axis");
    if (last[6] - table.to_degrees()).abs() >= 1e-3 {
        let e1: Vec<String> = report.axes.iter().enumerate().step_by(10).map(|(k, a)| format!("{k}:{:.3}", a[6])).collect();
        let missed: Vec<usize> = report.fresh.iter().enumerate().filter(|(_, f)| !**f).map(|(k, _)| k).collect();
        panic!(
            "{protocol}: the table ended at {:.6}°, the job's last segment says {:.6}°\nE1 every 10 cycles: {}\ncycles not fresh: {missed:?}\n{log}",
            last[6],
            table.to_degrees(),
            e1.join(" ")
        );
    }
    let (v, a) = report.max_rates(0.004, 0.008);
    for (k, (vl, al)) in limits_deg(&config).iter().enumerate() {
        assert!(v[k] <= vl * 1.001, "{protocol}: axis {} at {:.1} deg/s, limit {vl:.1}", k + 1, v[k]);
        assert!(a[k] <= al * 1.001, "{protocol}: axis {} at {:.1} deg/s², limit {al:.1}", k + 1, a[k]);
    }
    (report, stats)
}

#[test]
fn a_turntable_job_streams_through_strand_rsi_to_a_kuka_with_e1_and_finishes() {
    if !cells_run_here("a_turntable_job_streams_through_strand_rsi_to_a_kuka_with_e1_and_finishes") {
        return;
    }
    a_turntable_job_streams_through("rsi");
}

/// The same cell over EGM: the table in `externalJoints` (an ABB cell with a KUKA arm's URDF, which
/// EGM does not mind: it carries joint angles).
#[test]
fn a_turntable_job_streams_through_strand_egm_to_an_abb_with_an_external_joint_and_finishes() {
    if !cells_run_here("a_turntable_job_streams_through_strand_egm_to_an_abb_with_an_external_joint_and_finishes") {
        return;
    }
    a_turntable_job_streams_through("egm");
}

/// The same cell over EGM with the table a mechanical unit of its own (ABB MultiMove: a positioner
/// in its own motion task, its own EGM channel to `[driver] external_axes_bind`): strand-egm
/// merges the unit's `externalJoints` into the robot's state and answers each channel with its
/// share of the one command; the job ends as over one channel, the table at 60°.
#[test]
fn a_turntable_job_streams_through_strand_egm_to_a_multimove_abb_with_the_table_on_its_own_channel() {
    if !cells_run_here("a_turntable_job_streams_through_strand_egm_to_a_multimove_abb_with_the_table_on_its_own_channel") {
        return;
    }
    let cell = Cell::start_multimove("turntable-multimove", |dir| turntable_config(dir, "egm", ""));
    let (job, _) = turntable_job();
    let status = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| stream_job(&cell.prefix, &job, Duration::from_secs(60))))
        .unwrap_or_else(|_| panic!("multimove: the turntable job did not end\n{}", cell.logs()));
    let (report, stats) = the_turntable_job_ended_well(cell, "egm multimove", status);
    let unit = &stats["unit"];
    let count = |k: &str| unit[k].as_u64().unwrap_or_else(|| panic!("unit.{k}: {stats}"));
    assert_eq!((count("malformed"), count("foreign"), count("out_of_order")), (0, 0, 0), "{stats}");
    // Every unit packet is answered with the robot's answer of its cycle (but for what the
    // machine's noise takes), and the fake's table channel is answered in time as often.
    let packets = count("packets");
    assert!(packets + 2 >= report.cycles, "{packets} unit packets in {} cycles: {stats}", report.cycles);
    assert!(count("answered_with_robot") as f64 >= in_time_needed() * packets as f64, "{stats}");
    assert!(report.channel_in_time[1] as f64 >= in_time_needed() * packets as f64, "{:?} {stats}", report.channel_in_time);
}

/// The MultiMove cell's table falls silent mid-job for 0.3 s (its motion task stopped): from the
/// second robot cycle without it the arm is answered with where it is (it stands: the table
/// under the nozzle does not turn) and the service is not clocked, so it faults
/// `JointStateLost` after `joint_state_timeout` (0.05 s) and the job ends faulted; the driver
/// itself holds and does not fault, and follows again when the table streams again.
#[test]
fn a_multimove_table_that_falls_silent_mid_job_stands_the_arm_and_faults_the_job() {
    if !cells_run_here("a_multimove_table_that_falls_silent_mid_job_stands_the_arm_and_faults_the_job") {
        return;
    }
    use strand_ipc::ports::{ClientPorts, ClientRoles};
    let cell = Cell::start_multimove("turntable-silent", |dir| turntable_config(dir, "egm", ""));
    let (job, _) = turntable_job();
    let (prefix, mute) = (cell.prefix.clone(), cell.unit_mute.clone().unwrap());
    let silence = std::thread::spawn(move || {
        let monitor = ClientRoles { monitor: true, ..Default::default() };
        let ports = ClientPorts::open(&strand_ipc::ServiceNames::new(&prefix), "unit-silence", monitor).unwrap();
        let end = Instant::now() + Duration::from_secs(60);
        while Instant::now() < end && ports.latest_status().is_none_or(|s| s.executing_seq < 3) {
            std::thread::sleep(Duration::from_millis(1));
        }
        mute.store(true, Ordering::Relaxed);
        std::thread::sleep(Duration::from_millis(300));
        mute.store(false, Ordering::Relaxed);
    });
    let status = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| stream_job(&cell.prefix, &job, Duration::from_secs(60))))
        .unwrap_or_else(|_| panic!("multimove: the turntable job did not end\n{}", cell.logs()));
    silence.join().unwrap();
    let logs = cell.logs();
    assert_eq!(status.job_outcome, strand_ipc::JobOutcome::Faulted as u32, "{status:?}\n{logs}");
    assert_eq!(status.fault, strand_ipc::FaultCode::JointStateLost as u32, "{status:?}\n{logs}");
    std::thread::sleep(Duration::from_millis(200));
    let (report, stats, log) = cell.finish();
    assert_eq!(stats["counters"]["faults"], 0, "the driver held the robot and did not fault: {stats}\n{log}");
    // The silence is the longest run of cycles the table's channel sent nothing (not fresh).
    let (mut run, mut longest) = ((0, 0), (0, 0));
    for (k, fresh) in report.fresh.iter().enumerate() {
        run = if *fresh { (k + 1, k + 1) } else { (run.0, k + 1) };
        if run.1 - run.0 > longest.1 - longest.0 {
            longest = run;
        }
    }
    assert!(longest.1 - longest.0 >= 50, "a silence of 0.3 s is about 75 cycles: {longest:?}");
    // From the third cycle of it on (two for the driver to see it, one in flight) the arm stands.
    let moved = (0..6)
        .map(|j| (longest.0 + 3..longest.1).map(|k| (report.axes[k][j] - report.axes[longest.0 + 3][j]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    eprintln!("the table silent over cycles {longest:?}: the arm moved {moved:.2e}° from its third; driver: {stats}");
    assert!(moved < 1e-6, "the arm moved {moved}° while its table was silent (cycles {longest:?})");
    assert!(stats["unit"]["packets"].as_u64().unwrap() > 0, "{stats}");
}

/// A cell with a positioner: RSI and EGM carry its axis after the arm's six (and the per-joint
/// lists of `[driver]` may name the arm's joints only, or every joint); FRI, UR RTDE, the Meca500
/// and b-CAP refuse it at start, naming the protocol and the positioner — the library and the
/// binaries (which exit before they touch a socket).
#[test]
fn a_cell_with_a_turntable_is_carried_by_rsi_and_egm_and_refused_by_the_others() {
    use strand::config::driver::DriverProtocol;
    let dir = strand_testkit::temp_dir("driver", "turntable-setup");
    for (protocol, p) in [("rsi", DriverProtocol::Rsi), ("egm", DriverProtocol::Egm)] {
        for extra in [
            "",
            "axis_sign = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]",
            "axis_sign = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, -1.0]\naxis_offset = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.75]",
        ] {
            let cfg = Config::load(&turntable_config(&dir, protocol, extra)).unwrap();
            let d = strand_driver::driver_config(&cfg, p).unwrap_or_else(|e| panic!("{protocol} {extra:?}: {e}"));
            let dof = match p {
                DriverProtocol::Rsi => strand_driver::session(&cfg, &d, strand_driver::rsi::Rsi::new()).unwrap().dof(),
                _ => strand_driver::session(&cfg, &d, strand_driver::egm::Egm::new()).unwrap().dof(),
            };
            assert_eq!(dof, 7, "{protocol}: the arm's six and the table");
            // The table's axis maps by the list when it names it.
            let map = strand_driver::axes::AxisMap::new(7, &d.axis_sign, &d.axis_offset);
            let expect = if extra.contains("-1.0") { -0.25 + 0.75 } else { 0.25 };
            assert_eq!(map.axes_from_joints(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.25])[6], expect);
        }
        let cfg = Config::load(&turntable_config(&dir, protocol, "axis_offset = [0.0, 0.0, 0.0, 0.0, 0.0]")).unwrap();
        let e = strand_driver::driver_config(&cfg, p).unwrap_err().to_string();
        assert!(e.contains("axis_offset has 5 values") && e.contains("give 6") && e.contains("or 7"), "{e}");
    }
    for (protocol, p, said) in [
        ("fri", DriverProtocol::Fri, "FRI carries no external axes"),
        ("ur", DriverProtocol::Ur, "UR RTDE carries no external axes"),
        ("meca", DriverProtocol::Meca, "Meca500's TCP API carries no external axes"),
        ("bcap", DriverProtocol::Bcap, "b-CAP carries no external axes"),
    ] {
        let path = turntable_config(&dir, protocol, "");
        let cfg = Config::load(&path).unwrap();
        let e = strand_driver::driver_config(&cfg, p).unwrap_err().to_string();
        assert!(e.contains(said) && e.contains("[positioner]") && e.contains("turntable_c"), "{protocol}: {e}");
        let out = Command::new(bin(&format!("strand-{protocol}"))).arg("--config").arg(&path).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "strand-{protocol}: {stderr}");
        assert!(stderr.contains(said) && stderr.contains("[positioner]"), "strand-{protocol}: {stderr}");
    }
}

/// `[driver] external_axes_bind` (the external axes on a channel of their own): EGM with a cell
/// that has external axes takes it; RSI, an arm without external axes, and the robot's own port
/// are refused, each naming the key.
#[test]
fn external_axes_on_a_channel_of_their_own_are_egms_and_need_external_axes() {
    use strand::config::driver::DriverProtocol;
    let dir = strand_testkit::temp_dir("driver", "unit-setup");
    let unit = "external_axes_bind = \"127.0.0.1:6511\"";
    let cfg = Config::load(&turntable_config(&dir, "egm", unit)).unwrap();
    let d = strand_driver::driver_config(&cfg, DriverProtocol::Egm).unwrap();
    assert_eq!(d.unit_address().unwrap(), Some("127.0.0.1:6511".parse().unwrap()));
    let mut session = strand_driver::session(&cfg, &d, strand_driver::egm::Egm::new()).unwrap();
    assert_eq!(session.dof(), 7);
    use strand_driver::protocol::RobotProtocol;
    assert!(session.protocol_mut().unit_channel().is_some(), "the table on its own channel");
    // Refused when the config loads, or when the driver checks it against the cell.
    let refused = |path: &Path, p: DriverProtocol| match Config::load(path) {
        Err(e) => e.to_string(),
        Ok(cfg) => strand_driver::driver_config(&cfg, p).unwrap_err().to_string(),
    };
    let e = refused(&turntable_config(&dir, "rsi", unit), DriverProtocol::Rsi);
    assert!(e.contains("external_axes_bind") && e.contains("EGM's (MultiMove)"), "{e}");
    let same = "bind = \"127.0.0.1:6510\"\nexternal_axes_bind = \"127.0.0.1:6510\"";
    let e = refused(&turntable_config(&dir, "egm", same), DriverProtocol::Egm);
    assert!(e.contains("external_axes_bind") && e.contains("a port of its own"), "{e}");
    let arm = dir.join("irb140-unit.toml");
    let text = std::fs::read_to_string(root().join("config/irb140.toml")).unwrap();
    assert!(text.contains("[driver]"), "irb140's config has a [driver] section");
    let robot = root().join("config/robots/irb140.toml").canonicalize().unwrap();
    let text = text.replace("robot = \"robots/irb140.toml\"", &format!("robot = {:?}", robot.display().to_string()));
    std::fs::write(&arm, text.replace("[driver]", &format!("[driver]\n{unit}"))).unwrap();
    let e = refused(&arm, DriverProtocol::Egm);
    assert!(e.contains("external_axes_bind") && e.contains("no external axes"), "{e}");
}

/// CELL item 5: the bundled cell `config/cells/kr6-rsi-klipper.toml` with every process of it
/// against the fakes — the service on the robot's clock, strand-rsi and the fake KR C4, strand-mcu
/// and the fake Klipper board on a pty (its hot end a thermal model), strand-feed — on a short job
/// with temperatures: the job waits for the hot end (M109), prints the squares, and the filament the
/// fake board's steps pushed per millimetre of the nozzle's path (the fake KR C4's axes through the
/// arm's FK) is measured with the demo's bead metric (`strand_replay::bead`, 1 mm bins).
///
/// The fake board has no melt model: the bead here is filament, so the service runs without
/// pressure advance (nothing to compensate); and its PID is the fake hot end's (the bundled one is
/// a real hot end's, tuned for a plant ten times slower).
#[test]
fn the_kr6_cell_with_a_klipper_board_waits_for_its_hot_end_and_lays_its_bead() {
    use strand_mcu::fake::{FakeConfig, FakeMcu};
    if !cells_run_here("the_kr6_cell_with_a_klipper_board_waits_for_its_hot_end_and_lays_its_bead") {
        return;
    }
    let board = FakeMcu::start(FakeConfig::default()).unwrap();
    let bundled = root().join("config/cells/kr6-rsi-klipper.toml");
    let cell = Cell::start_logged(
        "rsi",
        "kr6-klipper",
        |dir| {
            let text = std::fs::read_to_string(&bundled).unwrap();
            let text = text
                .replace("robot = \"../robots/kr6r900.toml\"", &format!("robot = {:?}", root().join("config/robots/kr6r900.toml")))
                .replace("pid_kp = 22.2", "pid_kp = 8.0")
                .replace("pid_ki = 1.08", "pid_ki = 1.5")
                .replace("pid_kd = 114.0", "pid_kd = 5.0")
                // The fake KR C4's axes follow an answer some 12 ms later (a cycle, and its drives'
                // 8 ms lag), where a real one takes 30-50 ms: the extruder's lead (plus
                // motion_delay, 0) must be the arm's delay. With the bundled 30 ms the bead's
                // starts and corners come 18 ms late: 14 % of the bins beyond ±10 % (measured).
                .replace("step_lead_time = 0.03 ", "step_lead_time = 0.012");
            let path = dir.join("kr6-rsi-klipper.toml");
            std::fs::write(&path, text).unwrap();
            path
        },
        &["extruder.pressure_advance=0.0", "extruder.pressure_advance_smooth_time=0.0", "extruder.motor_lag=0.0"],
    );
    let mcu_log = cell.dir.join("mcu.log");
    let mut mcu = Reaped(
        Command::new(bin("strand-mcu"))
            .args(["--prefix", &cell.prefix, "--serial"])
            .arg(&board.path)
            .arg("--config")
            .arg(&cell.config)
            .arg("--stats")
            .arg(cell.dir.join("mcu.json"))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&mcu_log).unwrap())
            .spawn()
            .unwrap(),
    );
    wait_for(&mcu_log, "steps run", Duration::from_secs(20));
    let job = cell.dir.join("hot-squares.gcode");
    std::fs::write(&job, format!("M104 S200\nM109 S200\n{}M104 S0\n", common::squares_gcode())).unwrap();
    let feed_log = cell.dir.join("feed.log");
    let started = Instant::now();
    let mut feed = Reaped(cell.feed(&job).stdout(Stdio::null()).stderr(std::fs::File::create(&feed_log).unwrap()).spawn().unwrap());
    let code = feed.wait_until(Instant::now() + Duration::from_secs(300));
    let took = started.elapsed().as_secs_f64();
    if code != Some(0) {
        panic!("strand-feed ended with {code:?}\n{}", cell.logs());
    }
    mcu.signal(libc::SIGTERM);
    let mcu_code = mcu.wait_until(Instant::now() + Duration::from_secs(10));
    let mcu_said = std::fs::read_to_string(&mcu_log).unwrap_or_default();
    assert_eq!(mcu_code, Some(0), "strand-mcu:\n{mcu_said}");
    let logs = cell.logs();
    let dir = cell.dir.clone();
    let config = cell.config.clone();
    let (report, stats, _) = cell.finish();
    assert_eq!(stats["counters"]["faults"], 0, "{stats}");
    let st = board.snapshot();
    assert_eq!(st.shutdown, None, "{logs}");
    // The log: what each tick executed, and the temperatures the service saw.
    let log = strand::log::reader::LogFile::open(&dir.join("run.mcap")).unwrap();
    let cfg = Config::load(&config).unwrap();
    let model = cfg.robot.build_model().unwrap();
    let mount = cfg.base.mount();
    let area = std::f64::consts::PI * 0.25 * cfg.extruder.filament_diameter.powi(2);
    let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
    let (mut segments, mut ticks, mut times) = (Vec::new(), Vec::new(), Vec::new());
    let (mut hot_at_first_extrusion, mut held_ticks) = (None, 0u64);
    for (k, tick) in log.ticks().enumerate() {
        let tick = tick.unwrap();
        segments.extend(tick.input.segments().iter().copied());
        // On the robot clock the ticks are the KR C4's cycles: evenly spaced by the bead's count.
        ticks.push(strand_replay::bead::Executing::of(k as u64 * dt_ns, &tick.output));
        times.push(tick.input.time_ns);
        let s = &tick.output.status;
        if s.heat_hold != 0 {
            held_ticks += 1;
        }
        if hot_at_first_extrusion.is_none() && tick.output.extruder.filament_rate > 0.0 {
            hot_at_first_extrusion = Some(s.hot_end_temperature);
        }
    }
    let hot = hot_at_first_extrusion.expect("the job extruded");
    assert!(hot >= 197.0, "the first extrusion came at {hot:.1} °C: M109 did not hold");
    assert!(held_ticks > 250, "the job held at M109 for {held_ticks} ticks");
    // The truth, from the fakes: the nozzle through the KR C4's actual axes at each tick's time, and
    // the filament the board's steps pushed by then (its steps on its true clock).
    let axes_at = |t_ns: u64| -> Vec<f64> {
        let x = (t_ns.saturating_sub(report.start_ns)) as f64 / report.period_ns as f64;
        let i = (x.floor() as usize).min(report.axes.len() - 1);
        let j = (i + 1).min(report.axes.len() - 1);
        let f = (x - i as f64).clamp(0.0, 1.0);
        report.axes[i].iter().zip(&report.axes[j]).map(|(a, b)| (a + f * (b - a)).to_radians()).collect()
    };
    let per_m = f64::from(200 * cfg.extruder_board.as_ref().unwrap().microsteps) / cfg.extruder_board.as_ref().unwrap().rotation_distance;
    let fake_epoch_ns = strand::io::clock::monotonic_ns() as f64 - board.epoch.elapsed().as_secs_f64() * 1e9;
    let steps = &st.steps[&0];
    let mut clocks: Vec<(u64, i64)> = Vec::with_capacity(steps.len());
    let mut n = 0i64;
    for s in steps {
        n += if s.dir == 1 { 1 } else { -1 };
        clocks.push((s.clock, n));
    }
    let filament_at = |t_ns: u64| -> f64 {
        let clock = ((t_ns as f64 - fake_epoch_ns) * 1e-9 * board.true_freq).max(0.0) as u64;
        let i = clocks.partition_point(|(c, _)| *c <= clock);
        if i == 0 { 0.0 } else { clocks[i - 1].1 as f64 / per_m }
    };
    let mut truth = Vec::with_capacity(times.len());
    for (k, &t) in times.iter().enumerate() {
        let q: Vec<f64> = axes_at(t);
        let mut joints = strand_core::kin::JointVector::zeros();
        for (i, v) in q.iter().take(model.dof()).enumerate() {
            joints[i] = *v;
        }
        let tcp = (mount * model.forward_kinematics(&joints)).translation.vector;
        let previous = if k > 0 { times[k - 1] } else { t };
        let flow = if t > previous { (filament_at(t) - filament_at(previous)) * area / ((t - previous) as f64 * 1e-9) } else { 0.0 };
        truth.push(strand_replay::truth::Truth {
            time_ns: k as u64 * dt_ns,
            tcp: tcp.into(),
            tcp_part: tcp.into(),
            flow_actual: flow,
            ..Default::default()
        });
    }
    let sections = strand_replay::bead::asked_sections(&segments, area);
    let bead = strand_replay::bead::measure_run(&ticks, &sections, &truth, dt_ns, None);
    let program_filament: f64 = segments.iter().filter(|s| s.filament > 0.0).map(|s| s.filament).sum();
    let pushed = filament_at(u64::MAX / 2);
    eprintln!(
        "kr6-rsi-klipper: {took:.1} s; first extrusion at {hot:.1} °C after {held_ticks} ticks held at M109; {} steps, {:.2} mm of \
         filament pushed for {:.2} mm programmed; bead {} bins: p50 {:.1} %, p95 {:.1} %, {:.2} % beyond ±10 %, mean {:+.1} % (nozzle \
         {:.0} ms behind its target); {} KR C4 cycles, {:.3} % in time\n{mcu_said}",
        steps.len(),
        pushed * 1e3,
        program_filament * 1e3,
        bead.all.bins,
        100.0 * bead.all.p50,
        100.0 * bead.all.p95,
        100.0 * bead.all.beyond_10pct,
        100.0 * bead.all.mean_signed,
        bead.path_delay_s * 1e3,
        report.cycles,
        100.0 * report.in_time_share()
    );
    assert!((pushed / program_filament - 1.0).abs() < 0.01, "the board pushed {pushed} m of {program_filament} m");
    assert!(bead.all.bins > 150, "{} bins", bead.all.bins);
    assert!(bead.all.p50 < 0.05, "bead p50 {:.3}", bead.all.p50);
    assert!(bead.all.beyond_10pct < 0.10, "{:.3} of the bins beyond ±10 %", bead.all.beyond_10pct);
}
