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

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

pub mod virtual_time;

use super::{FakeReport, real_time, sleep_until};

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
    pub const SERVICE_START: u32 = 1;
    /// Service_Stop.
    pub const SERVICE_STOP: u32 = 2;
    /// Controller_Connect.
    pub const CONTROLLER_CONNECT: u32 = 3;
    /// Controller_Disconnect.
    pub const CONTROLLER_DISCONNECT: u32 = 4;
    /// Controller_GetRobot.
    pub const CONTROLLER_GET_ROBOT: u32 = 7;
    /// Controller_GetRobotNames.
    pub const CONTROLLER_GET_ROBOT_NAMES: u32 = 13;
    /// Controller_Execute.
    pub const CONTROLLER_EXECUTE: u32 = 17;
    /// Robot_Execute.
    pub const ROBOT_EXECUTE: u32 = 64;
    /// Robot_Release.
    pub const ROBOT_RELEASE: u32 = 84;
}

/// HRESULTs (§5), as the u32 in the packet.
pub mod hr {
    /// Success.
    pub const S_OK: u32 = 0;
    /// Interim "still running" packet.
    pub const S_EXECUTING: u32 = 0x0000_0900;
    /// slvMove accepted, the buffer is now full.
    pub const S_BUF_FULL: u32 = 0x0F20_0501;
    /// InvokeTimeout passed.
    pub const E_TIMEOUT: u32 = 0x8000_0900;
    /// Unknown Execute command.
    pub const E_INVALID_CMD_NAME: u32 = 0x8000_0904;
    /// Too many clients.
    pub const E_MAX_CONNECT: u32 = 0x8000_090B;
    /// ORiN object (here: provider) not found.
    pub const E_CAO_OBJECT_NOT_FOUND: u32 = 0x8000_0204;
    /// Function not implemented.
    pub const E_NOTIMPL: u32 = 0x8000_4001;
    /// Malformed packet.
    pub const E_INVALIDPACKET: u32 = 0x8001_0000;
    /// Wrong VARIANT type.
    pub const DISP_E_TYPEMISMATCH: u32 = 0x8002_0005;
    /// No authority (arm not taken).
    pub const E_ACCESSDENIED: u32 = 0x8007_0005;
    /// Invalid handle.
    pub const E_HANDLE: u32 = 0x8007_0006;
    /// Invalid argument.
    pub const E_INVALIDARG: u32 = 0x8007_0057;
    /// slvMove rejected, buffer full (not latched).
    pub const E_BUF_FULL: u32 = 0x8320_1483;
    /// Command buffer empty (client too late).
    pub const E_BUF_EMPTY: u32 = 0x8420_1482;
    /// slvMove while slave mode is off.
    pub const E_SLAVE_OFF: u32 = 0x8350_0121;
    /// Command not allowed in slave mode.
    pub const E_IN_SLAVE_MODE: u32 = 0x8350_1032;
    /// Motor is off.
    pub const E_MOTOR_OFF: u32 = 0x8150_1003;
    /// An error is pending (ClearError first).
    pub const E_ERROR_PENDING: u32 = 0x8150_1025;
    /// Command speed too large: + joint (1..8).
    pub const E_SPEED: u32 = 0x8420_4050;
    /// Command acceleration too large: + joint (1..8).
    pub const E_ACCEL: u32 = 0x8420_4040;
}

/// VARTYPEs (§2).
pub mod vt {
    /// VT_EMPTY.
    pub const EMPTY: u16 = 0;
    /// VT_NULL.
    pub const NULL: u16 = 1;
    /// VT_I2.
    pub const I2: u16 = 2;
    /// VT_I4.
    pub const I4: u16 = 3;
    /// VT_R4.
    pub const R4: u16 = 4;
    /// VT_R8.
    pub const R8: u16 = 5;
    /// VT_CY.
    pub const CY: u16 = 6;
    /// VT_DATE.
    pub const DATE: u16 = 7;
    /// VT_BSTR.
    pub const BSTR: u16 = 8;
    /// VT_ERROR.
    pub const ERROR: u16 = 10;
    /// VT_BOOL.
    pub const BOOL: u16 = 11;
    /// VT_VARIANT.
    pub const VARIANT: u16 = 12;
    /// VT_UI1.
    pub const UI1: u16 = 17;
    /// VT_UI2.
    pub const UI2: u16 = 18;
    /// VT_UI4.
    pub const UI4: u16 = 19;
    /// VT_I8.
    pub const I8: u16 = 20;
    /// VT_UI8.
    pub const UI8: u16 = 21;
    /// The array flag.
    pub const ARRAY: u16 = 0x2000;
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
    pub fn r8s(values: &[f64]) -> Variant {
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
    fn handle(&self) -> Option<u32> {
        match self {
            Variant::I4(x) => Some(*x as u32),
            Variant::Ui4(x) => Some(*x),
            _ => None,
        }
    }

    /// An integer of any integer type (or a bool: 1/0).
    fn int(&self) -> Option<i64> {
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

    fn str(&self) -> Option<&str> {
        if let Variant::Bstr(s) = self { Some(s) } else { None }
    }
}

/// Reads little-endian fields off a slice, never past its end.
struct Reader<'a>(&'a [u8]);

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
            if n % 2 != 0 {
                return None;
            }
            let units: Vec<u16> = r.take(n)?.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
            Bstr(String::from_utf16_lossy(&units))
        }
        _ => return None,
    })
}

/// Decodes one `vt, count, data` (nested VARIANT arrays to `depth` 8).
fn decode_variant(r: &mut Reader, depth: u32) -> Option<Variant> {
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
enum Framed {
    /// These many bytes are garbage: drop them.
    Skip(usize),
    /// A packet of this many bytes (not yet checked past its length).
    Packet(usize),
    /// More bytes needed.
    Incomplete,
}

fn frame(rx: &[u8]) -> Framed {
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

/// The controller's state (one lock: the tick, the session and the watch share it).
struct Ctrl {
    joints: usize,
    actual: Vec<f64>,
    target: Vec<f64>,
    /// The last two commands taken (the robot at rest at slave-mode entry: both its position).
    prev: Vec<f64>,
    prev2: Vec<f64>,
    arm_taken: bool,
    motor_on: bool,
    /// When a pending Motor on (noWait or timed out) completes (monotonic ns).
    motor_on_at: Option<u64>,
    send_fmt: u32,
    recv_fmt: u32,
    ts_us: bool,
    slave_mode: u32,
    buffer: VecDeque<[f64; MAX_JOINTS]>,
    /// A command was taken since slave mode was entered.
    streaming: bool,
    /// Commands popped by the tick (mode-2 holds wait for it to move).
    pops: u64,
    latched: Option<u32>,
    errors: Vec<u32>,
    connected: bool,
    released: bool,
    slave_ticks: u64,
    next_handle: u32,
    report: FakeReport,
    calls: Vec<String>,
    slv_moves: u64,
    buffer_full: u64,
}

impl Ctrl {
    /// A controller at `start` (degrees), disconnected, the motor off.
    fn new(start: &[f64]) -> Ctrl {
        Ctrl {
            joints: start.len(),
            actual: start.to_vec(),
            target: start.to_vec(),
            prev: start.to_vec(),
            prev2: start.to_vec(),
            arm_taken: false,
            motor_on: false,
            motor_on_at: None,
            send_fmt: 0,
            recv_fmt: 0x0002,
            ts_us: false,
            slave_mode: 0,
            buffer: VecDeque::with_capacity(4),
            streaming: false,
            pops: 0,
            latched: None,
            errors: Vec::new(),
            connected: false,
            released: false,
            slave_ticks: 0,
            next_handle: 1,
            report: FakeReport::default(),
            calls: Vec::new(),
            slv_moves: 0,
            buffer_full: 0,
        }
    }

    fn latch(&mut self, code: u32) {
        self.errors.push(code);
        self.latched = Some(code);
        self.leave_slave(true);
        if code & 0x8000_0000 != 0 && (code >> 24) & 0xF >= 4 {
            self.motor_on = false;
            self.motor_on_at = None;
        }
    }

    /// Slave mode 0, the buffer dropped; `stop`: the robot stops where it is.
    fn leave_slave(&mut self, stop: bool) {
        self.slave_mode = 0;
        self.buffer.clear();
        self.streaming = false;
        if stop {
            self.target.clone_from(&self.actual);
        }
    }

    fn enter_slave(&mut self, mode: u32) {
        self.leave_slave(false);
        self.slave_mode = mode;
        self.target.clone_from(&self.actual);
        self.prev.clone_from(&self.actual);
        self.prev2.clone_from(&self.actual);
    }

    fn resolve_motor(&mut self, now: u64) {
        if self.motor_on_at.is_some_and(|at| now >= at) {
            self.motor_on = true;
            self.motor_on_at = None;
        }
    }

    /// The error a command would latch against the previous two.
    fn check(&self, cmd: &[f64], opts: &BcapOptions) -> Option<u32> {
        let c = opts.cycle;
        let limit = |l: &[f64], j: usize| l.get(j).copied().unwrap_or(f64::INFINITY) * (1.0 + 1e-9);
        for j in 0..self.joints {
            if ((cmd[j] - self.prev[j]) / c).abs() > limit(&opts.speed_limit_deg, j) {
                return Some(hr::E_SPEED + j as u32 + 1);
            }
        }
        for j in 0..self.joints {
            if ((cmd[j] - 2.0 * self.prev[j] + self.prev2[j]) / (c * c)).abs() > limit(&opts.accel_limit_deg, j) {
                return Some(hr::E_ACCEL + j as u32 + 1);
            }
        }
        None
    }

    fn tick(&mut self, alpha: f64, opts: &BcapOptions) {
        self.resolve_motor(monotonic_ns());
        let mut row = None;
        if self.slave_mode != 0 {
            self.slave_ticks += 1;
            if let Some(cmd) = self.buffer.pop_front() {
                self.pops += 1;
                row = Some(true);
                let cmd = &cmd[..self.joints];
                match self.check(cmd, opts) {
                    Some(code) => self.latch(code),
                    None => {
                        std::mem::swap(&mut self.prev2, &mut self.prev);
                        self.prev.copy_from_slice(cmd);
                        self.target.copy_from_slice(cmd);
                        self.streaming = true;
                    }
                }
            } else if self.streaming {
                row = Some(false);
                self.latch(hr::E_BUF_EMPTY);
            }
        }
        for (a, t) in self.actual.iter_mut().zip(&self.target) {
            *a += alpha * (t - *a);
        }
        if let Some(fresh) = row {
            let r = &mut self.report;
            r.cycles += 1;
            if fresh {
                r.in_time += 1;
            } else {
                r.missing += 1;
            }
            r.fresh.push(fresh);
            r.axes.push(self.actual.clone());
        }
    }

    /// The 8 joints (degrees, unused 0).
    fn joints8(&self) -> [f64; MAX_JOINTS] {
        let mut q = [0.0; MAX_JOINTS];
        q[..self.joints].copy_from_slice(&self.actual);
        q
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
        if joints == 0 || joints > MAX_JOINTS || !(opts.cycle > 0.0) {
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

/// A successful call that matters to the release check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Step {
    SlaveOff,
    MotorOff,
    GiveArm,
    RobotRelease,
    CtrlDisconnect,
    ServiceStop,
    Other,
}

/// One client's session.
struct Session {
    wdt_ms: u64,
    invoke_timeout_ms: u64,
    ctrl: Option<u32>,
    robot: Option<u32>,
    entered_slave: bool,
    /// Successful calls, consecutive repeats merged, read-only ones left out.
    log: Vec<Step>,
}

impl Session {
    fn step(&mut self, s: Step) {
        if self.log.last() != Some(&s) {
            self.log.push(s);
        }
    }
    fn clean(&self) -> bool {
        use Step::*;
        let n = self.log.len();
        if n < 5 {
            return false;
        }
        let t = &self.log[n - 5..];
        let pair = matches!((t[0], t[1]), (MotorOff, GiveArm) | (GiveArm, MotorOff));
        pair && t[2..] == [RobotRelease, CtrlDisconnect, ServiceStop] && (!self.entered_slave || (n >= 6 && self.log[n - 6] == SlaveOff))
    }
}

fn session(inner: &Inner, mut stream: TcpStream) {
    // The replies are the controller's too: a session stalled by the host would make the client late.
    real_time(inner.opts.rt_priority);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(5)));
    let mut s = Session { wdt_ms: 0, invoke_timeout_ms: 180_000, ctrl: None, robot: None, entered_slave: false, log: Vec::new() };
    let mut rx: Vec<u8> = Vec::with_capacity(4096);
    let mut buf = vec![0u8; 65536];
    let mut last_rx = monotonic_ns();
    // Whether the client closed the connection (not the fake stopping).
    let mut closed = false;
    'session: while !inner.stopping() {
        loop {
            match frame(&rx) {
                Framed::Skip(n) => {
                    inner.lock().report.garbage += n as u64;
                    rx.drain(..n);
                }
                Framed::Packet(n) => {
                    let received = monotonic_ns();
                    let bytes: Vec<u8> = rx.drain(..n).collect();
                    if handle(inner, &mut s, &mut stream, &bytes, received).is_err() {
                        closed = true;
                        break 'session;
                    }
                    // A held reply is no stall of what follows it.
                    last_rx = monotonic_ns();
                }
                Framed::Incomplete => {
                    // A length that garbage made up must not stall the session.
                    if !rx.is_empty() && monotonic_ns().saturating_sub(last_rx) > 200_000_000 {
                        inner.lock().report.garbage += 1;
                        rx.drain(..1);
                        continue;
                    }
                    break;
                }
            }
        }
        match stream.read(&mut buf) {
            Ok(0) => {
                closed = true;
                break;
            }
            Ok(n) => {
                rx.extend_from_slice(&buf[..n]);
                last_rx = monotonic_ns();
            }
            Err(e)
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted) => {}
            Err(_) => {
                closed = true;
                break;
            }
        }
    }
    let mut c = inner.lock();
    c.connected = false;
    c.released = closed && s.clean() && c.slave_mode == 0;
    if c.slave_mode != 0 && !c.streaming {
        c.leave_slave(true);
    }
    c.arm_taken = false;
    drop(c);
    inner.cv.notify_all();
}

/// Handles one packet's bytes: a reply is written (an error if it is malformed).
fn handle(inner: &Inner, s: &mut Session, stream: &mut TcpStream, bytes: &[u8], received: u64) -> std::io::Result<()> {
    let p = match Packet::decode(bytes) {
        Ok(p) => p,
        Err(serial) => {
            inner.lock().report.garbage += 1;
            return stream.write_all(&Packet { serial: serial.unwrap_or(0), reserved: 0, id: hr::E_INVALIDPACKET, args: vec![] }.encode());
        }
    };
    let slv_move = p.id == func::ROBOT_EXECUTE && p.args.get(1).and_then(Variant::str).is_some_and(|c| c.eq_ignore_ascii_case("slvMove"));
    {
        let mut c = inner.lock();
        if slv_move {
            c.slv_moves += 1;
        } else {
            c.calls.push(call_name(&p));
        }
    }
    let (code, value) = call(inner, s, stream, &p);
    let args = match value {
        Some(v) if code & 0x8000_0000 == 0 => vec![v],
        _ => vec![],
    };
    let out = Packet { serial: p.serial, reserved: 0, id: code, args }.encode();
    let sent = stream.write_all(&out);
    if slv_move {
        inner.lock().report.round_trip.record(monotonic_ns().saturating_sub(received));
    }
    sent
}

fn call_name(p: &Packet) -> String {
    let command = || p.args.get(1).and_then(Variant::str).unwrap_or("?");
    match p.id {
        func::SERVICE_START => "Service_Start".into(),
        func::SERVICE_STOP => "Service_Stop".into(),
        func::CONTROLLER_CONNECT => "Controller_Connect".into(),
        func::CONTROLLER_DISCONNECT => "Controller_Disconnect".into(),
        func::CONTROLLER_GET_ROBOT => "Controller_GetRobot".into(),
        func::CONTROLLER_GET_ROBOT_NAMES => "Controller_GetRobotNames".into(),
        func::CONTROLLER_EXECUTE => format!("Controller_Execute({})", command()),
        func::ROBOT_EXECUTE => format!("Robot_Execute({})", command()),
        func::ROBOT_RELEASE => "Robot_Release".into(),
        id => format!("Function({id})"),
    }
}

type Answer = (u32, Option<Variant>);

fn ok(v: Variant) -> Answer {
    (hr::S_OK, Some(v))
}

fn error(code: u32) -> Answer {
    (code, None)
}

/// Parses `,WDT=400,InvokeTimeout=180000`.
fn service_options(s: &mut Session, option: &str) {
    for part in option.split(',') {
        let Some((k, v)) = part.split_once('=') else { continue };
        let Ok(v) = v.trim().parse::<u64>() else { continue };
        match k.trim().to_ascii_lowercase().as_str() {
            "wdt" => s.wdt_ms = if v == 0 { 0 } else { v.max(80) },
            "invoketimeout" => s.invoke_timeout_ms = v,
            _ => {}
        }
    }
}

fn call(inner: &Inner, s: &mut Session, stream: &mut TcpStream, p: &Packet) -> Answer {
    let a = &p.args;
    let handle_is = |i: usize, h: Option<u32>| a.get(i).and_then(Variant::handle).is_some_and(|x| Some(x) == h);
    match p.id {
        func::SERVICE_START => {
            match a.as_slice() {
                [] | [Variant::Empty] => {}
                [Variant::Bstr(o)] => service_options(s, o),
                [_] => return error(hr::DISP_E_TYPEMISMATCH),
                _ => return error(hr::E_INVALIDARG),
            }
            s.step(Step::Other);
            (hr::S_OK, None)
        }
        func::SERVICE_STOP => {
            s.step(Step::ServiceStop);
            (hr::S_OK, None)
        }
        func::CONTROLLER_CONNECT => {
            if a.len() != 4 {
                return error(hr::E_INVALIDARG);
            }
            let Some(provider) = a[1].str() else { return error(hr::DISP_E_TYPEMISMATCH) };
            if !a.iter().all(|v| v.str().is_some()) {
                return error(hr::DISP_E_TYPEMISMATCH);
            }
            if !provider.eq_ignore_ascii_case("CaoProv.DENSO.VRC") {
                return error(hr::E_CAO_OBJECT_NOT_FOUND);
            }
            let h = match s.ctrl {
                Some(h) => h,
                None => {
                    let mut c = inner.lock();
                    c.next_handle += 1;
                    c.next_handle - 1
                }
            };
            s.ctrl = Some(h);
            s.step(Step::Other);
            ok(Variant::I4(h as i32))
        }
        func::CONTROLLER_DISCONNECT => {
            if a.len() != 1 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            let mut c = inner.lock();
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            if s.robot.take().is_some() {
                c.arm_taken = false;
            }
            s.ctrl = None;
            s.step(Step::CtrlDisconnect);
            (hr::S_OK, None)
        }
        func::CONTROLLER_GET_ROBOT => {
            if a.len() != 3 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            if a[1].str().is_none() || a[2].str().is_none() {
                return error(hr::DISP_E_TYPEMISMATCH);
            }
            let h = match s.robot {
                Some(h) => h,
                None => {
                    let mut c = inner.lock();
                    c.next_handle += 1;
                    c.next_handle - 1
                }
            };
            s.robot = Some(h);
            s.step(Step::Other);
            ok(Variant::I4(h as i32))
        }
        func::CONTROLLER_GET_ROBOT_NAMES => {
            if a.is_empty() || a.len() > 2 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            ok(Variant::Array(vt::BSTR, vec![Variant::Bstr("Arm".into())]))
        }
        func::CONTROLLER_EXECUTE => {
            if a.len() != 2 && a.len() != 3 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            let Some(command) = a[1].str() else { return error(hr::DISP_E_TYPEMISMATCH) };
            let param = a.get(2).unwrap_or(&Variant::Empty);
            controller_execute(inner, command, param)
        }
        func::ROBOT_EXECUTE => {
            if a.len() != 2 && a.len() != 3 {
                return error(hr::E_INVALIDARG);
            }
            if s.ctrl.is_none() || !handle_is(0, s.robot) {
                return error(hr::E_HANDLE);
            }
            let Some(command) = a[1].str() else { return error(hr::DISP_E_TYPEMISMATCH) };
            let param = a.get(2).unwrap_or(&Variant::Empty);
            robot_execute(inner, s, stream, p.serial, command, param)
        }
        func::ROBOT_RELEASE => {
            if a.len() != 1 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.robot) {
                return error(hr::E_HANDLE);
            }
            let mut c = inner.lock();
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            c.arm_taken = false;
            s.robot = None;
            s.step(Step::RobotRelease);
            (hr::S_OK, None)
        }
        _ => error(hr::E_NOTIMPL),
    }
}

/// A description of the codes the fake knows.
fn describe(code: u32) -> String {
    let known = match code {
        hr::E_BUF_EMPTY => "Command buffer empty (command value generation delay)",
        hr::E_BUF_FULL => "Command buffer full",
        hr::E_SLAVE_OFF => "Slave move while slave mode off",
        hr::E_IN_SLAVE_MODE => "Invalid command in slave mode",
        hr::E_MOTOR_OFF => "Motor is off",
        hr::E_ERROR_PENDING => "Cannot execute while an error is pending",
        c if (hr::E_SPEED + 1..=hr::E_SPEED + 8).contains(&c) => return format!("Command speed too large (J{})", c - hr::E_SPEED),
        c if (hr::E_ACCEL + 1..=hr::E_ACCEL + 8).contains(&c) => return format!("Command acceleration too large (J{})", c - hr::E_ACCEL),
        c => return format!("Error 0x{c:08X}"),
    };
    known.into()
}

fn controller_execute(inner: &Inner, command: &str, param: &Variant) -> Answer {
    let mut c = inner.lock();
    match command.to_ascii_lowercase().as_str() {
        "clearerror" => {
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            c.latched = None;
            ok(Variant::Empty)
        }
        "geterrordescription" => {
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            match param.int() {
                Some(code) => ok(Variant::Bstr(describe(code as u32))),
                None => error(hr::DISP_E_TYPEMISMATCH),
            }
        }
        _ => error(hr::E_INVALID_CMD_NAME),
    }
}

/// `[state, noWait]` or a scalar state.
fn motor_param(param: &Variant) -> Option<(bool, bool)> {
    match param {
        Variant::Array(_, items) if !items.is_empty() && items.len() <= 2 => {
            Some((items[0].int()? != 0, items.get(1).map(Variant::int).unwrap_or(Some(0))? != 0))
        }
        v => Some((v.int()? != 0, false)),
    }
}

/// An integer format, or `[format, tsUnit]`.
fn format_param(param: &Variant) -> Option<(u32, Option<i64>)> {
    match param {
        Variant::Array(_, items) if !items.is_empty() && items.len() <= 2 => {
            Some((items[0].int()? as u32, items.get(1).map(Variant::int).unwrap_or(Some(0)).map(Some)?))
        }
        v => Some((v.int()? as u32, None)),
    }
}

fn robot_execute(inner: &Inner, s: &mut Session, stream: &mut TcpStream, serial: u16, command: &str, param: &Variant) -> Answer {
    let cmd = command.to_ascii_lowercase();
    if cmd == "slvmove" {
        return slv_move(inner, param);
    }
    if cmd == "motor" {
        return motor(inner, s, stream, serial, param);
    }
    let mut c = inner.lock();
    let answer = match cmd.as_str() {
        "takearm" | "givearm" | "slvsendformat" | "slvrecvformat" if c.slave_mode != 0 => error(hr::E_IN_SLAVE_MODE),
        "takearm" => {
            c.arm_taken = true;
            ok(Variant::Empty)
        }
        "givearm" => {
            c.arm_taken = false;
            s.step(Step::GiveArm);
            return ok(Variant::Empty);
        }
        "curjnt" => return ok(Variant::r8s(&c.joints8())),
        "highcurjntex" => {
            let mut v = vec![f64::from(inner.stamp(false))];
            v.extend_from_slice(&c.joints8());
            return ok(Variant::r8s(&v));
        }
        "slvsendformat" => match param {
            Variant::Empty => return ok(Variant::I4(c.send_fmt as i32)),
            v => match v.int() {
                Some(f) if f >= 0 && f & !(0x20 | 0x100 | 0x200) == 0 => {
                    c.send_fmt = f as u32;
                    ok(Variant::Empty)
                }
                Some(_) => error(hr::E_INVALIDARG),
                None => error(hr::DISP_E_TYPEMISMATCH),
            },
        },
        "slvrecvformat" => match param {
            Variant::Empty => return ok(Variant::I4(c.recv_fmt as i32)),
            v => match format_param(v) {
                Some((f, unit))
                    if f & 0xF == 2 && f & !(0xF | 0x10 | 0x20 | 0x40 | 0x100) == 0 && unit.is_none_or(|u| u == 0 || u == 1) =>
                {
                    c.recv_fmt = f;
                    c.ts_us = unit == Some(1);
                    ok(Variant::Empty)
                }
                Some(_) => error(hr::E_INVALIDARG),
                None => error(hr::DISP_E_TYPEMISMATCH),
            },
        },
        "slvchangemode" => {
            let Some(mode) = param.int() else { return error(hr::DISP_E_TYPEMISMATCH) };
            match mode {
                0 => {
                    if c.slave_mode != 0 {
                        c.leave_slave(false);
                    }
                    s.step(Step::SlaveOff);
                    drop(c);
                    inner.cv.notify_all();
                    return ok(Variant::Empty);
                }
                0x002 | 0x102 | 0x202 => {
                    c.resolve_motor(monotonic_ns());
                    if c.latched.is_some() {
                        error(hr::E_ERROR_PENDING)
                    } else if !c.arm_taken {
                        error(hr::E_ACCESSDENIED)
                    } else if !c.motor_on {
                        error(hr::E_MOTOR_OFF)
                    } else {
                        c.enter_slave(mode as u32);
                        s.entered_slave = true;
                        ok(Variant::Empty)
                    }
                }
                _ => error(hr::E_INVALIDARG),
            }
        }
        "slvgetmode" => return ok(Variant::I4(c.slave_mode as i32)),
        _ => return error(hr::E_INVALID_CMD_NAME),
    };
    if answer.0 & 0x8000_0000 == 0 {
        s.step(Step::Other);
    }
    answer
}

fn motor(inner: &Inner, s: &mut Session, stream: &mut TcpStream, serial: u16, param: &Variant) -> Answer {
    let Some((on, no_wait)) = motor_param(param) else { return error(hr::DISP_E_TYPEMISMATCH) };
    let now = monotonic_ns();
    let on_ns = (inner.opts.motor_on_time.max(0.0) * 1e9) as u64;
    {
        let mut c = inner.lock();
        c.resolve_motor(now);
        if !on {
            if c.slave_mode != 0 {
                c.leave_slave(true);
                s.step(Step::Other);
            }
            c.motor_on = false;
            c.motor_on_at = None;
            s.step(Step::MotorOff);
            drop(c);
            inner.cv.notify_all();
            return ok(Variant::Empty);
        }
        if c.latched.is_some() {
            return error(hr::E_ERROR_PENDING);
        }
        s.step(Step::Other);
        if c.motor_on {
            return ok(Variant::Empty);
        }
        let at = *c.motor_on_at.get_or_insert(now + on_ns);
        if no_wait {
            return ok(Variant::Empty);
        }
        drop(c);
        // Held until the motor is on or InvokeTimeout, S_EXECUTING every WDT ms meanwhile.
        let timeout = now.saturating_add(s.invoke_timeout_ms.saturating_mul(1_000_000));
        let end = at.min(timeout);
        let wdt_ns = s.wdt_ms * 1_000_000;
        let mut next_wdt = if wdt_ns > 0 { now + wdt_ns } else { u64::MAX };
        let executing = Packet { serial, reserved: 0, id: hr::S_EXECUTING, args: vec![] }.encode();
        loop {
            let t = monotonic_ns();
            if t >= end || inner.stopping() {
                break;
            }
            if t >= next_wdt {
                if stream.write_all(&executing).is_err() {
                    break;
                }
                next_wdt += wdt_ns;
            }
            sleep_until(end.min(next_wdt).min(t + 5_000_000));
        }
        if end < at {
            return error(hr::E_TIMEOUT);
        }
    }
    let mut c = inner.lock();
    let done = monotonic_ns().max(c.motor_on_at.unwrap_or(0));
    c.resolve_motor(done);
    if c.latched.is_some() && !c.motor_on {
        return error(hr::E_ERROR_PENDING);
    }
    c.motor_on = true;
    ok(Variant::Empty)
}

/// The slvMove reply value per the recv format: bare R8×8, or a VARIANT array.
fn position(inner: &Inner, c: &Ctrl) -> Variant {
    let pose = Variant::r8s(&c.joints8());
    let f = c.recv_fmt;
    if f & !0xF == 0 {
        return pose;
    }
    let mut v = Vec::new();
    if f & 0x10 != 0 {
        v.push(Variant::I4(inner.stamp(c.ts_us)));
    }
    v.push(pose);
    if f & 0x100 != 0 {
        v.push(Variant::I4(0));
    }
    if f & 0x20 != 0 {
        v.push(Variant::I4(0));
    }
    if f & 0x40 != 0 {
        v.push(Variant::r8s(&[0.0; MAX_JOINTS]));
    }
    Variant::Array(vt::VARIANT, v)
}

/// The 8 joint values (degrees) of a `slvMove` parameter under `slvSendFormat` `send_fmt`, or the
/// HRESULT that refuses it.
fn slv_pose(send_fmt: u32, param: &Variant) -> Result<[f64; MAX_JOINTS], u32> {
    let pose = match (send_fmt, param) {
        (0, Variant::Array(vt::R8, q)) => q,
        (f, Variant::Array(vt::VARIANT, items)) if f != 0 => match items.first() {
            Some(Variant::Array(vt::R8, q)) => q,
            _ => return Err(hr::DISP_E_TYPEMISMATCH),
        },
        _ => return Err(hr::DISP_E_TYPEMISMATCH),
    };
    if pose.len() != MAX_JOINTS && pose.len() != MAX_JOINTS + 1 {
        return Err(hr::E_INVALIDARG);
    }
    let mut cmd = [0.0; MAX_JOINTS];
    for (x, v) in cmd.iter_mut().zip(pose) {
        match v {
            Variant::R8(v) if v.is_finite() => *x = *v,
            _ => return Err(hr::E_INVALIDARG),
        }
    }
    Ok(cmd)
}

fn slv_move(inner: &Inner, param: &Variant) -> Answer {
    let mut c = inner.lock();
    if c.latched.is_some() || c.slave_mode == 0 {
        return error(hr::E_SLAVE_OFF);
    }
    let cmd = match slv_pose(c.send_fmt, param) {
        Ok(cmd) => cmd,
        Err(code) => return error(code),
    };
    let code = match (c.slave_mode >> 8) & 0xF {
        1 => {
            c.buffer.clear();
            c.buffer.push_back(cmd);
            hr::S_OK
        }
        mode => {
            if c.buffer.len() >= 3 {
                c.buffer_full += 1;
                return error(hr::E_BUF_FULL);
            }
            c.buffer.push_back(cmd);
            if c.buffer.len() < 3 {
                hr::S_OK
            } else if mode == 0 {
                hr::S_BUF_FULL
            } else {
                // Mode 2: held until a tick frees a slot.
                let pops = c.pops;
                while c.pops == pops && c.slave_mode != 0 && !inner.stopping() {
                    c = inner.cv.wait_timeout(c, Duration::from_millis(5)).map_or_else(|e| e.into_inner().0, |r| r.0);
                }
                match c.latched {
                    Some(code) => return error(code),
                    None if c.slave_mode == 0 => return error(hr::E_SLAVE_OFF),
                    None => hr::S_OK,
                }
            }
        }
    };
    (code, Some(position(inner, &c)))
}

#[cfg(test)]
mod tests {
    use super::*;

    // A small client-side encoder, independent of the fake's: arguments as `vt, count, data`.
    fn arg(t: u16, count: u32, data: &[u8]) -> Vec<u8> {
        let mut v = t.to_le_bytes().to_vec();
        v.extend_from_slice(&count.to_le_bytes());
        v.extend_from_slice(data);
        v
    }
    fn bstr(s: &str) -> Vec<u8> {
        let text: Vec<u8> = s.encode_utf16().flat_map(u16::to_le_bytes).collect();
        let mut d = (text.len() as u32).to_le_bytes().to_vec();
        d.extend_from_slice(&text);
        arg(8, 1, &d)
    }
    fn i4(v: i32) -> Vec<u8> {
        arg(3, 1, &v.to_le_bytes())
    }
    fn i4s(v: &[i32]) -> Vec<u8> {
        arg(0x2003, v.len() as u32, &v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>())
    }
    fn r8s(v: &[f64]) -> Vec<u8> {
        arg(0x2005, v.len() as u32, &v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>())
    }
    fn empty() -> Vec<u8> {
        arg(0, 1, &[])
    }
    fn request(serial: u16, id: u32, args: &[Vec<u8>]) -> Vec<u8> {
        let mut p = vec![1, 0, 0, 0, 0];
        p.extend_from_slice(&serial.to_le_bytes());
        p.extend_from_slice(&[0, 0]);
        p.extend_from_slice(&id.to_le_bytes());
        p.extend_from_slice(&(args.len() as u16).to_le_bytes());
        for a in args {
            p.extend_from_slice(&(a.len() as u32).to_le_bytes());
            p.extend_from_slice(a);
        }
        p.push(4);
        let n = p.len() as u32;
        p[1..5].copy_from_slice(&n.to_le_bytes());
        p
    }

    /// A reply as the test reads it: HRESULT, the raw value (vt, count, data), S_EXECUTING packets skipped.
    struct Reply {
        hr: u32,
        value: Option<Vec<u8>>,
        executing: u32,
    }
    impl Reply {
        fn r8s(&self) -> Vec<f64> {
            let v = self.value.as_ref().expect("a value");
            assert_eq!(&v[..2], &[0x05, 0x20]);
            v[6..].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect()
        }
        fn i4(&self) -> i32 {
            let v = self.value.as_ref().expect("a value");
            assert_eq!((v[0], v[1], v.len()), (3, 0, 10));
            i32::from_le_bytes(v[6..10].try_into().unwrap())
        }
        /// VARIANT[I4 time, R8×8].
        fn stamped(&self) -> (i32, Vec<f64>) {
            let v = self.value.as_ref().expect("a value");
            assert_eq!(&v[..16], &[0x0c, 0x20, 2, 0, 0, 0, 3, 0, 1, 0, 0, 0, v[12], v[13], v[14], v[15]]);
            assert_eq!(&v[16..22], &[0x05, 0x20, 8, 0, 0, 0]);
            (
                i32::from_le_bytes(v[12..16].try_into().unwrap()),
                v[22..].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect(),
            )
        }
    }

    struct Client {
        s: TcpStream,
        serial: u16,
        h: i32,
        r: i32,
    }
    impl Client {
        fn new(addr: SocketAddr) -> Client {
            let s = TcpStream::connect(addr).unwrap();
            s.set_nodelay(true).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
            Client { s, serial: 0, h: 0, r: 0 }
        }
        fn read(&mut self) -> (u16, u32, Option<Vec<u8>>) {
            let mut head = [0u8; 5];
            self.s.read_exact(&mut head).unwrap();
            assert_eq!(head[0], 1);
            let n = u32::from_le_bytes(head[1..5].try_into().unwrap()) as usize;
            let mut rest = vec![0u8; n - 5];
            self.s.read_exact(&mut rest).unwrap();
            assert_eq!(rest.last(), Some(&4));
            assert_eq!(&rest[2..4], &[0, 0], "reserved 0");
            let serial = u16::from_le_bytes([rest[0], rest[1]]);
            let hr = u32::from_le_bytes(rest[4..8].try_into().unwrap());
            let argc = u16::from_le_bytes([rest[8], rest[9]]);
            let value = (argc == 1).then(|| {
                let len = u32::from_le_bytes(rest[10..14].try_into().unwrap()) as usize;
                assert_eq!(14 + len + 1, rest.len());
                rest[14..14 + len].to_vec()
            });
            assert!(argc <= 1);
            (serial, hr, value)
        }
        fn send(&mut self, id: u32, args: &[Vec<u8>]) -> u16 {
            self.serial = self.serial % 65535 + 1;
            self.s.write_all(&request(self.serial, id, args)).unwrap();
            self.serial
        }
        fn call(&mut self, id: u32, args: &[Vec<u8>]) -> Reply {
            let serial = self.send(id, args);
            let mut executing = 0;
            loop {
                let (s, hr, value) = self.read();
                assert_eq!(s, serial);
                if hr == 0x900 {
                    assert!(value.is_none());
                    executing += 1;
                    continue;
                }
                return Reply { hr, value, executing };
            }
        }
        fn robot(&mut self, command: &str, param: Vec<u8>) -> Reply {
            let r = self.r;
            self.call(64, &[i4(r), bstr(command), param])
        }
        /// Service_Start .. Motor on, formats: ready for slvChangeMode.
        fn up(&mut self, recv: Vec<u8>) -> Vec<f64> {
            assert_eq!(self.call(1, &[bstr(",WDT=80,InvokeTimeout=180000")]).hr, 0);
            let c = self.call(3, &[bstr(""), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")]);
            assert_eq!(c.hr, 0);
            self.h = c.i4();
            assert_eq!(self.call(17, &[i4(self.h), bstr("ClearError"), empty()]).hr, 0);
            let r = self.call(7, &[i4(self.h), bstr("Arm"), bstr("")]);
            assert_eq!(r.hr, 0);
            self.r = r.i4();
            assert_eq!(self.robot("TakeArm", i4s(&[0, 1])).hr, 0);
            assert_eq!(self.robot("Motor", i4s(&[1, 0])).hr, 0);
            let q = self.robot("CurJnt", empty()).r8s();
            assert_eq!(self.robot("slvSendFormat", i4(0)).hr, 0);
            assert_eq!(self.robot("slvRecvFormat", recv).hr, 0);
            q
        }
        fn down(&mut self) {
            assert_eq!(self.robot("slvChangeMode", i4(0)).hr, 0);
            assert_eq!(self.robot("Motor", i4s(&[0, 0])).hr, 0);
            assert_eq!(self.robot("GiveArm", empty()).hr, 0);
            let r = self.r;
            assert_eq!(self.call(84, &[i4(r)]).hr, 0);
            let h = self.h;
            assert_eq!(self.call(4, &[i4(h)]).hr, 0);
            assert_eq!(self.call(2, &[]).hr, 0);
        }
    }

    /// SCHED_FIFO priority for the fake's threads and the streaming clients, if permitted: on a
    /// machine busy with builds a client stalled two cycles would rightly get 0x84201482.
    const RT: Option<i32> = Some(10);

    fn opts(cycle: f64) -> BcapOptions {
        BcapOptions {
            cycle,
            motor_on_time: 0.0,
            start_deg: vec![10.0, -20.0, 30.0, 0.0, 45.0, 0.0],
            rt_priority: RT,
            ..BcapOptions::default()
        }
    }

    /// The calling thread real-time while it lives (if permitted), back to SCHED_OTHER after.
    struct RealTime;
    impl RealTime {
        fn new() -> RealTime {
            real_time(RT);
            RealTime
        }
    }
    impl Drop for RealTime {
        fn drop(&mut self) {
            let param = libc::sched_param { sched_priority: 0 };
            // SAFETY: this thread (0), a valid sched_param.
            unsafe {
                libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
            }
        }
    }

    fn wait(mut f: impl FnMut() -> bool) {
        let t = std::time::Instant::now();
        while !f() {
            assert!(t.elapsed() < Duration::from_secs(2), "timed out");
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    fn hex(b: &str) -> Vec<u8> {
        b.split_whitespace().filter(|s| *s != "|").map(|s| u8::from_str_radix(s, 16).unwrap()).collect()
    }

    #[test]
    fn the_docs_worked_bytes() {
        let start = hex("01 1E 00 00 00 01 00 00 00 01 00 00 00 01 00 | 0A 00 00 00 08 00 01 00 00 00 00 00 00 00 | 04");
        let p = Packet { serial: 1, reserved: 0, id: func::SERVICE_START, args: vec![Variant::Bstr(String::new())] };
        assert_eq!(p.encode(), start);
        assert_eq!(Packet::decode(&start), Ok(p));
        assert_eq!(request(1, 1, &[bstr("")]), start, "the test's encoder agrees");

        let mut mode = hex("01 54 00 00 00 05 00 00 00 40 00 00 00 03 00 0A 00 00 00 03 00 01 00 00 00 12 00 00 00");
        mode.extend(hex("24 00 00 00 08 00 01 00 00 00 1A 00 00 00"));
        mode.extend("slvChangeMode".encode_utf16().flat_map(u16::to_le_bytes));
        mode.extend(hex("0A 00 00 00 03 00 01 00 00 00 02 02 00 00 04"));
        assert_eq!(mode.len(), 84);
        let p = Packet {
            serial: 5,
            reserved: 0,
            id: func::ROBOT_EXECUTE,
            args: vec![Variant::I4(0x12), Variant::Bstr("slvChangeMode".into()), Variant::I4(0x202)],
        };
        assert_eq!(p.encode(), mode);
        assert_eq!(Packet::decode(&mode), Ok(p));

        let q = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0, 0.0];
        let p = Packet { serial: 9, reserved: 0, id: 64, args: vec![Variant::I4(0x12), Variant::Bstr("slvMove".into()), Variant::r8s(&q)] };
        let b = p.encode();
        assert_eq!(b.len(), 132);
        assert_eq!(&b[b.len() - 75..b.len() - 65], &hex("46 00 00 00 05 20 08 00 00 00")[..]);
        assert_eq!(Packet::decode(&b), Ok(p));

        let e = hex("01 10 00 00 00 07 00 00 00 82 14 20 84 00 00 04");
        let p = Packet { serial: 7, reserved: 0, id: hr::E_BUF_EMPTY, args: vec![] };
        assert_eq!(p.encode(), e);
        assert_eq!(Packet::decode(&e), Ok(p));

        // §2: VARIANT array [I4 5, R8 [1, 2]].
        let v = Variant::Array(vt::VARIANT, vec![Variant::I4(5), Variant::r8s(&[1.0, 2.0])]);
        let mut out = Vec::new();
        v.encode(&mut out);
        let mut want = hex("0C 20 02 00 00 00 | 03 00 01 00 00 00 05 00 00 00 | 05 20 02 00 00 00");
        want.extend(1.0f64.to_le_bytes());
        want.extend(2.0f64.to_le_bytes());
        assert_eq!(out, want);
        assert_eq!(decode_variant(&mut Reader(&want), 0), Some(v));
        // BOOL true is 0xFFFF; a BSTR's length counts bytes.
        out.clear();
        Variant::Bool(true).encode(&mut out);
        assert_eq!(out, hex("0B 00 01 00 00 00 FF FF"));
        out.clear();
        Variant::Bstr("Ab".into()).encode(&mut out);
        assert_eq!(out, hex("08 00 01 00 00 00 04 00 00 00 41 00 62 00"));
    }

    #[test]
    fn no_input_panics_the_decoder() {
        let full = request(3, 64, &[i4(1), bstr("slvMove"), r8s(&[1.0; 8]), arg(0x200C, 2, &[i4(5), r8s(&[1.0, 2.0])].concat())]);
        assert!(Packet::decode(&full).is_ok());
        for n in 0..full.len() {
            assert!(Packet::decode(&full[..n]).is_err());
            let _ = frame(&full[..n]);
        }
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for len in 0..5000 {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            let mut m = full.clone();
            m[len % full.len()] = (x >> 33) as u8;
            m[(len * 7) % full.len()] ^= (x >> 17) as u8;
            let _ = (Packet::decode(&m), frame(&m));
            let bytes: Vec<u8> = (0..len % 97).map(|i| (x >> (i % 57)) as u8).collect();
            let _ = (Packet::decode(&bytes), frame(&bytes));
        }
        // A huge count must not allocate: rejected against the bytes left.
        let huge = request(1, 1, &[arg(0x2005, u32::MAX, &[0; 8])]);
        assert_eq!(Packet::decode(&huge), Err(Some(1)));
        let deep = request(1, 1, &[(0..20).fold(empty(), |inner, _| arg(0x200C, 1, &inner))]);
        assert_eq!(Packet::decode(&deep), Err(Some(1)));
    }

    #[test]
    fn the_full_sequence_streams_200_moves_in_mode_2_and_releases_cleanly() {
        // 7 ms: the client may stall two cycles (14 ms) on a loaded machine before the buffer runs dry.
        let cycle = 0.007;
        let _rt = RealTime::new();
        let fake = FakeBcap::spawn(BcapOptions { motor_on_time: 0.2, ..opts(cycle) }).unwrap();
        let watch = fake.watch();
        let mut c = Client::new(fake.addr());
        wait(|| watch.connected());
        assert_eq!(c.call(1, &[bstr(",WDT=80,InvokeTimeout=180000")]).hr, 0);
        let ctrl = c.call(3, &[bstr(""), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")]);
        assert_eq!(ctrl.hr, 0);
        c.h = ctrl.i4();
        assert_eq!(c.call(17, &[i4(c.h), bstr("ClearError"), empty()]).hr, 0);
        // Handles as VT_UI4 are taken too.
        let robot = c.call(7, &[arg(19, 1, &(c.h as u32).to_le_bytes()), bstr("Arm"), bstr("")]);
        c.r = robot.i4();
        assert_eq!(c.robot("TakeArm", i4s(&[0, 1])).hr, 0);
        assert!(watch.arm_taken());
        let t = std::time::Instant::now();
        let m = c.robot("Motor", i4s(&[1, 0]));
        assert_eq!(m.hr, 0);
        assert!(t.elapsed() >= Duration::from_millis(195));
        // At 80 and 160 ms (the second may be lost to a late wake-up on a loaded machine).
        assert!((1..=3).contains(&m.executing), "S_EXECUTING every 80 ms of 200: {}", m.executing);
        assert!(watch.motor_on());
        let start = c.robot("CurJnt", empty()).r8s();
        assert_eq!(start, [10.0, -20.0, 30.0, 0.0, 45.0, 0.0, 0.0, 0.0]);
        assert_eq!(c.robot("slvSendFormat", i4(0)).hr, 0);
        assert_eq!(c.robot("slvRecvFormat", i4s(&[0x12, 0])).hr, 0);
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
        assert_eq!(c.robot("slvGetMode", empty()).i4(), 0x202);
        assert_eq!(c.robot("TakeArm", i4s(&[0, 1])).hr, hr::E_IN_SLAVE_MODE);
        // A smooth ramp on J1 (10° over 200 cycles, cosine) and J5 (−5°).
        let n = 200;
        let t = std::time::Instant::now();
        let mut last = start.clone();
        let mut stamps = Vec::new();
        for k in 1..=n {
            let s = 0.5 - 0.5 * (std::f64::consts::PI * k as f64 / n as f64).cos();
            let mut q = start.clone();
            q[0] += 10.0 * s;
            q[4] -= 5.0 * s;
            let r = c.robot("slvMove", r8s(&q));
            assert_eq!(r.hr, 0, "move {k}");
            let (stamp, actual) = r.stamped();
            stamps.push(stamp);
            // The robot follows 2–3 commands behind (the buffer).
            assert!((actual[0] - q[0]).abs() < 4.0 * 10.0 * std::f64::consts::PI / 2.0 / n as f64 + 1e-9, "{k}: {actual:?} vs {q:?}");
            last = q;
        }
        let elapsed = t.elapsed().as_secs_f64();
        assert!(elapsed > (n - 4) as f64 * cycle * 0.95, "mode 2 paces the client to the cycle: {elapsed}");
        assert!(stamps.windows(2).all(|w| w[1] >= w[0]));
        // Leaving slave mode at once (the 2 commands still buffered are dropped): the robot stops
        // within 2 steps of the last command.
        assert_eq!(c.robot("slvChangeMode", i4(0)).hr, 0);
        let stop = c.robot("CurJnt", empty()).r8s();
        assert!((stop[0] - last[0]).abs() < 2.0 * 0.08 && stop[0] != start[0], "{stop:?} vs {last:?}");
        assert!(watch.errors().is_empty(), "{:x?}", watch.errors());
        c.down();
        drop(c);
        wait(|| !watch.connected());
        assert!(watch.released());
        assert!(!watch.arm_taken() && !watch.motor_on() && watch.slave_mode() == 0);
        let r = fake.stop();
        assert!(r.released);
        assert_eq!((r.slv_moves, r.buffer_full, r.garbage, r.errors.len()), (n as u64, 0, 0, 0));
        assert!((n as u64 - 3..=n as u64).contains(&r.report.in_time), "{}", r.report.in_time);
        assert_eq!(r.report.missing, 0);
        assert_eq!(r.report.round_trip.count(), n as u64);
        let (v, a) = r.report.max_rates(cycle, 0.0);
        assert!(v[0] < 20.5 && a[0] < 200.0, "{v:?} {a:?}");
        assert_eq!(
            r.calls,
            [
                "Service_Start",
                "Controller_Connect",
                "Controller_Execute(ClearError)",
                "Controller_GetRobot",
                "Robot_Execute(TakeArm)",
                "Robot_Execute(Motor)",
                "Robot_Execute(CurJnt)",
                "Robot_Execute(slvSendFormat)",
                "Robot_Execute(slvRecvFormat)",
                "Robot_Execute(slvChangeMode)",
                "Robot_Execute(slvGetMode)",
                "Robot_Execute(TakeArm)",
            ]
            .iter()
            .map(|s| s.to_string())
            .chain(r.calls[12..].iter().cloned())
            .collect::<Vec<_>>()
        );
        assert_eq!(r.calls.last().map(String::as_str), Some("Service_Stop"));
    }

    #[test]
    fn a_pause_of_5_cycles_latches_buffer_empty_and_recovery_needs_clear_error() {
        let _rt = RealTime::new();
        let fake = FakeBcap::spawn(opts(0.008)).unwrap();
        let watch = fake.watch();
        let mut c = Client::new(fake.addr());
        let q = c.up(i4(2));
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
        for _ in 0..20 {
            let r = c.robot("slvMove", r8s(&q));
            assert_eq!(r.hr, 0);
            assert_eq!(r.r8s(), q);
        }
        std::thread::sleep(Duration::from_millis(5 * 8 + 5));
        wait(|| !watch.errors().is_empty());
        assert_eq!(watch.errors(), [hr::E_BUF_EMPTY]);
        assert_eq!(watch.slave_mode(), 0);
        assert!(!watch.motor_on(), "a level-4 error switches the motor off");
        assert_eq!(c.robot("slvMove", r8s(&q)).hr, hr::E_SLAVE_OFF);
        assert_eq!(c.robot("Motor", i4(1)).hr, hr::E_ERROR_PENDING);
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_ERROR_PENDING);
        let h = c.h;
        let d = c.call(17, &[i4(h), bstr("GetErrorDescription"), i4(hr::E_BUF_EMPTY as i32)]);
        assert_eq!(d.hr, 0);
        assert!(d.value.unwrap().len() > 10);
        assert_eq!(c.call(17, &[i4(h), bstr("ClearError"), empty()]).hr, 0);
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_MOTOR_OFF);
        assert_eq!(c.robot("Motor", i4(1)).hr, 0);
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
        for _ in 0..10 {
            assert_eq!(c.robot("slvMove", r8s(&q)).hr, 0);
        }
        // An injected fault ends slave mode as a real one would.
        watch.inject_error(0x8420_1486);
        assert_eq!(c.robot("slvMove", r8s(&q)).hr, hr::E_SLAVE_OFF);
        c.down();
        drop(c);
        wait(|| !watch.connected());
        let r = fake.stop();
        assert_eq!(r.errors, [hr::E_BUF_EMPTY, 0x8420_1486]);
        assert!(r.released, "a clean release after faults is still clean");
        assert_eq!(r.report.missing, 1);
        assert_eq!(r.report.cycles, r.report.in_time + 1);
        assert_eq!(r.report.fresh.iter().filter(|f| !**f).count(), 1);
    }

    #[test]
    fn a_connection_dropped_mid_stream_runs_out_the_buffer_then_latches_buffer_empty() {
        let _rt = RealTime::new();
        let fake = FakeBcap::spawn(BcapOptions { lag: 0.02, ..opts(0.008) }).unwrap();
        let watch = fake.watch();
        let mut c = Client::new(fake.addr());
        let q = c.up(i4(2));
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
        let mut p = q.clone();
        for k in 1..=10 {
            p[1] = q[1] + 0.01 * f64::from(k);
            assert_eq!(c.robot("slvMove", r8s(&p)).hr, 0);
        }
        drop(c);
        wait(|| !watch.errors().is_empty());
        assert_eq!((watch.errors(), watch.slave_mode(), watch.arm_taken(), watch.released()), (vec![hr::E_BUF_EMPTY], 0, false, false));
        let r = fake.stop();
        assert_eq!((r.report.in_time, r.report.missing), (10, 1), "the 2 buffered commands were run out");
        // The drives lag: the actual joint 2 moves less than commanded, never past it.
        let j2: Vec<f64> = r.report.axes.iter().map(|a| a[1]).collect();
        assert!(j2.windows(2).all(|w| w[1] >= w[0] - 1e-12) && j2.iter().all(|v| *v < q[1] + 0.1 - 1e-6), "{j2:?}");
    }

    #[test]
    fn a_jump_latches_the_speed_or_acceleration_error_of_its_joint() {
        for (speed, accel, joint, step, code) in [(100.0, 1e9, 2, 5.0, hr::E_SPEED + 3), (1e9, 1000.0, 1, 0.1, hr::E_ACCEL + 2)] {
            let fake =
                FakeBcap::spawn(BcapOptions { speed_limit_deg: vec![speed; 6], accel_limit_deg: vec![accel; 6], ..opts(0.004) }).unwrap();
            let watch = fake.watch();
            let mut c = Client::new(fake.addr());
            let q = c.up(i4(2));
            assert_eq!(c.robot("slvChangeMode", i4(0x002)).hr, 0);
            let mut jump = q.clone();
            jump[joint] += step;
            let hrs: Vec<u32> = [&q, &q, &jump].iter().map(|p| c.robot("slvMove", r8s(p)).hr).collect();
            assert!(hrs.iter().all(|h| [hr::S_OK, hr::S_BUF_FULL].contains(h)), "{hrs:x?}");
            wait(|| !watch.errors().is_empty());
            assert_eq!(watch.errors(), [code]);
            assert_eq!(watch.slave_mode(), 0);
            assert_eq!(c.robot("CurJnt", empty()).r8s(), q, "the robot stopped before the jump");
            assert_eq!(c.robot("slvMove", r8s(&q)).hr, hr::E_SLAVE_OFF);
            drop(c);
            wait(|| !watch.connected());
            let r = fake.stop();
            assert!(!r.released);
            assert_eq!((r.report.cycles, r.report.in_time), (3, 3));
        }
    }

    #[test]
    fn mode_0_answers_buf_full_and_mode_1_overwrites() {
        let fake = FakeBcap::spawn(opts(0.3)).unwrap();
        let watch = fake.watch();
        let mut c = Client::new(fake.addr());
        let q = c.up(i4(2));
        assert_eq!(c.robot("slvChangeMode", i4(0x002)).hr, 0);
        let hrs: Vec<u32> = (0..5).map(|_| c.robot("slvMove", r8s(&q)).hr).collect();
        // A tick may pop one between two calls (one in 300 ms): the S_BUF_FULL → E_BUF_FULL pair is there anyway.
        let at = hrs.iter().position(|h| *h == hr::S_BUF_FULL).expect("S_BUF_FULL");
        assert_eq!(hrs.get(at + 1), Some(&hr::E_BUF_FULL), "{hrs:x?}");
        assert!(watch.errors().is_empty(), "E_BUF_FULL is not latched");
        assert_eq!(c.robot("slvChangeMode", i4(0)).hr, 0);
        assert_eq!(c.robot("slvChangeMode", i4(0x102)).hr, 0);
        assert!((0..5).all(|_| c.robot("slvMove", r8s(&q)).hr == hr::S_OK));
        assert_eq!(c.robot("slvChangeMode", i4(0)).hr, 0);
        assert_eq!(c.robot("slvChangeMode", i4(0x201)).hr, hr::E_INVALIDARG, "P type: no kinematics here");
        let r = fake.stop();
        assert!(r.buffer_full >= 1);
        assert!(r.errors.is_empty());
    }

    #[test]
    fn garbage_is_skipped_bad_packets_answered_and_a_second_client_refused() {
        let fake = FakeBcap::spawn(opts(0.008)).unwrap();
        let watch = fake.watch();
        let mut c = Client::new(fake.addr());
        c.s.write_all(b"HELLO").unwrap();
        assert_eq!(c.call(1, &[]).hr, 0);
        // A bad terminator: E_INVALIDPACKET with its serial.
        let mut bad = request(77, 1, &[]);
        *bad.last_mut().unwrap() = 5;
        c.s.write_all(&bad).unwrap();
        assert_eq!(c.read(), (77, hr::E_INVALIDPACKET, None));
        // An argument longer than the packet: the same.
        let mut bad = request(78, 1, &[bstr("x")]);
        bad[15] = 0x30;
        c.s.write_all(&bad).unwrap();
        assert_eq!(c.read(), (78, hr::E_INVALIDPACKET, None));
        // An SOH with a length below 16: dropped, the rest is garbage.
        c.s.write_all(&[1, 3, 0, 0, 0]).unwrap();
        assert_eq!(c.call(1, &[]).hr, 0);
        // An SOH whose made-up length never arrives: given up after 200 ms.
        c.s.write_all(&[1, 0xff, 0, 0, 0]).unwrap();
        std::thread::sleep(Duration::from_millis(250));
        assert_eq!(c.call(1, &[]).hr, 0);
        // Calls the controller refuses.
        let h = c.call(3, &[bstr(""), bstr("CaoProv.DENSO.RC8"), bstr(""), bstr("")]);
        assert_eq!((h.hr, h.value.is_none()), (hr::E_CAO_OBJECT_NOT_FOUND, true));
        let h = c.call(3, &[bstr(""), bstr("CaoProv.DENSO.VRC"), bstr(""), bstr("")]).i4();
        assert_eq!(c.call(7, &[i4(h + 100), bstr(""), bstr("")]).hr, hr::E_HANDLE);
        c.r = c.call(7, &[i4(h), bstr(""), bstr("")]).i4();
        assert_eq!(c.robot("Dance", empty()).hr, hr::E_INVALID_CMD_NAME);
        assert_eq!(c.robot("slvMove", r8s(&[0.0; 8])).hr, hr::E_SLAVE_OFF);
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_ACCESSDENIED);
        assert_eq!(c.robot("TakeArm", empty()).hr, 0);
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, hr::E_MOTOR_OFF);
        assert_eq!(c.robot("Motor", i4s(&[1, 1])).hr, 0, "noWait");
        assert_eq!(c.call(99, &[]).hr, hr::E_NOTIMPL);
        // A second client is refused while one is connected.
        let mut other = Client::new(fake.addr());
        let serial = other.send(1, &[]);
        assert_eq!(other.read(), (serial, hr::E_MAX_CONNECT, None));
        assert!(watch.connected());
        // Dropped in slave mode before any command: the robot stops, nothing latched.
        assert_eq!(c.robot("slvChangeMode", i4(0x202)).hr, 0);
        drop(c);
        wait(|| !watch.connected());
        assert_eq!((watch.slave_mode(), watch.errors().len(), watch.released()), (0, 0, false));
        let r = fake.stop();
        assert_eq!(r.garbage, 5 + 2 + 5 + 5, "HELLO, two bad packets, 01 03 00 00 00, 01 FF 00 00 00");
    }
}
