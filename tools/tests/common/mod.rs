//! Shared by the tools' process tests: the repository root, scratch folders and a small G-code job.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Child;

/// The repository root (configs and data are relative to it).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The `strand` service binary, built beside the tools.
pub fn strand_bin() -> PathBuf {
    let p = Path::new(env!("CARGO_BIN_EXE_strand-feed")).with_file_name("strand");
    assert!(p.exists(), "{} missing: build the workspace (cargo test --workspace builds it)", p.display());
    p
}

/// A child process killed (and reaped) when the test lets go of it, pass or panic.
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// An empty scratch folder for one test of one suite.
pub fn temp_dir(suite: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("strand-{suite}-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `layers` layers (0.2 mm, PrusaSlicer-style layer comments) of `loops` 10 mm squares at `feed`
/// mm/min, in bed coordinates (mm) near the iiwa7's start: per layer one travel and 4 × `loops`
/// extruding lines.
pub fn square_program(dir: &Path, layers: usize, loops: usize, feed: f64) -> PathBuf {
    let mut g = String::from("G21\nG90\nM83\n");
    for l in 0..layers {
        let z = 0.2 * (l + 1) as f64;
        g += &format!(";LAYER_CHANGE\n;Z:{z:.1}\nG0 X0 Y-20 Z{z:.1} F6000\nG1 F{feed}\n");
        for _ in 0..loops {
            g += "G1 X10 Y-20 E0.4\nG1 X10 Y-10 E0.4\nG1 X0 Y-10 E0.4\nG1 X0 Y-20 E0.4\n";
        }
    }
    let p = dir.join("square.gcode");
    std::fs::write(&p, g).unwrap();
    p
}

/// The number at `path` (object keys) in a JSON value; panics naming the path if it is missing.
pub fn json_f64(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut x = v;
    for k in path {
        x = &x[*k];
    }
    x.as_f64().unwrap_or_else(|| panic!("{path:?} missing in {v}"))
}
