//! The job check and the run agree: bundled and generated jobs go through `strand check-job` and
//! through `strand-demo` (service + sim + feeder on the robot clock), and
//! - the predicted job time is within 1 % of the demo's measured one;
//! - a job the check passes finishes in the demo without a fault;
//! - a job the check fails is refused by the feeder (exit 3, the report naming the line), and when
//!   forced through (`--no-check`) it faults at the line the check named, with `TcpErrorLimit`,
//!   and no filament is pushed after the fault.

use std::path::Path;
use std::process::Command;
use strand_testkit::{bin, json_f64, root, square_program, temp_dir};

use strand::log::reader::LogFile;
use strand_core::Event;

/// The approach at full joint speed (both sides use it): seconds of robot time saved per test.
const FAST_APPROACH: &str = "controller.approach_speed_fraction=1.0";

/// `strand check-job --json`: (exit code, report).
fn check_job(job: &Path, config: &str) -> (i32, serde_json::Value) {
    let out = Command::new(bin("strand"))
        .args(["check-job", "--json", "--config", config, "--set", FAST_APPROACH])
        .arg(job)
        .current_dir(root())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
    let report = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}\n{}", String::from_utf8_lossy(&out.stderr)));
    (out.status.code().unwrap_or(-1), report)
}

/// `strand-demo --json`: (exit code, summary, stderr).
fn demo(dir: &Path, job: &Path, config: &str, extra: &[&str]) -> (i32, serde_json::Value, String) {
    let out = Command::new(bin("strand-demo"))
        .args(["--json", "--config", config, "--set", FAST_APPROACH, "--gcode"])
        .arg(job)
        .args(extra)
        .arg("--out")
        .arg(dir)
        .current_dir(root())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let summary = serde_json::from_str(stdout.trim()).unwrap_or(serde_json::Value::Null);
    (out.status.code().unwrap_or(-1), summary, stderr)
}

#[test]
fn a_clean_job_finishes_in_the_demo_in_the_predicted_time() {
    let dir = temp_dir("check", "agree");
    let jobs = [
        (square_program(&dir, 2, 3, 2400.0), "config/iiwa7.toml"),
        (root().join("tests/data/gcode/orca/square20_klipper.gcode"), "config/iiwa7.toml"),
        (root().join("tests/data/gcode/cura/square20.gcode"), "config/irb140.toml"),
    ];
    for (k, (job, config)) in jobs.iter().enumerate() {
        let (code, report) = check_job(job, config);
        assert_eq!((code, report["clean"].as_bool()), (0, Some(true)), "{}: {report:#}", job.display());
        assert_eq!(report["outcome"], "Finished");
        let predicted = json_f64(&report, &["time", "total_s"]);
        // The cell's config as the check read it: without this the demo acts on the temperatures
        // the Orca job sets (`[extruder] heater = "wire"`, a minute of heat-up with iiwa7.toml's
        // built-in plant); the heat-up's prediction is checked in tests/heat_e2e.rs.
        let (code, summary, stderr) = demo(&dir.join(format!("demo-{k}")), job, config, &["--set", "extruder.heater=\"none\""]);
        assert_eq!(code, 0, "{}: a job the check passes must finish: {stderr}", job.display());
        assert_eq!(summary["job_outcome"], "Finished");
        assert!(summary["faults"].as_array().unwrap().is_empty(), "{summary}");
        let measured = json_f64(&summary, &["job_time_s"]);
        assert_eq!(json_f64(&summary, &["predicted_s"]), predicted, "the demo's own check is the same check");
        let ratio = predicted / measured;
        println!("{}: predicted {predicted:.3} s, measured {measured:.3} s, ratio {ratio:.4}", job.display());
        assert!((ratio - 1.0).abs() <= 0.01, "{}: predicted {predicted} s, measured {measured} s", job.display());
        // The run stayed clear of the watchdog, as the check saw it would (the run adds the
        // measured robot's share on top of the commanded TCP's error).
        let (seen, limit, predicted_error) = (
            json_f64(&summary, &["tcp_error_fault_m"]),
            json_f64(&summary, &["tcp_error_limit_m"]),
            json_f64(&report, &["max_tcp_error_m"]),
        );
        assert!(seen < limit && seen < predicted_error + 0.3e-3, "watchdog saw {seen} m, check predicted {predicted_error} m");
    }
}

#[test]
fn a_job_out_of_reach_is_refused_and_forced_through_it_faults_at_the_line_the_check_named() {
    // The job: its middle line runs 0.65 m past the iiwa7's reach.
    let dir = temp_dir("check", "reach");
    let job = dir.join("unreachable.gcode");
    std::fs::write(&job, "G21\nG90\nM83\nG1 Z0.3 F3000\nG1 X20 Y0 E1 F1200\nG1 X1000 Y0 E10\nG1 X20 Y20 E1\n").unwrap();
    let config = "config/iiwa7.toml";
    let (code, report) = check_job(&job, config);
    assert_eq!(code, 3, "{report:#}");
    assert_eq!(report["clean"], false);
    let problems = report["problems"].as_array().unwrap();
    let fault = problems.iter().find(|p| p["kind"] == "fault").unwrap_or_else(|| panic!("no fault predicted: {report:#}"));
    assert_eq!(fault["fault"], "TcpErrorLimit");
    let line = fault["lines"][0].as_u64().unwrap();
    assert_eq!(line, 6, "the far line: {report:#}");
    let unreachable = problems.iter().find(|p| p["kind"] == "unreachable").expect("an unreachable stretch");
    assert!(json_f64(unreachable, &["worst"]) > 0.6, "worst distance {unreachable}");

    // The demo checks it first and refuses it with the report, naming the line; nothing runs.
    let (code, _, stderr) = demo(&dir.join("refused"), &job, config, &[]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("refused") && stderr.contains("unreachable.gcode:6"), "{stderr}");
    assert!(!dir.join("refused/run.mcap").exists(), "nothing ran: no log of idle ticks");
    // So does the feeder (exit 3), before it looks for a service.
    let out = Command::new(bin("strand-feed"))
        .args(["--config", config, "--prefix", "strand/check-test-none", "--wait-service", "30", "--quiet"])
        .arg(&job)
        .current_dir(root())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("unreachable.gcode:6") && stderr.contains("would fault: TcpErrorLimit"), "{stderr}");

    // Forced through: the run faults at that line, and extrudes nothing from the fault on.
    let (code, summary, stderr) = demo(&dir.join("forced"), &job, config, &["--no-check"]);
    assert_eq!(code, 1, "a faulted job is not a success: {stderr}");
    assert_eq!(summary["job_outcome"], "Faulted", "{summary}");
    let log = LogFile::open(&dir.join("forced/run.mcap")).unwrap();
    let mut faulted_at = None;
    let mut pushed_after = 0.0;
    let mut last_position = None;
    for tick in log.ticks() {
        let tick = tick.unwrap();
        let o = &tick.output;
        for e in o.events() {
            if let Event::Fault { code, seq, line: at, value } = *e {
                assert_eq!(code, strand_ipc::FaultCode::TcpErrorLimit);
                assert_eq!(at as u64, line, "the run faults where the check said (segment {seq})");
                assert!(value > 2e-3 && value < 4e-3, "TCP error at the fault: {value} m");
                faulted_at = Some(tick.input.tick);
                last_position = Some(o.extruder.filament_position);
            }
        }
        if faulted_at.is_some_and(|t| tick.input.tick > t) {
            pushed_after += o.extruder.filament_rate.abs();
            assert_eq!(Some(o.extruder.filament_position), last_position, "filament moved after the fault");
        }
    }
    assert!(faulted_at.is_some(), "no fault in the log");
    assert_eq!(pushed_after, 0.0);
    // The check's predicted time of the fault and the run's agree (the run counts from its first tick
    // out of Idle; the check from Start).
    let predicted = fault["time_s"][0].as_f64().unwrap();
    let measured = json_f64(&summary, &["job_time_s"]);
    assert!((predicted - measured).abs() < 0.01 * measured + 0.05, "fault predicted at {predicted} s, run ended at {measured} s");
}
