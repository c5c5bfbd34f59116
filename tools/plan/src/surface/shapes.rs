//! The faces the planner works on: the [`Surface`] trait (a face r(u, v) over its parameter [`Domain`], 003's
//! Eq. 1, with Eq. 2's normal) and the five shapes `strand-plan surface` knows. Everything downstream sees a
//! face only through the trait, so a new shape needs nothing but an `impl Surface`.

use std::f64::consts::PI;

use nalgebra::Vector3;

/// The rectangle of parameters a surface is defined on: 003's `pRange` (units: the surface's u and v).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Domain {
    /// (u_min, u_max), in the surface's u unit (m or rad).
    pub u: (f64, f64),
    /// (v_min, v_max), in the surface's v unit (m or rad).
    pub v: (f64, f64),
}

impl Domain {
    /// u_max − u_min (u unit).
    pub(crate) fn span_u(&self) -> f64 {
        self.u.1 - self.u.0
    }

    /// v_max − v_min (v unit).
    pub(crate) fn span_v(&self) -> f64 {
        self.v.1 - self.v.0
    }

    /// True if (u, v) lies in the rectangle, with a tolerance of 1e-9 of each span for the rounding of
    /// summed steps.
    pub fn contains(&self, u: f64, v: f64) -> bool {
        let (eu, ev) = (1e-9 * self.span_u(), 1e-9 * self.span_v());
        u >= self.u.0 - eu && u <= self.u.1 + eu && v >= self.v.0 - ev && v <= self.v.1 + ev
    }
}

/// A face r(u, v) (003 Eq. 1) over a parameter rectangle, possibly trimmed.
pub trait Surface {
    /// The parameter rectangle (003's `pRange`).
    fn domain(&self) -> Domain;

    /// The point r(u, v) (m, bed frame; 003's `valueAt`). Defined on the whole domain and a little beyond
    /// (the calibration probes past the edges).
    fn point(&self, u: f64, v: f64) -> Vector3<f64>;

    /// The unit normal at (u, v), on the side the nozzle works from (the tool z axis is its negative).
    /// The default is 003's Eq. 2, ∂r/∂u × ∂r/∂v by central differences, normalised: a surface whose
    /// parametrisation has the nozzle on the other side must override it.
    fn normal(&self, u: f64, v: f64) -> Vector3<f64> {
        eq2_normal(self, u, v)
    }

    /// 003's `isInside`: true if (u, v) lies on the face. The default is the whole domain; a trimmed face
    /// narrows it.
    fn contains(&self, u: f64, v: f64) -> bool {
        self.domain().contains(u, v)
    }

    /// Axis labels for plots, with units: (u, v).
    fn parameter_labels(&self) -> (&'static str, &'static str);

    /// The periods of u and v where the surface closes on itself (a whole cylinder); none by default.
    fn periods(&self) -> [Option<f64>; 2] {
        [None, None]
    }
}

/// 003's Eq. 2 normal, n = ∂r/∂u × ∂r/∂v, by central differences (step 1e-6 of each span), normalised.
/// Zero where the parametrisation is degenerate (both partials parallel or zero).
pub fn eq2_normal<S: Surface + ?Sized>(s: &S, u: f64, v: f64) -> Vector3<f64> {
    let d = s.domain();
    let (hu, hv) = (1e-6 * d.span_u(), 1e-6 * d.span_v());
    let ru = (s.point(u + hu, v) - s.point(u - hu, v)) / (2.0 * hu);
    let rv = (s.point(u, v + hv) - s.point(u, v - hv)) / (2.0 * hv);
    ru.cross(&rv).try_normalize(1e-300).unwrap_or_else(Vector3::zeros)
}

/// A flat rectangle on the bed plane z = `z`: u along x, v along y (both m), normal +z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Extent along x = u (m).
    pub length: f64,
    /// Extent along y = v (m).
    pub width: f64,
    /// Height of the plane above the bed (m).
    pub z: f64,
}

impl Surface for Plane {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.length), v: (0.0, self.width) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(u, v, self.z)
    }
    fn normal(&self, _u: f64, _v: f64) -> Vector3<f64> {
        Vector3::z()
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = x (m)", "v = y (m)")
    }
}

/// A patch of a cylinder lying on the bed with its axis along x at height 0, printed from outside:
/// r(u, v) = (u, R sin v, R cos v), u ∈ [0, length] (m), v ∈ [−sweep/2, sweep/2] (rad from the top),
/// normal (0, sin v, cos v) (radially out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    /// Radius R (m).
    pub radius: f64,
    /// Extent along the axis (m).
    pub length: f64,
    /// Angle the patch spans around the axis, centred on the top (rad, < 2π).
    pub sweep: f64,
}

impl Surface for Cylinder {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.length), v: (-0.5 * self.sweep, 0.5 * self.sweep) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(u, self.radius * v.sin(), self.radius * v.cos())
    }
    fn normal(&self, _u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(0.0, v.sin(), v.cos())
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = x (m)", "v = angle from the top (rad)")
    }
}

/// 003's curved rectangle (Figs. 3, 5, 6), our reading. The text says only "a curved rectangular surface",
/// chosen "to demonstrate how a path for printing in overhang can be achieved", sampled at 10 mm, and that
/// weighting u is "to guide the path along the v-direction, resulting in movements from side to side". We take
/// a rectangular sheet, `width` wide along x, bent along its length into a circular arc of radius R in the
/// y–z plane: it leaves the bed tangentially, rises through vertical and, past 90°, curls back over the
/// bed, so its upper part overhangs and is printed with the nozzle pointing up-ish (a quarter pipe printed
/// from its concave side). u runs along the bend (up the sheet), v across it (side to side), so a u-weighted
/// path prints horizontal lines across the width, climbing the arch line by line into the overhang:
///
/// r(u, v) = (v, R sin φ, R (1 − cos φ)), φ = u / R, u ∈ [0, R·bend] (m of arc length), v ∈ [0, width] (m),
/// normal (0, −sin φ, cos φ), towards the centre of the bend (that is −(∂r/∂u × ∂r/∂v)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurvedRect {
    /// Width along x = v (m).
    pub width: f64,
    /// Bend radius R (m).
    pub radius: f64,
    /// Bend angle (rad); above π/2 the sheet overhangs.
    pub bend: f64,
}

impl Surface for CurvedRect {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.radius * self.bend), v: (0.0, self.width) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        let phi = u / self.radius;
        Vector3::new(v, self.radius * phi.sin(), self.radius * (1.0 - phi.cos()))
    }
    fn normal(&self, u: f64, _v: f64) -> Vector3<f64> {
        let phi = u / self.radius;
        Vector3::new(0.0, -phi.sin(), phi.cos())
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = arc length up the bend (m)", "v = x across (m)")
    }
}

/// 002's Gaussian bump (Eq. 20), a ridge along x: z = z0·exp(−y²/β²), u = x ∈ [0, length],
/// v = y ∈ [−width/2, width/2] (m); normal (0, −∂z/∂y, 1)/|·|.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bump {
    /// Extent along x (m).
    pub length: f64,
    /// Extent along y, centred on the ridge (m).
    pub width: f64,
    /// Peak height z0 (m).
    pub height: f64,
    /// Width parameter β (m).
    pub beta: f64,
}

impl Bump {
    /// Eq. 20: the height at y (m).
    pub fn z(&self, y: f64) -> f64 {
        self.height * (-(y * y) / (self.beta * self.beta)).exp()
    }

    /// dz/dy of Eq. 20.
    pub fn slope(&self, y: f64) -> f64 {
        -2.0 * y / (self.beta * self.beta) * self.z(y)
    }
}

impl Surface for Bump {
    fn domain(&self) -> Domain {
        Domain { u: (0.0, self.length), v: (-0.5 * self.width, 0.5 * self.width) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(u, v, self.z(v))
    }
    fn normal(&self, _u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(0.0, -self.slope(v), 1.0).normalize()
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = x (m)", "v = y (m)")
    }
}

/// A twisted, cambered, propeller-like blade standing in for 003's propeller blade (Figs. 4, 7, 8), a
/// trimmed face. Not a real propeller section; it has the features that matter to the paper: twist,
/// curvature, a non-rectangular outline.
///
/// u = r ∈ [hub_radius, tip_radius] is the span along x (m); v = s ∈ [−chord/2, chord/2] the chordwise
/// coordinate (m). The blade section at r is the camber line (s, h(s)), h(s) = camber·chord/2·(1 − (2s/chord)²),
/// turned by the pitch angle θ(r) = atan(pitch / (2π r)) (a constant-pitch helix: steep at the hub, flat at
/// the tip) in the y–z plane and lifted by `lift`:
///
/// r(u, v) = (r, s cos θ − h sin θ, s sin θ + h cos θ + lift).
///
/// The face is trimmed (003's `isInside`) to |s| ≤ c(r)/2 with the outline
/// c(r) = chord·(0.6 + 0.4 sin πσ)·√(1 − σ⁶), σ = (r − hub_radius)/(tip_radius − hub_radius): 60 % of the
/// chord at the root, widest mid-span, closing to a round tip. The normal is Eq. 2's (the suction side,
/// +z-ish).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blade {
    /// Span start (m from the propeller axis).
    pub hub_radius: f64,
    /// Span end (m from the propeller axis).
    pub tip_radius: f64,
    /// Widest chord (m).
    pub chord: f64,
    /// Geometric pitch (m per turn).
    pub pitch: f64,
    /// Camber height as a fraction of the half chord (1).
    pub camber: f64,
    /// Height of the blade's axis above the bed (m).
    pub lift: f64,
}

impl Blade {
    /// The trimmed chord length at span r (m).
    pub(crate) fn outline(&self, r: f64) -> f64 {
        let sigma = ((r - self.hub_radius) / (self.tip_radius - self.hub_radius)).clamp(0.0, 1.0);
        self.chord * (0.6 + 0.4 * (PI * sigma).sin()) * (1.0 - sigma.powi(6)).max(0.0).sqrt()
    }
}

impl Surface for Blade {
    fn domain(&self) -> Domain {
        Domain { u: (self.hub_radius, self.tip_radius), v: (-0.5 * self.chord, 0.5 * self.chord) }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        let theta = (self.pitch / (2.0 * PI * u)).atan();
        let s = 2.0 * v / self.chord;
        let h = self.camber * 0.5 * self.chord * (1.0 - s * s);
        let (st, ct) = theta.sin_cos();
        Vector3::new(u, v * ct - h * st, v * st + h * ct + self.lift)
    }
    fn contains(&self, u: f64, v: f64) -> bool {
        self.domain().contains(u, v) && v.abs() <= 0.5 * self.outline(u) * (1.0 + 1e-9)
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u = span r (m)", "v = chordwise s (m)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::fixtures::{blade, bump, curved, cylinder};

    #[test]
    fn analytic_normals_are_unit_and_agree_with_eq2() {
        let surfaces: [(&dyn Surface, f64); 4] =
            [(&Plane { length: 0.1, width: 0.1, z: 0.0 }, 1.0), (&cylinder(), 1.0), (&bump(), 1.0), (&curved(), -1.0)];
        for (s, sign) in surfaces {
            let d = s.domain();
            for i in 0..=6 {
                for j in 0..=6 {
                    let u = d.u.0 + d.span_u() * i as f64 / 6.0;
                    let v = d.v.0 + d.span_v() * j as f64 / 6.0;
                    let n = s.normal(u, v);
                    assert!((n.norm() - 1.0).abs() < 1e-12, "{n:?}");
                    let e = eq2_normal(s, u, v) * sign;
                    assert!((n - e).norm() < 1e-6, "({u}, {v}): {n:?} vs Eq. 2 {e:?}");
                }
            }
        }
    }

    #[test]
    fn normals_point_where_the_geometry_says() {
        // Cylinder: radially out from the axis (the x axis).
        let c = cylinder();
        for v in [-1.0, -0.3, 0.0, 0.7, 1.0] {
            let p = c.point(0.05, v);
            let radial = Vector3::new(0.0, p.y, p.z).normalize();
            assert!((c.normal(0.05, v) - radial).norm() < 1e-12);
        }
        // Bump: perpendicular to the ridge slope, up; level on the crest and tilted by atan(z') off it.
        let b = bump();
        assert!((b.normal(0.02, 0.0) - Vector3::z()).norm() < 1e-12);
        let y = b.beta / 2f64.sqrt(); // steepest point: z' = −√2·z0/β·e^(−1/2)
        let slope = 2f64.sqrt() * b.height / b.beta * (-0.5f64).exp();
        let n = b.normal(0.02, y);
        assert!((n.z.acos() - slope.atan()).abs() < 1e-12 && n.y > 0.0 && n.x == 0.0, "{n:?}");
        // Curved rectangle: up at the foot, −y at the vertical, pointing down past it (the overhang).
        let r = curved();
        assert!((r.normal(0.0, 0.05) - Vector3::z()).norm() < 1e-12);
        assert!((r.normal(0.05 * PI / 2.0, 0.05) + Vector3::y()).norm() < 1e-12);
        let top = r.normal(r.domain().u.1, 0.05);
        assert!(top.z < -0.49 && top.y < 0.0, "{top:?}");
        // Blade: Eq. 2 (finite differences) is unit and faces up on the suction side.
        let bl = blade();
        let n = bl.normal(0.09, 0.0);
        assert!((n.norm() - 1.0).abs() < 1e-9 && n.z > 0.5, "{n:?}");
    }
}
