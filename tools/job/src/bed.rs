//! The bed transform, the one home of where the bed is: G-code coordinates, given in the bed's own
//! frame, mapped into W, and the default tool orientation that keeps the nozzle normal to the bed.
//!
//! Two ways to say where the bed is, one transform: a full pose `[bed] frame = { xyz, rpy }` (what
//! `strand calibrate frame` measures from touched points), or, as before it, 004's inclined bed
//! (Section III-D): tilted by α about the bed's x axis and offset (Eqs. 8-9), which is the pose
//! `{ xyz = offset, rpy = [α, 0, 0] }`. The nozzle's default orientation is normal to the bed
//! either way (Eq. 10).

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use strand_core::kin::geom;
use strand_core::{BedMesh, BedMeshConfig, InvalidSetting, Segment, SegmentKind};

/// `[bed]`: where the print bed is in W: its full pose (`frame`), or an offset and a tilt about x.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BedConfig {
    /// Tilt α about the bed's x axis (rad), 004 Eq. 7-8; 0 for a flat bed. Not with `frame`.
    pub tilt: f64,
    /// Position of the bed origin in W (m). Not with `frame`.
    pub offset: [f64; 3],
    /// The bed's full pose in W (`strand calibrate frame`); replaces `tilt` and `offset`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<BedFrame>,
    /// `[bed.mesh]`: the bed's measured surface over the frame (`strand calibrate mesh`), which the
    /// path follows, faded out with height.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<BedMeshConfig>,
}

/// `[bed] frame = { xyz, rpy }`: the bed frame's pose in W.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BedFrame {
    /// The bed origin in W (m).
    pub xyz: [f64; 3],
    /// The bed's orientation in W as URDF roll, pitch, yaw (rad), fixed axes x, y, z: its z axis is
    /// the bed's normal, pointing away from the bed (towards the nozzle).
    pub rpy: [f64; 3],
}

impl BedConfig {
    /// The pose this config describes: `frame`, or `{ xyz = offset, rpy = [tilt, 0, 0] }`.
    pub fn pose(&self) -> BedFrame {
        self.frame.unwrap_or(BedFrame { xyz: self.offset, rpy: [self.tilt, 0.0, 0.0] })
    }
}

/// The map from bed coordinates (G-code) to W: `p_W = xyz + R·p_bed`, with R the frame's rotation
/// (`R(x, α)` for a tilt).
#[derive(Clone, Debug, PartialEq)]
pub struct BedTransform {
    rotation: Rotation3<f64>,
    offset: Vector3<f64>,
    tool: UnitQuaternion<f64>,
    mesh: Option<BedMesh>,
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
        let rotation = match &config.frame {
            None => geom::axis_angle(&Vector3::x(), config.tilt),
            Some(frame) => {
                if config.tilt != 0.0 || config.offset != [0.0; 3] {
                    return Err(InvalidSetting::new(
                        "bed",
                        format!(
                            "[bed] frame replaces tilt and offset: remove them (tilt = {}, offset = {:?} is the frame {{ xyz = {:?}, \
                             rpy = [{}, 0.0, 0.0] }})",
                            config.tilt, config.offset, config.offset, config.tilt
                        ),
                    ));
                }
                if !frame.xyz.iter().chain(&frame.rpy).all(|x| x.is_finite()) {
                    return Err(InvalidSetting::new("bed", "[bed] frame: xyz and rpy must be finite".to_string()));
                }
                let [r, p, y] = frame.rpy;
                geom::rpy(r, p, y)
            }
        };
        let offset = Vector3::from(config.pose().xyz);
        let flip = geom::axis_angle(&Vector3::y(), std::f64::consts::PI);
        // Eq. 10, R(y, π)·R(x, α): the nozzle (tool z) turned down, then tilted with the bed. With
        // our bed rotation R applied in W (R(x, α) for 004's tilt), the nozzle is normal to the bed
        // for R·R(y, π).
        let tool = UnitQuaternion::from_rotation_matrix(&(rotation * flip));
        let mesh = config.mesh.as_ref().map(|m| BedMesh::new(m, offset, rotation)).transpose()?;
        Ok(BedTransform { rotation, offset, tool, mesh })
    }

    /// The identity: a flat bed at the origin of W.
    pub fn flat() -> Self {
        BedTransform::new(&BedConfig::default()).expect("the flat bed is valid")
    }

    /// The bed's measured surface on this bed (`[bed.mesh]`), if the config has one: the path
    /// engine applies it ([`strand_core::PathEngine::set_bed_mesh`]); the segments stay flat.
    pub fn mesh(&self) -> Option<&BedMesh> {
        self.mesh.as_ref()
    }

    /// The default tool orientation on this bed (nozzle along the bed's inward normal).
    pub fn tool_orientation(&self) -> UnitQuaternion<f64> {
        self.tool
    }

    /// The bed frame's orientation in W (its z axis the normal).
    pub fn rotation(&self) -> Rotation3<f64> {
        self.rotation
    }

    /// The bed's unit normal in W (pointing away from the bed, towards the nozzle).
    pub fn normal(&self) -> Vector3<f64> {
        self.rotation * Vector3::z()
    }

    /// A point from bed coordinates to W (Eq. 9).
    pub fn point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.offset + self.rotation * p
    }

    /// A point from W to bed coordinates (m): Eq. 9's inverse.
    pub fn to_bed(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.inverse() * (p - self.offset)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_old_tilt_and_offset_is_the_frame_it_names() {
        let old = BedConfig { tilt: 0.3, offset: [0.45, -0.1, 0.2], frame: None, mesh: None };
        let new = BedConfig { frame: Some(BedFrame { xyz: [0.45, -0.1, 0.2], rpy: [0.3, 0.0, 0.0] }), ..BedConfig::default() };
        let (a, b) = (BedTransform::new(&old).unwrap(), BedTransform::new(&new).unwrap());
        for p in [Vector3::new(0.0, 0.0, 0.0), Vector3::new(0.1, 0.02, 0.003), Vector3::new(-0.05, 0.2, 0.0)] {
            assert!((a.point(&p) - b.point(&p)).norm() < 1e-15, "{p:?}");
        }
        assert!(a.tool_orientation().angle_to(&b.tool_orientation()) < 1e-12);
        assert!((a.normal() - b.normal()).norm() < 1e-15);
    }

    #[test]
    fn a_full_frame_maps_points_and_the_nozzle() {
        let rpy = [0.02, -0.03, 1.2];
        let cfg = BedConfig { frame: Some(BedFrame { xyz: [0.5, 0.1, 0.25], rpy }), ..BedConfig::default() };
        let bed = BedTransform::new(&cfg).unwrap();
        let r = geom::rpy(rpy[0], rpy[1], rpy[2]);
        let p = Vector3::new(0.03, 0.04, 0.0);
        assert!((bed.point(&p) - (Vector3::new(0.5, 0.1, 0.25) + r * p)).norm() < 1e-15);
        // The nozzle (tool z) points into the bed, along −normal.
        let nozzle = bed.tool_orientation() * Vector3::z();
        assert!((nozzle + bed.normal()).norm() < 1e-12, "{nozzle:?}");
        assert!((bed.normal() - r * Vector3::z()).norm() < 1e-15);
    }

    #[test]
    fn a_frame_with_a_tilt_or_offset_is_refused_naming_both() {
        let cfg = BedConfig { tilt: 0.1, offset: [0.0; 3], frame: Some(BedFrame::default()), mesh: None };
        let e = BedTransform::new(&cfg).unwrap_err();
        assert!(e.message.contains("[bed] frame replaces tilt and offset"), "{}", e.message);
        let cfg = BedConfig { frame: Some(BedFrame { xyz: [f64::NAN, 0.0, 0.0], rpy: [0.0; 3] }), ..BedConfig::default() };
        assert!(BedTransform::new(&cfg).unwrap_err().message.contains("finite"));
    }
}
