//! A fake DENSO RC8 robot controller speaking b-CAP over TCP in slave mode, written from the public
//! description `docs/protocols/bcap.md` only (not from the driver's code): the packets (§1.2) and
//! the VARIANTs (§2) are encoded and decoded here by hand, little-endian, so the driver's codec is
//! checked against an independent one.
//!
//! One client at a time; a second connection gets `E_MAX_CONNECT` (0x8000090B) to its first request
//! and is closed. Framing and resynchronisation follow §1.3: bytes before an SOH are skipped
//! (counted as garbage), an SOH whose length is below 16 (or above 16 MiB) is dropped and the
//! stream rescanned, a packet without its EOT or whose arguments do not fill its length exactly is
//! answered `E_INVALIDPACKET` with its serial (and counted); a packet left incomplete for 200 ms
//! loses its SOH and the stream is rescanned, so garbage never stalls the session. Replies echo the
//! serial, reserved 0, the HRESULT in the function-ID slot; argc is 1 (the return value) on success
//! of a function that returns one (Controller_Connect, _GetRobot, _GetRobotNames, _Execute,
//! Robot_Execute; VT_EMPTY when a command has nothing to return) and 0 on every failure (as the
//! doc's worked error reply). Requests are handled one at a time: one sent while a reply is held
//! (Motor on, a mode-2 slvMove) waits in the socket.
//!
//! The controller ticks on its own thread every `cycle` on absolute deadlines (woken a whole cycle
//! late, the fake skips the missed ticks rather than run them in a burst that would drain the
//! buffer and blame the client for its own stall; `rt_priority` makes it and the session thread
//! SCHED_FIFO where permitted). In slave mode it pops one buffered command (modes 0x0xx and 0x2xx:
//! a FIFO of 3; 0x1xx: a buffer of 1, the newest wins) into the drives' target, the drives follow
//! with a first-order `lag`, and one [`FakeReport`] row is recorded per tick from the first command
//! taken on (ticks in slave mode before it are counted by [`BcapWatch::slave_ticks`] only). A
//! command's first difference over the previous command / cycle above `speed_limit_deg` latches
//! 0x8420405n, its second difference / cycle² above `accel_limit_deg` latches 0x8420404n (n the
//! joint, 1-based; speed checked on all joints first; the robot is at rest when slave mode starts);
//! a tick that finds the buffer empty after the first command latches 0x84201482 (in every mode,
//! 0x1xx included). A latched error stops the robot (target := actual), leaves slave mode and, for
//! a level-4 error (0x84xxxxxx, the doc's recovery being "ClearError, Motor on, slvChangeMode"),
//! switches the motor off; until `ClearError`, Motor on and slvChangeMode ≠ 0 answer 0x81501025 and
//! slvMove answers 0x83500121. A mode-2 slvMove whose reply is held when an error latches is
//! answered with that error. slvChangeMode 0 drops the commands still buffered; the drives settle
//! on the last one taken.
//!
//! Mode 2 (0x2xx): a slvMove that fills the third slot is answered when a tick frees one (so the
//! client runs at the cycle, 2–3 commands ahead); mode 0: S_BUF_FULL when the push fills the third
//! slot, E_BUF_FULL (not latched, the command dropped) when it was full already; mode 1: the
//! command overwrites the pending one, S_OK at once. The reply value is the actual joints of that
//! moment per slvRecvFormat (8 values, degrees, unused joints 0).
//!
//! Choices the doc leaves open, made here: only J-type slave modes (0x002, 0x102, 0x202) are
//! accepted (no kinematics: P and T modes answer `E_INVALIDARG`); slvMove takes 8 doubles (or 9,
//! the 9th ignored, as DENSO's ROS driver sends); slvRecvFormat takes J (low nibble 2) with the
//! timestamp (0x10, ms or µs per tsUnit, since the fake started, wrapping i32), hand IO (0x20, 0),
//! motor current (0x40, zeros) and mini IO (0x100, 0) flags; slvSendFormat takes 0 or the IO flags
//! (the pose then the first element of a VARIANT array, the IO ignored). slvChangeMode ≠ 0 without
//! the arm answers `E_ACCESSDENIED`; a mode change while in slave mode restarts the stream.
//! TakeArm, GiveArm, the formats, ClearError, GetErrorDescription, Robot_Release and
//! Controller_Disconnect answer 0x83501032 in slave mode; Motor off in slave mode stops the robot
//! and leaves slave mode (no error, but the release is then not clean). Service_Start is not
//! required before the other calls. A provider other than "CaoProv.DENSO.VRC" answers
//! `E_CAO_OBJECT_NOT_FOUND` (0x80000204); any robot name is accepted. `WDT` below 80 ms is taken as
//! 80 (0: none); a Motor on longer than `InvokeTimeout` answers `E_TIMEOUT` at the timeout (the
//! motor still comes on when its time is up). With noWait (`[1, 1]`) Motor on answers at once and
//! the motor comes on `motor_on_time` later. Motor on does not need the arm (DENSO's ROS driver
//! switches the servo on before TakeArm). Handles are small integers, sent as VT_I4, taken as VT_I4
//! or VT_UI4; Controller_GetRobotNames answers `["Arm"]`; CurJnt answers R8×8 (degrees), HighCurJntEx
//! the time stamp (ms) then R8×8. Other function IDs answer `E_NOTIMPL`.
//!
//! A release is clean ([`BcapWatch::released`]) when the client's last successful state-changing
//! calls were slvChangeMode 0 (if the session entered slave mode), Motor off and GiveArm (either
//! order: DENSO's samples and ROS differ), Robot_Release, Controller_Disconnect, Service_Stop, and
//! the client then closed the connection.
//!
//! A connection dropped while in slave mode: the arm authority goes with the session; if no command
//! was taken yet the robot stops at once (slave mode 0, nothing latched); otherwise the controller
//! runs out the commands already buffered and the next tick finds the buffer empty and latches
//! 0x84201482, exactly as for a late client.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

mod calls;
mod controller;
pub mod virtual_time;
mod wire;

#[cfg(test)]
mod tests;

use super::{FakeReport, real_time, sleep_until};
use calls::session;
use controller::Ctrl;
pub use wire::{EOT, MAX_JOINTS, MAX_PACKET, MIN_PACKET, Packet, SOH, Variant, func, hr, vt};

/// How the fake controller runs.
#[derive(Clone, Debug)]
pub struct BcapOptions {
    /// Where it listens (127.0.0.1:0 in tests: any port; a real controller uses 5007).
    pub bind: SocketAddr,
    /// The controller cycle (s): 0.008 on an RC8.
    pub cycle: f64,
    /// The joints at the start (degrees; its length is the robot's joint count, at most 8).
    pub start_deg: Vec<f64>,
    /// Per joint (deg/s): a command's first difference / cycle above it latches 0x8420405n.
    pub speed_limit_deg: Vec<f64>,
    /// Per joint (deg/s²): a command's second difference / cycle² above it latches 0x8420404n.
    pub accel_limit_deg: Vec<f64>,
    /// First-order lag of the drives (s; 0: the actual joints are the commanded ones).
    pub lag: f64,
    /// SCHED_FIFO priority for the tick thread and the session's (its replies), if permitted (without the privilege they run as they are).
    pub rt_priority: Option<i32>,
    /// How long a "Motor" on call takes (s): the reply is held (S_EXECUTING every WDT ms if Service_Start set WDT).
    pub motor_on_time: f64,
}

impl Default for BcapOptions {
    /// A VP6242-like arm: 6 joints at 0°, 8 ms, limits generous (360 deg/s, 5000 deg/s²; not a
    /// data sheet), no lag, motor on in 0.2 s, any port on 127.0.0.1.
    fn default() -> BcapOptions {
        BcapOptions {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            cycle: 0.008,
            start_deg: vec![0.0; 6],
            speed_limit_deg: vec![360.0; 6],
            accel_limit_deg: vec![5000.0; 6],
            lag: 0.0,
            rt_priority: None,
            motor_on_time: 0.2,
        }
    }
}

struct Inner {
    ctrl: Mutex<Ctrl>,
    cv: Condvar,
    stop: AtomicBool,
    opts: BcapOptions,
    epoch_ns: u64,
}

impl Inner {
    fn lock(&self) -> MutexGuard<'_, Ctrl> {
        self.ctrl.lock().unwrap_or_else(|e| e.into_inner())
    }
    fn stopping(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }
    /// The controller's time stamp (ms or µs since the fake started, wrapping).
    fn stamp(&self, us: bool) -> i32 {
        let ns = monotonic_ns().saturating_sub(self.epoch_ns);
        (if us { ns / 1_000 } else { ns / 1_000_000 }) as u32 as i32
    }
}

/// The fake controller, running.
pub struct FakeBcap {
    inner: Arc<Inner>,
    addr: SocketAddr,
    threads: Vec<JoinHandle<()>>,
}

/// What a test sees of the fake while it runs: clones share it.
#[derive(Clone)]
pub struct BcapWatch(Arc<Inner>);

/// What a run saw.
#[derive(Debug)]
pub struct BcapReport {
    /// One row per controller tick in slave mode from the first command taken on: `cycles` such
    /// ticks, `in_time` those that took a command from the buffer, `missing` those that found it
    /// empty, `axes` the actual joints after the tick (degrees), `fresh` whether it took a command,
    /// `round_trip` slvMove request received → reply sent (ns), `garbage` bytes skipped before an
    /// SOH and malformed packets (count).
    pub report: FakeReport,
    /// The controller errors latched, in order (HRESULTs).
    pub errors: Vec<u32>,
    /// Every call in order ("Service_Start", "Robot_Execute(TakeArm)", ...), slvMove left out (counted in `slv_moves`).
    pub calls: Vec<String>,
    /// slvMove calls received (count).
    pub slv_moves: u64,
    /// E_BUF_FULL replies (count).
    pub buffer_full: u64,
    /// Whether the last session ended with a clean release (see [`BcapWatch::released`]).
    pub released: bool,
    /// Garbage bytes and malformed packets (count; also in `report.garbage`).
    pub garbage: u64,
}

impl FakeBcap {
    /// Binds, starts the tick and the accept threads, and returns at once.
    pub fn spawn(opts: BcapOptions) -> std::io::Result<FakeBcap> {
        let joints = opts.start_deg.len();
        if joints == 0 || joints > MAX_JOINTS || opts.cycle.is_nan() || opts.cycle <= 0.0 {
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "1..=8 joints and a positive cycle"));
        }
        let listener = TcpListener::bind(opts.bind)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let ctrl = Ctrl::new(&opts.start_deg);
        let inner =
            Arc::new(Inner { ctrl: Mutex::new(ctrl), cv: Condvar::new(), stop: AtomicBool::new(false), opts, epoch_ns: monotonic_ns() });
        let tick = {
            let inner = inner.clone();
            std::thread::Builder::new().name("fake-bcap-tick".into()).spawn(move || tick_loop(&inner))?
        };
        let accept = {
            let inner = inner.clone();
            std::thread::Builder::new().name("fake-bcap-accept".into()).spawn(move || accept_loop(&inner, listener))?
        };
        Ok(FakeBcap { inner, addr, threads: vec![tick, accept] })
    }

    /// Where it listens.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// A handle to watch it while it runs.
    pub fn watch(&self) -> BcapWatch {
        BcapWatch(self.inner.clone())
    }

    /// Stops the threads (an open session is closed), joins them and returns the report.
    pub fn stop(mut self) -> BcapReport {
        self.inner.stop.store(true, Ordering::Relaxed);
        self.inner.cv.notify_all();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        let mut c = self.inner.lock();
        let report = std::mem::take(&mut c.report);
        BcapReport {
            garbage: report.garbage,
            report,
            errors: c.errors.clone(),
            calls: std::mem::take(&mut c.calls),
            slv_moves: c.slv_moves,
            buffer_full: c.buffer_full,
            released: c.released,
        }
    }
}

impl Drop for FakeBcap {
    fn drop(&mut self) {
        self.inner.stop.store(true, Ordering::Relaxed);
        self.inner.cv.notify_all();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl BcapWatch {
    /// The slave mode (0: off; e.g. 0x202).
    pub fn slave_mode(&self) -> u32 {
        self.0.lock().slave_mode
    }
    /// Whether the motor is on.
    pub fn motor_on(&self) -> bool {
        let mut c = self.0.lock();
        c.resolve_motor(monotonic_ns());
        c.motor_on
    }
    /// Whether a client holds the arm (TakeArm).
    pub fn arm_taken(&self) -> bool {
        self.0.lock().arm_taken
    }
    /// The controller errors latched so far, in order (HRESULTs; ClearError does not remove them).
    pub fn errors(&self) -> Vec<u32> {
        self.0.lock().errors.clone()
    }
    /// Whether the last session ended cleanly (false while one is open): after slvChangeMode 0 (if
    /// it entered slave mode), Motor off and GiveArm (either order), Robot_Release,
    /// Controller_Disconnect and Service_Stop succeeded as its last calls, the client closed it.
    pub fn released(&self) -> bool {
        self.0.lock().released
    }
    /// Whether a client is connected.
    pub fn connected(&self) -> bool {
        self.0.lock().connected
    }
    /// Test hook: latches controller error `code` now, as a real fault would (the robot stops,
    /// slave mode 0, a level-4 code switches the motor off).
    pub fn inject_error(&self, code: u32) {
        self.0.lock().latch(code);
        self.0.cv.notify_all();
    }
    /// Controller ticks spent in slave mode (count), including those before the first command.
    pub fn slave_ticks(&self) -> u64 {
        self.0.lock().slave_ticks
    }
}

fn tick_loop(inner: &Inner) {
    real_time(inner.opts.rt_priority);
    let opts = &inner.opts;
    let period_ns = (opts.cycle * 1e9).round().max(1.0) as u64;
    let alpha = if opts.lag > 0.0 { 1.0 - (-opts.cycle / opts.lag).exp() } else { 1.0 };
    let t0 = monotonic_ns() + period_ns;
    let mut k = 0u64;
    while !inner.stopping() {
        let deadline = t0 + k * period_ns;
        sleep_until(deadline);
        // Woken a whole cycle late, the fake stalled (a controller does not): the missed ticks are
        // skipped, not run in a burst that would empty the buffer and blame the client.
        let now = monotonic_ns();
        if now >= deadline + period_ns {
            k = (now - t0) / period_ns;
        }
        k += 1;
        inner.lock().tick(alpha, opts);
        inner.cv.notify_all();
    }
}

fn accept_loop(inner: &Arc<Inner>, listener: TcpListener) {
    let mut sessions: Vec<JoinHandle<()>> = Vec::new();
    while !inner.stopping() {
        match listener.accept() {
            Ok((stream, _)) => {
                let _ = stream.set_nonblocking(false);
                let _ = stream.set_nodelay(true);
                let busy = {
                    let mut c = inner.lock();
                    let busy = c.connected;
                    if !busy {
                        c.connected = true;
                        c.released = false;
                    }
                    busy
                };
                let spawned = if busy {
                    std::thread::Builder::new().name("fake-bcap-refuse".into()).spawn(move || refuse(stream))
                } else {
                    let inner = inner.clone();
                    std::thread::Builder::new().name("fake-bcap-session".into()).spawn(move || session(&inner, stream))
                };
                match spawned {
                    Ok(t) => sessions.push(t),
                    Err(_) if !busy => inner.lock().connected = false,
                    Err(_) => {}
                }
            }
            Err(_) => std::thread::sleep(Duration::from_millis(2)),
        }
        sessions.retain(|t| !t.is_finished());
    }
    for t in sessions {
        let _ = t.join();
    }
}

/// A second client: its first request gets E_MAX_CONNECT, then the connection is closed.
fn refuse(mut stream: TcpStream) {
    let _ = stream.set_read_timeout(Some(Duration::from_millis(300)));
    let mut buf = [0u8; 64];
    if let Ok(n) = stream.read(&mut buf) {
        let serial = if n >= 7 && buf[0] == SOH { u16::from_le_bytes([buf[5], buf[6]]) } else { 0 };
        let _ = stream.write_all(&Packet { serial, reserved: 0, id: hr::E_MAX_CONNECT, args: vec![] }.encode());
    }
}
