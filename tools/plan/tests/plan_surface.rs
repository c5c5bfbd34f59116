//! `strand-plan surface` as a user runs it: 003's findings on the curved rectangle in the `--json`
//! report, a segment file that reads back, a PNG, and errors that name the flag.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_strand-plan"))
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = bin().arg("surface").args(args).arg("--json").output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn curved_rectangle_reproduces_003() {
    // 003's set-up: the curved rectangle sampled by Algorithm 1 as printed at d* = 10 mm.
    let r = json(&["--shape", "curved-rect", "--sampling", "paper", "--spacing", "0.01"]);
    assert_eq!(r["shape"], "curved-rect");
    let a = &r["algorithms"];
    let get = |alg: &str, key: &str| a[alg][key].as_f64().unwrap_or_else(|| panic!("{alg}.{key} in {r}"));
    for alg in ["greedy", "weighted-u", "weighted-v", "tsp"] {
        assert_eq!(get(alg, "points"), 120.0, "{alg}");
        assert!(get(alg, "path_length_m") > 1.1 && get(alg, "path_length_m") < 1.4, "{alg}: {r}");
        assert!(get(alg, "compute_s") >= 0.0);
    }
    assert!(get("greedy", "self_intersections") > 0.0, "greedy self-intersects: {r}");
    assert_eq!(get("weighted-u", "self_intersections"), 0.0, "weighted greedy does not: {r}");
    assert_eq!(get("tsp", "self_intersections"), 0.0);
    assert!(get("tsp", "path_length_m") <= get("greedy", "path_length_m"));
    // TSP is the slowest: compared by its work, which does not depend on the machine's load.
    assert!(get("tsp", "distance_evaluations") > 3.0 * get("greedy", "distance_evaluations"), "{r}");

    // One algorithm asked for, one reported.
    let r = json(&["--shape", "bump", "--algorithm", "weighted-u"]);
    assert_eq!(r["algorithms"].as_object().unwrap().len(), 1);
    assert_eq!(r["algorithms"]["weighted-u"]["points"], 121);
    assert_eq!(r["algorithms"]["weighted-u"]["self_intersections"], 0);
}

#[test]
fn writes_a_segment_file_and_a_png() {
    let dir = strand_testkit::temp_dir("plan-surface", "output");
    let file = dir.join("blade.jsonl");
    let png = dir.join("blade.png");
    let out =
        bin().args(["surface", "--shape", "blade", "--algorithm", "tsp", "--output"]).arg(&file).arg("--png").arg(&png).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("tsp") && text.contains("wrote"), "{text}");
    let back = strand_job::segfile::read_path(&file, 0).unwrap();
    assert!(back.note.unwrap().contains("--shape blade"));
    let segs: Vec<_> = back.segments.into_iter().map(|(s, _)| s).collect();
    assert!(segs.len() > 40);
    assert!(segs[0].flags.contains(strand_core::SegmentFlags::TRAVEL));
    assert!(segs[1..].iter().all(|s| s.extrudes() && s.filament > 0.0));
    assert!(segs.last().unwrap().flags.contains(strand_core::SegmentFlags::LAST));
    // The blade is twisted: the nozzle leans, by up to the pitch angle at the hub (atan(0.2/(2π·0.03)) ≈ 47°).
    let lean = segs.iter().map(|s| (s.orientation * -nalgebra::Vector3::z()).z.acos()).fold(0.0, f64::max);
    assert!(lean > 0.5 && lean < 1.0, "{lean}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_flags_are_named() {
    for (args, needle) in [
        (vec!["--spacing=-1"], "--spacing = -1"),
        (vec!["--shape", "cylinder", "--radius", "0"], "--radius = 0"),
        (vec!["--output", "x.jsonl"], "--algorithm"),
        (vec!["--spacing", "1e-7"], "too small"),
    ] {
        let out = bin().arg("surface").args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}
