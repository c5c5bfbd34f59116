//! strand-replay's command line on a real log: a service run of 300 ticks (free-run, echoing its
//! commands) is verified to the bit, summarised and exported; a missing file is refused by name.
//!
//! (Its being here also has cargo build the strand-replay binary in `cargo test --workspace`: cargo
//! builds a package's binaries for its own integration tests only, and the tools' bad-input suite in
//! strand-plan runs this binary too.)

use std::process::Command;

use strand_testkit::{service_log, temp_dir};

fn replay(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_strand-replay")).args(args).env("RUST_BACKTRACE", "0").output().unwrap()
}

#[test]
fn a_service_log_is_verified_summarised_and_exported_and_a_missing_one_is_named() {
    let dir = temp_dir("replay", "cli");
    let log = service_log(&dir, "replay-cli");
    let path = log.to_str().unwrap();

    let verify = replay(&["verify", path]);
    let said = String::from_utf8_lossy(&verify.stdout);
    assert!(verify.status.success(), "{said}{}", String::from_utf8_lossy(&verify.stderr));
    assert_eq!(said.trim(), "identical (300 ticks)");

    let info = replay(&["info", path]);
    assert!(info.status.success(), "{}", String::from_utf8_lossy(&info.stderr));
    assert!(!info.stdout.is_empty());

    let csv = dir.join("csv");
    let export = replay(&["export", path, "--csv", csv.to_str().unwrap()]);
    assert!(export.status.success(), "{}", String::from_utf8_lossy(&export.stderr));
    let ticks = std::fs::read_to_string(csv.join("strand_tick.csv")).unwrap();
    assert_eq!(ticks.lines().count(), 301, "a header and one row per tick");

    let missing = replay(&["verify", dir.join("nothing.mcap").to_str().unwrap()]);
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("nothing.mcap"), "{}", String::from_utf8_lossy(&missing.stderr));
}
