//! What the fuzz targets check, shared with `tests/fuzz_regressions.rs` (which includes this file
//! with `#[path]`), so a regression input is checked the same way in `cargo test` as under
//! libFuzzer. Each check panics with a message on a violation; that panic is the fuzzer's crash.
//!
//! - [`check_parser`]: any bytes through [`Parser`]: no panic; an error names the file, a line of the
//!   input (≥ 1), a column within that line (0 = the whole line) and a non-empty message, and ends the
//!   stream; every segment has finite fields, passes `Segment::check`, has increasing sequence
//!   numbers and a source line of the input, and only the last segment of a program read without
//!   error carries `LAST`.
//! - [`check_path`]: the segments (at most [`MAX_SEGMENTS`], long dwells clamped) through a
//!   [`PathEngine`] (default limits, 1 kHz; with external axes when the input maps rotary words) with
//!   the last flagged `LAST`: every segment accepted, the engine reaches [`Motion::Finished`] within
//!   a tick bound computed from the program, and every sample is finite and within the speed,
//!   acceleration and jerk limits.
//!
//! The options: an input whose first byte is [`ROTARY_MARK`] or above runs the rest of its bytes
//! with 5-axis options (rotary words `A`/`B`/`C` mapped onto external axes, some with the
//! tool-direction dialect; the byte's two low bits pick one of four, see [`split_options`]); any
//! other input (every text program) runs whole with the default options.

#![allow(dead_code)]

use std::io::Cursor;

use nalgebra::Vector3;
use strand_core::{AxisLimits, Motion, PathConfig, PathEngine, PathSample, Segment, SegmentFlags, SegmentKind};
use strand_job::gcode::{GcodeError, GcodeOptions, GcodeSegment, Parser, ROTARY_AXES, segment_length};

/// File name given to the parser.
pub const FILE: &str = "fuzz.gcode";
/// Most segments run through the path engine (the rest of a longer program is cut off).
pub const MAX_SEGMENTS: usize = 200;
/// Longest dwell run through the path engine (s); longer ones are shortened to this.
pub const MAX_DWELL_S: f64 = 2.0;
/// Most ticks a program may be given; programs whose bound is larger are not run.
pub const MAX_TICKS: u64 = 200_000;
/// Control period (s).
pub const DT: f64 = 1e-3;
/// A first byte from here up selects 5-axis options (and is not part of the program).
pub const ROTARY_MARK: u8 = 0x80;
/// The external axes' limits in [`check_path`] (rad/s, rad/s², rad/s³): a quick turntable.
pub const AXIS_LIMITS: AxisLimits = AxisLimits { velocity: 3.0, acceleration: 30.0, jerk: 600.0 };

/// The options `data` runs with and the program it holds (see the module documentation): after a
/// first byte ≥ [`ROTARY_MARK`], its two low bits pick C alone (0); A (sign −1, offset 0.1 rad) and
/// C (1); B and C with the tool-direction dialect (2); C (sign −1, offset 0.5 rad) with the
/// tool-direction dialect (3).
pub fn split_options(data: &[u8]) -> (GcodeOptions, &[u8]) {
    let Some((&first, program)) = data.split_first().filter(|(first, _)| **first >= ROTARY_MARK) else {
        return (GcodeOptions::default(), data);
    };
    let (words, signs, offsets, tool_direction): (&[&str], &[f64], &[f64], bool) = match first & 3 {
        0 => (&["C"], &[], &[], false),
        1 => (&["A", "C"], &[-1.0, 1.0], &[0.1, -0.2], false),
        2 => (&["B", "C"], &[], &[], true),
        _ => (&["C"], &[-1.0], &[0.5], true),
    };
    let options = GcodeOptions::default().with_rotary(words, signs, offsets).expect("valid rotary options");
    (GcodeOptions { tool_direction, ..options }, program)
}

/// What the parser made of an input.
pub struct Parsed {
    pub segments: Vec<GcodeSegment>,
    pub error: Option<GcodeError>,
}

/// Runs `data` through the parser (with the options it selects, [`split_options`]) and checks
/// everything it returns.
pub fn check_parser(data: &[u8]) -> Parsed {
    let (options, data) = split_options(data);
    let first_seq = options.first_seq;
    let mut parser = Parser::new(Cursor::new(data), FILE, options);
    let lines = line_count(data);
    let mut segments: Vec<GcodeSegment> = Vec::new();
    let mut error = None;
    for item in parser.by_ref() {
        match item {
            Ok(g) => {
                assert!(error.is_none(), "a segment after the error");
                check_segment(&g, lines);
                let expected_seq = segments.last().map_or(first_seq, |p| p.segment.seq + 1);
                assert_eq!(g.segment.seq, expected_seq, "line {}: sequence numbers must count up by one", g.line);
                if let Some(previous) = segments.last() {
                    assert!(
                        !previous.segment.flags.contains(SegmentFlags::LAST),
                        "line {}: LAST on a segment that is not the last",
                        previous.line
                    );
                    assert!(g.line >= previous.line, "line {}: source lines go back (from {})", g.line, previous.line);
                }
                segments.push(g);
            }
            Err(e) => {
                assert!(error.is_none(), "two errors");
                check_error(&e, data, lines);
                error = Some(e);
            }
        }
    }
    assert!(parser.next().is_none(), "the parser yields more after its end");
    if let Some(last) = segments.last() {
        let flagged = last.segment.flags.contains(SegmentFlags::LAST);
        if error.is_some() {
            assert!(!flagged, "line {}: LAST on the segment before an error", last.line);
        } else {
            assert!(flagged, "line {}: the last segment of a program read without error lacks LAST", last.line);
        }
    }
    Parsed { segments, error }
}

/// Lines in `data` as the parser counts them ("a\nb" and "a\nb\n" both have 2).
fn line_count(data: &[u8]) -> usize {
    let newlines = data.iter().filter(|b| **b == b'\n').count();
    newlines + usize::from(!data.is_empty() && data.last() != Some(&b'\n'))
}

/// The characters of 1-based line `line` of `data`, as the parser sees them (lossy UTF-8, line end
/// stripped).
fn line_chars(data: &[u8], line: usize) -> usize {
    let Some(bytes) = data.split(|b| *b == b'\n').nth(line - 1) else { return 0 };
    let bytes = bytes.strip_suffix(b"\r").unwrap_or(bytes);
    String::from_utf8_lossy(bytes).chars().count()
}

fn check_error(e: &GcodeError, data: &[u8], lines: usize) {
    assert_eq!(e.file, FILE, "error names another file: {e}");
    assert!(e.line >= 1 && e.line <= lines, "error line {} outside 1..={lines}: {e}", e.line);
    assert!(!e.message.trim().is_empty(), "error without a message: {e:?}");
    let chars = line_chars(data, e.line);
    assert!(e.column <= chars + 1, "error column {} past the line's {chars} characters: {e}", e.column);
    let shown = e.to_string();
    assert!(shown.starts_with(&format!("{FILE}:{}:{}: ", e.line, e.column)), "error display lacks file:line:column: {shown}");
}

fn finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn check_segment(g: &GcodeSegment, lines: usize) {
    let s = &g.segment;
    let at = g.line;
    assert!(at >= 1 && at <= lines, "segment line {at} outside 1..={lines}");
    assert!(finite(&s.end), "line {at}: end not finite: {s:?}");
    assert!(finite(&s.centre), "line {at}: centre not finite: {s:?}");
    assert!(finite(&s.normal), "line {at}: normal not finite: {s:?}");
    assert!(s.feed.is_finite(), "line {at}: feed not finite: {s:?}");
    assert!(s.filament.is_finite(), "line {at}: filament not finite: {s:?}");
    assert!(s.duration.is_finite(), "line {at}: duration not finite: {s:?}");
    assert!(s.sweep.is_finite(), "line {at}: sweep not finite: {s:?}");
    let q = s.orientation.quaternion();
    assert!(q.coords.iter().all(|x| x.is_finite()) && (q.norm() - 1.0).abs() < 1e-9, "line {at}: orientation not a unit quaternion");
    match s.kind {
        SegmentKind::Dwell => assert!(s.duration >= 0.0, "line {at}: negative dwell {s:?}"),
        SegmentKind::Heat => assert!(s.check().is_ok(), "line {at}: heat segment refused by its check: {s:?}"),
        SegmentKind::Line => assert!(s.feed > 0.0, "line {at}: feed {} on a move", s.feed),
        SegmentKind::Arc => {
            assert!(s.feed > 0.0, "line {at}: feed {} on an arc", s.feed);
            assert!(s.sweep > 0.0, "line {at}: arc sweep {} not positive", s.sweep);
            assert!((s.normal.norm() - 1.0).abs() < 1e-9, "line {at}: arc normal not unit: {:?}", s.normal);
        }
    }
    let extrude = s.flags.contains(SegmentFlags::EXTRUDE);
    let travel = s.flags.contains(SegmentFlags::TRAVEL);
    assert!(!(extrude && travel), "line {at}: both EXTRUDE and TRAVEL");
    if let Err(e) = s.check() {
        panic!("line {at}: the segment fails its own check: {e}: {s:?}");
    }
}

/// Runs `data` through the parser, then its segments through the path engine, checking both.
/// Every segment is pushed (and must be accepted) before the first tick; the program is then run
/// unless its tick bound is above [`MAX_TICKS`]. Returns the ticks run, or None when the program was
/// not run (no segment, or too long).
pub fn check_path(data: &[u8]) -> Option<u64> {
    let parsed = check_parser(data);
    let mut segments: Vec<Segment> = parsed.segments.iter().take(MAX_SEGMENTS).map(|g| g.segment).collect();
    let last = segments.last_mut()?;
    last.flags = last.flags.with(SegmentFlags::LAST);
    for s in &mut segments {
        if s.kind == SegmentKind::Dwell && s.duration > MAX_DWELL_S {
            s.duration = MAX_DWELL_S;
        }
    }
    let config = PathConfig::default();
    let (options, _) = split_options(data);
    let mut engine = PathEngine::new(&config, DT, options.start, options.orientation).expect("default path config");
    let axis_count = options.rotary.iter().rposition(Option::is_some).map_or(0, |k| k + 1);
    engine.set_external_axes(&[AXIS_LIMITS; ROTARY_AXES][..axis_count]);
    assert!(engine.free_space() >= segments.len(), "the intake queue holds fewer than {MAX_SEGMENTS} segments");
    for (k, s) in segments.iter().enumerate() {
        if let Err(e) = engine.push(s) {
            panic!("the engine refuses parser output (segment {k}, line {}): {e}: {s:?}", s.source_line);
        }
    }
    let bound = tick_bound(&segments, &options.start, &config)?;
    let mut previous: Option<PathSample> = None;
    for tick in 0..bound {
        // Heat waits: no heaters here, released as soon as the path stands at one.
        engine.release_wait();
        let sample = engine.step(1.0);
        check_sample(&sample, previous.as_ref(), &config, tick);
        previous = Some(sample);
        match sample.motion {
            Motion::Finished => return Some(tick + 1),
            Motion::Starved => panic!("tick {tick}: starved with the whole program queued (LAST not reached); engine {:?}", engine.stats()),
            _ => {}
        }
    }
    let s = previous.expect("at least one tick");
    panic!(
        "not finished after {bound} ticks ({} segments): motion {:?}, seq {}, s {} m, speed {} m/s, pending {}",
        segments.len(),
        s.motion,
        s.seq,
        s.s,
        s.speed,
        engine.pending()
    );
}

/// An upper bound on the ticks the program needs: each segment as if run from rest to rest at
/// min(feed, max speed, √(a_c·r) on an arc) with the acceleration and jerk ramps, dwells as given,
/// plus, for a segment that turns external axes, the time the largest turn takes at
/// [`AXIS_LIMITS`] (at the speed share the engine plans lines at, and as the smooth step a dwell
/// turns them by), all four times over, plus 10 s. None if it is above [`MAX_TICKS`].
pub fn tick_bound(segments: &[Segment], start: &Vector3<f64>, config: &PathConfig) -> Option<u64> {
    let (a, j) = (config.max_acceleration, config.max_jerk);
    let mut at = *start;
    let mut axes = [0.0; ROTARY_AXES];
    let mut total = 0.0;
    for s in segments {
        if let Some(next) = s.axes {
            let turn = next.iter().zip(&axes).map(|(n, a)| (n - a).abs()).fold(0.0, f64::max);
            let limits = AXIS_LIMITS;
            // 10τ³ − 15τ⁴ + 6τ⁵: peak speed 1.875, acceleration 5.78, jerk 60 times turn/T^k.
            total += turn / (0.9 * limits.velocity)
                + 1.875 * turn / limits.velocity
                + (5.78 * turn / limits.acceleration).sqrt()
                + (60.0 * turn / limits.jerk).cbrt();
            axes = next;
        }
        total += match s.kind {
            SegmentKind::Dwell => s.duration,
            // A heat wait is released at once here (no heaters): a stop, as a dwell of no time.
            SegmentKind::Heat => 0.0,
            SegmentKind::Line | SegmentKind::Arc => {
                let length = segment_length(&at, s);
                let mut v = s.feed.min(config.max_speed);
                if s.kind == SegmentKind::Arc {
                    let radius = (at - s.centre).norm().min((s.end - s.centre).norm());
                    v = v.min((config.centripetal_acceleration * radius).sqrt());
                }
                length / v + 2.0 * (v / a + a / j) + 4.0 * (length / j).cbrt()
            }
        };
        at = s.end;
    }
    let ticks = (4.0 * total + 10.0) / DT;
    (ticks.is_finite() && ticks <= MAX_TICKS as f64).then_some(ticks as u64)
}

fn check_sample(s: &PathSample, previous: Option<&PathSample>, config: &PathConfig, tick: u64) {
    let finite_all = finite(&s.position)
        && finite(&s.velocity)
        && finite(&s.acceleration)
        && finite(&s.angular_velocity)
        && s.orientation.quaternion().coords.iter().all(|x| x.is_finite())
        && [s.s, s.speed, s.path_acceleration, s.path_jerk, s.flow, s.dwell_filament_rate].iter().all(|x| x.is_finite());
    assert!(finite_all, "tick {tick}: sample not finite: {s:?}");
    assert!(s.speed >= -1e-12, "tick {tick}: negative speed {}", s.speed);
    assert!(s.speed <= config.max_speed * (1.0 + 1e-9), "tick {tick}: speed {} above {}", s.speed, config.max_speed);
    let acc = config.max_acceleration * (1.0 + 1e-6);
    assert!(s.path_acceleration.abs() <= acc, "tick {tick}: acceleration {} above {}", s.path_acceleration, config.max_acceleration);
    let jerk = config.max_jerk * (1.0 + 1e-6);
    assert!(s.path_jerk.abs() <= jerk, "tick {tick}: jerk {} above {}", s.path_jerk, config.max_jerk);
    if let Some(p) = previous {
        assert!(s.s >= p.s - 1e-12, "tick {tick}: backed up along the path from {} to {}", p.s, s.s);
    }
}
