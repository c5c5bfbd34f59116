//! Judging a path by its self-intersections in the (u, v) parameter plane: proper crossings, T's and
//! collinear overlaps (each deposits material twice), found through a uniform grid so that a path of
//! thousands of short steps costs near O(n) rather than all pairs.

use super::PointCloud;

/// How two segments of a path meet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactKind {
    /// The interiors cross at one point.
    Proper,
    /// An endpoint lies on the other segment (a T), or the segments overlap collinearly (including an
    /// adjacent pair that folds back on itself).
    Touching,
}

/// One self-intersection: segments `first` < `second` (segment k joins path points k and k+1) meet at
/// `at` (u, v).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Index of the earlier segment.
    pub first: usize,
    /// Index of the later segment.
    pub second: usize,
    /// A point of the contact in the parameter plane (u unit, v unit).
    pub at: (f64, f64),
    /// Crossing or touching.
    pub kind: ContactKind,
}

/// Signed area test with a relative tolerance: 0 if c is within 1e-9 (relative) of the line ab.
fn orient(a: (f64, f64), b: (f64, f64), c: (f64, f64)) -> i8 {
    let (abx, aby, acx, acy) = (b.0 - a.0, b.1 - a.1, c.0 - a.0, c.1 - a.1);
    let cross = abx * acy - aby * acx;
    let scale = (abx.hypot(aby)) * (acx.hypot(acy));
    if cross.abs() <= 1e-9 * scale {
        0
    } else if cross > 0.0 {
        1
    } else {
        -1
    }
}

/// For c collinear with ab: true if c lies within the segment ab's box.
fn within(a: (f64, f64), b: (f64, f64), c: (f64, f64)) -> bool {
    let e = 1e-12;
    c.0 >= a.0.min(b.0) - e && c.0 <= a.0.max(b.0) + e && c.1 >= a.1.min(b.1) - e && c.1 <= a.1.max(b.1) + e
}

/// How segments pq and rs meet, and a point where.
fn contact(p: (f64, f64), q: (f64, f64), r: (f64, f64), s: (f64, f64)) -> Option<(ContactKind, (f64, f64))> {
    let (d1, d2, d3, d4) = (orient(r, s, p), orient(r, s, q), orient(p, q, r), orient(p, q, s));
    if d1 * d2 < 0 && d3 * d4 < 0 {
        let (ex, ey, fx, fy) = (q.0 - p.0, q.1 - p.1, s.0 - r.0, s.1 - r.1);
        let t = ((r.0 - p.0) * fy - (r.1 - p.1) * fx) / (ex * fy - ey * fx);
        return Some((ContactKind::Proper, (p.0 + t * ex, p.1 + t * ey)));
    }
    for (d, x, a, b) in [(d1, p, r, s), (d2, q, r, s), (d3, r, p, q), (d4, s, p, q)] {
        if d == 0 && within(a, b, x) {
            return Some((ContactKind::Touching, x));
        }
    }
    None
}

/// The self-intersections of the path `order` through `cloud`, in the (u, v) plane: every pair of
/// segments that meet, counted once per pair. Non-adjacent segments count when they share any point: a
/// proper crossing, a T (an endpoint on the other segment) or a collinear overlap, since each deposits
/// material twice. Adjacent segments share their joint and count only when they overlap beyond it (the
/// path turns back 180° on itself). Zero-length segments are skipped, and so are steps across a periodic
/// seam (`PointCloud::periods`).
///
/// A uniform grid over the normalised (u, v) box (about one cell per segment) holds each segment in the
/// cells its bounding box covers; a pair is tested in the one cell holding the lower corner of the
/// intersection of their boxes, so each pair once. Near O(n) for paths of short steps; a long jump costs
/// the cells it spans.
pub fn self_intersections(cloud: &PointCloud, order: &[usize]) -> Vec<Contact> {
    let m = order.len().saturating_sub(1);
    if m < 2 {
        return Vec::new();
    }
    let (mut u0, mut u1, mut v0, mut v1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in &cloud.samples {
        (u0, u1, v0, v1) = (u0.min(s.u), u1.max(s.u), v0.min(s.v), v1.max(s.v));
    }
    let (su, sv) = ((u1 - u0).max(f64::MIN_POSITIVE), (v1 - v0).max(f64::MIN_POSITIVE));
    let pt = |k: usize| {
        let s = &cloud.samples[order[k]];
        ((s.u - u0) / su, (s.v - v0) / sv)
    };
    let g = ((m as f64).sqrt().ceil() as usize).clamp(1, 1024);
    let cell = |x: f64| ((x * g as f64) as usize).min(g - 1);
    let mut boxes = Vec::with_capacity(m);
    let mut grid: Vec<Vec<usize>> = vec![Vec::new(); g * g];
    for k in 0..m {
        let (a, b) = (pt(k), pt(k + 1));
        let bb = (a.0.min(b.0), a.1.min(b.1), a.0.max(b.0), a.1.max(b.1));
        boxes.push(bb);
        // A step across a periodic seam is short on the surface but spans the plane: it is not drawn
        // there, so it meets nothing.
        if a == b || cloud.crosses_seam(order[k], order[k + 1]) {
            continue;
        }
        for cy in cell(bb.1)..=cell(bb.3) {
            for cx in cell(bb.0)..=cell(bb.2) {
                grid[cy * g + cx].push(k);
            }
        }
    }
    let mut found = Vec::new();
    for (c, members) in grid.iter().enumerate() {
        let (cx, cy) = (c % g, c / g);
        for (x, &i) in members.iter().enumerate() {
            for &j in &members[x + 1..] {
                let (i, j) = if i < j { (i, j) } else { (j, i) };
                let (bi, bj) = (boxes[i], boxes[j]);
                let (lx, ly, hx, hy) = (bi.0.max(bj.0), bi.1.max(bj.1), bi.2.min(bj.2), bi.3.min(bj.3));
                if lx > hx + 1e-12 || ly > hy + 1e-12 || cell(lx) != cx || cell(ly) != cy {
                    continue;
                }
                let (p, q, r, s) = (pt(i), pt(i + 1), pt(j), pt(j + 1));
                let hit = if j == i + 1 {
                    // Adjacent: q == r is the joint; a fold-back is p, q, s collinear with p and s on the
                    // same side of q.
                    let folds = orient(p, q, s) == 0 && (p.0 - q.0) * (s.0 - q.0) + (p.1 - q.1) * (s.1 - q.1) > 0.0;
                    folds.then_some((ContactKind::Touching, q))
                } else {
                    contact(p, q, r, s)
                };
                if let Some((kind, at)) = hit {
                    found.push(Contact { first: i, second: j, at: (u0 + at.0 * su, v0 + at.1 * sv), kind });
                }
            }
        }
    }
    found.sort_by_key(|c| (c.first, c.second));
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::fixtures::{cloud_of, identity};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn intersection_counter_on_hand_made_paths() {
        let count = |uv: &[(f64, f64)]| {
            let c = cloud_of(uv);
            let found = self_intersections(&c, &identity(uv.len()));
            (
                found.iter().filter(|k| k.kind == ContactKind::Proper).count(),
                found.iter().filter(|k| k.kind == ContactKind::Touching).count(),
            )
        };
        // A boustrophedon and a spiral: clean.
        assert_eq!(count(&[(0.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (2.0, 0.0), (2.0, 1.0)]), (0, 0));
        assert_eq!(count(&[(0.0, 0.0), (3.0, 0.0), (3.0, 3.0), (0.0, 3.0), (0.0, 1.0), (2.0, 1.0), (2.0, 2.0), (1.0, 2.0)]), (0, 0));
        // An X: one proper crossing, at the middle.
        let x = cloud_of(&[(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)]);
        let found = self_intersections(&x, &identity(4));
        assert_eq!(found.len(), 1);
        assert_eq!((found[0].first, found[0].second, found[0].kind), (0, 2, ContactKind::Proper));
        assert!((found[0].at.0 - 0.5).abs() < 1e-12 && (found[0].at.1 - 0.5).abs() < 1e-12);
        // A T: the path ends on its first segment.
        assert_eq!(count(&[(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0, 1.0), (1.0, 0.0)]), (0, 1));
        // A fold-back of adjacent segments, and a plain 90° turn that is not one.
        assert_eq!(count(&[(0.0, 0.0), (2.0, 0.0), (1.0, 0.0)]), (0, 1));
        assert_eq!(count(&[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]), (0, 0));
        // A collinear overlap of non-adjacent segments, which also runs through the corner (2, 0).
        assert_eq!(count(&[(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (3.0, 1.0), (3.0, 0.0), (1.0, 0.0)]), (0, 2));
        // Passing exactly through a joint of the path: a touching with each of the two segments there.
        assert_eq!(count(&[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (2.0, -1.0)]), (0, 2));
        // Several crossings of one long segment: a zigzag cut by a line.
        let mut zig: Vec<(f64, f64)> = (0..10).map(|k| (k as f64, if k % 2 == 0 { 0.0 } else { 2.0 })).collect();
        zig.extend([(9.5, 1.0), (-0.5, 1.0)]);
        assert_eq!(count(&zig), (9, 0));
    }

    #[test]
    fn grid_counter_matches_all_pairs() {
        let mut rng = StdRng::seed_from_u64(3);
        for trial in 0..20 {
            let n = 10 + 15 * trial;
            // Integer points make touching and collinear cases common.
            let uv: Vec<(f64, f64)> =
                (0..n).map(|_| (rng.random_range(0..12) as f64 * 0.01, rng.random_range(0..12) as f64 * 0.01)).collect();
            let c = cloud_of(&uv);
            let order = identity(n);
            let fast = self_intersections(&c, &order);
            let pt = |k: usize| uv[k];
            let mut slow = 0;
            for i in 0..n - 1 {
                for j in i + 1..n - 1 {
                    if pt(i) == pt(i + 1) || pt(j) == pt(j + 1) {
                        continue;
                    }
                    let hit = if j == i + 1 {
                        let (p, q, s) = (pt(i), pt(i + 1), pt(j + 1));
                        orient(p, q, s) == 0 && (p.0 - q.0) * (s.0 - q.0) + (p.1 - q.1) * (s.1 - q.1) > 0.0
                    } else {
                        contact(pt(i), pt(i + 1), pt(j), pt(j + 1)).is_some()
                    };
                    slow += usize::from(hit);
                }
            }
            assert_eq!(fast.len(), slow, "trial {trial}");
        }
    }
}
