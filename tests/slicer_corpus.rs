//! Real slicer output through the same evaluation as `strand-plan time` (config/default.toml:
//! lookahead, its limits, its bed, 1 kHz): every `.gcode` file under tests/data/gcode/{cura,
//! prusaslicer25, slic3r13, orca, simplify3d} (a folder that is missing is skipped), each with its
//! slicer's own default start and end code (tests/data/gcode/README.md; slicers/slice.sh makes them).
//!
//! Per file: the parser and the engine finish it (no error, no timeout); it takes at least 98 % of
//! the feed-rate bound (blends shorten the path a little) and less than [`MAX_RATIO`] times it;
//! speed, acceleration, jerk and centripetal acceleration stay within the config's limits; the
//! executed path stays within the deviation tolerance; the flow error stays under 0.5 %.
//! A table of all files is printed (with the engine's forced brakes, for information) (`cargo test --test slicer_corpus -- --nocapture`); every file is
//! run before the test fails, and the failure lists each file's errors.

mod common;

use std::path::{Path, PathBuf};

use strand::config::Config;
use strand_job::bed::BedTransform;
use strand_job::gcode::{GcodeOptions, parse_file};
use strand_job::timing::{TimingReport, time_program};

/// The corpus folders, under tests/data/gcode.
const DIRS: [&str; 5] = ["cura", "prusaslicer25", "slic3r13", "orca", "simplify3d"];

/// Duration over the feed-rate bound. Measured with the lookahead engine of 2026-11 on the files
/// that ran (PrusaSlicer and Slic3r defaults; the MK3S files with the two lines the parser refused
/// taken out): 1.06 to 1.15, from the parts' short perimeter and infill segments at 3 m/s² and
/// 100 m/s³. Stop-and-go reaches 1.53 on slic3r13/default_cyl20, so 1.3 still tells a planner that
/// keeps its speed through junctions from one that stops at them. The hand-made Klipper square
/// (20 mm sides, firmware retraction at every travel) reaches 1.31: its moves are a few millimetres
/// long, so ramps dominate. 1.35 keeps both apart.
const MAX_RATIO: f64 = 1.35;

/// Flow error bound (relative), as tests/path_corpus.rs.
const MAX_FLOW_ERROR: f64 = 0.005;

/// Relative slack on the limits (the engine's own rounding).
const SLACK: f64 = 1e-6;

fn corpus_files() -> Vec<PathBuf> {
    let base = strand_testkit::root().join("tests/data/gcode");
    let mut files = Vec::new();
    for dir in DIRS {
        let Ok(entries) = std::fs::read_dir(base.join(dir)) else { continue };
        let mut here: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("gcode")))
            .collect();
        here.sort();
        files.extend(here);
    }
    files
}

/// What `strand-plan time FILE` computes, with the parser's warnings prepended.
fn time_file(config: &Config, file: &Path) -> Result<TimingReport, String> {
    let bed = BedTransform::new(&config.bed).map_err(|e| e.to_string())?;
    let mut parser = parse_file(file, GcodeOptions::default()).map_err(|e| e.to_string())?;
    let name = file.display().to_string();
    let mut report = time_program(parser.by_ref(), &name, &config.path, &config.extruder, &bed, config.controller.rate_hz, |_| {})
        .map_err(|e| e.to_string())?;
    let mut warnings: Vec<String> = parser.warnings().iter().chain(parser.notes()).map(|w| w.to_string()).collect();
    warnings.append(&mut report.warnings);
    report.warnings = warnings;
    Ok(report)
}

/// The checks, as messages (empty: the file passes).
fn check(config: &Config, r: &TimingReport) -> Vec<String> {
    let p = &config.path;
    let mut failed = Vec::new();
    let ratio = r.duration_s / r.lower_bound_s;
    if r.duration_s < 0.98 * r.lower_bound_s {
        failed.push(format!("{:.3} s, under 98 % of the bound {:.3} s", r.duration_s, r.lower_bound_s));
    }
    if ratio.is_nan() || ratio >= MAX_RATIO {
        failed.push(format!("duration / bound {ratio:.3} ≥ {MAX_RATIO}"));
    }
    if r.max_speed > p.max_speed * (1.0 + SLACK) {
        failed.push(format!("speed {} m/s over {}", r.max_speed, p.max_speed));
    }
    if r.max_acc > p.max_acceleration * (1.0 + SLACK) {
        failed.push(format!("acceleration {} m/s² over {}", r.max_acc, p.max_acceleration));
    }
    if r.max_jerk > p.max_jerk * (1.0 + SLACK) {
        failed.push(format!("jerk {} m/s³ over {}", r.max_jerk, p.max_jerk));
    }
    if r.max_centripetal_acc > p.centripetal_acceleration * (1.0 + SLACK) {
        failed.push(format!("centripetal acceleration {} m/s² over {}", r.max_centripetal_acc, p.centripetal_acceleration));
    }
    if r.max_deviation_m > p.deviation_tolerance * (1.0 + SLACK) {
        failed.push(format!("deviation {:.6} mm over {} mm", r.max_deviation_m * 1e3, p.deviation_tolerance * 1e3));
    }
    if r.max_flow_error.is_nan() || r.max_flow_error > MAX_FLOW_ERROR {
        failed.push(format!("flow error {:.2e} over {MAX_FLOW_ERROR}", r.max_flow_error));
    }
    failed
}

#[test]
fn every_slicer_file_finishes_within_the_limits() {
    let root = strand_testkit::root();
    let config = Config::load(&root.join("config/default.toml")).unwrap_or_else(|e| panic!("{e}"));
    let files = corpus_files();
    assert!(!files.is_empty(), "no corpus files under tests/data/gcode/{{{}}}", DIRS.join(","));
    let mut failures = Vec::new();
    println!(
        "{:<36} {:>6} {:>8} {:>8} {:>6} {:>8} {:>7} {:>6}  result",
        "file", "segs", "time s", "bound s", "ratio", "dev mm", "flow", "brakes"
    );
    for file in &files {
        let name = file.strip_prefix(root.join("tests/data/gcode")).unwrap_or(file).display().to_string();
        match time_file(&config, file) {
            Ok(r) => {
                let failed = check(&config, &r);
                println!(
                    "{:<36} {:>6} {:>8.1} {:>8.1} {:>6.3} {:>8.5} {:>7.1e} {:>6}  {}",
                    name,
                    r.segments,
                    r.duration_s,
                    r.lower_bound_s,
                    r.duration_s / r.lower_bound_s,
                    r.max_deviation_m * 1e3,
                    r.max_flow_error,
                    r.forced_brakes,
                    if failed.is_empty() { "ok".to_string() } else { failed.join("; ") }
                );
                if !failed.is_empty() {
                    failures.push(format!("{name}: {}", failed.join("; ")));
                }
            }
            Err(e) => {
                // The error names the absolute path; the table the relative one.
                let e = e.replace(&format!("{}/", root.join("tests/data/gcode").display()), "");
                println!("{name:<36} {:>6} {:>8} {:>8} {:>6} {:>8} {:>7} {:>6}  FAILED: {e}", "-", "-", "-", "-", "-", "-", "-");
                failures.push(format!("{name}: {e}"));
            }
        }
    }
    assert!(failures.is_empty(), "{} of {} corpus files failed:\n{}", failures.len(), files.len(), failures.join("\n"));
}
