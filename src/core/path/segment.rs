//! The motion segment: one piece of path as the controller receives it, in the world frame W and SI
//! units. Fixed size and `Copy`, so the real-time queue holds segments by value and the wire type in
//! `strand-ipc` can mirror it field for field.

use nalgebra::{UnitQuaternion, Vector3};

/// What a segment asks for: the wire contract's kind, one type on both sides. A line runs from
/// the previous end point to `end`; an arc (or helix, or a spiral as LinuxCNC allows) turns about
/// `centre` counter-clockwise about `normal` by `sweep`; a dwell stands still for `duration`, the
/// extruder pushing `filament` evenly meanwhile (a slicer's retraction).
pub use strand_ipc::SegmentKind;

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
        }
    }
}

impl Segment {
    /// True if the segment deposits material.
    pub fn extrudes(&self) -> bool {
        self.flags.contains(SegmentFlags::EXTRUDE)
    }
}
