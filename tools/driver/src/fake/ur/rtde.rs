//! RTDE, the controller's side of it: the packages and the recipes' fields encoded and decoded
//! by hand (big-endian), and a client's connection and session. What the controller does with each
//! package is `rtde_server`'s.

use std::net::{Shutdown, TcpStream};
use std::os::fd::AsRawFd;

use super::JOINTS;

/// Bytes queued for an RTDE client that does not read before it is dropped.
pub(super) const OUT_LIMIT: usize = 1 << 20;

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

    pub(super) fn type_name(self) -> &'static str {
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
pub(super) enum Value {
    U8(u8),
    U32(u32),
    I32(i32),
    F64(f64),
}

impl InField {
    pub(super) fn of(name: &str) -> Option<InField> {
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

    pub(super) fn type_name(self) -> &'static str {
        match self {
            InField::AnalogMask | InField::AnalogType | InField::DigitalMask | InField::Digital => "UINT8",
            InField::Analog(_) | InField::SliderFraction | InField::DoubleRegister(_) => "DOUBLE",
            InField::SliderMask => "UINT32",
            InField::BitRegister(_) => "BOOL",
            InField::IntRegister(_) => "INT32",
        }
    }

    pub(super) fn size(self) -> usize {
        match self.type_name() {
            "UINT8" | "BOOL" => 1,
            "UINT32" | "INT32" => 4,
            _ => 8,
        }
    }

    pub(super) fn decode(self, b: &[u8]) -> Option<Value> {
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
pub(super) fn text_message(message: &str, source: &str, level: u8) -> Vec<u8> {
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
