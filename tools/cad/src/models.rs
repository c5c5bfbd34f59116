//! The test models, made without a CAD program: faces and a solid built with truck from surfaces we
//! construct, written as STEP (AP203 B-rep; truck writes millimetres). `tests/data/step/` holds what
//! [`write_all`] writes (`cargo run -p strand-cad --example make_step_models` remakes them; a test holds
//! the committed files equal to it), so the reader is tested on files it did not write in memory.

use std::f64::consts::PI;

use truck_modeling::{
    BSplineSurface, Curve, Cut, Edge, Face, KnotVec, NurbsSurface, ParametricSurface, Point3, Shell, Solid, Surface, Vector3, Vector4,
    Vertex, Wire, builder,
};
use truck_stepio::out::{CompleteStepDisplay, StepHeaderDescriptor, StepModel};

/// 003's curved rectangle as `strand-plan surface --shape curved-rect` builds it (Fig. 3, our reading):
/// a sheet 100 mm wide along x, bent along its length into a 120° arc of radius 50 mm in the y–z plane,
/// leaving the bed tangentially at the origin and curling back over it. One face, on the NURBS surface
/// truck sweeps from an exact circular arc (a rational quadratic), oriented as the built-in one: its
/// normal towards the centre of the bend, the side the nozzle prints from.
pub fn curved_rect() -> Shell {
    let (r, bend, width) = (50.0, 2.0 * PI / 3.0, 100.0);
    let at = |phi: f64| Point3::new(0.0, r * phi.sin(), r * (1.0 - phi.cos()));
    let arc = builder::circle_arc(&builder::vertex(at(0.0)), &builder::vertex(at(bend)), at(0.5 * bend));
    let sheet: Face = builder::tsweep(&arc, Vector3::new(width, 0.0, 0.0));
    Shell::from(vec![sheet.inverse()])
}

/// A bicubic B-spline face, 100 × 60 mm with an 8 mm bump, and a rectangular hole trimmed out of it:
/// the hole's edges are the surface's own iso-parameter curves, so its trim in (u, v) is exactly
/// `HOLE_UV` (u ∈ [0.35, 0.65], v ∈ [0.3, 0.7]).
pub fn bump_with_hole() -> Shell {
    let cps: Vec<Vec<Point3>> = (0..4)
        .map(|i| {
            (0..4)
                .map(|j| {
                    let z = if (1..=2).contains(&i) && (1..=2).contains(&j) { 8.0 } else { 0.0 };
                    Point3::new(100.0 * i as f64 / 3.0, 60.0 * j as f64 / 3.0, z)
                })
                .collect()
        })
        .collect();
    let s = BSplineSurface::new((KnotVec::bezier_knot(3), KnotVec::bezier_knot(3)), cps);
    let outer = boundary_wire(&s.splitted_boundary().map(Curve::BSplineCurve), |u, v| s.subs(u, v));
    // The hole runs clockwise in (u, v), against the outer loop.
    let [(ua, ub), (va, vb)] = HOLE_UV;
    let corners = [(ua, va), (ua, vb), (ub, vb), (ub, va)];
    let hv: Vec<Vertex> = corners.iter().map(|&(u, v)| builder::vertex(s.subs(u, v))).collect();
    // The piece of an iso-parameter curve from t0 to t1 (in that direction).
    let piece = |mut c: truck_modeling::BSplineCurve<Point3>, t0: f64, t1: f64| {
        let mut mid = c.cut(t0.min(t1));
        mid.cut(t0.max(t1));
        if t0 > t1 {
            mid.invert();
        }
        Curve::BSplineCurve(mid)
    };
    let iso_u = |u: f64, v0: f64, v1: f64| piece(s.clone().ucut(u).column_curve(0), v0, v1);
    let iso_v = |v: f64, u0: f64, u1: f64| piece(s.clone().vcut(v).row_curve(0), u0, u1);
    let hole: Wire = vec![
        Edge::new(&hv[0], &hv[1], iso_u(ua, va, vb)),
        Edge::new(&hv[1], &hv[2], iso_v(vb, ua, ub)),
        Edge::new(&hv[2], &hv[3], iso_u(ub, vb, va)),
        Edge::new(&hv[3], &hv[0], iso_v(va, ub, ua)),
    ]
    .into();
    Shell::from(vec![Face::try_new(vec![outer, hole], Surface::BSplineSurface(s)).expect("a face with a hole")])
}

/// The hole of [`bump_with_hole`] in its surface's parameters: [(u_min, u_max), (v_min, v_max)].
pub const HOLE_UV: [(f64, f64); 2] = [(0.35, 0.65), (0.3, 0.7)];

/// A doubly curved rational patch: a bicubic NURBS saddle over 80 × 80 mm, ±10 mm, its inner control
/// points weighted 2 (so no polynomial B-spline is the same surface).
pub fn nurbs_saddle() -> Shell {
    let cps: Vec<Vec<Vector4>> = (0..4)
        .map(|i| {
            (0..4)
                .map(|j| {
                    let (x, y) = (80.0 * i as f64 / 3.0, 80.0 * j as f64 / 3.0);
                    let (a, b) = (i as f64 - 1.5, j as f64 - 1.5);
                    let z = 10.0 * (a * a - b * b) / 2.25;
                    let w = if (1..=2).contains(&i) && (1..=2).contains(&j) { 2.0 } else { 1.0 };
                    Vector4::new(w * x, w * y, w * z, w)
                })
                .collect()
        })
        .collect();
    let s = NurbsSurface::new(BSplineSurface::new((KnotVec::bezier_knot(3), KnotVec::bezier_knot(3)), cps));
    let outer = boundary_wire(&s.splitted_boundary().map(Curve::NurbsCurve), |u, v| s.subs(u, v));
    Shell::from(vec![Face::new(vec![outer], Surface::NurbsSurface(s))])
}

/// A multi-face solid: a plate 100 × 60 × 10 mm with a round hole of radius 15 mm through it at
/// (50, 30): six planes (top and bottom trimmed by the circle) and the hole's wall in two NURBS halves.
pub fn punched_plate() -> Solid {
    let v: Vec<Vertex> =
        [(0.0, 0.0), (100.0, 0.0), (100.0, 60.0), (0.0, 60.0)].iter().map(|&(x, y)| builder::vertex(Point3::new(x, y, 0.0))).collect();
    let outer: Wire = (0..4).map(|i| builder::line(&v[i], &v[(i + 1) % 4])).collect();
    let (c0, c1) = (builder::vertex(Point3::new(65.0, 30.0, 0.0)), builder::vertex(Point3::new(35.0, 30.0, 0.0)));
    let circle: Wire =
        vec![builder::circle_arc(&c0, &c1, Point3::new(50.0, 45.0, 0.0)), builder::circle_arc(&c1, &c0, Point3::new(50.0, 15.0, 0.0))]
            .into();
    let face = builder::try_attach_plane(&[outer, circle.inverse()]).expect("a plane with a hole");
    builder::tsweep(&face, Vector3::new(0.0, 0.0, 10.0))
}

/// The loop (0,0) → (1,0) → (1,1) → (0,1) of a Bézier patch, counter-clockwise in (u, v).
fn boundary_wire(curves: &[Curve; 4], at: impl Fn(f64, f64) -> Point3) -> Wire {
    let v: Vec<Vertex> = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)].iter().map(|&(u, w)| builder::vertex(at(u, w))).collect();
    (0..4).map(|k| Edge::new(&v[k], &v[(k + 1) % 4], curves[k].clone())).collect()
}

/// The STEP text of a shell (an open shell: one or more loose faces).
pub(crate) fn shell_step(shell: &Shell, name: &str) -> String {
    CompleteStepDisplay::new(StepModel::from(&shell.compress()), header(name)).to_string()
}

/// The STEP text of a solid (a manifold solid B-rep).
pub(crate) fn solid_step(solid: &Solid, name: &str) -> String {
    CompleteStepDisplay::new(StepModel::from(&solid.compress()), header(name)).to_string()
}

/// A fixed header, so the same model writes the same bytes.
fn header(name: &str) -> StepHeaderDescriptor {
    StepHeaderDescriptor {
        file_name: name.to_string(),
        time_stamp: "2026-11-26T00:00:00".to_string(),
        organization_system: "strand-cad models".to_string(),
        ..Default::default()
    }
}

/// Every test model: (file name, STEP text).
pub fn all() -> Vec<(&'static str, String)> {
    vec![
        ("curved_rect.step", shell_step(&curved_rect(), "curved_rect.step")),
        ("bump_with_hole.step", shell_step(&bump_with_hole(), "bump_with_hole.step")),
        ("nurbs_saddle.step", shell_step(&nurbs_saddle(), "nurbs_saddle.step")),
        ("punched_plate.step", solid_step(&punched_plate(), "punched_plate.step")),
    ]
}

/// Writes every test model into `dir`.
pub fn write_all(dir: &std::path::Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    for (name, text) in all() {
        std::fs::write(dir.join(name), text)?;
    }
    Ok(())
}
