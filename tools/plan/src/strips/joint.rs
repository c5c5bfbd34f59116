//! The staggered joint of Fig. 6: each layer's boundaries between strips moved by (N − i)·L towards the
//! strip printed second, and the lines cut exactly at them, each piece with its share of the filament.

use super::Line;

/// Two coordinates closer than this (m) along the split axis are the same: a line this close to a
/// boundary lies on it, and a line is not cut within this distance of its ends.
pub const BOUNDARY_EPS: f64 = 1e-9;

/// The strip boundaries on layer `layer` (0-based) of `layers`: `nominal` (origin, the boundaries
/// between strips, the far end; ascending) with every interior boundary moved by
/// (layers − 1 − layer)·`overlap` away from the origin (towards the strip printed second). The top
/// layer keeps the nominal boundaries.
pub fn layer_bounds(nominal: &[f64], layer: usize, layers: usize, overlap: f64) -> Vec<f64> {
    let shift = (layers - 1 - layer) as f64 * overlap;
    let last = nominal.len() - 1;
    nominal.iter().enumerate().map(|(k, &b)| if k == 0 || k == last { b } else { b + shift }).collect()
}

/// The strip (0-based) of a piece whose largest coordinate along the axis is `max`: one past the
/// number of interior boundaries it passes by more than [`BOUNDARY_EPS`]; so a piece lying on a
/// boundary, or ending on it, belongs to the strip below (printed first).
fn strip_of(max: f64, interior: &[f64]) -> usize {
    interior.iter().filter(|&&b| max > b + BOUNDARY_EPS).count()
}

/// Cuts `line` at the interior boundaries it crosses (by more than [`BOUNDARY_EPS`] on each side)
/// and returns each piece with its strip (0-based). A cut point lies exactly on the boundary along
/// `axis`; its other coordinates (z included) are interpolated linearly; each piece's filament is
/// the line's in proportion to its length (the last piece takes the remainder, so the sum is exact
/// to rounding).
pub fn cut(line: &Line, axis: usize, interior: &[f64]) -> Vec<(usize, Line)> {
    let (u, v) = (line.a[axis], line.b[axis]);
    let (lo, hi) = (u.min(v), u.max(v));
    let mut cuts: Vec<(f64, f64)> =
        interior.iter().filter(|&&b| b > lo + BOUNDARY_EPS && b < hi - BOUNDARY_EPS).map(|&b| ((b - u) / (v - u), b)).collect();
    if cuts.is_empty() {
        return vec![(strip_of(hi, interior), line.clone())];
    }
    cuts.sort_by(|p, q| p.0.total_cmp(&q.0));
    let d = line.b - line.a;
    let mut points = vec![line.a];
    for (t, b) in cuts {
        let mut p = line.a + d * t;
        p[axis] = b;
        points.push(p);
    }
    points.push(line.b);
    let total = line.length();
    let mut given = 0.0;
    let count = points.len() - 1;
    (0..count)
        .map(|k| {
            let (a, b) = (points[k], points[k + 1]);
            let filament = if k + 1 == count { line.filament - given } else { line.filament * (b - a).norm() / total };
            given += filament;
            (strip_of(a[axis].max(b[axis]), interior), Line { a, b, filament, ..line.clone() })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::strips::fixtures::{job_from, line, spec};
    use crate::strips::{Widths, plan};

    #[test]
    fn boundaries_move_by_l_per_layer_towards_the_second_strip() {
        let nominal = [0.05, 0.093, 0.153, 0.2];
        let expect = [[0.108, 0.168], [0.103, 0.163], [0.098, 0.158], [0.093, 0.153]];
        for (i, e) in expect.iter().enumerate() {
            let b = layer_bounds(&nominal, i, 4, 0.005);
            assert_eq!((b[0], b[3]), (0.05, 0.2), "outer edges stay");
            assert!((b[1] - e[0]).abs() < 1e-15 && (b[2] - e[1]).abs() < 1e-15, "layer {i}: {b:?}");
        }
        // Through plan(): one line across the part on each of 3 layers; its cut points.
        let mut g = String::from("M83\nG1 F600\n");
        for layer in 1..=3 {
            g += &format!(";LAYER_CHANGE\n;Z:{layer}\nG0 X0 Y10 Z{layer}\nG1 X30 Y10 E3\n");
        }
        let job = job_from(&g);
        let p = plan(&job, &spec(Widths::Uniform(0.01), 0.002, 0.02)).unwrap();
        assert_eq!(p.strips.len(), 3);
        assert_eq!(p.cuts, 3);
        for (i, shift) in [0.004, 0.002, 0.0].into_iter().enumerate() {
            let s1 = &p.strips[0].layers[i];
            let end = s1.paths[0][0].b.x.max(s1.paths[0][0].a.x);
            assert!((end - (0.01 + shift)).abs() < 1e-15, "layer {i}: strip 1 ends at {end}");
            let s2 = &p.strips[1].layers[i];
            assert!((s2.lo - (0.01 + shift)).abs() < 1e-15 && (s2.hi - (0.02 + shift)).abs() < 1e-15);
            // Strip 3 takes what strip 2 leaves: 10 mm − shift.
            let len3: f64 = p.strips[2].layers[i].paths.iter().flatten().map(Line::length).sum();
            assert!((len3 - (0.01 - shift)).abs() < 1e-12, "layer {i}: {len3}");
        }
    }

    #[test]
    fn a_line_on_a_boundary_goes_to_the_strip_printed_first() {
        let interior = [0.093];
        let on = line([0.093, 0.02, 0.001], [0.093, 0.1, 0.001], 1e-3);
        assert_eq!(cut(&on, 0, &interior), vec![(0, on.clone())]);
        let after = line([0.093, 0.02, 0.001], [0.12, 0.02, 0.001], 1e-3);
        assert_eq!(cut(&after, 0, &interior), vec![(1, after.clone())]);
        let before = line([0.06, 0.02, 0.001], [0.093, 0.02, 0.001], 1e-3);
        assert_eq!(cut(&before, 0, &interior), vec![(0, before.clone())]);
        // From G-code: X93 (0.093 after mm → m) against 0.05 + 0.043 summed in floating point.
        let job = job_from("M83\nG1 F600\nG0 X50 Y0 Z1\nG1 X60 Y0 E1\nG0 X93 Y20\nG1 X93 Y50 E1\nG0 X143 Y0\nG1 X140 Y0 E1\n");
        let mut s = spec(Widths::List(vec![0.043, 0.05]), 0.01, 0.2);
        s.origin = Some(0.05);
        let p = plan(&job, &s).unwrap();
        let xs = |k: usize| -> Vec<f64> { p.strips[k].layers.iter().flat_map(|l| l.paths.iter().flatten()).map(|l| l.a.x).collect() };
        assert_eq!(p.strips[0].layers[0].paths.len(), 2, "the X93 line is in strip 1");
        assert!(xs(0).iter().any(|x| (x - 0.093).abs() < 1e-12));
        assert_eq!(xs(1), vec![0.14], "reversed: its end is nearer the origin");
    }

    #[test]
    fn a_crossing_line_is_cut_exactly_at_the_boundary() {
        let l = line([0.08, 0.0, 0.001], [0.10, 0.02, 0.003], 1e-3);
        let pieces = cut(&l, 0, &[0.093]);
        assert_eq!(pieces.len(), 2);
        let ((s0, p0), (s1, p1)) = (&pieces[0], &pieces[1]);
        assert_eq!((*s0, *s1), (0, 1));
        assert_eq!(p0.b.x, 0.093, "exactly on the boundary");
        assert_eq!(p0.b, p1.a);
        assert!((p0.b.y - 0.013).abs() < 1e-15 && (p0.b.z - 0.0023).abs() < 1e-15, "{:?}", p0.b);
        assert!((p0.filament - 0.65e-3).abs() < 1e-15 && (p1.filament - 0.35e-3).abs() < 1e-15);
        assert_eq!(p0.filament + p1.filament, 1e-3);
        // Backwards across two boundaries: three pieces in travel order, strips 2, 1, 0.
        let back = line([0.2, 0.01, 0.001], [0.0, 0.01, 0.001], 2e-3);
        let pieces = cut(&back, 0, &[0.05, 0.15]);
        let strips: Vec<usize> = pieces.iter().map(|p| p.0).collect();
        assert_eq!(strips, vec![2, 1, 0]);
        assert_eq!((pieces[0].1.b.x, pieces[1].1.b.x), (0.15, 0.05));
        let f: Vec<f64> = pieces.iter().map(|p| p.1.filament).collect();
        assert!((f[0] - 0.5e-3).abs() < 1e-15 && (f[1] - 1e-3).abs() < 1e-15 && (f[2] - 0.5e-3).abs() < 1e-15, "{f:?}");
        // Within BOUNDARY_EPS of an end: not cut.
        let grazing = line([0.093 - 0.5e-9, 0.0, 0.0], [0.12, 0.0, 0.0], 1e-3);
        assert_eq!(cut(&grazing, 0, &[0.093]).len(), 1);
    }
}
