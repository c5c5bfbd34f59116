//! strand-mcu's process against the fake Klipper board on a pty and the service's own ports (this
//! test publishes what the service publishes): extruder commands become steps at the commanded
//! position a lead after each command, the heater target heats the fake hot end and its
//! temperatures come back as `HeaterState`, and a heater that does not heat is switched off and
//! said to be (`heater_flags::FAULT`, which the service turns into `HeaterFault`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use strand::io::clock::monotonic_ns;
use strand_ipc::ports::ServicePorts;
use strand_ipc::{self as ipc, ServiceNames, heater_flags};
use strand_mcu::config::BoardConfig;
use strand_mcu::fake::{FakeConfig, FakeMcu};
use strand_mcu::mcu::ConnectOptions;
use strand_mcu::process::{Report, RunOptions, run};

/// Real time over a pty with timing bounds: one test at a time.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn board(fake: &FakeMcu) -> BoardConfig {
    let text = format!(
        "serial = {:?}\nstep_pin = \"PA3\"\ndir_pin = \"PA4\"\nmicrosteps = 16\nrotation_distance = 0.0226\n\
         step_lead_time = 0.1\nheater_pin = \"PB1\"\nthermistor_pin = \"gpio26\"\n\
         thermistor = {{ type = \"beta\", t0 = 25.0, r0 = 100000.0, beta = 3950.0 }}\n\
         report_time = 0.1\npid_kp = 8.0\npid_ki = 1.5\npid_kd = 5.0\nmax_temp = 280.0\n",
        fake.path.display().to_string()
    );
    let cfg: BoardConfig = toml::from_str(&text).unwrap();
    cfg.validate().unwrap();
    cfg
}

/// Runs the process on its own thread (its ports live there) until `stop`.
fn spawn(cfg: BoardConfig, prefix: &str, stop: &'static AtomicBool) -> std::thread::JoinHandle<Report> {
    let prefix = prefix.to_string();
    std::thread::spawn(move || {
        let opts = RunOptions {
            prefix,
            stop,
            connect: ConnectOptions { timeout: 1.0, sync_interval: 0.01, sync_samples: 8, clock_interval: 0.1 },
        };
        run(&cfg, &opts, &mut |l| eprintln!("strand-mcu: {l}")).unwrap()
    })
}

fn heater_command(seq: u64, target: f64) -> ipc::HeaterCommand {
    ipc::HeaterCommand { seq, stamp_ns: monotonic_ns(), tick: seq, hot_end_target: target, ..Default::default() }
}

/// 4 mm/s of filament after a 0.2 s ramp, a 1 mm retraction at 0.6 s and its return at 0.8 s (m).
fn profile(t: f64) -> f64 {
    let v = 0.004;
    let base = if t < 0.2 { 0.5 * v / 0.2 * t * t } else { v * 0.1 + v * (t - 0.2) };
    let r = |a: f64| ((t - a) / 0.025).clamp(0.0, 1.0);
    base - 0.001 * r(0.6) + 0.001 * r(0.8)
}

#[test]
fn commands_become_steps_and_the_hot_end_heats_and_reports() {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let cfg = board(&fake);
    let prefix = format!("strand-mcu-process-{}", std::process::id());
    let service = ServicePorts::open(&ServiceNames::new(&prefix), "the-service").unwrap();
    static STOP: AtomicBool = AtomicBool::new(false);
    let process = spawn(cfg.clone(), &prefix, &STOP);
    // Heat to 120 °C; the temperatures come back.
    let t0 = Instant::now();
    let (mut seq, mut reached, mut states) = (0u64, None, Vec::new());
    while t0.elapsed() < Duration::from_secs(20) && reached.is_none() {
        seq += 1;
        service.publish_heater_command(&heater_command(seq, 120.0)).unwrap();
        while let Some(s) = service.receive_heater_state().unwrap() {
            assert_eq!(s.flags, heater_flags::HOT_END, "{s:?}");
            let age = monotonic_ns().saturating_sub(s.stamp_ns) as f64 * 1e-9;
            assert!(age < 0.5, "a temperature {age} s old");
            if s.hot_end >= 118.0 {
                reached = Some(t0.elapsed().as_secs_f64());
            }
            states.push(s);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let reached = reached.expect("the fake hot end reaches 120 °C");
    // Temperatures every report_time (0.1 s): the service's 1 s timeout is never near.
    let gaps: Vec<f64> = states.windows(2).map(|w| (w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9).collect();
    let worst_gap = gaps.iter().copied().fold(0.0, f64::max);
    assert!(worst_gap < 0.35, "a {worst_gap} s gap between temperatures");
    // The extruder: 1.2 s of commands at 1 kHz, stamped as the service stamps its ticks.
    let start_ns = monotonic_ns() + 1_000_000;
    let mut commands = Vec::new();
    for k in 0..=1200u64 {
        let stamp_ns = start_ns + k * 1_000_000;
        while monotonic_ns() < stamp_ns {
            std::hint::spin_loop();
        }
        let e =
            ipc::ExtruderCommand { seq: k + 1, stamp_ns, tick: k + 1, filament_position: profile(k as f64 * 1e-3), ..Default::default() };
        service.publish_extruder_command(&e).unwrap();
        commands.push(e);
        if k % 20 == 0 {
            seq += 1;
            service.publish_heater_command(&heater_command(seq, 120.0)).unwrap();
        }
    }
    std::thread::sleep(Duration::from_millis(400));
    STOP.store(true, Ordering::Relaxed);
    let report = process.join().unwrap();
    let st = fake.snapshot();
    assert_eq!(st.shutdown, None, "{report:?}");
    assert!(report.fault.is_none(), "{report:?}");
    // Each command's position at its stamp + lead, against the fake's steps on its true clock:
    // the step count within one step of it, within ±1 ms of that instant.
    let steps = &st.steps[&0];
    let per_m = 200.0 * 16.0 / 0.0226;
    let fake_epoch_ns = monotonic_ns() as f64 - fake.epoch.elapsed().as_secs_f64() * 1e9;
    let clock_at = |ns: f64| ((ns - fake_epoch_ns) * 1e-9 * fake.true_freq).max(0.0) as u64;
    let count = |clock: u64| -> i64 { steps.iter().filter(|s| s.clock <= clock).map(|s| if s.dir == 1 { 1 } else { -1 }).sum() };
    let first = (commands[0].filament_position * per_m).round();
    let (mut worst, mut checked) = (0.0f64, 0);
    for c in commands.iter().skip(1) {
        let at = c.stamp_ns as f64 + cfg.step_lead_time * 1e9;
        let want = c.filament_position * per_m - first;
        let (lo, hi) = (count(clock_at(at - 1e6)) as f64, count(clock_at(at + 1e6)) as f64);
        let miss = if want < lo.min(hi) {
            lo.min(hi) - want
        } else if want > lo.max(hi) {
            want - lo.max(hi)
        } else {
            0.0
        };
        worst = worst.max(miss);
        checked += 1;
    }
    let net: i64 = count(u64::MAX);
    eprintln!(
        "heat-up 25 → 118 °C in {reached:.1} s; {} temperatures, worst gap {worst_gap:.3} s; {} commands → {} steps (net {net}), \
         worst position error {worst:.2} steps at {checked} instants (±1 ms)",
        states.len(),
        report.commands,
        report.steps
    );
    assert_eq!(report.commands, 1201);
    assert!((net as f64 - (commands.last().unwrap().filament_position * per_m - first)).abs() <= 1.0, "net {net}");
    assert!(worst <= 1.0, "the steps' position left the command by {worst} steps");
}

#[test]
fn a_hot_end_that_does_not_heat_is_switched_off_and_reported_until_stopped() {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // A heater cartridge that gives almost nothing: verify_heater sees no rise.
    let fake = FakeMcu::start(FakeConfig { heater_power: 0.2, ..Default::default() }).unwrap();
    let mut cfg = board(&fake);
    cfg.check_gain_time = 1.5;
    let prefix = format!("strand-mcu-fault-{}", std::process::id());
    let service = ServicePorts::open(&ServiceNames::new(&prefix), "the-service").unwrap();
    static STOP: AtomicBool = AtomicBool::new(false);
    let process = spawn(cfg, &prefix, &STOP);
    let t0 = Instant::now();
    let (mut seq, mut faulted_at, mut after) = (0u64, None, 0);
    while t0.elapsed() < Duration::from_secs(15) {
        seq += 1;
        service.publish_heater_command(&heater_command(seq, 200.0)).unwrap();
        while let Some(s) = service.receive_heater_state().unwrap() {
            if s.flags & heater_flags::FAULT != 0 {
                faulted_at.get_or_insert(t0.elapsed().as_secs_f64());
                after += 1;
                assert_eq!(s.hot_end_power, 0.0);
            }
        }
        // Half a second of FAULT states after the first: it keeps saying so.
        if faulted_at.is_some_and(|t| t0.elapsed().as_secs_f64() > t + 0.5) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    STOP.store(true, Ordering::Relaxed);
    let report = process.join().unwrap();
    let faulted_at = faulted_at.expect("the fault reaches the service");
    let st = fake.snapshot();
    eprintln!("fault after {faulted_at:.1} s: {:?}; {after} FAULT states; the fake's heater duty {}", report.fault, st.heater_duty);
    assert!(report.fault.as_deref().is_some_and(|f| f.contains("not heating")), "{report:?}");
    assert!(after >= 4, "{after}");
    assert_eq!(st.heater_duty, 0.0, "the heater is off on the board");
}
