//! Writing the plan as G-code: strips in order, every layer of a strip before the next, a travel before
//! each path (retract, lift, move, lower, unretract), numbers in mm to 1e-9 so that the filament read back
//! equals the filament read in.

use std::fmt::Write as _;

use nalgebra::Vector3;
use serde::Serialize;
use strand_job::gcode::GcodeOptions;

use super::Plan;

/// A path move shorter than this (m) is folded into its neighbour when writing (the G-code written
/// keeps 1e-12 m, and the parser would read a shorter move as an extrusion without motion).
const MIN_MOVE: f64 = 1e-11;

/// How to write moves between paths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Travel {
    /// Travel speed (m/s).
    pub speed: f64,
    /// Filament retracted before a travel and pushed back after it (m; 0: none).
    pub retract: f64,
    /// Speed of the retraction (m/s of filament).
    pub retract_speed: f64,
    /// Lift (m) above the higher of the two layers during a travel (0: none).
    pub z_hop: f64,
}

impl Default for Travel {
    /// The truss plate's slicer settings: 120 mm/s travel, 1 mm retraction at 35 mm/s, no lift.
    fn default() -> Self {
        Travel { speed: 0.12, retract: 1e-3, retract_speed: 0.035, z_hop: 0.0 }
    }
}

/// What the writer did.
/// What a strip plan's G-code holds, counted as it was written.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Written {
    /// Travel moves between paths (including the one from the start position).
    pub travels: usize,
    /// Retractions before those travels.
    pub retractions: usize,
    /// Extruding `G1` moves.
    pub moves: usize,
}

/// mm with at most 9 decimals, no exponent, no "-0".
pub(super) fn mm(v: f64) -> String {
    let mut s = format!("{:.9}", v * 1e3);
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" { "0".into() } else { s }
}

/// mm/min for a speed in m/s.
fn per_min(v: f64) -> String {
    mm(v * 60.0)
}

/// The plan as G-code: mm, absolute positions, relative extrusion (M83); strips in order, all layers
/// of a strip before the next; each layer under a `;LAYER:n` marker (the job's layer, 0-based) and a
/// comment naming strip, layer and shift; each path after a travel (retract, lift, move, lower,
/// unretract). `header` lines are written as comments first.
pub fn write_gcode(plan: &Plan, travel: &Travel, header: &[String]) -> (String, Written) {
    let mut g = String::new();
    let mut w = Written::default();
    for h in header {
        let _ = writeln!(g, "; {h}");
    }
    let _ = writeln!(g, "G21 ; mm\nG90 ; absolute positions\nM83 ; relative extrusion");
    let mut at = GcodeOptions::default().start;
    let mut feed = f64::NAN;
    let mut extruded = false;
    let a = plan.axis.name();
    for (k, strip) in plan.strips.iter().enumerate() {
        let _ = writeln!(
            g,
            "; strip {} of {}: {a} from {} to {} mm (nominal), {} layers",
            k + 1,
            plan.strips.len(),
            mm(strip.lo),
            mm(strip.hi),
            strip.layers.len()
        );
        for sl in &strip.layers {
            let _ = writeln!(g, ";LAYER:{}", sl.layer);
            let _ = writeln!(
                g,
                "; strip {} layer {} (z {} mm): {a} from {} to {} mm, boundaries moved by {} mm, {} paths",
                k + 1,
                sl.layer + 1,
                mm(sl.z),
                mm(sl.lo),
                mm(sl.hi),
                mm((plan.layers - 1 - sl.layer) as f64 * plan.overlap),
                sl.paths.len()
            );
            for path in &sl.paths {
                // Fold moves too short to survive the text into their neighbour.
                let mut moves: Vec<(Vector3<f64>, f64, f64)> = Vec::with_capacity(path.len());
                let mut pending = 0.0;
                let mut from = path[0].a;
                for line in path {
                    if (line.b - from).norm() < MIN_MOVE {
                        match moves.last_mut() {
                            Some(m) => m.1 += line.filament,
                            None => pending += line.filament,
                        }
                        continue;
                    }
                    moves.push((line.b, line.filament + pending, line.feed));
                    pending = 0.0;
                    from = line.b;
                }
                if moves.is_empty() {
                    // A path of one line shorter than MIN_MOVE: write it as it is.
                    moves.push((path[0].b, pending, path[0].feed));
                }
                let to = path[0].a;
                if (to - at).norm() >= MIN_MOVE {
                    if extruded && travel.retract > 0.0 {
                        let _ = writeln!(g, "G1 E-{} F{}", mm(travel.retract), per_min(travel.retract_speed));
                        w.retractions += 1;
                    }
                    let high = at.z.max(to.z) + travel.z_hop;
                    let f = per_min(travel.speed);
                    if high != at.z {
                        let _ = writeln!(g, "G0 Z{} F{f}", mm(high));
                    }
                    let _ = writeln!(g, "G0 X{} Y{} F{f}", mm(to.x), mm(to.y));
                    if high != to.z {
                        let _ = writeln!(g, "G0 Z{} F{f}", mm(to.z));
                    }
                    feed = travel.speed;
                    if extruded && travel.retract > 0.0 {
                        let _ = writeln!(g, "G1 E{} F{}", mm(travel.retract), per_min(travel.retract_speed));
                        feed = f64::NAN;
                    }
                    w.travels += 1;
                    at = to;
                }
                for (p, filament, f) in moves {
                    let _ = write!(g, "G1 X{} Y{}", mm(p.x), mm(p.y));
                    if p.z != at.z {
                        let _ = write!(g, " Z{}", mm(p.z));
                    }
                    let _ = write!(g, " E{}", mm(filament));
                    if f != feed {
                        let _ = write!(g, " F{}", per_min(f));
                        feed = f;
                    }
                    g.push('\n');
                    at = p;
                    w.moves += 1;
                }
                extruded = true;
            }
        }
    }
    (g, w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::strips::fixtures::{job_from, spec};
    use crate::strips::{Widths, plan};
    use strand_job::gcode::Parser;

    #[test]
    fn the_output_is_strip_by_strip_and_reads_back() {
        // Two layers of a 30 mm line and a square loop across the middle; strips of 15 mm.
        let mut g = String::from("M83\nG1 F600\n");
        for z in [1, 2] {
            g += &format!(
                ";LAYER_CHANGE\n;Z:{z}\nG0 X0 Y0 Z{z}\nG1 X30 Y0 E3\nG0 X10 Y10\nG1 X20 Y10 E1\nG1 X20 Y20 E1\nG1 X10 Y20 E1\nG1 X10 Y10 E1\n"
            );
        }
        let job = job_from(&g);
        let mut s = spec(Widths::Uniform(0.015), 0.002, 0.04);
        s.origin = Some(0.0);
        let p = plan(&job, &s).unwrap();
        let (text, w) = write_gcode(&p, &Travel::default(), &["test".into()]);
        let parsed: Vec<_> = Parser::new(text.as_bytes(), "out", GcodeOptions::default())
            .collect::<Result<Vec<_>, _>>()
            .unwrap_or_else(|e| panic!("{e}\n{text}"));
        let out: f64 = parsed.iter().filter(|g| g.segment.extrudes()).map(|g| g.segment.filament).sum();
        assert!((out - job.filament()).abs() <= 1e-9 * job.filament(), "{out} vs {}", job.filament());
        // Order: strip 1 layers 1, 2, then strip 2 layers 1, 2 (layer tags from the ;LAYER: markers).
        let mut order: Vec<(usize, i32)> = Vec::new();
        let strip_lines: Vec<usize> =
            text.lines().enumerate().filter(|(_, l)| l.starts_with("; strip") && l.contains(" of ")).map(|(i, _)| i + 1).collect();
        for g in parsed.iter().filter(|g| g.segment.extrudes()) {
            let strip = strip_lines.iter().filter(|&&l| l < g.line).count();
            let key = (strip, g.tags.layer.unwrap());
            if order.last() != Some(&key) {
                order.push(key);
            }
        }
        assert_eq!(order, vec![(1, 0), (1, 1), (2, 0), (2, 1)]);
        // Layer 1: strip 1 ends at 13 mm. The loop is cut into a U on each side. Strip 1: the line,
        // then the U from its end nearest (13, 0): 2 paths. Strip 2: the line (13 → 30 mm), then the
        // endpoint nearest (30, 0) is the U's corner (20, 10), so the U is two paths: 3 paths.
        assert_eq!(p.strips[0].layers.iter().map(|l| l.paths.len()).collect::<Vec<_>>(), vec![2, 2]);
        assert_eq!(p.strips[1].layers.iter().map(|l| l.paths.len()).collect::<Vec<_>>(), vec![3, 3]);
        assert_eq!(p.strips[1].layers[0].paths[1][0].a, Vector3::new(0.02, 0.01, 0.001));
        // Travels: one per path (the first from the start position); a retraction before all but the first.
        assert_eq!((w.travels, w.retractions), (10, 9));
    }
}
