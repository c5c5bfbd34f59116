//! Tests of the fake Meca500 over its two ports, by a tiny client of the tests' own: the banner
//! and the single control client, the trajectory and its timeout, the state's gates, errors and
//! their recovery, the framing, the firmware's versions and the joint limits.

use super::*;
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::Instant;

/// A tiny client: a reader thread splits the stream on NUL into messages.
struct Client {
    stream: TcpStream,
    rx: Receiver<String>,
}

impl Client {
    fn connect(addr: SocketAddr) -> Client {
        let stream = TcpStream::connect(addr).unwrap();
        stream.set_nodelay(true).unwrap();
        let mut reader = stream.try_clone().unwrap();
        let (tx, rx) = channel();
        std::thread::spawn(move || {
            let (mut acc, mut buf) = (Vec::new(), [0u8; 4096]);
            while let Ok(n) = reader.read(&mut buf) {
                if n == 0 {
                    break;
                }
                for &b in &buf[..n] {
                    if b == 0 {
                        if tx.send(String::from_utf8(std::mem::take(&mut acc)).unwrap()).is_err() {
                            return;
                        }
                    } else {
                        acc.push(b);
                    }
                }
            }
        });
        Client { stream, rx }
    }
    fn raw(&mut self, bytes: &[u8]) {
        self.stream.write_all(bytes).unwrap();
    }
    fn send(&mut self, command: &str) {
        self.raw(format!("{command}\0").as_bytes());
    }
    /// The next message (None: closed or 2 s of silence).
    fn next(&self) -> Option<String> {
        self.rx.recv_timeout(Duration::from_secs(2)).ok()
    }
    /// Messages up to and including the first with `code`.
    fn until(&self, code: u32) -> Vec<String> {
        let mut seen = Vec::new();
        loop {
            let m = self.next().unwrap_or_else(|| panic!("no [{code}] after {seen:?}"));
            let done = code_of(&m) == code;
            seen.push(m);
            if done {
                return seen;
            }
        }
    }
    /// The payload of the first message with `code`, checking that no error came before it.
    fn expect(&self, code: u32) -> String {
        let seen = self.until(code);
        let errors: Vec<_> = seen[..seen.len() - 1].iter().filter(|m| is_error(code_of(m))).collect();
        assert!(errors.is_empty(), "errors before [{code}]: {errors:?}");
        payload(seen.last().unwrap()).to_string()
    }
    /// True if the connection is closed within 2 s (the messages before skipped).
    fn closed(&self) -> bool {
        let end = Instant::now() + Duration::from_secs(2);
        loop {
            match self.rx.recv_timeout(end.saturating_duration_since(Instant::now())) {
                Ok(_) => {}
                Err(RecvTimeoutError::Disconnected) => return true,
                Err(RecvTimeoutError::Timeout) => return false,
            }
        }
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        // The reader thread holds a clone: close the connection itself.
        let _ = self.stream.shutdown(Shutdown::Both);
    }
}

impl Client {
    /// The next message that is no EOB/EOM event.
    fn reply(&self) -> String {
        loop {
            let m = self.next().expect("a reply");
            if !matches!(code_of(&m), 3004 | 3012) {
                return m;
            }
        }
    }
    /// Waits for `[code][payload]`.
    fn until_is(&self, code: u32, payload: &str) {
        let want = format!("[{code:04}][{payload}]");
        for _ in 0..1000 {
            if *self.until(code).last().unwrap() == want {
                return;
            }
        }
        panic!("no {want}");
    }
}

fn code_of(m: &str) -> u32 {
    m.get(1..5).and_then(|c| c.parse().ok()).unwrap_or(0)
}
fn payload(m: &str) -> &str {
    let start = m.find("][").map_or(0, |i| i + 2);
    &m[start..m.rfind(']').unwrap_or(m.len()).max(start)]
}
fn is_error(code: u32) -> bool {
    (1000..2000).contains(&code) || matches!(code, 3001 | 3003 | 3005 | 3086)
}
fn floats(p: &str) -> Vec<f64> {
    p.split(',').map(|v| v.parse().unwrap()).collect()
}

/// A robot (activated and homed if `ready`) and its control client, past the banner.
fn robot(ready: bool, opts: MecaOptions) -> (FakeMeca, Client) {
    let fake = FakeMeca::spawn(MecaOptions { activated: ready, homed: ready, home_time: 0.05, ..opts }).unwrap();
    let c = Client::connect(fake.control_addr());
    assert_eq!(code_of(&c.reply()), 3000);
    (fake, c)
}

fn wait_for(what: &str, mut ok: impl FnMut() -> bool) {
    let end = Instant::now() + Duration::from_secs(2);
    while !ok() {
        assert!(Instant::now() < end, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn banner_and_one_control_client() {
    let fake = FakeMeca::spawn(MecaOptions::default()).unwrap();
    let watch = fake.watch();
    let mut c1 = Client::connect(fake.control_addr());
    assert_eq!(c1.next().unwrap(), "[3000][Connected to Meca500 R3 v9.3.0]");
    wait_for("connected", || watch.connected());
    let mut c2 = Client::connect(fake.control_addr());
    c2.raw(b"\0");
    assert_eq!(c2.next().unwrap(), "[3001][Another user is already connected, closing connection.]");
    assert!(c2.closed());
    // The first client is still served; an empty frame is ignored.
    c1.raw(b"\0");
    c1.send("GetStatusRobot");
    assert_eq!(c1.next().unwrap(), "[2007][0,0,0,0,1,1,1]");
    // Monitoring: many clients, each its banner then a 2007.
    let m1 = Client::connect(fake.monitor_addr());
    let m2 = Client::connect(fake.monitor_addr());
    for m in [&m1, &m2] {
        assert_eq!(code_of(&m.next().unwrap()), 3000);
        assert_eq!(m.next().unwrap(), "[2007][0,0,0,0,1,1,1]");
        let cycle = m.until(2230);
        let codes: Vec<u32> = cycle.iter().map(|m| code_of(m)).collect();
        assert!(codes.ends_with(&[2026, 2027, 2200, 2201, 2230]), "{codes:?}");
    }
    // The first client leaves: a new one is taken.
    drop(c1);
    wait_for("disconnected", || !watch.connected());
    let c3 = Client::connect(fake.control_addr());
    assert_eq!(code_of(&c3.next().unwrap()), 3000);
    let report = fake.stop();
    assert_eq!(report.errors, [3001]);
    assert_eq!(report.commands, ["GetStatusRobot"]);
    assert!(c3.closed(), "stop closes the connections");
}

#[test]
fn the_recipe_moves_the_joints_by_the_integral_of_the_velocity() {
    let start = [10.0, -20.0, 30.0, -40.0, 50.0, -60.0];
    let (fake, mut c) = robot(false, MecaOptions { start_deg: start, ..MecaOptions::default() });
    let watch = fake.watch();
    c.raw(b"\0");
    c.send("SetCtrlPortMonitoring(1)");
    assert_eq!(c.expect(2096), "1");
    assert_eq!(c.expect(2007), "0,0,0,0,1,1,1");
    c.send("GetStatusRobot");
    c.send("ActivateRobot");
    c.expect(2000);
    c.send("Home");
    c.expect(2002);
    assert_eq!(&watch.status()[..5], [true, true, false, false, false]);
    for cmd in ["SetJointVelLimit(100)", "SetJointAcc(100)", "SetVelTimeout(0.1)", "SetMonitoringInterval(0.01)"] {
        c.send(cmd);
    }
    c.send("SetRealTimeMonitoring(2210,2212)");
    assert_eq!(c.expect(2117), "2210,2212");
    c.until(2230);
    // Stream 0.5 s at 4 ms, half of them silent.
    let w = [10.0, -20.0, 30.0, -40.0, 50.0, -60.0];
    let first = monotonic_ns();
    let mut last = first;
    for k in 0..125u64 {
        crate::fake::sleep_until(first + k * 4_000_000);
        let dash = if k % 2 == 0 { "-" } else { "" };
        c.send(&format!("{dash}MoveJointsVel({})", w.map(|v| format!("{v:.4}")).join(",")));
        last = monotonic_ns();
    }
    assert_eq!(watch.timeouts(), 0, "the stream held");
    assert!((watch.velocity_deg()[5] - w[5]).abs() < 1e-9, "at speed: {:?}", watch.velocity_deg());
    wait_for("rest", || watch.velocity_deg() == [0.0; 6]);
    // The ramps up and down are alike: the joints moved by w × (stream + timeout).
    let span = (last - first) as f64 * 1e-9 + 0.1;
    let q = watch.joints_deg();
    for j in 0..6 {
        let expected = w[j] * span;
        assert!((q[j] - start[j] - expected).abs() < 0.02 * expected.abs() + 0.05, "J{}: {} vs {expected}", j + 1, q[j] - start[j]);
    }
    assert_eq!(watch.timeouts(), 1);
    // The monitoring cycles (on the control socket): each 2026 2027 2200 2201 2210 2212 2230,
    // one timestamp, 10 ms apart.
    let mut messages = Vec::new();
    while let Ok(m) = c.rx.try_recv() {
        messages.push(m);
    }
    assert!(messages.iter().all(|m| !is_error(code_of(m))), "{messages:?}");
    let mut cycles = Vec::new();
    let mut current = Vec::new();
    for m in messages.iter().filter(|m| !matches!(code_of(m), 2007 | 3012)) {
        current.push(m.clone());
        if code_of(m) == 2230 {
            cycles.push(std::mem::take(&mut current));
        }
    }
    assert!(cycles.len() >= 50, "{} cycles", cycles.len());
    let mut stamps = Vec::new();
    for cycle in &cycles {
        let codes: Vec<u32> = cycle.iter().map(|m| code_of(m)).collect();
        assert_eq!(codes, [2026, 2027, 2200, 2201, 2210, 2212, 2230]);
        let t: u64 = payload(&cycle[6]).parse().unwrap();
        for m in &cycle[2..6] {
            assert_eq!(floats(payload(m))[0], t as f64);
        }
        assert_eq!(floats(payload(&cycle[0])), floats(payload(&cycle[4]))[1..]);
        stamps.push(t);
    }
    assert!(stamps.windows(2).all(|w| w[1] - w[0] == 10_000), "{stamps:?}");
    let moving = cycles.iter().filter(|c| floats(payload(&c[5]))[1..] == w).count();
    assert!(moving >= 40, "{moving} cycles at speed");
    let report = fake.stop();
    assert_eq!(report.move_joints_vel, 125);
    assert_eq!(report.commands[..4], ["SetCtrlPortMonitoring", "GetStatusRobot", "ActivateRobot", "Home"]);
    assert!(report.report.in_time >= 20 && report.report.missing >= 5, "{:?}", report.report);
    assert_eq!(report.report.in_time + report.report.missing, report.report.cycles);
    assert_eq!((report.report.axes.len(), report.report.fresh.len()), (report.report.cycles as usize, report.report.cycles as usize));
    assert!(report.errors.is_empty() && report.garbage == 0);
}

#[test]
fn the_velocity_timeout_stops_the_arm() {
    let (fake, mut c) = robot(true, MecaOptions::default());
    let watch = fake.watch();
    c.send("SetEom(1)");
    assert_eq!(c.expect(2052), "End of movement is enabled.");
    c.send("SetVelTimeout(0.05)");
    c.send("MoveJointsVel(20,0,0,0,0,0)");
    // The events come on the transitions to rest: eob and eom were cleared while moving.
    c.expect(3004);
    c.expect(3012);
    assert_eq!(watch.velocity_deg(), [0.0; 6]);
    assert_eq!(watch.timeouts(), 1);
    assert!(watch.status()[5] && watch.status()[6]);
    // 20 °/s for 50 ms, the ramps up and down alike (600 °/s²: 33 ms each).
    assert!((watch.joints_deg()[0] - 1.0).abs() < 0.05, "{:?}", watch.joints_deg());
    // A zero command that lapses is no timeout.
    c.send("MoveJointsVel(0,0,0,0,0,0)");
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(fake.stop().timeouts, 1);
}

#[test]
fn motion_commands_are_gated_by_the_state() {
    let (fake, mut c) = robot(false, MecaOptions::default());
    let watch = fake.watch();
    c.send("MoveJointsVel(1,0,0,0,0,0)");
    assert_eq!(c.reply(), "[1005][Motors are not activated.]");
    c.send("SetVelTimeout(0.1)");
    assert_eq!(code_of(&c.reply()), 1005);
    c.send("Home");
    assert_eq!(code_of(&c.reply()), 1005);
    c.send("ActivateRobot()");
    c.expect(2000);
    c.send("MoveJointsVel(1,0,0,0,0,0)");
    assert_eq!(c.reply(), "[1006][Homing has not been performed.]");
    c.send("Home");
    c.send("MoveJointsVel(1,0,0,0,0,0)");
    assert_eq!(code_of(&c.reply()), 1006, "still homing");
    c.expect(2002);
    // Arguments: count, range, syntax, unknown names.
    for (cmd, code) in [
        ("MoveJointsVel(1,2,3)", 1003),
        ("MoveJointsVel(1,2,3,4,5,x)", 1003),
        ("MoveJointsVel(1,2,3,4,5,nan)", 1003),
        ("MoveJointsVel(1,2,3,4,5,6", 1002),
        ("MoveJointsVel(1,,3,4,5,6)", 1002),
        ("SetVelTimeout(2)", 1003),
        ("SetVelTimeout(0)", 1003),
        ("SetMonitoringInterval(0.0001)", 1003),
        ("SetJointAcc(151)", 1003),
        ("SetJointVelLimit(0)", 1003),
        ("SetEob(2)", 1003),
        ("SetRealTimeMonitoring(9999)", 1003),
        ("GetJointLimits(7)", 1003),
        ("ActivateRobot(1)", 1003),
        ("FlyToTheMoon()", 1001),
        ("ConnectionWatchdog(1)", 1001),
    ] {
        c.send(cmd);
        assert_eq!(code_of(&c.reply()), code, "{cmd}");
    }
    c.send("GetModelJointLimits(2)");
    assert_eq!(c.expect(2113), "2,-70.000000,90.000000");
    c.send("SetJointAcc(150)");
    c.send("GetJointAcc");
    assert_eq!(c.expect(2153), "150.000000");
    watch.inject_error(3005);
    assert_eq!(code_of(&c.reply()), 3005);
    c.send("MoveJointsVel(1,0,0,0,0,0)");
    assert_eq!(c.reply(), "[1011][The robot is in error.]");
    c.send("SetVelTimeout(0.1)");
    assert_eq!(code_of(&c.reply()), 1011);
    let report = fake.stop();
    assert_eq!(report.errors[..4], [1005, 1005, 1005, 1006]);
    assert_eq!(report.errors[report.errors.len() - 3..], [3005, 1011, 1011]);
    assert_eq!(report.garbage, 16);
    assert_eq!(report.move_joints_vel, 0);
}

#[test]
fn an_injected_error_stops_the_arm_until_reset_and_resume() {
    let (fake, mut c) = robot(true, MecaOptions::default());
    let watch = fake.watch();
    let m = Client::connect(fake.monitor_addr());
    assert_eq!(code_of(&m.next().unwrap()), 3000);
    assert_eq!(m.next().unwrap(), "[2007][1,1,0,0,0,1,1]");
    c.send("SetVelTimeout(1)");
    c.send("MoveJointsVel(0,0,0,100,0,0)");
    wait_for("speed", || watch.velocity_deg()[3] == 100.0);
    watch.inject_error(3005);
    assert_eq!(c.reply(), "[3005][Motion error.]");
    m.until_is(2007, "1,1,0,1,1,0,0");
    assert_eq!(&watch.status()[3..5], [true, true]);
    wait_for("rest", || watch.velocity_deg() == [0.0; 6]);
    c.send("MoveJointsVel(0,0,0,100,0,0)");
    assert_eq!(code_of(&c.reply()), 1011);
    c.send("ResumeMotion");
    assert_eq!(code_of(&c.reply()), 1011);
    c.send("ResetError");
    c.expect(2005);
    c.send("ResetError");
    c.expect(2006);
    // Reset but paused: accepted, not moving.
    c.send("MoveJointsVel(0,0,0,100,0,0)");
    c.send("GetStatusRobot");
    assert_eq!(c.expect(2007), "1,1,0,0,1,1,1");
    assert_eq!(watch.velocity_deg(), [0.0; 6]);
    c.send("ClearMotion");
    c.expect(2044);
    c.send("ResumeMotion");
    c.expect(2043);
    c.send("MoveJointsVel(0,0,0,100,0,0)");
    wait_for("moving again", || watch.velocity_deg()[3] > 0.0);
    c.send("PauseMotion");
    c.expect(2042);
    wait_for("paused rest", || watch.velocity_deg() == [0.0; 6]);
    let report = fake.stop();
    assert_eq!(report.errors, [3005, 1011, 1011]);
    assert_eq!(report.move_joints_vel, 3);
    assert_eq!(report.timeouts, 0);
}

#[test]
fn frames_split_merged_or_newline_terminated_and_any_bytes() {
    let (fake, mut c) = robot(true, MecaOptions::default());
    for piece in [&b"Get"[..], b"Stat", b"usRob", b"ot(", b")\0"] {
        c.raw(piece);
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(c.next().unwrap(), "[2007][1,1,0,0,0,1,1]");
    c.raw(b"GetJoints\ngetstatusrobot\r\n\0\0-GETSTATUSROBOT()\0 - GetJoints ( ) \n");
    assert_eq!(code_of(&c.reply()), 2026);
    assert_eq!(code_of(&c.reply()), 2007);
    assert_eq!(code_of(&c.reply()), 2007);
    assert_eq!(code_of(&c.reply()), 2026);
    // Too long, then garbage of every kind: answered, never fatal.
    c.raw(&[b'A'; 300]);
    c.raw(b"\0");
    assert_eq!(code_of(&c.reply()), 3003);
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let mut bytes = Vec::new();
    for _ in 0..5000 {
        x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        bytes.push((x >> 33) as u8);
    }
    bytes.extend_from_slice(b"\xff\xfe(\0)(,\0MoveJointsVel(\xff)\0-\0");
    c.raw(&bytes);
    c.send("GetStatusRobot");
    let seen = c.until(2007);
    assert!(seen[..seen.len() - 1].iter().all(|m| matches!(code_of(m), 1001..=1003 | 3003)), "{seen:?}");
    let report = fake.stop();
    assert_eq!(report.garbage as usize, seen.len());
    assert_eq!(report.commands.iter().filter(|c| c.eq_ignore_ascii_case("getstatusrobot")).count(), 4);
}

#[test]
fn commands_follow_the_firmware_version_and_the_watchdog_drops_the_client() {
    let (fake, mut c) = robot(true, MecaOptions { version: "9.2.0".into(), ..MecaOptions::default() });
    c.send("SetJointVelLimit(50)");
    assert_eq!(code_of(&c.reply()), 1001, "FW 9.3");
    c.send("SetCtrlPortMonitoring(1)");
    assert_eq!(c.expect(2096), "1");
    assert_eq!(fake.stop().errors, [1001]);
    let (fake, mut c) = robot(true, MecaOptions { version: "10.1.0".into(), ..MecaOptions::default() });
    let watch = fake.watch();
    c.send("SetJointVelLimit(50)");
    c.send("SetVelTimeout(1)");
    c.send("MoveJointsVel(1000,0,0,0,0,150)");
    wait_for("capped speed", || watch.velocity_deg()[0] == 75.0);
    assert_eq!(watch.velocity_deg()[5], 11.25, "scaled with J1");
    c.send("ConnectionWatchdog(0.05)");
    assert_eq!(c.expect(2177), "1");
    for _ in 0..5 {
        std::thread::sleep(Duration::from_millis(20));
        c.send("ConnectionWatchdog(0.05)");
        assert_eq!(c.expect(2177), "1");
    }
    assert!(watch.connected());
    c.expect(3086);
    assert!(c.closed());
    wait_for("rest", || watch.velocity_deg() == [0.0; 6] && !watch.connected());
    assert!(watch.status()[4], "paused");
    let report = fake.stop();
    assert_eq!((report.errors, report.timeouts), (vec![3086], 0));
}

#[test]
fn a_joint_stops_at_its_limit_and_a_dropped_client_stops_the_arm() {
    let start = [170.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    let (fake, mut c) = robot(true, MecaOptions { start_deg: start, ..MecaOptions::default() });
    let watch = fake.watch();
    c.send("SetVelTimeout(1)");
    c.send("MoveJointsVel(100,0,0,0,0,-50)");
    wait_for("J1 at its limit", || watch.joints_deg()[0] == 175.0);
    std::thread::sleep(Duration::from_millis(20));
    assert_eq!(watch.velocity_deg()[0], 0.0);
    assert!(watch.velocity_deg()[5] < 0.0, "J6 goes on");
    assert!(!watch.status()[3], "no error");
    c.send("GetJoints");
    assert_eq!(floats(&c.expect(2026))[0], 175.0);
    // The client goes: the arm decelerates to rest and pauses.
    drop(c);
    wait_for("rest", || watch.velocity_deg() == [0.0; 6]);
    assert!(!watch.connected());
    assert!(watch.status()[4], "paused");
    let report = fake.stop();
    assert_eq!((report.limit_stops, report.timeouts), (1, 0));
    assert!(report.errors.is_empty());
}
