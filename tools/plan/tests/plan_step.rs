//! `strand-plan surface --step` as a user runs it: a face of a STEP model listed, planned as the
//! built-in shape is (003's curved rectangle from a file reproduces the built-in one), checked on the
//! robot in the same command, and bad input named.

use std::path::PathBuf;
use std::process::{Command, Output};

fn step(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/step").join(name).display().to_string()
}

fn plan(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strand-plan")).arg("surface").args(args).output().unwrap()
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = plan(&[args, &["--json"]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn faces_are_listed_as_one_json_array() {
    let faces = json(&["--step", &step("punched_plate.step"), "--list-faces"]);
    let faces = faces.as_array().expect("an array");
    assert_eq!(faces.len(), 8);
    let planes = faces.iter().filter(|f| f["type"] == "plane").count();
    assert_eq!((planes, faces.len() - planes), (6, 2));
    let top = &faces[7];
    assert_eq!(top["bbox_min"][2].as_f64(), Some(0.01));
    assert!((top["area_m2"].as_f64().unwrap() - (0.006 - std::f64::consts::PI * 0.015 * 0.015)).abs() < 1e-6, "{top}");
    let text = plan(&["--step", &step("punched_plate.step"), "--list-faces"]);
    let text = String::from_utf8(text.stdout).unwrap();
    assert!(text.contains("8 faces, unit 0.001 m") && text.contains("nurbs"), "{text}");
}

#[test]
fn the_curved_rectangle_from_step_reproduces_the_built_in_one() {
    let built_in = json(&["--shape", "curved-rect"]);
    let from_step = json(&["--step", &step("curved_rect.step")]);
    assert_eq!(from_step["step"]["type"], "nurbs");
    let (a, b) = (built_in["samples"].as_f64().unwrap(), from_step["samples"].as_f64().unwrap());
    assert!((a - b).abs() <= 0.01 * a, "samples: built-in {a}, STEP {b}");
    for alg in ["weighted-u", "weighted-v", "tsp"] {
        let length = |r: &serde_json::Value| r["algorithms"][alg]["path_length_m"].as_f64().unwrap();
        let (a, b) = (length(&built_in), length(&from_step));
        assert!((a - b).abs() <= 0.01 * a, "{alg}: built-in {a} m, STEP {b} m");
    }
}

#[test]
fn weighted_greedy_never_crosses_itself_where_greedy_does() {
    // 003 Figs. 5-8: greedy jumps and crosses its own bead; weighted greedy keeps to rows.
    let mut greedy_crossed = 0;
    for (file, spacing) in [("curved_rect.step", "0.01"), ("nurbs_saddle.step", "0.008"), ("bump_with_hole.step", "0.006")] {
        let r = json(&["--step", &step(file), "--spacing", spacing]);
        let crossings = |alg: &str| r["algorithms"][alg]["proper_crossings"].as_u64().unwrap();
        greedy_crossed += crossings("greedy");
        assert_eq!((crossings("weighted-u"), crossings("weighted-v")), (0, 0), "{file}: {r}");
        if crossings("greedy") > 0 {
            assert!(r["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("greedy path crosses itself")), "{r}");
        }
    }
    assert!(greedy_crossed > 0, "greedy crossed itself somewhere");
}

#[test]
fn a_path_is_checked_on_the_robot_before_it_runs() {
    let dir = strand_testkit::temp_dir("plan-step", "check");
    let out = dir.join("top.jsonl");
    // The plate's top face, centred on the bed, two layers: the iiwa7 reaches it.
    let ok = plan(&[
        "--step",
        &step("punched_plate.step"),
        "--face",
        "7",
        "--place",
        "centre",
        "--layers",
        "2",
        "--spacing",
        "0.02",
        "--algorithm",
        "weighted-u",
        "-o",
        out.to_str().unwrap(),
        "--check",
        "--config",
        "iiwa7",
    ]);
    let text = String::from_utf8_lossy(&ok.stdout);
    assert!(ok.status.success(), "{text}\n{}", String::from_utf8_lossy(&ok.stderr));
    assert!(text.contains("check-job:") && text.contains("CLEAN"), "{text}");
    let header = file_note(&out);
    assert!(header.contains("placement centre") && header.contains("offset [-0.050000, -0.030000, -0.010000] m"), "{header}");
    // Two layers: the second 0.2 mm further out, starting right above where the first ended.
    let file = strand_job::segfile::read_path(&out, 0).unwrap();
    let segs: Vec<strand_core::Segment> = file.segments.iter().map(|(s, _)| *s).collect();
    let starts: Vec<usize> = (0..segs.len()).filter(|&k| segs[k].flags.contains(strand_core::SegmentFlags::LAYER_START)).collect();
    assert_eq!(starts.len(), 2, "{starts:?}");
    let (end, start) = (segs[starts[1] - 1].end, segs[starts[1]].end);
    assert!((start - end - nalgebra::Vector3::new(0.0, 0.0, 0.2e-3)).norm() < 1e-12, "{end:?} → {start:?}");
    // The B-spline face is beyond the iiwa7's elbow: refused with the report, exit 3 as check-job.
    let refused = plan(&[
        "--step",
        &step("bump_with_hole.step"),
        "--place",
        "centre",
        "--spacing",
        "0.02",
        "--algorithm",
        "weighted-u",
        "-o",
        out.to_str().unwrap(),
        "--check",
        "--config",
        "iiwa7",
    ]);
    let (text, err) = (String::from_utf8_lossy(&refused.stdout), String::from_utf8_lossy(&refused.stderr));
    assert_eq!(refused.status.code(), Some(3), "{text}\n{err}");
    assert!(text.contains("FAILS") && text.contains("position limit") && err.contains("refused the path"), "{text}\n{err}");
}

fn file_note(path: &std::path::Path) -> String {
    strand_job::segfile::read_path(path, 0).unwrap().note.unwrap_or_default()
}

#[test]
fn bad_models_and_choices_are_named() {
    let dir = strand_testkit::temp_dir("plan-step", "bad");
    let err = |args: &[&str]| {
        let out = plan(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", String::from_utf8_lossy(&out.stdout));
        String::from_utf8(out.stderr).unwrap()
    };
    let e = err(&["--step", &step("punched_plate.step")]);
    assert!(e.contains("8 faces") && e.contains("--face N"), "{e}");
    let e = err(&["--step", &step("punched_plate.step"), "--face-name", "lid"]);
    assert!(e.contains("no face is named \"lid\""), "{e}");
    let bad = dir.join("bad.step");
    let good = std::fs::read_to_string(step("bump_with_hole.step")).unwrap();
    std::fs::write(&bad, good.replacen("B_SPLINE_SURFACE_WITH_KNOTS", "FOO_SURFACE", 1)).unwrap();
    let e = err(&["--step", bad.to_str().unwrap()]);
    assert!(e.contains("bad.step: entity #47 (FOO_SURFACE)"), "{e}");
    std::fs::write(&bad, &good[..good.len() / 3]).unwrap();
    let e = err(&["--step", bad.to_str().unwrap(), "--list-faces"]);
    assert!(e.contains("bad.step: not a readable STEP file"), "{e}");
    let e = err(&["--list-faces"]);
    assert!(e.contains("--step FILE"), "{e}");
    let e = err(&["--step", &step("curved_rect.step"), "--check"]);
    assert!(e.contains("--output"), "{e}");
}

#[test]
fn the_bead_never_leaves_the_face_holes_are_crossed_by_lifted_travels() {
    let dir = strand_testkit::temp_dir("plan-step", "holes");
    let out = dir.join("top.jsonl");
    for alg in ["greedy", "weighted-u", "weighted-v", "tsp"] {
        let run = plan(&[
            "--step",
            &step("punched_plate.step"),
            "--face",
            "7",
            "--spacing",
            "0.005",
            "--algorithm",
            alg,
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let segs: Vec<strand_core::Segment> =
            strand_job::segfile::read_path(&out, 0).unwrap().segments.into_iter().map(|(s, _)| s).collect();
        let mut lifted = 0;
        for w in segs.windows(2) {
            let (a, b) = (w[0].end, w[1].end);
            if w[1].flags.contains(strand_core::SegmentFlags::EXTRUDE) {
                // Every bead on the top (z = 10 mm + 0.2 mm), no point of it over the hole.
                for t in [0.0, 0.25, 0.5, 0.75, 1.0] {
                    let p = a + t * (b - a);
                    let r = ((p.x - 0.05).powi(2) + (p.y - 0.03).powi(2)).sqrt();
                    assert!(r >= 0.015 - 1e-6 && (p.z - 0.0102).abs() < 1e-12, "{alg}: bead at {p:?}, {r} m from the hole's axis");
                }
            } else if b.z > 0.0102 + 1e-3 {
                lifted += 1;
            }
        }
        let stdout = String::from_utf8_lossy(&run.stdout);
        if alg.starts_with("weighted") {
            assert!(lifted > 0 && stdout.contains("would leave the face"), "{alg}: rows cross the hole: {stdout}");
        }
    }
}

#[test]
fn a_face_that_closes_on_itself_is_planned_across_its_seam() {
    // OpenCascade's cylinder (r 20 mm): its side is one periodic face with a seam edge. A step across
    // the seam is 5 mm in space, not a jump over the whole (u, v) plane: nothing crosses, nothing is
    // lifted, and no ring of samples lands on the first one again.
    let r = json(&["--step", &step("occt_cylinder.step"), "--face", "0", "--spacing", "0.005"]);
    for alg in ["greedy", "weighted-u", "weighted-v", "tsp"] {
        assert_eq!(r["algorithms"][alg]["self_intersections"], 0, "{alg}: {r}");
    }
    assert_eq!(r["warnings"].as_array().unwrap().len(), 0, "{r}");
    let dir = strand_testkit::temp_dir("plan-step", "seam");
    let out = dir.join("side.jsonl");
    let run = plan(&[
        "--step",
        &step("occt_cylinder.step"),
        "--face",
        "0",
        "--spacing",
        "0.005",
        "--algorithm",
        "greedy",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(run.status.success());
    let segs: Vec<strand_core::Segment> = strand_job::segfile::read_path(&out, 0).unwrap().segments.into_iter().map(|(s, _)| s).collect();
    let mut angles: Vec<f64> = segs.iter().map(|s| s.end.y.atan2(s.end.x).rem_euclid(std::f64::consts::TAU)).collect();
    angles.sort_by(f64::total_cmp);
    angles.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
    let gaps: Vec<f64> =
        angles.windows(2).map(|w| w[1] - w[0]).chain([angles[0] + std::f64::consts::TAU - angles[angles.len() - 1]]).collect();
    // Arc between rings at the bead's radius (20.2 mm): between half and one and a half spacings.
    for g in &gaps {
        assert!(*g * 0.0202 > 0.0025 && *g * 0.0202 < 0.0075, "rings {:.2} mm apart: {gaps:?}", g * 20.2);
    }
    assert!(
        segs.iter()
            .skip(1)
            .all(|s| s.flags.contains(strand_core::SegmentFlags::EXTRUDE) || s.flags.contains(strand_core::SegmentFlags::LAST)),
        "no travels on a whole cylinder"
    );
}
