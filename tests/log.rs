//! The MCAP log: every record type round-trips bit for bit, every channel's schema describes its
//! bytes, a replay of a job with faults, pause/resume and an underrun is identical, a changed gain is
//! caught at the first divergent tick, a file cut anywhere is recovered up to its last closed chunk,
//! rotation splits a run into parts that replay together, and a full queue is counted, not waited on.

mod common;

use std::path::{Path, PathBuf};

use common::Rng;
use common::cell::{Cell, IIWA_START, config, line, square_job};
use strand::config::Config;
use strand::log::cdr::{CdrType, CdrWriter, Scalar, decode, encode};
use strand::log::dynamic::{Schema, Value};
use strand::log::messages::{Tick, TickTiming};
use strand::log::reader::LogFile;
use strand::log::replay::{ReplayError, Verdict, verify, verify_with};
use strand::log::writer::{LogContext, Logger};
use strand::log::{LogConfig, topics};
use strand_core::{TickInput, TickOutput};
use strand_ipc as ipc;
use strand_ipc::{Command, RunState};
use strand_testkit::temp_dir;

fn log_cfg(f: impl FnOnce(&mut LogConfig)) -> LogConfig {
    let mut c = LogConfig { queue_ticks: 65536, ..LogConfig::default() };
    f(&mut c);
    c
}

/// Steps a cell, logging every tick; the writer is given time so nothing is dropped.
fn step_logged(cell: &mut Cell, logger: &Logger) -> TickOutput {
    cell.step_observed(&mut |i: &TickInput, o: &TickOutput| {
        logger.push(
            i,
            o,
            &TickTiming {
                wake_lateness_ns: 1000 + i.tick % 7,
                step_ns: 5000,
                tick_ns: 9000,
                receive_ns: 700 + i.tick % 3,
                command_ns: 6000,
            },
        );
    })
}

fn run_logged(cell: &mut Cell, logger: &Logger, max: u64, mut until: impl FnMut(&TickOutput) -> bool) -> TickOutput {
    for _ in 0..max {
        let out = step_logged(cell, logger);
        if until(&out) {
            return out;
        }
    }
    panic!("condition not reached in {max} ticks (state {:?})", cell.state());
}

/// A job with everything a replay must reproduce: an approach, an underrun (half the job, then
/// the rest), a rejected segment, pause and resume, a feed override, the end of the job, an
/// emergency stop (fault) and its clearing, and a silent driver (fault).
fn eventful_run(cfg: &Config, path: &Path) -> (u64, Vec<ipc::Segment>) {
    let model = cfg.robot.build_model().unwrap();
    let logger = Logger::start_at(&log_cfg(|_| {}), LogContext::new(cfg, &model), path).unwrap();
    let mut cell = Cell::new(cfg, &IIWA_START);
    let job = square_job(1, [0.45, 0.0, 0.3], 0.02, 2, 0.03);
    let (first, rest) = job.split_at(4);
    cell.send(first);
    cell.control(Command::Start, 0.0);
    run_logged(&mut cell, &logger, 60_000, |o| o.status.underruns > 0);
    // A segment with a NaN is rejected; the next good one carries on.
    let mut bad = rest[0];
    bad.feed = f64::NAN;
    cell.send(&[bad]);
    for _ in 0..20 {
        step_logged(&mut cell, &logger);
    }
    cell.send(rest);
    for _ in 0..200 {
        step_logged(&mut cell, &logger);
    }
    cell.control(Command::Pause, 0.0);
    run_logged(&mut cell, &logger, 5_000, |o| o.status.run_state == RunState::Paused as u32);
    for _ in 0..100 {
        step_logged(&mut cell, &logger);
    }
    cell.control(Command::Resume, 0.0);
    cell.control(Command::FeedOverride, 0.8);
    run_logged(&mut cell, &logger, 40_000, |o| {
        o.status.job_outcome == ipc::JobOutcome::Finished as u32 && o.status.run_state == RunState::Idle as u32
    });
    // Another job, cut by an emergency stop.
    cell.send(&square_job(job.len() as u64 + 1, [0.45, 0.0, 0.3], 0.02, 1, 0.03));
    cell.control(Command::Start, 0.0);
    run_logged(&mut cell, &logger, 60_000, |o| o.status.run_state == RunState::Running as u32 && o.status.path_position > 0.01);
    cell.control(Command::EmergencyStop, 0.0);
    run_logged(&mut cell, &logger, 5_000, |o| o.status.run_state == RunState::Fault as u32);
    cell.control(Command::ClearFault, 0.0);
    for _ in 0..50 {
        step_logged(&mut cell, &logger);
    }
    // The driver goes silent.
    cell.driver = false;
    run_logged(&mut cell, &logger, 5_000, |o| o.status.run_state == RunState::Fault as u32);
    for _ in 0..20 {
        step_logged(&mut cell, &logger);
    }
    let ticks = cell.tick;
    let report = logger.finish();
    assert_eq!(report.drops, 0, "the writer kept up");
    assert_eq!(report.ticks_written, ticks);
    assert!(report.error.is_none(), "{:?}", report.error);
    (ticks, job)
}

fn eventful_log() -> (PathBuf, u64) {
    static ONCE: std::sync::OnceLock<(PathBuf, u64)> = std::sync::OnceLock::new();
    ONCE.get_or_init(|| {
        let dir = temp_dir("core", "eventful");
        let path = dir.join("run.mcap");
        let (ticks, _) = eventful_run(&config(|_| {}), &path);
        (path, ticks)
    })
    .clone()
}

fn flat<T: CdrType>(v: &T) -> Vec<(String, Scalar)> {
    let mut out = Vec::new();
    v.flatten("", &mut out);
    out
}

fn bytes<T: CdrType>(v: &T) -> Vec<u8> {
    let mut w = CdrWriter::new();
    encode(&mut w, v);
    w.bytes().to_vec()
}

fn random_f64(rng: &mut Rng) -> f64 {
    // Any bit pattern: NaN payloads, infinities, subnormals, -0.
    match rng.next_u64() % 6 {
        0 => f64::from_bits(rng.next_u64()),
        1 => -0.0,
        2 => f64::NAN,
        3 => f64::from_bits(1),
        _ => rng.normal() * 10f64.powi((rng.next_u64() % 20) as i32 - 10),
    }
}

#[test]
fn every_record_type_round_trips_bit_for_bit() {
    let mut rng = Rng(7);
    for _ in 0..200 {
        let mut f = || random_f64(&mut rng);
        let seg = ipc::Segment {
            seq: 17,
            stamp_ns: u64::MAX,
            kind: 2,
            flags: 0xdead,
            end: [f(), f(), f()],
            centre: [f(), f(), f()],
            normal: [f(), f(), f()],
            sweep: f(),
            orientation: [f(), f(), f(), f()],
            feed: f(),
            filament: f(),
            duration: f(),
            source_line: 99,
            _reserved: 0,
            pressure_advance: f(),
            // A `/segments` record leaves the external axes out (a tick carries them after its
            // base command, so logs from before them still read).
            axes: [0.0; 2],
            // Likewise the heat fields (contract v5), after the axes.
            heater: 0,
            heat_wait: 0,
            temperature: 0.0,
            temperature_range: [0.0; 2],
        };
        assert_eq!(bytes(&decode::<ipc::Segment>(&bytes(&seg)).unwrap()), bytes(&seg));
        let st = ipc::Status { seq: 3, tcp_error: f(), path_speed: f(), feed_override: f(), log_state: 2, ..Default::default() };
        let back: ipc::Status = decode(&bytes(&st)).unwrap();
        assert_eq!(flat(&back), flat(&st));
        let js = ipc::JointState { dof: 7, position: [f(), f(), f(), f(), f(), f(), f(), f()], ..Default::default() };
        assert_eq!(flat(&decode::<ipc::JointState>(&bytes(&js)).unwrap()), flat(&js));
        // A tick carries its segments' external axes after the base command, bit for bit.
        let mut t = Tick::default();
        t.input.push_segment(&ipc::Segment { axes: [f(), f()], ..seg });
        t.input.push_segment(&ipc::Segment { seq: 18, axes: [f(), f()], ..seg });
        let back: Tick = decode(&bytes(&t)).unwrap();
        assert_eq!(back.input.segment_count, 2);
        for (a, b) in back.input.segments().iter().zip(t.input.segments()) {
            assert_eq!(a.axes.map(f64::to_bits), b.axes.map(f64::to_bits));
        }
        assert_eq!(bytes(&back), bytes(&t));
        // And the temperatures: the heater measurement, the segments' heat fields, the heater
        // command and the status's heat fields, bit for bit.
        let mut t = Tick::default();
        let heat = ipc::Segment { kind: 3, heater: 1, heat_wait: 3, temperature: f(), temperature_range: [f(), f()], ..seg };
        t.input.push_segment(&heat);
        t.input.heater_state = Some(ipc::HeaterState { seq: 5, stamp_ns: 6, hot_end: f(), bed: f(), flags: 3, ..Default::default() });
        t.output.heater = ipc::HeaterCommand { seq: 9, hot_end_target: f(), bed_target: f(), ..Default::default() };
        t.output.status.hot_end_temperature = f();
        t.output.status.heat_hold = 1;
        t.output.status.heat_hold_band = [f(), f()];
        let back: Tick = decode(&bytes(&t)).unwrap();
        assert_eq!(back.input.segments[0].temperature.to_bits(), heat.temperature.to_bits());
        assert_eq!(back.input.segments[0].temperature_range.map(f64::to_bits), heat.temperature_range.map(f64::to_bits));
        assert_eq!((back.input.segments[0].heater, back.input.segments[0].heat_wait), (1, 3));
        assert_eq!(back.input.heater_state.map(|h| h.hot_end.to_bits()), t.input.heater_state.map(|h| h.hot_end.to_bits()));
        assert_eq!(back.output.heater.hot_end_target.to_bits(), t.output.heater.hot_end_target.to_bits());
        assert_eq!(back.output.status.heat_hold_band.map(f64::to_bits), t.output.status.heat_hold_band.map(f64::to_bits));
        assert_eq!(bytes(&back), bytes(&t));
    }
    // Whole ticks from a real run (regenerated with the full record): each decodes to the same
    // bytes and the same fields.
    let (path, ticks) = eventful_log_regenerated();
    let log = LogFile::open(&path).unwrap();
    assert!(log.finished);
    let mut n = 0;
    let mut kinds = std::collections::BTreeSet::new();
    let mut with_segments = 0;
    for m in log.channel(topics::TICK) {
        let t: Tick = decode(&m.data).unwrap();
        assert_eq!(bytes(&t), m.data.as_ref(), "tick {} re-encodes to the logged bytes", t.input.tick);
        assert_eq!(flat(&decode::<Tick>(&bytes(&t)).unwrap()), flat(&t));
        for e in t.output.events() {
            kinds.insert(format!("{:?}", e).split([' ', '{', '(']).next().unwrap().to_string());
        }
        with_segments += (t.input.segment_count > 0) as u32;
        n += 1;
    }
    assert_eq!(n, ticks);
    assert!(with_segments >= 2);
    for k in ["SegmentRejected", "StateChanged", "Fault", "JobEnded"] {
        assert!(kinds.contains(k), "a {k} event was logged and decoded: {kinds:?}");
    }
}

/// The eventful log with every channel at every tick (`strand-replay regenerate`).
fn eventful_log_regenerated() -> (PathBuf, u64) {
    static ONCE: std::sync::OnceLock<(PathBuf, u64)> = std::sync::OnceLock::new();
    ONCE.get_or_init(|| {
        let (path, ticks) = eventful_log();
        let out = path.with_file_name("run-full-rate.mcap");
        let r = strand::log::regenerate::regenerate(&[LogFile::open(&path).unwrap()], &out).unwrap();
        assert_eq!(r.ticks, ticks);
        (out, ticks)
    })
    .clone()
}

#[test]
fn the_derived_channels_go_to_the_file_at_their_rate_and_regenerate_at_every_tick() {
    let (path, ticks) = eventful_log();
    let log = LogFile::open(&path).unwrap();
    let rate_hz = log.config().unwrap().controller.rate_hz;
    let derived_hz = LogConfig::default().derived_rate_hz;
    let mut counts = std::collections::BTreeMap::<String, u64>::new();
    let mut state = None;
    let (mut changes, mut changes_logged) = (0u64, 0u64);
    let mut status_at = std::collections::BTreeSet::new();
    let mut tick_at = Vec::new();
    for m in log.messages() {
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
        if m.channel.topic == topics::STATUS {
            status_at.insert(m.log_time);
        }
    }
    // The run's ticks and their log times, from its regenerated copy (the same times).
    let (full_path, _) = eventful_log_regenerated();
    let full = LogFile::open(&full_path).unwrap();
    for m in full.channel(topics::TICK) {
        let t: Tick = decode(&m.data).unwrap();
        let s = &t.output.status;
        let now = (s.run_state, s.fault, s.job_outcome, s.executing_layer);
        if state != Some(now) {
            changes += 1;
            tick_at.push(m.log_time);
        }
        state = Some(now);
    }
    // Every change of state has its /status, at its tick's time.
    for t in &tick_at {
        changes_logged += status_at.contains(t) as u64;
    }
    assert_eq!(changes_logged, changes, "every change of run state, fault, outcome or layer is in /status");
    // The replay record every tick; the derived channels at their rate (10 Hz) of the 1 kHz ticks.
    let expected = ticks as f64 * derived_hz / rate_hz;
    assert_eq!(log.records().count() as u64, ticks);
    assert!(!counts.contains_key(topics::TICK), "the compact record only: {counts:?}");
    for t in [topics::EXTRUDER, topics::TCP_TARGET, topics::BASE_ESTIMATED, topics::JOINT_COMMAND] {
        let n = counts[t] as f64;
        assert!((n - expected).abs() <= 2.0 + 0.01 * expected, "{t}: {n} messages, {expected:.0} expected");
    }
    let status = counts[topics::STATUS] as f64;
    assert!(status >= expected - 2.0 && status <= expected + changes as f64 + 2.0, "/status {status}");
    // Regenerated: every channel at every tick again, the same ticks (inputs and timings as the
    // compact record holds them, outputs as it recomputes them), with the full record.
    let mut full_counts = std::collections::BTreeMap::<String, u64>::new();
    for m in full.messages() {
        *full_counts.entry(m.channel.topic.clone()).or_default() += 1;
    }
    for t in [topics::TICK, topics::STATUS, topics::EXTRUDER, topics::TCP_TARGET, topics::BASE_ESTIMATED] {
        assert_eq!(full_counts[t], ticks, "{t}");
    }
    let mut same = 0;
    for (t, m) in log.ticks().zip(full.channel(topics::TICK)) {
        assert_eq!(bytes(&t.unwrap()), m.data.as_ref());
        same += 1;
    }
    assert_eq!(same, ticks, "the replay records are the run's");
    assert_eq!(verify(&[full]).unwrap(), Verdict::Identical { ticks });
    let bytes = |p: &Path| std::fs::metadata(p).unwrap().len() as f64;
    eprintln!(
        "eventful run, {ticks} ticks: {:.0} kB at {derived_hz} Hz derived, {:.0} kB at every tick",
        bytes(&path) / 1e3,
        bytes(&eventful_log_regenerated().0) / 1e3
    );
}

#[test]
fn every_channel_schema_describes_its_bytes_and_channels_agree() {
    let (path, ticks) = eventful_log_regenerated();
    let log = LogFile::open(&path).unwrap();
    let mut counts = std::collections::BTreeMap::<String, u64>::new();
    let mut schemas = std::collections::BTreeMap::<String, Schema>::new();
    let mut last_tick = None;
    let names: Vec<String> = log.meta("joint_names").unwrap().split(',').map(str::to_string).collect();
    assert_eq!(names.len(), 7);
    let mut checked_commands = 0;
    for m in log.messages() {
        let topic = m.channel.topic.clone();
        *counts.entry(topic.clone()).or_default() += 1;
        let schema = schemas.entry(topic.clone()).or_insert_with(|| {
            let s = m.channel.schema.as_ref().unwrap();
            assert_eq!(s.encoding, "ros2msg");
            assert_eq!(m.channel.message_encoding, "cdr");
            Schema::parse(&s.name, &String::from_utf8_lossy(&s.data)).unwrap()
        });
        let values = schema.decode(&m.data).unwrap_or_else(|e| panic!("{topic}: {e}"));
        let get = |k: &str| values.iter().find(|(p, _)| p == k).map(|(_, v)| v.clone());
        if topic == topics::TICK {
            last_tick = Some(decode::<Tick>(&m.data).unwrap());
        }
        if topic == topics::JOINT_COMMAND {
            // A known joint command: the same values the tick record holds, under the URDF's names.
            let t = last_tick.as_ref().unwrap();
            for (j, name) in names.iter().enumerate() {
                assert_eq!(get(&format!("name[{j}]")), Some(Value::S(name.clone())));
                assert_eq!(get(&format!("position[{j}]")), Some(Value::F(t.output.joint_command.position[j])));
            }
            let stamp = match (get("header.stamp.sec"), get("header.stamp.nanosec")) {
                (Some(Value::I(s)), Some(Value::U(ns))) => s as u64 * 1_000_000_000 + ns,
                other => panic!("{other:?}"),
            };
            assert_eq!(stamp, m.log_time);
            checked_commands += 1;
        }
    }
    assert!(checked_commands > 1000);
    for t in [topics::TICK, topics::STATUS, topics::EXTRUDER, topics::TCP_TARGET, topics::BASE_ESTIMATED] {
        assert_eq!(counts[t], ticks, "{t}");
    }
    assert!(counts[topics::JOINT_STATES] < ticks, "the silent driver's ticks have no joint state");
    assert!(counts[topics::SEGMENTS] >= 14);
}

#[test]
fn a_replay_of_faults_pause_resume_and_underrun_is_identical() {
    let (path, ticks) = eventful_log();
    let log = LogFile::open(&path).unwrap();
    assert_eq!(verify(&[log]).unwrap(), Verdict::Identical { ticks });
}

#[test]
fn a_changed_gain_is_reported_at_the_first_divergent_tick() {
    let (path, _) = eventful_log();
    let log = LogFile::open(&path).unwrap();
    // 10 % less (the gains are capped at 1/dt, so a raise from the default would change nothing).
    let change = |c: &mut Config| c.clik.gains[0] *= 0.9;
    let Verdict::Diverged { tick, field, logged, replayed } = verify_with(std::slice::from_ref(&log), change).unwrap() else {
        panic!("a changed gain must diverge");
    };
    // Independently: step the logged inputs through a controller with the changed gain and find
    // the first tick whose output differs from the log.
    let mut cfg = log.config().unwrap();
    change(&mut cfg);
    let mut ctl = strand_core::Controller::new(&cfg.controller_settings(), cfg.robot.build_model().unwrap()).unwrap();
    let first = log.ticks().map(Result::unwrap).find(|t| bytes(&ctl.step(&t.input)) != bytes(&t.output)).unwrap();
    assert_eq!(tick, first.input.tick);
    assert!(field.starts_with("output."), "{field}");
    assert_ne!(logged, replayed);
    // The gain acts once the CLIK follows a target: not before the approach has begun.
    assert!(first.output.status.run_state != RunState::Idle as u32, "{field} at tick {tick}");
}

/// Message identity for prefix checks.
fn message_keys(log: &LogFile) -> Vec<(String, u64, Vec<u8>)> {
    log.messages().map(|m| (m.channel.topic.clone(), m.log_time, m.data.into_owned())).collect()
}

#[test]
fn a_file_cut_anywhere_is_recovered_up_to_its_last_closed_chunk() {
    // A log with many small chunks.
    let dir = temp_dir("core", "recover");
    let cfg = config(|_| {});
    let model = cfg.robot.build_model().unwrap();
    let path = dir.join("run.mcap");
    let logger = Logger::start_at(
        &log_cfg(|c| {
            c.chunk_bytes = 4096;
            c.chunk_interval = 0.005;
        }),
        LogContext::new(&cfg, &model),
        &path,
    )
    .unwrap();
    let mut cell = Cell::new(&cfg, &IIWA_START);
    cell.send(&square_job(1, [0.45, 0.0, 0.3], 0.02, 1, 0.03));
    cell.control(Command::Start, 0.0);
    for _ in 0..3000 {
        step_logged(&mut cell, &logger);
    }
    logger.finish();
    let bytes = std::fs::read(&path).unwrap();
    let full = LogFile::open(&path).unwrap();
    let all = message_keys(&full);
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert!(summary.chunk_indexes.len() > 20, "{} chunks", summary.chunk_indexes.len());
    let mut rng = Rng(11);
    let mut cuts: Vec<usize> = (0..24).map(|_| (rng.unit() * bytes.len() as f64) as usize).collect();
    cuts.extend([0, 8, 100, bytes.len() - 1, bytes.len()]);
    let mut previous = 0;
    cuts.sort();
    for cut in cuts {
        let cut_path = dir.join("cut.mcap");
        std::fs::write(&cut_path, &bytes[..cut]).unwrap();
        let out = dir.join("cut.recovered.mcap");
        let r = match strand::log::recover::recover(&cut_path, &out) {
            Ok(r) => r,
            Err(e) => {
                assert!(cut < 8, "only a file without its magic is refused (cut {cut}): {e}");
                continue;
            }
        };
        let rec = LogFile::open(&out).unwrap();
        assert!(rec.finished, "the recovered file is finished");
        assert!(mcap::Summary::read(rec.bytes()).unwrap().is_some(), "and indexed");
        let got = message_keys(&rec);
        assert_eq!(got.len() as u64, r.messages);
        assert_eq!(&all[..got.len()], &got[..], "cut at {cut}: a prefix of the original, in order");
        // Everything logged before the end of the last chunk that closed before the cut is there.
        let closed = summary.chunk_indexes.iter().filter(|c| c.chunk_start_offset + c.chunk_length <= cut as u64);
        if let Some(last) = closed.max_by_key(|c| c.chunk_start_offset) {
            let must = all.iter().filter(|m| m.1 < last.message_end_time).count();
            assert!(got.len() >= must, "cut at {cut}: {} recovered, {must} were in closed chunks", got.len());
        }
        assert!(got.len() >= previous, "a later cut never recovers less");
        previous = got.len();
        if cut == bytes.len() {
            assert_eq!(got.len(), all.len());
        }
        // With its config attachments intact, the recovered prefix replays identically.
        if rec.attachments.len() == 2 && got.iter().any(|m| m.0 == topics::TICKS) {
            assert!(matches!(verify(&[rec]).unwrap(), Verdict::Identical { .. }), "cut at {cut}");
        }
    }
}

#[test]
fn rotated_parts_replay_together_and_a_later_part_alone_is_refused() {
    let dir = temp_dir("core", "rotate");
    let cfg = config(|_| {});
    let model = cfg.robot.build_model().unwrap();
    let path = dir.join("run.mcap");
    // Every channel at every tick, so that 4 s of ticks fill several 64 KiB parts.
    let rotating = log_cfg(|c| {
        c.rotate_bytes = 1 << 16;
        c.derived_rate_hz = 0.0;
    });
    let logger = Logger::start_at(&rotating, LogContext::new(&cfg, &model), &path).unwrap();
    let mut cell = Cell::new(&cfg, &IIWA_START);
    cell.send(&square_job(1, [0.45, 0.0, 0.3], 0.02, 1, 0.03));
    cell.control(Command::Start, 0.0);
    for _ in 0..4000 {
        step_logged(&mut cell, &logger);
    }
    let report = logger.finish();
    assert!(report.files.len() >= 3, "{:?}", report.files);
    assert_eq!(report.files[1], dir.join("run-001.mcap"));
    let parts: Vec<LogFile> = report.files.iter().map(|p| LogFile::open(p).unwrap()).collect();
    for (k, p) in parts.iter().enumerate() {
        assert!(p.finished);
        assert_eq!(p.meta("part"), Some(k.to_string().as_str()));
        assert!(p.attachment("robot.urdf").is_some(), "every part is self-contained");
    }
    let second_first_tick: u64 = parts[1].meta("first_tick").unwrap().parse().unwrap();
    assert_eq!(parts[1].records().next().unwrap().unwrap().input.tick, second_first_tick);
    // A later part alone holds its inputs, not the controller's state: its outputs need the parts
    // before it.
    let alone_err = parts[1].ticks().next().unwrap().unwrap_err().to_string();
    assert!(alone_err.contains("its outputs need the parts before it"), "{alone_err}");
    assert_eq!(strand::log::reader::ticks_of(&parts).count(), 4000);
    assert_eq!(verify(&parts).unwrap(), Verdict::Identical { ticks: 4000 });
    let alone = LogFile::open(&report.files[1]).unwrap();
    match verify(&[alone]) {
        Err(ReplayError::Gap { expected: 0, found, .. }) => assert_eq!(found, second_first_tick),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_full_queue_is_counted_and_never_waited_on() {
    let dir = temp_dir("core", "queue");
    let cfg = config(|_| {});
    let model = cfg.robot.build_model().unwrap();
    let logger = Logger::start_at(&log_cfg(|c| c.queue_ticks = 64), LogContext::new(&cfg, &model), &dir.join("q.mcap")).unwrap();
    let input = TickInput::new(0, 1);
    let output = TickOutput::default();
    let pushed = 50_000u64;
    for k in 0..pushed {
        let mut i = input;
        i.tick = k;
        logger.push(&i, &output, &TickTiming::default());
    }
    let dropped_while_pushing = logger.dropped();
    let report = logger.finish();
    assert_eq!(report.ticks_written + report.drops, pushed);
    assert_eq!(report.drops, dropped_while_pushing);
    assert!(report.drops > 0, "64 slots cannot hold 50 000 ticks pushed at once");
}

#[test]
fn a_log_that_cannot_be_created_names_the_path() {
    let dir = temp_dir("core", "bad");
    let file = dir.join("not-a-dir");
    std::fs::write(&file, b"x").unwrap();
    let cfg = config(|_| {});
    let model = cfg.robot.build_model().unwrap();
    let err = Logger::start_at(&LogConfig::default(), LogContext::new(&cfg, &model), &file.join("run.mcap")).err().unwrap();
    assert!(err.to_string().contains("not-a-dir"), "{err}");
    let err =
        Logger::start(&LogConfig { dir: file.display().to_string(), ..LogConfig::default() }, LogContext::new(&cfg, &model)).err().unwrap();
    assert!(err.to_string().contains("not-a-dir"), "{err}");
}

#[test]
fn the_effective_config_reads_back_to_the_same_values() {
    let cfg = config(|c| {
        c.clik.gains[2] = 123.456_789_012_345_67;
        c.controller.rate_hz = 4000.0;
        c.path.max_speed = 0.1 + 0.2;
    });
    let text = cfg.effective_toml();
    let back = Config::from_effective(Path::new("x.mcap"), &text, &cfg.robot.urdf_text).unwrap();
    assert_eq!(back.controller_settings(), cfg.controller_settings());
    assert_eq!(back.robot.build_model().unwrap().dof(), 7);
    assert_eq!(back, Config { file: back.file.clone(), robot: back.robot.clone(), ..cfg.clone() });
    // A board and a bed mesh travel with it.
    let with = config(|c| {
        c.extruder_board = Some(
            toml::from_str(
                "serial = \"/dev/ttyACM0\"\nstep_pin = \"gpio11\"\ndir_pin = \"gpio10\"\nmicrosteps = 16\nrotation_distance = 0.0226\n\
                 heater_pin = \"gpio23\"\nthermistor_pin = \"gpio26\"\nthermistor = { type = \"beta\", t0 = 25.0, r0 = 100000.0, beta = 3950.0 }\n\
                 pid_kp = 22.2\npid_ki = 1.08\npid_kd = 114.0\nmax_temp = 280.0\n",
            )
            .unwrap(),
        );
        c.bed.mesh = Some(toml::from_str("min = [0.0, 0.0]\nmax = [0.1, 0.1]\npoints = [[0.0, 0.0001], [-0.0001, 0.0002]]\n").unwrap());
    });
    let with_text = with.effective_toml();
    assert!(with_text.contains("[extruder.board]"), "{with_text}");
    let again = Config::from_effective(Path::new("x.mcap"), &with_text, &with.robot.urdf_text).unwrap();
    assert_eq!(again.extruder_board, with.extruder_board);
    assert_eq!(again.bed.mesh, with.bed.mesh);
    assert_eq!(again.controller_settings(), with.controller_settings());
    let broken = text.replace("rate_hz = 4000.0", "rate_hz = 40.0");
    let err = Config::from_effective(Path::new("x.mcap"), &broken, &cfg.robot.urdf_text).unwrap_err();
    assert!(err.to_string().contains("rate_hz"), "{err}");
}

#[test]
fn bad_segments_keep_their_reasons_in_the_log() {
    let cfg = config(|_| {});
    let dir = temp_dir("core", "reasons");
    let model = cfg.robot.build_model().unwrap();
    let path = dir.join("r.mcap");
    let logger = Logger::start_at(&log_cfg(|_| {}), LogContext::new(&cfg, &model), &path).unwrap();
    let mut cell = Cell::new(&cfg, &IIWA_START);
    let mut s = line(1, [0.45, 0.0, 0.3], 0.05, 0.0);
    s.end[1] = f64::INFINITY;
    cell.send(&[s]);
    for _ in 0..5 {
        step_logged(&mut cell, &logger);
    }
    logger.finish();
    let log = LogFile::open(&path).unwrap();
    let found = log
        .ticks()
        .map(Result::unwrap)
        .flat_map(|t| t.output.events().to_vec())
        .any(|e| matches!(e, strand_core::Event::SegmentRejected { seq: 1, reason: ipc::RejectReason::NonFinite, field: "end" }));
    assert!(found);
}

#[test]
fn the_compact_record_gives_back_every_bit_of_any_input() {
    use strand::log::record::{BlockEncoder, LoggedOutput, decode_block, output_digest};
    let (mut rng, mut noise) = (Rng(23), Rng(29));
    let mut enc = BlockEncoder::new();
    let mut ticks = Vec::new();
    let mut scratch = CdrWriter::new();
    for k in 0..700u64 {
        let mut f = || random_f64(&mut rng);
        let mut t = Tick::default();
        t.input.tick = 1_000 + k;
        t.input.time_ns = 5_000_000 + k * 1_000_000 + k % 3;
        // Joint states come and go (the words of a missing one repeat the last), any bit pattern.
        if k % 5 != 3 {
            let mut js = ipc::JointState { seq: k, stamp_ns: t.input.time_ns - 17, dof: 7, flags: (k % 4) as u32, ..Default::default() };
            for j in 0..ipc::MAX_JOINTS {
                js.position[j] = if k % 50 == 7 { f() } else { 0.3 * j as f64 + 1e-4 * k as f64 + 2e-6 * noise.normal() };
                js.velocity[j] = f();
                js.robot_target[j] = -0.0;
            }
            t.input.joint_state = Some(js);
        }
        if k % 10 == 0 {
            t.input.heater_state =
                Some(ipc::HeaterState { seq: k / 10, stamp_ns: k, hot_end: f(), bed: f(), flags: 3, ..Default::default() });
        }
        if k % 97 == 5 {
            t.input.push_segment(&ipc::Segment {
                seq: k,
                end: [f(), f(), f()],
                axes: [f(), f()],
                temperature: f(),
                heater: 1,
                ..Default::default()
            });
            t.input.push_control(&ipc::Control { seq: k, command: 3, value: f(), ..Default::default() });
        }
        for _ in 0..(k % 3) {
            t.input.push_base_pose(&ipc::BasePose { seq: k, stamp_ns: k, position: [f(), f(), f()], orientation: [f(), f(), f(), f()] });
        }
        t.input.feeder_lost = k % 11 == 0;
        t.input.cycle.overruns = k / 100;
        t.input.cycle.worst_lateness_ns = noise.next_u64();
        t.timing = TickTiming {
            wake_lateness_ns: k % 13,
            step_ns: 2000 + noise.next_u64() % 900,
            tick_ns: u64::MAX - k,
            receive_ns: 600,
            command_ns: 0,
        };
        t.output.joint_command.position[0] = f();
        t.output.status.tick = k;
        if !enc.takes(&t) {
            break;
        }
        enc.push(&t);
        ticks.push(t);
    }
    assert_eq!(ticks.len(), 700);
    let mut w = CdrWriter::new();
    enc.finish(&mut w).unwrap();
    assert!(enc.is_empty());
    let records = decode_block(w.bytes()).unwrap();
    assert_eq!(records.len(), ticks.len());
    for (r, t) in records.iter().zip(&ticks) {
        // The input and timing, bit for bit (a Tick's CDR with the logged output).
        let back = Tick { input: *r.input, output: t.output, timing: r.timing };
        assert_eq!(bytes(&back), bytes(t), "tick {}", t.input.tick);
        assert_eq!(r.digest, output_digest(&mut scratch, &t.output));
        match &r.output {
            LoggedOutput::Keyframe(o) => assert_eq!(r.input.tick, 1_000, "{:?}", o.status.tick),
            LoggedOutput::Digest(d) => assert_eq!(*d, r.digest),
            LoggedOutput::Whole(_) => panic!("a block holds no whole record"),
        }
    }
    // A tick that does not follow the block's last starts another block.
    let mut gap = ticks[0];
    gap.input.tick = 5;
    let mut enc = BlockEncoder::new();
    enc.push(&ticks[0]);
    assert!(!enc.takes(&gap));
    // A corrupted block is an error, never a panic.
    for cut in [5, 20, w.bytes().len() / 2, w.bytes().len() - 1] {
        assert!(decode_block(&w.bytes()[..cut]).is_err(), "cut at {cut}");
    }
}

#[test]
fn below_the_free_disk_floor_only_the_replay_record_is_written_and_it_replays() {
    let dir = temp_dir("core", "floor");
    let cfg = config(|_| {});
    let model = cfg.robot.build_model().unwrap();
    let path = dir.join("run.mcap");
    // No disk has this much free: record-only from the first chunk on.
    let logger = Logger::start_at(&log_cfg(|c| c.min_free_bytes = u64::MAX / 2), LogContext::new(&cfg, &model), &path).unwrap();
    let mut cell = Cell::new(&cfg, &IIWA_START);
    cell.send(&square_job(1, [0.45, 0.0, 0.3], 0.02, 1, 0.03));
    cell.control(Command::Start, 0.0);
    for _ in 0..2000 {
        step_logged(&mut cell, &logger);
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(logger.state(), ipc::LogState::RecordOnly as u32);
    let report = logger.finish();
    assert_eq!((report.drops, report.ticks_written), (0, 2000));
    let log = LogFile::open(&path).unwrap();
    let mut counts = std::collections::BTreeMap::<String, u64>::new();
    for m in log.messages() {
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
    }
    // Every tick and segment; of the derived channels at most what the first chunk held.
    assert_eq!(log.records().count(), 2000);
    assert!(counts.get(topics::SEGMENTS).copied().unwrap_or(0) > 0, "{counts:?}");
    let derived = counts.get(topics::JOINT_COMMAND).copied().unwrap_or(0);
    // (At 10 Hz the 2 s of ticks would have 200.)
    assert!(derived < 50, "{derived} joint commands: the derived channels stopped ({counts:?})");
    assert_eq!(verify(&[log]).unwrap(), Verdict::Identical { ticks: 2000 });
}
