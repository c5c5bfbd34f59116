//! A KUKA Sunrise controller with an LBR iiwa (7 joints) and an FRI session, as far as the wire
//! shows it, written from `docs/protocols/fri.md` (itself from KUKA's public FRI client SDK 1.x as
//! published in lbr-stack/fri, and the public Java examples): every cycle an `FRIMonitoringMessage`
//! — header (`messageIdentifier` 2380098, its `sequenceCounter` the cycle, `reflectedSequenceCounter`
//! the last command's `sequenceCounter`), robot info (7 drives ACTIVE, NORMAL_OPERATION,
//! AUTOMATIC_MODE, POSITION_CONTROLMODE), monitor data (measured and commanded joints in rad,
//! torques 0 Nm, Unix time stamp), connection info (session state, quality, `sendPeriod` in ms,
//! `receiveMultiplier` 1) and, while an overlay runs, ipo data (the PositionHold's joints in rad,
//! POSITION, JOINT overlay, tracking performance 1 in COMMANDING_ACTIVE, 0 in COMMANDING_WAIT).
//! Every JointValues carries exactly 7 values, unpacked, as the SDK's encoder writes them. The
//! answer is an `FRICommandMessage` (`messageIdentifier` 212993) whose `reflectedSequenceCounter`
//! names the message it answers, with the absolute joint targets (rad) in
//! `commandData.jointPosition`, packed or unpacked. Both messages are encoded and decoded here by
//! hand (protobuf wire format), so the driver's prost schema is checked byte for byte.
//!
//! The session follows the Java application: IDLE → MONITORING_WAIT at the first message →
//! MONITORING_READY once the quality is GOOD → COMMANDING_WAIT `overlay_after` cycles later (the
//! app starts `PositionHold` with the joint overlay at the position last commanded) →
//! COMMANDING_ACTIVE after `wait_cycles` answers that hold the ipo position. The fake's policy,
//! KUKA's not being public: the quality is the share of the last [`QUALITY_WINDOW`] cycles answered
//! in time ([`Quality::from_share`]); the overlay is aborted back to MONITORING_WAIT when it drops
//! below GOOD, and in COMMANDING_ACTIVE on a step faster than the joint's velocity limit over one
//! send period (the robot holds its last target over a missed answer, so the step is taken in
//! one), a non-finite value or an answer without joints. The app then starts its overlay again,
//! unless told not to.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::FakeProtocol;

/// `messageIdentifier` of a monitoring message (robot → client).
pub(crate) const MONITOR_ID: u32 = 2_380_098;
/// `messageIdentifier` of a command message (client → robot).
pub(crate) const COMMAND_ID: u32 = 212_993;
/// The LBR iiwa's joints: every JointValues carries exactly this many.
pub(crate) const JOINTS: usize = 7;
/// How far (rad) an answer in COMMANDING_WAIT may be from the ipo position.
pub(crate) const IPO_TOLERANCE: f64 = 1e-6;
/// The cycles over which the connection quality is rated (fewer at the start).
pub(crate) const QUALITY_WINDOW: u32 = 100;
/// The LBR iiwa 7 R800's axis speeds (deg/s, data sheet; A1..A7).
pub(crate) const IIWA7_SPEED_DEG: [f64; JOINTS] = [98.0, 98.0, 100.0, 130.0, 140.0, 180.0, 180.0];

/// `FRISessionState`, with its wire values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub enum SessionState {
    /// No session (before the first message, after [`FriWatch::close`]).
    #[default]
    Idle = 0,
    /// Monitoring, the quality too low to command.
    MonitoringWait = 1,
    /// Monitoring, the quality good enough to command.
    MonitoringReady = 2,
    /// An overlay motion is starting: the client must hold the ipo position.
    CommandingWait = 3,
    /// The client's joint positions command the robot.
    CommandingActive = 4,
}

impl SessionState {
    /// The state of wire value `v`, if it is one.
    pub fn from_u32(v: u32) -> Option<SessionState> {
        use SessionState::*;
        [Idle, MonitoringWait, MonitoringReady, CommandingWait, CommandingActive].into_iter().find(|s| *s as u32 == v)
    }
}

/// `FRIConnectionQuality`, with its wire values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub enum Quality {
    /// Below 80 % answered in time.
    #[default]
    Poor = 0,
    /// 80 % to 95 %: not enough to command.
    Fair = 1,
    /// 95 % to 99 %: enough to command.
    Good = 2,
    /// 99 % and more.
    Excellent = 3,
}

impl Quality {
    /// The fake's policy: the quality of a link that answered `share` (0..1) of the cycles in time.
    pub(crate) fn from_share(share: f64) -> Quality {
        let levels = [(0.99, Quality::Excellent), (0.95, Quality::Good), (0.80, Quality::Fair)];
        levels.into_iter().find(|(at, _)| share >= *at).map_or(Quality::Poor, |(_, q)| q)
    }

    /// The quality of wire value `v`, if it is one.
    pub fn from_u32(v: u32) -> Option<Quality> {
        [Quality::Poor, Quality::Fair, Quality::Good, Quality::Excellent].into_iter().find(|q| *q as u32 == v)
    }
}

/// How the fake Sunrise application runs its FRI session.
#[derive(Clone, Debug)]
pub struct FriOptions {
    /// `sendPeriod` (ms, 1..=100; `receiveMultiplier` is 1): the run's period.
    pub send_period_ms: u32,
    /// Each joint's velocity limit (rad/s): a commanded step faster over one period aborts.
    pub velocity_limit: [f64; JOINTS],
    /// Cycles in MONITORING_READY before the app starts its overlay (at least one is sent).
    pub overlay_after: u64,
    /// Answers holding the ipo position in COMMANDING_WAIT before COMMANDING_ACTIVE.
    pub wait_cycles: u64,
    /// Whether the app starts its overlay again after an abort.
    pub restart_after_abort: bool,
}

impl Default for FriOptions {
    /// 4 ms, the iiwa 7's speeds, 10 cycles READY, 10 cycles WAIT, restarting.
    fn default() -> FriOptions {
        FriOptions {
            send_period_ms: 4,
            velocity_limit: IIWA7_SPEED_DEG.map(f64::to_radians),
            overlay_after: 10,
            wait_cycles: 10,
            restart_after_abort: true,
        }
    }
}

#[derive(Default)]
struct Shared {
    state: AtomicU32,
    quality: AtomicU32,
    aborts: AtomicU64,
    last_abort: Mutex<String>,
    overlays: AtomicU64,
    active_cycles: AtomicU64,
    wrong_ipo: AtomicU64,
    closed: AtomicBool,
}

/// What a test sees of the fake while `run` owns it: clones share the same counters.
#[derive(Clone, Default)]
pub struct FriWatch(Arc<Shared>);

impl FriWatch {
    /// The session state of the last message sent (or after an abort in an answer).
    pub fn state(&self) -> SessionState {
        SessionState::from_u32(self.0.state.load(Ordering::Relaxed)).unwrap_or(SessionState::Idle)
    }
    /// The connection quality of the last message sent.
    pub fn quality(&self) -> Quality {
        Quality::from_u32(self.0.quality.load(Ordering::Relaxed)).unwrap_or(Quality::Poor)
    }
    /// Overlays aborted (quality, velocity, non-finite or missing joints).
    pub fn aborts(&self) -> u64 {
        self.0.aborts.load(Ordering::Relaxed)
    }
    /// Why the last overlay was aborted ("" if none was), e.g. "A3 velocity 25.000 rad/s > 1.745".
    pub fn last_abort(&self) -> String {
        self.0.last_abort.lock().map_or_else(|e| e.into_inner().clone(), |s| s.clone())
    }
    /// Overlays started (entries into COMMANDING_WAIT); read by the fake's own tests.
    #[cfg(test)]
    pub(crate) fn overlays(&self) -> u64 {
        self.0.overlays.load(Ordering::Relaxed)
    }
    /// Answers in COMMANDING_WAIT that did not hold the ipo position (each restarts the wait); read
    /// by the fake's own tests.
    #[cfg(test)]
    pub(crate) fn wrong_ipo(&self) -> u64 {
        self.0.wrong_ipo.load(Ordering::Relaxed)
    }
    /// Messages sent in COMMANDING_ACTIVE.
    pub fn active_cycles(&self) -> u64 {
        self.0.active_cycles.load(Ordering::Relaxed)
    }
    /// The app closes its `FRISession`: IDLE from the next message on.
    pub fn close(&self) {
        self.0.closed.store(true, Ordering::Relaxed);
    }
}

/// The fake Sunrise controller's FRI side. An answer that aborts the overlay still answers its
/// cycle in time (`Ok`, the axes left at the last target); a malformed one, one with another
/// `messageIdentifier` or with a `jointPosition` of other than 7 values is none (`Err(None)`).
#[derive(Default)]
pub struct FakeFri {
    opts: FriOptions,
    state: SessionState,
    /// Messages sent in `state`.
    in_state: u64,
    /// Bit i: cycle `k - 1 - i` answered in time; `seen` of them are rated.
    window: u128,
    seen: u32,
    /// The current cycle was answered in time.
    answered: bool,
    quality: Quality,
    /// The last command's `sequenceCounter`.
    reflected: u32,
    /// What the drives were last told (rad); the axes of the first message until an answer.
    commanded: Option<[f64; JOINTS]>,
    /// The PositionHold's position (rad), taken when the overlay starts.
    ipo: [f64; JOINTS],
    /// Answers in a row holding `ipo` in COMMANDING_WAIT.
    wait_good: u64,
    aborted: bool,
    /// Unix time of cycle 0 (ns).
    epoch_ns: u64,
    watch: FriWatch,
}

impl FakeFri {
    /// A controller about to open its FRI session, and the handle to watch it.
    pub fn new(opts: FriOptions) -> (FakeFri, FriWatch) {
        let epoch_ns = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
        let fri = FakeFri { opts, epoch_ns, ..FakeFri::default() };
        let watch = fri.watch.clone();
        (fri, watch)
    }

    fn period(&self) -> f64 {
        f64::from(self.opts.send_period_ms.max(1)) * 1e-3
    }

    fn enter(&mut self, next: SessionState) {
        if next == SessionState::CommandingWait {
            self.ipo = self.commanded.unwrap_or_default();
            self.watch.0.overlays.fetch_add(1, Ordering::Relaxed);
        }
        self.state = next;
        self.in_state = 0;
        self.wait_good = 0;
        self.watch.0.state.store(next as u32, Ordering::Relaxed);
    }

    fn abort(&mut self, why: String) {
        self.aborted = true;
        self.enter(SessionState::MonitoringWait);
        self.watch.0.aborts.fetch_add(1, Ordering::Relaxed);
        *self.watch.0.last_abort.lock().unwrap_or_else(|e| e.into_inner()) = why;
    }

    /// The state for the next message, from the quality and the app's schedule.
    fn step(&mut self) {
        use SessionState::*;
        let good = self.quality >= Quality::Good;
        let closed = self.watch.0.closed.load(Ordering::Relaxed);
        if self.state >= CommandingWait && !good && !closed {
            self.abort(format!("connection quality {:?}", self.quality));
        } else {
            let restart = !self.aborted || self.opts.restart_after_abort;
            let next = match self.state {
                _ if closed => Idle,
                Idle => MonitoringWait,
                MonitoringWait if good => MonitoringReady,
                MonitoringReady if !good => MonitoringWait,
                MonitoringReady if restart && self.in_state >= self.opts.overlay_after => CommandingWait,
                CommandingWait if self.wait_good >= self.opts.wait_cycles => CommandingActive,
                s => s,
            };
            if next != self.state {
                self.enter(next);
            }
        }
        self.in_state += 1;
        if self.state == CommandingActive {
            self.watch.0.active_cycles.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl FakeProtocol for FakeFri {
    fn packet(&mut self, k: u64, axes_deg: &[f64], out: &mut Vec<u8>) {
        let mut measured = [0.0; JOINTS];
        for (q, a) in measured.iter_mut().zip(axes_deg) {
            *q = a.to_radians();
        }
        if self.commanded.is_none() {
            self.commanded = Some(measured);
        } else {
            self.window = ((self.window << 1) | u128::from(self.answered)) & ((1u128 << QUALITY_WINDOW) - 1);
            self.seen = (self.seen + 1).min(QUALITY_WINDOW);
        }
        self.answered = false;
        self.quality =
            if self.seen == 0 { Quality::Poor } else { Quality::from_share(f64::from(self.window.count_ones()) / f64::from(self.seen)) };
        self.watch.0.quality.store(self.quality as u32, Ordering::Relaxed);
        self.step();
        let stamp = self.epoch_ns.wrapping_add(k.wrapping_mul(u64::from(self.opts.send_period_ms) * 1_000_000));
        let commanding = self.state >= SessionState::CommandingWait;
        let m = Monitoring {
            sequence: k as u32,
            reflected: self.reflected,
            state: self.state,
            quality: self.quality,
            send_period_ms: self.opts.send_period_ms,
            measured,
            commanded: self.commanded.unwrap_or(measured),
            ipo: commanding.then_some(self.ipo),
            tracking: if self.state == SessionState::CommandingActive { 1.0 } else { 0.0 },
            stamp: ((stamp / 1_000_000_000) as u32, (stamp % 1_000_000_000) as u32),
        };
        encode_monitoring(&m, out);
    }

    fn answer(&mut self, k: u64, bytes: &[u8], axes_deg: &mut [f64]) -> Result<(), Option<u64>> {
        use SessionState::*;
        let cmd = decode_command(bytes).ok_or(None)?;
        if cmd.identifier != COMMAND_ID {
            return Err(None);
        }
        self.reflected = cmd.sequence;
        let seq = k as u32;
        if cmd.reflected != seq {
            // An answer to an older message (within half the counter's range), or none.
            let behind = u64::from(seq.wrapping_sub(cmd.reflected));
            return Err((behind <= k && behind < 1 << 31).then(|| k - behind));
        }
        self.answered = true;
        match self.state {
            Idle | MonitoringWait | MonitoringReady => {}
            CommandingWait => {
                let holds = cmd.joints.is_some_and(|q| q.iter().zip(&self.ipo).all(|(a, b)| (a - b).abs() <= IPO_TOLERANCE));
                if holds {
                    self.wait_good += 1;
                } else {
                    self.wait_good = 0;
                    self.watch.0.wrong_ipo.fetch_add(1, Ordering::Relaxed);
                }
                self.commanded = Some(self.ipo);
                write_deg(axes_deg, &self.ipo);
            }
            CommandingActive => {
                let Some(q) = cmd.joints else {
                    self.abort("no jointPosition in COMMANDING_ACTIVE".into());
                    return Ok(());
                };
                let last = self.commanded.unwrap_or(self.ipo);
                let period = self.period();
                for (i, (&to, &from)) in q.iter().zip(&last).enumerate() {
                    let v = (to - from).abs() / period;
                    if !to.is_finite() {
                        self.abort(format!("A{} not finite", i + 1));
                        return Ok(());
                    }
                    if v > self.opts.velocity_limit[i] * (1.0 + 1e-9) {
                        self.abort(format!("A{} velocity {v:.3} rad/s > {:.3}", i + 1, self.opts.velocity_limit[i]));
                        return Ok(());
                    }
                }
                self.commanded = Some(q);
                write_deg(axes_deg, &q);
            }
        }
        Ok(())
    }
}

fn write_deg(axes_deg: &mut [f64], q: &[f64; JOINTS]) {
    for (a, v) in axes_deg.iter_mut().zip(q) {
        *a = v.to_degrees();
    }
}

/// One `FRIMonitoringMessage`'s content (angles in rad).
#[derive(Clone, Debug, PartialEq)]
pub struct Monitoring {
    /// The robot's `sequenceCounter`.
    pub sequence: u32,
    /// The last command's `sequenceCounter`.
    pub reflected: u32,
    /// `connectionInfo.sessionState`.
    pub state: SessionState,
    /// `connectionInfo.quality`.
    pub quality: Quality,
    /// `connectionInfo.sendPeriod` (ms).
    pub send_period_ms: u32,
    /// `monitorData.measuredJointPosition` (rad).
    pub measured: [f64; JOINTS],
    /// `monitorData.commandedJointPosition` (rad).
    pub commanded: [f64; JOINTS],
    /// `ipoData.jointPosition` (rad); `None`: no ipo data (monitoring).
    pub ipo: Option<[f64; JOINTS]>,
    /// `ipoData.trackingPerformance` (0..1).
    pub tracking: f64,
    /// `monitorData.timestamp`: Unix seconds and nanoseconds.
    pub stamp: (u32, u32),
}

/// A monitoring message's bytes, as the controller sends them.
pub fn monitoring_message(m: &Monitoring) -> Vec<u8> {
    let mut out = Vec::with_capacity(512);
    encode_monitoring(m, &mut out);
    out
}

/// Encodes `m` into `out` (cleared first): fields in tag order, required ones always.
pub(crate) fn encode_monitoring(m: &Monitoring, out: &mut Vec<u8>) {
    const ZERO: [f64; JOINTS] = [0.0; JOINTS];
    out.clear();
    nested(out, 1, |h| {
        uint(h, 1, MONITOR_ID.into());
        uint(h, 2, m.sequence.into());
        uint(h, 3, m.reflected.into());
    });
    nested(out, 2, |r| {
        uint(r, 1, JOINTS as u64); // numberOfJoints
        uint(r, 2, 0); // NORMAL_OPERATION
        for _ in 0..JOINTS {
            uint(r, 5, 2); // driveState ACTIVE, one tag per joint
        }
        uint(r, 6, 2); // AUTOMATIC_MODE
        uint(r, 7, 0); // POSITION_CONTROLMODE
    });
    nested(out, 3, |d| {
        joint_values(d, 1, &m.measured);
        joint_values(d, 2, &ZERO); // measuredTorque
        joint_values(d, 3, &m.commanded);
        joint_values(d, 4, &ZERO); // commandedTorque
        joint_values(d, 5, &ZERO); // externalTorque
        nested(d, 15, |t| {
            uint(t, 1, m.stamp.0.into());
            uint(t, 2, m.stamp.1.into());
        });
    });
    nested(out, 4, |c| {
        uint(c, 1, m.state as u64);
        uint(c, 2, m.quality as u64);
        uint(c, 3, m.send_period_ms.into());
        uint(c, 4, 1); // receiveMultiplier
    });
    if let Some(ipo) = &m.ipo {
        nested(out, 5, |i| {
            joint_values(i, 1, ipo);
            uint(i, 10, 1); // clientCommandMode POSITION
            uint(i, 11, 1); // overlayType JOINT
            double(i, 12, m.tracking);
        });
    }
}

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push(v as u8 | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn key(out: &mut Vec<u8>, field: u32, wire: u32) {
    varint(out, u64::from((field << 3) | wire));
}

fn uint(out: &mut Vec<u8>, field: u32, v: u64) {
    key(out, field, 0);
    varint(out, v);
}

fn double(out: &mut Vec<u8>, field: u32, v: f64) {
    key(out, field, 1);
    out.extend_from_slice(&v.to_le_bytes());
}

/// A length-delimited sub-message: its body written in place, its length put in front after.
fn nested(out: &mut Vec<u8>, field: u32, body: impl FnOnce(&mut Vec<u8>)) {
    key(out, field, 2);
    let start = out.len();
    body(out);
    let mut len = Vec::with_capacity(2);
    varint(&mut len, (out.len() - start) as u64);
    out.splice(start..start, len);
}

/// A `JointValues`: 7 values, one tag each (unpacked), as the SDK writes them.
fn joint_values(out: &mut Vec<u8>, field: u32, q: &[f64; JOINTS]) {
    nested(out, field, |j| q.iter().for_each(|v| double(j, 1, *v)));
}

/// A field's value on the wire.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Wire<'a> {
    Varint(u64),
    Fixed64([u8; 8]),
    Bytes(&'a [u8]),
    Fixed32,
}

fn read_varint(b: &mut &[u8]) -> Option<u64> {
    let mut v = 0u64;
    for i in 0..10 {
        let (&byte, rest) = b.split_first()?;
        *b = rest;
        v |= u64::from(byte & 0x7f) << (7 * i);
        if byte < 0x80 {
            return Some(v);
        }
    }
    None
}

fn take<'a>(b: &mut &'a [u8], n: usize) -> Option<&'a [u8]> {
    if b.len() < n {
        return None;
    }
    let (head, tail) = b.split_at(n);
    *b = tail;
    Some(head)
}

/// The next field (number, value), or `None` if the bytes are malformed (groups included).
fn read_field<'a>(b: &mut &'a [u8]) -> Option<(u64, Wire<'a>)> {
    let key = read_varint(b)?;
    let field = key >> 3;
    let value = match key & 7 {
        0 => Wire::Varint(read_varint(b)?),
        1 => Wire::Fixed64(take(b, 8)?.try_into().ok()?),
        2 => {
            let n = usize::try_from(read_varint(b)?).ok()?;
            Wire::Bytes(take(b, n)?)
        }
        5 => take(b, 4).map(|_| Wire::Fixed32)?,
        _ => return None,
    };
    (field != 0).then_some((field, value))
}

/// One `FRICommandMessage`'s content, as the fake reads it.
#[derive(Clone, Debug, PartialEq)]
pub struct Command {
    /// `header.messageIdentifier`.
    pub identifier: u32,
    /// `header.sequenceCounter` (the client's).
    pub sequence: u32,
    /// `header.reflectedSequenceCounter`: the monitoring message answered.
    pub reflected: u32,
    /// `commandData.jointPosition` (rad), if present.
    pub joints: Option<[f64; JOINTS]>,
}

/// Reads a command message; `None` if malformed, the header incomplete or a `jointPosition` that
/// is not exactly 7 values. Unknown fields are skipped; repeated sub-messages merge.
pub(crate) fn decode_command(bytes: &[u8]) -> Option<Command> {
    let mut header = [None::<u32>; 3];
    let mut joints: Option<Vec<f64>> = None;
    for_fields(bytes, |field, v| match (field, v) {
        (1, Wire::Bytes(h)) => for_fields(h, |f, v| match (f, v) {
            (1..=3, Wire::Varint(x)) => {
                header[f as usize - 1] = Some(x as u32);
                true
            }
            (1..=3, _) => false,
            _ => true,
        }),
        (2, Wire::Bytes(c)) => for_fields(c, |f, v| match (f, v) {
            (1, Wire::Bytes(j)) => {
                let values = joints.get_or_insert_with(Vec::new);
                // Unpacked (a fixed64 per value, as the SDK writes) or packed (one blob).
                for_fields(j, |f, v| match (f, v) {
                    (1, Wire::Fixed64(x)) => doubles_into(values, &x),
                    (1, Wire::Bytes(p)) => doubles_into(values, p),
                    (1, _) => false,
                    _ => true,
                })
            }
            (1, _) => false,
            _ => true,
        }),
        (1 | 2, _) => false,
        _ => true,
    })
    .then_some(())?;
    let [Some(identifier), Some(sequence), Some(reflected)] = header else { return None };
    let joints = joints.map(<[f64; JOINTS]>::try_from).transpose().ok()?;
    Some(Command { identifier, sequence, reflected, joints })
}

/// Appends the little-endian doubles of `bytes` (false if they are not whole).
fn doubles_into(values: &mut Vec<f64>, bytes: &[u8]) -> bool {
    values.extend(bytes.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap_or_default())));
    bytes.len().is_multiple_of(8)
}

/// Calls `f` on each field of `b`: false if the bytes are malformed or `f` says so.
fn for_fields<'a>(mut b: &'a [u8], mut f: impl FnMut(u64, Wire<'a>) -> bool) -> bool {
    while !b.is_empty() {
        match read_field(&mut b) {
            Some((field, v)) if f(field, v) => {}
            _ => return false,
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::SessionState::*;
    use super::*;

    fn fields(mut b: &[u8]) -> Vec<(u64, Wire<'_>)> {
        let mut v = Vec::new();
        while !b.is_empty() {
            v.push(read_field(&mut b).expect("well-formed"));
        }
        v
    }
    fn sub(b: &[u8], field: u64) -> Option<&[u8]> {
        fields(b).into_iter().find_map(|(f, v)| match v {
            Wire::Bytes(s) if f == field => Some(s),
            _ => None,
        })
    }
    fn varints(b: &[u8], field: u64) -> Vec<u64> {
        fields(b).into_iter().filter(|(f, _)| *f == field).map(|(_, v)| if let Wire::Varint(x) = v { x } else { panic!("{v:?}") }).collect()
    }
    /// The values of a JointValues, checking they are unpacked (one fixed64 tag each).
    fn doubles(b: &[u8]) -> Vec<f64> {
        fields(b)
            .into_iter()
            .map(|(f, v)| if let (1, Wire::Fixed64(x)) = (f, v) { f64::from_le_bytes(x) } else { panic!("{v:?}") })
            .collect()
    }

    /// A command message built by hand: header, then `commandData.jointPosition` if given.
    fn command(id: u32, seq: u32, reflected: u32, joints: Option<&[f64]>, packed: bool) -> Vec<u8> {
        let mut out = Vec::new();
        nested(&mut out, 1, |h| [id, seq, reflected].iter().zip(1..).for_each(|(v, f)| uint(h, f, u64::from(*v))));
        if let Some(q) = joints {
            nested(&mut out, 2, |c| {
                nested(c, 1, |j| {
                    if packed {
                        key(j, 1, 2);
                        varint(j, 8 * q.len() as u64);
                        q.iter().for_each(|v| j.extend_from_slice(&v.to_le_bytes()));
                    } else {
                        q.iter().for_each(|v| double(j, 1, *v));
                    }
                })
            });
        }
        out
    }

    /// One cycle of a client with lag-free drives: the packet, the state it shows, the answer.
    fn cycle(
        f: &mut FakeFri,
        k: u64,
        axes: &mut [f64; 7],
        reply: &mut dyn FnMut(u64, SessionState, [f64; 7]) -> Option<Vec<u8>>,
    ) -> SessionState {
        let mut out = Vec::new();
        f.packet(k, axes, &mut out);
        let info = sub(&out, 4).unwrap();
        let state = SessionState::from_u32(varints(info, 1)[0] as u32).unwrap();
        let ipo = sub(&out, 5).map_or([f64::NAN; 7], |i| doubles(sub(i, 1).unwrap()).try_into().unwrap());
        assert_eq!(ipo[0].is_nan(), state < CommandingWait, "ipo data only while commanding");
        if let Some(bytes) = reply(k, state, ipo) {
            assert_eq!(f.answer(k, &bytes, axes), Ok(()));
        }
        state
    }
    fn good(k: u64, s: SessionState, ipo: [f64; 7]) -> Option<Vec<u8>> {
        Some(command(COMMAND_ID, k as u32 + 1000, k as u32, (s >= CommandingWait).then_some(&ipo[..]), false))
    }
    fn fake(restart: bool) -> (FakeFri, FriWatch) {
        FakeFri::new(FriOptions { overlay_after: 3, wait_cycles: 2, restart_after_abort: restart, ..FriOptions::default() })
    }
    const START: [f64; 7] = [10.0, -20.0, 30.0, -40.0, 50.0, -60.0, 70.0];

    #[test]
    fn monitoring_message_round_trips() {
        let m = Monitoring {
            sequence: 300,
            reflected: 77,
            state: CommandingActive,
            quality: Quality::Good,
            send_period_ms: 4,
            measured: [0.1, -0.2, 0.3, -0.4, 0.5, -0.6, 0.7],
            commanded: [1.1, -1.2, 1.3, -1.4, 1.5, -1.6, 1.7],
            ipo: Some([2.1, -2.2, 2.3, -2.4, 2.5, -2.6, 2.7]),
            tracking: 1.0,
            stamp: (1_700_000_000, 123_456_789),
        };
        let b = monitoring_message(&m);
        // Header first, messageIdentifier 2380098 as the varint C2 A2 91 01.
        assert_eq!(&b[..7], &[0x0a, 0x0a, 0x08, 0xc2, 0xa2, 0x91, 0x01]);
        assert!(b.len() < 1500);
        assert_eq!(fields(&b).iter().map(|f| f.0).collect::<Vec<_>>(), [1, 2, 3, 4, 5]);
        let h = sub(&b, 1).unwrap();
        assert_eq!((varints(h, 1), varints(h, 2), varints(h, 3)), (vec![2_380_098], vec![300], vec![77]));
        let r = sub(&b, 2).unwrap();
        assert_eq!((varints(r, 1), varints(r, 2), varints(r, 6), varints(r, 7)), (vec![7], vec![0], vec![2], vec![0]));
        assert_eq!(varints(r, 5), vec![2; 7], "seven driveState tags, unpacked");
        let d = sub(&b, 3).unwrap();
        assert_eq!(&d[..4], &[0x0a, 0x3f, 0x09, 0x9a], "7 × (tag 09 + 8 bytes) = 63");
        assert_eq!(doubles(sub(d, 1).unwrap()), m.measured);
        assert_eq!(doubles(sub(d, 3).unwrap()), m.commanded);
        for torque in [2, 4, 5] {
            assert_eq!(doubles(sub(d, torque).unwrap()), [0.0; 7]);
        }
        let t = sub(d, 15).unwrap();
        assert_eq!((varints(t, 1), varints(t, 2)), (vec![1_700_000_000], vec![123_456_789]));
        let c = sub(&b, 4).unwrap();
        assert_eq!([1, 2, 3, 4].map(|f| varints(c, f)), [vec![4], vec![2], vec![4], vec![1]]);
        let i = sub(&b, 5).unwrap();
        assert_eq!(doubles(sub(i, 1).unwrap()), m.ipo.unwrap());
        assert_eq!((varints(i, 10), varints(i, 11)), (vec![1], vec![1]));
        assert_eq!(fields(i).last(), Some(&(12, Wire::Fixed64(1.0f64.to_le_bytes()))));
        let monitoring = monitoring_message(&Monitoring { state: MonitoringReady, ipo: None, ..m });
        assert!(sub(&monitoring, 5).is_none());
    }

    #[test]
    fn command_decodes_packed_or_not_and_rejects_the_malformed() {
        // Header only, written out: 212993 is the varint 81 80 0D.
        let header_only = [0x0a, 0x08, 0x08, 0x81, 0x80, 0x0d, 0x10, 0x05, 0x18, 0x00];
        assert_eq!(command(COMMAND_ID, 5, 0, None, false), header_only);
        assert_eq!(decode_command(&header_only), Some(Command { identifier: COMMAND_ID, sequence: 5, reflected: 0, joints: None }));
        let q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7];
        for packed in [false, true] {
            assert_eq!(decode_command(&command(COMMAND_ID, 1, 2, Some(&q), packed)).unwrap().joints, Some(q));
        }
        assert_eq!(decode_command(&command(COMMAND_ID, 1, 2, Some(&q[..6]), false)), None);
        assert_eq!(decode_command(&command(COMMAND_ID, 1, 2, Some(&[0.0; 8]), true)), None);
        assert_eq!(decode_command(&header_only[..9]), None);
        assert_eq!(decode_command(&[0x0a, 0x02, 0x08, 0x01]), None, "header incomplete");
        // No input panics: every truncation and a few thousand pseudo-random datagrams.
        let full = command(COMMAND_ID, 1, 2, Some(&q), false);
        (0..full.len()).for_each(|n| {
            let _ = decode_command(&full[..n]);
        });
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for len in 0..4000 {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            let bytes: Vec<u8> = (0..len % 97).map(|i| (x >> (i % 57)) as u8).collect();
            let mut mutated = full.clone();
            mutated[len % full.len()] = (x >> 33) as u8;
            let _ = (decode_command(&bytes), decode_command(&mutated));
        }
    }

    #[test]
    fn session_comes_up_with_answers_that_hold_the_ipo_position() {
        let (mut f, watch) = fake(true);
        let mut axes = START;
        let states: Vec<_> = (0..10).map(|k| cycle(&mut f, k, &mut axes, &mut good)).collect();
        use SessionState::{CommandingActive as CA, CommandingWait as CW, MonitoringReady as MR, MonitoringWait as MW};
        assert_eq!(states, [MW, MR, MR, MR, CW, CW, CA, CA, CA, CA]);
        assert_eq!((watch.state(), watch.active_cycles(), watch.overlays(), watch.aborts()), (CA, 4, 1, 0));
        assert_eq!(watch.quality(), Quality::Excellent);
        // The reflected counter is the last command's sequenceCounter; the ipo position is where
        // the robot stood; a step within the velocity limit moves the axes (degrees).
        let mut ipo0 = [0.0; 7];
        let state = cycle(&mut f, 10, &mut axes, &mut |k, _, ipo| {
            ipo0 = ipo;
            let mut q = ipo;
            q[0] += 0.005; // < 98°/s × 4 ms = 0.00684 rad
            Some(command(COMMAND_ID, 1010, k as u32, Some(&q), true))
        });
        assert_eq!(state, CA);
        assert!(ipo0.iter().zip(START).all(|(q, a)| (q - a.to_radians()).abs() < 1e-12));
        assert!((axes[0] - (START[0].to_radians() + 0.005).to_degrees()).abs() < 1e-9);
        let mut out = Vec::new();
        f.packet(11, &axes, &mut out);
        assert_eq!(varints(sub(&out, 1).unwrap(), 3), vec![1010]);
        assert_eq!(varints(sub(&out, 1).unwrap(), 2), vec![11]);
        assert_eq!(doubles(sub(sub(&out, 3).unwrap(), 3).unwrap())[0], START[0].to_radians() + 0.005);
    }

    #[test]
    fn a_wrong_ipo_answer_restarts_the_wait() {
        let (mut f, watch) = fake(true);
        let mut axes = START;
        let mut off = |k: u64, s: SessionState, mut ipo: [f64; 7]| {
            if k == 5 {
                ipo[6] += 1e-5;
            }
            good(k, s, ipo)
        };
        let states: Vec<_> = (0..9).map(|k| cycle(&mut f, k, &mut axes, &mut off)).collect();
        assert_eq!(&states[4..], [CommandingWait, CommandingWait, CommandingWait, CommandingWait, CommandingActive]);
        assert_eq!((watch.wrong_ipo(), watch.aborts()), (1, 0));
        assert_eq!(axes, START.map(|a| a.to_radians().to_degrees()), "the robot stays at the ipo position");
    }

    #[test]
    fn a_velocity_jump_a_nan_or_no_joints_aborts_and_the_app_restarts() {
        for (bad, why) in [(Some(0.1), "A3 velocity"), (Some(f64::NAN), "A3 not finite"), (None, "no jointPosition")] {
            let (mut f, watch) = fake(true);
            let mut axes = START;
            for k in 0..8 {
                cycle(&mut f, k, &mut axes, &mut good);
            }
            assert_eq!(watch.state(), CommandingActive);
            let held = axes;
            let mut jump = |k: u64, _: SessionState, mut ipo: [f64; 7]| {
                let q = bad.map(|d| {
                    ipo[2] += d;
                    ipo
                });
                Some(command(COMMAND_ID, 0, k as u32, q.as_ref().map(|q| &q[..]), false))
            };
            cycle(&mut f, 8, &mut axes, &mut jump);
            assert_eq!(axes, held, "the robot stops at its last target");
            assert_eq!((watch.state(), watch.aborts()), (MonitoringWait, 1));
            assert!(watch.last_abort().starts_with(why), "{}", watch.last_abort());
            let states: Vec<_> = (9..16).map(|k| cycle(&mut f, k, &mut axes, &mut good)).collect();
            assert_eq!(
                states,
                [MonitoringReady, MonitoringReady, MonitoringReady, CommandingWait, CommandingWait, CommandingActive, CommandingActive]
            );
            assert_eq!(watch.overlays(), 2);
        }
        let (mut f, watch) = fake(false);
        let mut axes = START;
        for k in 0..8 {
            cycle(&mut f, k, &mut axes, &mut good);
        }
        cycle(&mut f, 8, &mut axes, &mut |k, _, _| Some(command(COMMAND_ID, 0, k as u32, Some(&[9.0; 7]), false)));
        let states: Vec<_> = (9..30).map(|k| cycle(&mut f, k, &mut axes, &mut good)).collect();
        assert!(states.iter().all(|s| *s == MonitoringReady), "no restart: {states:?}");
        assert_eq!((watch.aborts(), watch.overlays()), (1, 1));
    }

    #[test]
    fn poor_quality_aborts_the_overlay() {
        let (mut f, watch) = fake(true);
        let mut axes = START;
        for k in 0..40 {
            cycle(&mut f, k, &mut axes, &mut good);
        }
        assert_eq!(watch.state(), CommandingActive);
        // 40 of 40 answered; 40/43 < 95 % after the third missing answer.
        let states: Vec<_> = (40..44).map(|k| cycle(&mut f, k, &mut axes, &mut |_, _, _| None)).collect();
        assert_eq!(states, [CommandingActive, CommandingActive, CommandingActive, MonitoringWait]);
        assert_eq!((watch.aborts(), watch.quality()), (1, Quality::Fair));
        assert!(watch.last_abort().contains("quality"));
        // Answering again: READY once 95 % of the window is in time (76 of 80 at cycle 80), then
        // the app's overlay again.
        let states: Vec<_> = (44..90).map(|k| cycle(&mut f, k, &mut axes, &mut good)).collect();
        assert_eq!(states.iter().position(|s| *s == MonitoringReady), Some(80 - 44));
        assert_eq!((states.last(), watch.overlays(), watch.aborts()), (Some(&CommandingActive), 2, 1));
    }

    #[test]
    fn answers_are_matched_by_their_reflected_counter() {
        let (mut f, watch) = fake(true);
        let (mut axes, mut out) = (START, Vec::new());
        f.packet(0, &axes, &mut out);
        f.packet(1, &axes, &mut out);
        assert_eq!(f.answer(1, &command(COMMAND_ID, 7, 0, None, false), &mut axes), Err(Some(0)));
        assert_eq!(f.answer(1, &command(COMMAND_ID, 8, 5, None, false), &mut axes), Err(None));
        assert_eq!(f.answer(1, &command(MONITOR_ID, 9, 1, None, false), &mut axes), Err(None));
        assert_eq!(f.answer(1, b"<Sen Type=\"ImFree\"/>", &mut axes), Err(None));
        assert_eq!(f.answer(1, &command(COMMAND_ID, 10, 1, Some(&[0.0; 6]), false), &mut axes), Err(None));
        assert_eq!(f.answer(1, &command(COMMAND_ID, 11, 1, None, false), &mut axes), Ok(()));
        assert_eq!(axes, START, "monitoring: a header-only answer moves nothing");
        f.packet(2, &axes, &mut out);
        assert_eq!(varints(sub(&out, 1).unwrap(), 3), vec![11]);
        assert_eq!(watch.quality(), Quality::Poor, "cycle 0 unanswered, cycle 1 answered: 1/2");
    }
}
