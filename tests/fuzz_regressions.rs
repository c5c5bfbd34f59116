//! The fuzz targets' regression inputs (fuzz/regressions/<target>/) through the same checks as the
//! targets (fuzz/src/checks.rs, included here): the parser never panics and reports errors with
//! file, line and column; parser → path engine finishes within its bound and keeps every limit.
//! Files named `open-*` are known failures not yet fixed: they must still fail (see
//! fuzz/regressions/README.md).

#[path = "../fuzz/src/checks.rs"]
#[allow(unreachable_pub, reason = "the fuzz crate's public checks, included here as a private module")]
mod checks;

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

fn inputs(target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions").join(target);
    let mut files: Vec<PathBuf> = match std::fs::read_dir(&dir) {
        Ok(entries) => entries.map(|e| e.unwrap().path()).filter(|p| p.is_file()).collect(),
        Err(_) => Vec::new(),
    };
    files.sort();
    files
}

fn is_open(file: &Path) -> bool {
    file.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("open-"))
}

/// Runs `check` on every input of `target`; returns how many ran. With `open`, inputs named
/// `open-*` must fail; without, every input must pass.
fn run_all(target: &str, open: bool, check: impl Fn(&[u8])) -> usize {
    let files = inputs(target);
    let mut fixed = Vec::new();
    for file in &files {
        let data = std::fs::read(file).unwrap();
        let result = catch_unwind(AssertUnwindSafe(|| check(&data)));
        match (result, open && is_open(file)) {
            (Ok(()), false) => println!("{}: ok", file.display()),
            (Err(panic), false) => std::panic::resume_unwind(panic),
            (Err(_), true) => println!("{}: still fails (open, as expected)", file.display()),
            (Ok(()), true) => fixed.push(file.display().to_string()),
        }
    }
    assert!(fixed.is_empty(), "open regressions now pass: drop their `open-` prefix so they guard the fix: {fixed:?}");
    files.len()
}

#[test]
fn parser_regressions_do_not_panic_and_name_file_line_and_column() {
    let n = run_all("gcode_parser", true, |data| {
        checks::check_parser(data);
    });
    // The path inputs go through the parser's checks too.
    let m = run_all("gcode_to_path", false, |data| {
        checks::check_parser(data);
    });
    println!("{n} parser inputs, {m} path inputs parsed");
}

#[test]
fn path_regressions_finish_within_every_limit() {
    let n = run_all("gcode_to_path", true, |data| {
        checks::check_path(data);
    });
    assert!(n > 0, "no regression inputs for gcode_to_path");
}
