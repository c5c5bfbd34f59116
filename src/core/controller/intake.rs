//! Intake: what the controller takes in and what it refuses. Segments must come in sequence, pass
//! their own check ([`Segment::try_from`]) and the workspace bounds, and not be stale (sent before
//! a stop that ended their job); every refusal (of a segment, a control or a joint state) is
//! counted, and the last one is named in `Status`.

use strand_wire as ipc;
use strand_wire::RejectReason;

use crate::path::{Segment, SegmentKind};

/// Sequence and acceptance state of the intake.
pub(super) struct Intake {
    /// The sequence number the next segment must carry (None: any, a new job starts).
    expected_seq: Option<u64>,
    /// The stamp of the last Stop or emergency stop taken (ns, the feeders' monotonic clock; 0:
    /// none). A segment stamped at or before it was sent for the job that stop ended: without
    /// this, the part of it still in flight (a batch the service had not taken when a stop came
    /// right after the start) would open a new job in Idle that nobody starts, and its feeder
    /// would wait for an end that never comes.
    stop_stamp_ns: u64,
    /// The last accepted segment's sequence number.
    pub(super) last_received_seq: u64,
    /// The last refused segment's sequence number.
    pub(super) last_rejected_seq: u64,
    /// Why the last refusal happened.
    pub(super) last_reject_reason: RejectReason,
    /// Refusals of any input (count).
    pub(super) rejected: u64,
    /// Accepted segments (count).
    pub(super) accepted: u64,
    /// Workspace bounds in W (m): a move must end inside.
    bounds_min: [f64; 3],
    bounds_max: [f64; 3],
}

impl Intake {
    /// An intake that takes any first sequence number, with the workspace bounds (m, W).
    pub(super) fn new(bounds_min: [f64; 3], bounds_max: [f64; 3]) -> Self {
        Intake {
            expected_seq: None,
            stop_stamp_ns: 0,
            last_received_seq: 0,
            last_rejected_seq: 0,
            last_reject_reason: RejectReason::None,
            rejected: 0,
            accepted: 0,
            bounds_min,
            bounds_max,
        }
    }

    /// Counts a refusal (of a segment when `seq` is given).
    pub(super) fn reject(&mut self, seq: Option<u64>, reason: RejectReason) {
        self.rejected += 1;
        self.last_reject_reason = reason;
        if let Some(seq) = seq {
            self.last_rejected_seq = seq;
        }
    }

    /// The segment, if it is the next in sequence, passes its own check and ends inside the
    /// workspace; otherwise the reason and the field.
    pub(super) fn admit(&self, w: &ipc::Segment) -> Result<Segment, (RejectReason, &'static str)> {
        if w.stamp_ns != 0 && w.stamp_ns <= self.stop_stamp_ns {
            return Err((RejectReason::Stale, "stamp_ns"));
        }
        if let Some(expected) = self.expected_seq
            && w.seq != expected
        {
            return Err((RejectReason::SequenceGap, "seq"));
        }
        let segment = Segment::try_from(w).map_err(|e| (e.reject, e.field))?;
        let inside = |p: &[f64; 3]| (0..3).all(|i| p[i] >= self.bounds_min[i] && p[i] <= self.bounds_max[i]);
        // A standstill (dwell, heat) stands where the tool is, whatever point it names.
        if !matches!(segment.kind, SegmentKind::Dwell | SegmentKind::Heat) && !inside(&w.end) {
            return Err((RejectReason::OutOfBounds, "end"));
        }
        Ok(segment)
    }

    /// Records an accepted segment: the next must follow it.
    pub(super) fn accepted(&mut self, seq: u64) {
        self.accepted += 1;
        self.expected_seq = Some(seq.wrapping_add(1));
        self.last_received_seq = seq;
    }

    /// A Stop or an emergency stop stamped `stamp_ns` was taken: segments sent before it are stale.
    pub(super) fn stopped_at(&mut self, stamp_ns: u64) {
        self.stop_stamp_ns = self.stop_stamp_ns.max(stamp_ns);
    }

    /// A job ended or a fault was cleared: the next segment may carry any sequence number.
    pub(super) fn restart_sequence(&mut self) {
        self.expected_seq = None;
    }
}
