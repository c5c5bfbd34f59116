//! strand-kin as a user runs it: the check report, and eval over JSON lines with bad lines mixed in.

use std::io::Write;
use std::process::{Command, Stdio};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_strand-kin"))
}

fn robots() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/robots")
}

#[test]
fn check_reports_chain_limits_reach_and_warnings() {
    let out = bin().arg("check").arg(robots().join("vp6242.toml")).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("base → tool0: 6 joints"), "{text}");
    assert!(text.contains("joint3") && text.contains("19.0") && text.contains("160.0"), "{text}");
    assert!(text.contains("q = 0 lies outside its limits"), "{text}");
    assert!(text.contains("likely a placeholder"), "{text}");
    let reach: f64 = text.split("reach").nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap();
    assert!((0.8..0.9).contains(&reach), "reach {reach}");

    let out = bin().args(["check"]).arg(robots().join("iiwa7.urdf")).args(["--root", "world", "--tip", "iiwa_link_ee"]).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("7 joints") && text.contains("bare URDF"), "{text}");
}

#[test]
fn check_fails_with_the_file_and_element_named() {
    let out = bin().args(["check"]).arg(robots().join("iiwa7.urdf")).args(["--root", "world", "--tip", "iiwa_link_99"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("iiwa7.urdf") && err.contains("iiwa_link_99"), "{err}");
    let out = bin().args(["check"]).arg(robots().join("iiwa7.urdf")).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8(out.stderr).unwrap().contains("--root"));
}

#[test]
fn eval_answers_every_line_and_reports_bad_ones() {
    let mut child = bin()
        .args(["eval", "--urdf"])
        .arg(robots().join("iiwa7.urdf"))
        .args(["--root", "world", "--tip", "iiwa_link_ee"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let input = "{\"q\":[0,0,0,0,0,0,0]}\n{\"q\":[1,2,3]}\nnot json\n{\"q\":[0,0.5,0,-1,0,1,0]}\n{\"q\":[0,0,0,0,0,0,NaN]}\n";
    child.stdin.take().unwrap().write_all(input.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 5);
    // iiwa7 upright: flange at 1.266 m, no tool with a bare URDF; stretched = singular.
    let pos: Vec<f64> = serde_json::from_value(lines[0]["pos"].clone()).unwrap();
    assert!((pos[2] - 1.266).abs() < 1e-9 && pos[0].abs() < 1e-12, "{pos:?}");
    assert!(lines[0]["manipulability"].as_f64().unwrap() < 1e-9);
    assert!(lines[1]["error"].as_str().unwrap().contains("line 2") && lines[1]["error"].as_str().unwrap().contains("7 joints"));
    assert!(lines[2]["error"].as_str().unwrap().contains("not JSON"));
    let j: Vec<Vec<f64>> = serde_json::from_value(lines[3]["jacobian"].clone()).unwrap();
    assert_eq!((j.len(), j[0].len()), (6, 7));
    let q: Vec<f64> = serde_json::from_value(lines[3]["quat"].clone()).unwrap();
    assert!((q.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-12);
    assert_eq!(serde_json::from_value::<Vec<f64>>(lines[3]["grad"].clone()).unwrap().len(), 7);
    assert!(lines[3]["manipulability"].as_f64().unwrap() > 1e-3);
    assert!(lines[4]["error"].as_str().unwrap().contains("line 5"));
}
