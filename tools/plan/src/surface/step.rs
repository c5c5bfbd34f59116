//! A face of the user's STEP model as a [`Surface`] (`strand-plan surface --step FILE --face N`): the
//! face as `strand_cad` reads it (S(u, v) in metres, the outward normal, the trim as `contains`), placed
//! where the job should be, and `--list-faces`. The rest of the pipeline sees only the trait, so 003's
//! sampling, the three orderings, the (u, v) self-intersection test and the segment writer run on a CAD
//! face exactly as on the built-in shapes.

use nalgebra::Vector3;
use strand_cad::{FaceSummary, Model, StepFace};

use super::shapes::{Domain, Surface};
use strand_cli::error::{Result, ToolError};

/// Where the face's points go in the segment file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Placement {
    /// The model's own frame (m): the part sits on the bed where the CAD put it relative to its origin.
    #[default]
    Model,
    /// Moved so the face's bounding box starts at the bed origin: (x, y, z)_min → (0, 0, 0).
    Origin,
    /// Moved so the face's bounding box is centred on the bed origin in x and y, its lowest point at z = 0.
    Centre,
}

impl Placement {
    /// The translation (m) this placement applies to a face with bounding box `bbox`.
    pub fn offset(self, bbox: &([f64; 3], [f64; 3])) -> Vector3<f64> {
        let (lo, hi) = bbox;
        match self {
            Placement::Model => Vector3::zeros(),
            Placement::Origin => -Vector3::new(lo[0], lo[1], lo[2]),
            Placement::Centre => -Vector3::new(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]),
        }
    }

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Placement::Model => "model",
            Placement::Origin => "origin",
            Placement::Centre => "centre",
        }
    }
}

/// A STEP face, placed and oriented for printing.
pub struct StepSurface {
    face: StepFace,
    /// +1, or −1 with `--flip-normal` (print the face from its other side).
    side: f64,
    /// Placement translation (m).
    pub offset: Vector3<f64>,
}

impl StepSurface {
    /// Face `face` of `model` (or the one named `face_name`), placed; errors name the file and face.
    pub fn new(model: &Model, face: Option<usize>, face_name: Option<&str>, flip: bool, placement: Placement) -> Result<StepSurface> {
        let chosen = match (face, face_name) {
            (Some(_), Some(_)) => return Err(ToolError::Usage("--face and --face-name choose the same thing: give one".to_string())),
            (Some(n), None) => model.face(n).map_err(cad)?,
            (None, Some(name)) => model.face_named(name).map_err(cad)?,
            (None, None) if model.faces.len() == 1 => &model.faces[0],
            (None, None) => {
                return Err(ToolError::Usage(format!(
                    "{}: the model has {} faces: choose one with --face N or --face-name NAME (--list-faces shows them)",
                    model.file,
                    model.faces.len()
                )));
            }
        };
        Ok(StepSurface { offset: placement.offset(&chosen.bbox), face: chosen.clone(), side: if flip { -1.0 } else { 1.0 } })
    }

    /// The face.
    pub fn face(&self) -> &StepFace {
        &self.face
    }
}

impl Surface for StepSurface {
    fn domain(&self) -> Domain {
        let [u, v] = self.face.domain();
        Domain { u, v }
    }
    fn point(&self, u: f64, v: f64) -> Vector3<f64> {
        self.face.point(u, v) + self.offset
    }
    fn normal(&self, u: f64, v: f64) -> Vector3<f64> {
        self.face.normal(u, v) * self.side
    }
    fn contains(&self, u: f64, v: f64) -> bool {
        self.face.contains(u, v)
    }
    fn parameter_labels(&self) -> (&'static str, &'static str) {
        ("u (the face's own parameter)", "v (the face's own parameter)")
    }
    fn periods(&self) -> [Option<f64>; 2] {
        self.face.periods()
    }
}

/// A strand-cad error as the planner reports it.
pub(super) fn cad(e: strand_cad::CadError) -> ToolError {
    ToolError::Content(e.to_string())
}

/// `--list-faces`: one line per face, or with `json` one JSON array of [`FaceSummary`] objects.
pub fn list_faces(model: &Model, json: bool) -> String {
    let faces: Vec<FaceSummary> = model.faces.iter().map(StepFace::summary).collect();
    if json {
        return serde_json::to_string(&faces).expect("a face list serialises");
    }
    let mut out = format!(
        "{}: {} faces, unit {} m{}\n  {:>5} {:>7} {:<11} {:>11} {:>5}  {:<24} {:<24} name\n",
        model.file,
        model.faces.len(),
        model.metres_per_unit,
        if model.unit_named { "" } else { " (assumed: the file names no length unit)" },
        "index",
        "entity",
        "type",
        "area (mm²)",
        "loops",
        "bbox min (mm)",
        "bbox max (mm)"
    );
    for f in &faces {
        let mm = |p: [f64; 3]| format!("{:.1}, {:.1}, {:.1}", p[0] * 1e3, p[1] * 1e3, p[2] * 1e3);
        out += &format!(
            "  {:>5} {:>7} {:<11} {:>11.2} {:>5}  {:<24} {:<24} {}\n",
            f.index,
            format!("#{}", f.entity),
            f.kind.name(),
            f.area_m2 * 1e6,
            f.loops,
            mm(f.bbox_min),
            mm(f.bbox_max),
            f.name
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::{Sampling, SamplingMode, sample};

    fn model(name: &str) -> Model {
        strand_cad::read_step(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/step").join(name)).unwrap()
    }

    fn at(spacing: f64) -> Sampling {
        Sampling { spacing_u: spacing, spacing_v: spacing, tolerance: 0.01, mode: SamplingMode::Robust }
    }

    #[test]
    fn samples_lie_on_the_face_inside_its_trim() {
        // The curved rectangle: every sample on the cylinder y² + (z − R)² = R² (R = 50 mm), within 1 µm.
        let s = StepSurface::new(&model("curved_rect.step"), None, None, false, Placement::Model).unwrap();
        let cloud = sample(&s, &at(0.005)).unwrap();
        assert!(cloud.samples.len() > 400);
        for p in &cloud.samples {
            let r = (p.point.y.powi(2) + (p.point.z - 0.05).powi(2)).sqrt();
            assert!(
                (r - 0.05).abs() <= 1e-6 && (-1e-9..=0.1 + 1e-9).contains(&p.point.x),
                "{:?} is off the face by {} m",
                p.point,
                r - 0.05
            );
            // The normal points at the bend's axis, as the built-in shape's.
            let towards_axis = (nalgebra::Vector3::new(p.point.x, 0.0, 0.05) - p.point).normalize();
            assert!((p.normal - towards_axis).norm() < 1e-6, "{:?}", p.normal);
        }
        // The plate's top: on z = 10 mm, never in the hole (r 15 mm about (50, 30) mm), placed at the
        // origin it starts at (0, 0, 0).
        let m = model("punched_plate.step");
        let s = StepSurface::new(&m, Some(7), None, false, Placement::Origin).unwrap();
        let cloud = sample(&s, &at(0.002)).unwrap();
        assert!(cloud.samples.len() > 1200, "{}", cloud.samples.len());
        for p in &cloud.samples {
            let hole = ((p.point.x - 0.05).powi(2) + (p.point.y - 0.03).powi(2)).sqrt();
            assert!(p.point.z.abs() <= 1e-12 && hole >= 0.015 - 1e-6, "{:?}: {hole} m from the hole's axis", p.point);
            assert!(s.contains(p.u, p.v));
        }
        // The B-spline face: no sample in its (u, v) hole.
        let s = StepSurface::new(&model("bump_with_hole.step"), None, None, true, Placement::Model).unwrap();
        let [(ua, ub), (va, vb)] = strand_cad::models::HOLE_UV;
        let cloud = sample(&s, &at(0.002)).unwrap();
        assert!(cloud.samples.iter().all(|p| !(p.u > ua + 1e-9 && p.u < ub - 1e-9 && p.v > va + 1e-9 && p.v < vb - 1e-9)));
        // --flip-normal turns the nozzle's side over.
        assert!(cloud.samples.iter().all(|p| p.normal.z < 0.0));
    }

    #[test]
    fn a_face_is_chosen_by_index_or_name_or_alone() {
        let m = model("punched_plate.step");
        let e = StepSurface::new(&m, None, None, false, Placement::Model).err().unwrap().to_string();
        assert!(e.contains("8 faces") && e.contains("--face N"), "{e}");
        let e = StepSurface::new(&m, Some(1), Some("x"), false, Placement::Model).err().unwrap().to_string();
        assert!(e.contains("--face and --face-name"), "{e}");
        let e = StepSurface::new(&m, Some(12), None, false, Placement::Model).err().unwrap().to_string();
        assert!(e.contains("no face 12"), "{e}");
        // Centred: the face's box about the bed origin, its lowest point at z = 0.
        let s = StepSurface::new(&m, Some(7), None, false, Placement::Centre).unwrap();
        assert!((s.offset - nalgebra::Vector3::new(-0.05, -0.03, -0.01)).norm() < 1e-12, "{:?}", s.offset);
        let listing = list_faces(&m, false);
        assert_eq!(listing.lines().count(), 2 + 8, "{listing}");
        let json: serde_json::Value = serde_json::from_str(&list_faces(&m, true)).unwrap();
        let faces = json.as_array().unwrap();
        assert_eq!(faces.len(), 8);
        for (k, f) in faces.iter().enumerate() {
            assert_eq!(f["index"], k);
            for key in ["type", "area_m2", "bbox_min", "bbox_max"] {
                assert!(!f[key].is_null(), "{key} in {f}");
            }
        }
    }
}
