//! The bed mesh: the bed's measured surface, heights on a grid over the bed (`[bed.mesh]`, what
//! `strand calibrate mesh` probes), and the correction it makes to the path. Every point the path
//! engine puts out is moved along the bed's normal by the surface's height under it, the correction
//! fading out with the height above the bed, as Klipper's `bed_mesh` does.
//!
//! Why in the path engine and not in the job: the engine is the one place every job passes,
//! G-code, a segment file or a planner streaming segments of its own, and there the correction is
//! a smooth function of the path position, not a polyline of split moves (Klipper splits every move
//! at 5 mm and at each 0.025 mm of correction because its kinematics only move in lines; the
//! engine evaluates the surface at every tick's point instead).
//!
//! Two spaces: the *program's* (what the segments say: the bed is the flat plane z = 0 of the bed
//! frame) and W (where the tool must go: the program's point moved by `c` along the bed normal).
//! The engine plans and measures progress in the program's space; what it puts out, and the start
//! points it is given (where the tool is), are in W. With `h` the program's height above the bed
//! and `m(x, y)` the surface:
//!
//! `c = m` for `h ≤ fade_start`; `c = t` for `h ≥ fade_end`; linear in between (t = `fade_target`,
//! by default the mesh's mean height, Klipper's default too), so the first layer follows the
//! surface and the layers above it blend back to a flat, level print. `fade_end = 0` never fades.
//!
//! Outside the probed grid the height is the grid's edge's (Klipper clamps the same way). Bilinear
//! interpolation is continuous, bicubic (Catmull–Rom, through every probed height) also has
//! continuous slopes, so the correction's velocity has no steps at cell edges.

use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::setting::InvalidSetting;

/// Probed heights per grid axis, at least and at most.
pub const MESH_COUNT: std::ops::RangeInclusive<usize> = 2..=32;

/// How heights between the probed ones are interpolated.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum MeshAlgorithm {
    /// Bilinear in each grid cell: continuous, with kinks at the cell edges.
    Bilinear,
    /// Bicubic (Catmull–Rom) through the probed heights: continuous slopes.
    #[default]
    Bicubic,
}

/// `[bed.mesh]`: the bed's surface probed on a grid, in the bed frame.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BedMeshConfig {
    /// The grid's lower corner (x, y) in the bed frame (m).
    pub min: [f64; 2],
    /// The grid's upper corner (x, y) in the bed frame (m).
    pub max: [f64; 2],
    /// The surface's height above the bed frame's xy plane at the grid's nodes (m): one row per y,
    /// from `min` y to `max` y, each row one height per x from `min` x to `max` x, evenly spaced
    /// (Klipper's `points`, in m). 2 to 32 per axis.
    pub points: Vec<Vec<f64>>,
    /// Interpolation between the probed heights: `bicubic` (default) or `bilinear`.
    #[serde(default)]
    pub algorithm: MeshAlgorithm,
    /// Height above the bed (m, the program's z) up to which the whole correction applies.
    #[serde(default = "default_fade_start")]
    pub fade_start: f64,
    /// Height above the bed (m) from which only `fade_target` applies; 0: the correction never fades.
    #[serde(default = "default_fade_end")]
    pub fade_end: f64,
    /// The correction above `fade_end` (m); by default the mean of `points`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fade_target: Option<f64>,
}

fn default_fade_start() -> f64 {
    1e-3
}

fn default_fade_end() -> f64 {
    10e-3
}

impl BedMeshConfig {
    /// Columns (x) and rows (y) of the grid.
    pub fn counts(&self) -> (usize, usize) {
        (self.points.first().map_or(0, Vec::len), self.points.len())
    }

    /// The lowest and highest probed heights (m).
    pub fn range(&self) -> (f64, f64) {
        let all = self.points.iter().flatten().copied();
        all.clone().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), z| (lo.min(z), hi.max(z)))
    }

    /// The mean probed height (m).
    pub fn mean(&self) -> f64 {
        let n: usize = self.points.iter().map(Vec::len).sum();
        self.points.iter().flatten().sum::<f64>() / n.max(1) as f64
    }

    /// How the interpolated height at bed (x, y) (m) weighs the probed ones: pairs of (node index,
    /// row-major: `j · x_count + i`; weight), the height being `Σ weight · height[node]` (the
    /// surface is linear in the heights). What a fit of the heights to touches off the nodes needs.
    pub fn node_weights(&self, x: f64, y: f64) -> Vec<(usize, f64)> {
        let (nx, ny) = self.counts();
        if nx < 2 || ny < 2 {
            return Vec::new();
        }
        let step = [(self.max[0] - self.min[0]) / (nx - 1) as f64, (self.max[1] - self.min[1]) / (ny - 1) as f64];
        let (i, tx, _) = cell(x, self.min[0], step[0], nx);
        let (j, ty, _) = cell(y, self.min[1], step[1], ny);
        let (wx, _) = weights(self.algorithm, tx);
        let (wy, _) = weights(self.algorithm, ty);
        let mut out: Vec<(usize, f64)> = Vec::new();
        for (b, wyb) in wy.iter().enumerate() {
            for (a, wxa) in wx.iter().enumerate() {
                if wxa * wyb != 0.0 {
                    spread(i + a as isize - 1, j + b as isize - 1, wxa * wyb, (nx, ny), &mut out);
                }
            }
        }
        out
    }

    /// A one-line summary: grid, extent, range, algorithm and fade (for the check and the logs).
    pub fn summary(&self) -> String {
        let (nx, ny) = self.counts();
        let (lo, hi) = self.range();
        let fade = if self.fade_end > 0.0 {
            format!("faded out from {:.1} to {:.1} mm", self.fade_start * 1e3, self.fade_end * 1e3)
        } else {
            "never faded".to_string()
        };
        format!(
            "{nx}×{ny} over x {:.1}…{:.1} mm, y {:.1}…{:.1} mm, heights {:+.3}…{:+.3} mm (range {:.3} mm), {}, {fade}",
            self.min[0] * 1e3,
            self.max[0] * 1e3,
            self.min[1] * 1e3,
            self.max[1] * 1e3,
            lo * 1e3,
            hi * 1e3,
            (hi - lo) * 1e3,
            match self.algorithm {
                MeshAlgorithm::Bilinear => "bilinear",
                MeshAlgorithm::Bicubic => "bicubic",
            }
        )
    }
}

/// The bed mesh in W: the surface, where the bed is, and the fade. Built once at start-up; the
/// tick only reads it.
#[derive(Clone, Debug, PartialEq)]
pub struct BedMesh {
    config: BedMeshConfig,
    /// Heights, row-major (y rows of x columns) (m).
    heights: Vec<f64>,
    nx: usize,
    ny: usize,
    /// Grid spacing (m).
    step: [f64; 2],
    /// Bed frame in W.
    origin: Vector3<f64>,
    rotation: Rotation3<f64>,
    target: f64,
}

/// The correction at a point and its derivatives in the bed frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Correction {
    /// Along the bed normal (m).
    c: f64,
    /// ∂c/∂(x, y, h) (1).
    gradient: [f64; 3],
}

impl BedMesh {
    /// The mesh of `config` on the bed whose frame has `origin` (m, W) and `rotation` (its z axis
    /// the bed normal); errors name the key.
    pub fn new(config: &BedMeshConfig, origin: Vector3<f64>, rotation: Rotation3<f64>) -> Result<Self, InvalidSetting> {
        let err = |m: String| Err(InvalidSetting::new("bed", format!("[bed.mesh] {m}")));
        let (nx, ny) = config.counts();
        if !MESH_COUNT.contains(&ny) || !MESH_COUNT.contains(&nx) {
            return err(format!(
                "points: {ny} rows of {nx} heights; the grid needs {} to {} per axis",
                MESH_COUNT.start(),
                MESH_COUNT.end()
            ));
        }
        if let Some((j, row)) = config.points.iter().enumerate().find(|(_, r)| r.len() != nx) {
            return err(format!("points: row {} has {} heights, the first has {nx}: every row needs one per x", j + 1, row.len()));
        }
        if let Some((j, i)) = (0..ny).flat_map(|j| (0..nx).map(move |i| (j, i))).find(|&(j, i)| !config.points[j][i].is_finite()) {
            return err(format!("points: row {}, column {} is not a finite number", j + 1, i + 1));
        }
        let finite = config.min.iter().chain(&config.max).all(|v| v.is_finite());
        if !finite || config.max[0] <= config.min[0] || config.max[1] <= config.min[1] {
            return err(format!("min = {:?}, max = {:?}: must be finite with min < max on x and y (m)", config.min, config.max));
        }
        let (lo, hi) = config.range();
        if hi - lo > 0.02 {
            return err(format!(
                "points: the heights span {:.1} mm: more than 20 mm is not a bed's unevenness (heights are in m; a mis-set bed \
                 frame is `strand calibrate frame`'s to fix)",
                (hi - lo) * 1e3
            ));
        }
        let target = config.fade_target.unwrap_or_else(|| config.mean());
        if !target.is_finite() {
            return err(format!("fade_target = {target}: must be finite (m)"));
        }
        if !(config.fade_start.is_finite() && config.fade_end.is_finite() && config.fade_start >= 0.0 && config.fade_end >= 0.0) {
            return err(format!("fade_start = {}, fade_end = {}: must be finite and ≥ 0 (m)", config.fade_start, config.fade_end));
        }
        if config.fade_end > 0.0 {
            let span = config.fade_end - config.fade_start;
            // Over the fade, each layer's correction changes by (m − t)·Δh / span: with |m − t|
            // under the span, a higher layer never lands below a lower one (the map stays one-to-one).
            let worst = (hi - target).abs().max((lo - target).abs());
            if span <= 2.0 * worst {
                return err(format!(
                    "fade_start = {} mm, fade_end = {} mm: the fade must span more than twice the mesh's largest departure from \
                     fade_target ({:.3} mm), so that each layer stays above the one before",
                    config.fade_start * 1e3,
                    config.fade_end * 1e3,
                    worst * 1e3
                ));
            }
        }
        let step = [(config.max[0] - config.min[0]) / (nx - 1) as f64, (config.max[1] - config.min[1]) / (ny - 1) as f64];
        Ok(BedMesh {
            config: config.clone(),
            heights: config.points.iter().flatten().copied().collect(),
            nx,
            ny,
            step,
            origin,
            rotation,
            target,
        })
    }

    /// The config it was built from.
    pub fn config(&self) -> &BedMeshConfig {
        &self.config
    }

    /// The bed's unit normal in W.
    pub fn normal(&self) -> Vector3<f64> {
        self.rotation * Vector3::z()
    }

    /// The surface's height (m) above the bed frame's xy plane at bed coordinates (x, y) (m), the
    /// grid's edge's outside it.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        self.surface(x, y).0
    }

    /// The point of the surface over bed (x, y) (m), in W.
    pub fn surface_point(&self, x: f64, y: f64) -> Vector3<f64> {
        self.origin + self.rotation * Vector3::new(x, y, self.height(x, y))
    }

    /// The surface's height at a point in W (its bed x and y), and the point's height above the
    /// bed plane (m).
    pub fn height_at(&self, p: &Vector3<f64>) -> (f64, f64) {
        let b = self.rotation.inverse() * (p - self.origin);
        (self.height(b.x, b.y), b.z)
    }

    /// A program point (m) in W: moved along the bed normal by the correction under it.
    pub fn to_world(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let b = self.rotation.inverse() * (p - self.origin);
        p + self.normal() * self.correction(&b).c
    }

    /// The program point (m) that [`to_world`](Self::to_world) takes to `p` (W): the inverse map,
    /// exact (the correction is piecewise linear in the height, and one-to-one by construction).
    pub fn to_program(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let b = self.rotation.inverse() * (p - self.origin);
        let (m, _) = self.surface(b.x, b.y);
        let (fs, fe, t) = (self.config.fade_start, self.config.fade_end, self.target);
        let h = if fe <= 0.0 || b.z - m <= fs {
            b.z - m
        } else if b.z - t >= fe {
            b.z - t
        } else {
            // h + t + (m − t)(fe − h)/(fe − fs) = b.z
            let k = (m - t) / (fe - fs);
            (b.z - t - k * fe) / (1.0 - k)
        };
        p + self.normal() * (h - b.z)
    }

    /// A path point's motion (program space: position m, velocity m/s, acceleration m/s²) in W:
    /// the position moved, the velocity and acceleration with the correction's rate of change
    /// along the motion (the surface's curvature term left out: its share of the acceleration is
    /// below 1e-4 of the path's on a bed's unevenness).
    pub fn apply(&self, position: &mut Vector3<f64>, velocity: &mut Vector3<f64>, acceleration: &mut Vector3<f64>) {
        let r_inv = self.rotation.inverse();
        let b = r_inv * (*position - self.origin);
        let k = self.correction(&b);
        let g = Vector3::from(k.gradient);
        let n = self.normal();
        *position += n * k.c;
        *velocity += n * g.dot(&(r_inv * *velocity));
        *acceleration += n * g.dot(&(r_inv * *acceleration));
    }

    /// The correction at bed coordinates `b` (x, y and the program's height h, m).
    fn correction(&self, b: &Vector3<f64>) -> Correction {
        let (m, [mx, my]) = self.surface(b.x, b.y);
        let (fs, fe, t) = (self.config.fade_start, self.config.fade_end, self.target);
        if fe <= 0.0 || b.z <= fs {
            Correction { c: m, gradient: [mx, my, 0.0] }
        } else if b.z >= fe {
            Correction { c: t, gradient: [0.0; 3] }
        } else {
            let f = (fe - b.z) / (fe - fs);
            Correction { c: t + f * (m - t), gradient: [f * mx, f * my, -(m - t) / (fe - fs)] }
        }
    }

    /// Height (m) and slope (∂/∂x, ∂/∂y) of the surface at bed (x, y), clamped to the grid.
    fn surface(&self, x: f64, y: f64) -> (f64, [f64; 2]) {
        let (i, tx, inside_x) = cell(x, self.config.min[0], self.step[0], self.nx);
        let (j, ty, inside_y) = cell(y, self.config.min[1], self.step[1], self.ny);
        let (wx, dx) = weights(self.config.algorithm, tx);
        let (wy, dy) = weights(self.config.algorithm, ty);
        let (mut z, mut zx, mut zy) = (0.0, 0.0, 0.0);
        for (b, (wyb, dyb)) in wy.iter().zip(&dy).enumerate() {
            for (a, (wxa, dxa)) in wx.iter().zip(&dx).enumerate() {
                if *wxa == 0.0 && *dxa == 0.0 || *wyb == 0.0 && *dyb == 0.0 {
                    continue;
                }
                let h = self.node(i + a as isize - 1, j + b as isize - 1);
                z += wxa * wyb * h;
                zx += dxa * wyb * h;
                zy += wxa * dyb * h;
            }
        }
        let sx = if inside_x { zx / self.step[0] } else { 0.0 };
        let sy = if inside_y { zy / self.step[1] } else { 0.0 };
        (z, [sx, sy])
    }

    /// The height at node (i, j), extended past the grid's edges linearly (the Catmull–Rom end
    /// condition that keeps a plane a plane).
    fn node(&self, i: isize, j: isize) -> f64 {
        let (nx, ny) = (self.nx as isize, self.ny as isize);
        if i < 0 {
            return 2.0 * self.node(0, j) - self.node(1, j);
        }
        if i >= nx {
            return 2.0 * self.node(nx - 1, j) - self.node(nx - 2, j);
        }
        if j < 0 {
            return 2.0 * self.node(i, 0) - self.node(i, 1);
        }
        if j >= ny {
            return 2.0 * self.node(i, ny - 1) - self.node(i, ny - 2);
        }
        self.heights[j as usize * self.nx + i as usize]
    }
}

/// Adds weight `w` of node (i, j) to `out`, a node past the grid's edge spread over the two it
/// is extended from ([`BedMesh::node`]'s rule).
fn spread(i: isize, j: isize, w: f64, (nx, ny): (usize, usize), out: &mut Vec<(usize, f64)>) {
    let (nxi, nyi) = (nx as isize, ny as isize);
    if i < 0 {
        spread(0, j, 2.0 * w, (nx, ny), out);
        spread(1, j, -w, (nx, ny), out);
    } else if i >= nxi {
        spread(nxi - 1, j, 2.0 * w, (nx, ny), out);
        spread(nxi - 2, j, -w, (nx, ny), out);
    } else if j < 0 {
        spread(i, 0, 2.0 * w, (nx, ny), out);
        spread(i, 1, -w, (nx, ny), out);
    } else if j >= nyi {
        spread(i, nyi - 1, 2.0 * w, (nx, ny), out);
        spread(i, nyi - 2, -w, (nx, ny), out);
    } else {
        let k = j as usize * nx + i as usize;
        match out.iter_mut().find(|(n, _)| *n == k) {
            Some((_, v)) => *v += w,
            None => out.push((k, w)),
        }
    }
}

/// The cell (its lower node) holding `x` on an axis from `min` with `step` and `n` nodes, the
/// fraction across it, and whether `x` was inside the grid (outside it is clamped to the edge).
fn cell(x: f64, min: f64, step: f64, n: usize) -> (isize, f64, bool) {
    let u = (x - min) / step;
    let top = (n - 1) as f64;
    let inside = (0.0..=top).contains(&u);
    let u = u.clamp(0.0, top);
    let i = (u.floor() as isize).min(n as isize - 2);
    (i, u - i as f64, inside)
}

/// The weights of the nodes i−1, i, i+1, i+2 at fraction `t` of cell i, and their derivatives
/// in `t`.
fn weights(algorithm: MeshAlgorithm, t: f64) -> ([f64; 4], [f64; 4]) {
    match algorithm {
        MeshAlgorithm::Bilinear => ([0.0, 1.0 - t, t, 0.0], [0.0, -1.0, 1.0, 0.0]),
        MeshAlgorithm::Bicubic => {
            let (t2, t3) = (t * t, t * t * t);
            (
                [0.5 * (-t + 2.0 * t2 - t3), 0.5 * (2.0 - 5.0 * t2 + 3.0 * t3), 0.5 * (t + 4.0 * t2 - 3.0 * t3), 0.5 * (-t2 + t3)],
                [
                    0.5 * (-1.0 + 4.0 * t - 3.0 * t2),
                    0.5 * (-10.0 * t + 9.0 * t2),
                    0.5 * (1.0 + 8.0 * t - 9.0 * t2),
                    0.5 * (-2.0 * t + 3.0 * t2),
                ],
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kin::geom;

    fn config(points: Vec<Vec<f64>>, algorithm: MeshAlgorithm) -> BedMeshConfig {
        BedMeshConfig { min: [0.0, 0.0], max: [0.2, 0.1], points, algorithm, fade_start: 1e-3, fade_end: 10e-3, fade_target: None }
    }

    /// A plane z = a + b·x + c·y on a 5×3 grid.
    fn plane(a: f64, b: f64, c: f64) -> Vec<Vec<f64>> {
        (0..3).map(|j| (0..5).map(|i| a + b * 0.05 * i as f64 + c * 0.05 * j as f64).collect()).collect()
    }

    #[test]
    fn both_algorithms_pass_through_the_probed_heights_and_keep_a_plane_a_plane() {
        let warp: Vec<Vec<f64>> = (0..3).map(|j| (0..5).map(|i| 1e-4 * ((i * 7 + j * 3) % 5) as f64 - 2e-4).collect()).collect();
        for algorithm in [MeshAlgorithm::Bilinear, MeshAlgorithm::Bicubic] {
            let mesh = BedMesh::new(&config(warp.clone(), algorithm), Vector3::zeros(), Rotation3::identity()).unwrap();
            for (j, row) in warp.iter().enumerate() {
                for (i, z) in row.iter().enumerate() {
                    assert!((mesh.height(0.05 * i as f64, 0.05 * j as f64) - z).abs() < 1e-15, "{algorithm:?} {i} {j}");
                }
            }
            let flat = BedMesh::new(&config(plane(1e-4, 2e-3, -1e-3), algorithm), Vector3::zeros(), Rotation3::identity()).unwrap();
            for (x, y) in [(0.013, 0.071), (0.1, 0.05), (0.199, 0.001), (0.0375, 0.0625)] {
                let (z, [sx, sy]) = flat.surface(x, y);
                assert!((z - (1e-4 + 2e-3 * x - 1e-3 * y)).abs() < 1e-15, "{algorithm:?} at {x} {y}: {z}");
                assert!((sx - 2e-3).abs() < 1e-12 && (sy + 1e-3).abs() < 1e-12, "{algorithm:?}: {sx} {sy}");
            }
            // Outside the grid: the edge's height, no slope.
            let (z, s) = flat.surface(0.3, -0.05);
            assert!((z - (1e-4 + 2e-3 * 0.2)).abs() < 1e-15 && s == [0.0, 0.0], "{z} {s:?}");
        }
    }

    #[test]
    fn the_node_weights_give_the_height() {
        let warp: Vec<Vec<f64>> = (0..3).map(|j| (0..5).map(|i| 1e-4 * (((i * 7 + j * 3) % 5) as f64).sin()).collect()).collect();
        for algorithm in [MeshAlgorithm::Bilinear, MeshAlgorithm::Bicubic] {
            let cfg = config(warp.clone(), algorithm);
            let mesh = BedMesh::new(&cfg, Vector3::zeros(), Rotation3::identity()).unwrap();
            for (x, y) in [(0.013, 0.071), (0.0, 0.0), (0.2, 0.1), (0.171, 0.09), (0.25, -0.01)] {
                let weighted: f64 = cfg.node_weights(x, y).iter().map(|(k, w)| w * warp[k / 5][k % 5]).sum();
                assert!((weighted - mesh.height(x, y)).abs() < 1e-18, "{algorithm:?} at {x} {y}");
            }
        }
    }

    #[test]
    fn the_slope_is_the_derivative_of_the_height() {
        let warp: Vec<Vec<f64>> = (0..3).map(|j| (0..5).map(|i| 1e-4 * (((i * 7 + j * 3) % 5) as f64).sin()).collect()).collect();
        for algorithm in [MeshAlgorithm::Bilinear, MeshAlgorithm::Bicubic] {
            let mesh = BedMesh::new(&config(warp.clone(), algorithm), Vector3::zeros(), Rotation3::identity()).unwrap();
            for (x, y) in [(0.013, 0.071), (0.111, 0.033), (0.171, 0.09)] {
                let (_, [sx, sy]) = mesh.surface(x, y);
                let e = 1e-7;
                let nx = (mesh.height(x + e, y) - mesh.height(x - e, y)) / (2.0 * e);
                let ny = (mesh.height(x, y + e) - mesh.height(x, y - e)) / (2.0 * e);
                assert!((sx - nx).abs() < 1e-7 && (sy - ny).abs() < 1e-7, "{algorithm:?}: {sx} {nx} {sy} {ny}");
            }
        }
    }

    #[test]
    fn the_correction_fades_and_its_inverse_is_exact_on_a_tilted_bed() {
        let warp: Vec<Vec<f64>> = (0..3).map(|j| (0..5).map(|i| 3e-4 * ((i + 2 * j) % 3) as f64 - 3e-4).collect()).collect();
        let cfg = config(warp, MeshAlgorithm::Bicubic);
        let (origin, rotation) = (Vector3::new(0.5, -0.1, 0.2), geom::rpy(0.1, -0.05, 0.7));
        let mesh = BedMesh::new(&cfg, origin, rotation).unwrap();
        let target = cfg.mean();
        let n = rotation * Vector3::z();
        for (x, y) in [(0.02, 0.03), (0.15, 0.08)] {
            let m = mesh.height(x, y);
            for (h, c) in [(0.0, m), (0.5e-3, m), (1e-3, m), (5.5e-3, target + 0.5 * (m - target)), (10e-3, target), (0.3, target)] {
                let p = origin + rotation * Vector3::new(x, y, h);
                let w = mesh.to_world(&p);
                assert!((w - (p + n * c)).norm() < 1e-15, "h {h}: {w:?}");
                assert!((mesh.to_program(&w) - p).norm() < 1e-15, "h {h}");
            }
        }
    }

    #[test]
    fn a_sample_moves_with_the_rate_of_change_of_its_correction() {
        let warp: Vec<Vec<f64>> = (0..3).map(|j| (0..5).map(|i| 2e-4 * ((i * 3 + j) % 4) as f64).collect()).collect();
        let mesh = BedMesh::new(&config(warp, MeshAlgorithm::Bicubic), Vector3::new(0.4, 0.0, 0.1), geom::rpy(0.0, 0.1, 0.3)).unwrap();
        let r = geom::rpy(0.0, 0.1, 0.3);
        // A line through the fade band, in the bed frame, at 0.05 m/s.
        let at = |t: f64| Vector3::new(0.4, 0.0, 0.1) + r * Vector3::new(0.02 + 0.04 * t, 0.01 + 0.03 * t, 0.5e-3 + 0.02 * t);
        let velocity = (at(1.0) - at(0.0)) * 0.05;
        let (t, e) = (0.3, 1e-6);
        let (mut position, mut v, mut a) = (at(t), velocity, Vector3::zeros());
        mesh.apply(&mut position, &mut v, &mut a);
        assert!((position - mesh.to_world(&at(t))).norm() < 1e-15);
        let numeric = (mesh.to_world(&at(t + e)) - mesh.to_world(&at(t - e))) / (2.0 * e) * 0.05;
        assert!((v - numeric).norm() < 1e-9, "{v:?} {numeric:?}");
    }

    #[test]
    fn bad_meshes_are_refused_naming_the_key() {
        let id = || (Vector3::zeros(), Rotation3::identity());
        let check = |cfg: BedMeshConfig, says: &str| {
            let e = BedMesh::new(&cfg, id().0, id().1).unwrap_err();
            assert!(e.message.starts_with("[bed.mesh] ") && e.message.contains(says), "{}", e.message);
        };
        check(config(vec![vec![0.0; 5]], MeshAlgorithm::Bicubic), "1 rows of 5 heights");
        check(config(vec![vec![0.0; 5], vec![0.0; 4], vec![0.0; 5]], MeshAlgorithm::Bicubic), "row 2 has 4 heights");
        check(config(vec![vec![0.0; 5], vec![0.0, f64::NAN, 0.0, 0.0, 0.0], vec![0.0; 5]], MeshAlgorithm::Bicubic), "row 2, column 2");
        check(config(plane(0.0, 0.5, 0.0), MeshAlgorithm::Bicubic), "heights are in m");
        check(BedMeshConfig { max: [0.0, 0.1], ..config(plane(0.0, 0.0, 0.0), MeshAlgorithm::Bicubic) }, "min < max");
        let steep = config(plane(0.0, 0.02, 0.0), MeshAlgorithm::Bicubic);
        check(BedMeshConfig { fade_start: 1e-3, fade_end: 2e-3, ..steep.clone() }, "more than twice");
        // No fade: any span of heights under 20 mm.
        assert!(BedMesh::new(&BedMeshConfig { fade_end: 0.0, ..steep }, id().0, id().1).is_ok());
    }
}
