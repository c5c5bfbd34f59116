//! strand-plan's planners as a user runs them: `base` on 000's 100 cm truss (Algorithm 1's cut-off,
//! the reach at which 000's arm runs out), `finish` and `tilt` writing segment files that read back,
//! and bad input refused with the flag named.

use std::process::{Command, Output};
use strand_testkit::{root, temp_dir};

use strand_job::segfile::read_path;

fn plan(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strand-plan")).args(args).current_dir(root()).output().unwrap()
}

fn json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn base_finds_the_cut_off_on_the_100_cm_truss() {
    let truss = "tests/data/gcode/truss/truss_1000mm.gcode";
    // 000's values: r_nom 230 mm, reach limit 270 mm, 60 ms samples; constant speed (fast in debug).
    let v = json(&plan(&["base", truss, "--timing", "constant", "--json"]));
    for k in ["fc_hz", "r_max_m", "a_max_mps2", "a_mean_mps2", "base_distance_m", "w_ff_j"] {
        assert!(v[k].as_f64().is_some_and(|x| x.is_finite() && x > 0.0), "{k}: {}", v[k]);
    }
    let fc = v["fc_hz"].as_f64().unwrap();
    // Our truss (5 passes along x, 33 min) needs 5.3 mHz where 000's (50 min) found 2.5 mHz.
    assert!((fc - 5.3e-3).abs() < 1e-9, "f_c {fc}");
    let r_max = v["r_max_m"].as_f64().unwrap();
    assert!(r_max > 0.26 && r_max <= 0.27, "r_max {r_max}");
    // The base stays far below the free flyer's 0.5 mm/s² (000's chosen limit).
    assert!(v["a_max_mps2"].as_f64().unwrap() < 0.5e-3);
    // The reach passes 370 mm (000's arm's physical limit) only at a lower cut-off.
    let v370 = json(&plan(&["base", truss, "--timing", "constant", "--json", "--reach-limit", "0.37"]));
    let fc370 = v370["fc_hz"].as_f64().unwrap();
    assert!((fc370 - 2.7e-3).abs() < 1e-9, "f_c at 370 mm: {fc370}");
    assert!(v370["w_ff_j"].as_f64().unwrap() < v["w_ff_j"].as_f64().unwrap(), "a lower cut-off costs less work");
}

#[test]
fn base_writes_the_csv_and_the_sweep() {
    let dir = temp_dir("plan", "base");
    let csv = dir.join("base.csv");
    let png = dir.join("sweep.png");
    let truss = "tests/data/gcode/truss/truss_200mm.gcode";
    let search = ["base", truss, "--timing", "constant", "--fc-start", "0.02", "--fc-step", "0.001"];
    let v = json(&plan(&[&search[..], &["--sweep", "--json", "--csv", csv.to_str().unwrap(), "--png", png.to_str().unwrap()]].concat()));
    let sweep = v["sweep"].as_array().unwrap();
    assert_eq!(sweep.len(), 20, "1 to 20 mHz");
    // Fig. 4: a_max falls and r_max rises as the cut-off is lowered.
    let col = |k: &str| sweep.iter().map(|r| r[k].as_f64().unwrap()).collect::<Vec<_>>();
    let (a, r) = (col("a_max_mps2"), col("r_max_m"));
    assert!(a.windows(2).all(|w| w[0] < w[1]), "a_max rises with f_c: {a:?}");
    assert!(r[0] > r[19] + 0.03, "r_max: {} mm at 1 mHz, {} mm at 20 mHz", r[0] * 1e3, r[19] * 1e3);
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t,tcp_x,tcp_y,base_x,base_y,s"));
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').map(|x| x.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), v["samples"].as_u64().unwrap() as usize);
    assert!(rows.windows(2).all(|w| (w[1][0] - w[0][0] - 0.06).abs() < 1e-9), "60 ms samples");
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
    // The same plan as strand-sim's base trajectory: from the free flyer's mount, after a 5 s hold.
    let traj = dir.join("flyer.csv");
    let out = plan(&[&search[..], &["--trajectory", traj.to_str().unwrap(), "--start-delay", "5"]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let t = strand_sim::flyer::BaseTrajectory::load(&traj, 0.0).unwrap();
    assert_eq!(t.at(0.0)[..2], [0.0, 0.0], "the free flyer's mount");
    assert_eq!(t.at(5.0)[..2], [0.0, 0.0]);
    let k = 1000;
    let (bx, by) = (rows[k][3] - rows[0][3], rows[k][4] - rows[0][4]);
    let p = t.at(5.0 + rows[k][0]);
    assert!((p[0] - bx).abs() < 1e-12 && (p[1] - by).abs() < 1e-12, "{p:?} vs {bx} {by}");
}

#[test]
fn finish_and_tilt_write_segment_files_that_read_back() {
    let dir = temp_dir("plan", "files");
    let finish = dir.join("finish.jsonl");
    let v = json(&plan(&["finish", "--width", "0.002", "-o", finish.to_str().unwrap(), "--json"]));
    let file = read_path(&finish, 1).unwrap();
    assert_eq!(file.segments.len() as u64, v["segments"].as_u64().unwrap());
    assert_eq!(file.segments.len(), 5 * 181);
    assert!(file.note.unwrap().contains("002 Eqs. 20-21"));
    // 002's profile: the tool tilts up to 8.14° from vertical (α = π ± 0.142 rad).
    assert!((v["max_tilt_rad"].as_f64().unwrap() - 0.141_998).abs() < 1e-5);
    let tilted = dir.join("box45.jsonl");
    let out = plan(&[
        "tilt",
        "tests/data/gcode/slic3r/box35.gcode",
        "--bolt-height",
        "0.1",
        "--bolt-distance",
        "0.1",
        "-o",
        tilted.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("45.000°"));
    let file = read_path(&tilted, 1).unwrap();
    assert!(file.segments.len() > 1000);
}

#[test]
fn bad_input_names_the_flag() {
    let out = plan(&["tilt", "tests/data/gcode/slic3r/box35.gcode", "--angle", "95", "-o", "/tmp/never.jsonl"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--angle 95.000°: must be at least 0° and below 90°"));
    let out = plan(&["base", "tests/data/gcode/truss/truss_200mm.gcode", "--timing", "constant", "--reach-limit", "0.2"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--reach-limit 0.2 m is below --r-nom 0.23 m"));
    let out = plan(&["base", "tests/data/gcode/truss/truss_200mm.gcode", "--timing", "constant", "--fc-start", "10"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("Nyquist"), "{}", String::from_utf8_lossy(&out.stderr));
    let out = plan(&["finish", "--spacing", "0.0001", "-o", "/tmp/never.jsonl"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--spacing"));
}
