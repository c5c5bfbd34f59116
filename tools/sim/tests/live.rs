//! The live view and the operator's console against a running service, in processes:
//!
//! - the Foxglove server: an independent client (Python, `websockets` + `mcap-ros2-support`,
//!   `tools/python/foxglove_client.py`) watches a job; every channel of the MCAP is advertised with
//!   its schema, the robot description arrives (latched), `/tf` names every link, and the sampled
//!   live messages equal the log's, decoded independently (`tools/python/check_live.py`); the view
//!   is read-only unless the config allows control, and then a client's pause request pauses; a
//!   client that connects mid-print gets the bead and the trail from the start;
//! - `strand ctl`: every verb against a running job, acknowledged or refused with the reason, and
//!   no service → exit 1;
//! - strand-feed's keys: pause, feed override, resume and stop from its stdin;
//! - `--resume-layer`: a job resumed at its second layer finishes;
//! - `strand-demo --view`: the whole cell (plant in real time) served live, and it still finishes
//!   with a log that replays identically.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{ChildStdin, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};
use strand_testkit::{Reaped, bin, root, square_program, temp_dir};

/// The approach at full joint speed: seconds saved in every test (debug builds are slow).
const FAST_APPROACH: &str = "controller.approach_speed_fraction=1.0";

/// `strand run` on the timer clock, echoing its commands as joint state, with `extra` arguments
/// (`--exit-when-done` to end with the job);
/// returns the process and, with the live view on, the address it serves (read from its log).
fn service(prefix: &str, extra: &[&str]) -> (Reaped, Option<String>) {
    let mut child = Command::new(bin("strand"))
        .args(["run", "--config", "config/default.toml", "--echo", "--prefix", prefix, "--set", FAST_APPROACH])
        .args(extra)
        .current_dir(root())
        .env("RUST_LOG", "warn,strand=info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let err = child.stderr.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            eprintln!("[strand] {line}");
            if let Some(i) = line.find("live view on ws://") {
                let addr: String = line[i + "live view on ".len()..].split_whitespace().next().unwrap_or("").to_string();
                let _ = tx.send(addr);
            }
        }
    });
    let view = extra.contains(&"--view");
    let addr = view.then(|| rx.recv_timeout(Duration::from_secs(30)).expect("the live view never started"));
    (Reaped(child), addr)
}

fn ctl(prefix: &str, args: &[&str]) -> Output {
    Command::new(bin("strand")).args(["ctl", "--prefix", prefix, "--timeout", "5"]).args(args).output().unwrap()
}

/// `strand ctl status --json`.
fn status(prefix: &str) -> serde_json::Value {
    let out = ctl(prefix, &["status", "--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn wait_state(prefix: &str, secs: u64, want: &[&str]) -> serde_json::Value {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        let s = status(prefix);
        if want.iter().any(|w| s["run_state"] == *w) {
            return s;
        }
        assert!(Instant::now() < deadline, "waited {secs} s for {want:?}; last {s}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn feed(prefix: &str, program: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(bin("strand-feed"));
    c.arg(program)
        .args(["--config", "config/default.toml", "--prefix", prefix, "--quiet", "--no-check", "--set", FAST_APPROACH])
        .args(extra)
        .current_dir(root());
    c
}

fn python(script: &str, args: &[&str]) -> Command {
    let mut c = Command::new("python3");
    c.arg(root().join("tools/python").join(script)).args(args);
    c
}

/// True when the independent client's Python packages are there (`pip install websockets==15.0.1
/// mcap-ros2-support==0.6.0`). Without them the view tests say so and pass, unless
/// `STRAND_REQUIRE_PYTHON=1` (CI installs them and sets it).
fn python_client_available() -> bool {
    let ok = Command::new("python3").args(["-c", "import websockets, mcap_ros2"]).output().is_ok_and(|o| o.status.success());
    if !ok {
        assert!(std::env::var_os("STRAND_REQUIRE_PYTHON").is_none(), "STRAND_REQUIRE_PYTHON is set but websockets / mcap_ros2 are missing");
        eprintln!(
            "SKIPPED: python3 with websockets and mcap-ros2-support is needed (pip install websockets==15.0.1 mcap-ros2-support==0.6.0)"
        );
    }
    ok
}

fn assert_ok(what: &str, out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(0), "{what}: {stderr}\n{}", String::from_utf8_lossy(&out.stdout));
    stderr
}

#[test]
fn the_live_view_serves_the_logs_channels_and_agrees_with_the_mcap() {
    if !python_client_available() {
        return;
    }
    let dir = temp_dir("live", "view");
    let program = square_program(&dir, 2, 3, 2400.0);
    let prefix = format!("strand/livetest-{}-view", std::process::id());
    let log = dir.join("run.mcap");
    let (mut svc, addr) =
        service(&prefix, &["--view", "--exit-when-done", "--set", "view.address=\"127.0.0.1:0\"", "--log", log.to_str().unwrap()]);
    let url = addr.unwrap();
    // The client watches until the service ends (exit 3: the server closed first), and tries to
    // publish a control request, which a read-only view must not take.
    let client =
        python("foxglove_client.py", &[&url, "--seconds", "120", "--json", "--publish", "/strand/control", r#"{"command": "stop"}"#])
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let fed = feed(&prefix, &program, &[]).output().unwrap();
    assert!(assert_ok("strand-feed", &fed).contains("job finished"));
    let t0 = Instant::now();
    while svc.0.try_wait().unwrap().is_none() && t0.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(svc.0.try_wait().unwrap().is_some_and(|s| s.success()), "the service ended with the job");
    let watched = client.wait_with_output().unwrap();
    assert!(matches!(watched.status.code(), Some(0 | 3)), "client: {:?}", watched.status);
    let live: serde_json::Value = serde_json::from_slice(&watched.stdout).unwrap();
    assert_eq!(live["publish"], "refused: no clientPublish capability", "read-only by default");
    assert!(live["server_info"]["name"].as_str().unwrap().contains("iiwa7"), "{}", live["server_info"]);
    let live_file = dir.join("live.json");
    std::fs::write(&live_file, &watched.stdout).unwrap();
    // The view is fed every tick; the file has the derived channels at `[log] derived_rate_hz`:
    // compare with the log regenerated at every tick (the same writer, the run's log times).
    let full = dir.join("run-full.mcap");
    let regenerated =
        Command::new(bin("strand-replay")).args(["regenerate", log.to_str().unwrap(), "-o", full.to_str().unwrap()]).output().unwrap();
    assert_ok("strand-replay regenerate", &regenerated);
    let checked = python("check_live.py", &[live_file.to_str().unwrap(), full.to_str().unwrap(), "--json", "--layout"])
        .arg(root().join("tools/foxglove/strand.json"))
        .output()
        .unwrap();
    let report: serde_json::Value = serde_json::from_slice(&checked.stdout).unwrap_or_else(|e| panic!("{e}: {checked:?}"));
    assert_eq!(report["ok"], true, "{report}");
    assert!(report["compared"].as_u64().unwrap() >= 200, "{report}");
    // Decimated for the network: well under the log's rate (a tick is ~2 kB on 16 channels).
    assert!(report["bytes_per_s"].as_f64().unwrap() < 400e3, "{report}");
    eprintln!("live view: {report}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_viewer_may_pause_only_when_the_config_allows_control() {
    if !python_client_available() {
        return;
    }
    let dir = temp_dir("live", "control");
    let program = square_program(&dir, 1, 40, 1200.0);
    let prefix = format!("strand/livetest-{}-control", std::process::id());
    let (_svc, addr) =
        service(&prefix, &["--view", "--no-log", "--set", "view.address=\"127.0.0.1:0\"", "--set", "view.allow_control=true"]);
    let mut fed = feed(&prefix, &program, &[]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    wait_state(&prefix, 60, &["Running"]);
    // Four seconds into the print (80 mm at 20 mm/s: a chunk of the trail and part of the next),
    // a viewer connects: it gets the trail and the bead from the start, then takes control.
    std::thread::sleep(Duration::from_secs(4));
    let url = addr.unwrap();
    let topics = "/status,/bead,/path/executed";
    let out = python(
        "foxglove_client.py",
        &[&url, "--seconds", "2", "--json", "--topics", topics, "--publish", "/strand/control", r#"{"command": "pause"}"#],
    )
    .output()
    .unwrap();
    let live: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {out:?}"));
    for topic in ["/path/executed", "/bead"] {
        let markers = live["topics"][topic]["first"]["markers"].as_array().unwrap_or_else(|| panic!("{topic}: {}", live["topics"]));
        assert!(markers.len() >= 2, "{topic}: the first message holds {} chunks", markers.len());
        if topic == "/path/executed" {
            assert_eq!(markers[0]["id"], 0, "{topic}: the history starts at the first chunk");
        }
        let points: usize = markers.iter().map(|m| m["points"].as_array().unwrap().len()).sum();
        assert!(points > 120, "{topic}: {points} points");
    }
    assert_eq!(live["publish"], "sent", "{live}");
    assert!(live["server_info"]["capabilities"].as_array().unwrap().iter().any(|c| c == "clientPublish"), "{live}");
    wait_state(&prefix, 10, &["Paused"]);
    assert_ok("ctl stop", &ctl(&prefix, &["stop"]));
    assert_eq!(fed.wait().unwrap().code(), Some(6), "the feeder saw the job stopped");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn strand_ctl_pauses_overrides_resumes_stops_and_refuses_with_reasons() {
    let dir = temp_dir("live", "ctl");
    // A long, slow job: 40 loops of a 10 mm square at 20 mm/s (32 s).
    let program = square_program(&dir, 1, 40, 1200.0);
    let prefix = format!("strand/livetest-{}-ctl", std::process::id());
    let (_svc, _) = service(&prefix, &["--no-log"]);
    // No job yet: a pause is refused, naming why.
    let out = ctl(&prefix, &["pause"]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("NotAllowed (only a running job can pause)"), "{out:?}");
    let mut fed = feed(&prefix, &program, &[]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    wait_state(&prefix, 60, &["Running"]);
    // Pause: acknowledged (Pausing or Paused), then the path stands still.
    let out = ctl(&prefix, &["pause"]);
    assert_ok("pause", &out);
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("Paus"), "{out:?}");
    let paused = wait_state(&prefix, 10, &["Paused"]);
    std::thread::sleep(Duration::from_millis(300));
    let still = status(&prefix);
    assert_eq!(still["run_state"], "Paused");
    assert_eq!(still["path_position_m"], paused["path_position_m"], "a paused job does not move");
    // Overrides: taken, or refused with the range.
    assert_ok("feed 50", &ctl(&prefix, &["feed", "50"]));
    assert_eq!(status(&prefix)["feed_override"], 0.5);
    let out = ctl(&prefix, &["feed", "500"]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("BadValue (the feed override must lie in 1 to 200 %)"), "{out:?}");
    assert_ok("flow 90", &ctl(&prefix, &["flow", "90"]));
    assert_eq!(status(&prefix)["flow_override"], 0.9);
    let out = ctl(&prefix, &["clear-fault"]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no fault to clear"), "{out:?}");
    // Resume: it continues from where it stood.
    assert_ok("resume", &ctl(&prefix, &["resume"]));
    std::thread::sleep(Duration::from_millis(500));
    let moving = status(&prefix);
    assert_eq!(moving["run_state"], "Running");
    assert!(moving["path_position_m"].as_f64().unwrap() > paused["path_position_m"].as_f64().unwrap());
    // The status: the job as the feeder sees it (name, progress, layer, ETA) beside the
    // controller's state and overrides.
    let line = ctl(&prefix, &["status"]);
    let text = String::from_utf8_lossy(&line.stdout);
    assert!(text.starts_with("Running · job InProgress square.gcode ") && text.contains("feed 50 % flow 90 %"), "{text}");
    assert!(text.contains(" · layer ") && text.contains(" · ETA "), "{text}");
    let s = status(&prefix);
    let job = &s["job"];
    assert_eq!(job["name"], "square.gcode", "{s}");
    let fraction = job["fraction"].as_f64().unwrap();
    assert!(fraction > 0.0 && fraction < 1.0, "{s}");
    assert!(job["eta_s"].as_f64().is_some_and(|e| e > 0.0), "{s}");
    assert_eq!(job["last_seq"].as_u64(), Some(161), "a travel and 40 × 4 lines: {s}");
    // Stop: the job ends Stopped and the feeder says so.
    assert_ok("stop", &ctl(&prefix, &["stop"]));
    assert_eq!(fed.wait().unwrap().code(), Some(6));
    // Emergency stop latches a fault; a stop is then refused; clear-fault clears it.
    assert_ok("estop", &ctl(&prefix, &["estop"]));
    assert_eq!(status(&prefix)["fault"], "EmergencyStop");
    let out = ctl(&prefix, &["stop"]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("clear-fault first"), "{out:?}");
    assert_ok("clear-fault", &ctl(&prefix, &["clear-fault"]));
    assert_eq!(status(&prefix)["run_state"], "Idle");
    // No service under a prefix: exit 1, saying so.
    let out = Command::new(bin("strand")).args(["ctl", "--prefix", "strand/nobody-here", "--timeout", "0.3", "status"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no strand service under prefix"), "{out:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn press(stdin: &mut ChildStdin, key: &str) {
    stdin.write_all(key.as_bytes()).unwrap();
    stdin.flush().unwrap();
}

#[test]
fn strand_feed_keys_pause_change_the_feed_resume_and_stop() {
    let dir = temp_dir("live", "keys");
    let program = square_program(&dir, 1, 40, 1200.0);
    let prefix = format!("strand/livetest-{}-keys", std::process::id());
    let (_svc, _) = service(&prefix, &["--no-log"]);
    let mut fed = feed(&prefix, &program, &["--keys"]).stdin(Stdio::piped()).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let mut keys = fed.stdin.take().unwrap();
    wait_state(&prefix, 60, &["Running"]);
    press(&mut keys, "p");
    wait_state(&prefix, 10, &["Paused"]);
    press(&mut keys, "-");
    let deadline = Instant::now() + Duration::from_secs(5);
    while status(&prefix)["feed_override"] != 0.9 {
        assert!(Instant::now() < deadline, "the - key did not lower the feed override");
        std::thread::sleep(Duration::from_millis(50));
    }
    press(&mut keys, "p");
    wait_state(&prefix, 10, &["Running"]);
    press(&mut keys, "s");
    let out = fed.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(6), "{stderr}");
    for sent in ["Pause sent", "FeedOverride 90 % sent", "Resume sent", "Stop sent", "job stopped"] {
        assert!(stderr.contains(sent), "{sent:?} missing: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_job_resumed_at_a_layer_finishes() {
    let dir = temp_dir("live", "resume");
    let program = square_program(&dir, 3, 2, 2400.0);
    let prefix = format!("strand/livetest-{}-resume", std::process::id());
    let (mut svc, _) = service(&prefix, &["--no-log", "--exit-when-done"]);
    // PrusaSlicer-style layer comments: `;Z:` layers are numbered by the slicer's height order.
    let out = feed(&prefix, &program, &["--resume-layer", "2"]).output().unwrap();
    let stderr = assert_ok("strand-feed --resume-layer 2", &out);
    assert!(stderr.contains("job finished"), "{stderr}");
    let t0 = Instant::now();
    while svc.0.try_wait().unwrap().is_none() && t0.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(50));
    }
    let bad = feed(&prefix, &program, &["--resume-layer", "99"]).output().unwrap();
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--resume-layer 99: the program has layers"), "{bad:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_demo_serves_the_live_view_and_still_finishes() {
    if !python_client_available() {
        return;
    }
    let dir = temp_dir("live", "demo");
    let program = square_program(&dir, 1, 2, 2400.0);
    let port = 18_000 + (std::process::id() % 1000) as u16;
    let address = format!("view.address=\"127.0.0.1:{port}\"");
    let demo = Command::new(Path::new(env!("CARGO_BIN_EXE_strand-demo")))
        .args(["--view", "--json", "--no-check", "--gcode", program.to_str().unwrap(), "--set", FAST_APPROACH, "--set", &address, "--out"])
        .arg(dir.join("demo"))
        .current_dir(root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let watched =
        python("foxglove_client.py", &[&format!("ws://127.0.0.1:{port}"), "--seconds", "120", "--json", "--connect-timeout", "60"])
            .output()
            .unwrap();
    let out = demo.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("live view on ws://127.0.0.1:"), "{stdout}");
    let summary: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(summary["identical"], true, "{summary}");
    let live: serde_json::Value = serde_json::from_slice(&watched.stdout).unwrap_or_else(|e| panic!("{e}: {watched:?}"));
    for topic in ["/robot_description", "/tf", "/bead", "/path/ahead", "/status", "/joint_states"] {
        assert!(live["topics"][topic]["count"].as_u64().unwrap_or(0) > 0, "{topic} not received: {}", live["topics"]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A stop as the job starts: whether `s` is read before the first batch or right after it and the
/// Start, the feeder ends stopped, and the service is left with no job in progress (before the
/// controller refused the segments still in flight behind a stop as `Stale`, they opened a job in
/// Idle that nobody started, and the feeder waited for it forever).
#[test]
fn a_stop_key_at_once_ends_the_feeder_stopped() {
    let dir = temp_dir("live", "stopkey");
    let program = square_program(&dir, 1, 40, 1200.0);
    let prefix = format!("strand/livetest-{}-stopkey", std::process::id());
    let (_svc, _) = service(&prefix, &["--no-log"]);
    // `s` is waiting on stdin before the first batch goes out: the feeder stops (exit 6) and does
    // not wait for a job that may never start.
    let mut fed = feed(&prefix, &program, &["--keys"]).stdin(Stdio::piped()).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let mut keys = fed.stdin.take().unwrap();
    press(&mut keys, "s");
    let t0 = Instant::now();
    while fed.try_wait().unwrap().is_none() {
        if t0.elapsed() > Duration::from_secs(60) {
            let _ = fed.kill();
            let out = fed.wait_with_output().unwrap();
            panic!("strand-feed did not end after s; its stderr:\n{}\nstatus {}", String::from_utf8_lossy(&out.stderr), status(&prefix));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = fed.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(6), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(status(&prefix)["fault"], "None", "a stop, not an emergency stop");
    let s = wait_state(&prefix, 10, &["Idle"]);
    assert_ne!(s["job_outcome"], "InProgress", "no job left in progress: {s}");
    let _ = std::fs::remove_dir_all(&dir);
}
