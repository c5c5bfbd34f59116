//! Reading a G-code job into what the split works on: the extruding lines of each layer, arcs flattened
//! to chords, skirt and brim dropped. Only this file drives the G-code reader; everything after it sees
//! [`Line`]s grouped into [`Layer`]s.

use std::collections::HashMap;
use std::io::BufRead;

use nalgebra::Vector3;
use strand_cli::error::{Result, ToolError};
use strand_core::{Geometry, Segment, SegmentKind, arc_geometry};
use strand_job::gcode::{GcodeOptions, Parser};

/// One extruding straight line (m, G-code frame).
#[derive(Clone, Debug, PartialEq)]
pub struct Line {
    /// Start point.
    pub a: Vector3<f64>,
    /// End point.
    pub b: Vector3<f64>,
    /// Filament pushed along it (m of filament, > 0).
    pub filament: f64,
    /// Programmed speed (m/s).
    pub feed: f64,
    /// Source line in the input G-code (1-based).
    pub source_line: usize,
}

impl Line {
    /// Length (m).
    pub fn length(&self) -> f64 {
        (self.b - self.a).norm()
    }

    /// The same line traversed the other way.
    pub fn reversed(&self) -> Line {
        Line { a: self.b, b: self.a, ..self.clone() }
    }
}

/// The extruding lines of one layer, in job order.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// Nominal height (m): the `;Z:` marker if the slicer wrote one, else the first line's end z.
    pub z: f64,
    /// The layer's extruding lines, in job order.
    pub lines: Vec<Line>,
}

/// What was read from a job.
#[derive(Clone, Debug, PartialEq)]
pub struct Job {
    /// File name, for reports.
    pub name: String,
    /// Layers in the order they first appear.
    pub layers: Vec<Layer>,
    /// `"tags"` when the slicer's layer markers grouped the lines, `"z"` when their height did.
    pub layer_source: &'static str,
    /// Arcs flattened to chords.
    pub arcs_flattened: usize,
    /// Skirt/brim lines dropped, and their filament (m).
    pub skirt_lines: usize,
    /// The filament of those lines (m).
    pub skirt_filament: f64,
}

impl Job {
    /// Every extruding line, layer by layer.
    pub fn lines(&self) -> impl Iterator<Item = &Line> {
        self.layers.iter().flat_map(|l| l.lines.iter())
    }

    /// Filament over all kept lines (m).
    pub fn filament(&self) -> f64 {
        self.lines().map(|l| l.filament).sum()
    }

    /// Extruded path length over all kept lines (m).
    pub fn path_length(&self) -> f64 {
        self.lines().map(Line::length).sum()
    }
}

/// How to read a job.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReadOptions {
    /// Largest sagitta (m) of the chords replacing an arc.
    pub arc_tolerance: f64,
    /// Keep skirt and brim lines.
    pub keep_skirt: bool,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions { arc_tolerance: 1e-5, keep_skirt: false }
    }
}

fn is_skirt(feature: Option<&str>) -> bool {
    feature.is_some_and(|f| {
        let f = f.to_ascii_lowercase();
        f.contains("skirt") || f.contains("brim")
    })
}

/// Reads the extruding lines of a job, grouped per layer (by the slicer's layer markers if every kept
/// line has one, else by the height of the line's end, to 1 µm). Errors name file and line.
pub fn read_job<R: BufRead>(parser: &mut Parser<R>, name: &str, options: &ReadOptions) -> Result<Job> {
    let mut start = GcodeOptions::default().start;
    let mut raw: Vec<(Option<i32>, Option<f64>, Line)> = Vec::new();
    let (mut arcs, mut skirt_lines, mut skirt_filament) = (0usize, 0usize, 0.0);
    for item in parser.by_ref() {
        let g = item?;
        let s = &g.segment;
        let from = start;
        start = s.end;
        if !s.extrudes() {
            continue;
        }
        if !options.keep_skirt && is_skirt(g.tags.feature.as_deref()) {
            skirt_lines += 1;
            skirt_filament += s.filament;
            continue;
        }
        let tag = (g.tags.layer, g.tags.z_marker);
        match s.kind {
            SegmentKind::Line => {
                raw.push((tag.0, tag.1, Line { a: from, b: s.end, filament: s.filament, feed: s.feed, source_line: g.line }))
            }
            SegmentKind::Arc => {
                arcs += 1;
                let points = flatten_arc(&from, s, options.arc_tolerance)
                    .map_err(|e| ToolError::Plan(format!("{name}:{}: {e} (--arc-tolerance {} m)", g.line, options.arc_tolerance)))?;
                let mut prev = from;
                let chords: Vec<(Vector3<f64>, Vector3<f64>)> = points
                    .iter()
                    .map(|p| {
                        let c = (prev, *p);
                        prev = *p;
                        c
                    })
                    .collect();
                let total: f64 = chords.iter().map(|(a, b)| (b - a).norm()).sum();
                let mut given = 0.0;
                for (k, (a, b)) in chords.iter().enumerate() {
                    let filament = if k + 1 == chords.len() { s.filament - given } else { s.filament * (b - a).norm() / total };
                    given += filament;
                    raw.push((tag.0, tag.1, Line { a: *a, b: *b, filament, feed: s.feed, source_line: g.line }));
                }
            }
            SegmentKind::Dwell | SegmentKind::Heat => {}
        }
    }
    if raw.is_empty() {
        return Err(ToolError::Plan(format!(
            "{name}: no extruding lines{}",
            if skirt_lines > 0 { format!(" besides {skirt_lines} skirt/brim lines (--keep-skirt keeps them)") } else { String::new() }
        )));
    }
    let by_tag = raw.iter().all(|r| r.0.is_some());
    let mut index: HashMap<i64, usize> = HashMap::new();
    let mut layers: Vec<Layer> = Vec::new();
    for (tag, z_marker, line) in raw {
        let key = if by_tag { i64::from(tag.expect("checked")) } else { (line.b.z * 1e6).round() as i64 };
        let k = *index.entry(key).or_insert_with(|| {
            layers.push(Layer { z: if by_tag { z_marker.unwrap_or(line.b.z) } else { line.b.z }, lines: Vec::new() });
            layers.len() - 1
        });
        layers[k].lines.push(line);
    }
    Ok(Job {
        name: name.to_string(),
        layers,
        layer_source: if by_tag { "tags" } else { "z" },
        arcs_flattened: arcs,
        skirt_lines,
        skirt_filament,
    })
}

/// Points after `start` along an arc segment, ending exactly at its end, such that each chord's
/// sagitta is at most `tolerance` (and each chord spans at most a quarter turn).
pub fn flatten_arc(start: &Vector3<f64>, s: &Segment, tolerance: f64) -> Result<Vec<Vector3<f64>>> {
    if tolerance.is_nan() || tolerance <= 0.0 {
        return Err(ToolError::Plan("the arc tolerance must be positive".to_string()));
    }
    // The core's geometry of the arc (the one the path engine runs): equal steps of θ along it.
    let Some(geometry @ Geometry::Arc { radius, radius_rate, sweep, .. }) = arc_geometry(start, s) else {
        return Ok(vec![s.end]);
    };
    let r = radius.max(radius + radius_rate * sweep);
    let step =
        if tolerance >= r { std::f64::consts::FRAC_PI_2 } else { (2.0 * (1.0 - tolerance / r).acos()).min(std::f64::consts::FRAC_PI_2) };
    let count = (sweep / step).ceil().max(1.0);
    if count > 1e6 {
        return Err(ToolError::Plan(format!("an arc of radius {r} m would need {count} chords")));
    }
    let count = count as usize;
    let length = geometry.length(0.0);
    let mut points = Vec::with_capacity(count);
    for j in 1..count {
        let f = j as f64 / count as f64;
        points.push(geometry.point(length * f, length).position);
    }
    points.push(s.end);
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::strips::fixtures::job_from;

    #[test]
    fn arcs_are_flattened_within_the_tolerance_and_keep_their_filament() {
        // A quarter circle of radius 10 mm about (10, 0) from (0, 0) to (10, 10), clockwise.
        let job = job_from("M83\nG1 F600\nG1 X0 Y0 Z1\nG2 X10 Y10 I10 J0 E2\n");
        let lines: Vec<&Line> = job.lines().collect();
        assert_eq!(job.arcs_flattened, 1);
        // Sagitta ≤ 10 µm on r = 10 mm: step ≤ 2·acos(0.999) = 0.0894 rad → ⌈(π/2)/0.0894⌉ = 18 chords.
        assert_eq!(lines.len(), 18);
        let centre = Vector3::new(0.01, 0.0, 0.001);
        for l in &lines {
            assert!(((l.b - centre).norm() - 0.01).abs() < 1e-15);
            let mid = (l.a + l.b) / 2.0;
            assert!(0.01 - (mid - centre).norm() <= 1e-5);
        }
        assert_eq!(lines.last().unwrap().b, Vector3::new(0.01, 0.01, 0.001));
        assert!((job.filament() - 2e-3).abs() < 1e-18, "{}", job.filament());
    }

    #[test]
    fn layers_come_from_tags_or_from_z() {
        let tagged = job_from("M83\nG1 F600\n;LAYER_CHANGE\n;Z:1\nG1 Z1\nG1 X10 E1\n;LAYER_CHANGE\n;Z:2\nG1 Z2\nG1 X0 E1\n");
        assert_eq!((tagged.layer_source, tagged.layers.len(), tagged.layers[1].z), ("tags", 2, 0.002));
        let untagged = job_from("M83\nG1 F600\nG1 Z1\nG1 X10 E1\nG1 Z2\nG1 X0 E1\nG1 Z1.0000002\nG1 X5 E1\n");
        assert_eq!(untagged.layer_source, "z");
        assert_eq!(untagged.layers.iter().map(|l| l.lines.len()).collect::<Vec<_>>(), vec![2, 1], "z to 1 µm");
        let skirt = job_from("M83\nG1 F600\n;TYPE:Skirt/Brim\nG1 X10 E1\n;TYPE:Perimeter\nG1 X20 E2\n");
        assert_eq!((skirt.skirt_lines, skirt.skirt_filament, skirt.filament()), (1, 1e-3, 2e-3));
    }
}
