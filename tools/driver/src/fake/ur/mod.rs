//! A Universal Robots e-Series controller (a UR5e) as its network interfaces show it, written from
//! `docs/protocols/ur.md` only (§1 RTDE with §1.9 "Fake RTDE server", §2 the reverse interface with
//! §2.7 "Fake controller side", §3.1 the primary interface), not from the driver's code, so that
//! the driver is checked against an independent reading of the same description. RTDE packages
//! and the reverse interface's 8 × int32 messages are encoded and decoded here by hand.
//!
//! Three network sides share one controller state:
//! - RTDE (port 30004 on a robot): `u16 size | u8 type | payload` packages, big-endian, split or
//!   merged across reads, any number of clients. `V` accepts protocol version 2 only, `v` gives
//!   [`UrOptions::version`], `O` sets up the output recipe (≤ 500 Hz, ≤ 125 Hz on a version < 5),
//!   `I` an input recipe, `S` starts the `U` stream (sent by the controller step, the newest state,
//!   never a backlog), `P` pauses it; a client's `U` is decoded with its input recipe and applied
//!   (standard analog outputs, the speed slider, digital outputs, input registers).
//! - The primary interface (30001/30002): a connection's text up to its close or 100 ms of silence
//!   is one script; a `def` program in it replaces the running one: it connects back to the first
//!   `socket_open("HOST", PORT` of its text and runs the §2.7 loop (8 × i32 messages, field 0 the
//!   next read's timeout in ms, mode 1 SERVOJ, mode −2 a clean stop, a timeout or EOF stops the arm
//!   at 4 rad/s² and ends the program).
//! - The controller step, every [`UrOptions::step`] on absolute deadlines: servoj moves each joint
//!   towards its target at most `speed_limit × step` per step; a stop decelerates every joint at
//!   4 rad/s² (`stopj(4.0)`).
//!
//! Choices where the description is open are listed on [`FakeUr`].

use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

mod controller;
mod program;
mod rtde;
mod rtde_server;
pub mod virtual_time;

#[cfg(test)]
mod tests;

use super::{FakeReport, every, real_time};
use controller::State;
use program::read_scripts;
use rtde::{Conn, Outputs, Session};
use rtde_server::rtde_session;

/// The arm's joints.
pub const JOINTS: usize = 6;
/// The only RTDE protocol version the fake accepts (§1.3).
pub const RTDE_PROTOCOL_VERSION: u16 = 2;
/// The highest RTDE output frequency of an e-Series controller (Hz, §1.3).
pub const URE_MAX_FREQUENCY: f64 = 500.0;
/// The highest RTDE output frequency of a CB3 controller, major version < 5 (Hz, §1.3).
pub const CB3_MAX_FREQUENCY: f64 = 125.0;
/// The longest list of names in `O` or `I` (bytes, §1.3).
pub const MAX_NAMES_LEN: usize = 2048;
/// Fields 1..6 of a reverse-interface message are the values × this (§2.2).
pub const MULT_JOINTSTATE: f64 = 1_000_000.0;
/// The deceleration of `stopj` when the program stops (rad/s², §2.4).
pub const STOPJ_ACCELERATION: f64 = 4.0;
/// A servoj setpoint stepping a joint faster than this from the last command is ignored (rad/s, §2.4).
pub const JOINT_IGNORE_SPEED: f64 = 20.0;
/// Reverse-interface control modes (§2.3).
pub const MODE_STOPPED: i32 = -2;
/// The script's mode before its first message.
pub const MODE_UNINITIALIZED: i32 = -1;
/// No motion: the servo stops.
pub const MODE_IDLE: i32 = 0;
/// Joint positions streamed to servoj.
pub const MODE_SERVOJ: i32 = 1;
/// `robot_mode` RUNNING (§1.8).
pub const ROBOT_MODE_RUNNING: i32 = 7;
/// `safety_mode` NORMAL (§1.8).
pub const SAFETY_NORMAL: i32 = 1;
/// `safety_mode` PROTECTIVE_STOP (§1.8).
pub const SAFETY_PROTECTIVE_STOP: i32 = 3;
/// `runtime_state` STOPPED (§1.8).
pub const RUNTIME_STOPPED: u32 = 1;
/// `runtime_state` PLAYING (§1.8).
pub const RUNTIME_PLAYING: u32 = 2;

/// The longest a blocking wait goes without looking at the stop flag (ns).
const SLICE_NS: u64 = 20_000_000;

/// How the fake controller starts.
#[derive(Clone, Debug)]
pub struct UrOptions {
    /// RTDE's address (port 0: any; 30004 on a robot).
    pub rtde: SocketAddr,
    /// The primary (script) port's address (port 0: any; 30001 or 30002 on a robot).
    pub primary: SocketAddr,
    /// The joints at start (rad).
    pub start_q: [f64; JOINTS],
    /// Each joint's speed limit: servoj moves a joint at most this fast (rad/s; π on a UR5e).
    pub speed_limit: [f64; JOINTS],
    /// The URControl version `v` answers: major, minor, bugfix, build (major < 5 is a CB3: RTDE
    /// at most 125 Hz).
    pub version: [u32; 4],
    /// The controller step (s; 0.002 on an e-Series).
    pub step: f64,
    /// SCHED_FIFO priority (1–99) for the controller step thread, if permitted (refused: it runs as
    /// it is).
    pub rt_priority: Option<i32>,
}

impl Default for UrOptions {
    /// Any free ports on 127.0.0.1, the joints at [0, −π/2, 0, −π/2, 0, 0] rad, π rad/s on every
    /// joint, URControl 5.15.0.0, a 2 ms step.
    fn default() -> UrOptions {
        let any = SocketAddr::from(([127, 0, 0, 1], 0));
        let h = std::f64::consts::FRAC_PI_2;
        UrOptions {
            rtde: any,
            primary: any,
            start_q: [0.0, -h, 0.0, -h, 0.0, 0.0],
            speed_limit: [std::f64::consts::PI; JOINTS],
            version: [5, 15, 0, 0],
            step: 0.002,
            rt_priority: None,
        }
    }
}

/// What a run saw.
#[derive(Debug, Default)]
pub struct UrReport {
    /// One row per controller step while a program runs in SERVOJ mode (from its first servoj
    /// message to its end): `axes` actual_q (deg), `cycles` the rows (steps), `in_time` the steps
    /// that had a fresh setpoint from the reverse interface since the previous step, `missing` those
    /// without one (the servo held its last target), `fresh` per row, `garbage` as below, `gave_up`
    /// whether a program ended on a read timeout; `late` 0 and `round_trip` empty (a TCP stream has
    /// no answer to match).
    pub report: FakeReport,
    /// Every script received on the primary port, in order (text, lossy UTF-8).
    pub scripts: Vec<String>,
    /// Reverse-interface reads that timed out or met the end of the stream (count): each stopped
    /// the arm and ended the program.
    pub timeouts: u64,
    /// Mode −2 (STOPPED) messages that ended the program (count).
    pub clean_stops: u64,
    /// Servoj setpoints ignored because a joint stepped faster than 20 rad/s from the last command
    /// (count, §2.4).
    pub violations: u64,
    /// RTDE input packages that set at least one standard analog output (count).
    pub analog_writes: u64,
    /// RTDE clients whose `S` was accepted (count).
    pub rtde_sessions: u64,
    /// Malformed packages or messages (count): RTDE packages of an unknown type, a wrong length, a
    /// bad size, an unknown recipe id, a value out of its range, a `U` before `S`; reverse messages
    /// with an unknown mode or a negative timeout; `def` scripts without a closing `end` or final
    /// newline.
    pub garbage: u64,
}

struct Shared {
    state: Mutex<State>,
    stop: AtomicBool,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn spawn(self: &Arc<Self>, name: &str, f: impl FnOnce() + Send + 'static) {
        if let Ok(h) = std::thread::Builder::new().name(name.into()).spawn(f) {
            self.threads.lock().unwrap_or_else(|e| e.into_inner()).push(h);
        }
    }
}

/// Whether `fd` has bytes (or its end, or an error) within `timeout_ns` (ppoll on a
/// high-resolution timer: a socket's receive timeout counts in scheduler ticks).
fn readable(fd: RawFd, timeout_ns: u64) -> bool {
    let mut p = libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
    let ts = libc::timespec { tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t, tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long };
    // SAFETY: one valid pollfd, a valid timespec, no signal mask.
    let n = unsafe { libc::ppoll(&mut p, 1, &ts, std::ptr::null()) };
    n > 0 && p.revents & (libc::POLLIN | libc::POLLHUP | libc::POLLERR) != 0
}

/// Whether the peer of `stream` has closed it.
fn peer_gone(stream: &TcpStream) -> bool {
    let mut p = libc::pollfd { fd: stream.as_raw_fd(), events: libc::POLLRDHUP, revents: 0 };
    // SAFETY: one valid pollfd, no wait.
    let n = unsafe { libc::poll(&mut p, 1, 0) };
    n > 0 && p.revents & (libc::POLLRDHUP | libc::POLLHUP | libc::POLLERR) != 0
}

/// The fake UR controller, running until [`FakeUr::stop`] (or dropped).
///
/// Where `docs/protocols/ur.md` leaves it open, the fake's choices:
/// - RTDE: the v2 package formats throughout (a `V` asking for another version is answered 0 and
///   changes nothing); the output recipe id is 1 and input recipe ids count from 1 per session; an
///   invalid recipe (a `NOT_FOUND` or `IN_USE` in its types) is answered with id 0 and the types,
///   and is not kept; a frequency outside (0, 500] Hz ((0, 125] for a version < 5) is answered with
///   an `M` ERROR text and then `O` with id 0 and no types, and the output recipe is invalid;
///   `O`/`I` while started are refused the same way (the old recipe kept); `S` is accepted (1) with
///   a valid output recipe, or with none but an input recipe, and is followed once per session by
///   an INFO `M`; the `U` packages go out on controller steps, at the requested rate on average
///   (none while the client has not taken the previous one: never a backlog), the first on the step
///   after `S`; a client's `U` before `S`, with an unknown recipe id or of the wrong length is
///   ignored and counted as garbage; an analog ratio outside [0, 1] (or a speed fraction) is
///   ignored and counted as garbage; a masked analog output is set from whichever of its type bit
///   and ratio the recipe holds; an input owned by a still-connected session is `IN_USE`;
///   `safety_status` repeats `safety_mode`; `target_qd` is the commanded velocity, which equals
///   `actual_qd` here; a package whose size is below 3 ends the connection (its framing is lost).
/// - Primary port: nothing is sent to the client; a connection may carry several scripts, each
///   ending at 100 ms of silence or the close; a `def` program must end with a newline and hold a
///   line `end` after its `def`, else it is garbage and not run; the reverse host and port may be
///   literals or names assigned literals earlier in the text; a program without `socket_open` or
///   received during a protective stop is stored and not run; the new program starts once the old
///   one has ended (its socket closed, the arm decelerating).
/// - Reverse interface: a read's timeout runs from the end of the previous message and ends at the
///   first controller step at or after it (a cyclic controller checks each step); a message with a
///   negative timeout or a mode other than −2, 0 and 1 is garbage and ignored (its timeout too);
///   mode 0 (IDLE) stops the servo (the arm decelerates) with the program still running; the first
///   SERVOJ message starts the servo from the actual joints and the 20 rad/s check is against the
///   last accepted command; without a fresh setpoint the servo holds its last target (no
///   extrapolation); a failed connection (5 attempts 0.2 s apart) ends the program.
/// - Motion: servoj is a per-joint speed limit (`speed_limit`, no acceleration limit, no lookahead
///   or gain: those are recorded only, see [`UrWatch::servo_args`]); `speed_scaling` and the speed
///   slider are reported only and do not slow the arm; a stop (timeout, mode −2, a new program, a
///   protective stop) decelerates each joint at 4 rad/s².
pub struct FakeUr {
    shared: Arc<Shared>,
    rtde_addr: SocketAddr,
    primary_addr: SocketAddr,
    main: Vec<JoinHandle<()>>,
}

/// What a test sees of the running controller; clones share it.
#[derive(Clone)]
pub struct UrWatch {
    shared: Arc<Shared>,
}

impl UrWatch {
    /// `robot_mode` (7 RUNNING).
    pub fn robot_mode(&self) -> i32 {
        self.shared.lock().robot_mode
    }
    /// `safety_mode` (1 NORMAL, 3 PROTECTIVE_STOP).
    pub fn safety_mode(&self) -> i32 {
        self.shared.lock().safety_mode
    }
    /// `runtime_state` (1 STOPPED, 2 PLAYING).
    pub fn runtime_state(&self) -> u32 {
        self.shared.lock().runtime_state
    }
    /// Whether a program runs.
    pub fn program_running(&self) -> bool {
        self.shared.lock().program_running
    }
    /// The `speed_scaling` output from now on (0..1; reported only, the arm is not slowed).
    pub fn set_speed_scaling(&self, s: f64) {
        self.shared.lock().speed_scaling = if s.is_finite() { s.clamp(0.0, 1.0) } else { 0.0 };
    }
    /// A protective stop: `safety_mode` 3, the program ends (`runtime_state` STOPPED, its reverse
    /// socket closed), the arm decelerates to rest at 4 rad/s²; no program runs until
    /// [`UrWatch::unlock_protective_stop`].
    pub fn protective_stop(&self) {
        let mut st = self.shared.lock();
        st.safety_mode = SAFETY_PROTECTIVE_STOP;
        if st.program_running {
            st.end_program();
        }
        st.stop_arm();
    }
    /// Back to `safety_mode` 1 NORMAL after a protective stop.
    pub fn unlock_protective_stop(&self) {
        self.shared.lock().safety_mode = SAFETY_NORMAL;
    }
    /// Per standard analog output: its domain (0 current, 1 voltage) and its ratio of the range
    /// (0..1), as last set over RTDE inputs.
    pub fn analog_output(&self) -> [(u8, f64); 2] {
        self.shared.lock().analog
    }
    /// `target_speed_fraction`, the speed slider (0..1) as last set over RTDE inputs.
    pub fn speed_fraction(&self) -> f64 {
        self.shared.lock().speed_fraction
    }
    /// `actual_q` (rad).
    pub fn joints(&self) -> [f64; JOINTS] {
        self.shared.lock().q
    }
    /// `actual_qd` (rad/s).
    pub fn velocities(&self) -> [f64; JOINTS] {
        self.shared.lock().qd
    }
    /// The last program's `lookahead_time=` (s) and `gain=` values, if it had them (`None`: no
    /// program yet).
    pub fn servo_args(&self) -> Option<(Option<f64>, Option<f64>)> {
        self.shared.lock().servo_args
    }
}

impl FakeUr {
    /// Binds the RTDE and primary ports and starts the controller's threads; returns at once.
    pub fn spawn(opts: UrOptions) -> std::io::Result<FakeUr> {
        let step = if opts.step.is_finite() && opts.step > 0.0 { opts.step } else { 0.002 };
        let opts = UrOptions { step, ..opts };
        let rtde = TcpListener::bind(opts.rtde)?;
        let primary = TcpListener::bind(opts.primary)?;
        rtde.set_nonblocking(true)?;
        primary.set_nonblocking(true)?;
        let (rtde_addr, primary_addr) = (rtde.local_addr()?, primary.local_addr()?);
        let t0 = monotonic_ns();
        let shared =
            Arc::new(Shared { state: Mutex::new(State::new(&opts, t0)), stop: AtomicBool::new(false), threads: Mutex::new(Vec::new()) });
        let mut main = Vec::new();
        let s = shared.clone();
        let step_ns = (step * 1e9).round().max(1.0) as u64;
        let priority = opts.rt_priority;
        main.push(std::thread::Builder::new().name("fake-ur-step".into()).spawn(move || {
            real_time(priority);
            every(t0, step_ns, || s.stop.load(Ordering::Relaxed), |deadline| s.lock().step(deadline));
        })?);
        let s = shared.clone();
        main.push(std::thread::Builder::new().name("fake-ur-rtde".into()).spawn(move || {
            while !s.stop.load(Ordering::Relaxed) {
                let Ok((stream, _)) = rtde.accept() else {
                    std::thread::sleep(Duration::from_millis(2));
                    continue;
                };
                if stream.set_nonblocking(false).is_err() {
                    continue;
                }
                let _ = stream.set_nodelay(true);
                let Ok(reader) = stream.try_clone() else { continue };
                let mut st = s.lock();
                let id = st.next_session;
                st.next_session += 1;
                st.sessions.push(Session {
                    id,
                    conn: Conn { stream, pending: Vec::new(), dead: false },
                    outputs: Outputs::None,
                    frequency: 0.0,
                    inputs: Vec::new(),
                    next_input_id: 0,
                    started: false,
                    told: false,
                    phase: 0.0,
                });
                drop(st);
                let s2 = s.clone();
                s.spawn("fake-ur-rtde-session", move || rtde_session(&s2, reader, id));
            }
        })?);
        let s = shared.clone();
        main.push(std::thread::Builder::new().name("fake-ur-primary".into()).spawn(move || {
            while !s.stop.load(Ordering::Relaxed) {
                let Ok((stream, _)) = primary.accept() else {
                    std::thread::sleep(Duration::from_millis(2));
                    continue;
                };
                if stream.set_nonblocking(false).is_err() {
                    continue;
                }
                let s2 = s.clone();
                s.spawn("fake-ur-script", move || read_scripts(&s2, stream));
            }
        })?);
        Ok(FakeUr { shared, rtde_addr, primary_addr, main })
    }

    /// RTDE's address.
    pub fn rtde_addr(&self) -> SocketAddr {
        self.rtde_addr
    }
    /// The primary (script) port's address.
    pub fn primary_addr(&self) -> SocketAddr {
        self.primary_addr
    }
    /// A handle on the running controller.
    pub fn watch(&self) -> UrWatch {
        UrWatch { shared: self.shared.clone() }
    }

    /// Stops the controller, closes every connection and reports the run.
    pub fn stop(mut self) -> UrReport {
        self.halt();
        let mut st = self.shared.lock();
        if let Some(r) = st.reverse.take() {
            let _ = r.shutdown(Shutdown::Both);
        }
        for s in st.sessions.drain(..) {
            let _ = s.conn.stream.shutdown(Shutdown::Both);
        }
        let mut report = std::mem::take(&mut st.report);
        report.report.garbage = report.garbage;
        report.report.gave_up = report.timeouts > 0;
        report
    }

    fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.main.drain(..) {
            let _ = t.join();
        }
        loop {
            let threads = std::mem::take(&mut *self.shared.threads.lock().unwrap_or_else(|e| e.into_inner()));
            if threads.is_empty() {
                break;
            }
            for t in threads {
                let _ = t.join();
            }
        }
    }
}

impl Drop for FakeUr {
    fn drop(&mut self) {
        self.halt();
    }
}
