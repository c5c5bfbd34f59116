//! strand-cad on STEP files: our own test models (written by truck, `strand_cad::models`) and models
//! another CAD kernel wrote (OpenCascade, `tools/cad/occt/make_models.py`, with OpenCascade's own
//! figures beside them); and on broken files, which must give an error naming the entity, never a panic.

use std::path::{Path, PathBuf};

use strand_cad::{CadError, Model, SurfaceType, models, parse_step, read_step};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/step").join(name)
}

fn model(name: &str) -> Model {
    read_step(&data(name)).unwrap_or_else(|e| panic!("{e}"))
}

fn text(name: &str) -> String {
    std::fs::read_to_string(data(name)).unwrap()
}

#[test]
fn the_committed_models_are_what_the_generator_writes() {
    for (name, written) in models::all() {
        assert_eq!(text(name), written, "tests/data/step/{name} is stale: cargo run -p strand-cad --example make_step_models");
    }
}

#[test]
fn faces_are_listed_with_their_type_area_and_box() {
    let pi = std::f64::consts::PI;
    // 003's curved rectangle: 100 mm × (50 mm · 2π/3) of arc.
    let m = model("curved_rect.step");
    assert_eq!((m.metres_per_unit, m.unit_named, m.faces.len()), (1e-3, true, 1));
    let f = &m.faces[0];
    assert_eq!(f.kind, SurfaceType::Nurbs);
    assert!((f.area_m2 - 0.1 * 0.05 * 2.0 * pi / 3.0).abs() < 1e-9, "{}", f.area_m2);
    let (lo, hi) = f.bbox;
    let want_hi = [0.1, 0.05, 0.075];
    for a in 0..3 {
        assert!(lo[a].abs() < 1e-9 && (hi[a] - want_hi[a]).abs() < 1e-6, "{:?}", f.bbox);
    }
    // The B-spline face with a hole: OpenCascade's area of this file is 5342.773 mm².
    let m = model("bump_with_hole.step");
    assert_eq!((m.faces[0].kind, m.faces[0].loops().len()), (SurfaceType::BSpline, 2));
    assert!((m.faces[0].area_m2 * 1e6 - 5342.773).abs() < 0.01, "{}", m.faces[0].area_m2 * 1e6);
    // The NURBS saddle: one rational face, ±6.67 mm (the weighted control net pulls it in).
    let m = model("nurbs_saddle.step");
    assert_eq!(m.faces[0].kind, SurfaceType::Nurbs);
    assert!((m.faces[0].bbox.1[2] - 0.02 / 3.0).abs() < 1e-6, "{:?}", m.faces[0].bbox);
    // The punched plate: six planes and the hole's wall in two halves.
    let m = model("punched_plate.step");
    let kinds: Vec<SurfaceType> = m.faces.iter().map(|f| f.kind).collect();
    assert_eq!(kinds.iter().filter(|k| **k == SurfaceType::Plane).count(), 6, "{kinds:?}");
    assert_eq!(kinds.iter().filter(|k| **k == SurfaceType::Nurbs).count(), 2, "{kinds:?}");
    let holed: Vec<_> = m.faces.iter().filter(|f| f.loops().len() == 2).collect();
    assert_eq!(holed.len(), 2, "top and bottom carry the hole");
    for f in holed {
        // 6000 − π·15² mm², plus the slivers between the circle and its 1 µm chords.
        let exact = 6000.0 - pi * 225.0;
        assert!((f.area_m2 * 1e6 - exact).abs() < 0.5, "{} mm² against {exact}", f.area_m2 * 1e6);
    }
    let wall: f64 = m.faces.iter().filter(|f| f.kind == SurfaceType::Nurbs).map(|f| f.area_m2).sum();
    assert!((wall * 1e6 - pi * 30.0 * 10.0).abs() < 0.01, "{}", wall * 1e6);
}

#[test]
fn a_solids_faces_point_out_of_it() {
    let m = model("punched_plate.step");
    for f in &m.faces {
        let [(u0, u1), (v0, v1)] = f.domain();
        // A point of the face and a step along its normal: outside the plate's material.
        let (u, v) = (0..50)
            .flat_map(|i| (0..50).map(move |j| (u0 + (u1 - u0) * (i as f64 + 0.5) / 50.0, v0 + (v1 - v0) * (j as f64 + 0.5) / 50.0)))
            .find(|&(u, v)| f.contains(u, v))
            .expect("a point on the face");
        let out = f.point(u, v) + 1e-3 * f.normal(u, v);
        let in_plate = |p: nalgebra::Vector3<f64>| {
            let hole = ((p.x - 0.05).powi(2) + (p.y - 0.03).powi(2)).sqrt() < 0.015;
            (0.0..=0.1).contains(&p.x) && (0.0..=0.06).contains(&p.y) && (0.0..=0.01).contains(&p.z) && !hole
        };
        assert!(
            !in_plate(out),
            "face {} ({:?}): normal {:?} at {:?} points into the plate",
            f.index,
            f.kind,
            f.normal(u, v),
            f.point(u, v)
        );
        assert!(in_plate(f.point(u, v) - 1e-3 * f.normal(u, v)), "face {}: inward is inside", f.index);
    }
}

#[test]
fn the_trim_keeps_holes_out_and_the_face_in() {
    // The B-spline face's hole is exactly a rectangle in (u, v).
    let m = model("bump_with_hole.step");
    let f = &m.faces[0];
    let [(ua, ub), (va, vb)] = models::HOLE_UV;
    let n = 200;
    for i in 0..n {
        for j in 0..n {
            let (u, v) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
            let in_hole = u > ua && u < ub && v > va && v < vb;
            let near_edge = [(u - ua).abs(), (u - ub).abs(), (v - va).abs(), (v - vb).abs()].iter().any(|d| *d < 1e-6);
            if !near_edge {
                assert_eq!(f.contains(u, v), !in_hole, "({u}, {v})");
            }
        }
    }
    // The plate's circular hole, judged in space: no point on the top face within the circle.
    let m = model("punched_plate.step");
    let top = m.faces.iter().find(|f| f.bbox.0[2] > 0.009 && f.kind == SurfaceType::Plane).unwrap();
    let [(u0, u1), (v0, v1)] = top.domain();
    let (mut inside, mut outside) = (0, 0);
    for i in 0..300 {
        for j in 0..300 {
            let (u, v) = (u0 + (u1 - u0) * (i as f64 + 0.5) / 300.0, v0 + (v1 - v0) * (j as f64 + 0.5) / 300.0);
            let p = top.point(u, v);
            let r = ((p.x - 0.05).powi(2) + (p.y - 0.03).powi(2)).sqrt();
            if top.contains(u, v) {
                // The trim's chords lie within 1 µm inside the circle.
                assert!(r > 0.015 - 1.1e-6, "({u}, {v}) → r = {r} m is in the hole");
                inside += 1;
            } else if r > 0.015 + 1e-6 {
                panic!("({u}, {v}) → r = {r} m is on the plate but refused");
            } else {
                outside += 1;
            }
        }
    }
    assert!(inside > 70_000 && outside > 8_000, "{inside} {outside}");
}

#[test]
fn models_another_kernel_wrote_read_as_it_reads_them() {
    for name in ["occt_cylinder", "occt_rounded_box", "occt_cone_inch"] {
        let m = model(&format!("{name}.step"));
        let occt: serde_json::Value = serde_json::from_str(&text(&format!("{name}.faces.json"))).unwrap();
        let occt = occt.as_array().unwrap();
        assert_eq!(m.faces.len(), occt.len(), "{name}: face count");
        for (f, o) in m.faces.iter().zip(occt) {
            let s = serde_json::to_value(f.summary()).unwrap();
            assert_eq!(s["type"], o["type"], "{name} face {}", f.index);
            let (a, b) = (f.area_m2, o["area_m2"].as_f64().unwrap());
            assert!((a - b).abs() <= 2e-4 * b, "{name} face {} ({}): area {a} m² against OpenCascade's {b}", f.index, s["type"]);
            for (k, corner) in [(0, "bbox_min"), (1, "bbox_max")] {
                for axis in 0..3 {
                    let (mine, theirs) = ([f.bbox.0, f.bbox.1][k][axis], o[corner][axis].as_f64().unwrap());
                    // OpenCascade's optimal box is padded by its tolerance (1e-7 m).
                    assert!((mine - theirs).abs() < 2e-5, "{name} face {}: {corner}[{axis}] {mine} against {theirs}", f.index);
                }
            }
        }
    }
    // The cone was written in inches: read back in metres.
    let m = model("occt_cone_inch.step");
    assert!((m.metres_per_unit - 0.0254).abs() < 1e-12 && m.unit_named);
    assert!(m.faces.iter().any(|f| (f.bbox.1[2] - 0.0508).abs() < 1e-6));
}

#[test]
fn faces_are_found_by_index_and_by_name() {
    let named = text("punched_plate.step").replacen("FACE_SURFACE('', ", "FACE_SURFACE('bottom', ", 1);
    let m = parse_step(&named, "named.step").unwrap();
    assert_eq!(m.face_named("bottom").unwrap().index, 0);
    let e = m.face_named("top").unwrap_err().to_string();
    assert!(e.contains("named.step") && e.contains("\"top\"") && e.contains("bottom"), "{e}");
    let e = m.face(8).unwrap_err().to_string();
    assert!(e.contains("no face 8") && e.contains("0 to 7"), "{e}");
}

/// Reads broken text; it must not panic, and must fail.
#[track_caller]
fn broken(text: &str) -> String {
    match std::panic::catch_unwind(|| parse_step(text, "broken.step")) {
        Ok(Ok(m)) => panic!("read {} faces from a broken file", m.faces.len()),
        Ok(Err(e)) => e.to_string(),
        Err(_) => panic!("panicked"),
    }
}

#[test]
fn broken_and_unsupported_files_are_named_errors_never_panics() {
    let good = text("bump_with_hole.step");
    for (what, t) in [
        ("garbage", "hello, not STEP".to_string()),
        ("empty", String::new()),
        ("cut in half", good[..good.len() / 2].to_string()),
        ("no trailer", good[..good.find("ENDSEC;\nEND-ISO").unwrap()].to_string()),
    ] {
        let e = broken(&t);
        assert!(e.starts_with("broken.step: not a readable STEP file"), "{what}: {e}");
    }
    let e = broken(
        "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION((''),'2;1');\nFILE_NAME('','',(''),(''),'','','');\nFILE_SCHEMA(('X'));\nENDSEC;\nEND-ISO-10303-21;\n",
    );
    assert!(e.contains("no DATA section"), "{e}");
    // An unknown surface type is named with its instance number.
    let e = broken(&good.replacen("B_SPLINE_SURFACE_WITH_KNOTS", "FOO_SURFACE", 1));
    assert!(e.contains("#47 (FOO_SURFACE)") && e.contains("face #18"), "{e}");
    // Knot multiplicities that do not fit the control net (truck panics on them).
    let e = broken(&good.replacen("(4, 4), (4, 4), (0.0, 1.0), (0.0, 1.0)", "(4, 4), (2, 2), (0.0, 1.0), (0.0, 1.0)", 1));
    assert!(e.contains("#47 (B_SPLINE_SURFACE_WITH_KNOTS)") || e.contains("#18"), "{e}");
    // An edge curve of an unknown type: the face's loop cannot close.
    let e = broken(&good.replacen("B_SPLINE_CURVE_WITH_KNOTS", "FOO_CURVE", 1));
    assert!(e.contains("#18 (FACE_SURFACE)") && e.contains("boundary loop"), "{e}");
    // A control point of the surface with a boolean for a coordinate.
    let at = good.find("#48 = CARTESIAN_POINT('', (").unwrap() + "#48 = CARTESIAN_POINT('', (".len();
    let end = at + good[at..].find(')').unwrap();
    let mut two = good.clone();
    let coords: Vec<String> = good[at..end].split(", ").map(str::to_string).collect();
    two.replace_range(at..end, &format!("{}, .T., {}", coords[0], coords[2]));
    let e = broken(&two);
    assert!(e.contains("broken.step: entity #47 (B_SPLINE_SURFACE_WITH_KNOTS)"), "{e}");
    // A dangling reference to the surface.
    let e = broken(&good.replacen("#18 = FACE_SURFACE('', (#19, #25), #47, .T.);", "#18 = FACE_SURFACE('', (#19, #25), #9999, .T.);", 1));
    assert!(e.contains("#9999 (missing)"), "{e}");
    // No shell at all.
    let start = good.find("DATA;").unwrap() + "DATA;".len();
    let e = broken(&format!("{}\n#1 = CARTESIAN_POINT('', (0.0, 0.0, 0.0));\nENDSEC;\nEND-ISO-10303-21;\n", &good[..start]));
    assert!(e.contains("no shell"), "{e}");
    // A missing file.
    let e = read_step(Path::new("/nonexistent/part.step")).unwrap_err();
    assert!(matches!(e, CadError::Io { .. }) && e.to_string().starts_with("/nonexistent/part.step"), "{e}");
}

#[test]
fn a_zero_direction_is_refused_not_looped_on() {
    // DIRECTION(0, 0, 0) gives NaN geometry; a mesher would allocate until the process aborts.
    let m = text("punched_plate.step");
    let at = m.find("DIRECTION('', (0.0, 0.0, 1.0))").expect("a z direction");
    let mut bad = m.clone();
    bad.replace_range(at..at + "DIRECTION('', (0.0, 0.0, 1.0))".len(), "DIRECTION('', (0.0, 0.0, 0.0))");
    let _ = std::panic::catch_unwind(|| parse_step(&bad, "zero.step")).expect("no panic");
}
