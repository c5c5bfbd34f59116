//! The jobs the tools run when given none — the demo's first layers of the 35 mm box and its 200 mm
//! truss, the turntable cell's helix cylinder, the benchmarks' PrusaSlicer box — built into the binaries, so `strand-demo` and
//! `strand-bench` run outside the repository too.

use std::path::{Path, PathBuf};

macro_rules! job {
    ($rel:literal) => {
        ($rel, include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../", $rel)) as &[u8])
    };
}

/// The built-in jobs: their path in the repository and their bytes.
pub static FILES: &[(&str, &[u8])] = &[
    job!("tests/data/gcode/slic3r/box35.gcode"),
    job!("tests/data/gcode/truss/truss_200mm.gcode"),
    job!("tests/data/gcode/prusaslicer/box35.gcode"),
    job!("tests/data/gcode/turntable/helix_cylinder.gcode"),
];

/// The demo's default job for a fixed base: Slic3r's 35 mm box.
pub const DEMO_BOX: &str = "tests/data/gcode/slic3r/box35.gcode";
/// The demo's default job for a tracked base: the 200 mm 1D truss.
pub const DEMO_TRUSS: &str = "tests/data/gcode/truss/truss_200mm.gcode";
/// The demo's default job for a cell with a rotary table (`cells/kr6-turntable`): a 600 mm
/// cylinder printed as one helix, the table turning under a nearly still arm (its far side is out
/// of the arm's reach).
pub const DEMO_HELIX: &str = "tests/data/gcode/turntable/helix_cylinder.gcode";

/// A folder under which every path of [`FILES`] exists: the working directory when it has them (the
/// repository root), else the built-in copy written to the cache folder of
/// `strand::config::locate` (`jobs-<version>-<hash>`).
pub fn root() -> Result<PathBuf, strand::config::ConfigError> {
    if FILES.iter().all(|(rel, _)| Path::new(rel).is_file()) {
        return Ok(PathBuf::from("."));
    }
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for (rel, bytes) in FILES {
        for b in rel.bytes().chain([0]).chain(bytes.iter().copied()) {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    let leaf = format!("jobs-{}-{hash:016x}", env!("CARGO_PKG_VERSION"));
    strand::config::locate::materialise(&leaf, FILES)
}
