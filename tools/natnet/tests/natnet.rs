//! strand-natnet against the fake Motive over the loopback: the poses published on the service's
//! port against the fake's trajectory, in every NatNet version the client reads, unicast and
//! multicast; untracked frames; a rigid body the server does not have; a server that does not
//! answer; the command line.

use std::net::{Ipv4Addr, SocketAddrV4, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use strand::config::tracker::{TrackerConfig, Transmission, UpAxis};
use strand::io::histogram::Histogram;
use strand_ipc::ports::ServicePorts;
use strand_ipc::{BasePose, ServiceNames};
use strand_natnet::client::{ClientError, Report, RunOptions, run};
use strand_natnet::fake::{FakeConfig, FakeMotive, SentFrame};
use strand_natnet::protocol::Version;
use strand_natnet::session::SessionError;

/// The fake's body in Motive's Y-up world: a circle of 0.2 m in the ground plane (x, z) at
/// 0.3 m height, yawing ±0.5 rad about Motive's up (y).
fn trajectory(t: f64) -> ([f64; 3], [f64; 4]) {
    let w = 2.0;
    let yaw = 0.5 * (w * t).sin();
    ([0.5 + 0.2 * (w * t).sin(), 0.3, -0.4 + 0.2 * (w * t).cos()], [0.0, (yaw / 2.0).sin(), 0.0, (yaw / 2.0).cos()])
}

fn fake(version: Version, multicast: Option<(Ipv4Addr, u16)>) -> FakeConfig {
    FakeConfig {
        version,
        bodies: vec![("flyer".into(), 3), ("bed".into(), 5)],
        multicast,
        rate_hz: 200.0,
        clock_hz: 10_000_000,
        latency: 0.004,
        untracked: 0..0,
        silent: false,
        trajectory: std::sync::Arc::new(trajectory),
    }
}

/// The cell: Motive's world (Y-up, turned to Z-up) 1 m along x and 2 m along y of W and turned
/// 90° about z; the base 0.1 m below the body's pivot.
fn tracker(command_port: u16, transmission: Transmission, data_port: u16) -> TrackerConfig {
    TrackerConfig {
        command_port,
        data_port,
        transmission,
        rigid_body: "flyer".into(),
        up_axis: UpAxis::Y,
        world_xyz: [1.0, 2.0, 0.0],
        world_rpy: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
        body_xyz: [0.0, 0.0, -0.1],
        connect_timeout: 2.0,
        keepalive_period: 0.1,
        ..TrackerConfig::default()
    }
}

/// B in W for a frame, worked out by hand for [`tracker`]'s cell (not through the crate's
/// mapping): Y-up (x, y, z) is Z-up (x, −z, y), a yaw θ about Motive's y is one about z; then
/// Rz(90°): (x, y) → (−y, x), plus (1, 2, 0); B is 0.1 m down the body's z (which is W's z).
fn expected(f: &SentFrame) -> ([f64; 3], f64) {
    let [x, y, z] = f.position.map(|v| v as f64);
    let [_, qy, _, qw] = f.orientation.map(|v| v as f64);
    let theta = 2.0 * qy.atan2(qw);
    let (zx, zy, zz) = (x, -z, y);
    ([1.0 - zy, 2.0 + zx, zz - 0.1], std::f64::consts::FRAC_PI_2 + theta)
}

struct Outcome {
    result: Result<Report, ClientError>,
    poses: Vec<BasePose>,
    sent: Vec<SentFrame>,
    logs: Vec<String>,
    keepalives: u64,
}

fn free_udp_port() -> u16 {
    UdpSocket::bind(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 0)).unwrap().local_addr().unwrap().port()
}

/// Runs the client against `fake` until it published `want` poses (or failed, or 15 s passed).
fn run_against(name: &str, fake_cfg: FakeConfig, cfg: impl FnOnce(u16) -> TrackerConfig, want: usize) -> Outcome {
    let prefix = format!("test/natnet/{}/{name}", std::process::id());
    let service = ServicePorts::open(&ServiceNames::new(&prefix), "test-service").unwrap();
    let fake = FakeMotive::start(fake_cfg, 0).unwrap();
    let cfg = cfg(fake.command_addr().port());
    let stop = Arc::new(AtomicBool::new(false));
    let logs = Arc::new(Mutex::new(Vec::new()));
    let client = {
        let (stop, logs, prefix) = (stop.clone(), logs.clone(), prefix.clone());
        std::thread::spawn(move || run(&cfg, &RunOptions { prefix, stop: &stop }, &mut |l| logs.lock().unwrap().push(l)))
    };
    let mut poses = Vec::new();
    let started = Instant::now();
    while poses.len() < want && !client.is_finished() && started.elapsed() < Duration::from_secs(15) {
        while let Some(p) = service.receive_base_pose().unwrap() {
            poses.push(p);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    stop.store(true, Ordering::Relaxed);
    let result = client.join().unwrap();
    while let Some(p) = service.receive_base_pose().unwrap() {
        poses.push(p);
    }
    let logs = logs.lock().unwrap().clone();
    Outcome { result, poses, sent: fake.sent(), logs, keepalives: fake.keepalives() }
}

/// Every published pose against the frame of the same number: position error (m), orientation
/// error (rad), and stamp − the frame's true mid-exposure (ns).
fn errors(o: &Outcome) -> (f64, f64, Vec<i64>) {
    let (mut dp, mut dq, mut stamps) = (0.0f64, 0.0f64, Vec::new());
    for p in &o.poses {
        let f = o.sent.iter().find(|f| f.number as u64 == p.seq).expect("a pose for a frame the fake sent");
        assert!(f.tracked, "frame {} was sent untracked but published", f.number);
        let (pos, yaw) = expected(f);
        let e = ((p.position[0] - pos[0]).powi(2) + (p.position[1] - pos[1]).powi(2) + (p.position[2] - pos[2]).powi(2)).sqrt();
        dp = dp.max(e);
        let [w, x, y, z] = p.orientation;
        assert!(((w * w + x * x + y * y + z * z).sqrt() - 1.0).abs() < 1e-12);
        // R_WB is a yaw: the angle between it and the expected yaw.
        let (ew, ez) = ((yaw / 2.0).cos(), (yaw / 2.0).sin());
        let dot = (w * ew + z * ez).abs().min(1.0);
        dq = dq.max(2.0 * dot.acos()).max(x.abs()).max(y.abs());
        stamps.push(p.stamp_ns as i64 - f.mid_exposure_ns as i64);
    }
    (dp, dq, stamps)
}

fn report_line(what: &str, o: &Outcome, r: &Report) {
    let (dp, dq, mut stamps) = errors(o);
    stamps.sort_unstable();
    let pct = |q: f64| stamps[((stamps.len() - 1) as f64 * q) as usize] as f64 * 1e-3;
    eprintln!(
        "{what}: {} poses of {} frames sent; pose error max {dp:.2e} m, {dq:.2e} rad; stamp − true mid-exposure p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs; arrival → publish p50 {:.1} µs, p99 {:.1} µs",
        o.poses.len(),
        o.sent.len(),
        pct(0.5),
        pct(0.99),
        pct(1.0),
        r.latency.percentile(50.0) as f64 * 1e-3,
        r.latency.percentile(99.0) as f64 * 1e-3,
    );
}

fn check_stream(what: &str, o: &Outcome, want: usize) -> Report {
    let r = o.result.as_ref().unwrap_or_else(|e| panic!("{what}: {e}")).clone();
    assert!(o.poses.len() >= want, "{what}: {} poses", o.poses.len());
    let (dp, dq, stamps) = errors(o);
    // The wire carries f32: the mapping adds nothing measurable to the position, and the
    // orientation is within f32 rounding of the quaternion sent.
    assert!(dp < 1e-9, "{what}: position error {dp} m");
    assert!(dq < 1e-6, "{what}: orientation error {dq} rad");
    // The stamp is the capture time: never before it (the transit only adds), by at most a tick
    // of the fake's 10 MHz clock when rounding; the frame's own 4 ms latency is taken off.
    for s in &stamps {
        assert!(*s >= -200, "{what}: stamp {s} ns before the mid-exposure");
        assert!(*s < 2_000_000_000, "{what}: stamp {s} ns after the mid-exposure");
    }
    let mut sorted = stamps.clone();
    sorted.sort_unstable();
    assert!(
        sorted[sorted.len() / 2] < 4_000_000,
        "{what}: the median stamp is {} ns after capture: the frame's latency was not taken off",
        sorted[sorted.len() / 2]
    );
    // Stamps strictly increase (the service refuses a sample not newer than the last).
    assert!(o.poses.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns && w[1].seq > w[0].seq));
    assert!(o.logs.iter().any(|l| l.contains("rigid body \"flyer\" is id 3")), "{what}: {:?}", o.logs);
    report_line(what, o, &r);
    r
}

#[test]
fn unicast_poses_follow_the_fakes_trajectory_in_every_version() {
    let mut all = Histogram::new();
    for v in [Version::new(3, 0), Version::new(3, 1), Version::new(4, 0), Version::new(4, 1), Version::new(4, 2)] {
        let o =
            run_against(&format!("unicast-{}{}", v.0[0], v.0[1]), fake(v, None), |port| tracker(port, Transmission::Unicast, 1511), 100);
        let r = check_stream(&format!("NatNet {v} unicast"), &o, 100);
        assert_eq!(r.counters.malformed, 0);
        assert_eq!(r.counters.unstamped, 0);
        // Unicast subscriptions are kept with keep-alives (every 0.1 s here).
        assert!(o.keepalives >= 1, "no keep-alive in {} poses", o.poses.len());
        all.merge(&r.latency);
    }
    eprintln!(
        "all versions, unicast: arrival → publish over {} poses: p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        all.count(),
        all.percentile(50.0) as f64 * 1e-3,
        all.percentile(99.0) as f64 * 1e-3,
        all.max() as f64 * 1e-3
    );
}

#[test]
fn multicast_poses_follow_the_fakes_trajectory() {
    for v in [Version::new(3, 1), Version::new(4, 1)] {
        let port = free_udp_port();
        let group = Ipv4Addr::new(239, 255, 42, 99);
        let o = run_against(
            &format!("multicast-{}{}", v.0[0], v.0[1]),
            fake(v, Some((group, port))),
            |p| tracker(p, Transmission::Multicast, port),
            100,
        );
        let r = check_stream(&format!("NatNet {v} multicast"), &o, 100);
        assert_eq!(r.counters.malformed, 0);
        assert_eq!(o.keepalives, 0, "multicast needs no keep-alive");
    }
}

#[test]
fn untracked_frames_publish_nothing_and_the_stream_comes_back() {
    let mut f = fake(Version::new(4, 1), None);
    f.untracked = 60..100;
    let o = run_against("untracked", f, |p| tracker(p, Transmission::Unicast, 1511), 120);
    let r = o.result.as_ref().unwrap();
    assert!(o.poses.iter().all(|p| !(60..100).contains(&p.seq)), "a pose published for an untracked frame");
    assert!(o.poses.iter().any(|p| p.seq < 60) && o.poses.iter().any(|p| p.seq >= 100));
    // Every frame the client read in 60..100 was counted untracked; none of them published.
    let read_untracked = o.sent.iter().filter(|f| !f.tracked).count() as u64;
    assert!(r.counters.untracked >= 1 && r.counters.untracked <= read_untracked, "{:?}", r.counters);
    assert!(o.logs.iter().any(|l| l.contains("not tracked")), "{:?}", o.logs);
    assert!(o.logs.iter().any(|l| l.contains("tracked again")), "{:?}", o.logs);
    // A gap of 40 frames at 200 Hz: 0.2 s without a pose, past the default [base] timeout (0.1 s).
    let gap = o.poses.windows(2).map(|w| w[1].stamp_ns - w[0].stamp_ns).max().unwrap();
    assert!(gap >= 150_000_000, "largest gap {gap} ns");
    check_stream("untracked 60..100", &o, 100);
}

#[test]
fn a_rigid_body_the_server_does_not_have_is_an_error_naming_it() {
    let o = run_against(
        "missing",
        fake(Version::new(4, 2), None),
        |p| TrackerConfig { rigid_body: "base".into(), ..tracker(p, Transmission::Unicast, 1511) },
        1,
    );
    match o.result {
        Err(ClientError::Session(SessionError::RigidBodyNotFound { name, available, .. })) => {
            assert_eq!(name, "base");
            assert!(available.contains("\"flyer\" (id 3)") && available.contains("\"bed\" (id 5)"), "{available}");
        }
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("no error"),
    }
    assert!(o.poses.is_empty());
}

#[test]
fn a_server_that_does_not_answer_is_an_error_within_the_timeout() {
    let mut f = fake(Version::new(4, 1), None);
    f.silent = true;
    let started = Instant::now();
    let o = run_against("silent", f, |p| TrackerConfig { connect_timeout: 1.0, ..tracker(p, Transmission::Unicast, 1511) }, 1);
    let took = started.elapsed();
    let e = o.result.expect_err("an error");
    let text = e.to_string();
    assert!(matches!(e, ClientError::Session(SessionError::NoAnswer { tries, .. }) if tries >= 2), "{text}");
    assert!(text.contains("no answer from a NatNet server at 127.0.0.1:") && text.contains("within 1.0 s"), "{text}");
    // The timeout is the session's (1 s); this bound only says "seconds, not forever".
    assert!(took < Duration::from_secs(10), "{took:?}");
}

#[test]
fn unicast_against_a_multicast_server_says_so() {
    let port = free_udp_port();
    let o = run_against(
        "mismatch",
        fake(Version::new(4, 1), Some((Ipv4Addr::new(239, 255, 42, 99), port))),
        |p| tracker(p, Transmission::Unicast, port),
        1,
    );
    let text = o.result.expect_err("an error").to_string();
    assert!(text.contains("Motive streams multicast") && text.contains("transmission = \"unicast\""), "{text}");
}

#[test]
fn the_command_line_names_the_missing_rigid_body_and_exits_1() {
    let fake = FakeMotive::start(fake(Version::new(4, 1), None), 0).unwrap();
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/default.toml");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strand-natnet"))
        .args(["--config", config, "--server", "127.0.0.1", "--prefix", &format!("test/natnet/{}/cli", std::process::id())])
        .args(["--set", "tracker.rigid_body=nobody", "--set", "tracker.transmission=unicast"])
        .args(["--set", &format!("tracker.command_port={}", fake.command_addr().port())])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("no rigid body named \"nobody\"") && stderr.contains("\"flyer\" (id 3)"), "{stderr}");

    // A config without [tracker] and no --set: exit 2, saying what is missing.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strand-natnet")).args(["--config", config]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("no [tracker] section"), "{stderr}");

    // A bad key is named.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strand-natnet"))
        .args(["--config", config, "--set", "tracker.rigid_body=flyer", "--set", "tracker.connect_timeout=0"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("[tracker] connect_timeout = 0"), "{stderr}");
}
