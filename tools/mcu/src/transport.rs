//! Klipper's message blocks and the host's reliable send window.
//!
//! A block on the wire is `len seq content… crc_hi crc_lo 0x7e`: `len` counts the whole block
//! (5..=64 bytes), `seq` is `0x10 | (sequence & 0x0f)`, the CRC is Klipper's CRC16-CCITT over
//! `len seq content`. The MCU answers every good block with an *ack*: an empty block whose seq is
//! the next sequence it expects; every block it sends carries that same number. A block that
//! arrives out of order is dropped and answered with the same (unchanged) ack, which the host
//! reads as a NAK and retransmits from the oldest unacknowledged block. Blocks not acked within the
//! retransmission timeout (RFC 6298 estimate of the round trip, as Klipper's serialqueue.c) are
//! resent too, with the timeout doubled each time.
//!
//! Nothing here panics on any input: the parser skips to the next sync byte on garbage.

use std::collections::VecDeque;

/// Smallest block: header (2) + trailer (3). An empty block is an ack.
pub const MESSAGE_MIN: usize = 5;
/// Largest block, bytes.
pub const MESSAGE_MAX: usize = 64;
/// Largest content of one block, bytes.
pub const MESSAGE_PAYLOAD_MAX: usize = MESSAGE_MAX - MESSAGE_MIN;
/// The byte that ends every block; after garbage the parser resynchronises on it.
pub const MESSAGE_SYNC: u8 = 0x7e;
/// The high nibble of every sequence byte.
pub const MESSAGE_DEST: u8 = 0x10;
/// The sequence number's bits in the sequence byte.
pub const MESSAGE_SEQ_MASK: u8 = 0x0f;

/// Klipper's CRC16-CCITT (initial 0xffff, the byte-wise form in msgproto.py / crc16_ccitt()).
pub fn crc16_ccitt(buf: &[u8]) -> u16 {
    let mut crc: u16 = 0xffff;
    for &b in buf {
        let mut data = b ^ (crc & 0xff) as u8;
        data ^= (data & 0x0f) << 4;
        let d = u16::from(data);
        crc = ((d << 8) | (crc >> 8)) ^ (d >> 4) ^ (d << 3);
    }
    crc
}

/// Appends `v` as Klipper's variable-length quantity (1..=5 bytes).
///
/// The value is taken as the 32-bit pattern the MCU sees: an `i32` and a `u32` with the same bits
/// encode identically, and small negative numbers are short (the 0x60 sign rule of msgproto.py).
pub fn encode_vlq(out: &mut Vec<u8>, v: u32) {
    let sv = v as i32;
    if !(-(1 << 26)..(3 << 26)).contains(&sv) {
        out.push(((v >> 28) & 0x7f) as u8 | 0x80);
    }
    if !(-(1 << 19)..(3 << 19)).contains(&sv) {
        out.push(((v >> 21) & 0x7f) as u8 | 0x80);
    }
    if !(-(1 << 12)..(3 << 12)).contains(&sv) {
        out.push(((v >> 14) & 0x7f) as u8 | 0x80);
    }
    if !(-(1 << 5)..(3 << 5)).contains(&sv) {
        out.push(((v >> 7) & 0x7f) as u8 | 0x80);
    }
    out.push((v & 0x7f) as u8);
}

/// Parses one VLQ at `*pos`, advancing it. `None` when the buffer ends mid-number or the number
/// is longer than 5 bytes (which no MCU sends).
pub fn decode_vlq(buf: &[u8], pos: &mut usize) -> Option<u32> {
    let mut c = *buf.get(*pos)?;
    *pos += 1;
    let mut v = u32::from(c & 0x7f);
    if c & 0x60 == 0x60 {
        v |= (-0x20i32) as u32;
    }
    let mut n = 1;
    while c & 0x80 != 0 {
        if n >= 5 {
            return None;
        }
        c = *buf.get(*pos)?;
        *pos += 1;
        n += 1;
        v = (v << 7) | u32::from(c & 0x7f);
    }
    Some(v)
}

/// Frames `content` (at most [`MESSAGE_PAYLOAD_MAX`] bytes) as a block with sequence `seq`.
pub fn encode_block(seq: u8, content: &[u8]) -> Vec<u8> {
    debug_assert!(content.len() <= MESSAGE_PAYLOAD_MAX);
    let len = MESSAGE_MIN + content.len();
    let mut out = Vec::with_capacity(len);
    out.push(len as u8);
    out.push(MESSAGE_DEST | (seq & MESSAGE_SEQ_MASK));
    out.extend_from_slice(content);
    let crc = crc16_ccitt(&out);
    out.push((crc >> 8) as u8);
    out.push(crc as u8);
    out.push(MESSAGE_SYNC);
    out
}

/// One good block received.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Block {
    /// The 4-bit sequence number (the sender's next expected sequence, for blocks from the MCU).
    pub seq: u8,
    /// The content between header and trailer (empty for an ack/nak).
    pub content: Vec<u8>,
}

/// Splits an incoming byte stream into blocks, discarding garbage up to the next sync byte.
#[derive(Debug, Default)]
pub struct BlockParser {
    buf: Vec<u8>,
    need_sync: bool,
    /// Bytes thrown away as not part of a valid block (count).
    pub bytes_invalid: u64,
}

impl BlockParser {
    /// A parser with an empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds received bytes and returns every complete, valid block they finish.
    pub fn push(&mut self, data: &[u8]) -> Vec<Block> {
        self.buf.extend_from_slice(data);
        let mut out = Vec::new();
        let mut start = 0;
        loop {
            let rest = &self.buf[start..];
            if rest.is_empty() {
                break;
            }
            if self.need_sync {
                match rest.iter().position(|&b| b == MESSAGE_SYNC) {
                    Some(i) => {
                        self.bytes_invalid += i as u64 + 1;
                        start += i + 1;
                        self.need_sync = false;
                        continue;
                    }
                    None => {
                        self.bytes_invalid += rest.len() as u64;
                        start += rest.len();
                        break;
                    }
                }
            }
            match check_block(rest) {
                Check::NeedMore => break,
                Check::Good(len) => {
                    out.push(Block { seq: rest[1] & MESSAGE_SEQ_MASK, content: rest[2..len - 3].to_vec() });
                    start += len;
                }
                Check::Bad => {
                    if rest[0] == MESSAGE_SYNC {
                        // A stray sync byte between blocks: drop just it.
                        start += 1;
                    } else {
                        self.need_sync = true;
                    }
                }
            }
        }
        self.buf.drain(..start);
        out
    }
}

enum Check {
    NeedMore,
    Good(usize),
    Bad,
}

fn check_block(s: &[u8]) -> Check {
    if s.is_empty() {
        return Check::NeedMore;
    }
    let len = s[0] as usize;
    if !(MESSAGE_MIN..=MESSAGE_MAX).contains(&len) {
        return Check::Bad;
    }
    if s.len() >= 2 && s[1] & !MESSAGE_SEQ_MASK != MESSAGE_DEST {
        return Check::Bad;
    }
    if s.len() < len {
        return Check::NeedMore;
    }
    if s[len - 1] != MESSAGE_SYNC {
        return Check::Bad;
    }
    let crc = crc16_ccitt(&s[..len - 3]);
    if s[len - 3] != (crc >> 8) as u8 || s[len - 2] != crc as u8 {
        return Check::Bad;
    }
    Check::Good(len)
}

/// Smallest retransmission timeout, s (serialqueue.c MIN_RTO).
pub const MIN_RTO: f64 = 0.025;
/// Largest retransmission timeout, s (serialqueue.c MAX_RTO).
pub const MAX_RTO: f64 = 5.0;

#[derive(Debug, Clone)]
struct Sent {
    seq: u64,
    bytes: Vec<u8>,
    sent_time: f64,
    retransmitted: bool,
}

/// The host side of the reliable link: packs commands into blocks, numbers them, keeps them until
/// acked, retransmits on NAK or timeout. Times are host monotonic seconds given by the caller, so
/// the logic is testable without a clock.
#[derive(Debug)]
pub struct SendWindow {
    /// Next sequence number to send (64-bit, unwrapped).
    send_seq: u64,
    /// Next sequence the MCU expects, as last acked (64-bit, unwrapped).
    receive_seq: u64,
    last_ack_seq: u64,
    first_contact: bool,
    ignore_nak_seq: u64,
    sent: VecDeque<Sent>,
    pending: VecDeque<Vec<u8>>,
    /// Bytes the MCU can buffer unacked (its RECEIVE_WINDOW constant), bytes.
    pub receive_window: usize,
    srtt: f64,
    rttvar: f64,
    /// Current retransmission timeout, s.
    pub rto: f64,
    retransmit_at: Option<f64>,
    rtt_sample_seq: Option<u64>,
    /// Blocks sent again (count), for the retransmission tests and statistics.
    pub retransmits: u64,
    /// When the last acked block was sent (host monotonic s), `None` if it was retransmitted.
    pub last_acked_sent_time: Option<f64>,
}

impl Default for SendWindow {
    fn default() -> Self {
        Self::new(192)
    }
}

impl SendWindow {
    /// A window for an MCU that buffers `receive_window` bytes; sequence starts at 0 (a fresh MCU)
    /// and is corrected by the first ack received.
    pub fn new(receive_window: usize) -> Self {
        Self {
            send_seq: 1,
            receive_seq: 1,
            last_ack_seq: 0,
            first_contact: true,
            ignore_nak_seq: 0,
            sent: VecDeque::new(),
            pending: VecDeque::new(),
            receive_window,
            srtt: 0.0,
            rttvar: 0.0,
            rto: MIN_RTO.max(0.1),
            retransmit_at: None,
            rtt_sample_seq: None,
            retransmits: 0,
            last_acked_sent_time: None,
        }
    }

    /// Queues one encoded command (message id + parameters) for sending.
    pub fn queue(&mut self, cmd: Vec<u8>) {
        self.pending.push_back(cmd);
    }

    /// Whether anything waits to be sent or acked.
    pub fn busy(&self) -> bool {
        !self.sent.is_empty() || !self.pending.is_empty()
    }

    /// Blocks sent but not yet acked (count).
    pub fn in_flight(&self) -> usize {
        self.sent.len()
    }

    /// Handles one block from the MCU (any block carries its next expected sequence). Returns
    /// whether it acknowledged new blocks (then [`SendWindow::last_acked_sent_time`] is its
    /// request's send time).
    pub fn on_block(&mut self, seq4: u8, is_ack: bool, now: f64) -> bool {
        let mut advanced = false;
        let delta = u64::from(seq4.wrapping_sub(self.receive_seq as u8) & MESSAGE_SEQ_MASK);
        let rseq = self.receive_seq + delta;
        if rseq != self.receive_seq {
            if rseq > self.send_seq {
                if !self.first_contact {
                    // An ack for a block never sent: stale or corrupt; ignore.
                    return false;
                }
                // First contact with an MCU that expects another number (a previous host left it
                // there): renumber what we sent and send it again with its numbering.
                while let Some(s) = self.sent.pop_back() {
                    let content = s.bytes[2..s.bytes.len() - 3].to_vec();
                    self.pending.push_front(content);
                }
                self.send_seq = rseq;
                self.receive_seq = rseq;
                self.last_ack_seq = rseq;
                self.first_contact = false;
                self.retransmit_at = None;
                self.rtt_sample_seq = None;
                return false;
            }
            self.first_contact = false;
            self.update_receive_seq(rseq, now);
            advanced = true;
        }
        if is_ack {
            if self.last_ack_seq < rseq {
                self.last_ack_seq = rseq;
            } else if rseq > self.ignore_nak_seq && !self.sent.is_empty() {
                // A repeated ack is a NAK: retransmit now.
                self.retransmit_at = Some(now);
            }
        }
        advanced
    }

    fn update_receive_seq(&mut self, rseq: u64, now: f64) {
        let mut sent_time = None;
        if self.sent.is_empty() {
            // An ack for nothing we sent: the connection starts; adopt the MCU's numbering.
            self.send_seq = rseq;
        }
        while let Some(front) = self.sent.front() {
            if front.seq >= rseq {
                break;
            }
            let s = self.sent.pop_front().expect("front exists");
            if s.seq + 1 == rseq {
                sent_time = if s.retransmitted { None } else { Some(s.sent_time) };
            }
        }
        self.receive_seq = rseq;
        self.last_acked_sent_time = sent_time;
        if let (Some(sample), Some(st)) = (self.rtt_sample_seq, sent_time)
            && rseq > sample
        {
            let delta = now - st;
            if self.srtt == 0.0 {
                self.rttvar = delta / 2.0;
                self.srtt = delta * 10.0;
            } else {
                self.rttvar = (3.0 * self.rttvar + (self.srtt - delta).abs()) / 4.0;
                self.srtt = (7.0 * self.srtt + delta) / 8.0;
            }
            self.rto = (self.srtt + (4.0 * self.rttvar).max(0.001)).clamp(MIN_RTO, MAX_RTO);
            self.rtt_sample_seq = None;
        }
        self.retransmit_at = if self.sent.is_empty() { None } else { Some(now + self.rto) };
    }

    /// The bytes to write now: retransmissions due, then new blocks while the window has room.
    pub fn poll_output(&mut self, now: f64) -> Vec<u8> {
        let mut out = Vec::new();
        if let Some(t) = self.retransmit_at
            && now >= t
            && !self.sent.is_empty()
        {
            // Resend everything unacked, in order; an MCU that lost one drops the rest.
            out.push(MESSAGE_SYNC);
            for s in self.sent.iter_mut() {
                out.extend_from_slice(&s.bytes);
                s.retransmitted = true;
                self.retransmits += 1;
            }
            self.ignore_nak_seq = self.send_seq;
            self.rto = (self.rto * 2.0).min(MAX_RTO);
            self.retransmit_at = Some(now + self.rto);
            self.rtt_sample_seq = None;
        }
        loop {
            if self.pending.is_empty() {
                break;
            }
            let in_flight: usize = self.sent.iter().map(|s| s.bytes.len()).sum();
            let mut content = Vec::new();
            while let Some(cmd) = self.pending.front() {
                if content.len() + cmd.len() > MESSAGE_PAYLOAD_MAX {
                    break;
                }
                let cmd = self.pending.pop_front().expect("front exists");
                content.extend_from_slice(&cmd);
            }
            if content.is_empty() {
                // A single command longer than a block can carry: the encoder prevents this.
                self.pending.pop_front();
                continue;
            }
            if in_flight > 0 && in_flight + content.len() + MESSAGE_MIN > self.receive_window {
                // Window full: put the content back as one pending entry and wait for acks.
                self.pending.push_front(content);
                break;
            }
            let seq = self.send_seq;
            let bytes = encode_block(seq as u8, &content);
            out.extend_from_slice(&bytes);
            if self.rtt_sample_seq.is_none() {
                self.rtt_sample_seq = Some(seq);
            }
            self.sent.push_back(Sent { seq, bytes, sent_time: now, retransmitted: false });
            self.send_seq += 1;
            if self.retransmit_at.is_none() {
                self.retransmit_at = Some(now + self.rto);
            }
        }
        out
    }

    /// When [`SendWindow::poll_output`] must run next at the latest (host monotonic s).
    pub fn next_deadline(&self) -> Option<f64> {
        self.retransmit_at
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> u64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        *state >> 33
    }

    #[test]
    fn bytes_match_klippers_msgproto() {
        // Vectors produced by running Klipper's klippy/msgproto.py (encode_msgblock, PT_uint32).
        assert_eq!(encode_block(0, &[1, 0, 40]), vec![8, 16, 1, 0, 40, 94, 159, 126]);
        assert_eq!(encode_block(5, &[]), vec![5, 21, 201, 44, 126]);
        let vectors: &[(i64, &[u8])] = &[
            (0, &[0]),
            (95, &[95]),
            (96, &[128, 96]),
            (-32, &[96]),
            (-33, &[255, 95]),
            (12287, &[223, 127]),
            (12288, &[128, 224, 0]),
            (1000, &[135, 104]),
            (-2, &[126]),
            (0xc000000, &[128, 224, 128, 128, 0]),
            (0x8000_0000, &[136, 128, 128, 128, 0]),
            (-4097, &[255, 223, 127]),
        ];
        for &(v, want) in vectors {
            let mut out = Vec::new();
            encode_vlq(&mut out, v as u32);
            assert_eq!(out, want, "{v}");
        }
    }

    #[test]
    fn crc_matches_klipper_identify_block() {
        // identify offset=0 count=40 in block seq 0; the frame layout and CRC placement.
        let b = encode_block(0, &[0x01, 0x00, 0x28]);
        assert_eq!(b.len(), 8);
        assert_eq!(b[0], 8);
        assert_eq!(b[1], 0x10);
        assert_eq!(*b.last().unwrap(), 0x7e);
        let crc = crc16_ccitt(&b[..5]);
        assert_eq!([b[5], b[6]], [(crc >> 8) as u8, crc as u8]);
        // The standard check value of CRC-16/MCRF4XX (this reflected 0x1021 form) for "123456789".
        assert_eq!(crc16_ccitt(b"123456789"), 0x6f91);
    }

    #[test]
    fn vlq_roundtrip_and_lengths() {
        let cases: &[(i64, usize)] = &[
            (0, 1),
            (95, 1),
            (96, 2),
            (-32, 1),
            (-33, 2),
            (12287, 2),
            (12288, 3),
            (-4096, 2),
            (-4097, 3),
            (0x17ffff, 3),
            (0x180000, 4),
            (0xbffffff, 4),
            (0xc000000, 5),
            (0xffff_ffff, 1), // -1 as u32 is short
            (0x8000_0000, 5),
            (i64::from(i32::MIN), 5),
        ];
        for &(v, n) in cases {
            let mut out = Vec::new();
            encode_vlq(&mut out, v as u32);
            assert_eq!(out.len(), n, "length of {v}");
            let mut pos = 0;
            assert_eq!(decode_vlq(&out, &mut pos), Some(v as u32));
            assert_eq!(pos, n);
        }
        let mut s = 1u64;
        for _ in 0..100_000 {
            let v = lcg(&mut s) as u32 ^ ((lcg(&mut s) as u32) << 16);
            let mut out = Vec::new();
            encode_vlq(&mut out, v);
            let mut pos = 0;
            assert_eq!(decode_vlq(&out, &mut pos), Some(v));
        }
    }

    #[test]
    fn parser_survives_random_bytes_and_resyncs() {
        let mut s = 7u64;
        for round in 0..200 {
            let mut p = BlockParser::new();
            let mut stream = Vec::new();
            let mut expected = Vec::new();
            for i in 0..20 {
                let garbage = (lcg(&mut s) % 12) as usize;
                for _ in 0..garbage {
                    stream.push(lcg(&mut s) as u8);
                }
                // A sync after garbage lets the receiver find the next block (the sender's
                // retransmission always starts with one).
                stream.push(MESSAGE_SYNC);
                let n = (lcg(&mut s) % 20) as usize;
                let content: Vec<u8> = (0..n).map(|_| lcg(&mut s) as u8).collect();
                stream.extend(encode_block(i as u8, &content));
                expected.push(content);
            }
            let mut got = Vec::new();
            let mut pos = 0;
            while pos < stream.len() {
                let k = 1 + (lcg(&mut s) % 9) as usize;
                let end = (pos + k).min(stream.len());
                got.extend(p.push(&stream[pos..end]));
                pos = end;
            }
            let got: Vec<Vec<u8>> = got.into_iter().map(|b| b.content).collect();
            // Random garbage may, rarely, swallow a block (a fake length byte spanning it); every
            // block received must be one of the sent ones, in order, and nearly all arrive.
            let mut it = expected.iter();
            for g in &got {
                assert!(it.any(|e| e == g), "round {round}: unexpected block");
            }
            assert!(got.len() >= 17, "round {round}: only {} of 20 blocks", got.len());
        }
        // Pure noise never panics.
        let mut p = BlockParser::new();
        for _ in 0..100_000 {
            let b = [lcg(&mut s) as u8; 1];
            let _ = p.push(&b);
        }
    }

    #[test]
    fn window_acks_retransmits_on_nak_and_timeout() {
        let mut w = SendWindow::new(192);
        // Connection start: the MCU's first ack says it expects seq 3.
        w.on_block(3, true, 0.0);
        w.queue(vec![1, 2, 3]);
        let out = w.poll_output(0.0);
        assert_eq!(out[1], 0x13);
        assert_eq!(w.in_flight(), 1);
        w.on_block(4, true, 0.001);
        assert_eq!(w.in_flight(), 0);
        // Two blocks, the first lost: the MCU naks with 4 again.
        w.queue(vec![5; 40]);
        w.queue(vec![6; 40]);
        let out = w.poll_output(0.01);
        assert_eq!(out.len(), 2 * 45);
        w.on_block(4, true, 0.012);
        let out = w.poll_output(0.012);
        assert_eq!(out[0], MESSAGE_SYNC);
        assert_eq!(out.len(), 1 + 2 * 45);
        assert_eq!(w.retransmits, 2);
        w.on_block(6, true, 0.02);
        assert!(!w.busy());
        // Timeout: nothing acks, the block goes again after rto.
        w.queue(vec![7]);
        let _ = w.poll_output(1.0);
        assert!(w.poll_output(1.0 + w.rto * 0.5).is_empty());
        let again = w.poll_output(1.0 + w.rto + 1e-6);
        assert!(!again.is_empty());
    }
}
