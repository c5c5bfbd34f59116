//! Temperatures end to end (CELL item 2), as separate processes over iceoryx2: strand-demo runs the
//! service on the robot clock, strand-sim (the robot and the heaters: `[thermal]`) and strand-feed
//! on a small job that opens cold with `M140`/`M104`/`M190`/`M109`. From the service's MCAP log:
//! the job holds at each wait until the measured temperature has been within the tolerance for
//! the settle time, the first extruding tick comes after the hot end settled, nothing extrudes
//! below `min_extrude_temp`, the job finishes, and the log replays bit for bit (the demo's verify,
//! with the heater measurements as recorded inputs).
//!
//! Needs the debug binaries `strand`, `strand-sim`, `strand-feed` and `strand-demo`
//! (`cargo build -p strand -p strand-sim -p strand-feed --bins`).

use std::process::Command;

use strand::log::messages::Tick;
use strand::log::reader::LogFile;
use strand_ipc::{HeatHold, JobOutcome, heater_flags};
use strand_testkit::{bin, root, square_program, temp_dir};

#[test]
fn m109_holds_the_printing_cell_until_the_hot_end_has_settled() {
    let dir = temp_dir("heat", "e2e");
    let square = square_program(&dir, 1, 1, 2400.0);
    let program = dir.join("heat.gcode");
    let body = std::fs::read_to_string(&square).unwrap();
    std::fs::write(&program, format!("M140 S60\nM104 S150\nM190 S60\nM109 S210\n{body}")).unwrap();
    let settle = 1.5;
    let out = Command::new(bin("strand-demo"))
        .arg("--gcode")
        .arg(&program)
        .args(["--json", "--out"])
        .arg(dir.join("demo"))
        .args(["--set", "controller.approach_speed_fraction=1.0"])
        .args(["--set", &format!("extruder.temperature_settle_time={settle}")])
        .current_dir(root())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "stdout: {stdout}\nstderr: {stderr}");
    let r: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"));
    assert_eq!(r["job_outcome"], "Finished", "{r}");
    assert_eq!(r["identical"], true, "the log replays bit for bit: {r}");
    // The demo's own summary of the heaters.
    assert!(r["heat"]["bed_wait_s"].as_f64().unwrap() > settle, "{}", r["heat"]);
    assert!(r["heat"]["hot_end_wait_s"].as_f64().unwrap() > settle, "{}", r["heat"]);
    assert!(r["heat"]["extruding_c"][0].as_f64().unwrap() >= 170.0, "{}", r["heat"]);

    let log = LogFile::open(std::path::Path::new(r["log"].as_str().unwrap())).unwrap();
    let (tolerance, min_extrude) = (3.0, 170.0);
    let mut dt = 0.0;
    let mut last_ns = None;
    let mut hot_end: Option<f64> = None;
    // The hot end's time within 210 ± 3 °C without a break, at each tick (s).
    let mut in_band_for = 0.0;
    let mut bed_held = 0u64;
    let mut hot_end_held = 0u64;
    let mut first_extruding = None;
    let mut in_band_at_first = 0.0;
    let mut finished = false;
    let mut ticks = 0u64;
    let mut seen_hold_after_bed = false;
    for t in log.ticks() {
        let t: Tick = t.unwrap();
        ticks += 1;
        if let Some(prev) = last_ns {
            dt = (t.input.time_ns - prev) as f64 * 1e-9;
        }
        last_ns = Some(t.input.time_ns);
        let s = &t.output.status;
        if s.heater_flags & heater_flags::HOT_END != 0 {
            hot_end = Some(s.hot_end_temperature);
        }
        assert_ne!(s.heater_flags & heater_flags::ACTING, 0, "the demo acts on the sim's temperatures");
        match HeatHold::from_u32(s.heat_hold) {
            Some(HeatHold::Bed) => {
                bed_held += 1;
                assert_eq!(s.heat_hold_band, [57.0, 63.0]);
                assert!(!seen_hold_after_bed, "the bed's wait comes first");
            }
            Some(HeatHold::HotEnd) => {
                hot_end_held += 1;
                seen_hold_after_bed = true;
                assert_eq!(s.heat_hold_band, [207.0, 213.0]);
            }
            _ => {}
        }
        if s.heat_hold != 0 {
            assert_eq!(t.output.extruder.filament_rate, 0.0, "nothing extrudes during a wait");
        }
        match hot_end {
            Some(h) if (h - 210.0).abs() <= tolerance => in_band_for += dt,
            _ => in_band_for = 0.0,
        }
        if t.output.extruder.filament_rate > 0.0 {
            let h = hot_end.expect("a measured hot end before any extrusion");
            assert!(h >= min_extrude, "extruding at {h} °C");
            if first_extruding.is_none() {
                first_extruding = Some(ticks);
                in_band_at_first = in_band_for;
            }
        }
        finished |= s.job_outcome == JobOutcome::Finished as u32;
    }
    assert!(finished);
    assert!(bed_held > 0 && hot_end_held > 0, "both waits held: bed {bed_held}, hot end {hot_end_held} ticks");
    // The first extruding tick only once the hot end has been within 210 ± 3 °C for the settle time.
    let first = first_extruding.expect("the job extruded");
    assert!(in_band_at_first >= settle, "first extrusion at tick {first} after {in_band_at_first:.3} s in band (settle {settle} s)");
    // The waits took the fast plant's heat-up (default.toml's [thermal]: the bed 25 → 57 °C, the
    // hot end from where the bed's wait left it) plus a settle each: seconds, not milliseconds.
    let held_s = (bed_held + hot_end_held) as f64 * dt;
    assert!(held_s > 2.0 * settle + 2.0, "held {held_s:.2} s");
    // The demo's own check-job predicted the run, heat-ups included (its `[thermal]` plant is the
    // sim's), to 1 %.
    let (predicted, measured) = (r["predicted_s"].as_f64().unwrap(), r["job_time_s"].as_f64().unwrap());
    assert!((predicted / measured - 1.0).abs() <= 0.01, "predicted {predicted:.3} s, measured {measured:.3} s");
    eprintln!("predicted {predicted:.3} s, measured {measured:.3} s");
    eprintln!("held {held_s:.2} s (bed {bed_held}, hot end {hot_end_held} ticks), first extrusion after {in_band_at_first:.3} s in band");
}
