//! A Mecademic Meca500 R3 robot as its TCP text API shows it, written from
//! `docs/protocols/meca500.md` only (§1 transport, §2 commands, §3 codes, §4 velocity mode, §5
//! monitoring, §7 the fake robot's spec), not from the driver's code, so that the driver is
//! checked against an independent reading of the same description.
//!
//! Two listeners: the control port (one client at a time; a second is told `[3001]` and closed)
//! takes NUL- or `\n`-terminated commands, split or merged across reads, and answers
//! `[CCCC][payload]\0`; the monitoring port (any number of clients) sends its banner, a `[2007]`
//! snapshot, every change of the status and, every monitoring interval, `[2026]` joints,
//! `[2027]` pose (zeros), `[2200]` target joints, `[2201]` target pose (zeros), the optional
//! real-time codes enabled with `SetRealTimeMonitoring`, then `[2230][t]`, all stamped with the
//! same `t` (µs since [`FakeMeca::spawn`]). On firmware ≥ 9 `SetCtrlPortMonitoring(1)` copies that
//! stream onto the control socket.
//!
//! A trajectory thread runs every `tick` on absolute deadlines: the joints' velocities ramp
//! towards the last `MoveJointsVel` (capped to the R3's speeds × `SetJointVelLimit` %) at the
//! per-joint acceleration × `SetJointAcc` %, all joints reaching the target together (§4: "all
//! joints start and stop together"); after `SetVelTimeout` without a newer `MoveJointsVel` the
//! target is zero (a timeout counted); paused, in error, deactivated or without a control client
//! the arm decelerates to rest; a joint reaching its R3 limit stops there (no error, counted).
//! Choices where the description is open are listed on [`FakeMeca`].

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

mod commands;
mod robot;
pub mod virtual_time;

#[cfg(test)]
mod tests;

use super::{FakeReport, every, real_time};
use robot::State;

/// One message on the wire: `[CCCC][payload]` and the NUL that ends it.
fn msg(code: u32, payload: &str) -> Vec<u8> {
    format!("[{code:04}][{payload}]\0").into_bytes()
}

/// Values as the robot prints them: comma-separated, six decimals.
fn list(values: &[f64]) -> String {
    values.iter().map(|v| format!("{v:.6}")).collect::<Vec<_>>().join(",")
}

/// A real-time monitoring payload: the timestamp (µs) and the values.
fn stamped(t_us: u64, values: &[f64]) -> String {
    format!("{t_us},{}", list(values))
}

/// The Meca500's joints.
pub const JOINTS: usize = 6;
/// The Meca500 R3's joint ranges (deg, §4.1). Joint 6: ±100 turns (the turn configuration's
/// range, which velocity moves may use), not the nominal ±180.
pub const R3_LIMITS_DEG: [(f64, f64); JOINTS] =
    [(-175.0, 175.0), (-70.0, 90.0), (-135.0, 70.0), (-170.0, 170.0), (-115.0, 115.0), (-36000.0, 36000.0)];
/// The Meca500 R3's joint speeds (deg/s, §4.1) at `SetJointVelLimit(100)`.
pub const R3_SPEED_DEG: [f64; JOINTS] = [150.0, 150.0, 180.0, 300.0, 300.0, 500.0];
/// `SetVelTimeout`'s default, restored at every activation (s, §4).
pub const DEFAULT_VEL_TIMEOUT: f64 = 0.050;
/// `SetJointAcc`'s default, restored at every activation (%, the current firmware header's, §4).
pub const DEFAULT_JOINT_ACC: f64 = 80.0;
/// The monitoring interval at start (s, §5.1: robots report 0.017).
pub const DEFAULT_MONITORING_INTERVAL: f64 = 0.017;
/// The longest command (bytes, without its terminator) before `[3003]` (§7: "> ~256 bytes").
pub const MAX_COMMAND_LEN: usize = 256;
/// The optional real-time codes `SetRealTimeMonitoring` accepts (and `all` enables).
pub const RT_CODES: [u32; 21] =
    [2200, 2201, 2202, 2203, 2204, 2208, 2209, 2210, 2211, 2212, 2213, 2214, 2218, 2219, 2220, 2221, 2222, 2226, 2227, 2228, 2229];

/// Bytes queued for a client that does not read before it is dropped.
const OUT_LIMIT: usize = 4 << 20;

/// How the fake robot starts.
#[derive(Clone, Debug)]
pub struct MecaOptions {
    /// The control port's address (port 0: any; 10000 on a robot).
    pub control: SocketAddr,
    /// The monitoring port's address (port 0: any; 10001 on a robot).
    pub monitor: SocketAddr,
    /// The trajectory cycle (s).
    pub tick: f64,
    /// The joints at start (deg).
    pub start_deg: [f64; JOINTS],
    /// Each joint's acceleration at `SetJointAcc(100)` (deg/s²).
    pub accel_deg: [f64; JOINTS],
    /// How long `Home` takes before its `[2002]` (s).
    pub home_time: f64,
    /// Activated at start (as a robot is not after power-up).
    pub activated: bool,
    /// Homed at start (only if also `activated`).
    pub homed: bool,
    /// The firmware version in the banner, "major.minor.patch" (gates SetCtrlPortMonitoring ≥ 9.0,
    /// SetJointVelLimit ≥ 9.3, ConnectionWatchdog ≥ 10.1, GetRtTargetJointPos ≥ 8.4).
    pub version: String,
    /// SCHED_FIFO priority (1–99) for the trajectory thread, if permitted (refused: it runs as it is).
    pub rt_priority: Option<i32>,
}

impl Default for MecaOptions {
    /// Any free ports on 127.0.0.1, 1 ms tick, joints at 0, accelerations 5 × the R3's speeds per
    /// second (0.2 s to full speed at 100 %), homing 0.1 s, deactivated and not homed, FW 9.3.0.
    fn default() -> MecaOptions {
        let any = SocketAddr::from(([127, 0, 0, 1], 0));
        MecaOptions {
            control: any,
            monitor: any,
            tick: 0.001,
            start_deg: [0.0; JOINTS],
            accel_deg: R3_SPEED_DEG.map(|v| 5.0 * v),
            home_time: 0.1,
            activated: false,
            homed: false,
            version: "9.3.0".into(),
            rt_priority: None,
        }
    }
}

/// What a run saw.
#[derive(Debug, Default)]
pub struct MecaReport {
    /// One row per monitoring interval while a control client was connected and the robot
    /// activated and homed: `axes` the joints (deg), `cycles` the rows, `in_time` the intervals in
    /// which a MoveJointsVel was accepted, `missing` those without one, `fresh` per row whether one
    /// was, `garbage` as below; `late` 0 and `round_trip` empty (a TCP stream has no answer to
    /// match).
    pub report: FakeReport,
    /// Every command other than MoveJointsVel with a known name, in order (its name as sent,
    /// without a `-` prefix or arguments), whatever it was answered.
    pub commands: Vec<String>,
    /// MoveJointsVel commands accepted (count; those while paused are accepted and ignored).
    pub move_joints_vel: u64,
    /// Every error code sent (1xxx replies; 3001, 3003, 3086 and the injected 3xxx), in order.
    pub errors: Vec<u32>,
    /// Velocity timeouts that stopped a non-zero MoveJointsVel (count).
    pub timeouts: u64,
    /// Times a joint reached its limit and stopped there (count).
    pub limit_stops: u64,
    /// Frames that were no command: answered 1001, 1002, 1003 or 3003 (count).
    pub garbage: u64,
}

/// A client's socket and what it has not yet taken: writes never block the robot (a client that
/// leaves more than [`OUT_LIMIT`] unread is dropped). Without a socket (virtual time) the bytes
/// wait in `pending` for the caller to take.
struct Out {
    stream: Option<TcpStream>,
    pending: Vec<u8>,
    dead: bool,
}

impl Out {
    fn new(stream: TcpStream) -> Out {
        Out { stream: Some(stream), pending: Vec::new(), dead: false }
    }

    /// A client in virtual time: what is sent to it waits in `pending`.
    fn sink() -> Out {
        Out { stream: None, pending: Vec::new(), dead: false }
    }

    fn shutdown(&self) {
        if let Some(s) = &self.stream {
            let _ = s.shutdown(Shutdown::Both);
        }
    }

    fn push(&mut self, bytes: &[u8]) {
        if !self.dead {
            self.pending.extend_from_slice(bytes);
            self.flush();
        }
    }

    fn flush(&mut self) {
        let Some(stream) = &self.stream else { return };
        if !self.dead && !crate::fake::send_pending(stream.as_raw_fd(), &mut self.pending, OUT_LIMIT) {
            self.dead = true;
        }
        if self.dead {
            self.pending = Vec::new();
            self.shutdown();
        }
    }
}

struct Shared {
    state: Mutex<State>,
    stop: AtomicBool,
    readers: Mutex<Vec<JoinHandle<()>>>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The fake Meca500 R3, running until [`FakeMeca::stop`] (or dropped).
///
/// Where `docs/protocols/meca500.md` leaves it open, the fake's choices: replies are the codes of
/// §2 with short English texts (`[2096][1]`/`[2096][0]`, `[2177][1]`/`[2177][0]`); no reply to a
/// successful SetMonitoringInterval or motion-queue command; a command's name is checked first
/// (1001), then its parentheses and commas (1002), its arguments' count and range (1003, also a
/// non-numeric or non-finite one; exponents are read), then the robot's state (1005, 1006, 1011);
/// a frame longer than [`MAX_COMMAND_LEN`] bytes gets `[3003]` and is skipped to its terminator;
/// ActivateRobot/Home when already done answer 2000/2002 on FW ≥ 9 (2001/2003 before); ActivateRobot
/// restores SetVelTimeout 0.05 s, SetJointAcc 80 %, SetJointVelLimit 100 % and resumes (pm = 0);
/// DeactivateRobot stops the arm at once (brakes) and loses the homing; EOB events on, EOM events
/// off at start; MoveJointsVel beyond the speeds is scaled down as a whole (its direction kept);
/// MoveJointsVel while paused (not in error) is accepted and ignored (not queued for ResumeMotion);
/// a joint stops dead at its limit (no braking ahead of it), J6's limit being ±100 turns; Home,
/// Pause/Resume/ClearMotion need the motors activated (1005), Home and ResumeMotion no error (1011);
/// a dropped control connection pauses the robot (pm = 1), which decelerates to rest; ConnectionWatchdog
/// (FW ≥ 10.1) is refreshed only by itself, takes any t ≥ 0, and on expiry sends `[3086]`, pauses
/// and closes the control connection; the monitoring stream's `t` is the trajectory cycle's
/// deadline, so cycles are exactly `SetMonitoringInterval` apart (rounded up to ticks).
pub struct FakeMeca {
    shared: Arc<Shared>,
    control_addr: SocketAddr,
    monitor_addr: SocketAddr,
    threads: Vec<JoinHandle<()>>,
}

/// What a test sees of the running fake; clones share it.
#[derive(Clone)]
pub struct MecaWatch {
    shared: Arc<Shared>,
}

impl MecaWatch {
    /// The status as `[2007]` gives it: activated, homed, simulation, error, paused, end of block,
    /// end of movement.
    pub fn status(&self) -> [bool; 7] {
        self.shared.lock().status()
    }
    /// The joints (deg).
    pub fn joints_deg(&self) -> [f64; JOINTS] {
        self.shared.lock().q
    }
    /// The joints' velocities (deg/s).
    pub fn velocity_deg(&self) -> [f64; JOINTS] {
        self.shared.lock().v
    }
    /// A motion error `code` (e.g. 3005) as the robot raises one: es = 1, pm = 1, the arm
    /// decelerates, `[code][text]` on the control port and a `[2007]` everywhere.
    pub fn inject_error(&self, code: u32) {
        let text = match code {
            3005 => "Motion error.",
            3029 => "Torque limit exceeded.",
            3041 => "Collision detected.",
            3049 => "Work zone error.",
            _ => "Error.",
        };
        self.shared.lock().raise(code, text);
    }
    /// Velocity timeouts that stopped a non-zero MoveJointsVel so far (count).
    pub fn timeouts(&self) -> u64 {
        self.shared.lock().report.timeouts
    }
    /// Whether a control client is connected.
    pub fn connected(&self) -> bool {
        self.shared.lock().control.is_some()
    }
}

impl FakeMeca {
    /// Binds both ports and starts the robot's threads; returns at once.
    pub fn spawn(opts: MecaOptions) -> std::io::Result<FakeMeca> {
        let control = TcpListener::bind(opts.control)?;
        let monitor = TcpListener::bind(opts.monitor)?;
        control.set_nonblocking(true)?;
        monitor.set_nonblocking(true)?;
        let (control_addr, monitor_addr) = (control.local_addr()?, monitor.local_addr()?);
        let t0 = monotonic_ns();
        let shared =
            Arc::new(Shared { state: Mutex::new(State::new(&opts, t0)), stop: AtomicBool::new(false), readers: Mutex::new(Vec::new()) });
        let banner = msg(3000, &format!("Connected to Meca500 R3 v{}", opts.version));
        let mut threads = Vec::new();
        let s = shared.clone();
        let tick_ns = ((if opts.tick.is_finite() && opts.tick > 0.0 { opts.tick } else { 0.001 }) * 1e9).round() as u64;
        let priority = opts.rt_priority;
        threads.push(std::thread::Builder::new().name("fake-meca-tick".into()).spawn(move || {
            real_time(priority);
            every(t0, tick_ns, || s.stop.load(Ordering::Relaxed), |deadline| s.lock().step(deadline));
        })?);
        let s = shared.clone();
        let b = banner.clone();
        threads.push(std::thread::Builder::new().name("fake-meca-control".into()).spawn(move || accept_control(&s, &control, &b))?);
        let s = shared.clone();
        threads.push(std::thread::Builder::new().name("fake-meca-monitor".into()).spawn(move || {
            while !s.stop.load(Ordering::Relaxed) {
                match monitor.accept() {
                    Ok((stream, _)) => {
                        if stream.set_nonblocking(false).is_err() {
                            continue;
                        }
                        let _ = stream.set_nodelay(true);
                        let mut st = s.lock();
                        let mut out = Out::new(stream);
                        out.push(&banner);
                        out.push(&msg(2007, &st.status_payload()));
                        st.monitors.push(out);
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        })?);
        Ok(FakeMeca { shared, control_addr, monitor_addr, threads })
    }

    /// The control port's address.
    pub fn control_addr(&self) -> SocketAddr {
        self.control_addr
    }
    /// The monitoring port's address.
    pub fn monitor_addr(&self) -> SocketAddr {
        self.monitor_addr
    }
    /// A handle on the running robot.
    pub fn watch(&self) -> MecaWatch {
        MecaWatch { shared: self.shared.clone() }
    }

    /// Stops the robot, closes every connection and reports the run.
    pub fn stop(mut self) -> MecaReport {
        self.halt();
        let mut st = self.shared.lock();
        if let Some(c) = st.control.take() {
            c.shutdown();
        }
        for m in st.monitors.drain(..) {
            m.shutdown();
        }
        let mut report = std::mem::take(&mut st.report);
        report.report.garbage = report.garbage;
        report
    }

    fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        let readers = std::mem::take(&mut *self.shared.readers.lock().unwrap_or_else(|e| e.into_inner()));
        for t in readers {
            let _ = t.join();
        }
    }
}

impl Drop for FakeMeca {
    fn drop(&mut self) {
        self.halt();
    }
}

fn accept_control(s: &Arc<Shared>, listener: &TcpListener, banner: &[u8]) {
    while !s.stop.load(Ordering::Relaxed) {
        let stream = match listener.accept() {
            Ok((stream, _)) => stream,
            Err(_) => {
                std::thread::sleep(Duration::from_millis(2));
                continue;
            }
        };
        if stream.set_nonblocking(false).is_err() {
            continue;
        }
        let _ = stream.set_nodelay(true);
        let mut st = s.lock();
        if st.control.is_some() {
            st.report.errors.push(3001);
            drop(st);
            refuse(stream);
            continue;
        }
        let Ok(reader) = stream.try_clone() else { continue };
        st.control_gen += 1;
        let generation = st.control_gen;
        st.control = Some(Out::new(stream));
        st.ctrl_monitoring = false;
        st.send_control(banner);
        st.publish_status(false);
        drop(st);
        let s2 = s.clone();
        if let Ok(handle) = std::thread::Builder::new().name("fake-meca-reader".into()).spawn(move || read_control(&s2, reader, generation))
        {
            s.readers.lock().unwrap_or_else(|e| e.into_inner()).push(handle);
        }
    }
}

/// `[3001]` to a second control client, then closed (its bytes drained first, so that the close
/// is a FIN, not a reset that could lose the message).
fn refuse(mut stream: TcpStream) {
    let _ = std::thread::Builder::new().name("fake-meca-refuse".into()).spawn(move || {
        let _ = stream.write_all(&msg(3001, "Another user is already connected, closing connection."));
        let _ = stream.shutdown(Shutdown::Write);
        let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
        let mut buf = [0u8; 1024];
        for _ in 0..10 {
            match stream.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(_) => {}
            }
        }
    });
}

fn read_control(s: &Shared, mut stream: TcpStream, generation: u64) {
    let _ = stream.set_read_timeout(Some(Duration::from_millis(20)));
    let mut frame = Vec::with_capacity(MAX_COMMAND_LEN);
    let mut skipping = false;
    let mut buf = [0u8; 4096];
    while !s.stop.load(Ordering::Relaxed) {
        let n = match stream.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e)
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted) =>
            {
                continue;
            }
            Err(_) => break,
        };
        let now = monotonic_ns();
        let mut st = s.lock();
        if st.control_gen != generation {
            break;
        }
        for &b in &buf[..n] {
            if b == 0 || b == b'\n' {
                if !skipping {
                    st.frame(&frame, now);
                }
                skipping = false;
                frame.clear();
            } else if !skipping {
                frame.push(b);
                if frame.len() > MAX_COMMAND_LEN {
                    st.report.errors.push(3003);
                    st.report.garbage += 1;
                    st.send_control(&msg(3003, "Command too long."));
                    skipping = true;
                    frame.clear();
                }
            }
        }
    }
    let mut st = s.lock();
    if st.control_gen == generation && st.control.is_some() {
        if let Some(c) = st.control.as_ref() {
            c.shutdown();
        }
        st.disconnected();
    }
}
