//! The extruder board against the fake MCU over a real pty: steps, heater, safety shutdown.

use strand_mcu::board::ExtruderBoard;
use strand_mcu::config::{BoardConfig, ThermistorConfig};
use strand_mcu::fake::{FakeConfig, FakeMcu};
use strand_mcu::mcu::{ConnectOptions, McuError};

/// These tests run the host and the fake MCU on real time over a pty, with timing bounds: one at a
/// time, so that on a loaded machine they do not also compete with each other.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn opts() -> ConnectOptions {
    ConnectOptions { timeout: 1.0, sync_interval: 0.01, sync_samples: 8, clock_interval: 0.1 }
}

fn board_cfg(fake: &FakeMcu) -> BoardConfig {
    BoardConfig {
        serial: fake.path.clone(),
        baud: 250_000,
        step_pin: "PA3".into(),
        dir_pin: "PA4".into(),
        invert_dir: false,
        enable_pin: Some("PA5".into()),
        microsteps: 16,
        full_steps_per_rotation: 200,
        rotation_distance: 0.0226,
        step_pulse_duration: 2e-6,
        max_step_error: 25e-6,
        step_lead_time: 0.1,
        heater_pin: "PB1".into(),
        pwm_cycle_time: 0.1,
        max_power: 1.0,
        heater_max_duration: 0.5,
        thermistor_pin: "gpio26".into(),
        thermistor: ThermistorConfig::Beta { t0: 25.0, r0: 100_000.0, beta: 3950.0 },
        pullup_resistor: 4700.0,
        inline_resistor: 0.0,
        report_time: 0.1,
        sample_count: 8,
        sample_time: 0.001,
        pid_kp: 8.0,
        pid_ki: 1.5,
        pid_kd: 5.0,
        smooth_time: 1.0,
        min_temp: 0.0,
        max_temp: 280.0,
        hysteresis: 5.0,
        max_error: 120.0,
        heating_gain: 2.0,
        check_gain_time: 20.0,
    }
}

/// 4 mm/s after a 0.2 s ramp, a 1 mm retraction at 0.6 s and its return at 0.8 s.
fn profile(t: f64) -> f64 {
    let v = 0.004;
    let base = if t < 0.2 { 0.5 * v / 0.2 * t * t } else { v * 0.1 + v * (t - 0.2) };
    let r = |a: f64| ((t - a) / 0.025).clamp(0.0, 1.0);
    base - 0.001 * r(0.6) + 0.001 * r(0.8)
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[test]
fn steps_from_a_1khz_profile_land_on_time() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let mut b = ExtruderBoard::connect(board_cfg(&fake), opts()).unwrap();
    assert!(fake.snapshot().finalized);
    let start = b.mcu.now() + 0.3;
    let dur = 1.2;
    let mut ideal = Vec::new(); // (host time, direction)
    let mut gen_ = strand_mcu::stepcompress::StepGenerator::new(200, 16, 0.0226);
    let mut i = 0usize;
    let mut counts = Vec::new();
    loop {
        // Feed the samples up to 0.2 s ahead, as a controller planning ahead would.
        while (i as f64) * 0.001 <= dur && start + i as f64 * 0.001 < b.mcu.now() + 0.2 {
            let t = i as f64 * 0.001;
            b.sample(start + t, profile(t));
            ideal.extend(gen_.sample(start + t, profile(t)));
            // The MCU clock the host commanded for this instant (its estimate at sampling time).
            let est = b.mcu.clock.as_ref().unwrap().clock_at(start + t) - f64::from(FakeConfig::default().clock_start);
            counts.push((est, gen_.position));
            i += 1;
        }
        b.poll(0.001).unwrap();
        if b.mcu.now() > start + dur + 0.3 {
            break;
        }
    }
    b.flush_steps().unwrap();
    for _ in 0..50 {
        b.poll(0.002).unwrap();
    }
    let st = fake.snapshot();
    assert_eq!(st.shutdown, None);
    let got = &st.steps[&0];
    assert_eq!(got.len(), ideal.len(), "every step arrives");
    // Truth: the fake's clock is (instant - fake.epoch) * true_freq.
    let off = b.mcu.epoch().duration_since(fake.epoch).as_secs_f64();
    let mut errs: Vec<f64> = Vec::new();
    for (g, (t, d)) in got.iter().zip(&ideal) {
        assert_eq!(g.dir, *d);
        let ideal_clock = (t + off) * fake.true_freq;
        errs.push((g.clock as f64 - ideal_clock) / fake.true_freq * 1e6);
    }
    let mut abs: Vec<f64> = errs.iter().map(|e| e.abs()).collect();
    let p99 = percentile(&mut abs, 0.99);
    let max = abs.last().copied().unwrap();
    let mut worst_count = 0i64;
    // Step count vs the commanded position at every sample instant, on the MCU's clock as the
    // host commanded it (the clock-sync error is reported above, separately).
    for &(est, cmd) in &counts {
        let c = est as u64;
        let n: i64 = got.iter().filter(|s| s.clock <= c).map(|s| if s.dir == 1 { 1 } else { -1 }).sum();
        let start_pos = counts[0].1;
        worst_count = worst_count.max((n + start_pos - cmd).abs());
    }
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    let spread = errs.iter().map(|e| (e - mean).abs()).fold(0.0, f64::max);
    println!(
        "{} steps, timing error p99 {p99:.0} us, max {max:.0} us (mean {mean:.0} us = clock-sync offset, spread about it {spread:.0} us); worst count error {worst_count} steps",
        got.len()
    );
    assert!(max < 1000.0, "max step timing error {max} us");
    assert!(worst_count <= 1);
}

#[test]
fn pid_heats_the_fake_hot_end_and_holds_210() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let mut cfg = board_cfg(&fake);
    cfg.heater_max_duration = 3.0;
    let mut b = ExtruderBoard::connect(cfg, opts()).unwrap();
    b.target = 210.0;
    let t0 = b.mcu.now();
    let mut reached = None;
    let mut peak: f64 = 0.0;
    let mut hold: f64 = 0.0;
    while b.mcu.now() - t0 < 11.0 {
        b.poll(0.005).unwrap();
        for r in b.take_readings() {
            let t = r.time - t0;
            if reached.is_none() && r.temp >= 208.0 {
                reached = Some(t);
            }
            peak = peak.max(r.temp);
            if t > 9.0 {
                hold = hold.max((r.temp - 210.0).abs());
            }
        }
    }
    let st = fake.snapshot();
    println!(
        "heat-up to within 2 K of 210 °C: {:.1} s, overshoot {:.1} K, hold ±{:.2} K (fake block {:.1} °C)",
        reached.unwrap_or(f64::NAN),
        peak - 210.0,
        hold,
        st.block_temp
    );
    assert!(reached.is_some_and(|t| t < 9.0));
    assert!(peak - 210.0 < 5.0);
    assert!(hold < 2.5);
    assert_eq!(st.shutdown, None);
}

#[test]
fn fake_shuts_heater_down_when_not_refreshed() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let mut b = ExtruderBoard::connect(board_cfg(&fake), opts()).unwrap();
    b.target = 210.0;
    let t0 = b.mcu.now();
    while b.mcu.now() - t0 < 0.5 {
        b.poll(0.005).unwrap();
    }
    assert!(fake.snapshot().heater_duty > 0.5);
    b.refresh_heater = false;
    let stopped = b.mcu.now();
    let err = loop {
        match b.poll(0.005) {
            Ok(()) => assert!(b.mcu.now() - stopped < 2.0, "no shutdown"),
            Err(e) => break e,
        }
    };
    let st = fake.snapshot();
    println!("after {:.2} s without refresh: {err}", b.mcu.now() - stopped);
    assert!(matches!(err, McuError::Shutdown(ref s) if s.contains("Missed scheduling of next hard pwm event")));
    assert_eq!(st.heater_duty, 0.0);
}

#[test]
fn missing_pin_is_named_and_late_step_shuts_down() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let mut cfg = board_cfg(&fake);
    cfg.step_pin = "PZ9".into();
    let e = ExtruderBoard::connect(cfg, opts()).unwrap_err();
    assert_eq!(e.to_string(), "the MCU has no pin 'PZ9'");
    // A step scheduled in the past: "Timer too close", like the firmware.
    let mut b = ExtruderBoard::connect(board_cfg(&fake), opts()).unwrap();
    let now = b.mcu.now();
    b.sample(now - 0.1, 0.0);
    b.sample(now - 0.05, 0.0001);
    b.flush_steps().unwrap();
    let err = loop {
        if let Err(e) = b.poll(0.005) {
            break e;
        }
        assert!(b.mcu.now() - now < 1.0);
    };
    assert!(err.to_string().contains("Timer too close"), "{err}");
}

#[test]
fn reconnect_compares_config_crc() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let first = ExtruderBoard::connect(board_cfg(&fake), opts()).unwrap();
    let crc = first.config_crc;
    drop(first);
    // Same configuration: accepted without reconfiguring (the MCU's sequence number continues
    // from the first host; the new host adopts it).
    let again = ExtruderBoard::connect(board_cfg(&fake), opts()).unwrap();
    assert_eq!(again.config_crc, crc);
    drop(again);
    // Different configuration: the MCU must be restarted.
    let mut cfg = board_cfg(&fake);
    cfg.heater_pin = "PB2".into();
    let e = ExtruderBoard::connect(cfg, opts()).unwrap_err();
    println!("{e}");
    assert!(matches!(e, McuError::ConfigMismatch { .. }));
}
