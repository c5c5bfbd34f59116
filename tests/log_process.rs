//! The log of a real service process: `kill -9` in the middle of a run leaves a file whose closed
//! chunks (at most `chunk_interval` old) are recovered and replay identically; a log that hits the
//! file-size limit (the stand-in for a full disk) stops logging while control goes on, and Status
//! says so.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use mcap::read::{LinearReader, Options};
use mcap::records::Record;
use strand::log::reader::LogFile;
use strand::log::replay::{Verdict, verify};
use strand::log::{topics, unix_now_ns};
use strand_testkit::temp_dir;

fn strand(prefix: &str, log: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_strand"));
    c.args(["run", "--config", "config/default.toml", "--prefix", prefix, "--echo", "--log"])
        .arg(log)
        .args(extra)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "warn");
    c
}

#[test]
fn a_killed_service_leaves_a_log_recovered_to_its_last_chunk_that_replays_identically() {
    let dir = temp_dir("core", "kill");
    let log = dir.join("killed.mcap");
    let prefix = format!("strand/logkill-{}", std::process::id());
    let mut child = strand(&prefix, &log, &["--clock", "timer"]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    // Let it run about 1.5 s past start-up.
    let t0 = std::time::Instant::now();
    while !log.exists() && t0.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(1500));
    child.kill().unwrap(); // SIGKILL
    let killed_at = unix_now_ns();
    child.wait().unwrap();

    let cut = LogFile::open(&log).unwrap();
    assert!(!cut.finished, "a killed writer cannot have finished its file");
    // Chunks were closed by time: their spans of log time stay near chunk_interval (100 ms).
    let mut spans: Vec<u64> = LinearReader::new_with_options(cut.bytes(), Options::IgnoreEndMagic.into())
        .unwrap()
        .map_while(Result::ok)
        .filter_map(|r| match r {
            Record::Chunk { header, .. } => Some(header.message_end_time - header.message_start_time),
            _ => None,
        })
        .collect();
    spans.sort();
    assert!(spans.len() >= 8, "{} chunks in 1.5 s", spans.len());
    assert!(spans[spans.len() / 2] <= 110_000_000, "median chunk span {} ns", spans[spans.len() / 2]);

    let out = dir.join("killed.recovered.mcap");
    let r = strand::log::recover::recover(&log, &out).unwrap();
    let rec = LogFile::open(&out).unwrap();
    let recovered_ticks = rec.records().count() as u64;
    assert!(recovered_ticks > 800, "{recovered_ticks} ticks: {:?}", r.per_topic);
    let lost_s = (killed_at - r.last_log_time) as f64 * 1e-9;
    assert!(lost_s < 0.5, "the last recovered tick is {lost_s:.3} s older than the kill");
    assert!(rec.finished);
    match verify(&[rec]).unwrap() {
        Verdict::Identical { ticks } => assert_eq!(ticks, recovered_ticks),
        v => panic!("{v:?}"),
    }
}

#[test]
fn a_log_that_hits_the_file_size_limit_stops_and_control_goes_on() {
    let dir = temp_dir("core", "full");
    let log = dir.join("full.mcap");
    let prefix = format!("strand/logfull-{}", std::process::id());
    // An idle robot's compact log is a few bytes a tick: write the full record and every channel,
    // so that the limit is met mid-run.
    let extra = ["--clock", "free-run", "--ticks", "20000", "--set", "log.record=full", "--set", "log.derived_rate_hz=0"];
    let cmd = strand(&prefix, &log, &extra);
    let args: Vec<String> = cmd.get_args().map(|a| format!("'{}'", a.to_string_lossy())).collect();
    // 256 KiB (bash counts ulimit -f in KiB): the header and a few chunks fit, the rest does not.
    let script = format!("ulimit -f 256; exec '{}' {}", env!("CARGO_BIN_EXE_strand"), args.join(" "));
    let out = Command::new("bash").args(["-c", &script]).current_dir(env!("CARGO_MANIFEST_DIR")).env("RUST_LOG", "warn").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "control went on to the end: {stderr}");
    assert!(stderr.contains("ticks 20000 "), "{stderr}");
    assert!(stderr.contains("STOPPED"), "the log says it stopped: {stderr}");
    assert!(stderr.contains("log Some(Failed)"), "Status says so: {stderr}");
    assert!(std::fs::metadata(&log).unwrap().len() <= 256 * 1024);
    // What was written before the limit is recovered and replays identically.
    let rec_path = dir.join("full.recovered.mcap");
    let r = strand::log::recover::recover(&log, &rec_path).unwrap();
    let ticks = LogFile::open(&rec_path).unwrap().records().count() as u64;
    assert!(ticks > 0 && ticks < 20000 && r.per_topic.contains_key(topics::TICK), "{ticks}: {:?}", r.per_topic);
    assert_eq!(verify(&[LogFile::open(&rec_path).unwrap()]).unwrap(), Verdict::Identical { ticks });
}
