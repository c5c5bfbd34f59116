//! Chaining one strip's lines of one layer into continuous paths (Fig. 8), through a uniform grid over the
//! endpoints so that each nearest-endpoint query stays cheap on large layers.

use nalgebra::Vector3;

use super::Line;

/// A uniform grid over line endpoints in x-y for nearest-endpoint queries with removal.
struct Grid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: i64,
    ny: i64,
    /// Endpoint ids (2·line + end) per cell; entries of used lines are dropped lazily.
    cells: Vec<Vec<u32>>,
}

impl Grid {
    fn new(points: &[[f64; 2]], tolerance: f64) -> Grid {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in points {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        let area = ((x1 - x0) * (y1 - y0)).max(0.0);
        let side = (x1 - x0).max(y1 - y0);
        // About two endpoints per cell, at most 1024 cells a side, never finer than the tolerance.
        let mut cell = (2.0 * area / points.len() as f64).sqrt().max(side / 1024.0).max(tolerance).max(1e-9);
        if !cell.is_finite() {
            // The area overflowed (coordinates far apart): 1024 cells a side, or one cell.
            cell = side / 1024.0;
            if !(cell.is_finite() && cell > 0.0) {
                cell = f64::MAX;
            }
        }
        let count = |span: f64| (span / cell).floor().clamp(0.0, 1023.0) as i64 + 1;
        let (nx, ny) = (count(x1 - x0), count(y1 - y0));
        let mut cells = vec![Vec::new(); (nx * ny) as usize];
        let mut grid = Grid { x0, y0, cell, nx, ny, cells: Vec::new() };
        for (id, p) in points.iter().enumerate() {
            let (cx, cy) = grid.cell_of(p);
            cells[(cy * nx + cx) as usize].push(id as u32);
        }
        grid.cells = cells;
        grid
    }

    /// The cell of `p`, or for a point outside the grid the grid's cell nearest it (the ring search
    /// from there still ends with the nearest point: it stops early only once its square holds `p`).
    fn cell_of(&self, p: &[f64; 2]) -> (i64, i64) {
        let index = |v: f64, n: i64| if v.is_nan() { 0 } else { v.floor().clamp(0.0, (n - 1) as f64) as i64 };
        (index((p[0] - self.x0) / self.cell, self.nx), index((p[1] - self.y0) / self.cell, self.ny))
    }

    /// The live endpoint nearest `p` in x-y: (id, distance). Ties: the smaller id (earlier line, its
    /// start before its end).
    fn nearest(&mut self, p: &[f64; 2], points: &[[f64; 2]], used: &[bool]) -> Option<(usize, f64)> {
        let (cx, cy) = self.cell_of(p);
        let mut best: Option<(usize, f64)> = None;
        let mut r = 0i64;
        loop {
            // Ring r: cells with Chebyshev distance r from (cx, cy), clipped to the grid.
            let (ylo, yhi) = ((cy - r).max(0), (cy + r).min(self.ny - 1));
            for y in ylo..=yhi {
                // The top and bottom rows of the ring in full, the other rows at its two ends.
                let full = y == cy - r || y == cy + r;
                let step = if full { 1 } else { 2 * r };
                let (mut x, last) = if full { ((cx - r).max(0), (cx + r).min(self.nx - 1)) } else { (cx - r, cx + r) };
                while x <= last {
                    if (0..self.nx).contains(&x) {
                        let cell = &mut self.cells[(y * self.nx + x) as usize];
                        cell.retain(|&id| !used[id as usize / 2]);
                        for &id in cell.iter() {
                            let q = points[id as usize];
                            let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                            if best.is_none_or(|(bid, bd)| d < bd || (d == bd && (id as usize) < bid)) {
                                best = Some((id as usize, d));
                            }
                        }
                    }
                    x += step;
                }
            }
            // Everything not yet examined lies outside the square of rings 0..=r around p's cell.
            let left = p[0] - (self.x0 + (cx - r) as f64 * self.cell);
            let right = self.x0 + (cx + r + 1) as f64 * self.cell - p[0];
            let below = p[1] - (self.y0 + (cy - r) as f64 * self.cell);
            let above = self.y0 + (cy + r + 1) as f64 * self.cell - p[1];
            let bound = left.min(right).min(below).min(above);
            let covered = cx - r <= 0 && cy - r <= 0 && cx + r >= self.nx - 1 && cy + r >= self.ny - 1;
            if covered || best.is_some_and(|(_, d)| d < bound) {
                return best;
            }
            r += 1;
        }
    }
}

/// Chains lines into continuous paths (000 Fig. 8): from `start` (x-y), take the line with the
/// nearest endpoint; continue with a line having an endpoint within `tolerance` (3-D) of the current
/// end (reversing it if that endpoint is its end); when there is none, start a new path at the
/// remaining endpoint nearest the current end. Every line appears once, in one path.
///
/// Among several matching lines (000: "there is no rule dictating which will be selected next") the
/// one that follows the current line in `lines` (the job's own continuation: the next line if going
/// forwards, the previous one if going backwards) is taken when it matches; otherwise the nearest
/// endpoint, then the earlier line, then a line's start before its end.
pub fn chain(lines: &[Line], start: [f64; 2], tolerance: f64) -> Vec<Vec<Line>> {
    if lines.is_empty() {
        return Vec::new();
    }
    let points: Vec<[f64; 2]> = lines.iter().flat_map(|l| [[l.a.x, l.a.y], [l.b.x, l.b.y]]).collect();
    let mut grid = Grid::new(&points, tolerance);
    let mut used = vec![false; lines.len()];
    let mut paths: Vec<Vec<Line>> = Vec::new();
    let mut here = start;
    let mut end3: Option<Vector3<f64>> = None;
    let mut follow: Option<usize> = None;
    while let Some(id) = follow.take().or_else(|| grid.nearest(&here, &points, &used).map(|(id, _)| id)) {
        let (k, reversed) = (id / 2, id % 2 == 1);
        used[k] = true;
        let line = if reversed { lines[k].reversed() } else { lines[k].clone() };
        let joins = end3.is_some_and(|e| (line.a - e).norm() <= tolerance);
        if !joins {
            paths.push(Vec::new());
        }
        follow = if !reversed {
            (k + 1 < lines.len() && !used[k + 1] && (lines[k + 1].a - line.b).norm() <= tolerance).then(|| 2 * (k + 1))
        } else {
            (k >= 1 && !used[k - 1] && (lines[k - 1].b - line.b).norm() <= tolerance).then(|| 2 * (k - 1) + 1)
        };
        here = [line.b.x, line.b.y];
        end3 = Some(line.b);
        paths.last_mut().expect("a path was started").push(line);
    }
    paths
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::strips::fixtures::line;

    #[test]
    fn chaining_a_grid_follows_fig_8() {
        // A 2 × 2 grid of unit cells (3 × 3 nodes, 12 edges), edges listed rows first, then columns.
        let e = |a: [f64; 2], b: [f64; 2]| line([a[0], a[1], 0.001], [b[0], b[1], 0.001], 1.0);
        let mut lines = Vec::new();
        for y in 0..3 {
            for x in 0..2 {
                lines.push(e([x as f64, y as f64], [x as f64 + 1.0, y as f64]));
            }
        }
        for x in 0..3 {
            for y in 0..2 {
                lines.push(e([x as f64, y as f64], [x as f64, y as f64 + 1.0]));
            }
        }
        let paths = chain(&lines, [-0.5, -0.5], 1e-6);
        // By hand: from (0,0) the earlier of the two lines there, (0,0)→(1,0); then the job's next
        // line (1,0)→(2,0); at (2,0) the only match, (2,0)→(2,1), whose job successor (2,1)→(2,2)
        // follows; at (2,2) row 2 backwards to (0,2), column 0 down to (0,0): 8 lines. Nothing left at
        // (0,0): (0,1) and (1,0) are nearest at 1, the earlier line wins: (0,1)→(1,1)→(2,1). From
        // (2,1) the nearest ends are at (1,1): (1,1)→(1,0), then (1,1)→(1,2) alone.
        let lens: Vec<usize> = paths.iter().map(Vec::len).collect();
        assert_eq!(lens, vec![8, 2, 1, 1]);
        assert_eq!(paths[0][0].a, Vector3::new(0.0, 0.0, 0.001), "starts nearest the origin");
        assert_eq!(paths[0].last().unwrap().b, Vector3::new(0.0, 0.0, 0.001));
        assert_eq!(paths[1][0].a, Vector3::new(0.0, 1.0, 0.001));
        assert_eq!((paths[2][0].a, paths[2][0].b), (Vector3::new(1.0, 1.0, 0.001), Vector3::new(1.0, 0.0, 0.001)));
        for p in &paths {
            for w in p.windows(2) {
                assert_eq!(w[0].b, w[1].a, "continuous");
            }
        }
        // Disjoint polylines given shuffled and reversed come back as one path each.
        let mut pieces = Vec::new();
        for k in 0..5 {
            let y = 0.01 * k as f64;
            for j in 0..4 {
                let (a, b) = ([0.1 + 0.01 * j as f64, y, 0.0], [0.11 + 0.01 * j as f64, y, 0.0]);
                pieces.push(if (j + k) % 2 == 0 { line(a, b, 1.0) } else { line(b, a, 1.0) });
            }
        }
        pieces.reverse();
        let paths = chain(&pieces, [0.0, 0.0], 1e-9);
        assert_eq!(paths.iter().map(Vec::len).collect::<Vec<_>>(), vec![4; 5]);
        assert_eq!(paths[0][0].a, Vector3::new(0.1, 0.0, 0.0));
        // Each new path starts at the endpoint nearest the last end, one row up: a boustrophedon,
        // x = 0.10 on even rows and 0.14 on odd ones.
        for (k, p) in paths.iter().enumerate() {
            let x = if k % 2 == 0 { 0.1 } else { 0.14 };
            assert!((p[0].a.x - x).abs() < 1e-12 && (p[0].a.y - 0.01 * k as f64).abs() < 1e-12, "path {k}: {:?}", p[0].a);
        }
    }
}
