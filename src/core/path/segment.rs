//! The motion segment: one piece of path as the controller receives it, in the world frame W and SI
//! units. Fixed size and `Copy`, so the real-time queue holds segments by value and the wire type in
//! `strand-wire` can mirror it field for field.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use strand_wire as ipc;
use strand_wire::RejectReason;

/// What a segment asks for: the wire contract's kind, one type on both sides. A line runs from
/// the previous end point to `end`; an arc (or helix, or a spiral as LinuxCNC allows) turns about
/// `centre` counter-clockwise about `normal` by `sweep`; a dwell stands still for `duration`, the
/// extruder pushing `filament` evenly meanwhile (a slicer's retraction).
pub use strand_wire::SegmentKind;

/// Which heater a heat segment is about, and how it holds the job (the wire's enums).
pub use strand_wire::{HeatWait, Heater};

/// The highest target or band a heat segment may name (°C): above any hot end's or bed's rating,
/// so a typo (`M104 S2100`) is refused.
pub const MAX_TEMPERATURE: f64 = 500.0;
/// A [`HeatWait::Range`] band's open ends (°C): absolute zero and 10,000 °C.
pub const OPEN_BAND: [f64; 2] = [-273.15, 10_000.0];

/// The most an arc may turn (rad): 1,000 full turns. A helix of more turns is a program error, not
/// a path (at a 0.2 mm pitch it is 20 cm of spring), and the bound keeps the arc's length and its
/// sampling finite. The G-code parser (`P` turns), the segment file and the engine's intake all
/// check against this one number, so whatever the parser accepts the engine takes.
pub const MAX_ARC_SWEEP: f64 = 1000.0 * std::f64::consts::TAU;

/// Flags on a segment (a bit set, as on the wire).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct SegmentFlags(pub u32);

impl SegmentFlags {
    /// The segment deposits material (filament > 0 on a move).
    pub const EXTRUDE: SegmentFlags = SegmentFlags(1);
    /// A travel move: the nozzle moves without depositing.
    pub const TRAVEL: SegmentFlags = SegmentFlags(1 << 1);
    /// The first segment of a new layer.
    pub const LAYER_START: SegmentFlags = SegmentFlags(1 << 2);
    /// The last segment of the job: the controller stops at its end and reports completion.
    pub const LAST: SegmentFlags = SegmentFlags(1 << 3);

    /// True if every bit of `other` is set.
    pub const fn contains(self, other: SegmentFlags) -> bool {
        self.0 & other.0 == other.0
    }

    /// Self with the bits of `other` set.
    pub const fn with(self, other: SegmentFlags) -> SegmentFlags {
        SegmentFlags(self.0 | other.0)
    }
}

/// One motion segment, world frame W, SI units. It starts where the previous segment ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    /// Sequence number, strictly increasing along a job.
    pub seq: u64,
    /// Line, arc or dwell.
    pub kind: SegmentKind,
    /// End point of the TCP (m, W). For a dwell: the current point.
    pub end: Vector3<f64>,
    /// Arc centre (m, W), in the plane of the arc's start point. Unused for lines and dwells.
    pub centre: Vector3<f64>,
    /// Arc plane normal (unit, W); the arc turns counter-clockwise about it (right-hand rule), so a
    /// G17 G2 (clockwise seen from +z) has normal (0, 0, -1). Unused for lines and dwells.
    pub normal: Vector3<f64>,
    /// Angle swept about `normal` (rad, > 0; 2π for a full circle, more for several turns). Arcs only.
    pub sweep: f64,
    /// Tool orientation at the end of the segment (W); interpolated from the previous one along the
    /// segment.
    pub orientation: UnitQuaternion<f64>,
    /// Programmed speed along the path (m/s, > 0 for lines and arcs).
    pub feed: f64,
    /// Filament to push over the segment (m of filament; negative retracts).
    pub filament: f64,
    /// Dwell time (s, ≥ 0). Dwells only.
    pub duration: f64,
    /// Extrude/travel, layer start, last segment.
    pub flags: SegmentFlags,
    /// The line in the source program this segment came from (1-based; 0 if none).
    pub source_line: u32,
    /// Pressure advance the program set for this segment (s: Klipper's `SET_PRESSURE_ADVANCE`,
    /// Marlin's `M900 K`, RepRapFirmware's `M572 S`); None keeps the config's. The extruder clamps it
    /// to `[extruder] max_pressure_advance`.
    pub pressure_advance: Option<f64>,
    /// Where the cell's external axes (a positioner under the part) are at the segment's end (rad
    /// or m, in the chain order of `[positioner]`; unused entries 0); None: they stay where they
    /// are. Over the segment they move in proportion to the path travelled; the points are then in
    /// the work frame at home (where they lie in W with every external axis at 0).
    pub axes: Option<[f64; ipc::MAX_EXTERNAL_AXES]>,
    /// Heat segments ([`SegmentKind::Heat`]): the heater, the hold, the new target (°C; 0 off,
    /// < 0 keeps the current one) and a [`HeatWait::Range`] band (°C, low and high).
    pub heat: HeatRequest,
}

/// What a heat segment asks for (°C, the wire's exception to SI).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeatRequest {
    /// Which heater.
    pub heater: Heater,
    /// How the job holds.
    pub wait: HeatWait,
    /// The new target (°C; 0 off; < 0 keeps the current target).
    pub target: f64,
    /// The band of a [`HeatWait::Range`] hold (°C, low then high).
    pub band: [f64; 2],
}

impl Default for Segment {
    fn default() -> Self {
        Segment {
            seq: 0,
            kind: SegmentKind::Line,
            end: Vector3::zeros(),
            centre: Vector3::zeros(),
            normal: Vector3::z(),
            sweep: 0.0,
            orientation: UnitQuaternion::identity(),
            feed: 0.0,
            filament: 0.0,
            duration: 0.0,
            flags: SegmentFlags::default(),
            source_line: 0,
            pressure_advance: None,
            axes: None,
            heat: HeatRequest::default(),
        }
    }
}

impl Segment {
    /// True if the segment deposits material.
    pub fn extrudes(&self) -> bool {
        self.flags.contains(SegmentFlags::EXTRUDE)
    }
}

/// Why a segment is not one the path engine can run, judged from its own fields (what depends on
/// the segments before it — the sequence, a dwell's place, an arc's end — the engine checks on
/// intake). `reject` is the wire's reason for it, `field` the field at fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("field `{field}` {reason}")]
pub struct InvalidSegment {
    /// The reason the controller reports on the wire.
    pub reject: RejectReason,
    /// The field at fault (its wire name).
    pub field: &'static str,
    /// What is wrong with it.
    pub reason: &'static str,
}

fn invalid(reject: RejectReason, field: &'static str, reason: &'static str) -> Result<(), InvalidSegment> {
    Err(InvalidSegment { reject, field, reason })
}

impl Segment {
    /// The one check of a segment's own fields, for segments from the wire
    /// ([`TryFrom<&ipc::Segment>`]) and from the offline readers alike: every number finite, a
    /// move's feed > 0, a dwell's duration in [0, 1e6) s (> 0 if it moves filament), a unit
    /// orientation, a pressure advance ≥ 0, an arc's unit normal and sweep in (0, 1,000 turns].
    pub fn check(&self) -> Result<(), InvalidSegment> {
        use RejectReason::{BadFeed, BadGeometry, NonFinite};
        let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
        let q = self.orientation.quaternion();
        for (field, ok) in [
            ("end", finite(&self.end)),
            ("centre", finite(&self.centre)),
            ("normal", finite(&self.normal)),
            ("sweep", self.sweep.is_finite()),
            ("orientation", q.coords.iter().all(|x| x.is_finite())),
            ("feed", self.feed.is_finite()),
            ("filament", self.filament.is_finite()),
            ("duration", self.duration.is_finite()),
            ("pressure_advance", self.pressure_advance.is_none_or(f64::is_finite)),
            ("axes", self.axes.is_none_or(|a| a.iter().all(|x| x.is_finite()))),
        ] {
            if !ok {
                return invalid(NonFinite, field, "is not finite");
            }
        }
        match self.kind {
            SegmentKind::Dwell => {
                if self.duration < 0.0 {
                    return invalid(BadFeed, "duration", "must be >= 0 s");
                }
                if self.duration >= 1e6 {
                    return invalid(BadGeometry, "duration", "must be finite, >= 0 and < 1e6 s");
                }
                if self.filament != 0.0 && self.duration <= 0.0 {
                    return invalid(BadGeometry, "duration", "a dwell that moves filament needs a duration > 0");
                }
            }
            SegmentKind::Line | SegmentKind::Arc => {
                if self.feed <= 0.0 {
                    return invalid(BadFeed, "feed", "must be finite and > 0");
                }
            }
            SegmentKind::Heat => {
                let h = &self.heat;
                if !(h.target.is_finite() && h.band.iter().all(|t| t.is_finite())) {
                    return invalid(NonFinite, "temperature", "is not finite");
                }
                if h.target > MAX_TEMPERATURE {
                    return invalid(BadGeometry, "temperature", "must be <= 500 degC (< 0 keeps the target)");
                }
                if h.target < 0.0 && matches!(h.wait, HeatWait::Heating | HeatWait::Both) {
                    return invalid(BadGeometry, "temperature", "a wait for the target needs a target >= 0 degC");
                }
                if h.wait == HeatWait::Range && !(h.band[0] >= OPEN_BAND[0] && h.band[0] <= h.band[1] && h.band[1] <= OPEN_BAND[1]) {
                    return invalid(BadGeometry, "temperature_range", "must be low <= high within [-273.15, 10000] degC");
                }
                if self.filament != 0.0 || self.duration != 0.0 {
                    return invalid(BadGeometry, "filament", "a heat segment moves nothing (filament and duration 0)");
                }
            }
        }
        if (q.norm() - 1.0).abs() > 1e-6 {
            return invalid(BadGeometry, "orientation", "is not a finite unit quaternion");
        }
        if self.pressure_advance.is_some_and(|k| k < 0.0) {
            return invalid(BadGeometry, "pressure_advance", "must be finite and >= 0 s");
        }
        if self.kind == SegmentKind::Arc {
            if (self.normal.norm() - 1.0).abs() >= 1e-6 {
                return invalid(BadGeometry, "normal", "must be a unit vector");
            }
            if !(self.sweep > 0.0 && self.sweep <= MAX_ARC_SWEEP) {
                return invalid(BadGeometry, "sweep", "must be finite and in (0, 2000π] rad (1,000 turns)");
            }
        }
        Ok(())
    }
}

/// A wire segment as the core's, checked ([`Segment::check`]); an unknown kind, or a non-finite
/// number in any field (used or not), is refused before anything is converted.
impl TryFrom<&ipc::Segment> for Segment {
    type Error = InvalidSegment;

    fn try_from(w: &ipc::Segment) -> Result<Segment, InvalidSegment> {
        let Some(kind) = SegmentKind::from_u32(w.kind) else {
            return Err(InvalidSegment { reject: RejectReason::UnknownKind, field: "kind", reason: "is not a segment kind" });
        };
        let heat = if kind == SegmentKind::Heat {
            let Some(heater) = Heater::from_u32(w.heater) else {
                return Err(InvalidSegment { reject: RejectReason::UnknownKind, field: "heater", reason: "is not a heater" });
            };
            let Some(wait) = HeatWait::from_u32(w.heat_wait) else {
                return Err(InvalidSegment { reject: RejectReason::UnknownKind, field: "heat_wait", reason: "is not a heat wait" });
            };
            HeatRequest { heater, wait, target: w.temperature, band: w.temperature_range }
        } else {
            HeatRequest::default()
        };
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        for (field, ok) in
            [("orientation", finite(&w.orientation)), ("pressure_advance", w.pressure_advance.is_finite()), ("axes", finite(&w.axes))]
        {
            if !ok {
                return Err(InvalidSegment { reject: RejectReason::NonFinite, field, reason: "is not finite" });
            }
        }
        let [qw, qx, qy, qz] = w.orientation;
        let segment = Segment {
            seq: w.seq,
            kind,
            end: Vector3::from(w.end),
            centre: Vector3::from(w.centre),
            normal: Vector3::from(w.normal),
            sweep: w.sweep,
            // Not renormalised: `check` refuses a quaternion that is not unit to 1e-6.
            orientation: UnitQuaternion::new_unchecked(Quaternion::new(qw, qx, qy, qz)),
            feed: w.feed,
            filament: w.filament,
            duration: w.duration,
            flags: SegmentFlags(w.flags & !(ipc::segment_flags::PRESSURE_ADVANCE | ipc::segment_flags::AXES)),
            source_line: w.source_line,
            pressure_advance: (w.flags & ipc::segment_flags::PRESSURE_ADVANCE != 0).then_some(w.pressure_advance),
            axes: (w.flags & ipc::segment_flags::AXES != 0).then_some(w.axes),
            heat,
        };
        segment.check()?;
        // The controller used to renormalise here: keep the bits the engine has always seen.
        Ok(Segment { orientation: UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz)), ..segment })
    }
}
