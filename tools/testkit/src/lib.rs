//! The tests' common ground, in one place: the repository, the built binaries, scratch folders, a
//! small G-code job, and the child-process guard (`strand_cli::child::Reaped`, the tools' own).
//! A dev-dependency only: no library or binary links it.

use std::path::{Path, PathBuf};

pub use strand_cli::child::Reaped;

/// The repository root (configs and data are relative to it).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A binary of the workspace (`strand`, `strand-feed`, `strand-egm`...), built beside the running
/// test (`target/<profile>/`): `cargo test --workspace` builds every binary before it runs a test;
/// a test of one package needs the others built first, and the panic says so.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the running test's path");
    // target/<profile>/deps/<test>-<hash>
    let dir = exe.parent().and_then(Path::parent).expect("a test runs from target/<profile>/deps");
    let p = dir.join(name);
    assert!(p.is_file(), "{} missing: build the workspace first (cargo build --workspace, or cargo test --workspace)", p.display());
    p
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

/// The seed of a property test's run: `PROPTEST_RNG_SEED` when set (to replay a run), else a fresh
/// one each run, so CI explores new cases every time instead of replaying one fixed set. The seed
/// is printed first: the test harness shows a failing test's output, so a failure names the seed
/// that reproduces it (`PROPTEST_RNG_SEED=<seed> cargo test --test <test>`). Pinned regressions
/// stay as their own tests beside the random one.
pub fn proptest_seed(test: &str) -> u64 {
    let seed = match std::env::var("PROPTEST_RNG_SEED") {
        Ok(v) => v.trim().parse().unwrap_or_else(|_| panic!("PROPTEST_RNG_SEED={v:?}: not a whole number")),
        Err(_) => {
            // std's per-process random keys (the OS's entropy), mixed with the clock and the pid.
            use std::hash::{BuildHasher, Hasher};
            let mut h = std::collections::hash_map::RandomState::new().build_hasher();
            h.write_u128(std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos()));
            h.write_u32(std::process::id());
            h.finish()
        }
    };
    eprintln!("{test}: PROPTEST_RNG_SEED={seed} (set it to replay this run)");
    seed
}

/// A real log: the service (`strand run`) in free-run, echoing its commands, for 300 ticks, written
/// to `<dir>/run.mcap` (its prefix made unique by `name` and the process). Panics with the
/// service's stderr if it fails.
pub fn service_log(dir: &Path, name: &str) -> PathBuf {
    service_log_of(dir, name, 300)
}

/// As [`service_log`], `ticks` ticks long, to `<dir>/run-<ticks>.mcap` (`run.mcap` for 300). A
/// free-run service closes a block of the compact record every 1,024 ticks: a log meant to be cut
/// needs a few.
pub fn service_log_of(dir: &Path, name: &str, ticks: u64) -> PathBuf {
    let log = if ticks == 300 { dir.join("run.mcap") } else { dir.join(format!("run-{ticks}.mcap")) };
    let out = std::process::Command::new(bin("strand"))
        .args(["run", "--clock", "free-run", "--echo", "--ticks", &ticks.to_string(), "--prefix"])
        .arg(format!("strand/{name}-{}", std::process::id()))
        .arg("--log")
        .arg(&log)
        .current_dir(root())
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    log
}

/// Nozzle pointing down in W (π about y), as a wire quaternion (w, x, y, z).
pub const NOZZLE_DOWN: [f64; 4] = [0.0, 0.0, 1.0, 0.0];

/// A line to `end` (m, W; in a cell with external axes, on the part at home) with the external
/// axes at `axes` (rad or m) at its end (`AXES`), the nozzle down, at `feed` (m/s): extruding
/// `filament` (m) when > 0, else a travel.
pub fn line_with_axes(seq: u64, end: [f64; 3], axes: [f64; 2], feed: f64, filament: f64) -> strand_wire::Segment {
    use strand_wire::segment_flags::{AXES, EXTRUDE, TRAVEL};
    strand_wire::Segment {
        seq,
        kind: strand_wire::SegmentKind::Line as u32,
        flags: AXES | if filament > 0.0 { EXTRUDE } else { TRAVEL },
        end,
        orientation: NOZZLE_DOWN,
        feed,
        filament,
        axes,
        ..Default::default()
    }
}

/// The next batch of `job`, from `*next` on (advanced past it), that the credit window `status`
/// announces allows: segments numbered up to `last_received_seq + queue_free`, at most a batch's
/// capacity; empty when the window is shut. Numbered `batch_seq`, stamped `stamp_ns`.
pub fn credit_batch(
    job: &[strand_wire::Segment],
    next: &mut usize,
    status: &strand_wire::Status,
    batch_seq: u64,
    stamp_ns: u64,
) -> strand_wire::SegmentBatch {
    let window_end = status.last_received_seq + u64::from(status.queue_free);
    let mut batch = strand_wire::SegmentBatch { seq: batch_seq, stamp_ns, ..Default::default() };
    while *next < job.len() && (batch.len as usize) < strand_wire::SEGMENT_BATCH_CAPACITY && job[*next].seq <= window_end {
        batch.segments[batch.len as usize] = job[*next];
        batch.len += 1;
        *next += 1;
    }
    batch
}

/// A G-code-like program from random words, for the parsers' property tests: each (letter, value,
/// style) writes `L<value>` with three decimals (style 0), `L<small integer>` (1), `L<value>` with
/// no separator (2) or a line break (3); a line break every seventh word besides.
pub fn gcode_from_words(words: &[(u8, f64, u8)]) -> Vec<u8> {
    let mut text = String::new();
    for (i, (letter, value, style)) in words.iter().enumerate() {
        let letter = *letter as char;
        match style {
            0 => text.push_str(&format!("{letter}{value:.3} ")),
            1 => text.push_str(&format!("{letter}{} ", (*value as i64 % 5).abs())),
            2 => text.push_str(&format!("{letter}{value}")),
            _ => text.push('\n'),
        }
        if i % 7 == 6 {
            text.push('\n');
        }
    }
    text.into_bytes()
}

/// The first Status `until` accepts, waiting on the monitor's port; panics naming `what` and the
/// last Status after `seconds`.
pub fn wait_for_status(
    m: &strand_ipc::ports::ClientPorts,
    seconds: u64,
    what: &str,
    until: impl Fn(&strand_ipc::Status) -> bool,
) -> strand_ipc::Status {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(seconds);
    loop {
        if let Some(s) = m.latest_status()
            && until(&s)
        {
            return s;
        }
        assert!(std::time::Instant::now() < deadline, "timed out waiting for {what}: {:?}", m.latest_status());
        let _ = m.wait_status(20_000_000);
    }
}
