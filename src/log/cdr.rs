//! CDR (little-endian XCDR1, as ROS 2 writes it) by hand: a reusable encoder, a decoder that
//! checks every bound, and the [`CdrType`] trait that ties a Rust type to its ros2msg declaration,
//! its encoding, its decoding and a flat field-by-field view (used to name the first divergent field
//! in a replay).
//!
//! Why by hand: the messages are few and fixed, the encoder must not allocate once warmed up, and a
//! replay needs every `f64` back bit for bit, which CDR gives (IEEE 754 little-endian, no text).
//! Alignment is counted from the byte after the 4-byte encapsulation header; a primitive is
//! aligned to its own size, a string is a u32 length (with the NUL), the bytes and a NUL, a sequence
//! a u32 count and its elements, a fixed array just its elements.

use std::fmt;

/// Encapsulation header of little-endian plain CDR.
pub(crate) const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Appends CDR to a reused buffer (no allocation once the buffer has grown to its working size).
#[derive(Default)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl CdrWriter {
    /// An empty encoder.
    pub fn new() -> Self {
        CdrWriter { buf: Vec::with_capacity(4096) }
    }

    /// Starts a new message (keeps the buffer's capacity).
    pub fn begin(&mut self) {
        self.buf.clear();
        self.buf.extend_from_slice(&CDR_LE_HEADER);
    }

    /// The message so far, header included.
    pub fn bytes(&self) -> &[u8] {
        &self.buf
    }

    /// The message, owned (the encoder is used up).
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - CDR_LE_HEADER.len();
        let pad = (n - pos % n) % n;
        self.buf.extend(std::iter::repeat_n(0u8, pad));
    }

    /// A u8 or bool.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// A u16.
    pub fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// A u32.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// An i32.
    pub fn i32(&mut self, v: i32) {
        self.u32(v as u32);
    }
    /// A u64.
    pub fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// An f32 (colours).
    pub fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    /// An f64, bit for bit.
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    /// A string.
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    /// Bytes as they are (after a [`len`](Self::len), a `uint8[]`).
    pub fn raw(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }
    /// A sequence length.
    pub fn len(&mut self, n: usize) {
        self.u32(n as u32);
    }
}

/// Why a CDR message could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// The buffer ended inside a value.
    #[error("message ends at byte {at} inside a {what}")]
    Truncated {
        /// Byte offset.
        at: usize,
        /// What was being read.
        what: &'static str,
    },
    /// The encapsulation header is not little-endian plain CDR.
    #[error("not little-endian CDR (header {0:02x?})")]
    Header([u8; 4]),
    /// A string is not NUL-terminated UTF-8.
    #[error("bad string at byte {0}")]
    BadString(usize),
    /// A sequence is longer than the field allows.
    #[error("sequence of {len} at byte {at} exceeds its bound {max}")]
    TooLong {
        /// Byte offset.
        at: usize,
        /// Length found.
        len: usize,
        /// Bound.
        max: usize,
    },
    /// An enumeration value is not known.
    #[error("unknown {what} value {value}")]
    Unknown {
        /// The enumeration.
        what: &'static str,
        /// The value.
        value: u32,
    },
}

/// Reads CDR from a message, checking every bound.
pub struct CdrReader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// A reader over a whole message (header included).
    pub fn new(buf: &'a [u8]) -> Result<Self, CdrError> {
        if buf.len() < 4 {
            return Err(CdrError::Truncated { at: 0, what: "header" });
        }
        let h = [buf[0], buf[1], buf[2], buf[3]];
        if h[..2] != CDR_LE_HEADER[..2] {
            return Err(CdrError::Header(h));
        }
        Ok(CdrReader { buf, pos: 4 })
    }

    /// The byte offset reached.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    fn align(&mut self, n: usize) {
        let rel = self.pos - 4;
        self.pos += (n - rel % n) % n;
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CdrError> {
        if self.pos + n > self.buf.len() {
            return Err(CdrError::Truncated { at: self.pos, what });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// A u8.
    pub fn u8(&mut self) -> Result<u8, CdrError> {
        Ok(self.take(1, "uint8")?[0])
    }
    /// A u16.
    pub fn u16(&mut self) -> Result<u16, CdrError> {
        self.align(2);
        Ok(u16::from_le_bytes(self.take(2, "uint16")?.try_into().unwrap()))
    }
    /// A u32.
    pub fn u32(&mut self) -> Result<u32, CdrError> {
        self.align(4);
        Ok(u32::from_le_bytes(self.take(4, "uint32")?.try_into().unwrap()))
    }
    /// An i32.
    pub fn i32(&mut self) -> Result<i32, CdrError> {
        Ok(self.u32()? as i32)
    }
    /// A u64.
    pub fn u64(&mut self) -> Result<u64, CdrError> {
        self.align(8);
        Ok(u64::from_le_bytes(self.take(8, "uint64")?.try_into().unwrap()))
    }
    /// An f64.
    pub fn f64(&mut self) -> Result<f64, CdrError> {
        Ok(f64::from_bits(self.u64()?))
    }
    /// A string.
    pub fn string(&mut self) -> Result<&'a str, CdrError> {
        let at = self.pos;
        let n = self.u32()? as usize;
        let bytes = self.take(n, "string")?;
        match bytes.split_last() {
            Some((0, s)) => std::str::from_utf8(s).map_err(|_| CdrError::BadString(at)),
            _ => Err(CdrError::BadString(at)),
        }
    }
    /// A `uint8[]` of at most `max` bytes, borrowed.
    pub fn byte_seq(&mut self, max: usize) -> Result<&'a [u8], CdrError> {
        let n = self.len(max)?;
        self.take(n, "uint8[]")
    }
    /// A sequence length, checked against its bound.
    pub fn len(&mut self, max: usize) -> Result<usize, CdrError> {
        let at = self.pos;
        let n = self.u32()? as usize;
        if n > max {
            return Err(CdrError::TooLong { at, len: n, max });
        }
        Ok(n)
    }
}

/// One primitive value of a flattened message, compared by bits.
#[derive(Clone, Copy, Debug)]
pub enum Scalar {
    /// Unsigned.
    U(u64),
    /// Signed.
    I(i64),
    /// Floating point (compared by bits, so NaN equals itself and -0 differs from 0).
    F(f64),
    /// Text that is part of a message (an event's field name).
    S(&'static str),
}

impl PartialEq for Scalar {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Scalar::U(a), Scalar::U(b)) => a == b,
            (Scalar::I(a), Scalar::I(b)) => a == b,
            (Scalar::F(a), Scalar::F(b)) => a.to_bits() == b.to_bits(),
            (Scalar::S(a), Scalar::S(b)) => a == b,
            _ => false,
        }
    }
}

impl fmt::Display for Scalar {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Scalar::U(v) => write!(f, "{v}"),
            Scalar::I(v) => write!(f, "{v}"),
            Scalar::F(v) => write!(f, "{v:e} (bits {:#018x})", v.to_bits()),
            Scalar::S(v) => write!(f, "{v:?}"),
        }
    }
}

/// A type with a ros2msg declaration and a CDR encoding.
pub trait CdrType: Sized {
    /// The type as written in a field declaration: `float64`, `float64[3]`, `strand_msgs/Segment`.
    fn ros_type() -> String;
    /// Appends the definitions of the message types this type uses (name, body), once each.
    fn dependencies(_out: &mut Vec<(String, String)>) {}
    /// Encodes.
    fn write(&self, w: &mut CdrWriter);
    /// Decodes.
    fn read(r: &mut CdrReader) -> Result<Self, CdrError>;
    /// Every primitive with its path, in declaration order.
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>);
}

macro_rules! primitive {
    ($t:ty, $ros:literal, $w:ident, $r:ident, $s:ident) => {
        impl CdrType for $t {
            fn ros_type() -> String {
                $ros.to_string()
            }
            fn write(&self, w: &mut CdrWriter) {
                w.$w(*self)
            }
            fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
                r.$r()
            }
            fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
                out.push((path.to_string(), Scalar::$s((*self).into())));
            }
        }
    };
}
primitive!(u8, "uint8", u8, u8, U);
primitive!(u16, "uint16", u16, u16, U);
primitive!(u32, "uint32", u32, u32, U);
primitive!(u64, "uint64", u64, u64, U);
primitive!(i32, "int32", i32, i32, I);
primitive!(f64, "float64", f64, f64, F);

impl CdrType for bool {
    fn ros_type() -> String {
        "bool".to_string()
    }
    fn write(&self, w: &mut CdrWriter) {
        w.u8(*self as u8)
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(r.u8()? != 0)
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        out.push((path.to_string(), Scalar::U(*self as u64)));
    }
}

impl<T: CdrType + Copy + Default, const N: usize> CdrType for [T; N] {
    fn ros_type() -> String {
        format!("{}[{N}]", T::ros_type())
    }
    fn dependencies(out: &mut Vec<(String, String)>) {
        T::dependencies(out)
    }
    fn write(&self, w: &mut CdrWriter) {
        for v in self {
            v.write(w);
        }
    }
    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        let mut a = [T::default(); N];
        for v in &mut a {
            *v = T::read(r)?;
        }
        Ok(a)
    }
    fn flatten(&self, path: &str, out: &mut Vec<(String, Scalar)>) {
        for (i, v) in self.iter().enumerate() {
            v.flatten(&format!("{path}[{i}]"), out);
        }
    }
}

/// The ros2msg type of a field, found through an accessor (lets the macro below avoid repeating
/// field types).
pub(crate) fn ros_type_of<S, T: CdrType>(_: fn(&S) -> &T) -> String {
    T::ros_type()
}

/// The dependencies of a field's type.
pub(crate) fn dependencies_of<S, T: CdrType>(_: fn(&S) -> &T, out: &mut Vec<(String, String)>) {
    T::dependencies(out)
}

/// Adds a message definition to a dependency list unless it is there already.
pub(crate) fn add_dependency(out: &mut Vec<(String, String)>, name: String, body: impl FnOnce() -> String) {
    if !out.iter().any(|(n, _)| *n == name) {
        let body = body();
        out.push((name, body));
    }
}

/// Implements [`CdrType`] for a struct with `Default`, as a ros2msg message of the given name
/// (`pkg/msg/Type`) whose fields are the listed struct fields, in order.
#[macro_export]
macro_rules! cdr_message {
    ($t:ty, $name:literal, [$($field:ident),* $(,)?]) => {
        impl $crate::log::cdr::CdrType for $t {
            fn ros_type() -> String {
                $name.replace("/msg/", "/")
            }
            fn dependencies(out: &mut Vec<(String, String)>) {
                $( $crate::log::cdr::dependencies_of(|s: &$t| &s.$field, out); )*
                $crate::log::cdr::add_dependency(out, $name.replace("/msg/", "/"), || {
                    let mut body = String::new();
                    $( body += &format!("{} {}\n", $crate::log::cdr::ros_type_of(|s: &$t| &s.$field), stringify!($field)); )*
                    body
                });
            }
            fn write(&self, w: &mut $crate::log::cdr::CdrWriter) {
                $( $crate::log::cdr::CdrType::write(&self.$field, w); )*
            }
            fn read(r: &mut $crate::log::cdr::CdrReader) -> Result<Self, $crate::log::cdr::CdrError> {
                #[allow(clippy::needless_update)]
                let mut v = <$t>::default();
                $( v.$field = $crate::log::cdr::CdrType::read(r)?; )*
                Ok(v)
            }
            fn flatten(&self, path: &str, out: &mut Vec<(String, $crate::log::cdr::Scalar)>) {
                $( $crate::log::cdr::CdrType::flatten(&self.$field, &format!("{path}.{}", stringify!($field)), out); )*
            }
        }
    };
}

/// The full ros2msg schema text of a top-level message type: its own body, then each dependency
/// after a line of 80 `=` and `MSG: pkg/Type`, as rosbag2 and the MCAP ros2msg profile expect.
pub fn schema_text<T: CdrType>() -> String {
    let mut deps = Vec::new();
    T::dependencies(&mut deps);
    let top = T::ros_type();
    let mut text = String::new();
    if let Some((_, body)) = deps.iter().find(|(n, _)| *n == top) {
        text += body;
    }
    for (name, body) in deps.iter().filter(|(n, _)| *n != top) {
        text += &"=".repeat(80);
        text += &format!("\nMSG: {name}\n{body}");
    }
    text
}

/// Encodes one message with a fresh header into `w`.
pub fn encode<T: CdrType>(w: &mut CdrWriter, v: &T) {
    w.begin();
    v.write(w);
}

/// Decodes one whole message; trailing bytes (other than the up-to-3 padding bytes some writers add)
/// are an error because they mean the schema and the encoder disagree.
pub fn decode<T: CdrType>(bytes: &[u8]) -> Result<T, CdrError> {
    let mut r = CdrReader::new(bytes)?;
    let v = T::read(&mut r)?;
    if r.remaining() > 3 {
        return Err(CdrError::TooLong { at: r.pos, len: r.remaining(), max: 0 });
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_counts_from_after_the_header() {
        let mut w = CdrWriter::new();
        w.begin();
        w.u8(1);
        w.f64(2.5);
        w.string("ab");
        w.u16(7);
        let b = w.bytes();
        assert_eq!(&b[..4], &CDR_LE_HEADER);
        assert_eq!(b[4], 1);
        assert_eq!(&b[5..12], &[0; 7]);
        assert_eq!(f64::from_le_bytes(b[12..20].try_into().unwrap()), 2.5);
        assert_eq!(u32::from_le_bytes(b[20..24].try_into().unwrap()), 3);
        assert_eq!(&b[24..27], b"ab\0");
        assert_eq!(b[27], 0);
        assert_eq!(u16::from_le_bytes(b[28..30].try_into().unwrap()), 7);
        let mut r = CdrReader::new(b).unwrap();
        assert_eq!(r.u8().unwrap(), 1);
        assert_eq!(r.f64().unwrap(), 2.5);
        assert_eq!(r.string().unwrap(), "ab");
        assert_eq!(r.u16().unwrap(), 7);
        assert_eq!(r.remaining(), 0);
        assert!(matches!(r.u32(), Err(CdrError::Truncated { .. })));
    }
}
