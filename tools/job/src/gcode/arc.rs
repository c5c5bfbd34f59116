//! Arcs: centre, sweep and plane of `G2`/`G3` as LinuxCNC reads them, and the length of the
//! (possibly helical, possibly spiral) path.

use std::f64::consts::{PI, TAU};

use nalgebra::Vector3;

use super::block::Block;
use super::codes::{Motion, PlaneAxes};
use super::interpreter::{Interpreter, bounded, finite};
use super::lexer::Fault;
use super::{MM, ZERO_LENGTH};
use strand_core::{MAX_ARC_SWEEP, Segment, SegmentKind, arc_geometry};

/// Path length (m) of `segment` when it starts at `start` (m): the chord of a line, 0 for a dwell,
/// and for an arc the length of the core's own geometry of it (`strand_core::arc_geometry`, the
/// one home of arc geometry: a helix or spiral measured here is the one the path engine runs).
pub fn segment_length(start: &Vector3<f64>, segment: &Segment) -> f64 {
    match segment.kind {
        SegmentKind::Line => (segment.end - start).norm(),
        SegmentKind::Dwell => 0.0,
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

impl Interpreter {
    pub(super) fn arc(&self, block: &mut Block, motion: Motion, column: usize, target: Vector3<f64>) -> Result<ArcGeometry, Fault> {
        let axes = self.modal.plane.axes();
        let start = self.machine.position;
        let plane = PlaneArc { start: (start[axes.first], start[axes.second]), end: (target[axes.first], target[axes.second]) };
        let clockwise = motion == Motion::Clockwise;
        let centre = if block.has(b'R') {
            self.radius_form_centre(block, &axes, &plane, clockwise, column)?
        } else {
            self.offset_form_centre(block, &axes, column)?
        };
        let full_circle = plane.chord() < ZERO_LENGTH;
        self.check_radii(&plane, centre, column)?;
        let turns_column = block.column(b'P');
        let turns = arc_turns(block)?;
        let sweep = finite(arc_sweep(&plane, centre, clockwise, full_circle) + TAU * (turns - 1.0), column)?;
        if sweep > MAX_ARC_SWEEP {
            let message = format!("P{turns}: the arc sweeps {sweep} rad, more than 1000 turns (2000π rad)");
            return Err(Fault::new(turns_column, message));
        }
        let mut centre3 = start;
        centre3[axes.first] = centre.0;
        centre3[axes.second] = centre.1;
        let mut normal = Vector3::zeros();
        normal[axes.normal] = if clockwise { -1.0 } else { 1.0 };
        Ok(ArcGeometry { centre: centre3, normal, sweep })
    }

    /// Centre from I/J/K: offsets from the start (absolute under G90.1). The normal's offset is an error.
    pub(super) fn offset_form_centre(&self, block: &mut Block, axes: &PlaneAxes, column: usize) -> Result<(f64, f64), Fault> {
        let [first, second, normal] = axes.offsets;
        if block.has(normal) {
            let message = format!("{} word given for an arc in the {}", normal as char, axes.name);
            return Err(Fault::new(block.column(normal), message));
        }
        if !block.has(first) && !block.has(second) {
            return Err(Fault::new(column, format!("arc without a centre: give {} / {} or R", first as char, second as char)));
        }
        let unit = self.modal.unit;
        let (i, j) = (block.take(first)?.unwrap_or(0.0) * unit, block.take(second)?.unwrap_or(0.0) * unit);
        let position = self.machine.position;
        let centre = if self.modal.absolute_arc_centres {
            (i + self.machine.offset[axes.first], j + self.machine.offset[axes.second])
        } else {
            (position[axes.first] + i, position[axes.second] + j)
        };
        Ok((bounded(centre.0, block.column(first))?, bounded(centre.1, block.column(second))?))
    }

    /// Centre from R (LinuxCNC's construction): on the chord's perpendicular bisector, on the side
    /// that makes the arc at most a half circle for R > 0 and at least one for R < 0.
    pub(super) fn radius_form_centre(
        &self,
        block: &mut Block,
        axes: &PlaneAxes,
        arc: &PlaneArc,
        clockwise: bool,
        column: usize,
    ) -> Result<(f64, f64), Fault> {
        let r_column = block.column(b'R');
        let [first, second, normal] = axes.offsets;
        if let Some(letter) = [first, second, normal].into_iter().find(|l| block.has(*l)) {
            return Err(Fault::new(block.column(letter), format!("both R and {} given for one arc", letter as char)));
        }
        let radius = bounded(block.take(b'R')?.unwrap_or(0.0) * self.modal.unit, r_column)?;
        let abs_radius = radius.abs();
        if abs_radius < self.zero_radius() {
            return Err(Fault::new(r_column, "zero radius arc"));
        }
        if arc.chord() < ZERO_LENGTH {
            return Err(Fault::new(column, "R-form arc with its end on its start: the circle is undefined (use I/J/K for a full circle)"));
        }
        let mut half = arc.chord() / 2.0;
        if half - abs_radius > self.tolerance(abs_radius) {
            let message =
                format!("arc radius too small to reach the end point: |R| = {} mm, half chord = {} mm", abs_radius / MM, half / MM);
            return Err(Fault::new(r_column, message));
        }
        half = half.min(abs_radius);
        let mid = ((arc.start.0 + arc.end.0) / 2.0, (arc.start.1 + arc.end.1) / 2.0);
        let chord_angle = libm::atan2(arc.end.1 - arc.start.1, arc.end.0 - arc.start.0);
        let right_side = clockwise == (radius > 0.0);
        let direction = if right_side { chord_angle - PI / 2.0 } else { chord_angle + PI / 2.0 };
        let offset = libm::sqrt((abs_radius - half) * (abs_radius + half));
        Ok((mid.0 + offset * libm::cos(direction), mid.1 + offset * libm::sin(direction)))
    }

    /// Radius tolerance (m) for an arc of radius `radius`.
    pub(super) fn tolerance(&self, radius: f64) -> f64 {
        self.options.arc_radius_tolerance.max(0.001 * radius)
    }

    /// Radii below this (m) are zero: a tenth of the absolute tolerance, as LinuxCNC.
    pub(super) fn zero_radius(&self) -> f64 {
        (0.1 * self.options.arc_radius_tolerance).max(ZERO_LENGTH)
    }

    /// Rejects zero radii and start/end radii further apart than the tolerance.
    pub(super) fn check_radii(&self, arc: &PlaneArc, centre: (f64, f64), column: usize) -> Result<(), Fault> {
        let r0 = libm::hypot(arc.start.0 - centre.0, arc.start.1 - centre.1);
        let r1 = libm::hypot(arc.end.0 - centre.0, arc.end.1 - centre.1);
        if r0 < self.zero_radius() || r1 < self.zero_radius() {
            return Err(Fault::new(column, format!("zero radius arc: start radius {} mm, end radius {} mm", r0 / MM, r1 / MM)));
        }
        let tolerance = self.tolerance(r0.max(r1));
        if (r0 - r1).abs() > tolerance {
            let message = format!(
                "radius to end of arc differs from radius to start: r0 = {:.6} mm, r1 = {:.6} mm, tolerance {:.6} mm",
                r0 / MM,
                r1 / MM,
                tolerance / MM
            );
            return Err(Fault::new(column, message));
        }
        Ok(())
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
