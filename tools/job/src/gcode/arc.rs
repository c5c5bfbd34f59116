//! Arcs: centre, sweep and plane of `G2`/`G3` as LinuxCNC reads them, and the length of the
//! (possibly helical, possibly spiral) path.

use std::f64::consts::TAU;

use nalgebra::Vector3;

use super::block::Block;
use super::lexer::Fault;
use strand_core::{Segment, SegmentKind, arc_geometry};

/// Path length (m) of `segment` when it starts at `start` (m): the chord of a line, 0 for a dwell,
/// and for an arc the length of the core's own geometry of it (`strand_core::arc_geometry`, the
/// one home of arc geometry: a helix or spiral measured here is the one the path engine runs).
pub fn segment_length(start: &Vector3<f64>, segment: &Segment) -> f64 {
    match segment.kind {
        SegmentKind::Line => (segment.end - start).norm(),
        SegmentKind::Dwell | SegmentKind::Heat => 0.0,
        // A degenerate arc (start on the axis) is refused by the reader and the engine; its chord
        // is the honest length until then.
        SegmentKind::Arc => arc_geometry(start, segment).map_or((segment.end - start).norm(), |g| g.length(0.0)),
    }
}

/// An arc's geometry, as the segment carries it.
pub(super) struct ArcGeometry {
    pub(super) centre: Vector3<f64>,
    pub(super) normal: Vector3<f64>,
    pub(super) sweep: f64,
}

/// An arc's start and end in plane coordinates (first, second), metres.
pub(super) struct PlaneArc {
    pub(super) start: (f64, f64),
    pub(super) end: (f64, f64),
}

impl PlaneArc {
    pub(super) fn chord(&self) -> f64 {
        libm::hypot(self.end.0 - self.start.0, self.end.1 - self.start.1)
    }
}

/// Turns from the P word: a whole number ≥ 1 (default 1).
pub(super) fn arc_turns(block: &mut Block) -> Result<f64, Fault> {
    let column = block.column(b'P');
    match block.take(b'P')? {
        None => Ok(1.0),
        Some(p) if p >= 1.0 && p.fract() == 0.0 => Ok(p),
        Some(p) => Err(Fault::new(column, format!("P{p}: the number of turns must be a whole number ≥ 1"))),
    }
}

/// Angle (rad, in (0, 2π]) swept from start to end about the centre, clockwise or not.
pub(super) fn arc_sweep(arc: &PlaneArc, centre: (f64, f64), clockwise: bool, full_circle: bool) -> f64 {
    if full_circle {
        return TAU;
    }
    let a0 = libm::atan2(arc.start.1 - centre.1, arc.start.0 - centre.0);
    let a1 = libm::atan2(arc.end.1 - centre.1, arc.end.0 - centre.0);
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    if sweep <= 0.0 {
        sweep += TAU;
    }
    if sweep > TAU { sweep - TAU } else { sweep }
}
