//! The compact replay record: `/strand/ticks`, one `strand_msgs/msg/TickBlock` message per run of
//! consecutive ticks (closed with each chunk, at most [`MAX_BLOCK_TICKS`]).
//!
//! Why it looks like this. A replay needs every tick's *input* bit for bit, and nothing else: the
//! output follows from the input by `Controller::step`. So a block keeps the inputs and timings
//! whole, and of each output only a 16-bit digest (FNV-1a of its CDR, folded, [`output_digest`]) that a
//! replay checks — plus the whole output of the block's first tick, so that a divergence can be
//! named field by field, and a reader sees real values without replaying. What is left is mostly
//! counters that grow by one, stamps that grow by a period, and measured joints that move a little
//! each tick: each column is predicted from the ticks before it (the previous value, or a line or a
//! parabola through the last two or three, whichever leaves the least in this block), and the
//! residuals are stored byte plane by byte plane, so the chunk's zstd sees runs of zeros where
//! the high bytes agree. Every `f64` is predicted on its bit pattern as an integer, which is exact
//! (a wrapping difference) and, within one binade, linear in the value. Nothing of the encoding
//! is lossy: decoding gives back the bits that went in.
//!
//! A block holds (see `TICK_BLOCK_DEFINITION`): the version, the first tick, the count, then
//! - `columns`: one byte `ROW_WORDS`, then per column (`ROW_WORDS` of them, the row layout below) one
//!   byte `order | planes << 4` and `planes × count` bytes, plane k holding byte k of each tick's
//!   zig-zagged residual (the words of a joint or heater state that did not arrive repeat the last
//!   ones, so that a column stays flat between arrivals; the flags say which arrived);
//! - `variable`: a CDR message with, for each tick that received any, its segments (each with its
//!   external axes and heat fields), controls and tracking samples, in tick order (the counts are
//!   in the row);
//! - `keyframe`: the first tick's whole output, as [`super::messages::encode_output`] writes it.
//!
//! One block is one message and decodes alone: a file cut short loses its open chunk and nothing
//! before it.

use strand_ipc as ipc;
use strand_ipc::MAX_JOINTS;

use super::cdr::{CdrError, CdrReader, CdrType, CdrWriter, add_dependency};
use super::messages::{HeatStatus, Tick, TickTiming, encode_output};
use strand_core::{MAX_BASE_POSES_PER_TICK, MAX_CONTROLS_PER_TICK, MAX_SEGMENTS_PER_TICK, TickInput, TickOutput};

/// The block layout's version (in every message).
pub const BLOCK_VERSION: u32 = 1;
/// Most ticks in one block (about a second at 1 kHz; a block closes earlier with each chunk).
pub const MAX_BLOCK_TICKS: usize = 1024;

/// The ros2msg schema of `strand_msgs/msg/TickBlock`.
const TICK_BLOCK_DEFINITION: &str = "\
# strand's compact replay record: a run of consecutive ticks (see the strand log documentation).
uint32 version
uint64 first_tick
uint32 count
uint8[] columns
uint8[] variable
uint8[] keyframe
";

// The row: one u64 per column, every tick.
const W_TICK: usize = 0;
const W_TIME: usize = 1;
/// feeder_lost (bit 0), a joint state (bit 1), a heater state (bit 2), segments << 8, controls << 16,
/// tracking samples << 24.
const W_FLAGS: usize = 2;
const W_CYCLE: usize = 3; // 5 words: overruns, late_wakeups, worst_lateness_ns, log_drops, log_state
const W_TIMING: usize = 8; // 3 words: wake_lateness_ns, step_ns, tick_ns − command_ns
const W_DIGEST: usize = 11;
const W_JOINTS: usize = 12; // seq, stamp_ns, dof | flags << 32, then 5 arrays of MAX_JOINTS
const JOINT_WORDS: usize = 3 + 5 * MAX_JOINTS;
const W_HEATER: usize = W_JOINTS + JOINT_WORDS; // seq, stamp_ns, 4 f64, flags | reserved << 32
const HEATER_WORDS: usize = 7;
const W_STAGES: usize = W_HEATER + HEATER_WORDS; // 2 words: receive_ns, command_ns − (receive_ns + step_ns)
/// Columns in a row.
const ROW_WORDS: usize = W_STAGES + 2;

type Row = [u64; ROW_WORDS];

/// Heat fields per segment in `variable`: heater, wait, target, band low, band high.
const HEAT_PER_SEGMENT: usize = 5;

/// A tick's whole output in CDR (what [`encode_output`] writes), digested to 16 bits: FNV-1a (32
/// bit), its halves xor-folded. `scratch` is reused (no allocation once grown).
///
/// Why 16 bits: a digest only pins the first tick a replay differs at (one chance in 65,536 that
/// it names the tick after); every block's first output is logged whole and compared field by
/// field, so a divergence that lasts is caught exactly within a block. Two more bytes a tick
/// would be a tenth of the record.
pub fn output_digest(scratch: &mut CdrWriter, output: &TickOutput) -> u32 {
    encode_output(scratch, output);
    let h = scratch.bytes().iter().fold(0x811c_9dc5u32, |h, &b| (h ^ u32::from(b)).wrapping_mul(0x0100_0193));
    (h >> 16) ^ (h & 0xffff)
}

/// What the log holds of one tick's output.
#[derive(Clone, Debug)]
pub enum LoggedOutput {
    /// All of it: a `/strand/tick` record (`[log] record = "full"`).
    Whole(Box<TickOutput>),
    /// All of it, as the first tick of a `/strand/ticks` block: a replay still recomputes it.
    Keyframe(Box<TickOutput>),
    /// Its digest only ([`output_digest`]); a replay recomputes the output and checks it.
    Digest(u32),
}

/// One tick as the log holds it: all its input and timing, and its output whole or as a digest.
#[derive(Clone, Debug)]
pub struct TickRecord {
    /// Everything that influenced the tick.
    pub input: Box<TickInput>,
    /// What it cost.
    pub timing: TickTiming,
    /// What it decided.
    pub output: LoggedOutput,
    /// The output's digest (computed for a whole output).
    pub digest: u32,
}

/// Builds blocks on the writer thread. Allocates while it grows to its working size, then not.
pub struct BlockEncoder {
    rows: Vec<Row>,
    /// The last tick's row: a joint or heater state that did not arrive keeps its words (the flags
    /// say it is absent and a decoder ignores them), so a column stays flat between arrivals
    /// instead of jumping to 0 and back.
    last: Row,
    first_tick: u64,
    first_time_ns: u64,
    variable: CdrWriter,
    keyframe: CdrWriter,
    scratch: CdrWriter,
    columns: Vec<u8>,
    residuals: Vec<u64>,
}

impl Default for BlockEncoder {
    fn default() -> Self {
        Self::new()
    }
}

impl BlockEncoder {
    /// An empty block.
    pub fn new() -> Self {
        let mut variable = CdrWriter::new();
        variable.begin();
        BlockEncoder {
            rows: Vec::with_capacity(MAX_BLOCK_TICKS),
            last: [0; ROW_WORDS],
            first_tick: 0,
            first_time_ns: 0,
            variable,
            keyframe: CdrWriter::new(),
            scratch: CdrWriter::new(),
            columns: Vec::new(),
            residuals: Vec::with_capacity(MAX_BLOCK_TICKS),
        }
    }

    /// Ticks in the block.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// No tick in the block.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The block's first tick time (ns, the tick clock), for its message's log time.
    pub fn first_time_ns(&self) -> u64 {
        self.first_time_ns
    }

    /// Whether `t` can join the block: it has room and `t` is the tick after its last.
    pub fn takes(&self, t: &Tick) -> bool {
        self.rows.is_empty() || (self.rows.len() < MAX_BLOCK_TICKS && t.input.tick == self.first_tick + self.rows.len() as u64)
    }

    /// Adds a tick (call [`takes`](Self::takes) first; a tick it would not take starts a new
    /// block after [`finish`](Self::finish)).
    pub fn push(&mut self, t: &Tick) {
        if self.rows.is_empty() {
            self.first_tick = t.input.tick;
            self.first_time_ns = t.input.time_ns;
            encode_output(&mut self.keyframe, &t.output);
        }
        let digest = output_digest(&mut self.scratch, &t.output);
        let mut row = row_of(&t.input, &t.timing, digest);
        if t.input.joint_state.is_none() {
            row[W_JOINTS..W_JOINTS + JOINT_WORDS].copy_from_slice(&self.last[W_JOINTS..W_JOINTS + JOINT_WORDS]);
        }
        if t.input.heater_state.is_none() {
            row[W_HEATER..W_HEATER + HEATER_WORDS].copy_from_slice(&self.last[W_HEATER..W_HEATER + HEATER_WORDS]);
        }
        self.last = row;
        self.rows.push(row);
        let i = &t.input;
        if i.segment_count + i.control_count + i.base_pose_count > 0 {
            write_variable(&mut self.variable, i);
        }
    }

    /// Writes the block as one `TickBlock` message into `w` and empties it. `None` if empty.
    pub fn finish(&mut self, w: &mut CdrWriter) -> Option<()> {
        if self.rows.is_empty() {
            return None;
        }
        self.columns.clear();
        self.columns.push(ROW_WORDS as u8);
        for c in 0..ROW_WORDS {
            encode_column(&self.rows, c, &mut self.residuals, &mut self.columns);
        }
        w.begin();
        w.u32(BLOCK_VERSION);
        w.u64(self.first_tick);
        w.u32(self.rows.len() as u32);
        for part in [&self.columns[..], self.variable.bytes(), self.keyframe.bytes()] {
            w.len(part.len());
            w.raw(part);
        }
        self.rows.clear();
        self.variable.begin();
        Some(())
    }
}

/// Dependencies and schema of the block message (for the writer's channel).
pub struct TickBlockSchema;

impl CdrType for TickBlockSchema {
    fn ros_type() -> String {
        "strand_msgs/TickBlock".to_string()
    }
    fn dependencies(out: &mut Vec<(String, String)>) {
        add_dependency(out, Self::ros_type(), || TICK_BLOCK_DEFINITION.to_string());
    }
    fn write(&self, _: &mut CdrWriter) {}
    fn read(_: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(TickBlockSchema)
    }
    fn flatten(&self, _: &str, _: &mut Vec<(String, super::cdr::Scalar)>) {}
}

fn row_of(i: &TickInput, timing: &TickTiming, digest: u32) -> Row {
    let mut r = [0u64; ROW_WORDS];
    r[W_TICK] = i.tick;
    r[W_TIME] = i.time_ns;
    r[W_FLAGS] = u64::from(i.feeder_lost)
        | u64::from(i.joint_state.is_some()) << 1
        | u64::from(i.heater_state.is_some()) << 2
        | u64::from(i.segment_count) << 8
        | u64::from(i.control_count) << 16
        | u64::from(i.base_pose_count) << 24;
    let c = &i.cycle;
    r[W_CYCLE..W_CYCLE + 5].copy_from_slice(&[c.overruns, c.late_wakeups, c.worst_lateness_ns, c.log_drops, u64::from(c.log_state)]);
    // The timing's stages as the parts they measure (wrapping, so any values round-trip): the
    // tick less the command, the command less receive and step — smaller and less correlated
    // numbers than the running totals.
    let command_part = timing.command_ns.wrapping_sub(timing.receive_ns.wrapping_add(timing.step_ns));
    r[W_TIMING..W_TIMING + 3].copy_from_slice(&[timing.wake_lateness_ns, timing.step_ns, timing.tick_ns.wrapping_sub(timing.command_ns)]);
    r[W_DIGEST] = u64::from(digest);
    r[W_STAGES..W_STAGES + 2].copy_from_slice(&[timing.receive_ns, command_part]);
    if let Some(js) = &i.joint_state {
        let j = &mut r[W_JOINTS..W_JOINTS + JOINT_WORDS];
        j[0] = js.seq;
        j[1] = js.stamp_ns;
        j[2] = u64::from(js.dof) | u64::from(js.flags) << 32;
        for (k, a) in [&js.position, &js.velocity, &js.effort, &js.robot_target, &js.robot_target_velocity].into_iter().enumerate() {
            for (w, v) in j[3 + k * MAX_JOINTS..3 + (k + 1) * MAX_JOINTS].iter_mut().zip(a) {
                *w = v.to_bits();
            }
        }
    }
    if let Some(h) = &i.heater_state {
        let w = &mut r[W_HEATER..W_HEATER + HEATER_WORDS];
        w.copy_from_slice(&[
            h.seq,
            h.stamp_ns,
            h.hot_end.to_bits(),
            h.bed.to_bits(),
            h.hot_end_power.to_bits(),
            h.bed_power.to_bits(),
            u64::from(h.flags) | u64::from(h._reserved) << 32,
        ]);
    }
    r
}

/// The input and timing a row holds (the variable parts come after); returns the digest.
fn input_of(r: &Row, i: &mut TickInput, timing: &mut TickTiming) -> u32 {
    i.reset(r[W_TICK], r[W_TIME]);
    let flags = r[W_FLAGS];
    i.feeder_lost = flags & 1 != 0;
    let c = &r[W_CYCLE..W_CYCLE + 5];
    i.cycle =
        strand_core::CycleCounters { overruns: c[0], late_wakeups: c[1], worst_lateness_ns: c[2], log_drops: c[3], log_state: c[4] as u32 };
    let (step_ns, receive_ns) = (r[W_TIMING + 1], r[W_STAGES]);
    let command_ns = r[W_STAGES + 1].wrapping_add(receive_ns.wrapping_add(step_ns));
    *timing =
        TickTiming { wake_lateness_ns: r[W_TIMING], step_ns, tick_ns: r[W_TIMING + 2].wrapping_add(command_ns), receive_ns, command_ns };
    if flags & 2 != 0 {
        let j = &r[W_JOINTS..W_JOINTS + JOINT_WORDS];
        let mut js = ipc::JointState { seq: j[0], stamp_ns: j[1], dof: j[2] as u32, flags: (j[2] >> 32) as u32, ..Default::default() };
        for (k, a) in [&mut js.position, &mut js.velocity, &mut js.effort, &mut js.robot_target, &mut js.robot_target_velocity]
            .into_iter()
            .enumerate()
        {
            for (v, w) in a.iter_mut().zip(&j[3 + k * MAX_JOINTS..3 + (k + 1) * MAX_JOINTS]) {
                *v = f64::from_bits(*w);
            }
        }
        i.joint_state = Some(js);
    }
    if flags & 4 != 0 {
        let h = &r[W_HEATER..W_HEATER + HEATER_WORDS];
        i.heater_state = Some(ipc::HeaterState {
            seq: h[0],
            stamp_ns: h[1],
            hot_end: f64::from_bits(h[2]),
            bed: f64::from_bits(h[3]),
            hot_end_power: f64::from_bits(h[4]),
            bed_power: f64::from_bits(h[5]),
            flags: h[6] as u32,
            _reserved: (h[6] >> 32) as u32,
        });
    }
    r[W_DIGEST] as u32
}

/// The counts a row's flags give: segments, controls, tracking samples.
fn counts(r: &Row) -> (usize, usize, usize) {
    let f = r[W_FLAGS];
    ((f >> 8 & 0xff) as usize, (f >> 16 & 0xff) as usize, (f >> 24 & 0xff) as usize)
}

fn write_variable(w: &mut CdrWriter, i: &TickInput) {
    for s in i.segments() {
        s.write(w);
        for a in s.axes {
            w.f64(a);
        }
        for x in [f64::from(s.heater), f64::from(s.heat_wait), s.temperature, s.temperature_range[0], s.temperature_range[1]] {
            w.f64(x);
        }
    }
    for c in i.controls() {
        c.write(w);
    }
    for p in i.base_poses() {
        p.write(w);
    }
}

fn read_variable(r: &mut CdrReader, i: &mut TickInput, (segments, controls, poses): (usize, usize, usize)) -> Result<(), CdrError> {
    let too_many = |len, max| CdrError::TooLong { at: 0, len, max };
    if segments > MAX_SEGMENTS_PER_TICK {
        return Err(too_many(segments, MAX_SEGMENTS_PER_TICK));
    }
    if controls > MAX_CONTROLS_PER_TICK {
        return Err(too_many(controls, MAX_CONTROLS_PER_TICK));
    }
    if poses > MAX_BASE_POSES_PER_TICK {
        return Err(too_many(poses, MAX_BASE_POSES_PER_TICK));
    }
    for _ in 0..segments {
        let mut s = ipc::Segment::read(r)?;
        for a in s.axes.iter_mut() {
            *a = r.f64()?;
        }
        let mut heat = [0.0; HEAT_PER_SEGMENT];
        for x in heat.iter_mut() {
            *x = r.f64()?;
        }
        // Small whole numbers written from u32: exact in f64.
        (s.heater, s.heat_wait, s.temperature, s.temperature_range) = (heat[0] as u32, heat[1] as u32, heat[2], [heat[3], heat[4]]);
        i.push_segment(&s);
    }
    for _ in 0..controls {
        i.push_control(&ipc::Control::read(r)?);
    }
    for _ in 0..poses {
        i.push_base_pose(&ipc::BasePose::read(r)?);
    }
    Ok(())
}

/// The value predicted for tick `k` of a column by `order` (0: the previous value, 1: the line
/// through the last two, 2: the parabola through the last three; fewer where the block has not
/// that many yet). Wrapping integer arithmetic: exact and the same on both sides.
fn predict(col: &[u64], k: usize, order: u8) -> u64 {
    if k == 0 {
        return 0;
    }
    match order.min((k - 1).min(2) as u8) {
        0 => col[k - 1],
        1 => col[k - 1].wrapping_mul(2).wrapping_sub(col[k - 2]),
        _ => col[k - 1].wrapping_sub(col[k - 2]).wrapping_mul(3).wrapping_add(col[k - 3]),
    }
}

fn zigzag(d: u64) -> u64 {
    (d << 1) ^ ((d as i64 >> 63) as u64)
}

fn unzigzag(u: u64) -> u64 {
    (u >> 1) ^ (u & 1).wrapping_neg()
}

/// Bytes a residual needs (0 for 0).
fn width(u: u64) -> usize {
    (64 - u.leading_zeros() as usize).div_ceil(8)
}

fn encode_column(rows: &[Row], c: usize, buf: &mut Vec<u64>, out: &mut Vec<u8>) {
    buf.clear();
    buf.extend(rows.iter().map(|r| r[c]));
    let residual = |col: &[u64], k: usize, order: u8| zigzag(col[k].wrapping_sub(predict(col, k, order)));
    let cost = |order: u8| -> usize { (0..buf.len()).map(|k| width(residual(buf, k, order))).sum() };
    let order = (0..3u8).min_by_key(|&o| cost(o)).unwrap_or(0);
    // In place, from the last tick back: a prediction reads only the ticks before.
    for k in (0..buf.len()).rev() {
        buf[k] = residual(buf, k, order);
    }
    let planes = buf.iter().map(|&u| width(u)).max().unwrap_or(0);
    out.push(order | (planes as u8) << 4);
    for p in 0..planes {
        out.extend(buf.iter().map(|&u| (u >> (8 * p)) as u8));
    }
}

/// Decodes one `TickBlock` message into its ticks.
pub fn decode_block(bytes: &[u8]) -> Result<Vec<TickRecord>, CdrError> {
    let mut r = CdrReader::new(bytes)?;
    let version = r.u32()?;
    if version != BLOCK_VERSION {
        return Err(CdrError::Unknown { what: "TickBlock version", value: version });
    }
    let first_tick = r.u64()?;
    let count = r.len(MAX_BLOCK_TICKS)?;
    let columns = r.byte_seq(usize::MAX)?;
    let variable = r.byte_seq(usize::MAX)?;
    let keyframe = r.byte_seq(usize::MAX)?;
    let rows = decode_columns(columns, count)?;
    let mut var = CdrReader::new(variable)?;
    let mut out = Vec::with_capacity(count);
    for (k, row) in rows.iter().enumerate() {
        let mut input = Box::<TickInput>::default();
        let mut timing = TickTiming::default();
        let digest = input_of(row, &mut input, &mut timing);
        if input.tick != first_tick + k as u64 {
            return Err(CdrError::Unknown { what: "tick in TickBlock (not consecutive)", value: k as u32 });
        }
        read_variable(&mut var, &mut input, counts(row))?;
        let output = if k == 0 { LoggedOutput::Keyframe(Box::new(decode_output(keyframe)?)) } else { LoggedOutput::Digest(digest) };
        out.push(TickRecord { input, timing, output, digest });
    }
    Ok(out)
}

fn decode_columns(bytes: &[u8], count: usize) -> Result<Vec<Row>, CdrError> {
    let truncated = |at| CdrError::Truncated { at, what: "TickBlock columns" };
    match bytes.first() {
        Some(&n) if n as usize == ROW_WORDS => {}
        Some(&n) => return Err(CdrError::Unknown { what: "TickBlock row width", value: u32::from(n) }),
        None => return Err(truncated(0)),
    }
    let mut rows = vec![[0u64; ROW_WORDS]; count];
    let mut at = 1;
    let mut col = vec![0u64; count];
    for c in 0..ROW_WORDS {
        let head = *bytes.get(at).ok_or(truncated(at))?;
        at += 1;
        let (order, planes) = (head & 0x0f, (head >> 4) as usize);
        if order > 2 || planes > 8 {
            return Err(CdrError::Unknown { what: "TickBlock column header", value: u32::from(head) });
        }
        let data = bytes.get(at..at + planes * count).ok_or(truncated(at))?;
        at += planes * count;
        for k in 0..count {
            let zz = (0..planes).fold(0u64, |u, p| u | u64::from(data[p * count + k]) << (8 * p));
            col[k] = predict(&col, k, order).wrapping_add(unzigzag(zz));
            rows[k][c] = col[k];
        }
    }
    Ok(rows)
}

/// A whole output as [`encode_output`] wrote it.
pub(crate) fn decode_output(bytes: &[u8]) -> Result<TickOutput, CdrError> {
    let mut r = CdrReader::new(bytes)?;
    let mut out = TickOutput::read(&mut r)?;
    out.base_command = ipc::BaseCommand::read(&mut r)?;
    out.heater = ipc::HeaterCommand::read(&mut r)?;
    HeatStatus::read(&mut r)?.put(&mut out.status);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zigzag_and_prediction_round_trip_every_bit() {
        for d in [0u64, 1, u64::MAX, 1 << 63, 12345, (-7i64) as u64] {
            assert_eq!(unzigzag(zigzag(d)), d);
        }
        assert_eq!(zigzag((-1i64) as u64), 1);
        assert_eq!(width(0), 0);
        assert_eq!(width(255), 1);
        assert_eq!(width(256), 2);
        // A counter is a line: order 1 leaves zeros.
        let col: Vec<u64> = (100..110).collect();
        assert!((2..10).all(|k| predict(&col, k, 1) == col[k]));
        let col = [u64::MAX - 1, u64::MAX, 0, 1];
        assert_eq!(predict(&col, 2, 1), 0);
    }
}
