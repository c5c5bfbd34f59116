//! RTDE's bytes (Universal Robots' Real-Time Data Exchange, TCP 30004, protocol version 2), from
//! `docs/protocols/ur.md` §1: every package `u16 size | u8 type | payload`, big-endian, the size
//! counting the header; the setup packages (protocol version, controller version, output and
//! input recipes, start, pause) and the data packages laid out by their recipe. Sans-IO: the link
//! feeds the stream in and writes what these functions encode.

/// Package types (ASCII letters).
pub mod kind {
    /// Request protocol version (`V`).
    pub(crate) const PROTOCOL_VERSION: u8 = b'V';
    /// Controller version (`v`).
    pub(crate) const URCONTROL_VERSION: u8 = b'v';
    /// Text message (`M`).
    pub(crate) const TEXT_MESSAGE: u8 = b'M';
    /// Data package (`U`).
    pub const DATA: u8 = b'U';
    /// Output recipe setup (`O`).
    pub(crate) const SETUP_OUTPUTS: u8 = b'O';
    /// Input recipe setup (`I`).
    pub(crate) const SETUP_INPUTS: u8 = b'I';
    /// Start the stream (`S`).
    pub const START: u8 = b'S';
    /// Pause the stream (`P`).
    pub const PAUSE: u8 = b'P';
}

/// The outputs strand reads each cycle, in this order.
pub const OUTPUTS: [&str; 8] =
    ["timestamp", "actual_q", "actual_qd", "robot_mode", "safety_mode", "runtime_state", "speed_scaling", "target_speed_fraction"];
/// Their types as the controller must name them.
pub(crate) const OUTPUT_TYPES: [&str; 8] = ["DOUBLE", "VECTOR6D", "VECTOR6D", "INT32", "INT32", "UINT32", "DOUBLE", "DOUBLE"];
/// The inputs strand writes (the standard analog output for the extruder).
pub const INPUTS: [&str; 4] =
    ["standard_analog_output_mask", "standard_analog_output_type", "standard_analog_output_0", "standard_analog_output_1"];
/// Their types.
pub(crate) const INPUT_TYPES: [&str; 4] = ["UINT8", "UINT8", "DOUBLE", "DOUBLE"];

/// A package that is not RTDE, or not what the recipe says; a recipe the controller refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct RtdeError(pub String);

use crate::protocol::Frame;

/// Encodes a package into `out` (cleared first).
pub fn encode(out: &mut Vec<u8>, kind: u8, payload: &[u8]) {
    out.clear();
    out.extend_from_slice(&((payload.len() + 3) as u16).to_be_bytes());
    out.push(kind);
    out.extend_from_slice(payload);
}

/// The output recipe setup at `frequency` (Hz).
pub(crate) fn setup_outputs(out: &mut Vec<u8>, frequency: f64) {
    let mut p = frequency.to_be_bytes().to_vec();
    p.extend_from_slice(OUTPUTS.join(",").as_bytes());
    encode(out, kind::SETUP_OUTPUTS, &p);
}

/// The input recipe setup.
pub(crate) fn setup_inputs(out: &mut Vec<u8>) {
    encode(out, kind::SETUP_INPUTS, INPUTS.join(",").as_bytes());
}

/// A data package for the input recipe `id`: analog output `pin` (0 or 1) to `ratio` (0..1) in
/// the voltage domain (`voltage`) or the current domain.
pub fn analog_output(out: &mut Vec<u8>, id: u8, pin: u8, voltage: bool, ratio: f64) {
    let mut p = Vec::with_capacity(19);
    p.push(id);
    p.push(1 << pin);
    p.push(if voltage { 1 << pin } else { 0 });
    let ratio = if ratio.is_finite() { ratio.clamp(0.0, 1.0) } else { 0.0 };
    for k in 0..2 {
        p.extend_from_slice(&(if k == pin { ratio } else { 0.0 }).to_be_bytes());
    }
    encode(out, kind::DATA, &p);
}

/// Where the next package ends in the RTDE stream: its size is its first two bytes (big-endian,
/// header included). RTDE has no start byte to resynchronise on, so a size below the header's
/// loses the stream (for [`crate::protocol::RobotProtocol::frame`] in a
/// [`strand_robot::channel::StreamBuffer`]).
pub fn frame(b: &[u8]) -> Frame {
    if b.len() < 3 {
        return Frame::Incomplete;
    }
    match u16::from_be_bytes([b[0], b[1]]) as usize {
        size if size < 3 => Frame::Lost(format!("an RTDE package of size {size}")),
        size => Frame::Packet(size),
    }
}

/// The type of a package and its payload.
pub fn split(package: &[u8]) -> (u8, &[u8]) {
    (package.get(2).copied().unwrap_or(0), package.get(3..).unwrap_or(&[]))
}

/// A recipe setup's answer: its id, and the types (checked against `want`, a name that is
/// `NOT_FOUND` or `IN_USE` named).
pub fn recipe(payload: &[u8], names: &[&str], want: &[&str]) -> Result<u8, RtdeError> {
    let fail = |why: String| Err(RtdeError(why));
    let Some((&id, types)) = payload.split_first() else {
        return fail("an empty recipe answer".into());
    };
    let types = String::from_utf8_lossy(types);
    let got: Vec<&str> = types.split(',').collect();
    if got.len() != names.len() {
        return fail(format!("{} types for {} names: {types}", got.len(), names.len()));
    }
    for ((name, t), w) in names.iter().zip(&got).zip(want) {
        match *t {
            "NOT_FOUND" => return fail(format!("the controller does not know {name} (NOT_FOUND): too old a software version?")),
            "IN_USE" => return fail(format!("{name} is IN_USE: another RTDE client, a fieldbus or a URCap writes it")),
            t if t != *w => return fail(format!("{name} is {t}, not {w}")),
            _ => {}
        }
    }
    if id == 0 {
        return fail(format!("recipe id 0: the controller refused the recipe ({types})"));
    }
    Ok(id)
}

/// What the robot says each cycle (the output recipe [`OUTPUTS`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct RobotData {
    /// Controller time (s since its start).
    pub timestamp: f64,
    /// Joint positions (rad).
    pub actual_q: [f64; 6],
    /// Joint velocities (rad/s).
    pub actual_qd: [f64; 6],
    /// `robot_mode` (7: RUNNING).
    pub robot_mode: i32,
    /// `safety_mode` (1: NORMAL, 2: REDUCED, 3: PROTECTIVE_STOP …).
    pub safety_mode: i32,
    /// `runtime_state` (2: PLAYING).
    pub runtime_state: u32,
    /// The trajectory limiter's speed scaling (0..1).
    pub speed_scaling: f64,
    /// The speed slider (0..1).
    pub target_speed_fraction: f64,
}

/// Bytes of a data package of the output recipe: type, id, 8 + 48 + 48 + 4 + 4 + 4 + 8 + 8.
pub(crate) const DATA_LEN: usize = 3 + 1 + 132;

/// Reads a data package of output recipe `id`.
pub(crate) fn read_data(package: &[u8], id: u8) -> Result<RobotData, RtdeError> {
    let (k, p) = split(package);
    if k != kind::DATA {
        return Err(RtdeError(format!("package type {:?}, not a data package", k as char)));
    }
    if package.len() != DATA_LEN {
        return Err(RtdeError(format!("a data package of {} bytes; the recipe's are {DATA_LEN}", package.len())));
    }
    if p[0] != id {
        return Err(RtdeError(format!("recipe {} in a data package; the output recipe is {id}", p[0])));
    }
    let f = |at: usize| f64::from_be_bytes(p[at..at + 8].try_into().unwrap_or_default());
    let i = |at: usize| i32::from_be_bytes(p[at..at + 4].try_into().unwrap_or_default());
    let mut d = RobotData { timestamp: f(1), ..Default::default() };
    for k in 0..6 {
        d.actual_q[k] = f(9 + 8 * k);
        d.actual_qd[k] = f(57 + 8 * k);
    }
    d.robot_mode = i(105);
    d.safety_mode = i(109);
    d.runtime_state = i(113) as u32;
    d.speed_scaling = f(117);
    d.target_speed_fraction = f(125);
    Ok(d)
}

/// `robot_mode`'s name.
pub(crate) fn robot_mode_name(m: i32) -> String {
    let n = ["DISCONNECTED", "CONFIRM_SAFETY", "BOOTING", "POWER_OFF", "POWER_ON", "IDLE", "BACKDRIVE", "RUNNING", "UPDATING_FIRMWARE"];
    match m {
        -1 => "NO_CONTROLLER".into(),
        0..=8 => n[m as usize].into(),
        m => format!("robot mode {m}"),
    }
}

/// `safety_mode`'s name.
pub(crate) fn safety_mode_name(m: i32) -> String {
    let n = [
        "NORMAL",
        "REDUCED",
        "PROTECTIVE_STOP",
        "RECOVERY",
        "SAFEGUARD_STOP",
        "SYSTEM_EMERGENCY_STOP",
        "ROBOT_EMERGENCY_STOP",
        "VIOLATION",
        "FAULT",
        "VALIDATE_JOINT_ID",
        "UNDEFINED_SAFETY_MODE",
        "AUTOMATIC_MODE_SAFEGUARD_STOP",
        "SYSTEM_THREE_POSITION_ENABLING_STOP",
        "TP_THREE_POSITION_ENABLING_STOP",
        "IMMI_EMERGENCY_STOP",
        "IMMI_SAFEGUARD_STOP",
        "PROFISAFE_WAITING_FOR_PARAMETERS",
        "PROFISAFE_AUTOMATIC_MODE_SAFEGUARD_STOP",
        "PROFISAFE_SAFEGUARD_STOP",
        "PROFISAFE_EMERGENCY_STOP",
    ];
    match m {
        1..=20 => format!("{} ({m})", n[m as usize - 1]),
        22 => "SAFETY_API_SAFEGUARD_STOP (22)".into(),
        m => format!("safety mode {m}"),
    }
}

/// `runtime_state`'s name.
pub(crate) fn runtime_state_name(s: u32) -> String {
    let n = ["STOPPING", "STOPPED", "PLAYING", "PAUSING", "PAUSED", "RESUMING"];
    n.get(s as usize).map_or_else(|| format!("runtime state {s}"), |n| n.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_notes_byte_examples() {
        let mut out = Vec::new();
        encode(&mut out, kind::PROTOCOL_VERSION, &2u16.to_be_bytes());
        assert_eq!(out, [0x00, 0x05, 0x56, 0x00, 0x02]);
        encode(&mut out, kind::URCONTROL_VERSION, &[]);
        assert_eq!(out, [0x00, 0x03, 0x76]);
        // Analog out 0 to a voltage ratio of 0.5 with input recipe 1 (out 1 untouched: its mask bit is 0).
        analog_output(&mut out, 1, 0, true, 0.5);
        assert_eq!(&out[..14], &[0x00, 0x16, 0x55, 0x01, 0x01, 0x01, 0x3f, 0xe0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(out.len(), 0x16);
    }

    #[test]
    fn a_data_package_reads_back_and_recipes_are_checked() {
        let mut p = vec![1u8];
        p.extend_from_slice(&12.5f64.to_be_bytes());
        for k in 0..12 {
            p.extend_from_slice(&(k as f64 * 0.1).to_be_bytes());
        }
        p.extend_from_slice(&7i32.to_be_bytes());
        p.extend_from_slice(&1i32.to_be_bytes());
        p.extend_from_slice(&2u32.to_be_bytes());
        p.extend_from_slice(&0.5f64.to_be_bytes());
        p.extend_from_slice(&1.0f64.to_be_bytes());
        let mut out = Vec::new();
        encode(&mut out, kind::DATA, &p);
        let d = read_data(&out, 1).unwrap();
        assert_eq!((d.timestamp, d.robot_mode, d.safety_mode, d.runtime_state, d.speed_scaling), (12.5, 7, 1, 2, 0.5));
        assert!((d.actual_q[5] - 0.5).abs() < 1e-15 && (d.actual_qd[0] - 0.6).abs() < 1e-15);
        assert!(read_data(&out, 2).is_err() && read_data(&out[..out.len() - 1], 1).is_err());
        let mut answer = vec![1u8];
        answer.extend_from_slice(OUTPUT_TYPES.join(",").as_bytes());
        assert_eq!(recipe(&answer, &OUTPUTS, &OUTPUT_TYPES), Ok(1));
        let mut bad = vec![1u8];
        bad.extend_from_slice(b"DOUBLE,VECTOR6D,VECTOR6D,INT32,INT32,UINT32,NOT_FOUND,DOUBLE");
        assert!(recipe(&bad, &OUTPUTS, &OUTPUT_TYPES).unwrap_err().0.contains("speed_scaling"));
        assert_eq!(safety_mode_name(3), "PROTECTIVE_STOP (3)");
    }

    #[test]
    fn the_framer_waits_for_whole_packages() {
        let mut f = strand_robot::channel::StreamBuffer::default();
        f.push(&[0x00, 0x05]);
        assert_eq!(f.next_len(frame), Ok(None));
        f.push(&[0x56, 0x01, 0x00, 0x00]);
        assert_eq!(f.next_len(frame), Ok(Some(5)));
        f.consume(5);
        assert_eq!(f.next_len(frame), Ok(None));
        f.push(&[0x00, 0x01, 0x00]);
        assert!(f.next_len(frame).unwrap_err().0.contains("an RTDE package of size 0"));
    }
}
