//! Tests of the fake UR controller over its sockets, by a tiny RTDE client and a reverse-interface
//! peer of the tests' own: the doc's handshake bytes, the stream's rate and layout, the framing,
//! and programs that run, time out, stop and are replaced.

use super::program::{Program, parse_program};
use super::rtde::{DATA, PAUSE, SETUP_INPUTS, SETUP_OUTPUTS, START, TEXT, V, VERSION};
use super::*;
use std::io::{Read, Write};
use std::time::Instant;

fn pkg(ty: u8, payload: &[u8]) -> Vec<u8> {
    let mut p = ((payload.len() + 3) as u16).to_be_bytes().to_vec();
    p.push(ty);
    p.extend_from_slice(payload);
    p
}

/// A tiny RTDE client with its own framing.
struct Rtde {
    s: TcpStream,
    acc: Vec<u8>,
}

impl Rtde {
    fn connect(addr: SocketAddr) -> Rtde {
        let s = TcpStream::connect(addr).unwrap();
        s.set_nodelay(true).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        Rtde { s, acc: Vec::new() }
    }
    fn raw(&mut self, bytes: &[u8]) {
        self.s.write_all(bytes).unwrap();
    }
    fn send(&mut self, ty: u8, payload: &[u8]) {
        self.raw(&pkg(ty, payload));
    }
    /// The next package (type, payload); None when closed.
    fn next(&mut self) -> Option<(u8, Vec<u8>)> {
        loop {
            if self.acc.len() >= 3 {
                let size = usize::from(u16::from_be_bytes([self.acc[0], self.acc[1]]));
                assert!(size >= 3);
                if self.acc.len() >= size {
                    let p: Vec<u8> = self.acc.drain(..size).collect();
                    return Some((p[2], p[3..].to_vec()));
                }
            }
            let mut buf = [0u8; 4096];
            match self.s.read(&mut buf) {
                Ok(0) => return None,
                Ok(n) => self.acc.extend_from_slice(&buf[..n]),
                Err(e) => panic!("read: {e}"),
            }
        }
    }
    /// The next reply of type `ty`, skipping `M` and `U`.
    fn reply(&mut self, ty: u8) -> Vec<u8> {
        loop {
            let (t, p) = self.next().expect("closed");
            if t == ty {
                return p;
            }
            assert!(t == TEXT || t == DATA, "unexpected {t} waiting for {ty}");
        }
    }
    fn setup_outputs(&mut self, hz: f64, names: &str) -> (u8, String) {
        let mut p = hz.to_be_bytes().to_vec();
        p.extend_from_slice(names.as_bytes());
        self.send(SETUP_OUTPUTS, &p);
        let r = self.reply(SETUP_OUTPUTS);
        (r[0], String::from_utf8(r[1..].to_vec()).unwrap())
    }
    fn setup_inputs(&mut self, names: &str) -> (u8, String) {
        self.send(SETUP_INPUTS, names.as_bytes());
        let r = self.reply(SETUP_INPUTS);
        (r[0], String::from_utf8(r[1..].to_vec()).unwrap())
    }
    fn start(&mut self) -> u8 {
        self.send(START, &[]);
        self.reply(START)[0]
    }
}

fn f64s(b: &[u8]) -> Vec<f64> {
    b.chunks_exact(8).map(|c| f64::from_be_bytes(c.try_into().unwrap())).collect()
}

fn wait_for(what: &str, mut ok: impl FnMut() -> bool) {
    let t = Instant::now();
    while !ok() {
        assert!(t.elapsed() < Duration::from_secs(2), "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn script(port: u16) -> String {
    format!(
        "stop program\ndef strandControl():\n\tsteptime = get_steptime()\n\t# socket_open(\"10.0.0.1\", 1, \"x\")\n\
         \tsocket_open(\"127.0.0.1\", {port}, \"reverse_socket\")\n\tservoj(q, t=steptime, lookahead_time=0.05, gain=1000)\nend\n"
    )
}

fn send_script(addr: SocketAddr, text: &str) {
    let mut c = TcpStream::connect(addr).unwrap();
    c.write_all(text.as_bytes()).unwrap();
}

/// Sends a program whose reverse socket connects back to a listener here; the accepted socket.
fn start_program(ur: &FakeUr) -> TcpStream {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    send_script(ur.primary_addr(), &script(l.local_addr().unwrap().port()));
    l.set_nonblocking(true).unwrap();
    let t = Instant::now();
    loop {
        if let Ok((c, _)) = l.accept() {
            c.set_nonblocking(false).unwrap();
            c.set_nodelay(true).unwrap();
            c.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
            return c;
        }
        assert!(t.elapsed() < Duration::from_secs(2), "the program did not connect back");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn message(timeout_ms: i32, q: [f64; 6], mode: i32) -> [u8; 32] {
    let mut m = [0u8; 32];
    m[..4].copy_from_slice(&timeout_ms.to_be_bytes());
    for (j, v) in q.iter().enumerate() {
        m[4 + 4 * j..8 + 4 * j].copy_from_slice(&((v * 1e6).round() as i32).to_be_bytes());
    }
    m[28..].copy_from_slice(&mode.to_be_bytes());
    m
}

fn at_eof(c: &mut TcpStream) -> bool {
    let mut b = [0u8; 16];
    matches!(c.read(&mut b), Ok(0) | Err(_))
}

#[test]
fn handshake_bytes_from_the_doc() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let mut c = Rtde::connect(ur.rtde_addr());
    // §1.3 step 2: V version 2, then v.
    c.raw(&[0x00, 0x05, 0x56, 0x00, 0x02]);
    assert_eq!(c.next(), Some((V, vec![1])));
    c.send(V, &[0, 1]);
    assert_eq!(c.next(), Some((V, vec![0])));
    c.raw(&[0x00, 0x03, 0x76]);
    let (t, p) = c.next().unwrap();
    assert_eq!((t, p.len()), (VERSION, 16));
    assert_eq!(&p[..8], &[0, 0, 0, 5, 0, 0, 0, 15]);
    // §1.3 step 4 bytes.
    let mut o = vec![0x00, 0x1d, 0x4f, 0x40, 0x7f, 0x40, 0, 0, 0, 0, 0];
    o.extend_from_slice(b"timestamp,actual_q");
    assert_eq!(o, pkg(SETUP_OUTPUTS, &[&500f64.to_be_bytes()[..], b"timestamp,actual_q"].concat()));
    c.raw(&o);
    assert_eq!(c.reply(SETUP_OUTPUTS), [&[1u8][..], b"DOUBLE,VECTOR6D"].concat());
    // §1.6: the analog recipe and the example package.
    assert_eq!(
        c.setup_inputs("standard_analog_output_mask,standard_analog_output_type,standard_analog_output_0"),
        (1, "UINT8,UINT8,DOUBLE".into())
    );
    // §1.5: the speed slider recipe (id 2 here) and its test vector's layout.
    assert_eq!(c.setup_inputs("speed_slider_mask"), (2, "UINT32".into()));
    assert_eq!(c.start(), 1);
    c.raw(&[0x00, 0x0e, 0x55, 0x01, 0x01, 0x01, 0x3f, 0xe0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(pkg(DATA, &[1, 0, 0, 0, 1]), [0x00, 0x08, 0x55, 0x01, 0, 0, 0, 1]);
    c.raw(&[0x00, 0x08, 0x55, 0x02, 0, 0, 0, 1]);
    let w = ur.watch();
    wait_for("the analog output", || w.analog_output()[0] == (1, 0.5));
    assert_eq!(w.analog_output()[1], (0, 0.0));
    // The second recipe's package is read (a mask without a fraction changes nothing).
    std::thread::sleep(Duration::from_millis(20));
    let r = ur.stop();
    assert_eq!((r.analog_writes, r.garbage, r.rtde_sessions), (1, 0, 1));
}

#[test]
fn a_session_streams_at_500_hz_with_the_recipe_layout() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let w = ur.watch();
    let mut c = Rtde::connect(ur.rtde_addr());
    c.send(V, &2u16.to_be_bytes());
    assert_eq!(c.reply(V), [1]);
    c.send(VERSION, &[]);
    c.reply(VERSION);
    let names = "timestamp,actual_q,actual_qd,target_q,target_qd,robot_mode,safety_mode,runtime_state,speed_scaling,\
                 target_speed_fraction,robot_status_bits,safety_status_bits";
    let (id, types) = c.setup_outputs(500.0, names);
    assert_eq!(id, 1);
    assert_eq!(types, "DOUBLE,VECTOR6D,VECTOR6D,VECTOR6D,VECTOR6D,INT32,INT32,UINT32,DOUBLE,DOUBLE,UINT32,UINT32");
    let (iid, _) = c.setup_inputs("standard_analog_output_mask,standard_analog_output_type,standard_analog_output_1");
    assert_eq!(iid, 1);
    w.set_speed_scaling(0.25);
    assert_eq!(c.start(), 1);
    // Set output 1 to current, 0.75 (and one package that sets nothing).
    c.send(DATA, &[&[1u8, 2, 0][..], &0.75f64.to_be_bytes()].concat());
    c.send(DATA, &[&[1u8, 0, 0][..], &0.1f64.to_be_bytes()].concat());
    let mut stamps = Vec::new();
    let mut texts = 0;
    let t = Instant::now();
    while stamps.len() < 200 {
        let (ty, p) = c.next().unwrap();
        if ty == TEXT {
            texts += 1;
            continue;
        }
        assert_eq!(ty, DATA);
        assert_eq!(p.len(), 1 + 8 + 4 * 48 + 4 + 4 + 4 + 8 + 8 + 4 + 4);
        assert_eq!(p[0], 1);
        let d = f64s(&p[1..1 + 8 * 25]);
        assert_eq!(&d[1..7], &UrOptions::default().start_q);
        let ints = &p[1 + 200..];
        assert_eq!(i32::from_be_bytes(ints[..4].try_into().unwrap()), 7);
        assert_eq!(i32::from_be_bytes(ints[4..8].try_into().unwrap()), 1);
        assert_eq!(u32::from_be_bytes(ints[8..12].try_into().unwrap()), 1);
        assert_eq!(f64s(&ints[12..28]), [0.25, 1.0]);
        assert_eq!(u32::from_be_bytes(ints[28..32].try_into().unwrap()), 1);
        assert_eq!(u32::from_be_bytes(ints[32..36].try_into().unwrap()), 1);
        stamps.push(d[0]);
    }
    let elapsed = t.elapsed().as_secs_f64();
    assert!(texts <= 1);
    let span = stamps[199] - stamps[0];
    assert!((span / 199.0 - 0.002).abs() < 0.0005, "mean interval {}", span / 199.0);
    assert!(stamps.windows(2).all(|w| w[1] > w[0]));
    assert!(elapsed > 0.3 && elapsed < 1.0, "200 packages in {elapsed} s");
    assert_eq!(w.analog_output(), [(0, 0.0), (0, 0.75)]);
    // Pause: the reply, then silence.
    c.send(PAUSE, &[]);
    assert_eq!(c.reply(PAUSE), [1]);
    c.s.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
    let mut b = [0u8; 64];
    assert!(c.s.read(&mut b).is_err());
    let r = ur.stop();
    assert_eq!((r.analog_writes, r.garbage), (1, 0));
}

#[test]
fn unknown_names_bad_frequency_and_inputs_in_use() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let mut c = Rtde::connect(ur.rtde_addr());
    assert_eq!(c.setup_outputs(500.0, "timestamp,no_such_output"), (0, "DOUBLE,NOT_FOUND".into()));
    assert_eq!(c.start(), 0);
    assert_eq!(c.setup_outputs(600.0, "timestamp"), (0, String::new()));
    assert_eq!(c.setup_outputs(125.0, "timestamp"), (1, "DOUBLE".into()));
    assert_eq!(c.setup_inputs("speed_slider_mask,bogus"), (0, "UINT32,NOT_FOUND".into()));
    assert_eq!(c.setup_inputs("speed_slider_mask,speed_slider_fraction"), (1, "UINT32,DOUBLE".into()));
    let mut d = Rtde::connect(ur.rtde_addr());
    assert_eq!(d.setup_inputs("speed_slider_fraction,input_int_register_3"), (0, "IN_USE,INT32".into()));
    drop(c);
    let mut e = Rtde::connect(ur.rtde_addr());
    assert_eq!(e.setup_inputs("speed_slider_fraction,input_int_register_3"), (1, "DOUBLE,INT32".into()));
    // A CB3 allows 125 Hz at most.
    let cb3 = FakeUr::spawn(UrOptions { version: [3, 15, 0, 0], ..UrOptions::default() }).unwrap();
    let mut f = Rtde::connect(cb3.rtde_addr());
    assert_eq!(f.setup_outputs(250.0, "timestamp"), (0, String::new()));
    assert_eq!(f.setup_outputs(125.0, "timestamp"), (1, "DOUBLE".into()));
    let r = ur.stop();
    assert_eq!(r.garbage, 0);
}

#[test]
fn framing_split_and_merged_and_any_bytes() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let mut c = Rtde::connect(ur.rtde_addr());
    for b in [0x00, 0x05, 0x56, 0x00, 0x02] {
        c.raw(&[b]);
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(c.next(), Some((V, vec![1])));
    c.raw(
        &[&pkg(V, &[0, 2])[..], &pkg(VERSION, &[]), &pkg(SETUP_OUTPUTS, &[&250f64.to_be_bytes()[..], b"actual_q"].concat())[..5]].concat(),
    );
    assert_eq!(c.next(), Some((V, vec![1])));
    assert_eq!(c.next().unwrap().0, VERSION);
    c.raw(&pkg(SETUP_OUTPUTS, &[&250f64.to_be_bytes()[..], b"actual_q"].concat())[5..]);
    assert_eq!(c.reply(SETUP_OUTPUTS), [&[1u8][..], b"VECTOR6D"].concat());
    assert_eq!(c.start(), 1);
    let t = Instant::now();
    let mut n = 0;
    while n < 25 {
        let (ty, p) = c.next().unwrap();
        if ty == DATA {
            assert_eq!(p.len(), 49);
            n += 1;
        }
    }
    assert!(t.elapsed() > Duration::from_millis(80), "250 Hz: 25 packages in {:?}", t.elapsed());
    // Unknown types and bad lengths are counted; a size below 3 ends the connection.
    c.send(b'Z', &[1, 2, 3]);
    c.send(V, &[2]);
    c.send(DATA, &[9, 9]);
    c.raw(&[0x00, 0x01, 0x00]);
    while c.next().is_some() {}
    // Any bytes on a fresh connection and on the reverse interface: no panic.
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for _ in 0..4 {
        let mut g = TcpStream::connect(ur.rtde_addr()).unwrap();
        let bytes: Vec<u8> = (0..2000).map(|_| rnd() as u8).collect();
        let _ = g.write_all(&bytes);
    }
    let mut rev = start_program(&ur);
    for _ in 0..50 {
        let mut m: Vec<u8> = (0..32).map(|_| rnd() as u8).collect();
        m[28..].copy_from_slice(&[0, 0, 0, 9]);
        rev.write_all(&m).unwrap();
    }
    std::thread::sleep(Duration::from_millis(50));
    assert!(ur.watch().program_running());
    let r = ur.stop();
    assert!(r.garbage >= 54, "garbage {}", r.garbage);
}

#[test]
fn a_program_follows_servoj_and_ends_cleanly() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let w = ur.watch();
    let mut c = Rtde::connect(ur.rtde_addr());
    c.send(V, &[0, 2]);
    c.reply(V);
    assert_eq!(c.setup_outputs(500.0, "actual_q,actual_qd,runtime_state").0, 1);
    assert_eq!(c.start(), 1);
    let mut rev = start_program(&ur);
    wait_for("PLAYING", || w.runtime_state() == RUNTIME_PLAYING && w.program_running());
    assert_eq!(w.servo_args(), Some((Some(0.05), Some(1000.0))));
    let q0 = UrOptions::default().start_q;
    // 0.4 rad/s on joint 0 for 0.5 s, a message every 2 ms (200 ms timeout: a loaded machine).
    let rtde = std::thread::spawn(move || {
        let (mut last, mut vmax) = (Vec::new(), 0.0f64);
        let t = Instant::now();
        while t.elapsed() < Duration::from_millis(650) {
            let (ty, p) = c.next().unwrap();
            if ty == DATA {
                let d = f64s(&p[1..97]);
                vmax = vmax.max(d[6].abs());
                last = d[..6].to_vec();
            }
        }
        (last, vmax)
    });
    let t = Instant::now();
    let mut k = 0u32;
    let mut q = q0;
    while t.elapsed() < Duration::from_millis(500) {
        q[0] = q0[0] + 0.4 * 0.002 * f64::from(k);
        rev.write_all(&message(200, q, MODE_SERVOJ)).unwrap();
        k += 1;
        let next = t + Duration::from_micros(2000 * u64::from(k));
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
    }
    // Hold there while RTDE catches the end.
    for _ in 0..60 {
        rev.write_all(&message(200, q, MODE_SERVOJ)).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    let (last, vmax) = rtde.join().unwrap();
    assert!((last[0] - q[0]).abs() < 1e-6, "actual_q {last:?} vs {q:?}");
    // 0.4 rad/s, more where late messages came together, never beyond the speed limit.
    assert!((0.3..=std::f64::consts::PI + 1e-9).contains(&vmax), "largest actual_qd {vmax}");
    assert!(w.program_running());
    rev.write_all(&message(100, [0.0; 6], MODE_STOPPED)).unwrap();
    wait_for("STOPPED", || w.runtime_state() == RUNTIME_STOPPED && !w.program_running());
    assert!(at_eof(&mut rev));
    let r = ur.stop();
    assert_eq!((r.clean_stops, r.timeouts, r.violations, r.garbage), (1, 0, 0, 0));
    assert_eq!(r.scripts.len(), 1);
    assert!(r.report.cycles > 250 && r.report.cycles < 400, "rows {}", r.report.cycles);
    assert_eq!(r.report.cycles, r.report.in_time + r.report.missing);
    assert!(r.report.in_time_share() > 0.5, "in time {}", r.report.in_time_share());
    let end = r.report.axes.last().unwrap();
    assert!((end[0] - q[0].to_degrees()).abs() < 1e-4);
    assert!(!r.report.gave_up);
}

#[test]
fn silence_times_the_program_out() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let w = ur.watch();
    let mut rev = start_program(&ur);
    let mut q = UrOptions::default().start_q;
    rev.write_all(&message(20, q, MODE_SERVOJ)).unwrap();
    q[0] += 0.01;
    let t = Instant::now();
    rev.write_all(&message(30, q, MODE_SERVOJ)).unwrap();
    wait_for("the timeout", || !w.program_running());
    let waited = t.elapsed();
    assert!(waited >= Duration::from_millis(29), "stopped after {waited:?}");
    assert_eq!(w.runtime_state(), RUNTIME_STOPPED);
    assert!(at_eof(&mut rev));
    let r = ur.stop();
    assert_eq!((r.timeouts, r.clean_stops), (1, 0));
    assert!(r.report.gave_up);
}

#[test]
fn a_fast_step_is_a_violation_and_ignored() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let w = ur.watch();
    let mut rev = start_program(&ur);
    let q0 = UrOptions::default().start_q;
    let mut q = q0;
    rev.write_all(&message(0, q, MODE_SERVOJ)).unwrap();
    q[1] += 0.05; // 25 rad/s over a 2 ms step
    rev.write_all(&message(0, q, MODE_SERVOJ)).unwrap();
    std::thread::sleep(Duration::from_millis(30));
    // Held at the first setpoint (q0 to the µrad of the wire).
    assert!(w.joints().iter().zip(&q0).all(|(a, b)| (a - b).abs() < 1e-6), "{:?}", w.joints());
    q[1] = q0[1] + 0.01; // 5 rad/s: accepted, reached at π rad/s
    rev.write_all(&message(0, q, MODE_SERVOJ)).unwrap();
    wait_for("the joint", || (w.joints()[1] - q[1]).abs() < 1e-6);
    rev.write_all(&message(100, [0.0; 6], MODE_STOPPED)).unwrap();
    wait_for("the end", || !w.program_running());
    let r = ur.stop();
    assert_eq!((r.violations, r.clean_stops, r.timeouts), (1, 1, 0));
}

#[test]
fn protective_stop_ends_the_program_and_a_new_program_replaces_the_old() {
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let w = ur.watch();
    let mut a = start_program(&ur);
    let mut q = UrOptions::default().start_q;
    a.write_all(&message(0, q, MODE_SERVOJ)).unwrap();
    let mut b = start_program(&ur);
    assert!(at_eof(&mut a));
    assert!(w.program_running());
    // Setpoints at 15 rad/s (under the 20 rad/s that is ignored) run away from an arm limited to
    // π rad/s, so it is still moving at its limit when the stop comes, however late this thread
    // runs (a setpoint it had reached would leave it at rest, and the deceleration untested).
    for _ in 0..50 {
        q[0] += 0.03;
        b.write_all(&message(0, q, MODE_SERVOJ)).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    w.protective_stop();
    let v0 = w.velocities()[0];
    assert_eq!((w.safety_mode(), w.runtime_state(), w.program_running()), (SAFETY_PROTECTIVE_STOP, RUNTIME_STOPPED, false));
    assert!(at_eof(&mut b));
    // It decelerates at 4 rad/s² from π rad/s: at rest within 0.8 s, not at once.
    wait_for("rest", || w.velocities()[0] == 0.0);
    assert!(v0 > 2.5, "{v0}");
    // No program runs in a protective stop.
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    send_script(ur.primary_addr(), &script(l.local_addr().unwrap().port()));
    std::thread::sleep(Duration::from_millis(200));
    assert!(!w.program_running());
    w.unlock_protective_stop();
    let _c = start_program(&ur);
    assert!(w.program_running());
    let r = ur.stop();
    assert_eq!(r.scripts.len(), 4);
    assert_eq!((r.timeouts, r.clean_stops), (0, 0));
}

#[test]
fn scripts_are_parsed_and_a_failed_connection_ends_the_program() {
    assert!(matches!(parse_program("def p():\n  x = 1\nend"), Program::Malformed));
    assert!(matches!(parse_program("sec p():\n  x = 1\nend\n"), Program::None));
    let Program::Def(p) = parse_program(
        "def p():\n  # socket_open(\"1.2.3.4\", 1)\n  host = \"10.1.2.3\"\n  port = 50001\n  \
         socket_open(host, port, \"reverse_socket\")\n  servoj(q, t=0.002, lookahead_time = 0.1,gain=300)\nend\n",
    ) else {
        panic!()
    };
    assert_eq!(p.reverse, Some(("10.1.2.3".into(), 50001)));
    assert_eq!((p.lookahead_time, p.gain), (Some(0.1), Some(300.0)));
    let ur = FakeUr::spawn(UrOptions::default()).unwrap();
    let w = ur.watch();
    let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    send_script(ur.primary_addr(), &script(port));
    wait_for("PLAYING", || w.program_running());
    let t = Instant::now();
    while w.program_running() {
        assert!(t.elapsed() < Duration::from_secs(3));
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(t.elapsed() > Duration::from_millis(600), "gave up after {:?}", t.elapsed());
    assert_eq!(w.runtime_state(), RUNTIME_STOPPED);
    let r = ur.stop();
    assert_eq!(r.scripts.len(), 1);
}
