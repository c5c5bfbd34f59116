//! The interpreter's `G2`/`G3`: an arc's centre, sweep and plane read from the block in the
//! interpreter's modal state (plane, units, distance mode), with the geometry of [`super::super::arc`].

use std::f64::consts::{PI, TAU};

use nalgebra::Vector3;

use super::super::arc::{ArcGeometry, PlaneArc, arc_sweep, arc_turns};
use super::super::block::Block;
use super::super::codes::{Motion, PlaneAxes};
use super::super::lexer::{Fault, bounded, finite};
use super::super::{MM, ZERO_LENGTH};
use super::Interpreter;
use strand_core::MAX_ARC_SWEEP;

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
