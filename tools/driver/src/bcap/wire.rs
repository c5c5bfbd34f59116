//! b-CAP's bytes: the packet (SOH, length, serial, HRESULT or function id, arguments, EOT), the
//! VARIANT values inside it, the stream framing with DENSO's resynchronisation, and the HRESULT
//! names — written from `docs/protocols/bcap.md` §1, §2 and §5 (itself from DENSO WAVE's MIT
//! `bcap_core` and the ORiN samples). The cycle's own packets (`slvMove` and its reply) are encoded
//! and read without allocating; the setup calls use [`Variant`].

/// Start of a packet.
pub const SOH: u8 = 0x01;
/// End of a packet.
pub const EOT: u8 = 0x04;
/// The shortest packet: header, no argument.
pub const MIN_PACKET: usize = 16;
/// The longest packet strand takes (a reply to anything it sends is far shorter; DENSO's limit is
/// 16 MB).
pub const MAX_PACKET: usize = 64 * 1024;

use crate::protocol::Frame;

/// VARTYPE codes (`docs/protocols/bcap.md` §2).
pub mod vt {
    /// No value.
    pub const EMPTY: u16 = 0;
    /// i16.
    pub(crate) const I2: u16 = 2;
    /// i32.
    pub(crate) const I4: u16 = 3;
    /// f32.
    pub(crate) const R4: u16 = 4;
    /// f64.
    pub(crate) const R8: u16 = 5;
    /// A string (u32 byte length + UTF-16LE).
    pub(crate) const BSTR: u16 = 8;
    /// An SCODE (i32).
    pub(crate) const ERROR: u16 = 10;
    /// A 2-byte boolean (true = 0xFFFF).
    pub(crate) const BOOL: u16 = 11;
    /// Nested values.
    pub(crate) const VARIANT: u16 = 12;
    /// u8.
    pub(crate) const UI1: u16 = 17;
    /// u16.
    pub(crate) const UI2: u16 = 18;
    /// u32.
    pub(crate) const UI4: u16 = 19;
    /// i64.
    pub(crate) const I8: u16 = 20;
    /// u64.
    pub(crate) const UI8: u16 = 21;
    /// OR-ed into a type for an array of it.
    pub(crate) const ARRAY: u16 = 0x2000;
}

/// Function ids strand calls (§3.1).
pub mod func {
    /// Service_Start(option).
    pub(crate) const SERVICE_START: i32 = 1;
    /// Service_Stop().
    pub(crate) const SERVICE_STOP: i32 = 2;
    /// Controller_Connect(name, provider, machine, option) → handle.
    pub(crate) const CONTROLLER_CONNECT: i32 = 3;
    /// Controller_Disconnect(handle).
    pub(crate) const CONTROLLER_DISCONNECT: i32 = 4;
    /// Controller_GetRobot(handle, name, option) → handle.
    pub(crate) const CONTROLLER_GET_ROBOT: i32 = 7;
    /// Controller_Execute(handle, command, param) → value.
    pub(crate) const CONTROLLER_EXECUTE: i32 = 17;
    /// Robot_Execute(handle, command, param) → value.
    pub(crate) const ROBOT_EXECUTE: i32 = 64;
    /// Robot_Release(handle).
    pub(crate) const ROBOT_RELEASE: i32 = 84;
}

/// HRESULTs the driver acts on (§5).
pub mod hr {
    /// Success.
    pub const S_OK: u32 = 0;
    /// An interim "still running" packet during a long call: not the reply.
    pub(crate) const S_EXECUTING: u32 = 0x0000_0900;
    /// slvMove accepted, the buffer is now full (success).
    pub const S_BUF_FULL: u32 = 0x0F20_0501;
    /// slvMove refused, the buffer was full: not an error, send again next cycle.
    pub(crate) const E_BUF_FULL: u32 = 0x8320_1483;
}

/// A b-CAP value.
#[derive(Clone, Debug, PartialEq)]
pub enum Variant {
    /// VT_EMPTY.
    Empty,
    /// VT_I2.
    I2(i16),
    /// VT_I4 (handles are sent as this).
    I4(i32),
    /// VT_UI4 (a handle from a controller that sends them unsigned).
    UI4(u32),
    /// VT_R8.
    R8(f64),
    /// VT_BSTR.
    Bstr(String),
    /// VT_BOOL.
    Bool(bool),
    /// VT_ARRAY|VT_I4.
    I4Array(Vec<i32>),
    /// VT_ARRAY|VT_R8.
    R8Array(Vec<f64>),
    /// VT_ARRAY|VT_VARIANT.
    Array(Vec<Variant>),
    /// Any other type, kept as its code (strand reads none of them).
    Other(u16),
}

impl Variant {
    /// The value as a handle or an integer (VT_I4, VT_UI4, VT_I2).
    pub(crate) fn as_i32(&self) -> Option<i32> {
        match self {
            Variant::I4(v) => Some(*v),
            Variant::UI4(v) => Some(*v as i32),
            Variant::I2(v) => Some(i32::from(*v)),
            _ => None,
        }
    }

    /// Appends the value (type, count, data) to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let head = |out: &mut Vec<u8>, t: u16, n: usize| {
            out.extend_from_slice(&t.to_le_bytes());
            out.extend_from_slice(&(n as u32).to_le_bytes());
        };
        match self {
            Variant::Empty => head(out, vt::EMPTY, 1),
            Variant::I2(v) => {
                head(out, vt::I2, 1);
                out.extend_from_slice(&v.to_le_bytes());
            }
            Variant::I4(v) => {
                head(out, vt::I4, 1);
                out.extend_from_slice(&v.to_le_bytes());
            }
            Variant::UI4(v) => {
                head(out, vt::UI4, 1);
                out.extend_from_slice(&v.to_le_bytes());
            }
            Variant::R8(v) => {
                head(out, vt::R8, 1);
                out.extend_from_slice(&v.to_le_bytes());
            }
            Variant::Bool(b) => {
                head(out, vt::BOOL, 1);
                out.extend_from_slice(&(if *b { 0xFFFFu16 } else { 0 }).to_le_bytes());
            }
            Variant::Bstr(s) => {
                head(out, vt::BSTR, 1);
                encode_bstr(s, out);
            }
            Variant::I4Array(v) => {
                head(out, vt::ARRAY | vt::I4, v.len());
                v.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
            }
            Variant::R8Array(v) => {
                head(out, vt::ARRAY | vt::R8, v.len());
                v.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
            }
            Variant::Array(v) => {
                head(out, vt::ARRAY | vt::VARIANT, v.len());
                v.iter().for_each(|x| x.encode(out));
            }
            Variant::Other(t) => head(out, *t, 0),
        }
    }
}

fn encode_bstr(s: &str, out: &mut Vec<u8>) {
    let units: Vec<u16> = s.encode_utf16().collect();
    out.extend_from_slice(&((units.len() * 2) as u32).to_le_bytes());
    units.iter().for_each(|u| out.extend_from_slice(&u.to_le_bytes()));
}

/// A packet that is not b-CAP, or not a reply strand can read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub(crate) struct WireError(pub String);

fn bad<T>(why: impl Into<String>) -> Result<T, WireError> {
    Err(WireError(why.into()))
}

/// A little-endian reader over a packet.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], WireError> {
        let end = self.at.checked_add(n).filter(|e| *e <= self.bytes.len());
        let Some(end) = end else {
            return bad(format!("cut short at byte {} (needs {n} more)", self.at));
        };
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16, WireError> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().unwrap_or_default()))
    }
    fn u32(&mut self) -> Result<u32, WireError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap_or_default()))
    }
    fn f64(&mut self) -> Result<f64, WireError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap_or_default()))
    }
}

/// Reads one value (type, count, data); `depth` bounds nested arrays.
fn decode_variant(r: &mut Reader<'_>, depth: u32) -> Result<Variant, WireError> {
    if depth > 4 {
        return bad("VARIANT arrays nested deeper than 4");
    }
    let t = r.u16()?;
    let n = r.u32()? as usize;
    // Every element takes at least a byte: a count beyond the packet is a lie, not an allocation.
    if n > r.bytes.len() {
        return bad(format!("VARIANT count {n} beyond the packet"));
    }
    let one = |_: &mut Reader<'_>| if n == 1 { Ok(()) } else { bad(format!("scalar type {t:#x} with count {n}")) };
    Ok(match t {
        vt::EMPTY | 1 => Variant::Empty,
        vt::I2 => {
            one(r)?;
            Variant::I2(r.u16()? as i16)
        }
        vt::I4 | vt::ERROR => {
            one(r)?;
            Variant::I4(r.u32()? as i32)
        }
        vt::UI4 => {
            one(r)?;
            Variant::UI4(r.u32()?)
        }
        vt::R8 => {
            one(r)?;
            Variant::R8(r.f64()?)
        }
        vt::BOOL => {
            one(r)?;
            Variant::Bool(r.u16()? != 0)
        }
        vt::BSTR => {
            one(r)?;
            let len = r.u32()? as usize;
            if !len.is_multiple_of(2) {
                return bad(format!("BSTR of odd byte length {len}"));
            }
            let raw = r.take(len)?;
            let units: Vec<u16> = raw.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
            Variant::Bstr(String::from_utf16_lossy(&units))
        }
        t if t == vt::ARRAY | vt::I4 => Variant::I4Array((0..n).map(|_| r.u32().map(|v| v as i32)).collect::<Result<_, _>>()?),
        t if t == vt::ARRAY | vt::R8 => Variant::R8Array((0..n).map(|_| r.f64()).collect::<Result<_, _>>()?),
        t if t == vt::ARRAY | vt::VARIANT => Variant::Array((0..n).map(|_| decode_variant(r, depth + 1)).collect::<Result<_, _>>()?),
        other => {
            // A type strand does not read: skip it when its size is known, else give up.
            let size = match other & !vt::ARRAY {
                vt::I2 | vt::UI2 | vt::BOOL => 2,
                vt::I4 | vt::R4 | vt::ERROR | vt::UI4 => 4,
                vt::R8 | 6 | 7 | vt::I8 | vt::UI8 => 8,
                vt::UI1 => 1,
                _ => return bad(format!("VARIANT type {other:#x} strand cannot skip")),
            };
            r.take(size * n)?;
            Variant::Other(other)
        }
    })
}

/// A reply, its header read (the value left in place).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ReplyHeader {
    /// The serial of the request it answers.
    pub serial: u16,
    /// The HRESULT (as the wire's u32).
    pub hresult: u32,
    /// Return values: 0 or 1.
    pub argc: u16,
}

/// Checks a whole packet's frame and reads its header; the arguments start at byte 15.
pub(crate) fn read_header(packet: &[u8]) -> Result<ReplyHeader, WireError> {
    if packet.len() < MIN_PACKET {
        return bad(format!("{} bytes: shorter than any b-CAP packet (16)", packet.len()));
    }
    let len = u32::from_le_bytes([packet[1], packet[2], packet[3], packet[4]]) as usize;
    if packet[0] != SOH || packet[packet.len() - 1] != EOT || len != packet.len() {
        return bad(format!(
            "not a b-CAP packet (SOH {:#04x}, length {len} of {} bytes, EOT {:#04x})",
            packet[0],
            packet.len(),
            packet[packet.len() - 1]
        ));
    }
    Ok(ReplyHeader {
        serial: u16::from_le_bytes([packet[5], packet[6]]),
        hresult: u32::from_le_bytes([packet[9], packet[10], packet[11], packet[12]]),
        argc: u16::from_le_bytes([packet[13], packet[14]]),
    })
}

/// The return value of a reply (None if it has none), its header checked by [`read_header`].
pub(crate) fn read_value(packet: &[u8]) -> Result<Option<Variant>, WireError> {
    let h = read_header(packet)?;
    if h.argc == 0 {
        return Ok(None);
    }
    let mut r = Reader { bytes: &packet[..packet.len() - 1], at: 15 };
    let size = r.u32()? as usize;
    let start = r.at;
    let v = decode_variant(&mut r, 0)?;
    if r.at - start != size {
        return bad(format!("argument length {size}, its value {} bytes", r.at - start));
    }
    Ok(Some(v))
}

/// Reads the joints (degrees, or mm) of a `slvMove` reply's value into `out` without allocating:
/// a bare VT_ARRAY|VT_R8 (receive format 0x0002), or VT_ARRAY|VT_VARIANT whose first R8 array is
/// the joints (0x0012: a time stamp first). Returns how many values it held.
pub(crate) fn read_joints(packet: &[u8], out: &mut [f64; 8]) -> Result<usize, WireError> {
    let h = read_header(packet)?;
    if h.argc != 1 {
        return bad("a slvMove reply without the robot's position");
    }
    let mut r = Reader { bytes: &packet[..packet.len() - 1], at: 15 };
    r.u32()?;
    let mut t = r.u16()?;
    let mut n = r.u32()? as usize;
    if t == vt::ARRAY | vt::VARIANT {
        // Walk the elements to the first R8 array; a time stamp (I4) before it is skipped.
        let elements = n;
        let mut found = false;
        for _ in 0..elements {
            t = r.u16()?;
            n = r.u32()? as usize;
            if t == vt::ARRAY | vt::R8 {
                found = true;
                break;
            }
            match t {
                vt::I4 | vt::UI4 | vt::ERROR if n == 1 => {
                    r.take(4)?;
                }
                _ => return bad(format!("slvMove reply: element of type {t:#x} before the joints")),
            }
        }
        if !found {
            return bad("slvMove reply: no joint array");
        }
    }
    if t != vt::ARRAY | vt::R8 {
        return bad(format!("slvMove reply: value of type {t:#x}, not the joints (R8 array)"));
    }
    if n == 0 || n > out.len() {
        return bad(format!("slvMove reply: {n} joint values (1 to 8)"));
    }
    for v in out.iter_mut().take(n) {
        *v = r.f64()?;
    }
    Ok(n)
}

/// Appends a packet's header to `out` (cleared first); finish it with [`finish`].
fn start(out: &mut Vec<u8>, serial: u16, func: i32, argc: u16) {
    out.clear();
    out.push(SOH);
    out.extend_from_slice(&[0; 4]);
    out.extend_from_slice(&serial.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&func.to_le_bytes());
    out.extend_from_slice(&argc.to_le_bytes());
}

fn finish(out: &mut Vec<u8>) {
    out.push(EOT);
    let len = (out.len() as u32).to_le_bytes();
    out[1..5].copy_from_slice(&len);
}

/// Appends one top-level argument: its byte length, then the value.
fn argument(out: &mut Vec<u8>, write: impl FnOnce(&mut Vec<u8>)) {
    let at = out.len();
    out.extend_from_slice(&[0; 4]);
    write(out);
    let size = (out.len() - at - 4) as u32;
    out[at..at + 4].copy_from_slice(&size.to_le_bytes());
}

/// Encodes a call into `out` (cleared first).
pub(crate) fn encode_call(out: &mut Vec<u8>, serial: u16, func: i32, args: &[Variant]) {
    start(out, serial, func, args.len() as u16);
    for a in args {
        argument(out, |o| a.encode(o));
    }
    finish(out);
}

/// The UTF-16LE bytes of "slvMove" as a BSTR, with its length.
const SLV_MOVE: &str = "slvMove";

/// Encodes `Robot_Execute(robot, "slvMove", joints)` into `out` (cleared first) without allocating
/// once `out` has grown: joints in degrees (mm for a linear axis), eight values, unused ones 0.
pub(crate) fn encode_slv_move(out: &mut Vec<u8>, serial: u16, robot: i32, joints: &[f64; 8]) {
    start(out, serial, func::ROBOT_EXECUTE, 3);
    argument(out, |o| {
        o.extend_from_slice(&vt::I4.to_le_bytes());
        o.extend_from_slice(&1u32.to_le_bytes());
        o.extend_from_slice(&robot.to_le_bytes());
    });
    argument(out, |o| {
        o.extend_from_slice(&vt::BSTR.to_le_bytes());
        o.extend_from_slice(&1u32.to_le_bytes());
        o.extend_from_slice(&((SLV_MOVE.len() * 2) as u32).to_le_bytes());
        for b in SLV_MOVE.bytes() {
            o.extend_from_slice(&[b, 0]);
        }
    });
    argument(out, |o| {
        o.extend_from_slice(&(vt::ARRAY | vt::R8).to_le_bytes());
        o.extend_from_slice(&8u32.to_le_bytes());
        joints.iter().for_each(|x| o.extend_from_slice(&x.to_le_bytes()));
    });
    finish(out);
}

/// Where the next packet ends in a TCP byte stream, resynchronising as DENSO's receiver does:
/// bytes before a SOH are skipped, a length below 16 or above [`MAX_PACKET`] drops that SOH, a
/// packet whose last byte is not EOT is dropped whole (for [`crate::protocol::RobotProtocol::frame`]
/// in a [`strand_robot::channel::StreamBuffer`], which counts what is skipped).
pub fn frame(b: &[u8]) -> Frame {
    if b.first() != Some(&SOH) {
        return Frame::Skip(b.iter().position(|x| *x == SOH).unwrap_or(b.len()));
    }
    if b.len() < 5 {
        return Frame::Incomplete;
    }
    let len = u32::from_le_bytes([b[1], b[2], b[3], b[4]]) as usize;
    if !(MIN_PACKET..=MAX_PACKET).contains(&len) {
        return Frame::Skip(1);
    }
    if b.len() < len {
        return Frame::Incomplete;
    }
    if b[len - 1] != EOT {
        return Frame::Skip(len);
    }
    Frame::Packet(len)
}

/// The name and meaning of an HRESULT (`docs/protocols/bcap.md` §5), for messages: `0x84201482
/// (command buffer empty: the driver was late)`.
pub fn describe(hresult: u32) -> String {
    let name = match hresult {
        0x0000_0000 => "S_OK",
        0x0000_0001 => "S_FALSE",
        0x0000_0900 => "S_EXECUTING",
        0x0F20_0501 => "S_BUF_FULL: accepted, the buffer is full",
        0x8000_0900 => "E_TIMEOUT: no reply in time",
        0x8000_0901 => "E_NO_LICENSE",
        0x8000_0902 => "E_NOT_CONNECTED: no session",
        0x8000_0903 => "E_NOT_USE",
        0x8000_0904 => "E_INVALID_CMD_NAME: unknown command",
        0x8000_0905 => "E_MAX_OBJECT: too many handles",
        0x8000_0906 => "E_ALREADY_REGISTER",
        0x8000_0909 => "E_TOO_MUCH_DATA: packet too long",
        0x8000_090B => "E_MAX_CONNECT: too many clients",
        0x8000_4001 => "E_NOTIMPL: not implemented",
        0x8000_4003 => "E_POINTER",
        0x8000_4004 => "E_ABORT: aborted",
        0x8000_4005 => "E_FAIL: unspecified failure",
        0x8000_FFFF => "E_UNEXPECTED",
        0x8001_0000 => "E_INVALIDPACKET: malformed packet",
        0x8002_0005 => "DISP_E_TYPEMISMATCH: wrong value type",
        0x8002_0008 => "DISP_E_BADVARTYPE: bad value type",
        0x8002_000A => "DISP_E_OVERFLOW: value out of range",
        0x8002_000B => "DISP_E_BADINDEX",
        0x8007_0005 => "E_ACCESSDENIED: no authority (is the arm taken by another client or the pendant?)",
        0x8007_0006 => "E_HANDLE: invalid handle",
        0x8007_000E => "E_OUTOFMEMORY",
        0x8007_0057 => "E_INVALIDARG: invalid argument",
        0x8091_00AA => "E_BUSY_PROC: a call is still running",
        0x8320_1483 => "E_BUF_FULL: the command buffer was full (sent again next cycle)",
        0x8420_1482 => "command buffer empty: a slave-mode command came too late, the arm stopped",
        0x8420_1486 => "command position generation stopped (mode switch or emergency stop)",
        0x8350_0121 => "slvMove while slave mode is off (the controller left it after an error)",
        0x8350_1032 => "not allowed in slave mode",
        0x8320_4231 => "invalid command, everything stopped",
        0x8150_1003 => "motor is off",
        0x8150_1025 => "an error is pending: clear it first",
        0x8350_106E => "motor on while it turns off",
        0x8350_0178 => "not allowed during an emergency stop",
        h @ 0x8420_4041..=0x8420_4048 => return format!("{h:#010x} (command acceleration too large, J{})", h - 0x8420_4040),
        h @ 0x8420_4051..=0x8420_4058 => return format!("{h:#010x} (command speed too large, J{})", h - 0x8420_4050),
        h @ 0x8320_4071..=0x8320_4078 => return format!("{h:#010x} (J{} beyond its software limit)", h - 0x8320_4070),
        h @ 0x8420_4081..=0x8420_40A8 => return format!("{h:#010x} (joint speed over its limit)"),
        h if h & 0xFFFF_0000 == 0x8091_0000 => return format!("{h:#010x} (the controller's OS error {})", h & 0xFFFF),
        h if h & 0x8000_0000 == 0 => return format!("{h:#010x} (success)"),
        _ => "a controller error: look it up on the pendant or with GetErrorDescription",
    };
    format!("{hresult:#010x} ({name})")
}

/// Whether a slave-mode reply lets the stream go on: success, or the buffer was full (the command
/// is sent again next cycle). Every other code means the controller stopped the arm.
pub(crate) fn keeps_streaming(hresult: u32) -> bool {
    hresult & 0x8000_0000 == 0 || hresult == hr::E_BUF_FULL
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace().filter(|t| *t != "|").map(|t| u8::from_str_radix(t, 16).unwrap()).collect()
    }

    #[test]
    fn the_notes_worked_examples_encode_to_their_bytes() {
        let mut out = Vec::new();
        encode_call(&mut out, 1, func::SERVICE_START, &[Variant::Bstr(String::new())]);
        assert_eq!(out, hex("01 1E 00 00 00 01 00 00 00 01 00 00 00 01 00 | 0A 00 00 00 08 00 01 00 00 00 00 00 00 00 | 04"));
        encode_call(&mut out, 5, func::ROBOT_EXECUTE, &[Variant::I4(0x12), Variant::Bstr("slvChangeMode".into()), Variant::I4(0x202)]);
        assert_eq!(out.len(), 84);
        assert_eq!(&out[..15], &hex("01 54 00 00 00 05 00 00 00 40 00 00 00 03 00")[..]);
        assert_eq!(&out[15..29], &hex("0A 00 00 00 03 00 01 00 00 00 12 00 00 00")[..]);
        assert_eq!(&out[29..39], &hex("24 00 00 00 08 00 01 00 00 00 1A 00 00 00")[..39 - 29]);
        assert_eq!(&out[69..83], &hex("0A 00 00 00 03 00 01 00 00 00 02 02 00 00")[..]);
        let mut joints = [0.0; 8];
        joints[1] = 12.5;
        encode_slv_move(&mut out, 9, 0x12, &joints);
        assert_eq!(out.len(), 132);
        assert_eq!(&out[57..67], &hex("46 00 00 00 05 20 08 00 00 00")[..]);
        // The same call through the general encoder: byte for byte.
        let mut general = Vec::new();
        encode_call(
            &mut general,
            9,
            func::ROBOT_EXECUTE,
            &[Variant::I4(0x12), Variant::Bstr("slvMove".into()), Variant::R8Array(joints.to_vec())],
        );
        assert_eq!(out, general);
        let err = hex("01 10 00 00 00 07 00 00 00 82 14 20 84 00 00 04");
        assert_eq!(read_header(&err), Ok(ReplyHeader { serial: 7, hresult: 0x8420_1482, argc: 0 }));
        assert!(describe(0x8420_1482).contains("too late"));
        assert!(describe(0x8420_4053).contains("speed too large, J3"));
    }

    #[test]
    fn joints_are_read_from_either_receive_format() {
        let joints: Vec<f64> = (0..8).map(|k| k as f64 * 1.5).collect();
        let mut reply = Vec::new();
        let mut value = Vec::new();
        Variant::R8Array(joints.clone()).encode(&mut value);
        start(&mut reply, 3, 0, 1);
        argument(&mut reply, |o| o.extend_from_slice(&value));
        finish(&mut reply);
        let mut out = [0.0; 8];
        assert_eq!(read_joints(&reply, &mut out), Ok(8));
        assert_eq!(out.to_vec(), joints);
        value.clear();
        Variant::Array(vec![Variant::I4(1234), Variant::R8Array(joints.clone())]).encode(&mut value);
        start(&mut reply, 3, 0, 1);
        argument(&mut reply, |o| o.extend_from_slice(&value));
        finish(&mut reply);
        out = [0.0; 8];
        assert_eq!(read_joints(&reply, &mut out), Ok(8));
        assert_eq!(out.to_vec(), joints);
        assert_eq!(read_value(&reply).unwrap(), Some(Variant::Array(vec![Variant::I4(1234), Variant::R8Array(joints)])));
    }

    #[test]
    fn the_framer_resynchronises_after_garbage_and_split_reads() {
        let mut a = Vec::new();
        encode_call(&mut a, 1, func::SERVICE_STOP, &[]);
        let mut f = strand_robot::channel::StreamBuffer::default();
        // Garbage, a SOH with a silly length, then a packet split in two, then another.
        f.push(&[0x55, 0x66, SOH, 0xFF, 0xFF, 0xFF, 0x7F]);
        f.push(&a[..7]);
        assert_eq!(f.next_len(frame), Ok(None));
        f.push(&a[7..]);
        f.push(&a);
        let n = f.next_len(frame).unwrap().unwrap();
        assert_eq!(f.packet(n), &a[..]);
        f.consume(n);
        assert_eq!(f.next_len(frame), Ok(Some(a.len())));
        assert_eq!(f.skipped(), 7);
        // A packet whose last byte is not EOT is dropped whole.
        let mut cut = a.clone();
        *cut.last_mut().unwrap() = 0;
        f.consume(a.len());
        f.push(&cut);
        f.push(&a);
        assert_eq!(f.next_len(frame), Ok(Some(a.len())));
        assert_eq!(f.skipped(), 7 + a.len() as u64);
    }

    #[test]
    fn no_bytes_make_the_reader_panic() {
        // Every prefix and a few corruptions of a real reply: an error or a value, never a panic.
        let mut reply = Vec::new();
        let mut value = Vec::new();
        Variant::Array(vec![Variant::I4(1), Variant::Bstr("x".into()), Variant::R8Array(vec![1.0; 8])]).encode(&mut value);
        start(&mut reply, 3, 0, 1);
        argument(&mut reply, |o| o.extend_from_slice(&value));
        finish(&mut reply);
        for cut in 0..reply.len() {
            let _ = read_value(&reply[..cut]);
            let mut j = [0.0; 8];
            let _ = read_joints(&reply[..cut], &mut j);
        }
        for i in 15..reply.len() - 1 {
            let mut bad = reply.clone();
            bad[i] ^= 0xFF;
            let _ = read_value(&bad);
            let mut j = [0.0; 8];
            let _ = read_joints(&bad, &mut j);
        }
    }
}
