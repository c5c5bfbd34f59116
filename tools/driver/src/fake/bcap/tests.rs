//! Tests of the fake RC8: the doc's worked bytes, a decoder no input panics, and whole sessions
//! over TCP by a small client of the tests' own (its encoder independent of the fake's).

use super::wire::{Reader, decode_variant, frame};
use super::*;

// A small client-side encoder, independent of the fake's: arguments as `vt, count, data`.
fn arg(t: u16, count: u32, data: &[u8]) -> Vec<u8> {
    let mut v = t.to_le_bytes().to_vec();
    v.extend_from_slice(&count.to_le_bytes());
    v.extend_from_slice(data);
    v
}
fn bstr(s: &str) -> Vec<u8> {
    let text: Vec<u8> = s.encode_utf16().flat_map(u16::to_le_bytes).collect();
    let mut d = (text.len() as u32).to_le_bytes().to_vec();
    d.extend_from_slice(&text);
    arg(8, 1, &d)
}
fn i4(v: i32) -> Vec<u8> {
    arg(3, 1, &v.to_le_bytes())
}
fn i4s(v: &[i32]) -> Vec<u8> {
    arg(0x2003, v.len() as u32, &v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>())
}
fn r8s(v: &[f64]) -> Vec<u8> {
    arg(0x2005, v.len() as u32, &v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>())
}
fn empty() -> Vec<u8> {
    arg(0, 1, &[])
}
fn request(serial: u16, id: u32, args: &[Vec<u8>]) -> Vec<u8> {
    let mut p = vec![1, 0, 0, 0, 0];
    p.extend_from_slice(&serial.to_le_bytes());
    p.extend_from_slice(&[0, 0]);
    p.extend_from_slice(&id.to_le_bytes());
    p.extend_from_slice(&(args.len() as u16).to_le_bytes());
    for a in args {
        p.extend_from_slice(&(a.len() as u32).to_le_bytes());
        p.extend_from_slice(a);
    }
    p.push(4);
    let n = p.len() as u32;
    p[1..5].copy_from_slice(&n.to_le_bytes());
    p
}

/// A reply as the test reads it: HRESULT, the raw value (vt, count, data), S_EXECUTING packets skipped.
struct Reply {
    hr: u32,
    value: Option<Vec<u8>>,
    executing: u32,
}
impl Reply {
    fn r8s(&self) -> Vec<f64> {
        let v = self.value.as_ref().expect("a value");
        assert_eq!(&v[..2], &[0x05, 0x20]);
        v[6..].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect()
    }
    fn i4(&self) -> i32 {
        let v = self.value.as_ref().expect("a value");
        assert_eq!((v[0], v[1], v.len()), (3, 0, 10));
        i32::from_le_bytes(v[6..10].try_into().unwrap())
    }
    /// VARIANT[I4 time, R8×8].
    fn stamped(&self) -> (i32, Vec<f64>) {
        let v = self.value.as_ref().expect("a value");
        assert_eq!(&v[..16], &[0x0c, 0x20, 2, 0, 0, 0, 3, 0, 1, 0, 0, 0, v[12], v[13], v[14], v[15]]);
        assert_eq!(&v[16..22], &[0x05, 0x20, 8, 0, 0, 0]);
        (
            i32::from_le_bytes(v[12..16].try_into().unwrap()),
            v[22..].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect(),
        )
    }
}

struct Client {
    s: TcpStream,
    serial: u16,
    h: i32,
    r: i32,
}
impl Client {
    fn new(addr: SocketAddr) -> Client {
        let s = TcpStream::connect(addr).unwrap();
        s.set_nodelay(true).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
        Client { s, serial: 0, h: 0, r: 0 }
    }
    fn read(&mut self) -> (u16, u32, Option<Vec<u8>>) {
        let mut head = [0u8; 5];
        self.s.read_exact(&mut head).unwrap();
        assert_eq!(head[0], 1);
        let n = u32::from_le_bytes(head[1..5].try_into().unwrap()) as usize;
        let mut rest = vec![0u8; n - 5];
        self.s.read_exact(&mut rest).unwrap();
        assert_eq!(rest.last(), Some(&4));
        assert_eq!(&rest[2..4], &[0, 0], "reserved 0");
        let serial = u16::from_le_bytes([rest[0], rest[1]]);
        let hr = u32::from_le_bytes(rest[4..8].try_into().unwrap());
        let argc = u16::from_le_bytes([rest[8], rest[9]]);
        let value = (argc == 1).then(|| {
            let len = u32::from_le_bytes(rest[10..14].try_into().unwrap()) as usize;
            assert_eq!(14 + len + 1, rest.len());
            rest[14..14 + len].to_vec()
        });
        assert!(argc <= 1);
        (serial, hr, value)
    }
    fn send(&mut self, id: u32, args: &[Vec<u8>]) -> u16 {
        self.serial = self.serial % 65535 + 1;
        self.s.write_all(&request(self.serial, id, args)).unwrap();
        self.serial
    }
    fn call(&mut self, id: u32, args: &[Vec<u8>]) -> Reply {
        let serial = self.send(id, args);
        let mut executing = 0;
        loop {
            let (s, hr, value) = self.read();
            assert_eq!(s, serial);
            if hr == 0x900 {
                assert!(value.is_none());
                executing += 1;
                continue;
            }
            return Reply { hr, value, executing };
        }
    }
    fn robot(&mut self, command: &str, param: Vec<u8>) -> Reply {
        let r = self.r;
        self.call(64, &[i4(r), bstr(command), param])
    }
    /// Service_Start .. Motor on, formats: ready for slvChangeMode.
    fn up(&mut self, recv: Vec<u8>) -> Vec<f64> {
        assert_eq!(self.call(1, &[bstr(",WDT=80,InvokeTimeout=180000")]).hr, 0);
        let c = self.call(3, &[bstr(""), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")]);
        assert_eq!(c.hr, 0);
        self.h = c.i4();
        assert_eq!(self.call(17, &[i4(self.h), bstr("ClearError"), empty()]).hr, 0);
        let r = self.call(7, &[i4(self.h), bstr("Arm"), bstr("")]);
        assert_eq!(r.hr, 0);
        self.r = r.i4();
        assert_eq!(self.robot("TakeArm", i4s(&[0, 1])).hr, 0);
        assert_eq!(self.robot("Motor", i4s(&[1, 0])).hr, 0);
        let q = self.robot("CurJnt", empty()).r8s();
        assert_eq!(self.robot("slvSendFormat", i4(0)).hr, 0);
        assert_eq!(self.robot("slvRecvFormat", recv).hr, 0);
        q
    }
    fn down(&mut self) {
        assert_eq!(self.robot("slvChangeMode", i4(0)).hr, 0);
        assert_eq!(self.robot("Motor", i4s(&[0, 0])).hr, 0);
        assert_eq!(self.robot("GiveArm", empty()).hr, 0);
        let r = self.r;
        assert_eq!(self.call(84, &[i4(r)]).hr, 0);
        let h = self.h;
        assert_eq!(self.call(4, &[i4(h)]).hr, 0);
        assert_eq!(self.call(2, &[]).hr, 0);
    }
}

/// SCHED_FIFO priority for the fake's threads and the streaming clients, if permitted: on a
/// machine busy with builds a client stalled two cycles would rightly get 0x84201482.
const RT: Option<i32> = Some(10);

fn opts(cycle: f64) -> BcapOptions {
    BcapOptions { cycle, motor_on_time: 0.0, start_deg: vec![10.0, -20.0, 30.0, 0.0, 45.0, 0.0], rt_priority: RT, ..BcapOptions::default() }
}

/// The calling thread real-time while it lives (if permitted), back to SCHED_OTHER after.
struct RealTime;
impl RealTime {
    fn new() -> RealTime {
        real_time(RT);
        RealTime
    }
}
impl Drop for RealTime {
    fn drop(&mut self) {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: this thread (0), a valid sched_param.
        unsafe {
            libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
        }
    }
}

fn wait(mut f: impl FnMut() -> bool) {
    let t = std::time::Instant::now();
    while !f() {
        assert!(t.elapsed() < Duration::from_secs(2), "timed out");
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn hex(b: &str) -> Vec<u8> {
    b.split_whitespace().filter(|s| *s != "|").map(|s| u8::from_str_radix(s, 16).unwrap()).collect()
}

#[test]
fn the_docs_worked_bytes() {
    let start = hex("01 1E 00 00 00 01 00 00 00 01 00 00 00 01 00 | 0A 00 00 00 08 00 01 00 00 00 00 00 00 00 | 04");
    let p = Packet { serial: 1, reserved: 0, id: func::SERVICE_START, args: vec![Variant::Bstr(String::new())] };
    assert_eq!(p.encode(), start);
    assert_eq!(Packet::decode(&start), Ok(p));
    assert_eq!(request(1, 1, &[bstr("")]), start, "the test's encoder agrees");

    let mut mode = hex("01 54 00 00 00 05 00 00 00 40 00 00 00 03 00 0A 00 00 00 03 00 01 00 00 00 12 00 00 00");
    mode.extend(hex("24 00 00 00 08 00 01 00 00 00 1A 00 00 00"));
    mode.extend("slvChangeMode".encode_utf16().flat_map(u16::to_le_bytes));
    mode.extend(hex("0A 00 00 00 03 00 01 00 00 00 02 02 00 00 04"));
    assert_eq!(mode.len(), 84);
    let p = Packet {
        serial: 5,
        reserved: 0,
        id: func::ROBOT_EXECUTE,
        args: vec![Variant::I4(0x12), Variant::Bstr("slvChangeMode".into()), Variant::I4(0x202)],
    };
    assert_eq!(p.encode(), mode);
    assert_eq!(Packet::decode(&mode), Ok(p));

    let q = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0, 0.0];
    let p = Packet { serial: 9, reserved: 0, id: 64, args: vec![Variant::I4(0x12), Variant::Bstr("slvMove".into()), Variant::r8s(&q)] };
    let b = p.encode();
    assert_eq!(b.len(), 132);
    assert_eq!(&b[b.len() - 75..b.len() - 65], &hex("46 00 00 00 05 20 08 00 00 00")[..]);
    assert_eq!(Packet::decode(&b), Ok(p));

    let e = hex("01 10 00 00 00 07 00 00 00 82 14 20 84 00 00 04");
    let p = Packet { serial: 7, reserved: 0, id: hr::E_BUF_EMPTY, args: vec![] };
    assert_eq!(p.encode(), e);
    assert_eq!(Packet::decode(&e), Ok(p));

    // §2: VARIANT array [I4 5, R8 [1, 2]].
    let v = Variant::Array(vt::VARIANT, vec![Variant::I4(5), Variant::r8s(&[1.0, 2.0])]);
    let mut out = Vec::new();
    v.encode(&mut out);
    let mut want = hex("0C 20 02 00 00 00 | 03 00 01 00 00 00 05 00 00 00 | 05 20 02 00 00 00");
    want.extend(1.0f64.to_le_bytes());
    want.extend(2.0f64.to_le_bytes());
    assert_eq!(out, want);
    assert_eq!(decode_variant(&mut Reader(&want), 0), Some(v));
    // BOOL true is 0xFFFF; a BSTR's length counts bytes.
    out.clear();
    Variant::Bool(true).encode(&mut out);
    assert_eq!(out, hex("0B 00 01 00 00 00 FF FF"));
    out.clear();
    Variant::Bstr("Ab".into()).encode(&mut out);
    assert_eq!(out, hex("08 00 01 00 00 00 04 00 00 00 41 00 62 00"));
}

#[test]
fn no_input_panics_the_decoder() {
    let full = request(3, 64, &[i4(1), bstr("slvMove"), r8s(&[1.0; 8]), arg(0x200C, 2, &[i4(5), r8s(&[1.0, 2.0])].concat())]);
    assert!(Packet::decode(&full).is_ok());
    for n in 0..full.len() {
        assert!(Packet::decode(&full[..n]).is_err());
        let _ = frame(&full[..n]);
    }
    let mut x = 0x2545_f491_4f6c_dd1du64;
    for len in 0..5000 {
        x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let mut m = full.clone();
        m[len % full.len()] = (x >> 33) as u8;
        m[(len * 7) % full.len()] ^= (x >> 17) as u8;
        let _ = (Packet::decode(&m), frame(&m));
        let bytes: Vec<u8> = (0..len % 97).map(|i| (x >> (i % 57)) as u8).collect();
        let _ = (Packet::decode(&bytes), frame(&bytes));
    }
    // A huge count must not allocate: rejected against the bytes left.
    let huge = request(1, 1, &[arg(0x2005, u32::MAX, &[0; 8])]);
    assert_eq!(Packet::decode(&huge), Err(Some(1)));
    let deep = request(1, 1, &[(0..20).fold(empty(), |inner, _| arg(0x200C, 1, &inner))]);
    assert_eq!(Packet::decode(&deep), Err(Some(1)));
}

#[test]
fn the_full_sequence_streams_200_moves_in_mode_2_and_releases_cleanly() {
    // 7 ms: the client may stall two cycles (14 ms) on a loaded machine before the buffer runs dry.
    let cycle = 0.007;
    let _rt = RealTime::new();
    let fake = FakeBcap::spawn(BcapOptions { motor_on_time: 0.2, ..opts(cycle) }).unwrap();
    let watch = fake.watch();
    let mut c = Client::new(fake.addr());
    wait(|| watch.connected());
    assert_eq!(c.call(1, &[bstr(",WDT=80,InvokeTimeout=180000")]).hr, 0);
    let ctrl = c.call(3, &[bstr(""), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")]);
    assert_eq!(ctrl.hr, 0);
    c.h = ctrl.i4();
    assert_eq!(c.call(17, &[i4(c.h), bstr("ClearError"), empty()]).hr, 0);
    // Handles as VT_UI4 are taken too.
    let robot = c.call(7, &[arg(19, 1, &(c.h as u32).to_le_bytes()), bstr("Arm"), bstr("")]);
    c.r = robot.i4();
    assert_eq!(c.robot("TakeArm", i4s(&[0, 1])).hr, 0);
    assert!(watch.arm_taken());
    let t = std::time::Instant::now();
    let m = c.robot("Motor", i4s(&[1, 0]));
    assert_eq!(m.hr, 0);
    assert!(t.elapsed() >= Duration::from_millis(195));
    // At 80 and 160 ms (the second may be lost to a late wake-up on a loaded machine).
    assert!((1..=3).contains(&m.executing), "S_EXECUTING every 80 ms of 200: {}", m.executing);
    assert!(watch.motor_on());
    let start = c.robot("CurJnt", empty()).r8s();
    assert_eq!(start, [10.0, -20.0, 30.0, 0.0, 45.0, 0.0, 0.0, 0.0]);
    assert_eq!(c.robot("slvSendFormat", i4(0)).hr, 0);
    assert_eq!(c.robot("slvRecvFormat", i4s(&[0x12, 0])).hr, 0);
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
    assert_eq!(c.robot("slvGetMode", empty()).i4(), 0x202);
    assert_eq!(c.robot("TakeArm", i4s(&[0, 1])).hr, hr::E_IN_SLAVE_MODE);
    // A smooth ramp on J1 (10° over 200 cycles, cosine) and J5 (−5°).
    let n = 200;
    let t = std::time::Instant::now();
    let mut last = start.clone();
    let mut stamps = Vec::new();
    for k in 1..=n {
        let s = 0.5 - 0.5 * (std::f64::consts::PI * k as f64 / n as f64).cos();
        let mut q = start.clone();
        q[0] += 10.0 * s;
        q[4] -= 5.0 * s;
        let r = c.robot("slvMove", r8s(&q));
        assert_eq!(r.hr, 0, "move {k}");
        let (stamp, actual) = r.stamped();
        stamps.push(stamp);
        // The robot follows 2–3 commands behind (the buffer).
        assert!((actual[0] - q[0]).abs() < 4.0 * 10.0 * std::f64::consts::PI / 2.0 / n as f64 + 1e-9, "{k}: {actual:?} vs {q:?}");
        last = q;
    }
    let elapsed = t.elapsed().as_secs_f64();
    assert!(elapsed > (n - 4) as f64 * cycle * 0.95, "mode 2 paces the client to the cycle: {elapsed}");
    assert!(stamps.windows(2).all(|w| w[1] >= w[0]));
    // Leaving slave mode at once (the 2 commands still buffered are dropped): the robot stops
    // within 2 steps of the last command.
    assert_eq!(c.robot("slvChangeMode", i4(0)).hr, 0);
    let stop = c.robot("CurJnt", empty()).r8s();
    assert!((stop[0] - last[0]).abs() < 2.0 * 0.08 && stop[0] != start[0], "{stop:?} vs {last:?}");
    assert!(watch.errors().is_empty(), "{:x?}", watch.errors());
    c.down();
    drop(c);
    wait(|| !watch.connected());
    assert!(watch.released());
    assert!(!watch.arm_taken() && !watch.motor_on() && watch.slave_mode() == 0);
    let r = fake.stop();
    assert!(r.released);
    assert_eq!((r.slv_moves, r.buffer_full, r.garbage, r.errors.len()), (n as u64, 0, 0, 0));
    assert!((n as u64 - 3..=n as u64).contains(&r.report.in_time), "{}", r.report.in_time);
    assert_eq!(r.report.missing, 0);
    assert_eq!(r.report.round_trip.count(), n as u64);
    let (v, a) = r.report.max_rates(cycle, 0.0);
    assert!(v[0] < 20.5 && a[0] < 200.0, "{v:?} {a:?}");
    assert_eq!(
        r.calls,
        [
            "Service_Start",
            "Controller_Connect",
            "Controller_Execute(ClearError)",
            "Controller_GetRobot",
            "Robot_Execute(TakeArm)",
            "Robot_Execute(Motor)",
            "Robot_Execute(CurJnt)",
            "Robot_Execute(slvSendFormat)",
            "Robot_Execute(slvRecvFormat)",
            "Robot_Execute(slvChangeMode)",
            "Robot_Execute(slvGetMode)",
            "Robot_Execute(TakeArm)",
        ]
        .iter()
        .map(|s| s.to_string())
        .chain(r.calls[12..].iter().cloned())
        .collect::<Vec<_>>()
    );
    assert_eq!(r.calls.last().map(String::as_str), Some("Service_Stop"));
}

#[test]
fn a_pause_of_5_cycles_latches_buffer_empty_and_recovery_needs_clear_error() {
    let _rt = RealTime::new();
    let fake = FakeBcap::spawn(opts(0.008)).unwrap();
    let watch = fake.watch();
    let mut c = Client::new(fake.addr());
    let q = c.up(i4(2));
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
    for _ in 0..20 {
        let r = c.robot("slvMove", r8s(&q));
        assert_eq!(r.hr, 0);
        assert_eq!(r.r8s(), q);
    }
    std::thread::sleep(Duration::from_millis(5 * 8 + 5));
    wait(|| !watch.errors().is_empty());
    assert_eq!(watch.errors(), [hr::E_BUF_EMPTY]);
    assert_eq!(watch.slave_mode(), 0);
    assert!(!watch.motor_on(), "a level-4 error switches the motor off");
    assert_eq!(c.robot("slvMove", r8s(&q)).hr, hr::E_SLAVE_OFF);
    assert_eq!(c.robot("Motor", i4(1)).hr, hr::E_ERROR_PENDING);
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_ERROR_PENDING);
    let h = c.h;
    let d = c.call(17, &[i4(h), bstr("GetErrorDescription"), i4(hr::E_BUF_EMPTY as i32)]);
    assert_eq!(d.hr, 0);
    assert!(d.value.unwrap().len() > 10);
    assert_eq!(c.call(17, &[i4(h), bstr("ClearError"), empty()]).hr, 0);
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_MOTOR_OFF);
    assert_eq!(c.robot("Motor", i4(1)).hr, 0);
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
    for _ in 0..10 {
        assert_eq!(c.robot("slvMove", r8s(&q)).hr, 0);
    }
    // An injected fault ends slave mode as a real one would.
    watch.inject_error(0x8420_1486);
    assert_eq!(c.robot("slvMove", r8s(&q)).hr, hr::E_SLAVE_OFF);
    c.down();
    drop(c);
    wait(|| !watch.connected());
    let r = fake.stop();
    assert_eq!(r.errors, [hr::E_BUF_EMPTY, 0x8420_1486]);
    assert!(r.released, "a clean release after faults is still clean");
    assert_eq!(r.report.missing, 1);
    assert_eq!(r.report.cycles, r.report.in_time + 1);
    assert_eq!(r.report.fresh.iter().filter(|f| !**f).count(), 1);
}

#[test]
fn a_connection_dropped_mid_stream_runs_out_the_buffer_then_latches_buffer_empty() {
    let _rt = RealTime::new();
    let fake = FakeBcap::spawn(BcapOptions { lag: 0.02, ..opts(0.008) }).unwrap();
    let watch = fake.watch();
    let mut c = Client::new(fake.addr());
    let q = c.up(i4(2));
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
    let mut p = q.clone();
    for k in 1..=10 {
        p[1] = q[1] + 0.01 * f64::from(k);
        assert_eq!(c.robot("slvMove", r8s(&p)).hr, 0);
    }
    drop(c);
    wait(|| !watch.errors().is_empty());
    assert_eq!((watch.errors(), watch.slave_mode(), watch.arm_taken(), watch.released()), (vec![hr::E_BUF_EMPTY], 0, false, false));
    let r = fake.stop();
    assert_eq!((r.report.in_time, r.report.missing), (10, 1), "the 2 buffered commands were run out");
    // The drives lag: the actual joint 2 moves less than commanded, never past it.
    let j2: Vec<f64> = r.report.axes.iter().map(|a| a[1]).collect();
    assert!(j2.windows(2).all(|w| w[1] >= w[0] - 1e-12) && j2.iter().all(|v| *v < q[1] + 0.1 - 1e-6), "{j2:?}");
}

#[test]
fn a_jump_latches_the_speed_or_acceleration_error_of_its_joint() {
    for (speed, accel, joint, step, code) in [(100.0, 1e9, 2, 5.0, hr::E_SPEED + 3), (1e9, 1000.0, 1, 0.1, hr::E_ACCEL + 2)] {
        let fake =
            FakeBcap::spawn(BcapOptions { speed_limit_deg: vec![speed; 6], accel_limit_deg: vec![accel; 6], ..opts(0.004) }).unwrap();
        let watch = fake.watch();
        let mut c = Client::new(fake.addr());
        let q = c.up(i4(2));
        assert_eq!(c.robot("slvChangeMode", i4(0x002)).hr, 0);
        let mut jump = q.clone();
        jump[joint] += step;
        let hrs: Vec<u32> = [&q, &q, &jump].iter().map(|p| c.robot("slvMove", r8s(p)).hr).collect();
        assert!(hrs.iter().all(|h| [hr::S_OK, hr::S_BUF_FULL].contains(h)), "{hrs:x?}");
        wait(|| !watch.errors().is_empty());
        assert_eq!(watch.errors(), [code]);
        assert_eq!(watch.slave_mode(), 0);
        assert_eq!(c.robot("CurJnt", empty()).r8s(), q, "the robot stopped before the jump");
        assert_eq!(c.robot("slvMove", r8s(&q)).hr, hr::E_SLAVE_OFF);
        drop(c);
        wait(|| !watch.connected());
        let r = fake.stop();
        assert!(!r.released);
        assert_eq!((r.report.cycles, r.report.in_time), (3, 3));
    }
}

#[test]
fn mode_0_answers_buf_full_and_mode_1_overwrites() {
    let fake = FakeBcap::spawn(opts(0.3)).unwrap();
    let watch = fake.watch();
    let mut c = Client::new(fake.addr());
    let q = c.up(i4(2));
    assert_eq!(c.robot("slvChangeMode", i4(0x002)).hr, 0);
    let hrs: Vec<u32> = (0..5).map(|_| c.robot("slvMove", r8s(&q)).hr).collect();
    // A tick may pop one between two calls (one in 300 ms): the S_BUF_FULL → E_BUF_FULL pair is there anyway.
    let at = hrs.iter().position(|h| *h == hr::S_BUF_FULL).expect("S_BUF_FULL");
    assert_eq!(hrs.get(at + 1), Some(&hr::E_BUF_FULL), "{hrs:x?}");
    assert!(watch.errors().is_empty(), "E_BUF_FULL is not latched");
    assert_eq!(c.robot("slvChangeMode", i4(0)).hr, 0);
    assert_eq!(c.robot("slvChangeMode", i4(0x102)).hr, 0);
    assert!((0..5).all(|_| c.robot("slvMove", r8s(&q)).hr == hr::S_OK));
    assert_eq!(c.robot("slvChangeMode", i4(0)).hr, 0);
    assert_eq!(c.robot("slvChangeMode", i4(0x201)).hr, hr::E_INVALIDARG, "P type: no kinematics here");
    let r = fake.stop();
    assert!(r.buffer_full >= 1);
    assert!(r.errors.is_empty());
}

#[test]
fn garbage_is_skipped_bad_packets_answered_and_a_second_client_refused() {
    let fake = FakeBcap::spawn(opts(0.008)).unwrap();
    let watch = fake.watch();
    let mut c = Client::new(fake.addr());
    c.s.write_all(b"HELLO").unwrap();
    assert_eq!(c.call(1, &[]).hr, 0);
    // A bad terminator: E_INVALIDPACKET with its serial.
    let mut bad = request(77, 1, &[]);
    *bad.last_mut().unwrap() = 5;
    c.s.write_all(&bad).unwrap();
    assert_eq!(c.read(), (77, hr::E_INVALIDPACKET, None));
    // An argument longer than the packet: the same.
    let mut bad = request(78, 1, &[bstr("x")]);
    bad[15] = 0x30;
    c.s.write_all(&bad).unwrap();
    assert_eq!(c.read(), (78, hr::E_INVALIDPACKET, None));
    // An SOH with a length below 16: dropped, the rest is garbage.
    c.s.write_all(&[1, 3, 0, 0, 0]).unwrap();
    assert_eq!(c.call(1, &[]).hr, 0);
    // An SOH whose made-up length never arrives: given up after 200 ms.
    c.s.write_all(&[1, 0xff, 0, 0, 0]).unwrap();
    std::thread::sleep(Duration::from_millis(250));
    assert_eq!(c.call(1, &[]).hr, 0);
    // Calls the controller refuses.
    let h = c.call(3, &[bstr(""), bstr("CaoProv.DENSO.RC8"), bstr(""), bstr("")]);
    assert_eq!((h.hr, h.value.is_none()), (hr::E_CAO_OBJECT_NOT_FOUND, true));
    let h = c.call(3, &[bstr(""), bstr("CaoProv.DENSO.VRC"), bstr(""), bstr("")]).i4();
    assert_eq!(c.call(7, &[i4(h + 100), bstr(""), bstr("")]).hr, hr::E_HANDLE);
    c.r = c.call(7, &[i4(h), bstr(""), bstr("")]).i4();
    assert_eq!(c.robot("Dance", empty()).hr, hr::E_INVALID_CMD_NAME);
    assert_eq!(c.robot("slvMove", r8s(&[0.0; 8])).hr, hr::E_SLAVE_OFF);
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_ACCESSDENIED);
    assert_eq!(c.robot("TakeArm", empty()).hr, 0);
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_MOTOR_OFF);
    assert_eq!(c.robot("Motor", i4s(&[1, 1])).hr, 0, "noWait");
    assert_eq!(c.call(99, &[]).hr, hr::E_NOTIMPL);
    // A second client is refused while one is connected.
    let mut other = Client::new(fake.addr());
    let serial = other.send(1, &[]);
    assert_eq!(other.read(), (serial, hr::E_MAX_CONNECT, None));
    assert!(watch.connected());
    // Dropped in slave mode before any command: the robot stops, nothing latched.
    assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
    drop(c);
    wait(|| !watch.connected());
    assert_eq!((watch.slave_mode(), watch.errors().len(), watch.released()), (0, 0, false));
    let r = fake.stop();
    assert_eq!(r.garbage, 5 + 2 + 5 + 5, "HELLO, two bad packets, 01 03 00 00 00, 01 FF 00 00 00");
}
