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

use std::io::Read;
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use super::{FakeReport, every, real_time};

pub mod virtual_time;

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

/// Silence that ends a script on the primary port (ns).
const SCRIPT_IDLE_NS: u64 = 100_000_000;
/// The longest script kept (bytes); more is dropped as garbage.
const MAX_SCRIPT_LEN: usize = 1 << 20;
/// The program's attempts to connect back, and the wait between them (s, §2.1).
const CONNECT_ATTEMPTS: u32 = 5;
const CONNECT_RETRY: f64 = 0.2;
/// Bytes queued for an RTDE client that does not read before it is dropped.
const OUT_LIMIT: usize = 1 << 20;
/// The longest a blocking wait goes without looking at the stop flag (ns).
const SLICE_NS: u64 = 20_000_000;

const V: u8 = b'V';
const VERSION: u8 = b'v';
const TEXT: u8 = b'M';
const DATA: u8 = b'U';
const SETUP_OUTPUTS: u8 = b'O';
const SETUP_INPUTS: u8 = b'I';
const START: u8 = b'S';
const PAUSE: u8 = b'P';

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

/// An RTDE output the fake knows (§1.7).
#[derive(Clone, Copy, Debug, PartialEq)]
enum OutField {
    Timestamp,
    ActualQ,
    ActualQd,
    TargetQ,
    TargetQd,
    RobotMode,
    SafetyMode,
    SafetyStatus,
    RuntimeState,
    SpeedScaling,
    TargetSpeedFraction,
    RobotStatusBits,
    SafetyStatusBits,
}

impl OutField {
    fn of(name: &str) -> Option<OutField> {
        Some(match name {
            "timestamp" => OutField::Timestamp,
            "actual_q" => OutField::ActualQ,
            "actual_qd" => OutField::ActualQd,
            "target_q" => OutField::TargetQ,
            "target_qd" => OutField::TargetQd,
            "robot_mode" => OutField::RobotMode,
            "safety_mode" => OutField::SafetyMode,
            "safety_status" => OutField::SafetyStatus,
            "runtime_state" => OutField::RuntimeState,
            "speed_scaling" => OutField::SpeedScaling,
            "target_speed_fraction" => OutField::TargetSpeedFraction,
            "robot_status_bits" => OutField::RobotStatusBits,
            "safety_status_bits" => OutField::SafetyStatusBits,
            _ => return None,
        })
    }

    fn type_name(self) -> &'static str {
        match self {
            OutField::Timestamp | OutField::SpeedScaling | OutField::TargetSpeedFraction => "DOUBLE",
            OutField::ActualQ | OutField::ActualQd | OutField::TargetQ | OutField::TargetQd => "VECTOR6D",
            OutField::RobotMode | OutField::SafetyMode | OutField::SafetyStatus => "INT32",
            OutField::RuntimeState | OutField::RobotStatusBits | OutField::SafetyStatusBits => "UINT32",
        }
    }

    fn encode(self, s: &Snapshot, out: &mut Vec<u8>) {
        let vec6 = |out: &mut Vec<u8>, v: &[f64; JOINTS]| v.iter().for_each(|x| out.extend_from_slice(&x.to_be_bytes()));
        match self {
            OutField::Timestamp => out.extend_from_slice(&s.time.to_be_bytes()),
            OutField::ActualQ => vec6(out, &s.q),
            OutField::ActualQd => vec6(out, &s.qd),
            OutField::TargetQ => vec6(out, &s.target_q),
            OutField::TargetQd => vec6(out, &s.qd),
            OutField::RobotMode => out.extend_from_slice(&s.robot_mode.to_be_bytes()),
            OutField::SafetyMode | OutField::SafetyStatus => out.extend_from_slice(&s.safety_mode.to_be_bytes()),
            OutField::RuntimeState => out.extend_from_slice(&s.runtime_state.to_be_bytes()),
            OutField::SpeedScaling => out.extend_from_slice(&s.speed_scaling.to_be_bytes()),
            OutField::TargetSpeedFraction => out.extend_from_slice(&s.speed_fraction.to_be_bytes()),
            OutField::RobotStatusBits => {
                // Bit 0 power on, bit 1 program running (§1.7).
                let bits = 1u32 | (u32::from(s.program_running) << 1);
                out.extend_from_slice(&bits.to_be_bytes());
            }
            OutField::SafetyStatusBits => {
                // Bits 0 normal, 1 reduced, 2 protective stop, 10 stopped due to safety (§1.7).
                let bits = match s.safety_mode {
                    1 => 1u32,
                    2 => 1 << 1,
                    3 => (1 << 2) | (1 << 10),
                    _ => 1 << 10,
                };
                out.extend_from_slice(&bits.to_be_bytes());
            }
        }
    }
}

/// An RTDE input the fake knows (§1.6).
#[derive(Clone, Copy, Debug, PartialEq)]
enum InField {
    AnalogMask,
    AnalogType,
    Analog(usize),
    SliderMask,
    SliderFraction,
    DigitalMask,
    Digital,
    BitRegister(usize),
    IntRegister(usize),
    DoubleRegister(usize),
}

/// A decoded input value.
#[derive(Clone, Copy, Debug)]
enum Value {
    U8(u8),
    U32(u32),
    I32(i32),
    F64(f64),
}

impl InField {
    fn of(name: &str) -> Option<InField> {
        let register = |prefix: &str, range: std::ops::RangeInclusive<usize>| {
            name.strip_prefix(prefix).and_then(|n| n.parse::<usize>().ok()).filter(|n| range.contains(n))
        };
        Some(match name {
            "standard_analog_output_mask" => InField::AnalogMask,
            "standard_analog_output_type" => InField::AnalogType,
            "standard_analog_output_0" => InField::Analog(0),
            "standard_analog_output_1" => InField::Analog(1),
            "speed_slider_mask" => InField::SliderMask,
            "speed_slider_fraction" => InField::SliderFraction,
            "standard_digital_output_mask" => InField::DigitalMask,
            "standard_digital_output" => InField::Digital,
            _ => {
                if let Some(n) = register("input_bit_register_", 64..=127) {
                    InField::BitRegister(n)
                } else if let Some(n) = register("input_int_register_", 0..=47) {
                    InField::IntRegister(n)
                } else if let Some(n) = register("input_double_register_", 0..=47) {
                    InField::DoubleRegister(n)
                } else {
                    return None;
                }
            }
        })
    }

    fn type_name(self) -> &'static str {
        match self {
            InField::AnalogMask | InField::AnalogType | InField::DigitalMask | InField::Digital => "UINT8",
            InField::Analog(_) | InField::SliderFraction | InField::DoubleRegister(_) => "DOUBLE",
            InField::SliderMask => "UINT32",
            InField::BitRegister(_) => "BOOL",
            InField::IntRegister(_) => "INT32",
        }
    }

    fn size(self) -> usize {
        match self.type_name() {
            "UINT8" | "BOOL" => 1,
            "UINT32" | "INT32" => 4,
            _ => 8,
        }
    }

    fn decode(self, b: &[u8]) -> Option<Value> {
        Some(match self.type_name() {
            "UINT8" | "BOOL" => Value::U8(*b.first()?),
            "UINT32" => Value::U32(u32::from_be_bytes(b.get(..4)?.try_into().ok()?)),
            "INT32" => Value::I32(i32::from_be_bytes(b.get(..4)?.try_into().ok()?)),
            _ => Value::F64(f64::from_be_bytes(b.get(..8)?.try_into().ok()?)),
        })
    }
}

/// One package on the wire.
fn package(ty: u8, payload: &[u8]) -> Vec<u8> {
    let mut p = Vec::with_capacity(payload.len() + 3);
    p.extend_from_slice(&((payload.len() + 3) as u16).to_be_bytes());
    p.push(ty);
    p.extend_from_slice(payload);
    p
}

/// A v2 text message (`M`): message, source, level (3 INFO, 1 ERROR).
fn text_message(message: &str, source: &str, level: u8) -> Vec<u8> {
    let (m, s) = (&message.as_bytes()[..message.len().min(255)], &source.as_bytes()[..source.len().min(255)]);
    let mut payload = vec![m.len() as u8];
    payload.extend_from_slice(m);
    payload.push(s.len() as u8);
    payload.extend_from_slice(s);
    payload.push(level);
    package(TEXT, &payload)
}

/// A client's socket and what it has not yet taken: writes never block the controller.
struct Conn {
    stream: TcpStream,
    pending: Vec<u8>,
    dead: bool,
}

impl Conn {
    fn push(&mut self, bytes: &[u8]) {
        if !self.dead {
            self.pending.extend_from_slice(bytes);
            self.flush();
        }
    }

    fn flush(&mut self) {
        while !self.dead && !self.pending.is_empty() {
            // SAFETY: a valid socket and buffer; MSG_DONTWAIT makes this one call non-blocking
            // without touching the descriptor's flags (the reader shares them).
            let n = unsafe {
                libc::send(
                    self.stream.as_raw_fd(),
                    self.pending.as_ptr().cast(),
                    self.pending.len(),
                    libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
                )
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
            let _ = self.stream.shutdown(Shutdown::Both);
        }
    }
}

/// The output recipe of a session.
enum Outputs {
    None,
    Invalid,
    Valid(Vec<OutField>),
}

/// One RTDE client.
struct Session {
    id: u64,
    conn: Conn,
    outputs: Outputs,
    frequency: f64,
    inputs: Vec<(u8, Vec<InField>)>,
    next_input_id: u8,
    started: bool,
    told: bool,
    phase: f64,
}

/// The controller state the RTDE stream shows.
struct Snapshot {
    time: f64,
    q: [f64; JOINTS],
    qd: [f64; JOINTS],
    target_q: [f64; JOINTS],
    robot_mode: i32,
    safety_mode: i32,
    runtime_state: u32,
    speed_scaling: f64,
    speed_fraction: f64,
    program_running: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Motion {
    /// At rest.
    Hold,
    /// Following `target` (servoj).
    Servo,
    /// Decelerating to rest at [`STOPJ_ACCELERATION`].
    Stopping,
}

struct State {
    opts: UrOptions,
    t0: u64,
    time: f64,
    q: [f64; JOINTS],
    qd: [f64; JOINTS],
    target: [f64; JOINTS],
    motion: Motion,
    robot_mode: i32,
    safety_mode: i32,
    runtime_state: u32,
    program_running: bool,
    control_mode: i32,
    fresh: bool,
    program_gen: u64,
    reverse: Option<TcpStream>,
    servo_args: Option<(Option<f64>, Option<f64>)>,
    speed_scaling: f64,
    speed_fraction: f64,
    analog: [(u8, f64); 2],
    digital: u8,
    bit_registers: u64,
    int_registers: [i32; 48],
    double_registers: [f64; 48],
    sessions: Vec<Session>,
    next_session: u64,
    /// Inputs owned by a session (name, session id): another session asking for them gets IN_USE.
    owners: Vec<(String, u64)>,
    report: UrReport,
}

impl State {
    fn new(opts: &UrOptions, t0: u64) -> State {
        State {
            opts: opts.clone(),
            t0,
            time: 0.0,
            q: opts.start_q,
            qd: [0.0; JOINTS],
            target: opts.start_q,
            motion: Motion::Hold,
            robot_mode: ROBOT_MODE_RUNNING,
            safety_mode: SAFETY_NORMAL,
            runtime_state: RUNTIME_STOPPED,
            program_running: false,
            control_mode: MODE_UNINITIALIZED,
            fresh: false,
            program_gen: 0,
            reverse: None,
            servo_args: None,
            speed_scaling: 1.0,
            speed_fraction: 1.0,
            analog: [(0, 0.0); 2],
            digital: 0,
            bit_registers: 0,
            int_registers: [0; 48],
            double_registers: [0.0; 48],
            sessions: Vec::new(),
            next_session: 1,
            owners: Vec::new(),
            report: UrReport::default(),
        }
    }

    fn snapshot(&self) -> Snapshot {
        Snapshot {
            time: self.time,
            q: self.q,
            qd: self.qd,
            target_q: if self.motion == Motion::Servo { self.target } else { self.q },
            robot_mode: self.robot_mode,
            safety_mode: self.safety_mode,
            runtime_state: self.runtime_state,
            speed_scaling: self.speed_scaling,
            speed_fraction: self.speed_fraction,
            program_running: self.program_running,
        }
    }

    /// One controller step at `deadline` (ns).
    fn step(&mut self, deadline: u64) {
        let dt = self.opts.step;
        self.time = deadline.saturating_sub(self.t0) as f64 * 1e-9;
        match self.motion {
            Motion::Servo => {
                for j in 0..JOINTS {
                    let lim = self.opts.speed_limit[j].abs() * dt;
                    let d = (self.target[j] - self.q[j]).clamp(-lim, lim);
                    self.q[j] += d;
                    self.qd[j] = d / dt;
                }
            }
            Motion::Stopping => {
                let dv = STOPJ_ACCELERATION * dt;
                let mut moving = false;
                for j in 0..JOINTS {
                    let v = self.qd[j];
                    let nv = v.signum() * (v.abs() - dv).max(0.0);
                    self.q[j] += 0.5 * (v + nv) * dt;
                    self.qd[j] = nv;
                    moving |= nv != 0.0;
                }
                if !moving {
                    self.motion = Motion::Hold;
                }
            }
            Motion::Hold => self.qd = [0.0; JOINTS],
        }
        if self.program_running && self.control_mode == MODE_SERVOJ {
            let r = &mut self.report.report;
            r.axes.push(self.q.iter().map(|q| q.to_degrees()).collect());
            r.fresh.push(self.fresh);
            r.cycles += 1;
            if self.fresh {
                r.in_time += 1;
            } else {
                r.missing += 1;
            }
        }
        self.fresh = false;
        // The RTDE stream: each started session at its own frequency, on step boundaries, the
        // newest state; a package is skipped while the client has not taken the last one.
        let snap = self.snapshot();
        for s in &mut self.sessions {
            let Outputs::Valid(fields) = &s.outputs else { continue };
            if !s.started || s.conn.dead {
                continue;
            }
            s.phase += s.frequency * dt;
            if s.phase < 1.0 - 1e-9 {
                continue;
            }
            s.phase = (s.phase - 1.0).clamp(0.0, 0.999);
            if !s.conn.pending.is_empty() {
                s.conn.flush();
                continue;
            }
            let mut payload = Vec::with_capacity(256);
            payload.push(1u8);
            for f in fields {
                f.encode(&snap, &mut payload);
            }
            s.conn.push(&package(DATA, &payload));
        }
    }

    /// Ends the running program (the arm decelerates to rest, the reverse socket is closed).
    fn end_program(&mut self) {
        self.program_gen += 1;
        self.program_running = false;
        self.runtime_state = RUNTIME_STOPPED;
        self.control_mode = MODE_UNINITIALIZED;
        self.stop_arm();
        if let Some(r) = self.reverse.take() {
            let _ = r.shutdown(Shutdown::Both);
        }
    }

    fn stop_arm(&mut self) {
        if self.motion != Motion::Hold {
            self.motion = Motion::Stopping;
        }
    }

    fn session(&mut self, id: u64) -> Option<&mut Session> {
        self.sessions.iter_mut().find(|s| s.id == id)
    }

    fn reply(&mut self, id: u64, bytes: &[u8]) {
        if let Some(s) = self.session(id) {
            s.conn.push(bytes);
        }
    }

    /// One RTDE package from session `id`.
    fn rtde_package(&mut self, id: u64, ty: u8, payload: &[u8]) {
        match ty {
            V => {
                let Ok(v) = <[u8; 2]>::try_from(payload) else { return self.report.garbage += 1 };
                let accepted = u16::from_be_bytes(v) == RTDE_PROTOCOL_VERSION;
                self.reply(id, &package(V, &[u8::from(accepted)]));
            }
            VERSION => {
                if !payload.is_empty() {
                    return self.report.garbage += 1;
                }
                let mut p = Vec::with_capacity(16);
                for v in self.opts.version {
                    p.extend_from_slice(&v.to_be_bytes());
                }
                self.reply(id, &package(VERSION, &p));
            }
            SETUP_OUTPUTS => self.setup_outputs(id, payload),
            SETUP_INPUTS => self.setup_inputs(id, payload),
            START => {
                if !payload.is_empty() {
                    return self.report.garbage += 1;
                }
                let step = self.opts.step;
                let Some(s) = self.session(id) else { return };
                let accepted = match s.outputs {
                    Outputs::Valid(_) => true,
                    Outputs::None => !s.inputs.is_empty(),
                    Outputs::Invalid => false,
                };
                s.conn.push(&package(START, &[u8::from(accepted)]));
                if accepted {
                    if !s.started {
                        s.phase = 1.0 - s.frequency * step;
                    }
                    s.started = true;
                    if !s.told {
                        s.told = true;
                        s.conn.push(&text_message("RTDE started", "strand fake UR", 3));
                    }
                    self.report.rtde_sessions += 1;
                }
            }
            PAUSE => {
                if !payload.is_empty() {
                    return self.report.garbage += 1;
                }
                if let Some(s) = self.session(id) {
                    s.started = false;
                    s.conn.push(&package(PAUSE, &[1]));
                }
            }
            DATA => self.input_data(id, payload),
            TEXT => {
                // v2: u8 len, message, u8 len, source, u8 level; read and dropped.
                let ok = (|| {
                    let m = usize::from(*payload.first()?);
                    let s = usize::from(*payload.get(1 + m)?);
                    (payload.len() == 1 + m + 1 + s + 1).then_some(())
                })();
                if ok.is_none() {
                    self.report.garbage += 1;
                }
            }
            _ => self.report.garbage += 1,
        }
    }

    /// The names of a setup package, or `None` (garbage: not ASCII, empty or too long).
    fn names(&mut self, bytes: &[u8]) -> Option<Vec<String>> {
        let text = std::str::from_utf8(bytes).ok().filter(|t| t.is_ascii() && !t.is_empty() && t.len() <= MAX_NAMES_LEN);
        if text.is_none() {
            self.report.garbage += 1;
        }
        Some(text?.split(',').map(str::to_string).collect())
    }

    fn setup_outputs(&mut self, id: u64, payload: &[u8]) {
        let max = if self.opts.version[0] < 5 { CB3_MAX_FREQUENCY } else { URE_MAX_FREQUENCY };
        let Some(f) = payload.get(..8).and_then(|b| b.try_into().ok()).map(f64::from_be_bytes) else {
            return self.report.garbage += 1;
        };
        let names = self.names(&payload[8..]);
        let Some(s) = self.session(id) else { return };
        let Some(names) = names else {
            s.outputs = Outputs::Invalid;
            return s.conn.push(&package(SETUP_OUTPUTS, &[0]));
        };
        if s.started {
            // A recipe cannot change while the stream runs: refused, the old one kept.
            s.conn.push(&text_message("Cannot set up outputs while started; pause first", "strand fake UR", 1));
            return s.conn.push(&package(SETUP_OUTPUTS, &[0]));
        }
        if !(f > 0.0 && f <= max) {
            s.outputs = Outputs::Invalid;
            s.conn.push(&text_message(&format!("RTDE frequency {f} Hz out of range (0, {max}]"), "strand fake UR", 1));
            return s.conn.push(&package(SETUP_OUTPUTS, &[0]));
        }
        let fields: Vec<Option<OutField>> = names.iter().map(|n| OutField::of(n)).collect();
        let types: Vec<&str> = fields.iter().map(|f| f.map_or("NOT_FOUND", OutField::type_name)).collect();
        let valid = fields.iter().all(Option::is_some);
        let mut p = vec![u8::from(valid)];
        p.extend_from_slice(types.join(",").as_bytes());
        s.frequency = f;
        s.outputs = if valid { Outputs::Valid(fields.into_iter().flatten().collect()) } else { Outputs::Invalid };
        s.conn.push(&package(SETUP_OUTPUTS, &p));
    }

    fn setup_inputs(&mut self, id: u64, payload: &[u8]) {
        let names = self.names(payload);
        // Owners whose client has gone (its reader not yet noticed) give their inputs up.
        let gone: Vec<u64> = self.sessions.iter().filter(|s| s.id != id && peer_gone(&s.conn.stream)).map(|s| s.id).collect();
        self.owners.retain(|(_, o)| !gone.contains(o));
        let in_use: Vec<bool> = names.iter().flatten().map(|n| self.owners.iter().any(|(name, owner)| name == n && *owner != id)).collect();
        let Some(s) = self.sessions.iter_mut().find(|s| s.id == id) else { return };
        let Some(names) = names else { return s.conn.push(&package(SETUP_INPUTS, &[0])) };
        if s.started {
            s.conn.push(&text_message("Cannot set up inputs while started; pause first", "strand fake UR", 1));
            return s.conn.push(&package(SETUP_INPUTS, &[0]));
        }
        let fields: Vec<Option<InField>> = names.iter().map(|n| InField::of(n)).collect();
        let types: Vec<&str> = fields
            .iter()
            .zip(&in_use)
            .map(|(f, used)| match f {
                None => "NOT_FOUND",
                Some(_) if *used => "IN_USE",
                Some(f) => f.type_name(),
            })
            .collect();
        let valid = fields.iter().all(Option::is_some) && !in_use.iter().any(|u| *u);
        let rid = if valid && s.next_input_id < 255 {
            s.next_input_id += 1;
            s.inputs.push((s.next_input_id, fields.into_iter().flatten().collect()));
            s.next_input_id
        } else {
            0
        };
        let mut p = vec![rid];
        p.extend_from_slice(types.join(",").as_bytes());
        s.conn.push(&package(SETUP_INPUTS, &p));
        if rid != 0 {
            for n in names {
                if !self.owners.iter().any(|(name, _)| *name == n) {
                    self.owners.push((n, id));
                }
            }
        }
    }

    /// A client's `U`: decoded with its input recipe and applied.
    fn input_data(&mut self, id: u64, payload: &[u8]) {
        let Some(s) = self.sessions.iter().find(|s| s.id == id) else { return };
        let Some(&rid) = payload.first() else { return self.report.garbage += 1 };
        let Some((_, fields)) = s.inputs.iter().find(|(r, _)| *r == rid) else { return self.report.garbage += 1 };
        if !s.started || 1 + fields.iter().map(|f| f.size()).sum::<usize>() != payload.len() {
            return self.report.garbage += 1;
        }
        let mut values = Vec::with_capacity(fields.len());
        let mut at = 1;
        for f in fields {
            let Some(v) = payload.get(at..).and_then(|b| f.decode(b)) else { return self.report.garbage += 1 };
            values.push((*f, v));
            at += f.size();
        }
        let get = |want: InField| values.iter().rev().find(|(f, _)| *f == want).map(|(_, v)| *v);
        let (mut bad, mut wrote) = (false, false);
        if let Some(Value::U8(mask)) = get(InField::AnalogMask) {
            let domain = match get(InField::AnalogType) {
                Some(Value::U8(t)) => Some(t),
                _ => None,
            };
            for pin in 0..2 {
                if mask & (1 << pin) == 0 {
                    continue;
                }
                let ratio = match get(InField::Analog(pin)) {
                    Some(Value::F64(r)) if (0.0..=1.0).contains(&r) => Some(r),
                    Some(_) => {
                        bad = true;
                        continue;
                    }
                    None => None,
                };
                if domain.is_none() && ratio.is_none() {
                    continue;
                }
                if let Some(t) = domain {
                    self.analog[pin].0 = (t >> pin) & 1;
                }
                if let Some(r) = ratio {
                    self.analog[pin].1 = r;
                }
                wrote = true;
            }
        }
        if let (Some(Value::U32(mask)), Some(Value::F64(f))) = (get(InField::SliderMask), get(InField::SliderFraction))
            && mask & 1 != 0
        {
            if (0.0..=1.0).contains(&f) {
                self.speed_fraction = f;
            } else {
                bad = true;
            }
        }
        if let (Some(Value::U8(mask)), Some(Value::U8(d))) = (get(InField::DigitalMask), get(InField::Digital)) {
            self.digital = (self.digital & !mask) | (d & mask);
        }
        for (f, v) in &values {
            match (f, v) {
                (InField::BitRegister(n), Value::U8(b)) => {
                    let bit = 1u64 << (n - 64);
                    self.bit_registers = if *b != 0 { self.bit_registers | bit } else { self.bit_registers & !bit };
                }
                (InField::IntRegister(n), Value::I32(i)) => self.int_registers[*n] = *i,
                (InField::DoubleRegister(n), Value::F64(d)) => self.double_registers[*n] = *d,
                _ => {}
            }
        }
        if wrote {
            self.report.analog_writes += 1;
        }
        if bad {
            self.report.garbage += 1;
        }
    }

    /// A script received on the primary port.
    fn script(&mut self, s: &Arc<Shared>, text: String) {
        let program = parse_program(&text);
        self.report.scripts.push(text);
        let program = match program {
            Program::None => return,
            Program::Malformed => return self.report.garbage += 1,
            Program::Def(p) => p,
        };
        if self.program_running {
            self.end_program();
        }
        if self.safety_mode != SAFETY_NORMAL && self.safety_mode != 2 {
            // A controller in a protective stop runs no program.
            return;
        }
        let Some((host, port)) = program.reverse else { return };
        self.program_gen += 1;
        self.program_running = true;
        self.runtime_state = RUNTIME_PLAYING;
        self.control_mode = MODE_UNINITIALIZED;
        self.servo_args = Some((program.lookahead_time, program.gain));
        let generation = self.program_gen;
        let s2 = s.clone();
        match std::thread::Builder::new().name("fake-ur-program".into()).spawn(move || run_program(&s2, generation, &host, port)) {
            Ok(h) => s.threads.lock().unwrap_or_else(|e| e.into_inner()).push(h),
            Err(_) => self.end_program(),
        }
    }

    /// One 8 × i32 message of program `generation`; false when it ends the program.
    fn reverse_message(&mut self, f: [i32; 8], timeout_ms: &mut i32) -> bool {
        if f[0] < 0 {
            self.report.garbage += 1;
            return true;
        }
        match f[7] {
            MODE_STOPPED => {
                self.report.clean_stops += 1;
                self.end_program();
                return false;
            }
            MODE_SERVOJ => {
                if self.control_mode != MODE_SERVOJ {
                    // A new mode starts from the actual joints (§2.4).
                    self.control_mode = MODE_SERVOJ;
                    self.target = self.q;
                    self.motion = Motion::Servo;
                }
                let mut q = [0.0; JOINTS];
                for (j, v) in q.iter_mut().enumerate() {
                    *v = f64::from(f[j + 1]) / MULT_JOINTSTATE;
                }
                let dt = self.opts.step;
                if q.iter().zip(&self.target).any(|(n, c)| (n - c).abs() / dt > JOINT_IGNORE_SPEED) {
                    self.report.violations += 1;
                } else {
                    self.target = q;
                    self.fresh = true;
                }
                self.motion = Motion::Servo;
            }
            MODE_IDLE => {
                if self.control_mode != MODE_IDLE {
                    self.control_mode = MODE_IDLE;
                    self.stop_arm();
                }
            }
            _ => {
                self.report.garbage += 1;
                return true;
            }
        }
        *timeout_ms = f[0];
        true
    }
}

/// What a script holds.
enum Program {
    /// No `def` program (a `sec` program or single statements): stored only.
    None,
    /// A `def` without its `end` or the final newline.
    Malformed,
    Def(ProgramInfo),
}

struct ProgramInfo {
    reverse: Option<(String, u16)>,
    lookahead_time: Option<f64>,
    gain: Option<f64>,
}

/// A line without its comment (`#` outside a string).
fn code_of(line: &str) -> &str {
    let mut quoted = false;
    for (i, c) in line.char_indices() {
        match c {
            '"' => quoted = !quoted,
            '#' if !quoted => return &line[..i],
            _ => {}
        }
    }
    line
}

fn parse_program(text: &str) -> Program {
    let lines: Vec<&str> = text.lines().map(code_of).collect();
    let Some(def) = lines.iter().position(|l| {
        let t = l.trim();
        t.starts_with("def ") && t.ends_with(':')
    }) else {
        return Program::None;
    };
    if !text.ends_with('\n') || !lines[def + 1..].iter().any(|l| l.trim() == "end") {
        return Program::Malformed;
    }
    let code = lines.join("\n");
    let reverse = lines.iter().enumerate().find_map(|(i, l)| {
        let at = l.find("socket_open(")?;
        Some(socket_target(&l[at + "socket_open(".len()..], &lines[..i]))
    });
    Program::Def(ProgramInfo {
        reverse: reverse.flatten(),
        lookahead_time: number_after(&code, "lookahead_time"),
        gain: number_after(&code, "gain"),
    })
}

/// HOST and PORT of `socket_open(` arguments: literals, or names assigned a literal earlier.
fn socket_target(args: &str, before: &[&str]) -> Option<(String, u16)> {
    let mut parts = Vec::new();
    let (mut cur, mut quoted) = (String::new(), false);
    for c in args.chars() {
        match c {
            '"' => {
                quoted = !quoted;
                cur.push(c);
            }
            ',' | ')' if !quoted => {
                parts.push(cur.trim().to_string());
                cur.clear();
                if c == ')' || parts.len() == 2 {
                    break;
                }
            }
            _ => cur.push(c),
        }
    }
    let resolve = |arg: &str| -> Option<String> {
        if arg.starts_with('"') || arg.parse::<u16>().is_ok() {
            return Some(arg.to_string());
        }
        // The last assignment `name = literal` before the call.
        before.iter().rev().find_map(|l| {
            let t = l.trim();
            let t = t.strip_prefix("global ").or_else(|| t.strip_prefix("local ")).unwrap_or(t);
            let (lhs, rhs) = t.split_once('=')?;
            (lhs.trim() == arg && !rhs.starts_with('=')).then(|| rhs.trim().to_string())
        })
    };
    let host = resolve(parts.first()?)?;
    let host = host.strip_prefix('"')?.strip_suffix('"')?.to_string();
    let port = resolve(parts.get(1)?)?.parse::<u16>().ok()?;
    Some((host, port))
}

/// The number after the first `key=` (spaces allowed around `=`), `key` not part of a longer name.
fn number_after(code: &str, key: &str) -> Option<f64> {
    let mut from = 0;
    while let Some(at) = code[from..].find(key).map(|a| a + from) {
        from = at + key.len();
        let before_ok = code[..at].chars().next_back().is_none_or(|c| !(c.is_alphanumeric() || c == '_'));
        let rest = code[from..].trim_start();
        if before_ok && let Some(rest) = rest.strip_prefix('=') {
            let rest = rest.trim_start();
            let end = rest.find(|c: char| !(c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '+' | '-'))).unwrap_or(rest.len());
            if let Ok(v) = rest[..end].parse() {
                return Some(v);
            }
        }
    }
    None
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

/// One RTDE client: packages split or merged across reads.
fn rtde_session(s: &Shared, mut stream: TcpStream, id: u64) {
    let fd = stream.as_raw_fd();
    let mut acc: Vec<u8> = Vec::with_capacity(4096);
    let mut buf = [0u8; 4096];
    'conn: while !s.stop.load(Ordering::Relaxed) {
        if !readable(fd, SLICE_NS) {
            if s.lock().session(id).is_none_or(|x| x.conn.dead) {
                break;
            }
            continue;
        }
        let n = match stream.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => continue,
            Err(_) => break,
        };
        acc.extend_from_slice(&buf[..n]);
        let mut at = 0;
        let mut st = s.lock();
        while acc.len() - at >= 3 {
            let size = usize::from(u16::from_be_bytes([acc[at], acc[at + 1]]));
            if size < 3 {
                st.report.garbage += 1;
                break 'conn;
            }
            if acc.len() - at < size {
                break;
            }
            st.rtde_package(id, acc[at + 2], &acc[at + 3..at + size]);
            at += size;
        }
        drop(st);
        acc.drain(..at);
    }
    let mut st = s.lock();
    if let Some(i) = st.sessions.iter().position(|x| x.id == id) {
        let x = st.sessions.remove(i);
        let _ = x.conn.stream.shutdown(Shutdown::Both);
    }
    st.owners.retain(|(_, o)| *o != id);
}

/// A primary-port connection: each stretch of text up to 100 ms of silence or the close is a script.
fn read_scripts(s: &Arc<Shared>, mut stream: TcpStream) {
    let fd = stream.as_raw_fd();
    let mut text: Vec<u8> = Vec::new();
    let mut buf = [0u8; 4096];
    let mut last = monotonic_ns();
    let mut overflow = false;
    let mut open = true;
    while open && !s.stop.load(Ordering::Relaxed) {
        let idle = last + SCRIPT_IDLE_NS;
        let now = monotonic_ns();
        let mut done = now >= idle;
        if !done && readable(fd, (idle - now).min(SLICE_NS)) {
            match stream.read(&mut buf) {
                Ok(0) => (done, open) = (true, false),
                Ok(n) => {
                    last = monotonic_ns();
                    if text.len() + n > MAX_SCRIPT_LEN {
                        overflow = true;
                    } else {
                        text.extend_from_slice(&buf[..n]);
                    }
                }
                Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => {}
                Err(_) => (done, open) = (true, false),
            }
        }
        if done {
            if overflow {
                s.lock().report.garbage += 1;
            } else if !text.is_empty() {
                let t = String::from_utf8_lossy(&text).into_owned();
                s.lock().script(s, t);
            }
            text.clear();
            overflow = false;
            last = monotonic_ns();
        }
    }
    let _ = stream.shutdown(Shutdown::Both);
}

/// The program's reverse-interface side: connect back, then the §2.7 loop.
fn run_program(s: &Shared, generation: u64, host: &str, port: u16) {
    let ended = |s: &Shared| s.stop.load(Ordering::Relaxed) || s.lock().program_gen != generation;
    let retry = Duration::from_secs_f64(CONNECT_RETRY);
    let mut stream = None;
    'attempts: for attempt in 0..CONNECT_ATTEMPTS {
        if ended(s) {
            return;
        }
        if attempt > 0 {
            std::thread::sleep(retry);
        }
        for addr in (host, port).to_socket_addrs().into_iter().flatten() {
            if let Ok(c) = TcpStream::connect_timeout(&addr, retry) {
                stream = Some(c);
                break 'attempts;
            }
        }
    }
    let Some(mut stream) = stream else {
        let mut st = s.lock();
        if st.program_gen == generation {
            st.end_program();
        }
        return;
    };
    let _ = stream.set_nodelay(true);
    {
        let mut st = s.lock();
        if st.program_gen != generation {
            return;
        }
        st.reverse = stream.try_clone().ok();
    }
    let fd = stream.as_raw_fd();
    let step_ns = (s.lock().opts.step * 1e9).round().max(1.0) as u64;
    let t0 = s.lock().t0;
    let mut timeout_ms: i32 = 0; // the first read blocks
    loop {
        let start = monotonic_ns();
        let deadline = (timeout_ms > 0).then(|| {
            // The first controller step at or after the timeout.
            let d = start + timeout_ms as u64 * 1_000_000 - t0;
            t0 + d.div_ceil(step_ns) * step_ns
        });
        let mut msg = [0u8; 32];
        let mut have = 0;
        let complete = loop {
            if ended(s) {
                return;
            }
            let now = monotonic_ns();
            let wait = match deadline {
                Some(d) if now >= d => break false,
                Some(d) => (d - now).min(SLICE_NS),
                None => SLICE_NS,
            };
            if !readable(fd, wait) {
                continue;
            }
            match stream.read(&mut msg[have..]) {
                Ok(0) => break false,
                Ok(n) => {
                    have += n;
                    if have == msg.len() {
                        break true;
                    }
                }
                Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => {}
                Err(_) => break false,
            }
        };
        let mut st = s.lock();
        if st.program_gen != generation {
            return;
        }
        if !complete {
            st.report.timeouts += 1;
            st.end_program();
            return;
        }
        let mut f = [0i32; 8];
        for (i, v) in f.iter_mut().enumerate() {
            *v = i32::from_be_bytes([msg[4 * i], msg[4 * i + 1], msg[4 * i + 2], msg[4 * i + 3]]);
        }
        if !st.reverse_message(f, &mut timeout_ms) {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;
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
            &[&pkg(V, &[0, 2])[..], &pkg(VERSION, &[]), &pkg(SETUP_OUTPUTS, &[&250f64.to_be_bytes()[..], b"actual_q"].concat())[..5]]
                .concat(),
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
}
