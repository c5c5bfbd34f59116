//! RTDE, the controller's side of it: the packages and the recipes' fields encoded and decoded
//! by hand (big-endian), a client's connection and session, and what the controller does with each
//! package a client sends.

use std::io::Read;
use std::net::{Shutdown, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::Ordering;

use super::controller::State;
use super::{CB3_MAX_FREQUENCY, JOINTS, MAX_NAMES_LEN, RTDE_PROTOCOL_VERSION, SLICE_NS, Shared, URE_MAX_FREQUENCY, peer_gone, readable};

/// Bytes queued for an RTDE client that does not read before it is dropped.
const OUT_LIMIT: usize = 1 << 20;

pub(super) const V: u8 = b'V';
pub(super) const VERSION: u8 = b'v';
pub(super) const TEXT: u8 = b'M';
pub(super) const DATA: u8 = b'U';
pub(super) const SETUP_OUTPUTS: u8 = b'O';
pub(super) const SETUP_INPUTS: u8 = b'I';
pub(super) const START: u8 = b'S';
pub(super) const PAUSE: u8 = b'P';

/// An RTDE output the fake knows (§1.7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum OutField {
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
    pub(super) fn of(name: &str) -> Option<OutField> {
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

    pub(super) fn encode(self, s: &Snapshot, out: &mut Vec<u8>) {
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
pub(super) enum InField {
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
pub(super) fn package(ty: u8, payload: &[u8]) -> Vec<u8> {
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
pub(super) struct Conn {
    pub(super) stream: TcpStream,
    pub(super) pending: Vec<u8>,
    pub(super) dead: bool,
}

impl Conn {
    pub(super) fn push(&mut self, bytes: &[u8]) {
        if !self.dead {
            self.pending.extend_from_slice(bytes);
            self.flush();
        }
    }

    pub(super) fn flush(&mut self) {
        if !self.dead && !crate::fake::send_pending(self.stream.as_raw_fd(), &mut self.pending, OUT_LIMIT) {
            self.dead = true;
        }
        if self.dead {
            self.pending = Vec::new();
            let _ = self.stream.shutdown(Shutdown::Both);
        }
    }
}

/// The output recipe of a session.
pub(super) enum Outputs {
    None,
    Invalid,
    Valid(Vec<OutField>),
}

/// One RTDE client.
pub(super) struct Session {
    pub(super) id: u64,
    pub(super) conn: Conn,
    pub(super) outputs: Outputs,
    pub(super) frequency: f64,
    pub(super) inputs: Vec<(u8, Vec<InField>)>,
    pub(super) next_input_id: u8,
    pub(super) started: bool,
    pub(super) told: bool,
    pub(super) phase: f64,
}

/// The controller state the RTDE stream shows.
pub(super) struct Snapshot {
    pub(super) time: f64,
    pub(super) q: [f64; JOINTS],
    pub(super) qd: [f64; JOINTS],
    pub(super) target_q: [f64; JOINTS],
    pub(super) robot_mode: i32,
    pub(super) safety_mode: i32,
    pub(super) runtime_state: u32,
    pub(super) speed_scaling: f64,
    pub(super) speed_fraction: f64,
    pub(super) program_running: bool,
}

impl State {
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
}

/// One RTDE client: packages split or merged across reads.
pub(super) fn rtde_session(s: &Shared, mut stream: TcpStream, id: u64) {
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
