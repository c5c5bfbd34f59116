//! The service over iceoryx2, in processes: the `strand` binary as the controller, a tiny feeder and
//! a tiny driver (this test binary re-run as a child process, so they can be killed with SIGKILL), a
//! unique service prefix per test so tests run in parallel.
//!
//! - a whole job streamed with back-pressure (more segments than the queue holds) finishes, nothing
//!   rejected, nothing lost;
//! - a feeder killed mid-job → the service stops on the path (job outcome Stopped, no fault);
//! - a driver killed while the service runs on the robot clock → JointStateLost fault.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

use std::time::{Duration, Instant};
use strand_testkit::Reaped;

use strand::io::clock::monotonic_ns;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{self as ipc, FaultCode, JobOutcome, RunState, ServiceNames};

const ORIGIN: [f64; 3] = [0.45, -0.02, 0.2];
const DOWN: [f64; 4] = [0.0, 0.0, 1.0, 0.0];
const FLOW: f64 = 0.0333;

fn prefix(name: &str) -> String {
    format!("strand/svc-test-{}-{name}", std::process::id())
}

fn service(prefix: &str, extra: &[&str]) -> Reaped {
    let mut args = vec!["run", "--config", "config/default.toml", "--prefix", prefix];
    args.extend_from_slice(extra);
    if !extra.contains(&"--log") {
        args.push("--no-log");
    }
    let child = Command::new(env!("CARGO_BIN_EXE_strand"))
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start strand");
    Reaped(child)
}

/// Re-runs this test binary as a child in `role`, waiting until it prints READY.
fn child(role: &str, prefix: &str) -> Child {
    let mut c = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "child_process", "--ignored", "--nocapture", "--test-threads", "1"])
        .env("STRAND_CHILD_ROLE", role)
        .env("STRAND_CHILD_PREFIX", prefix)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start child");
    let out = c.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            if line.contains("READY") {
                let _ = tx.send(());
            }
        }
    });
    rx.recv_timeout(Duration::from_secs(30)).expect("child never became ready");
    c
}

fn monitor(prefix: &str) -> ClientPorts {
    ClientPorts::open(&ServiceNames::new(prefix), "monitor", ClientRoles { monitor: true, ..Default::default() }).unwrap()
}

/// Waits until a Status satisfies `f` (polling), or panics after `secs`.
fn wait_for(m: &ClientPorts, secs: u64, what: &str, mut f: impl FnMut(&ipc::Status) -> bool) -> ipc::Status {
    let deadline = Instant::now() + Duration::from_secs(secs);
    let mut last = None;
    while Instant::now() < deadline {
        if let Some(s) = m.latest_status() {
            if f(&s) {
                return s;
            }
            last = Some(s);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    panic!("timed out waiting for {what}; last status {last:?}");
}

fn square_job(loops: usize, side: f64, feed: f64) -> Vec<ipc::Segment> {
    let line = |seq: u64, end: [f64; 3], feed: f64, filament: f64| ipc::Segment {
        seq,
        kind: ipc::SegmentKind::Line as u32,
        flags: if filament > 0.0 { ipc::segment_flags::EXTRUDE } else { ipc::segment_flags::TRAVEL },
        end,
        orientation: DOWN,
        feed,
        filament,
        ..Default::default()
    };
    let mut v = vec![line(1, ORIGIN, 0.1, 0.0)];
    let [x, y, z] = ORIGIN;
    for _ in 0..loops {
        for c in [[x + side, y, z], [x + side, y + side, z], [x, y + side, z], [x, y, z]] {
            let seq = v.len() as u64 + 1;
            v.push(line(seq, c, feed, side * FLOW));
        }
    }
    v.last_mut().unwrap().flags |= ipc::segment_flags::LAST;
    v
}

/// Streams `job` within the credit window announced in Status; sends Start after the first batch.
fn feed(ports: &ClientPorts, job: &[ipc::Segment]) {
    let mut next = 0usize;
    let mut started = false;
    let mut batch_seq = 0;
    while next < job.len() {
        let Some(status) = ports.latest_status() else {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        };
        let batch = strand_testkit::credit_batch(job, &mut next, &status, batch_seq + 1, monotonic_ns());
        if batch.len > 0 {
            batch_seq += 1;
            ports.send_segments(&batch).unwrap();
            // Wait until the service has taken it before counting on the new window.
            let last = job[next - 1].seq;
            while ports.latest_status().is_none_or(|s| s.last_received_seq < last && s.rejected == 0) {
                std::thread::sleep(Duration::from_micros(200));
            }
        } else {
            std::thread::sleep(Duration::from_millis(1));
        }
        if !started {
            started = true;
            let start = ipc::Control { seq: 1, stamp_ns: monotonic_ns(), command: ipc::Command::Start as u32, ..Default::default() };
            ports.send_control(&start).unwrap();
        }
    }
}

/// The body of the child processes (run only through [`child`]).
#[test]
#[ignore = "run as a child process by the other tests"]
fn child_process() {
    let (Ok(role), Ok(prefix)) = (std::env::var("STRAND_CHILD_ROLE"), std::env::var("STRAND_CHILD_PREFIX")) else { return };
    let names = ServiceNames::new(&prefix);
    match role.as_str() {
        "feeder" => {
            let ports = ClientPorts::open(&names, "feeder", ClientRoles { feeder: true, monitor: true, ..Default::default() }).unwrap();
            println!("READY");
            // A long job; the parent kills this process mid-way.
            feed(&ports, &square_job(200, 0.04, 0.05));
            std::thread::sleep(Duration::from_secs(600));
        }
        "driver" => {
            let ports = ClientPorts::open(&names, "driver", ClientRoles { driver: true, ..Default::default() }).unwrap();
            println!("READY");
            let mut state = ipc::JointState { dof: 7, ..Default::default() };
            state.position[..7].copy_from_slice(&[0.0, 0.4, 0.0, -1.5, 0.0, 1.2, 0.0]);
            loop {
                // A robot that follows its commands, clocking the controller at 1 kHz.
                while let Ok(Some(cmd)) = ports.receive_joint_command() {
                    if cmd.valid == 1 {
                        state.position = cmd.position;
                    }
                }
                state.seq += 1;
                state.stamp_ns = monotonic_ns();
                ports.send_joint_state(&state).unwrap();
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        other => panic!("unknown role {other}"),
    }
}

#[test]
fn a_job_streams_with_back_pressure_and_finishes() {
    let p = prefix("job");
    let _svc = service(&p, &["--clock", "free-run", "--echo"]);
    let names = ServiceNames::new(&p);
    let ports = ClientPorts::open(&names, "feeder", ClientRoles { feeder: true, monitor: true, ..Default::default() }).unwrap();
    wait_for(&ports, 30, "the service", |_| true);
    // 1201 segments: more than the 1024 the queue holds.
    let job = square_job(300, 0.004, 0.2);
    feed(&ports, &job);
    let s = wait_for(&ports, 120, "the job to finish", |s| {
        s.job_outcome != JobOutcome::InProgress as u32 && s.run_state == RunState::Idle as u32
    });
    assert_eq!(s.job_outcome, JobOutcome::Finished as u32, "{s:?}");
    assert_eq!(s.rejected, 0);
    assert_eq!(s.segments_accepted, job.len() as u64);
    assert_eq!(s.last_received_seq, job.len() as u64);
    assert_eq!(s.clamps, 0);
    assert_eq!(s.contract_version, ipc::CONTRACT_VERSION);
}

#[test]
fn a_killed_feeder_stops_the_job_on_the_path() {
    let p = prefix("feeder");
    let _svc = service(&p, &["--clock", "timer", "--echo"]);
    let m = monitor(&p);
    wait_for(&m, 30, "the service", |_| true);
    let mut feeder = child("feeder", &p);
    wait_for(&m, 60, "the job to run", |s| s.run_state == RunState::Running as u32 && s.path_speed > 0.0);
    feeder.kill().unwrap();
    feeder.wait().unwrap();
    let s = wait_for(&m, 10, "a controlled stop", |s| s.job_outcome == JobOutcome::Stopped as u32 && s.run_state == RunState::Idle as u32);
    assert_eq!(s.fault, FaultCode::None as u32);
}

#[test]
fn a_killed_driver_faults_the_service() {
    let p = prefix("driver");
    let _svc = service(&p, &["--clock", "robot"]);
    let m = monitor(&p);
    let mut driver = child("driver", &p);
    wait_for(&m, 30, "ticks clocked by the driver", |s| s.tick > 200);
    driver.kill().unwrap();
    driver.wait().unwrap();
    let s = wait_for(&m, 10, "a fault", |s| s.run_state == RunState::Fault as u32);
    assert_eq!(s.fault, FaultCode::JointStateLost as u32);
}
