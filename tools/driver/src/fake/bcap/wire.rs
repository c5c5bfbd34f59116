//! The fake's own b-CAP codec, written from the doc and not shared with the driver: the packet
//! (§1.2) and VARIANT (§2) encodings, little-endian by hand, the constants they use, and the
//! framing that finds a packet in a TCP stream (§1.3).

/// Start of a packet.
pub const SOH: u8 = 0x01;
/// End of a packet.
pub const EOT: u8 = 0x04;
/// The smallest packet (bytes): no arguments.
pub const MIN_PACKET: usize = 16;
/// The largest packet taken (bytes); a longer length field is garbage.
pub const MAX_PACKET: usize = 16 << 20;
/// Joints in a slave-mode pose (J type).
pub const MAX_JOINTS: usize = 8;

/// Function IDs (§3.1).
pub mod func {
    /// Service_Start.
    pub(crate) const SERVICE_START: u32 = 1;
    /// Service_Stop.
    pub(crate) const SERVICE_STOP: u32 = 2;
    /// Controller_Connect.
    pub(crate) const CONTROLLER_CONNECT: u32 = 3;
    /// Controller_Disconnect.
    pub(crate) const CONTROLLER_DISCONNECT: u32 = 4;
    /// Controller_GetRobot.
    pub(crate) const CONTROLLER_GET_ROBOT: u32 = 7;
    /// Controller_GetRobotNames.
    pub(crate) const CONTROLLER_GET_ROBOT_NAMES: u32 = 13;
    /// Controller_Execute.
    pub(crate) const CONTROLLER_EXECUTE: u32 = 17;
    /// Robot_Execute.
    pub(crate) const ROBOT_EXECUTE: u32 = 64;
    /// Robot_Release.
    pub(crate) const ROBOT_RELEASE: u32 = 84;
}

/// HRESULTs (§5), as the u32 in the packet.
pub mod hr {
    /// Success.
    pub const S_OK: u32 = 0;
    /// Interim "still running" packet.
    pub(crate) const S_EXECUTING: u32 = 0x0000_0900;
    /// slvMove accepted, the buffer is now full.
    pub const S_BUF_FULL: u32 = 0x0F20_0501;
    /// InvokeTimeout passed.
    pub(crate) const E_TIMEOUT: u32 = 0x8000_0900;
    /// Unknown Execute command.
    pub(crate) const E_INVALID_CMD_NAME: u32 = 0x8000_0904;
    /// Too many clients.
    pub(crate) const E_MAX_CONNECT: u32 = 0x8000_090B;
    /// ORiN object (here: provider) not found.
    pub(crate) const E_CAO_OBJECT_NOT_FOUND: u32 = 0x8000_0204;
    /// Function not implemented.
    pub(crate) const E_NOTIMPL: u32 = 0x8000_4001;
    /// Malformed packet.
    pub(crate) const E_INVALIDPACKET: u32 = 0x8001_0000;
    /// Wrong VARIANT type.
    pub(crate) const DISP_E_TYPEMISMATCH: u32 = 0x8002_0005;
    /// No authority (arm not taken).
    pub(crate) const E_ACCESSDENIED: u32 = 0x8007_0005;
    /// Invalid handle.
    pub(crate) const E_HANDLE: u32 = 0x8007_0006;
    /// Invalid argument.
    pub(crate) const E_INVALIDARG: u32 = 0x8007_0057;
    /// slvMove rejected, buffer full (not latched).
    pub(crate) const E_BUF_FULL: u32 = 0x8320_1483;
    /// Command buffer empty (client too late).
    pub(crate) const E_BUF_EMPTY: u32 = 0x8420_1482;
    /// slvMove while slave mode is off.
    pub(crate) const E_SLAVE_OFF: u32 = 0x8350_0121;
    /// Command not allowed in slave mode.
    pub(crate) const E_IN_SLAVE_MODE: u32 = 0x8350_1032;
    /// Motor is off.
    pub(crate) const E_MOTOR_OFF: u32 = 0x8150_1003;
    /// An error is pending (ClearError first).
    pub(crate) const E_ERROR_PENDING: u32 = 0x8150_1025;
    /// Command speed too large: + joint (1..8).
    pub(crate) const E_SPEED: u32 = 0x8420_4050;
    /// Command acceleration too large: + joint (1..8).
    pub(crate) const E_ACCEL: u32 = 0x8420_4040;
}

/// VARTYPEs (§2).
pub mod vt {
    /// VT_EMPTY.
    pub const EMPTY: u16 = 0;
    /// VT_NULL.
    pub(crate) const NULL: u16 = 1;
    /// VT_I2.
    pub(crate) const I2: u16 = 2;
    /// VT_I4.
    pub(crate) const I4: u16 = 3;
    /// VT_R4.
    pub(crate) const R4: u16 = 4;
    /// VT_R8.
    pub(crate) const R8: u16 = 5;
    /// VT_CY.
    pub(crate) const CY: u16 = 6;
    /// VT_DATE.
    pub(crate) const DATE: u16 = 7;
    /// VT_BSTR.
    pub(crate) const BSTR: u16 = 8;
    /// VT_ERROR.
    pub(crate) const ERROR: u16 = 10;
    /// VT_BOOL.
    pub(crate) const BOOL: u16 = 11;
    /// VT_VARIANT.
    pub(crate) const VARIANT: u16 = 12;
    /// VT_UI1.
    pub(crate) const UI1: u16 = 17;
    /// VT_UI2.
    pub(crate) const UI2: u16 = 18;
    /// VT_UI4.
    pub(crate) const UI4: u16 = 19;
    /// VT_I8.
    pub(crate) const I8: u16 = 20;
    /// VT_UI8.
    pub(crate) const UI8: u16 = 21;
    /// The array flag.
    pub(crate) const ARRAY: u16 = 0x2000;
}

/// A b-CAP VARIANT.
#[derive(Clone, Debug, PartialEq)]
pub enum Variant {
    /// VT_EMPTY.
    Empty,
    /// VT_NULL.
    Null,
    /// VT_I2.
    I2(i16),
    /// VT_I4.
    I4(i32),
    /// VT_R4.
    R4(f32),
    /// VT_R8.
    R8(f64),
    /// VT_CY.
    Cy(i64),
    /// VT_DATE (days since 1899-12-30).
    Date(f64),
    /// VT_BSTR.
    Bstr(String),
    /// VT_ERROR.
    Error(i32),
    /// VT_BOOL.
    Bool(bool),
    /// VT_UI1.
    Ui1(u8),
    /// VT_UI2.
    Ui2(u16),
    /// VT_UI4.
    Ui4(u32),
    /// VT_I8.
    I8(i64),
    /// VT_UI8.
    Ui8(u64),
    /// VT_ARRAY | element type (the first field, without VT_ARRAY): elements of that type, any for VT_VARIANT.
    Array(u16, Vec<Variant>),
}

impl Variant {
    /// An R8 array.
    pub(crate) fn r8s(values: &[f64]) -> Variant {
        Variant::Array(vt::R8, values.iter().map(|v| Variant::R8(*v)).collect())
    }

    /// Its VARTYPE.
    pub fn vt(&self) -> u16 {
        use Variant::*;
        match self {
            Empty => vt::EMPTY,
            Null => vt::NULL,
            I2(_) => vt::I2,
            I4(_) => vt::I4,
            R4(_) => vt::R4,
            R8(_) => vt::R8,
            Cy(_) => vt::CY,
            Date(_) => vt::DATE,
            Bstr(_) => vt::BSTR,
            Error(_) => vt::ERROR,
            Bool(_) => vt::BOOL,
            Ui1(_) => vt::UI1,
            Ui2(_) => vt::UI2,
            Ui4(_) => vt::UI4,
            I8(_) => vt::I8,
            Ui8(_) => vt::UI8,
            Array(e, _) => vt::ARRAY | e,
        }
    }

    /// Appends `vt, count, data` (§2).
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.vt().to_le_bytes());
        match self {
            Variant::Array(e, items) => {
                out.extend_from_slice(&(items.len() as u32).to_le_bytes());
                for item in items {
                    if *e == vt::VARIANT { item.encode(out) } else { item.data(out) }
                }
            }
            v => {
                out.extend_from_slice(&1u32.to_le_bytes());
                v.data(out);
            }
        }
    }

    /// Appends a scalar's data.
    fn data(&self, out: &mut Vec<u8>) {
        use Variant::*;
        match self {
            Empty | Null => {}
            I2(x) => out.extend_from_slice(&x.to_le_bytes()),
            I4(x) | Error(x) => out.extend_from_slice(&x.to_le_bytes()),
            R4(x) => out.extend_from_slice(&x.to_le_bytes()),
            R8(x) | Date(x) => out.extend_from_slice(&x.to_le_bytes()),
            Cy(x) | I8(x) => out.extend_from_slice(&x.to_le_bytes()),
            Bstr(s) => {
                let units: Vec<u16> = s.encode_utf16().collect();
                out.extend_from_slice(&(2 * units.len() as u32).to_le_bytes());
                units.iter().for_each(|u| out.extend_from_slice(&u.to_le_bytes()));
            }
            Bool(b) => out.extend_from_slice(&(if *b { 0xFFFFu16 } else { 0 }).to_le_bytes()),
            Ui1(x) => out.push(*x),
            Ui2(x) => out.extend_from_slice(&x.to_le_bytes()),
            Ui4(x) => out.extend_from_slice(&x.to_le_bytes()),
            Ui8(x) => out.extend_from_slice(&x.to_le_bytes()),
            Array(..) => self.encode(out),
        }
    }

    /// A handle: VT_I4 or VT_UI4.
    pub(super) fn handle(&self) -> Option<u32> {
        match self {
            Variant::I4(x) => Some(*x as u32),
            Variant::Ui4(x) => Some(*x),
            _ => None,
        }
    }

    /// An integer of any integer type (or a bool: 1/0).
    pub(super) fn int(&self) -> Option<i64> {
        use Variant::*;
        match self {
            I2(x) => Some(i64::from(*x)),
            I4(x) => Some(i64::from(*x)),
            Ui1(x) => Some(i64::from(*x)),
            Ui2(x) => Some(i64::from(*x)),
            Ui4(x) => Some(i64::from(*x)),
            I8(x) => Some(*x),
            Bool(b) => Some(i64::from(*b)),
            _ => None,
        }
    }

    pub(super) fn str(&self) -> Option<&str> {
        if let Variant::Bstr(s) = self { Some(s) } else { None }
    }
}

/// Reads little-endian fields off a slice, never past its end.
pub(super) struct Reader<'a>(pub(super) &'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        if n > self.0.len() {
            return None;
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Some(a)
    }
    fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.take(N)?.try_into().ok()
    }
    fn u16(&mut self) -> Option<u16> {
        self.array().map(u16::from_le_bytes)
    }
    fn u32(&mut self) -> Option<u32> {
        self.array().map(u32::from_le_bytes)
    }
}

/// The smallest encoding of one element of an array of `e` (None: no such array).
fn element_size(e: u16) -> Option<usize> {
    match e {
        vt::I2 | vt::UI2 | vt::BOOL => Some(2),
        vt::I4 | vt::UI4 | vt::R4 | vt::ERROR | vt::BSTR => Some(4),
        vt::I8 | vt::UI8 | vt::R8 | vt::CY | vt::DATE => Some(8),
        vt::UI1 => Some(1),
        vt::VARIANT => Some(6),
        _ => None,
    }
}

fn scalar(r: &mut Reader, t: u16) -> Option<Variant> {
    use Variant::*;
    Some(match t {
        vt::EMPTY => Empty,
        vt::NULL => Null,
        vt::I2 => I2(i16::from_le_bytes(r.array()?)),
        vt::I4 => I4(i32::from_le_bytes(r.array()?)),
        vt::R4 => R4(f32::from_le_bytes(r.array()?)),
        vt::R8 => R8(f64::from_le_bytes(r.array()?)),
        vt::CY => Cy(i64::from_le_bytes(r.array()?)),
        vt::DATE => Date(f64::from_le_bytes(r.array()?)),
        vt::ERROR => Error(i32::from_le_bytes(r.array()?)),
        vt::BOOL => Bool(r.u16()? != 0),
        vt::UI1 => Ui1(r.array::<1>()?[0]),
        vt::UI2 => Ui2(r.u16()?),
        vt::UI4 => Ui4(r.u32()?),
        vt::I8 => I8(i64::from_le_bytes(r.array()?)),
        vt::UI8 => Ui8(u64::from_le_bytes(r.array()?)),
        vt::BSTR => {
            let n = r.u32()? as usize;
            if !n.is_multiple_of(2) {
                return None;
            }
            let units: Vec<u16> = r.take(n)?.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
            Bstr(String::from_utf16_lossy(&units))
        }
        _ => return None,
    })
}

/// Decodes one `vt, count, data` (nested VARIANT arrays to `depth` 8).
pub(super) fn decode_variant(r: &mut Reader, depth: u32) -> Option<Variant> {
    let t = r.u16()?;
    let count = r.u32()? as usize;
    if t & vt::ARRAY == 0 {
        return match t {
            vt::EMPTY | vt::NULL => scalar(r, t),
            _ if count == 1 => scalar(r, t),
            _ => None,
        };
    }
    let e = t & !vt::ARRAY;
    if depth >= 8 || count.checked_mul(element_size(e)?)? > r.0.len() {
        return None;
    }
    let mut items = Vec::with_capacity(count);
    for _ in 0..count {
        items.push(if e == vt::VARIANT { decode_variant(r, depth + 1)? } else { scalar(r, e)? });
    }
    Some(Variant::Array(e, items))
}

/// A b-CAP packet: `id` is the function ID of a request, the HRESULT of a reply.
#[derive(Clone, Debug, PartialEq)]
pub struct Packet {
    /// The serial (a reply echoes its request's).
    pub serial: u16,
    /// The reserved field (TCP: 0).
    pub reserved: u16,
    /// Function ID (request) or HRESULT (reply).
    pub id: u32,
    /// The arguments (a reply: 0 or 1).
    pub args: Vec<Variant>,
}

impl Packet {
    /// The packet's bytes (§1.2).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = vec![SOH, 0, 0, 0, 0];
        out.extend_from_slice(&self.serial.to_le_bytes());
        out.extend_from_slice(&self.reserved.to_le_bytes());
        out.extend_from_slice(&self.id.to_le_bytes());
        out.extend_from_slice(&(self.args.len() as u16).to_le_bytes());
        for a in &self.args {
            let at = out.len();
            out.extend_from_slice(&[0; 4]);
            a.encode(&mut out);
            let n = (out.len() - at - 4) as u32;
            out[at..at + 4].copy_from_slice(&n.to_le_bytes());
        }
        out.push(EOT);
        let n = out.len() as u32;
        out[1..5].copy_from_slice(&n.to_le_bytes());
        out
    }

    /// Decodes exactly one whole packet (strictly against its length); `Err` carries the serial
    /// when the header is there to read it.
    pub fn decode(b: &[u8]) -> Result<Packet, Option<u16>> {
        let serial = (b.len() >= 7).then(|| u16::from_le_bytes([b[5], b[6]]));
        let bad = || serial;
        if b.len() < MIN_PACKET || b[0] != SOH || b[b.len() - 1] != EOT {
            return Err(bad());
        }
        let mut r = Reader(&b[1..b.len() - 1]);
        let len = r.u32().ok_or_else(bad)? as usize;
        if len != b.len() {
            return Err(bad());
        }
        let serial = r.u16().ok_or_else(bad)?;
        let reserved = r.u16().ok_or_else(bad)?;
        let id = r.u32().ok_or_else(bad)?;
        let argc = r.u16().ok_or_else(bad)?;
        let mut args = Vec::new();
        for _ in 0..argc {
            let n = r.u32().ok_or_else(bad)? as usize;
            let mut a = Reader(r.take(n).ok_or_else(bad)?);
            let v = decode_variant(&mut a, 0).ok_or_else(bad)?;
            if !a.0.is_empty() {
                return Err(bad());
            }
            args.push(v);
        }
        if !r.0.is_empty() {
            return Err(bad());
        }
        Ok(Packet { serial, reserved, id, args })
    }
}

/// What the front of a receive buffer holds (§1.3).
#[derive(Debug, PartialEq)]
pub(super) enum Framed {
    /// These many bytes are garbage: drop them.
    Skip(usize),
    /// A packet of this many bytes (not yet checked past its length).
    Packet(usize),
    /// More bytes needed.
    Incomplete,
}

pub(super) fn frame(rx: &[u8]) -> Framed {
    match rx.iter().position(|b| *b == SOH) {
        None if rx.is_empty() => Framed::Incomplete,
        None => Framed::Skip(rx.len()),
        Some(p) if p > 0 => Framed::Skip(p),
        Some(_) if rx.len() < 5 => Framed::Incomplete,
        Some(_) => {
            let len = u32::from_le_bytes([rx[1], rx[2], rx[3], rx[4]]) as usize;
            if !(MIN_PACKET..=MAX_PACKET).contains(&len) {
                Framed::Skip(1)
            } else if rx.len() < len {
                Framed::Incomplete
            } else {
                Framed::Packet(len)
            }
        }
    }
}
