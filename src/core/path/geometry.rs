//! Path geometry: the primitives the engine runs along (lines, arcs and helices, standstills),
//! parameterised by arc length, with their first and second derivatives so that a path speed and
//! acceleration map to a TCP velocity and acceleration.

use nalgebra::Vector3;

use super::segment::Segment;

/// A primitive of the executed path, in W.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Geometry {
    /// `start + direction · s`.
    Line {
        /// Where the line starts (m).
        start: Vector3<f64>,
        /// Unit direction of motion.
        direction: Vector3<f64>,
    },
    /// A circular arc, a helix or a slight spiral (002 Eqs. 4-5, extended):
    /// `x(θ) = centre + r(θ)(cos θ·e1 + sin θ·e2) + pitch·θ·normal`, `r(θ) = radius + radius_rate·θ`,
    /// θ from 0 to `sweep`, with θ proportional to arc length.
    Arc {
        /// Centre in the start's plane (m).
        centre: Vector3<f64>,
        /// Unit vector from the centre towards the start.
        e1: Vector3<f64>,
        /// `normal × e1`: the direction of motion at the start.
        e2: Vector3<f64>,
        /// Unit normal; the arc turns counter-clockwise about it.
        normal: Vector3<f64>,
        /// Radius at the start (m).
        radius: f64,
        /// Change of radius per radian (m/rad); 0 for a true circle.
        radius_rate: f64,
        /// Advance along the normal per radian (m/rad); 0 for a planar arc.
        pitch: f64,
        /// Swept angle (rad, > 0).
        sweep: f64,
    },
    /// Standing still (a dwell); zero length.
    Hold {
        /// Where the tool stands (m).
        point: Vector3<f64>,
    },
}

/// Position and its first two derivatives with respect to arc length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathPoint {
    /// Position (m, W).
    pub position: Vector3<f64>,
    /// Unit tangent dx/ds.
    pub tangent: Vector3<f64>,
    /// Curvature vector d²x/ds² (1/m).
    pub curvature: Vector3<f64>,
}

impl Geometry {
    /// The arc length (m) of the primitive (`line_length` for a line): for an arc, ∫ |p'(θ)| dθ
    /// along the helical spiral whose radius goes linearly from `radius` to its end radius while
    /// the height along `normal` goes linearly with θ — exact for circles, helices and spirals
    /// ([`spiral_length`]). The one length of an arc: the G-code reader's flow per metre, the path
    /// engine's pieces and the planners' flattening all use it.
    pub fn length(&self, line_length: f64) -> f64 {
        match *self {
            Geometry::Line { .. } => line_length,
            Geometry::Arc { radius, radius_rate, pitch, sweep, .. } => {
                spiral_length(radius, radius + radius_rate * sweep, sweep, pitch * sweep)
            }
            Geometry::Hold { .. } => 0.0,
        }
    }

    /// The point at arc length `s` (m) from the start, for a primitive of length `length`.
    pub fn point(&self, s: f64, length: f64) -> PathPoint {
        match *self {
            Geometry::Line { start, direction } => {
                PathPoint { position: start + direction * s, tangent: direction, curvature: Vector3::zeros() }
            }
            Geometry::Arc { centre, e1, e2, normal, radius, radius_rate, pitch, sweep } => {
                let k = sweep / length; // dθ/ds
                let theta = s * k;
                let (sn, cs) = (libm::sin(theta), libm::cos(theta));
                let radial = e1 * cs + e2 * sn;
                let along = e2 * cs - e1 * sn;
                let r = radius + radius_rate * theta;
                let position = centre + radial * r + normal * (pitch * theta);
                let d_theta = radial * radius_rate + along * r + normal * pitch;
                let dd_theta = along * (2.0 * radius_rate) - radial * r;
                PathPoint { position, tangent: d_theta * k, curvature: dd_theta * (k * k) }
            }
            Geometry::Hold { point } => PathPoint { position: point, tangent: Vector3::zeros(), curvature: Vector3::zeros() },
        }
    }

    /// The end point of a primitive of length `length`.
    pub fn end(&self, length: f64) -> Vector3<f64> {
        self.point(length, length).position
    }

    /// The radius of curvature that bounds the centripetal acceleration (m); infinite for lines.
    pub fn min_radius(&self) -> f64 {
        match *self {
            Geometry::Arc { radius, radius_rate, sweep, pitch, .. } => {
                let r = radius.min(radius + radius_rate * sweep).max(1e-12);
                // A helix curves less than its projection: κ = r / (r² + pitch²).
                (r * r + pitch * pitch) / r
            }
            _ => f64::INFINITY,
        }
    }
}

/// Length (m) of the spiral r(φ) = r₀ + (r₁ − r₀)·φ/θ, height h·φ/θ, φ ∈ [0, θ]: with r₀ = r₁
/// `√((r·θ)² + h²)`, otherwise the closed form of ∫ √(a + r²) dr / k (k = (r₁ − r₀)/θ,
/// a = k² + (h/θ)²), written without cancellation.
fn spiral_length(r0: f64, r1: f64, theta: f64, h: f64) -> f64 {
    let dr = r1 - r0;
    if dr == 0.0 || theta <= 0.0 {
        return libm::hypot(r0 * theta, h);
    }
    let a = (dr / theta).powi(2) + (h / theta).powi(2);
    let (s0, s1) = (libm::sqrt(a + r0 * r0), libm::sqrt(a + r1 * r1));
    // [r·√(a+r²)] from r₀ to r₁, divided by Δr.
    let algebraic = (r1 + r0) * (a + r0 * r0 + r1 * r1) / (r1 * s1 + r0 * s0);
    // [a·asinh(r/√a)] from r₀ to r₁, divided by Δr, via asinh x − asinh y = asinh(x√(1+y²) − y√(1+x²)).
    let z = dr * (r1 + r0) / (r1 * s0 + r0 * s1);
    let asinh_ratio = if z.abs() < 1e-4 { 1.0 - z * z / 6.0 } else { libm::asinh(z) / z };
    let logarithmic = a * (r1 + r0) / (r1 * s0 + r0 * s1) * asinh_ratio;
    0.5 * theta * (algebraic + logarithmic)
}

/// The distance (m) from `p` to the segment `a`–`b`.
pub fn distance_to_segment(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let ab = b - a;
    let len2 = ab.norm_squared();
    let t = if len2 > 0.0 { ((p - a).dot(&ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
    (a + ab * t - p).norm()
}

/// The distance (m) from `p` to an arc primitive: the nearest of its two ends and the points at
/// `p`'s projected angle on every turn (exact for planar arcs; for helices and spirals the point at
/// the projected angle, which is within the pitch/radius mismatch of the nearest).
pub fn distance_to_arc(p: &Vector3<f64>, geometry: &Geometry, length: f64) -> f64 {
    let Geometry::Arc { centre, e1, e2, sweep, .. } = *geometry else {
        return f64::INFINITY;
    };
    let d = p - centre;
    let (x, y) = (d.dot(&e1), d.dot(&e2));
    let mut theta = libm::atan2(y, x);
    if theta < 0.0 {
        theta += 2.0 * std::f64::consts::PI;
    }
    // Candidate angles: the projected one on every turn the arc sweeps, and the two ends.
    let mut best = (geometry.point(0.0, length).position - p).norm().min((geometry.point(length, length).position - p).norm());
    let turns = (sweep / (2.0 * std::f64::consts::PI)).ceil() as i64 + 1;
    for turn in 0..turns {
        let t = theta + 2.0 * std::f64::consts::PI * turn as f64;
        if t <= sweep {
            let s = t / sweep * length;
            best = best.min((geometry.point(s, length).position - p).norm());
        }
    }
    best
}

/// The arc from `start` that a segment describes, or None if the start lies on its axis.
pub fn arc_geometry(start: &Vector3<f64>, s: &Segment) -> Option<Geometry> {
    let n = s.normal.normalize();
    let radial0 = start - s.centre;
    let axial0 = radial0.dot(&n);
    let radial0 = radial0 - n * axial0;
    let radius = radial0.norm();
    if radius < 1e-9 {
        return None;
    }
    let e1 = radial0 / radius;
    let e2 = n.cross(&e1);
    let end_rel = s.end - s.centre;
    let end_axial = end_rel.dot(&n);
    let end_radial = end_rel - n * end_axial;
    let radius_end = end_radial.norm();
    let pitch = (end_axial - axial0) / s.sweep;
    let radius_rate = (radius_end - radius) / s.sweep;
    // The centre sits in the start's plane.
    let centre = s.centre + n * axial0;
    Some(Geometry::Arc { centre, e1, e2, normal: n, radius, radius_rate, pitch, sweep: s.sweep })
}
