//! Turning the chosen path into what strand-feed sends: the bead and motion parameters ([`Deposition`]),
//! one segment per step with the tool z axis along −normal, and the segment file writer, the one place the
//! planner touches that format.

use std::path::Path;

use strand_core::{Segment, SegmentFlags, SegmentKind};

use serde::Serialize;

use super::PointCloud;
use strand_cli::error::{Result, ToolError};

/// Bead and motion parameters for the segment stream (SI).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deposition {
    /// Extrusion (line) width w (m).
    pub line_width: f64,
    /// Layer height h (m).
    pub layer_height: f64,
    /// Filament diameter d (m).
    pub filament_diameter: f64,
    /// Print speed (m/s).
    pub speed: f64,
    /// Speed of the travel move to the start (m/s).
    pub travel_speed: f64,
    /// Nozzle tip offset from the surface along its normal (m): one layer height lays the bead onto the
    /// surface; 0 puts the tip on 003's sample points themselves.
    pub standoff: f64,
}

impl Default for Deposition {
    /// A 0.45 mm line, 0.2 mm layers, 1.75 mm filament, 10 mm/s printing, 50 mm/s travel, tip one layer
    /// off the surface.
    fn default() -> Self {
        Deposition {
            line_width: 0.45e-3,
            layer_height: 0.2e-3,
            filament_diameter: 1.75e-3,
            speed: 0.01,
            travel_speed: 0.05,
            standoff: 0.2e-3,
        }
    }
}

impl Deposition {
    /// Filament per metre of path (m/m): Slic3r's bead cross-section A = h(w − h) + π(h/2)² (a rectangle
    /// with round ends) over the filament's area π(d/2)².
    pub(crate) fn filament_per_metre(&self) -> f64 {
        crate::filament_per_metre(self.line_width, self.layer_height, self.filament_diameter)
    }

    /// How far a travel over a gap in the face rises off it (m): five layers, at least 2 mm.
    pub fn lift(&self) -> f64 {
        (5.0 * self.layer_height).max(2.0e-3)
    }

    /// Checks the values; the message names the flag.
    pub fn validate(&self) -> Result<()> {
        crate::positive("line-width", self.line_width)?;
        crate::positive("layer-height", self.layer_height)?;
        crate::positive("filament-diameter", self.filament_diameter)?;
        crate::positive("speed", self.speed)?;
        crate::positive("travel-speed", self.travel_speed)?;
        if self.layer_height > self.line_width {
            return Err(ToolError::Usage(format!(
                "--layer-height = {} m is more than --line-width = {} m",
                self.layer_height, self.line_width
            )));
        }
        if !self.standoff.is_finite() {
            return Err(ToolError::Usage(format!("--standoff = {}: must be finite", self.standoff)));
        }
        Ok(())
    }
}

/// The segment stream for `order` through `cloud`: a travel to the first sample, then one extruding line
/// per step, the last flagged LAST. Each end is the sample point offset by the standoff along its normal
/// (m, bed frame), with the nozzle along −normal (`strand_job::segfile::tool_pointing`: the shortest turn from
/// nozzle-down, π about x for straight up); sequence numbers from 0.
pub fn segments(cloud: &PointCloud, order: &[usize], dep: &Deposition) -> Vec<Segment> {
    segments_on(cloud, order, dep, &|_, _| true)
}

/// [`segments`] on a trimmed face: a step whose chord leaves the face (`on_face` false somewhere along
/// it in (u, v): across a hole, or across a notch of the trim) lays no bead; it becomes a travel lifted
/// [`Deposition::lift`] off the surface (up along the normal, across, down), so the nozzle neither
/// strings melt over the hole nor drags through the part.
pub fn segments_on(cloud: &PointCloud, order: &[usize], dep: &Deposition, on_face: &dyn Fn(f64, f64) -> bool) -> Vec<Segment> {
    let per_m = dep.filament_per_metre();
    let tip = |k: usize, off: f64| {
        let s = &cloud.samples[order[k]];
        (s.point + (dep.standoff + off) * s.normal, strand_job::segfile::tool_pointing(&-s.normal))
    };
    let line = |end, orientation, feed, filament, flags| Segment {
        kind: SegmentKind::Line,
        end,
        orientation,
        feed,
        filament,
        flags,
        ..Segment::default()
    };
    let mut out = Vec::with_capacity(order.len());
    for k in 0..order.len() {
        let (end, orientation) = tip(k, 0.0);
        if k == 0 {
            out.push(line(end, orientation, dep.travel_speed, 0.0, SegmentFlags::TRAVEL.with(SegmentFlags::LAYER_START)));
        } else if chord_on_face(cloud, order[k - 1], order[k], on_face) {
            out.push(line(end, orientation, dep.speed, per_m * (end - tip(k - 1, 0.0).0).norm(), SegmentFlags::EXTRUDE));
        } else {
            let (up, up_orientation) = tip(k - 1, dep.lift());
            let (over, _) = tip(k, dep.lift());
            out.push(line(up, up_orientation, dep.travel_speed, 0.0, SegmentFlags::TRAVEL));
            out.push(line(over, orientation, dep.travel_speed, 0.0, SegmentFlags::TRAVEL));
            out.push(line(end, orientation, dep.travel_speed, 0.0, SegmentFlags::TRAVEL));
        }
    }
    for (k, s) in out.iter_mut().enumerate() {
        s.seq = k as u64;
    }
    if let Some(last) = out.last_mut() {
        last.flags = last.flags.with(SegmentFlags::LAST);
    }
    out
}

/// Steps of `order` whose chord leaves the face (each becomes a lifted travel in [`segments_on`]).
pub fn steps_off_face(cloud: &PointCloud, order: &[usize], on_face: &dyn Fn(f64, f64) -> bool) -> usize {
    order.windows(2).filter(|w| !chord_on_face(cloud, w[0], w[1], on_face)).count()
}

/// The step from sample `a` to sample `b` stays on the face: eight points along its (u, v) chord, the
/// short way round a periodic seam, are on it (a point past the seam is on it a period back or on).
fn chord_on_face(cloud: &PointCloud, a: usize, b: usize, on_face: &dyn Fn(f64, f64) -> bool) -> bool {
    let (du, dv) = cloud.step(a, b);
    let s = &cloud.samples[a];
    let shifts = |period: Option<f64>| match period {
        Some(p) => [0.0, p, -p],
        None => [0.0; 3],
    };
    let (su, sv) = (shifts(cloud.periods[0]), shifts(cloud.periods[1]));
    (1..8).all(|i| {
        let t = i as f64 / 8.0;
        let (u, v) = (s.u + t * du, s.v + t * dv);
        su.iter().any(|x| sv.iter().any(|y| on_face(u + x, v + y)))
    })
}

/// [`segments`] for `layers` layers: layer k runs the path offset k layer heights further along the
/// normal, every other layer backwards, so each starts right above where the one before ended (a step
/// of one layer height along the normal, a travel flagged LAYER_START). Sequence numbers run on.
pub fn layered_segments(
    cloud: &PointCloud,
    order: &[usize],
    dep: &Deposition,
    layers: usize,
    on_face: &dyn Fn(f64, f64) -> bool,
) -> Vec<Segment> {
    let mut out: Vec<Segment> = Vec::with_capacity(order.len() * layers);
    let mut reversed: Vec<usize> = order.to_vec();
    reversed.reverse();
    for k in 0..layers {
        let layer = Deposition { standoff: dep.standoff + k as f64 * dep.layer_height, ..*dep };
        let mut segs = segments_on(cloud, if k % 2 == 0 { order } else { &reversed }, &layer, on_face);
        for s in &mut segs {
            s.seq += out.len() as u64;
            s.flags = SegmentFlags(s.flags.0 & !SegmentFlags::LAST.0);
        }
        out.extend(segs);
    }
    if let Some(last) = out.last_mut() {
        last.flags = last.flags.with(SegmentFlags::LAST);
    }
    out
}

/// How tightly a path's surface bends, from the turn of the normal between successive samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Curvature {
    /// Smallest radius where the surface bends towards the nozzle (concave, m); None if nowhere.
    pub min_concave_radius_m: Option<f64>,
    /// Smallest radius where it bends away (convex, m); None if nowhere.
    pub min_convex_radius_m: Option<f64>,
}

/// The radii of curvature along `order` (steps no longer than `max_step`, m, so a jump between rows
/// is not taken for a bend): for a step from p₀ to p₁ with normals n₀, n₁, κ = |n₁ − n₀| / |p₁ − p₀|,
/// concave where the normals converge ((n₁ − n₀)·(p₁ − p₀) < 0).
pub fn curvature(cloud: &PointCloud, order: &[usize], max_step: f64) -> Curvature {
    let mut c = Curvature::default();
    for w in order.windows(2) {
        let (a, b) = (&cloud.samples[w[0]], &cloud.samples[w[1]]);
        let (dp, dn) = (b.point - a.point, b.normal - a.normal);
        let step = dp.norm();
        if step == 0.0 || step > max_step || dn.norm() < 1e-9 * step {
            continue;
        }
        let radius = step / dn.norm();
        let slot = if dn.dot(&dp) < 0.0 { &mut c.min_concave_radius_m } else { &mut c.min_convex_radius_m };
        *slot = Some(slot.map_or(radius, |r: f64| r.min(radius)));
    }
    c
}

/// Writes the segments as a segment file (`strand_job::segfile`). The one place this module touches that
/// format.
pub fn write_segments(path: &Path, segments: &[Segment], note: &str) -> Result<()> {
    Ok(strand_job::segfile::write_path(path, segments, note).map_err(strand_job::JobError::from)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::fixtures::{bump, curved, robust};
    use crate::surface::{Algorithm, plan, sample};
    use nalgebra::Vector3;
    use std::f64::consts::PI;

    #[test]
    fn segments_follow_the_normal_and_meter_the_filament() {
        let surface = curved();
        let cloud = sample(&surface, &robust(0.01)).unwrap();
        let p = plan(&cloud, Algorithm::WeightedU, None, 10);
        let dep = Deposition::default();
        // Slic3r: A = 0.2·(0.45 − 0.2) + π·0.1² mm² over π·0.875² mm².
        let per_m = (0.2 * 0.25 + PI * 0.01) / (PI * 0.875 * 0.875);
        assert!((dep.filament_per_metre() - per_m).abs() < 1e-15);
        let segs = segments(&cloud, &p.order, &dep);
        assert_eq!(segs.len(), cloud.samples.len());
        assert_eq!(segs[0].flags, SegmentFlags::TRAVEL.with(SegmentFlags::LAYER_START));
        assert_eq!(segs[0].filament, 0.0);
        assert!(segs[1..segs.len() - 1].iter().all(|s| s.flags == SegmentFlags::EXTRUDE && s.feed == dep.speed));
        assert_eq!(segs.last().unwrap().flags, SegmentFlags::EXTRUDE.with(SegmentFlags::LAST));
        let mut length = 0.0;
        for (k, s) in segs.iter().enumerate() {
            let sample = &cloud.samples[p.order[k]];
            assert_eq!(s.seq, k as u64);
            assert!((s.end - (sample.point + 0.2e-3 * sample.normal)).norm() < 1e-15);
            let tool_z = s.orientation * Vector3::z();
            assert!((tool_z + sample.normal).norm() < 1e-12, "nozzle along −normal");
            if k > 0 {
                let step = (s.end - segs[k - 1].end).norm();
                assert!((s.filament - per_m * step).abs() < 1e-15);
                length += step;
            }
        }
        // The standoff makes the concave side's path a little shorter than the samples' polyline.
        assert!(length < p.length && length > 0.99 * p.length);
        // The overhang: past vertical the nozzle points up.
        assert!(segs.iter().any(|s| (s.orientation * Vector3::z()).z > 0.4));
        // Straight up (normal −z, a ceiling) takes the π turn about x.
        let q = strand_job::segfile::tool_pointing(&Vector3::z());
        assert!(((q * Vector3::z()) - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn segment_file_round_trips() {
        let cloud = sample(&bump(), &robust(0.01)).unwrap();
        let p = plan(&cloud, Algorithm::Tsp, None, 10);
        let segs = segments(&cloud, &p.order, &Deposition::default());
        let file = std::env::temp_dir().join(format!("strand-surface-unit-{}.jsonl", std::process::id()));
        write_segments(&file, &segs, "unit test").unwrap();
        let back = strand_job::segfile::read_path(&file, 0).unwrap();
        let _ = std::fs::remove_file(&file);
        assert_eq!(back.note.as_deref(), Some("unit test"));
        // The reader numbers source lines by file line (the header is line 1).
        let read: Vec<Segment> = back.segments.into_iter().map(|(s, _)| s).collect();
        assert_eq!(read.len(), segs.len());
        for (k, (r, s)) in read.iter().zip(&segs).enumerate() {
            assert_eq!(r.source_line as usize, k + 2);
            assert_eq!(Segment { source_line: 0, ..*r }, *s, "segment {k}");
        }
    }
}
