//! What the driver tests share beyond `strand_testkit`: the job every cell prints and waiting for a
//! log line.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Two layers of three 10 mm squares at 30 mm/s in the middle of the bundled robots' beds (G-code).
pub(crate) fn squares_gcode() -> String {
    let mut g = String::from("G21\nG90\nM83\n");
    for l in 0..2 {
        let z = 0.2 * (l + 1) as f64;
        g += &format!(";LAYER_CHANGE\n;Z:{z:.1}\nG0 X120 Y120 Z{z:.1} F6000\nG1 F1800\n");
        for _ in 0..3 {
            g += "G1 X130 Y120 E0.4\nG1 X130 Y130 E0.4\nG1 X120 Y130 E0.4\nG1 X120 Y120 E0.4\n";
        }
    }
    g
}

/// The job the drivers' job tests print, and `strand-feed`'s arguments for it: the shared squares
/// (`squares_gcode`, written into `dir`: seconds), or with `STRAND_DEMO_JOB=1` the demo's job —
/// `strand-demo`'s 35 mm box sliced by Slic3r (`strand_cli::jobs::DEMO_BOX`) to its first layer,
/// about two minutes a driver (the long mode; CI runs the squares).
pub(crate) fn cell_job(dir: &Path) -> (PathBuf, Vec<&'static str>) {
    if std::env::var_os("STRAND_DEMO_JOB").is_some_and(|v| v == "1") {
        return (strand_testkit::root().join("tests/data/gcode/slic3r/box35.gcode"), vec!["--layers", "1"]);
    }
    let p = dir.join("squares.gcode");
    std::fs::write(&p, squares_gcode()).unwrap();
    (p, Vec::new())
}

pub(crate) fn wait_for(file: &Path, text: &str, within: Duration) {
    let end = Instant::now() + within;
    while Instant::now() < end {
        if std::fs::read_to_string(file).is_ok_and(|t| t.contains(text)) {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    panic!("{} never said {text:?}:\n{}", file.display(), std::fs::read_to_string(file).unwrap_or_default());
}

/// Whether the real-time cells (a job or a killed service through a driver, against a fake on its
/// own deadlines) run in this build: optimised, or when `STRAND_DEBUG_CELLS=1`. Unoptimised, a
/// service, a driver and a fake sharing two cores miss their cycles for the build's sake, and the
/// fakes' timing rules then fail the run (drivers.rs saw it in 4 of 6 debug runs, connecting.rs'
/// UR job once in CI's debug stage: ten late commands in a row); CI's release stages run them.
pub(crate) fn cells_run_here(test: &str) -> bool {
    let here = !cfg!(debug_assertions) || std::env::var_os("STRAND_DEBUG_CELLS").is_some_and(|v| v == "1");
    if !here {
        eprintln!("{test}: skipped in a debug build (real-time cells run with --release, or STRAND_DEBUG_CELLS=1)");
    }
    here
}

/// SCHED_FIFO priority of the driver in a test cell (`--rt`), as the README's cells run it: the
/// fake robot above it (90, its own clock), the driver next, the service below
/// ([`SERVICE_RT_SETTING`]). Without it every process of the cell is SCHED_OTHER, and a 20 µs
/// sleep of the driver's wait for the command could end a whole scheduler slice later (measured
/// with two spinning loads on this 2-core machine: receive → reply p99 2.97 ms, 5 robot cycles
/// lost in one RSI job); a CI run then saw three late answers in a row while the feeder started
/// up, and the driver faulted, twice. A machine that refuses the priority runs the cell all the
/// same and the driver warns.
pub(crate) const DRIVER_RT: &str = "80";

/// The service's `--set` for its cycle thread's priority in a test cell, below the driver's
/// ([`DRIVER_RT`]).
pub(crate) const SERVICE_RT_SETTING: &str = "realtime.fifo_priority=70";
