//! The host against the fake MCU over a real pty: connect, errors, retransmission.

use std::time::Instant;

use strand_mcu::fake::{FakeConfig, FakeMcu, Faults, Personality};
use strand_mcu::mcu::{ConnectOptions, Mcu, McuError};

/// These tests run the host and the fake MCU on real time over a pty, with timing bounds: one at a
/// time, so that on a loaded machine they do not also compete with each other.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn fast() -> ConnectOptions {
    ConnectOptions { timeout: 1.0, sync_interval: 0.01, sync_samples: 8, clock_interval: 0.1 }
}

#[test]
fn connects_identifies_and_syncs_clock() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig::default()).unwrap();
    let t0 = Instant::now();
    let mut m = Mcu::connect(&fake.path, 250_000, fast()).unwrap();
    println!("connect took {:.3} s", t0.elapsed().as_secs_f64());
    assert_eq!(m.dict.constant_str("MCU").unwrap(), "rp2040");
    assert_eq!(m.dict.constant_f64("CLOCK_FREQ").unwrap(), 12e6);
    assert_eq!(m.dict.enum_value("pin", "PB3").unwrap(), 19);
    // Run past the fake's 32-bit wrap (1 s after start) and compare clocks.
    let until = m.now() + 1.2;
    while m.now() < until {
        m.poll(0.01).unwrap();
    }
    let host_est = m.clock_now() as f64;
    let truth = fake.epoch.elapsed().as_secs_f64() * fake.true_freq + f64::from(FakeConfig::default().clock_start);
    let err_us = (host_est - truth) / 12.0;
    let cs = m.clock.as_ref().unwrap();
    let ppm = (cs.freq() / fake.true_freq - 1.0) * 1e6;
    println!("clock error {err_us:.0} us, frequency error {ppm:.1} ppm, half rtt {:.0} us", cs.min_half_rtt * 1e6);
    assert!(err_us.abs() < 1000.0, "clock error {err_us} us");
    assert!(host_est > 4_294_967_296.0, "64-bit clock past the wrap");
}

#[test]
fn silent_garbage_and_foreign_boards_fail_fast_and_say_why() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for (p, want) in [
        (Personality::Silent, "no answer"),
        (Personality::Garbage, "not in Klipper's protocol"),
        (Personality::GcodeFirmware, "other firmware"),
    ] {
        let fake = FakeMcu::start(FakeConfig { personality: p, ..Default::default() }).unwrap();
        let t0 = Instant::now();
        let e = Mcu::connect(&fake.path, 250_000, fast()).unwrap_err();
        let s = e.to_string();
        println!("{p:?}: {s} ({:.2} s)", t0.elapsed().as_secs_f64());
        assert!(s.contains(want), "{p:?}: {s}");
        assert!(t0.elapsed().as_secs_f64() < 2.0);
        if p == Personality::Silent {
            assert!(matches!(e, McuError::NoAnswer(_)));
        }
    }
    let e = Mcu::connect(std::path::Path::new("/dev/does-not-exist"), 250_000, fast()).unwrap_err();
    assert!(e.to_string().contains("/dev/does-not-exist"));
}

#[test]
fn retransmits_through_drops_corruption_and_garbage() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let faults = Faults { drop_rx_every: 5, corrupt_tx_every: 7, garbage_tx_every: 11 };
    let fake = FakeMcu::start(FakeConfig { faults, ..Default::default() }).unwrap();
    let mut m = Mcu::connect(&fake.path, 250_000, fast()).unwrap();
    // Many round trips; each must eventually succeed.
    for _ in 0..60 {
        let r = m.request("get_config", &[], "config", 2.0).unwrap();
        assert_eq!(r.msg.int("move_count").unwrap(), 1024);
    }
    let st = fake.snapshot();
    println!(
        "retransmits {}, fake dropped {} blocks, corrupted {}, sent {} naks",
        m.retransmits(),
        st.dropped_rx,
        st.corrupted_tx,
        st.naks
    );
    assert!(st.dropped_rx > 5 && st.corrupted_tx > 5);
    assert!(m.retransmits() > 0);
}

#[test]
fn identify_binary_prints_the_board() {
    let _one_at_a_time = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let fake = FakeMcu::start(FakeConfig { mcu: "stm32f446xx".into(), ..Default::default() }).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strand-mcu"))
        .args(["--serial", fake.path.to_str().unwrap(), "--identify"])
        .output()
        .unwrap();
    let s = String::from_utf8_lossy(&out.stdout);
    print!("{s}");
    assert!(out.status.success());
    assert!(s.contains("mcu: stm32f446xx") && s.contains("clock_freq: 12000000 Hz"));
}
