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

use std::collections::BTreeSet;
use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

pub mod virtual_time;

use super::{FakeReport, every, real_time};

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
        while !self.dead && !self.pending.is_empty() {
            // SAFETY: a valid socket and buffer; MSG_DONTWAIT makes this one call non-blocking
            // without touching the descriptor's flags (the reader shares them).
            let n = unsafe {
                libc::send(stream.as_raw_fd(), self.pending.as_ptr().cast(), self.pending.len(), libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL)
            };
            if n > 0 {
                self.pending.drain(..n as usize);
            } else {
                match std::io::Error::last_os_error().kind() {
                    std::io::ErrorKind::Interrupted => {}
                    std::io::ErrorKind::WouldBlock => break,
                    _ => self.dead = true,
                }
            }
        }
        if self.pending.len() > OUT_LIMIT {
            self.dead = true;
        }
        if self.dead {
            self.pending = Vec::new();
            self.shutdown();
        }
    }
}

/// One message on the wire.
fn msg(code: u32, payload: &str) -> Vec<u8> {
    format!("[{code:04}][{payload}]\0").into_bytes()
}

fn list(values: &[f64]) -> String {
    values.iter().map(|v| format!("{v:.6}")).collect::<Vec<_>>().join(",")
}

fn stamped(t_us: u64, values: &[f64]) -> String {
    format!("{t_us},{}", list(values))
}

/// "major.minor.patch" as a comparable triple (missing or unreadable parts 0).
fn parse_version(v: &str) -> (u32, u32, u32) {
    let mut parts = v.trim().trim_start_matches('v').split('.').map(|p| p.parse::<u32>().unwrap_or(0));
    (parts.next().unwrap_or(0), parts.next().unwrap_or(0), parts.next().unwrap_or(0))
}

/// The command names the fake knows (lower case).
const KNOWN: [&str; 34] = [
    "activaterobot",
    "home",
    "deactivaterobot",
    "reseterror",
    "pausemotion",
    "resumemotion",
    "clearmotion",
    "getstatusrobot",
    "getjoints",
    "getrttargetjointpos",
    "getrtjointpos",
    "getrttargetjointvel",
    "getrtjointvel",
    "setmonitoringinterval",
    "getmonitoringinterval",
    "setrealtimemonitoring",
    "getrealtimemonitoring",
    "setctrlportmonitoring",
    "setveltimeout",
    "getveltimeout",
    "movejointsvel",
    "setjointacc",
    "getjointacc",
    "setjointvellimit",
    "getjointvellimit",
    "setjointvel",
    "getjointvel",
    "seteob",
    "seteom",
    "connectionwatchdog",
    "getmodeljointlimits",
    "getjointlimits",
    "getfwversion",
    "getproducttype",
];

struct State {
    t0_ns: u64,
    tick: f64,
    accel: [f64; JOINTS],
    home_ns: u64,
    version: String,
    fw: (u32, u32, u32),

    activated: bool,
    homed: bool,
    error: bool,
    paused: bool,
    eob: bool,
    eom: bool,
    homing_until: Option<u64>,
    q: [f64; JOINTS],
    v: [f64; JOINTS],
    /// The accepted MoveJointsVel (capped, deg/s) and when it arrived.
    cmd: [f64; JOINTS],
    cmd_at: Option<u64>,
    vel_timeout: f64,
    joint_acc: f64,
    joint_vel_limit: f64,
    joint_vel: f64,
    monitoring_interval: f64,
    next_monitor_ns: u64,
    rt: BTreeSet<u32>,
    eob_enabled: bool,
    eom_enabled: bool,
    watchdog: Option<(f64, u64)>,

    control: Option<Out>,
    control_gen: u64,
    ctrl_monitoring: bool,
    monitors: Vec<Out>,
    last_status: [bool; 7],

    report: MecaReport,
    vel_in_interval: bool,
}

impl State {
    fn new(opts: &MecaOptions, t0_ns: u64) -> State {
        let activated = opts.activated;
        let mut s = State {
            t0_ns,
            tick: if opts.tick.is_finite() && opts.tick > 0.0 { opts.tick } else { 0.001 },
            accel: opts.accel_deg,
            home_ns: (opts.home_time.max(0.0) * 1e9) as u64,
            version: opts.version.clone(),
            fw: parse_version(&opts.version),
            activated,
            homed: activated && opts.homed,
            error: false,
            paused: !activated,
            eob: true,
            eom: true,
            homing_until: None,
            q: opts.start_deg,
            v: [0.0; JOINTS],
            cmd: [0.0; JOINTS],
            cmd_at: None,
            vel_timeout: DEFAULT_VEL_TIMEOUT,
            joint_acc: DEFAULT_JOINT_ACC,
            joint_vel_limit: 100.0,
            joint_vel: 100.0,
            monitoring_interval: DEFAULT_MONITORING_INTERVAL,
            next_monitor_ns: t0_ns,
            rt: BTreeSet::new(),
            eob_enabled: true,
            eom_enabled: false,
            watchdog: None,
            control: None,
            control_gen: 0,
            ctrl_monitoring: false,
            monitors: Vec::new(),
            last_status: [false; 7],
            report: MecaReport::default(),
            vel_in_interval: false,
        };
        s.last_status = s.status();
        s
    }

    fn status(&self) -> [bool; 7] {
        [self.activated, self.homed, false, self.error, self.paused, self.eob, self.eom]
    }

    fn status_payload(&self) -> String {
        self.status().iter().map(|b| if *b { "1" } else { "0" }).collect::<Vec<_>>().join(",")
    }

    fn t_us(&self, now: u64) -> u64 {
        now.saturating_sub(self.t0_ns) / 1000
    }

    fn at_least(&self, major: u32, minor: u32) -> bool {
        (self.fw.0, self.fw.1) >= (major, minor)
    }

    fn to_control(&mut self, bytes: &[u8]) {
        if let Some(c) = self.control.as_mut() {
            c.push(bytes);
        }
    }

    /// To every monitoring client, and to the control client if it asked for the stream.
    fn to_monitors(&mut self, bytes: &[u8]) {
        for m in &mut self.monitors {
            m.push(bytes);
        }
        if self.ctrl_monitoring {
            self.to_control(bytes);
        }
    }

    fn reply(&mut self, code: u32, payload: &str) {
        if (1000..2000).contains(&code) {
            self.report.errors.push(code);
            if matches!(code, 1001..=1003) {
                self.report.garbage += 1;
            }
        }
        self.to_control(&msg(code, payload));
    }

    /// A `[2007]` everywhere if the status changed (or `force`).
    fn publish_status(&mut self, force: bool) {
        let status = self.status();
        if force || status != self.last_status {
            self.last_status = status;
            let m = msg(2007, &self.status_payload());
            self.to_monitors(&m);
        }
    }

    /// The velocity command is dropped: the arm decelerates.
    fn drop_velocity(&mut self) {
        self.cmd = [0.0; JOINTS];
        self.cmd_at = None;
    }

    fn raise(&mut self, code: u32, text: &str) {
        self.error = true;
        self.paused = true;
        self.drop_velocity();
        self.report.errors.push(code);
        self.to_control(&msg(code, text));
        self.publish_status(true);
    }

    fn disconnected(&mut self) {
        self.control = None;
        self.ctrl_monitoring = false;
        self.watchdog = None;
        self.drop_velocity();
        // §5.2: a dropped control connection pauses motion.
        if self.activated {
            self.paused = true;
        }
        self.publish_status(false);
    }

    /// One frame from the control client (without its terminator), received at `now`.
    fn frame(&mut self, frame: &[u8], now: u64) {
        let text = String::from_utf8_lossy(frame);
        let text = text.trim();
        let text = text.strip_prefix('-').unwrap_or(text).trim();
        if text.is_empty() {
            return;
        }
        let (name, rest) = match text.find('(') {
            Some(i) => (text[..i].trim(), Some(&text[i..])),
            None => (text, None),
        };
        let key = name.to_ascii_lowercase();
        if !KNOWN.contains(&key.as_str()) {
            self.reply(1001, "Unknown command.");
            return;
        }
        if key != "movejointsvel" {
            self.report.commands.push(name.to_string());
        }
        let args: Vec<&str> = match rest {
            None => Vec::new(),
            Some(r) => {
                let inner = r.strip_prefix('(').and_then(|r| r.strip_suffix(')'));
                match inner {
                    Some(inner) if !inner.contains(['(', ')']) => {
                        let inner = inner.trim();
                        if inner.is_empty() { Vec::new() } else { inner.split(',').map(str::trim).collect() }
                    }
                    _ => {
                        self.reply(1002, "Syntax error, symbol missing.");
                        return;
                    }
                }
            }
        };
        if args.iter().any(|a| a.is_empty()) {
            self.reply(1002, "Syntax error, symbol missing.");
            return;
        }
        self.command(&key, &args, now);
    }

    fn arg_error(&mut self) {
        self.reply(1003, "Argument error.");
    }

    /// `n` finite numbers, or None (1003 sent).
    fn numbers(&mut self, args: &[&str], n: usize) -> Option<Vec<f64>> {
        let values: Option<Vec<f64>> = args.iter().map(|a| a.parse::<f64>().ok().filter(|v| v.is_finite())).collect();
        match values {
            Some(v) if v.len() == n => Some(v),
            _ => {
                self.arg_error();
                None
            }
        }
    }

    /// One number within `lo..=hi`, or None (1003 sent).
    fn number_in(&mut self, args: &[&str], lo: f64, hi: f64) -> Option<f64> {
        let v = self.numbers(args, 1)?[0];
        if (lo..=hi).contains(&v) {
            Some(v)
        } else {
            self.arg_error();
            None
        }
    }

    /// An integer among `allowed`, or None (1003 sent).
    fn integer_of(&mut self, args: &[&str], allowed: std::ops::RangeInclusive<i64>) -> Option<i64> {
        let v = self.numbers(args, 1)?[0];
        if v.fract() == 0.0 && allowed.contains(&(v as i64)) {
            Some(v as i64)
        } else {
            self.arg_error();
            None
        }
    }

    fn no_args(&mut self, args: &[&str]) -> bool {
        if args.is_empty() {
            true
        } else {
            self.arg_error();
            false
        }
    }

    /// A motion-queue command may run (else 1005, 1006 or 1011 sent).
    fn queue_ready(&mut self) -> bool {
        if !self.activated {
            self.reply(1005, "Motors are not activated.");
        } else if !self.homed {
            self.reply(1006, "Homing has not been performed.");
        } else if self.error {
            self.reply(1011, "The robot is in error.");
        } else {
            return true;
        }
        false
    }

    fn activated_or_1005(&mut self) -> bool {
        if !self.activated {
            self.reply(1005, "Motors are not activated.");
        }
        self.activated
    }

    fn unknown_before(&mut self, major: u32, minor: u32) -> bool {
        if self.at_least(major, minor) {
            false
        } else {
            self.reply(1001, "Unknown command.");
            true
        }
    }

    fn command(&mut self, key: &str, args: &[&str], now: u64) {
        match key {
            "activaterobot" => {
                if !self.no_args(args) {
                } else if self.error {
                    self.reply(1011, "The robot is in error.");
                } else if self.activated {
                    if self.at_least(9, 0) {
                        self.reply(2000, "Motors activated.");
                    } else {
                        self.reply(2001, "Motors already activated.");
                    }
                } else {
                    self.activated = true;
                    self.paused = false;
                    self.vel_timeout = DEFAULT_VEL_TIMEOUT;
                    self.joint_acc = DEFAULT_JOINT_ACC;
                    self.joint_vel_limit = 100.0;
                    self.joint_vel = 100.0;
                    self.drop_velocity();
                    self.reply(2000, "Motors activated.");
                    self.publish_status(true);
                }
            }
            "home" => {
                if !self.no_args(args) || !self.activated_or_1005() {
                } else if self.error {
                    self.reply(1011, "The robot is in error.");
                } else if self.homed {
                    if self.at_least(9, 0) {
                        self.reply(2002, "Homing done.");
                    } else {
                        self.reply(2003, "Homing already done.");
                    }
                } else if self.homing_until.is_none() {
                    self.homing_until = Some(now.saturating_add(self.home_ns));
                }
            }
            "deactivaterobot" => {
                if self.no_args(args) {
                    self.activated = false;
                    self.homed = false;
                    self.homing_until = None;
                    self.paused = true;
                    self.v = [0.0; JOINTS];
                    self.drop_velocity();
                    self.reply(2004, "Motors deactivated.");
                    self.publish_status(true);
                }
            }
            "reseterror" => {
                if self.no_args(args) {
                    if self.error {
                        self.error = false;
                        self.reply(2005, "The error was reset.");
                    } else {
                        self.reply(2006, "There was no error to reset.");
                    }
                    self.publish_status(true);
                }
            }
            "pausemotion" => {
                if self.no_args(args) && self.activated_or_1005() {
                    self.paused = true;
                    self.drop_velocity();
                    self.reply(2042, "Motion paused.");
                    self.publish_status(true);
                }
            }
            "resumemotion" => {
                if !self.no_args(args) || !self.activated_or_1005() {
                } else if self.error {
                    self.reply(1011, "The robot is in error.");
                } else {
                    self.paused = false;
                    self.reply(2043, "Motion resumed.");
                    self.publish_status(true);
                }
            }
            "clearmotion" => {
                if self.no_args(args) && self.activated_or_1005() {
                    self.paused = true;
                    self.drop_velocity();
                    self.reply(2044, "The motion was cleared.");
                    self.publish_status(true);
                }
            }
            "getstatusrobot" => {
                if self.no_args(args) {
                    let p = self.status_payload();
                    self.reply(2007, &p);
                }
            }
            "getjoints" => {
                if self.no_args(args) {
                    let p = list(&self.q);
                    self.reply(2026, &p);
                }
            }
            "getrttargetjointpos" | "getrtjointpos" | "getrttargetjointvel" | "getrtjointvel" => {
                if (key == "getrttargetjointpos" && self.unknown_before(8, 4)) || !self.no_args(args) {
                    return;
                }
                let (code, values) = match key {
                    "getrttargetjointpos" => (2200, self.q),
                    "getrtjointpos" => (2210, self.q),
                    "getrttargetjointvel" => (2202, self.v),
                    _ => (2212, self.v),
                };
                let p = stamped(self.t_us(now), &values);
                self.reply(code, &p);
            }
            "setmonitoringinterval" => {
                if let Some(t) = self.number_in(args, 0.001, 1.0) {
                    self.monitoring_interval = t;
                    self.next_monitor_ns = now;
                }
            }
            "getmonitoringinterval" => {
                if self.no_args(args) {
                    let p = format!("{:.6}", self.monitoring_interval);
                    self.reply(2116, &p);
                }
            }
            "setrealtimemonitoring" => {
                let mut set = BTreeSet::new();
                for a in args {
                    if a.eq_ignore_ascii_case("all") {
                        set.extend(RT_CODES);
                    } else {
                        match a.parse::<u32>() {
                            Ok(c) if RT_CODES.contains(&c) => {
                                set.insert(c);
                            }
                            _ => return self.arg_error(),
                        }
                    }
                }
                self.rt = set;
                self.rt_reply();
            }
            "getrealtimemonitoring" => {
                if self.no_args(args) {
                    self.rt_reply();
                }
            }
            "setctrlportmonitoring" => {
                if self.unknown_before(9, 0) {
                    return;
                }
                if let Some(on) = self.integer_of(args, 0..=1) {
                    self.ctrl_monitoring = on == 1;
                    self.reply(2096, &on.to_string());
                    if self.ctrl_monitoring {
                        let m = msg(2007, &self.status_payload());
                        self.to_control(&m);
                    }
                }
            }
            "setveltimeout" => {
                if let Some(t) = self.number_in(args, 0.001, 1.0)
                    && self.queue_ready()
                {
                    self.vel_timeout = t;
                }
            }
            "movejointsvel" => {
                if let Some(w) = self.numbers(args, JOINTS)
                    && self.queue_ready()
                {
                    self.report.move_joints_vel += 1;
                    self.vel_in_interval = true;
                    if self.paused {
                        return;
                    }
                    // Capped to the speeds × SetJointVelLimit, scaled together (the direction kept).
                    let ratio = (0..JOINTS).map(|j| w[j].abs() / (R3_SPEED_DEG[j] * self.joint_vel_limit / 100.0)).fold(1.0f64, f64::max);
                    for j in 0..JOINTS {
                        self.cmd[j] = w[j] / ratio;
                    }
                    self.cmd_at = Some(now);
                }
            }
            "setjointacc" => {
                if let Some(p) = self.number_in(args, 0.001, 150.0)
                    && self.queue_ready()
                {
                    self.joint_acc = p;
                }
            }
            "setjointvellimit" => {
                if self.unknown_before(9, 3) {
                    return;
                }
                if let Some(p) = self.number_in(args, 0.001, 100.0)
                    && self.queue_ready()
                {
                    self.joint_vel_limit = p;
                }
            }
            "setjointvel" => {
                if let Some(p) = self.number_in(args, 0.001, 100.0)
                    && self.queue_ready()
                {
                    self.joint_vel = p;
                }
            }
            "getveltimeout" | "getjointacc" | "getjointvellimit" | "getjointvel" => {
                if (key == "getjointvellimit" && self.unknown_before(9, 3)) || !self.no_args(args) {
                    return;
                }
                let (code, v) = match key {
                    "getveltimeout" => (2151, self.vel_timeout),
                    "getjointacc" => (2153, self.joint_acc),
                    "getjointvellimit" => (2169, self.joint_vel_limit),
                    _ => (2152, self.joint_vel),
                };
                self.reply(code, &format!("{v:.6}"));
            }
            "seteob" | "seteom" => {
                if let Some(on) = self.integer_of(args, 0..=1) {
                    let on = on == 1;
                    if key == "seteob" {
                        self.eob_enabled = on;
                        self.reply(if on { 2054 } else { 2055 }, if on { "End of block is enabled." } else { "End of block is disabled." });
                    } else {
                        self.eom_enabled = on;
                        self.reply(
                            if on { 2052 } else { 2053 },
                            if on { "End of movement is enabled." } else { "End of movement is disabled." },
                        );
                    }
                }
            }
            "connectionwatchdog" => {
                if self.unknown_before(10, 1) {
                    return;
                }
                if let Some(t) = self.number_in(args, 0.0, f64::MAX) {
                    if t > 0.0 {
                        self.watchdog = Some((t, now.saturating_add((t * 1e9) as u64)));
                        self.reply(2177, "1");
                    } else {
                        self.watchdog = None;
                        self.reply(2177, "0");
                    }
                }
            }
            "getmodeljointlimits" | "getjointlimits" => {
                if let Some(n) = self.integer_of(args, 1..=JOINTS as i64) {
                    let (lo, hi) = R3_LIMITS_DEG[n as usize - 1];
                    let p = format!("{n},{lo:.6},{hi:.6}");
                    self.reply(if key == "getmodeljointlimits" { 2113 } else { 2090 }, &p);
                }
            }
            "getfwversion" => {
                if self.no_args(args) {
                    let p = format!("v{}", self.version);
                    self.reply(2081, &p);
                }
            }
            "getproducttype" => {
                if self.no_args(args) {
                    self.reply(2084, "Meca500");
                }
            }
            _ => self.reply(1001, "Unknown command."),
        }
    }

    fn rt_reply(&mut self) {
        let p = self.rt.iter().map(u32::to_string).collect::<Vec<_>>().join(",");
        self.reply(2117, &p);
    }

    /// One trajectory cycle ending at `now` (its deadline).
    fn step(&mut self, now: u64) {
        let dt = self.tick;
        if let Some(until) = self.homing_until
            && now >= until
        {
            self.homing_until = None;
            if self.activated && !self.error {
                self.homed = true;
                self.reply(2002, "Homing done.");
                self.publish_status(true);
            }
        }
        if let Some((_, deadline)) = self.watchdog
            && now > deadline
        {
            self.watchdog = None;
            self.report.errors.push(3086);
            self.to_control(&msg(3086, "Connection watchdog expired."));
            if let Some(c) = self.control.as_mut() {
                c.flush();
                c.shutdown();
            }
            self.drop_velocity();
            if self.activated {
                self.paused = true;
            }
        }
        let ready = self.activated && self.homed && !self.error && !self.paused && self.control.is_some();
        if !ready {
            self.drop_velocity();
        }
        let mut target = [0.0; JOINTS];
        if let Some(at) = self.cmd_at {
            if now > at.saturating_add((self.vel_timeout * 1e9) as u64) {
                if self.cmd.iter().any(|w| *w != 0.0) {
                    self.report.timeouts += 1;
                }
                self.drop_velocity();
            } else {
                target = self.cmd;
            }
        }
        // A joint at its limit is not driven into it.
        for j in 0..JOINTS {
            let (lo, hi) = R3_LIMITS_DEG[j];
            if (self.q[j] >= hi && target[j] > 0.0) || (self.q[j] <= lo && target[j] < 0.0) {
                target[j] = 0.0;
            }
        }
        let v_old = self.v;
        if !self.activated {
            self.v = [0.0; JOINTS];
        } else {
            // All joints reach the target together, none faster than its acceleration.
            let need = (0..JOINTS)
                .map(|j| (target[j] - self.v[j]).abs() / (self.accel[j] * self.joint_acc / 100.0).max(1e-9))
                .fold(0.0f64, f64::max);
            if need <= dt {
                self.v = target;
            } else {
                for j in 0..JOINTS {
                    self.v[j] += (target[j] - self.v[j]) * dt / need;
                }
            }
        }
        for j in 0..JOINTS {
            let (lo, hi) = R3_LIMITS_DEG[j];
            let before = self.q[j];
            self.q[j] += 0.5 * (v_old[j] + self.v[j]) * dt;
            if self.q[j] >= hi || self.q[j] <= lo {
                if before < hi && before > lo {
                    self.report.limit_stops += 1;
                }
                self.q[j] = self.q[j].clamp(lo, hi);
                self.v[j] = 0.0;
            }
        }
        let moving = self.v.iter().any(|v| *v != 0.0);
        let busy = self.cmd_at.is_some() && self.cmd.iter().any(|w| *w != 0.0);
        let (eom, eob) = (!moving, !moving && !busy);
        if eom && !self.eom && self.eom_enabled {
            self.to_control(&msg(3004, "End of movement."));
        }
        if eob && !self.eob && self.eob_enabled {
            self.to_control(&msg(3012, "End of block."));
        }
        (self.eom, self.eob) = (eom, eob);
        self.publish_status(false);
        if now >= self.next_monitor_ns {
            let cycle = self.cycle(now);
            self.to_monitors(&cycle);
            if self.control.is_some() && self.activated && self.homed {
                let r = &mut self.report.report;
                r.axes.push(self.q.to_vec());
                r.cycles += 1;
                r.fresh.push(self.vel_in_interval);
                if self.vel_in_interval {
                    r.in_time += 1;
                } else {
                    r.missing += 1;
                }
            }
            self.vel_in_interval = false;
            let interval = (self.monitoring_interval * 1e9).round() as u64;
            self.next_monitor_ns += interval;
            if self.next_monitor_ns <= now {
                self.next_monitor_ns = now + interval;
            }
        }
        self.monitors.retain_mut(|m| {
            m.flush();
            !m.dead
        });
        if let Some(c) = self.control.as_mut() {
            c.flush();
        }
    }

    /// One monitoring cycle: every message stamped `t`, ended by `[2230][t]`.
    fn cycle(&self, now: u64) -> Vec<u8> {
        let t = self.t_us(now);
        let zeros = [0.0; JOINTS];
        let mut out = Vec::with_capacity(1024);
        out.extend(msg(2026, &list(&self.q)));
        out.extend(msg(2027, &list(&zeros)));
        out.extend(msg(2200, &stamped(t, &self.q)));
        out.extend(msg(2201, &stamped(t, &zeros)));
        for &code in &self.rt {
            let values: &[f64] = match code {
                2202 | 2212 => &self.v,
                2210 | 2221 => &self.q,
                2203 | 2204 | 2211 | 2213 | 2214 => &zeros,
                2222 => &[100.0],
                _ => continue,
            };
            out.extend(msg(code, &stamped(t, values)));
        }
        out.extend(msg(2230, &t.to_string()));
        out
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
        let tick_ns = ((opts.tick.is_finite() && opts.tick > 0.0).then_some(opts.tick).unwrap_or(0.001) * 1e9).round() as u64;
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
        st.to_control(banner);
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
                    st.to_control(&msg(3003, "Command too long."));
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

#[cfg(test)]
mod tests {
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
}
