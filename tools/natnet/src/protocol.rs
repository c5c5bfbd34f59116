//! The NatNet wire format (3.0 to 4.2): message ids, the requests a client sends, and the server's
//! packets — server info, model definitions, frames of data — read and written, each as the
//! version that sent it lays it out.
//!
//! Written from NaturalPoint's public depacketization samples (`PacketClient.cpp`,
//! `NatNetClient.py`) and the NatNet SDK's documented structures; no code of theirs. Everything is
//! little-endian. A packet is `u16 message id, u16 payload bytes, payload`. The layout changes
//! with the stream version:
//!
//! - 3.0: rigid bodies lose their marker lists (the markers are in the description); the frame's
//!   suffix gains three high-resolution timestamps (camera mid-exposure, data received,
//!   transmit) in the server's clock ticks, whose frequency the server info gives.
//! - 4.0: rigid body descriptions name their markers.
//! - 4.1: every frame section and every description carries its size in bytes after its count
//!   (this reader trusts the size, so fields a later version adds to a section are skipped);
//!   frames carry assets; the suffix gains a precision (PTP) timestamp.
//! - 4.2: rigid body descriptions carry an orientation offset.
//!
//! Reading never panics and never allocates by a count it has not checked against the bytes left:
//! a short, long or garbled packet is a [`ParseError`] naming what was being read.

use thiserror::Error;

/// Client → server: connect ("ping"), answered by [`NAT_SERVERINFO`].
pub const NAT_CONNECT: u16 = 0;
/// Server → client: the server's name, versions, clock and data connection.
pub const NAT_SERVERINFO: u16 = 1;
/// Client → server: a text command.
pub const NAT_REQUEST: u16 = 2;
/// Server → client: the answer to a [`NAT_REQUEST`].
pub const NAT_RESPONSE: u16 = 3;
/// Client → server: send the model definitions.
pub const NAT_REQUEST_MODELDEF: u16 = 4;
/// Server → client: the model definitions (names and ids of every asset).
pub const NAT_MODELDEF: u16 = 5;
/// Client → server: send the current frame.
pub const NAT_REQUEST_FRAMEOFDATA: u16 = 6;
/// Server → client: one frame of motion capture data.
pub const NAT_FRAMEOFDATA: u16 = 7;
/// Server → client: a text message.
pub const NAT_MESSAGESTRING: u16 = 8;
/// Client → server: disconnect.
pub const NAT_DISCONNECT: u16 = 9;
/// Client → server: still here (unicast subscriptions expire without it).
pub const NAT_KEEPALIVE: u16 = 10;
/// Server → client: a request the server does not know.
pub const NAT_UNRECOGNIZED_REQUEST: u16 = 100;

/// Frame parameter bit: Motive is recording.
pub const FRAME_RECORDING: i16 = 0x01;
/// Frame parameter bit: the tracked models changed (the model definitions are out of date).
pub const FRAME_MODELS_CHANGED: i16 = 0x02;
/// Rigid body parameter bit: tracked in this frame.
pub const BODY_TRACKED: i16 = 0x01;

/// The bytes of the sender name field in the server info and the connect packet.
const NAME_BYTES: usize = 256;

/// A NatNet stream version (major, minor, build, revision).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Version(pub [u8; 4]);

impl Version {
    /// major.minor (build and revision do not change the layout).
    pub fn new(major: u8, minor: u8) -> Self {
        Version([major, minor, 0, 0])
    }
    /// Whether this version lays packets out as `major.minor` or later.
    pub fn at_least(self, major: u8, minor: u8) -> bool {
        (self.0[0], self.0[1]) >= (major, minor)
    }
    /// Sizes after every frame section's count and every description's type (4.1+).
    fn sized(self) -> bool {
        self.at_least(4, 1)
    }
}

impl std::fmt::Display for Version {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}.{}", self.0[0], self.0[1], self.0[2], self.0[3])
    }
}

/// A packet that cannot be read: what was being read, and why.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
pub enum ParseError {
    /// Fewer bytes than the header or the field needs.
    #[error("truncated: {what} needs {need} bytes at offset {at}, {have} left")]
    Truncated {
        /// The field being read.
        what: &'static str,
        /// Its offset in the payload (bytes).
        at: usize,
        /// Bytes it needs.
        need: usize,
        /// Bytes left.
        have: usize,
    },
    /// A count or size that is negative or larger than the bytes left can hold.
    #[error("bad {what}: {value} at offset {at}")]
    BadCount {
        /// The count being read.
        what: &'static str,
        /// Its value.
        value: i64,
        /// Its offset in the payload (bytes).
        at: usize,
    },
    /// A string without its terminating NUL or not UTF-8.
    #[error("bad string for {what} at offset {at}")]
    BadString {
        /// The field being read.
        what: &'static str,
        /// Its offset in the payload (bytes).
        at: usize,
    },
    /// A description type this version cannot skip.
    #[error("unknown description type {kind} (NatNet {version} gives no size to skip it)")]
    UnknownDescription {
        /// The type.
        kind: i32,
        /// The stream version.
        version: Version,
    },
    /// Another message than the one expected.
    #[error("message {got}, expected {expected}")]
    WrongMessage {
        /// The message id read.
        got: u16,
        /// The one expected.
        expected: u16,
    },
}

/// The server's answer to a connect.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServerInfo {
    /// The server application's name ("Motive").
    pub app_name: String,
    /// The server application's version.
    pub app_version: Version,
    /// The NatNet stream version the server sends.
    pub natnet_version: Version,
    /// The server's high-resolution clock (ticks per second); 0 if the server did not say
    /// (before 3.0). The frame timestamps are in its ticks.
    pub clock_hz: u64,
    /// The data connection, if the server said (3.0+).
    pub connection: Option<DataConnection>,
}

/// How the server streams frames (server info, 3.0+).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataConnection {
    /// The server's data port (UDP).
    pub data_port: u16,
    /// Multicast (true) or unicast.
    pub multicast: bool,
    /// The multicast group.
    pub multicast_group: [u8; 4],
}

/// A rigid body's description: what finds it by name.
#[derive(Clone, Debug, PartialEq)]
pub struct RigidBodyDescription {
    /// Its name in Motive.
    pub name: String,
    /// Its id in frames.
    pub id: i32,
    /// Its parent's id (−1: none).
    pub parent_id: i32,
    /// Offset from its parent (m).
    pub offset: [f32; 3],
    /// Orientation offset from its parent (x, y, z, w; 4.2+, identity before).
    pub orientation_offset: [f32; 4],
    /// Its markers: position in the body (m), active label, name (4.0+, empty before).
    pub markers: Vec<([f32; 3], i32, String)>,
}

/// One entry of the model definitions. Only rigid bodies matter to strand; the others are kept
/// as what they are so a fake server can send them and a reader can skip them.
#[derive(Clone, Debug, PartialEq)]
pub enum Description {
    /// Type 0: a marker set: name, marker names.
    MarkerSet(String, Vec<String>),
    /// Type 1: a rigid body.
    RigidBody(RigidBodyDescription),
    /// Type 2: a skeleton: name, id, bones.
    Skeleton(String, i32, Vec<RigidBodyDescription>),
    /// Type 3: a force plate: id, serial, channel names.
    ForcePlate(i32, String, Vec<String>),
    /// Type 4: a device (analog, NI-DAQ): id, name, serial, channel names.
    Device(i32, String, String, Vec<String>),
    /// Type 5: a camera: name, position (m), orientation (x, y, z, w).
    Camera(String, [f32; 3], [f32; 4]),
    /// Type 6 (4.1+): an asset (trained markerset): name, type, id, bodies, marker names and ids.
    Asset(String, i32, i32, Vec<RigidBodyDescription>, Vec<(String, i32)>),
    /// A type a 4.1+ server sent that this reader does not know (skipped by its size).
    Other(i32),
}

/// A rigid body in a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidBodyPose {
    /// Its id (from the description).
    pub id: i32,
    /// Position (m, Motive's world).
    pub position: [f32; 3],
    /// Orientation R_MB as (x, y, z, w) — NatNet's order.
    pub orientation: [f32; 4],
    /// Mean marker error (m).
    pub mean_error: f32,
    /// Parameters ([`BODY_TRACKED`]).
    pub params: i16,
}

impl RigidBodyPose {
    /// Whether Motive tracked it in this frame (otherwise its pose is the last one or zero).
    pub fn tracked(&self) -> bool {
        self.params & BODY_TRACKED != 0
    }
}

/// A labeled marker in a frame: id, position (m), size (m), parameters, residual (m).
pub type LabeledMarker = (i32, [f32; 3], f32, i16, f32);

/// A force plate or device in a frame: id, channels of samples.
pub type ChannelData = (i32, Vec<Vec<f32>>);

/// An asset in a frame (4.1+): id, its bodies, its markers.
pub type AssetFrame = (i32, Vec<RigidBodyPose>, Vec<LabeledMarker>);

/// One frame of data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    /// Motive's frame number.
    pub number: i32,
    /// Marker sets: name, marker positions (m).
    pub marker_sets: Vec<(String, Vec<[f32; 3]>)>,
    /// Unlabeled ("other") markers (m).
    pub other_markers: Vec<[f32; 3]>,
    /// Rigid bodies.
    pub rigid_bodies: Vec<RigidBodyPose>,
    /// Skeletons: id, bones.
    pub skeletons: Vec<(i32, Vec<RigidBodyPose>)>,
    /// Assets (4.1+).
    pub assets: Vec<AssetFrame>,
    /// Labeled markers.
    pub labeled_markers: Vec<LabeledMarker>,
    /// Force plates: id, channels of samples (N, N·m).
    pub force_plates: Vec<ChannelData>,
    /// Devices: id, channels of samples (the device's units).
    pub devices: Vec<ChannelData>,
    /// SMPTE timecode and subframe.
    pub timecode: (u32, u32),
    /// Motive's time of the frame since its start (s).
    pub timestamp: f64,
    /// Camera mid-exposure (server clock ticks): when the frame was seen.
    pub mid_exposure: u64,
    /// When the cameras' data reached Motive (server clock ticks).
    pub data_received: u64,
    /// When Motive sent the frame (server clock ticks).
    pub transmit: u64,
    /// Precision (PTP) timestamp: seconds and fraction (4.1+; 0 when absent).
    pub precision: (u32, u32),
    /// Frame parameters ([`FRAME_RECORDING`], [`FRAME_MODELS_CHANGED`]).
    pub params: i16,
}

/// A packet's message id and payload, checked against its declared size. The size field is 16
/// bits, so a datagram longer than 65,539 bytes carries its true size only in its length; a
/// declared size larger than the datagram is a truncated packet.
pub fn split(datagram: &[u8]) -> Result<(u16, &[u8]), ParseError> {
    if datagram.len() < 4 {
        return Err(ParseError::Truncated { what: "packet header", at: 0, need: 4, have: datagram.len() });
    }
    let id = u16::from_le_bytes([datagram[0], datagram[1]]);
    let declared = u16::from_le_bytes([datagram[2], datagram[3]]) as usize;
    let payload = &datagram[4..];
    if declared > payload.len() {
        return Err(ParseError::Truncated { what: "payload", at: 4, need: declared, have: payload.len() });
    }
    if payload.len() <= u16::MAX as usize { Ok((id, &payload[..declared])) } else { Ok((id, payload)) }
}

/// A little-endian reader over a payload that never reads past its end.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    /// Frame sections carry their size after their count (4.1+).
    sized: bool,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        Reader { bytes, at: 0, sized: false }
    }
    fn left(&self) -> usize {
        self.bytes.len() - self.at
    }
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], ParseError> {
        if n > self.left() {
            return Err(ParseError::Truncated { what, at: self.at, need: n, have: self.left() });
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], ParseError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, what)?);
        Ok(a)
    }
    fn u8(&mut self, what: &'static str) -> Result<u8, ParseError> {
        Ok(self.array::<1>(what)?[0])
    }
    fn i16(&mut self, what: &'static str) -> Result<i16, ParseError> {
        Ok(i16::from_le_bytes(self.array(what)?))
    }
    fn u16(&mut self, what: &'static str) -> Result<u16, ParseError> {
        Ok(u16::from_le_bytes(self.array(what)?))
    }
    fn i32(&mut self, what: &'static str) -> Result<i32, ParseError> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, ParseError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    fn u64(&mut self, what: &'static str) -> Result<u64, ParseError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }
    fn f32(&mut self, what: &'static str) -> Result<f32, ParseError> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }
    fn f64(&mut self, what: &'static str) -> Result<f64, ParseError> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }
    fn vec3(&mut self, what: &'static str) -> Result<[f32; 3], ParseError> {
        Ok([self.f32(what)?, self.f32(what)?, self.f32(what)?])
    }
    fn quat(&mut self, what: &'static str) -> Result<[f32; 4], ParseError> {
        Ok([self.f32(what)?, self.f32(what)?, self.f32(what)?, self.f32(what)?])
    }
    /// A count of items of at least `min_item` bytes each: never more than the bytes left hold.
    fn count(&mut self, what: &'static str, min_item: usize) -> Result<usize, ParseError> {
        let at = self.at;
        let n = self.i32(what)?;
        if n < 0 || (n as usize).saturating_mul(min_item.max(1)) > self.left() {
            return Err(ParseError::BadCount { what, value: n as i64, at });
        }
        Ok(n as usize)
    }
    /// A section size (4.1+): the end offset of the section, inside the payload.
    fn size(&mut self, what: &'static str) -> Result<usize, ParseError> {
        let at = self.at;
        let n = self.i32(what)?;
        if n < 0 || n as usize > self.left() {
            return Err(ParseError::BadCount { what, value: n as i64, at });
        }
        Ok(self.at + n as usize)
    }
    /// A NUL-terminated UTF-8 string.
    fn cstr(&mut self, what: &'static str) -> Result<String, ParseError> {
        let at = self.at;
        let rest = &self.bytes[self.at..];
        let end = rest.iter().position(|b| *b == 0).ok_or(ParseError::BadString { what, at })?;
        let s = std::str::from_utf8(&rest[..end]).map_err(|_| ParseError::BadString { what, at })?;
        self.at += end + 1;
        Ok(s.to_string())
    }
    /// A fixed-size NUL-padded name field.
    fn name_field(&mut self, what: &'static str) -> Result<String, ParseError> {
        let at = self.at;
        let raw = self.take(NAME_BYTES, what)?;
        let end = raw.iter().position(|b| *b == 0).unwrap_or(raw.len());
        std::str::from_utf8(&raw[..end]).map(str::to_string).map_err(|_| ParseError::BadString { what, at })
    }
}

/// The client's connect packet: a sender named "strand-natnet" with no version of its own, and
/// connection options asking for the server's own stream version (all zero).
pub fn connect_packet() -> Vec<u8> {
    // sSender (name[256], app version[4], NatNet version[4]) + sConnectionOptions (bool
    // subscribed-data-only, bitstream version[4]) + a pad byte, as the samples send it.
    let mut payload = vec![0u8; NAME_BYTES + 8 + 5 + 1];
    let name = b"strand-natnet";
    payload[..name.len()].copy_from_slice(name);
    packet(NAT_CONNECT, &payload)
}

/// A request without a payload ([`NAT_REQUEST_MODELDEF`], [`NAT_KEEPALIVE`], ...).
pub fn request_packet(id: u16) -> Vec<u8> {
    packet(id, &[])
}

/// A packet: header and payload. Payloads over 65,535 bytes declare their size modulo 2^16, as
/// Motive's do; [`split`] then takes the datagram's length.
pub fn packet(id: u16, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(4 + payload.len());
    out.extend_from_slice(&id.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u16).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// Reads a [`NAT_SERVERINFO`] payload.
pub fn parse_server_info(payload: &[u8]) -> Result<ServerInfo, ParseError> {
    let mut r = Reader::new(payload);
    let app_name = r.name_field("server name")?;
    let app_version = Version(r.array("server version")?);
    let natnet_version = Version(r.array("NatNet version")?);
    // 3.0+: the clock and the data connection. Older servers end here.
    let (clock_hz, connection) = if r.left() >= 8 + 2 + 1 + 4 {
        let clock_hz = r.u64("clock frequency")?;
        let data_port = r.u16("data port")?;
        let multicast = r.u8("multicast flag")? != 0;
        let multicast_group = r.array("multicast group")?;
        (clock_hz, Some(DataConnection { data_port, multicast, multicast_group }))
    } else {
        (0, None)
    };
    Ok(ServerInfo { app_name, app_version, natnet_version, clock_hz, connection })
}

fn rigid_body_description(r: &mut Reader<'_>, v: Version) -> Result<RigidBodyDescription, ParseError> {
    let name = r.cstr("rigid body name")?;
    let id = r.i32("rigid body id")?;
    let parent_id = r.i32("rigid body parent id")?;
    let offset = r.vec3("rigid body offset")?;
    let orientation_offset = if v.at_least(4, 2) { r.quat("rigid body orientation offset")? } else { [0.0, 0.0, 0.0, 1.0] };
    let n = r.count("rigid body marker count", 16)?;
    let mut positions = Vec::with_capacity(n);
    for _ in 0..n {
        positions.push(r.vec3("rigid body marker position")?);
    }
    let mut labels = Vec::with_capacity(n);
    for _ in 0..n {
        labels.push(r.i32("rigid body marker label")?);
    }
    let mut markers = Vec::with_capacity(n);
    for (p, l) in positions.into_iter().zip(labels) {
        let name = if v.at_least(4, 0) { r.cstr("rigid body marker name")? } else { String::new() };
        markers.push((p, l, name));
    }
    Ok(RigidBodyDescription { name, id, parent_id, offset, orientation_offset, markers })
}

fn names(r: &mut Reader<'_>, what: &'static str) -> Result<Vec<String>, ParseError> {
    let n = r.count(what, 1)?;
    (0..n).map(|_| r.cstr(what)).collect()
}

fn description(r: &mut Reader<'_>, kind: i32, v: Version) -> Result<Description, ParseError> {
    Ok(match kind {
        0 => {
            let name = r.cstr("marker set name")?;
            Description::MarkerSet(name, names(r, "marker set marker names")?)
        }
        1 => Description::RigidBody(rigid_body_description(r, v)?),
        2 => {
            let name = r.cstr("skeleton name")?;
            let id = r.i32("skeleton id")?;
            let n = r.count("skeleton bone count", 25)?;
            let bones = (0..n).map(|_| rigid_body_description(r, v)).collect::<Result<_, _>>()?;
            Description::Skeleton(name, id, bones)
        }
        3 => {
            let id = r.i32("force plate id")?;
            let serial = r.cstr("force plate serial")?;
            // width, length, origin, 12×12 calibration matrix, 4 corners: 2 + 3 + 144 + 12 floats.
            r.take(4 * (2 + 3 + 144 + 12), "force plate geometry")?;
            r.i32("force plate type")?;
            r.i32("force plate channel data type")?;
            Description::ForcePlate(id, serial, names(r, "force plate channel names")?)
        }
        4 => {
            let id = r.i32("device id")?;
            let name = r.cstr("device name")?;
            let serial = r.cstr("device serial")?;
            r.i32("device type")?;
            r.i32("device channel data type")?;
            Description::Device(id, name, serial, names(r, "device channel names")?)
        }
        5 => {
            let name = r.cstr("camera name")?;
            Description::Camera(name, r.vec3("camera position")?, r.quat("camera orientation")?)
        }
        6 => {
            let name = r.cstr("asset name")?;
            let kind = r.i32("asset type")?;
            let id = r.i32("asset id")?;
            let n = r.count("asset body count", 25)?;
            let bodies = (0..n).map(|_| rigid_body_description(r, v)).collect::<Result<_, _>>()?;
            let m = r.count("asset marker count", 23)?;
            let mut markers = Vec::with_capacity(m);
            for _ in 0..m {
                let name = r.cstr("asset marker name")?;
                let mid = r.i32("asset marker id")?;
                r.take(12 + 4 + 2, "asset marker position, size, params")?;
                markers.push((name, mid));
            }
            Description::Asset(name, kind, id, bodies, markers)
        }
        _ => return Err(ParseError::UnknownDescription { kind, version: v }),
    })
}

/// Reads a [`NAT_MODELDEF`] payload sent as version `v`.
pub fn parse_model_definitions(payload: &[u8], v: Version) -> Result<Vec<Description>, ParseError> {
    let mut r = Reader::new(payload);
    let n = r.count("description count", 8)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let kind = r.i32("description type")?;
        if v.sized() {
            let end = r.size("description size")?;
            let mut sub = Reader::new(&r.bytes[..end]);
            sub.at = r.at;
            let d = match description(&mut sub, kind, v) {
                Err(ParseError::UnknownDescription { .. }) => Description::Other(kind),
                other => other?,
            };
            out.push(d);
            // The size wins: what a later version appended to a description is skipped.
            r.at = end;
        } else {
            out.push(description(&mut r, kind, v)?);
        }
    }
    Ok(out)
}

fn rigid_body(r: &mut Reader<'_>) -> Result<RigidBodyPose, ParseError> {
    Ok(RigidBodyPose {
        id: r.i32("rigid body id")?,
        position: r.vec3("rigid body position")?,
        orientation: r.quat("rigid body orientation")?,
        mean_error: r.f32("rigid body mean error")?,
        params: r.i16("rigid body params")?,
    })
}

fn marker(r: &mut Reader<'_>) -> Result<LabeledMarker, ParseError> {
    Ok((r.i32("marker id")?, r.vec3("marker position")?, r.f32("marker size")?, r.i16("marker params")?, r.f32("marker residual")?))
}

fn channels(r: &mut Reader<'_>, what: &'static str) -> Result<Vec<ChannelData>, ParseError> {
    let n = r.count(what, 8)?;
    let end = if_sized(r)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = r.i32(what)?;
        let c = r.count(what, 4)?;
        let mut chans = Vec::with_capacity(c);
        for _ in 0..c {
            let f = r.count(what, 4)?;
            chans.push((0..f).map(|_| r.f32(what)).collect::<Result<Vec<_>, _>>()?);
        }
        out.push((id, chans));
    }
    close(r, end);
    Ok(out)
}

/// A section's size after its count (4.1+): its end offset.
fn if_sized(r: &mut Reader<'_>) -> Result<Option<usize>, ParseError> {
    if r.sized { r.size("section size").map(Some) } else { Ok(None) }
}

/// The size wins: the reader goes on at the section's end.
fn close(r: &mut Reader<'_>, end: Option<usize>) {
    if let Some(e) = end {
        r.at = e;
    }
}

/// Reads a [`NAT_FRAMEOFDATA`] payload sent as version `v` (3.0 or later).
pub fn parse_frame(payload: &[u8], v: Version) -> Result<Frame, ParseError> {
    let mut r = Reader::new(payload);
    r.sized = v.sized();
    let mut f = Frame { number: r.i32("frame number")?, ..Frame::default() };

    let n = r.count("marker set count", 5)?;
    let end = if_sized(&mut r)?;
    for _ in 0..n {
        let name = r.cstr("marker set name")?;
        let m = r.count("marker set marker count", 12)?;
        f.marker_sets.push((name, (0..m).map(|_| r.vec3("marker set marker")).collect::<Result<_, _>>()?));
    }
    close(&mut r, end);

    let n = r.count("other marker count", 12)?;
    let end = if_sized(&mut r)?;
    f.other_markers = (0..n).map(|_| r.vec3("other marker")).collect::<Result<_, _>>()?;
    close(&mut r, end);

    let n = r.count("rigid body count", 38)?;
    let end = if_sized(&mut r)?;
    f.rigid_bodies = (0..n).map(|_| rigid_body(&mut r)).collect::<Result<_, _>>()?;
    close(&mut r, end);

    let n = r.count("skeleton count", 8)?;
    let end = if_sized(&mut r)?;
    for _ in 0..n {
        let id = r.i32("skeleton id")?;
        let b = r.count("skeleton bone count", 38)?;
        f.skeletons.push((id, (0..b).map(|_| rigid_body(&mut r)).collect::<Result<_, _>>()?));
    }
    close(&mut r, end);

    if v.at_least(4, 1) {
        let n = r.count("asset count", 12)?;
        let end = if_sized(&mut r)?;
        for _ in 0..n {
            let id = r.i32("asset id")?;
            let b = r.count("asset body count", 38)?;
            let bodies = (0..b).map(|_| rigid_body(&mut r)).collect::<Result<_, _>>()?;
            let m = r.count("asset marker count", 26)?;
            let markers = (0..m).map(|_| marker(&mut r)).collect::<Result<_, _>>()?;
            f.assets.push((id, bodies, markers));
        }
        close(&mut r, end);
    }

    let n = r.count("labeled marker count", 26)?;
    let end = if_sized(&mut r)?;
    f.labeled_markers = (0..n).map(|_| marker(&mut r)).collect::<Result<_, _>>()?;
    close(&mut r, end);

    f.force_plates = channels(&mut r, "force plate")?;
    f.devices = channels(&mut r, "device")?;

    f.timecode = (r.u32("timecode")?, r.u32("timecode subframe")?);
    f.timestamp = r.f64("timestamp")?;
    f.mid_exposure = r.u64("mid-exposure timestamp")?;
    f.data_received = r.u64("data received timestamp")?;
    f.transmit = r.u64("transmit timestamp")?;
    if v.at_least(4, 1) {
        f.precision = (r.u32("precision timestamp")?, r.u32("precision timestamp fraction")?);
    }
    f.params = r.i16("frame params")?;
    // An end-of-data tag (0) follows in Motive's packets; nothing after the params is read.
    Ok(f)
}

/// A little-endian writer: the fake server's side of the format.
#[derive(Default)]
struct Writer(Vec<u8>);

impl Writer {
    fn i16(&mut self, v: i16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn cstr(&mut self, s: &str) {
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
    fn count(&mut self, n: usize) {
        self.i32(n as i32);
    }
    /// Starts a sized section (4.1+): a placeholder to fill with [`Writer::end`].
    fn begin(&mut self, sized: bool) -> Option<usize> {
        sized.then(|| {
            self.i32(0);
            self.0.len()
        })
    }
    fn end(&mut self, start: Option<usize>) {
        if let Some(s) = start {
            let n = (self.0.len() - s) as i32;
            self.0[s - 4..s].copy_from_slice(&n.to_le_bytes());
        }
    }
}

/// Writes a [`NAT_SERVERINFO`] packet (3.0+ layout, with the clock and the data connection).
pub fn server_info_packet(info: &ServerInfo) -> Vec<u8> {
    let mut w = Writer::default();
    let mut name = [0u8; NAME_BYTES];
    let n = info.app_name.len().min(NAME_BYTES - 1);
    name[..n].copy_from_slice(&info.app_name.as_bytes()[..n]);
    w.0.extend_from_slice(&name);
    w.0.extend_from_slice(&info.app_version.0);
    w.0.extend_from_slice(&info.natnet_version.0);
    if let Some(c) = info.connection {
        w.u64(info.clock_hz);
        w.0.extend_from_slice(&c.data_port.to_le_bytes());
        w.0.push(c.multicast as u8);
        w.0.extend_from_slice(&c.multicast_group);
    }
    packet(NAT_SERVERINFO, &w.0)
}

fn write_rigid_body_description(w: &mut Writer, d: &RigidBodyDescription, v: Version) {
    w.cstr(&d.name);
    w.i32(d.id);
    w.i32(d.parent_id);
    w.f32s(&d.offset);
    if v.at_least(4, 2) {
        w.f32s(&d.orientation_offset);
    }
    w.count(d.markers.len());
    for (p, _, _) in &d.markers {
        w.f32s(p);
    }
    for (_, l, _) in &d.markers {
        w.i32(*l);
    }
    if v.at_least(4, 0) {
        for (_, _, n) in &d.markers {
            w.cstr(n);
        }
    }
}

fn write_names(w: &mut Writer, names: &[String]) {
    w.count(names.len());
    for n in names {
        w.cstr(n);
    }
}

/// Writes a [`NAT_MODELDEF`] packet as version `v` (assets only at 4.1+: skipped before).
pub fn model_definitions_packet(descriptions: &[Description], v: Version) -> Vec<u8> {
    let mut w = Writer::default();
    let kept: Vec<&Description> = descriptions
        .iter()
        .filter(|d| !matches!(d, Description::Other(_)) && (v.sized() || !matches!(d, Description::Asset(..))))
        .collect();
    w.count(kept.len());
    for d in kept {
        let kind = match d {
            Description::MarkerSet(..) => 0,
            Description::RigidBody(_) => 1,
            Description::Skeleton(..) => 2,
            Description::ForcePlate(..) => 3,
            Description::Device(..) => 4,
            Description::Camera(..) => 5,
            Description::Asset(..) => 6,
            Description::Other(k) => *k,
        };
        w.i32(kind);
        let s = w.begin(v.sized());
        match d {
            Description::MarkerSet(name, markers) => {
                w.cstr(name);
                write_names(&mut w, markers);
            }
            Description::RigidBody(b) => write_rigid_body_description(&mut w, b, v),
            Description::Skeleton(name, id, bones) => {
                w.cstr(name);
                w.i32(*id);
                w.count(bones.len());
                for b in bones {
                    write_rigid_body_description(&mut w, b, v);
                }
            }
            Description::ForcePlate(id, serial, chans) => {
                w.i32(*id);
                w.cstr(serial);
                w.f32s(&[0.6, 0.4, 0.0, 0.0, -0.04]);
                w.f32s(&[0.0; 144]);
                w.f32s(&[0.3, 0.2, 0.0, -0.3, 0.2, 0.0, -0.3, -0.2, 0.0, 0.3, -0.2, 0.0]);
                w.i32(2);
                w.i32(1);
                write_names(&mut w, chans);
            }
            Description::Device(id, name, serial, chans) => {
                w.i32(*id);
                w.cstr(name);
                w.cstr(serial);
                w.i32(1);
                w.i32(1);
                write_names(&mut w, chans);
            }
            Description::Camera(name, p, q) => {
                w.cstr(name);
                w.f32s(p);
                w.f32s(q);
            }
            Description::Asset(name, kind, id, bodies, markers) => {
                w.cstr(name);
                w.i32(*kind);
                w.i32(*id);
                w.count(bodies.len());
                for b in bodies {
                    write_rigid_body_description(&mut w, b, v);
                }
                w.count(markers.len());
                for (n, mid) in markers {
                    w.cstr(n);
                    w.i32(*mid);
                    w.f32s(&[0.0, 0.0, 0.0, 0.014]);
                    w.i16(0);
                }
            }
            Description::Other(_) => {}
        }
        w.end(s);
    }
    packet(NAT_MODELDEF, &w.0)
}

fn write_rigid_body(w: &mut Writer, b: &RigidBodyPose) {
    w.i32(b.id);
    w.f32s(&b.position);
    w.f32s(&b.orientation);
    w.f32s(&[b.mean_error]);
    w.i16(b.params);
}

fn write_marker(w: &mut Writer, m: &LabeledMarker) {
    w.i32(m.0);
    w.f32s(&m.1);
    w.f32s(&[m.2]);
    w.i16(m.3);
    w.f32s(&[m.4]);
}

fn write_channels(w: &mut Writer, items: &[ChannelData], sized: bool) {
    w.count(items.len());
    let s = w.begin(sized);
    for (id, chans) in items {
        w.i32(*id);
        w.count(chans.len());
        for c in chans {
            w.count(c.len());
            w.f32s(c);
        }
    }
    w.end(s);
}

/// Writes a [`NAT_FRAMEOFDATA`] packet as version `v` (3.0 or later; assets only at 4.1+), with
/// Motive's end-of-data tag.
pub fn frame_packet(f: &Frame, v: Version) -> Vec<u8> {
    let sized = v.sized();
    let mut w = Writer::default();
    w.i32(f.number);
    w.count(f.marker_sets.len());
    let s = w.begin(sized);
    for (name, markers) in &f.marker_sets {
        w.cstr(name);
        w.count(markers.len());
        for m in markers {
            w.f32s(m);
        }
    }
    w.end(s);
    w.count(f.other_markers.len());
    let s = w.begin(sized);
    for m in &f.other_markers {
        w.f32s(m);
    }
    w.end(s);
    w.count(f.rigid_bodies.len());
    let s = w.begin(sized);
    for b in &f.rigid_bodies {
        write_rigid_body(&mut w, b);
    }
    w.end(s);
    w.count(f.skeletons.len());
    let s = w.begin(sized);
    for (id, bones) in &f.skeletons {
        w.i32(*id);
        w.count(bones.len());
        for b in bones {
            write_rigid_body(&mut w, b);
        }
    }
    w.end(s);
    if v.at_least(4, 1) {
        w.count(f.assets.len());
        let s = w.begin(sized);
        for (id, bodies, markers) in &f.assets {
            w.i32(*id);
            w.count(bodies.len());
            for b in bodies {
                write_rigid_body(&mut w, b);
            }
            w.count(markers.len());
            for m in markers {
                write_marker(&mut w, m);
            }
        }
        w.end(s);
    }
    w.count(f.labeled_markers.len());
    let s = w.begin(sized);
    for m in &f.labeled_markers {
        write_marker(&mut w, m);
    }
    w.end(s);
    write_channels(&mut w, &f.force_plates, sized);
    write_channels(&mut w, &f.devices, sized);
    w.u32(f.timecode.0);
    w.u32(f.timecode.1);
    w.0.extend_from_slice(&f.timestamp.to_le_bytes());
    w.u64(f.mid_exposure);
    w.u64(f.data_received);
    w.u64(f.transmit);
    if v.at_least(4, 1) {
        w.u32(f.precision.0);
        w.u32(f.precision.1);
    }
    w.i16(f.params);
    w.i32(0);
    packet(NAT_FRAMEOFDATA, &w.0)
}
