//! The bed mesh from probed heights: points on the bed's surface (touched with the nozzle, or from
//! a file a probe wrote), in the bed frame, fitted to the heights at the nodes of an even grid
//! (`[bed.mesh] points`), which the path engine then interpolates (`strand_core::BedMesh`).
//!
//! The touches need not sit exactly on the nodes (an operator jogging a nozzle never hits them): the
//! node heights are the least-squares fit to every touch of the very surface the engine will
//! interpolate through them (bicubic or bilinear: it is linear in the heights), with a faint
//! second-difference smoothing that only decides what the touches leave open. A node no touch
//! comes near (within about half a cell) is refused rather than invented. Touched on the nodes, the
//! fit is the touches' own heights (to well under a micrometre).

use std::path::Path;

use nalgebra::{DMatrix, DVector, Vector3};

use strand_core::{BedMeshConfig, MeshAlgorithm};

use crate::error::CalibrationError;
use crate::linalg::least_squares;
use crate::rows;

/// Touches the fit needs at least (a 2 × 2 grid).
pub const MIN_POINTS: usize = 4;
/// A node needs touches whose interpolation weights on it add up to this much (a touch on the
/// node gives 1, one half a cell away on both axes 0.25 bilinear, 0.32 bicubic).
pub const MIN_SUPPORT: f64 = 0.2;
/// Weight of the second-difference smoothing against a touch.
const SMOOTHING: f64 = 1e-4;

/// The grid: node counts and, if given, its corners (else the touches' bounding box), and the
/// interpolation the heights are for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshGrid {
    /// The interpolation the path engine will use between the heights (the fit uses the same).
    pub algorithm: MeshAlgorithm,
    /// Nodes along x and along y (2 to 32 each).
    pub counts: [usize; 2],
    /// Lower and upper corner (x, y) in the bed frame (m); `None`: the touches' extent.
    pub bounds: Option<([f64; 2], [f64; 2])>,
}

/// The mesh found.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshFit {
    /// The grid's lower corner (x, y), bed frame (m): `[bed.mesh] min`.
    pub min: [f64; 2],
    /// The grid's upper corner (x, y), bed frame (m): `[bed.mesh] max`.
    pub max: [f64; 2],
    /// Heights at the nodes (m), one row per y, one value per x: `[bed.mesh] points`.
    pub points: Vec<Vec<f64>>,
    /// Each touch's height minus the fitted surface's there (mm).
    pub residuals_mm: Vec<f64>,
    /// Highest minus lowest node (mm).
    pub range_mm: f64,
    /// Slope of the touches' mean plane along x and y (mrad): what a better `[bed] frame` would take out.
    pub tilt_mrad: [f64; 2],
}

/// The node heights of `grid` fitted to `touches` (x, y, height in the bed frame, m).
pub fn solve_mesh(touches: &[Vector3<f64>], grid: MeshGrid) -> Result<MeshFit, CalibrationError> {
    let n = touches.len();
    if n < MIN_POINTS {
        return Err(CalibrationError::TooFew { what: "points", needed: MIN_POINTS, got: n });
    }
    let [nx, ny] = grid.counts;
    for (axis, c) in [("x", nx), ("y", ny)] {
        if !strand_core::MESH_COUNT.contains(&c) {
            return Err(CalibrationError::BadValue {
                what: "grid",
                reason: format!("{c} nodes along {axis}: a mesh has 2 to 32 per axis"),
            });
        }
    }
    if n < nx * ny / 2 {
        return Err(CalibrationError::TooFew { what: "points for the grid", needed: nx * ny / 2, got: n });
    }
    let (min, max) = grid.bounds.unwrap_or_else(|| {
        let lo = |k: usize| touches.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
        let hi = |k: usize| touches.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max);
        ([lo(0), lo(1)], [hi(0), hi(1)])
    });
    for (k, axis) in ["x", "y"].iter().enumerate() {
        let span = max[k] - min[k];
        if span.is_nan() || span < 5e-3 {
            return Err(CalibrationError::degenerate(format!(
                "the grid spans {:.1} mm along {axis}: touch points spread over the bed (at least 5 mm apart on x and on y)",
                (max[k] - min[k]) * 1e3
            )));
        }
    }
    let step = [(max[0] - min[0]) / (nx - 1) as f64, (max[1] - min[1]) / (ny - 1) as f64];
    // The surface the path engine will interpolate is linear in the node heights: each touch's
    // weights on them are what the engine's interpolation gives it.
    let layout = BedMeshConfig {
        min,
        max,
        points: vec![vec![0.0; nx]; ny],
        algorithm: grid.algorithm,
        fade_start: 0.0,
        fade_end: 0.0,
        fade_target: None,
    };
    let weights = |p: &Vector3<f64>| layout.node_weights(p.x, p.y);
    let nodes = nx * ny;
    let mut support = vec![0.0; nodes];
    for p in touches {
        for (k, w) in weights(p) {
            support[k] += w.max(0.0);
        }
    }
    if let Some(k) = (0..nodes).find(|&k| support[k] < MIN_SUPPORT) {
        let (i, j) = (k % nx, k / nx);
        return Err(CalibrationError::degenerate(format!(
            "no touch near node ({}, {}) at x = {:.1} mm, y = {:.1} mm (bed frame): touch there, or use a coarser --grid",
            i + 1,
            j + 1,
            (min[0] + i as f64 * step[0]) * 1e3,
            (min[1] + j as f64 * step[1]) * 1e3
        )));
    }
    let smoothing_rows = ny * nx.saturating_sub(2) + nx * ny.saturating_sub(2);
    let mut a = DMatrix::zeros(n + smoothing_rows, nodes);
    let mut b = DVector::zeros(n + smoothing_rows);
    for (r, p) in touches.iter().enumerate() {
        for (k, w) in weights(p) {
            a[(r, k)] += w;
        }
        b[r] = p.z;
    }
    let mut r = n;
    for j in 0..ny {
        for i in 1..nx.saturating_sub(1) {
            for (di, c) in [(0, 1.0), (1, -2.0), (2, 1.0)] {
                a[(r, j * nx + i - 1 + di)] = SMOOTHING * c;
            }
            r += 1;
        }
    }
    for i in 0..nx {
        for j in 1..ny.saturating_sub(1) {
            for (dj, c) in [(0, 1.0), (1, -2.0), (2, 1.0)] {
                a[(r, (j - 1 + dj) * nx + i)] = SMOOTHING * c;
            }
            r += 1;
        }
    }
    let (x, condition) = least_squares(&a, &b);
    if !condition.is_finite() || x.iter().any(|v| !v.is_finite()) {
        return Err(CalibrationError::degenerate("the touches do not determine the grid's heights: spread them over every cell"));
    }
    let residuals_mm = touches.iter().map(|p| (p.z - weights(p).iter().map(|(k, w)| w * x[*k]).sum::<f64>()) * 1e3).collect();
    let points: Vec<Vec<f64>> = (0..ny).map(|j| (0..nx).map(|i| x[j * nx + i]).collect()).collect();
    let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
    Ok(MeshFit { min, max, points, residuals_mm, range_mm: (hi - lo) * 1e3, tilt_mrad: mean_slope(touches) })
}

/// The slope (dz/dx, dz/dy, mrad) of the least-squares plane through `touches`.
fn mean_slope(touches: &[Vector3<f64>]) -> [f64; 2] {
    let mut a = DMatrix::zeros(touches.len(), 3);
    let mut b = DVector::zeros(touches.len());
    for (r, p) in touches.iter().enumerate() {
        a[(r, 0)] = 1.0;
        a[(r, 1)] = p.x;
        a[(r, 2)] = p.y;
        b[r] = p.z;
    }
    let (x, _) = least_squares(&a, &b);
    [x[1] * 1e3, x[2] * 1e3]
}

/// Reads probed points, one per line: x, y, z in the bed frame (m), comma-separated, `#` comments
/// allowed (what a probe's script writes; `strand calibrate mesh --points`).
pub fn read_points(path: &Path) -> Result<Vec<Vector3<f64>>, CalibrationError> {
    let text = rows::read(path)?;
    let rows = rows::parse(&text, &path.display().to_string(), &|n| n == 3, "3: x, y, z (m, bed frame)")?;
    Ok(rows.iter().map(|r| Vector3::new(r.values[0], r.values[1], r.values[2])).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tilted, warped bed (m): 0.3 mm of tilt across 100 mm and a 0.15 mm bowl.
    fn surface(x: f64, y: f64) -> f64 {
        3e-3 * x - 1e-3 * y + 0.15e-3 * (((x - 0.05) / 0.05).powi(2) + ((y - 0.04) / 0.04).powi(2))
    }

    fn noise(k: usize) -> f64 {
        // A fixed, zero-mean pseudo-random sequence in [−1, 1].
        ((k as f64 * 12.9898).sin() * 43758.5453).rem_euclid(1.0) * 2.0 - 1.0
    }

    #[test]
    fn touches_on_the_nodes_are_the_heights_and_off_them_the_surface_is_recovered_within_the_noise() {
        let on: Vec<Vector3<f64>> = (0..4)
            .flat_map(|j| (0..5).map(move |i| (0.025 * i as f64, 0.08 / 3.0 * j as f64)))
            .map(|(x, y)| Vector3::new(x, y, surface(x, y)))
            .collect();
        // An operator's touches: up to 2 mm off the nodes, 5 µm of noise, two per node.
        let off: Vec<Vector3<f64>> = on
            .iter()
            .enumerate()
            .flat_map(|(k, p)| [(k, 1.0), (k + 100, -1.0)].map(|(s, sign)| (s, p, sign)))
            .map(|(s, p, sign)| {
                let (x, y) = (p.x + sign * 2e-3 * noise(s), p.y - sign * 2e-3 * noise(s + 50));
                Vector3::new(x, y, surface(x, y) + 5e-6 * noise(s + 7))
            })
            .collect();
        // A touch 2 mm off a node reads the curved surface where a bilinear model has its chord,
        // ½·f''·d·(h − d) per axis (about 5 µm each here), and the bicubic one, extended linearly
        // past the edges, bends less than the bowl does in the edge cells: some 20 µm either way
        // on this 0.15 mm bowl over 25 mm cells, far inside the 0.05 mm a first layer needs.
        for (algorithm, within, residual_mm) in [(MeshAlgorithm::Bilinear, 25e-6, 0.03), (MeshAlgorithm::Bicubic, 25e-6, 0.02)] {
            let grid = MeshGrid { algorithm, counts: [5, 4], bounds: Some(([0.0, 0.0], [0.1, 0.08])) };
            let fit = solve_mesh(&on, grid).unwrap();
            for (k, p) in on.iter().enumerate() {
                assert!((fit.points[k / 5][k % 5] - p.z).abs() < 1e-9, "{algorithm:?} node {k}");
            }
            assert!(fit.residuals_mm.iter().all(|r| r.abs() < 1e-6));
            assert!((fit.tilt_mrad[0] - 3.0).abs() < 0.5 && (fit.tilt_mrad[1] + 1.0).abs() < 0.5, "{:?}", fit.tilt_mrad);
            let fit = solve_mesh(&off, grid).unwrap();
            let worst = on.iter().enumerate().map(|(k, p)| (fit.points[k / 5][k % 5] - p.z).abs()).fold(0.0, f64::max);
            eprintln!("{algorithm:?}: worst node error {:.1} µm", worst * 1e6);
            assert!(worst < within, "{algorithm:?}: {worst}");
            assert!(fit.residuals_mm.iter().all(|r| r.abs() < residual_mm), "{algorithm:?}: {:?}", fit.residuals_mm);
        }
    }

    #[test]
    fn degenerate_touches_are_refused_with_the_reason() {
        let grid = MeshGrid { algorithm: MeshAlgorithm::Bicubic, counts: [3, 3], bounds: None };
        let line: Vec<Vector3<f64>> = (0..9).map(|k| Vector3::new(0.01 * k as f64, 0.02, 0.0)).collect();
        let e = solve_mesh(&line, grid).unwrap_err();
        assert!(e.to_string().contains("spans 0.0 mm along y"), "{e}");
        let e = solve_mesh(&line[..3], grid).unwrap_err();
        assert_eq!(e, CalibrationError::TooFew { what: "points", needed: 4, got: 3 });
        // A corner no touch comes near.
        let corners: Vec<Vector3<f64>> =
            [(0.0, 0.0), (0.1, 0.0), (0.0, 0.1), (0.05, 0.05), (0.05, 0.0), (0.0, 0.05), (0.1, 0.05), (0.05, 0.1), (0.09, 0.09)]
                .iter()
                .map(|&(x, y)| Vector3::new(x, y, 0.0))
                .collect();
        let e =
            solve_mesh(&corners, MeshGrid { algorithm: MeshAlgorithm::Bicubic, counts: [3, 3], bounds: Some(([0.0, 0.0], [0.1, 0.1])) })
                .unwrap();
        assert!(e.points.iter().flatten().all(|z| z.abs() < 1e-12));
        let sparse: Vec<Vector3<f64>> = corners[..8].to_vec();
        let e = solve_mesh(&sparse, MeshGrid { algorithm: MeshAlgorithm::Bicubic, counts: [3, 3], bounds: Some(([0.0, 0.0], [0.1, 0.1])) })
            .unwrap_err();
        assert!(e.to_string().contains("no touch near node (3, 3) at x = 100.0 mm, y = 100.0 mm"), "{e}");
        let e = solve_mesh(&corners, MeshGrid { algorithm: MeshAlgorithm::Bicubic, counts: [40, 3], bounds: None }).unwrap_err();
        assert!(e.to_string().contains("40 nodes along x"), "{e}");
    }

    #[test]
    fn a_points_file_names_the_line_at_fault() {
        let dir = std::env::temp_dir().join(format!("strand-mesh-points-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("probe.csv");
        std::fs::write(&f, "# x, y, z (m)\n0.0, 0.0, 0.0001\n0.1, 0.0\n").unwrap();
        let e = read_points(&f).unwrap_err();
        assert!(e.to_string().contains(":3:0: 2 fields, expected 3: x, y, z"), "{e}");
        std::fs::write(&f, "0.0, 0.0, 0.0001  # a corner\n0.1, 0.0, -0.0002\n").unwrap();
        assert_eq!(read_points(&f).unwrap(), vec![Vector3::new(0.0, 0.0, 0.0001), Vector3::new(0.1, 0.0, -0.0002)]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
