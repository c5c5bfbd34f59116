//! How the robot's bytes reach the driver, without the socket: a datagram is one packet (EGM, RSI,
//! FRI), or a byte stream is cut into packets by the protocol's framing (b-CAP, RTDE, the
//! Meca500's text messages). The cutting is where a stream driver goes wrong — a packet split over
//! two reads, two packets in one, garbage after a reconnect — so it lives here once, tested once,
//! and each protocol says only where its next packet ends ([`crate::protocol::RobotProtocol::frame`]).

/// What carries the robot's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// UDP: each datagram is one packet, whole or lost.
    Datagram,
    /// TCP: framed bytes of a stream, cut by [`crate::protocol::RobotProtocol::frame`] in a
    /// [`StreamBuffer`].
    Stream,
}

/// Where the next packet is, at the front of a stream's buffered bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Frame {
    /// A whole packet of this many bytes (its terminator included).
    Packet(usize),
    /// This many bytes at the front are no packet (garbage before a start byte, a length out of
    /// range, a packet without its end byte): dropped and counted, and the search goes on.
    Skip(usize),
    /// The front packet is not whole yet: wait for more bytes.
    Incomplete,
    /// The stream cannot be resynchronised (RTDE has no start byte: a size below its header's means
    /// every later byte is misread); the connection is lost, for this reason.
    Lost(String),
}

/// A stream that lost its framing (see [`Frame::Lost`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the stream lost its framing: {0}")]
pub struct FramingLost(pub String);

/// A stream's bytes as they came, cut into packets by a framing rule. Reads go straight into its
/// spare capacity ([`StreamBuffer::spare`]) and packets are handed out as slices of it: nothing is
/// allocated once the buffer has grown to the largest burst.
#[derive(Debug, Default)]
pub struct StreamBuffer {
    buf: Vec<u8>,
    /// Bytes dropped as no packet, since the start.
    skipped: u64,
}

impl StreamBuffer {
    /// An empty buffer with room for `capacity` bytes.
    pub fn with_capacity(capacity: usize) -> StreamBuffer {
        StreamBuffer { buf: Vec::with_capacity(capacity), skipped: 0 }
    }

    /// Room for the next read of up to `n` bytes: read into it, then call
    /// [`StreamBuffer::filled`] with how many came.
    pub fn spare(&mut self, n: usize) -> &mut [u8] {
        let at = self.buf.len();
        self.buf.resize(at + n, 0);
        &mut self.buf[at..]
    }

    /// `n` bytes were read into the slice of `asked` bytes [`StreamBuffer::spare`] gave.
    pub fn filled(&mut self, asked: usize, n: usize) {
        let keep = self.buf.len() - asked + n.min(asked);
        self.buf.truncate(keep);
    }

    /// Takes bytes read elsewhere.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The length of the next whole packet at the front, as `frame` finds it (dropping and counting
    /// what it skips); None until one is whole. Read it with [`StreamBuffer::packet`], then
    /// [`StreamBuffer::consume`] it.
    pub fn next_len(&mut self, frame: impl Fn(&[u8]) -> Frame) -> Result<Option<usize>, FramingLost> {
        loop {
            if self.buf.is_empty() {
                return Ok(None);
            }
            match frame(&self.buf) {
                Frame::Packet(0) | Frame::Skip(0) => return Err(FramingLost("the framing found an empty packet".into())),
                Frame::Packet(n) if n <= self.buf.len() => return Ok(Some(n)),
                // A framing that says more than is buffered is not whole yet.
                Frame::Packet(_) | Frame::Incomplete => return Ok(None),
                Frame::Skip(n) => {
                    let n = n.min(self.buf.len());
                    self.skipped += n as u64;
                    self.buf.drain(..n);
                }
                Frame::Lost(why) => return Err(FramingLost(why)),
            }
        }
    }

    /// The front `len` bytes: a packet [`StreamBuffer::next_len`] found.
    pub fn packet(&self, len: usize) -> &[u8] {
        &self.buf[..len.min(self.buf.len())]
    }

    /// Drops the front `len` bytes.
    pub fn consume(&mut self, len: usize) {
        self.buf.drain(..len.min(self.buf.len()));
    }

    /// Bytes buffered and not yet consumed.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Bytes dropped as no packet since the start.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// Forgets everything buffered (a new connection).
    pub fn clear(&mut self) {
        self.buf.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A toy framing: `[` starts a packet, `]` ends it; anything before `[` is garbage; a `[`
    /// inside a packet means the one before was cut (skip to it); `!` loses the stream.
    fn brackets(b: &[u8]) -> Frame {
        if b[0] == b'!' {
            return Frame::Lost("a bang".into());
        }
        if b[0] != b'[' {
            return Frame::Skip(b.iter().position(|c| *c == b'[').unwrap_or(b.len()));
        }
        match b[1..].iter().position(|c| *c == b']' || *c == b'[') {
            Some(k) if b[k + 1] == b']' => Frame::Packet(k + 2),
            Some(k) => Frame::Skip(k + 1),
            None => Frame::Incomplete,
        }
    }

    #[test]
    fn packets_split_over_reads_and_packed_in_one_come_out_whole_and_garbage_is_counted() {
        let mut s = StreamBuffer::with_capacity(64);
        s.push(b"xx[ab");
        assert_eq!(s.next_len(brackets), Ok(None));
        assert_eq!(s.skipped(), 2);
        let spare = s.spare(16);
        spare[..9].copy_from_slice(b"c][d][e[f");
        s.filled(16, 9);
        assert_eq!(s.buffered(), 12);
        let n = s.next_len(brackets).unwrap().unwrap();
        assert_eq!(s.packet(n), b"[abc]");
        s.consume(n);
        let n = s.next_len(brackets).unwrap().unwrap();
        assert_eq!(s.packet(n), b"[d]");
        s.consume(n);
        // "[e" was cut by "[f": skipped, and "[f" waits for its end.
        assert_eq!(s.next_len(brackets), Ok(None));
        assert_eq!((s.skipped(), s.buffered()), (4, 2));
        s.push(b"]!");
        let n = s.next_len(brackets).unwrap().unwrap();
        assert_eq!(s.packet(n), b"[f]");
        s.consume(n);
        assert_eq!(s.next_len(brackets), Err(FramingLost("a bang".into())));
        s.clear();
        assert_eq!((s.next_len(brackets), s.buffered()), (Ok(None), 0));
    }

    #[test]
    fn a_framing_that_finds_nothing_cannot_spin() {
        let mut s = StreamBuffer::default();
        s.push(b"abc");
        assert!(s.next_len(|_| Frame::Skip(0)).is_err());
        assert!(s.next_len(|_| Frame::Packet(0)).is_err());
        // A length beyond what is buffered waits.
        assert_eq!(s.next_len(|_| Frame::Packet(10)), Ok(None));
    }
}
