//! The bed transform for printing on inclined planes (004 Section III-D): G-code coordinates, given
//! in the bed's own frame, are tilted by α about the bed's x axis and offset (Eqs. 8-9), and the
//! default tool orientation keeps the nozzle normal to the tilted bed (Eq. 10).

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use strand_core::kin::geom;
use strand_core::{InvalidSetting, Segment, SegmentKind};

/// `[bed]`: where the print bed is in W and how far it is tilted.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BedConfig {
    /// Tilt α about the bed's x axis (rad), 004 Eq. 7-8; 0 for a flat bed.
    pub tilt: f64,
    /// Position of the bed origin in W (m).
    pub offset: [f64; 3],
}

/// The map from bed coordinates (G-code) to W: `p_W = offset + R(x, α)·p_bed`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BedTransform {
    rotation: Rotation3<f64>,
    offset: Vector3<f64>,
    tool: UnitQuaternion<f64>,
}

impl BedTransform {
    /// The transform for a bed config; errors name the key.
    pub fn new(config: &BedConfig) -> Result<Self, InvalidSetting> {
        if !(config.tilt.is_finite() && config.tilt.abs() < std::f64::consts::FRAC_PI_2) {
            return Err(InvalidSetting::new("bed", "[bed] tilt: must be finite and below 90° (π/2 rad) in magnitude".to_string()));
        }
        if !config.offset.iter().all(|x| x.is_finite()) {
            return Err(InvalidSetting::new("bed", "[bed] offset: must be finite".to_string()));
        }
        let rotation = geom::axis_angle(&Vector3::x(), config.tilt);
        let flip = geom::axis_angle(&Vector3::y(), std::f64::consts::PI);
        // Eq. 10, R(y, π)·R(x, α): the nozzle (tool z) turned down, then tilted with the bed. With
        // our bed tilt R(x, α) applied in W, the nozzle is normal to the bed for R(x, α)·R(y, π).
        let tool = UnitQuaternion::from_rotation_matrix(&(rotation * flip));
        Ok(BedTransform { rotation, offset: Vector3::from(config.offset), tool })
    }

    /// The identity: a flat bed at the origin of W.
    pub fn flat() -> Self {
        BedTransform::new(&BedConfig::default()).expect("the flat bed is valid")
    }

    /// The default tool orientation on this bed (nozzle along the bed's inward normal).
    pub fn tool_orientation(&self) -> UnitQuaternion<f64> {
        self.tool
    }

    /// The bed's unit normal in W (pointing away from the bed, towards the nozzle).
    pub fn normal(&self) -> Vector3<f64> {
        self.rotation * Vector3::z()
    }

    /// A point from bed coordinates to W (Eq. 9).
    pub fn point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.offset + self.rotation * p
    }

    /// A segment from bed coordinates to W. Orientations given in bed coordinates are rotated with
    /// the bed, so the flat-bed default (nozzle down) becomes Eq. 10's orientation.
    pub fn segment(&self, s: &Segment) -> Segment {
        let mut out = *s;
        out.end = self.point(&s.end);
        if s.kind == SegmentKind::Arc {
            out.centre = self.point(&s.centre);
            out.normal = self.rotation * s.normal;
        }
        out.orientation = UnitQuaternion::from_rotation_matrix(&self.rotation) * s.orientation;
        out
    }
}
