//! Offline evaluation of the path engine (`strand-plan time`): runs a G-code program through the same
//! per-tick code the controller uses — [`PathEngine::step`] and [`Extruder::step`] at the configured
//! rate — and measures the result against the program: duration against the feed-rate bound, limits
//! along the path, deviation from the programmed polyline or arc, and flow error.

use std::collections::VecDeque;

use nalgebra::Vector3;
use serde::Serialize;

use crate::bed::BedTransform;
use crate::gcode::{GcodeError, GcodeSegment, segment_length};
use strand_core::Geometry;
use strand_core::arc_geometry;
use strand_core::{Extruder, ExtruderConfig};
use strand_core::{Motion, PathConfig, PathEngine, PathSample, Segment, SegmentFlags, SegmentKind};

/// What one run measured. Speeds, accelerations and jerks are along the path.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TimingReport {
    /// Planning mode used.
    pub mode: String,
    /// Time from the first tick to the end of the last segment (s).
    pub duration_s: f64,
    /// Programmed path length: lines and arcs (m).
    pub path_length_m: f64,
    /// Net filament the extruder commands were integrated to (m; retractions subtract).
    pub extrude_length_m: f64,
    /// Programmed filament, sum of ΔE over the program (m).
    pub program_filament_m: f64,
    /// Σ L / min(F, max_speed) over the moves, plus the dwell times (s): no planner can be faster.
    pub lower_bound_s: f64,
    /// Highest speed (m/s).
    pub max_speed: f64,
    /// Highest |acceleration| (m/s²).
    pub max_acc: f64,
    /// Highest |jerk| (m/s³), from the profile and from the tick-to-tick change of acceleration.
    pub max_jerk: f64,
    /// Highest centripetal (normal) acceleration of the TCP (m/s²), on arcs and corner blends.
    pub max_centripetal_acc: f64,
    /// Highest ratio of the speed to the programmed feed of the segment being run.
    pub max_feed_ratio: f64,
    /// Largest distance of a sample from the programmed line or arc it belongs to (m).
    pub max_deviation_m: f64,
    /// Largest relative error of the commanded filament rate against ΔE/L·ṡ on extruding samples.
    pub max_flow_error: f64,
    /// Segments in the program (moves and dwells, after skipping zero-length moves).
    pub segments: u64,
    /// Ticks run.
    pub ticks: u64,
    /// Parser warnings and engine notes.
    pub warnings: Vec<String>,
    /// Times the engine stopped for want of segments.
    pub underruns: u64,
    /// Times a limit could not be met and the engine braked instead.
    pub forced_brakes: u64,
    /// Heat waits passed without waiting (the heaters are not modelled here; `strand check-job`
    /// predicts them with `[thermal]`).
    pub heat_waits: u64,
}

/// Longest a single segment may take in an offline run (s): ten days.
pub const MAX_SEGMENT_SECONDS: f64 = 864_000.0;

/// A run failed: bad G-code, or a segment the engine refused.
#[derive(Debug, thiserror::Error)]
pub enum TimingError {
    /// The G-code parser stopped.
    #[error(transparent)]
    Gcode(#[from] GcodeError),
    /// The engine refused a segment.
    #[error("{file}:{line}: {message}")]
    Segment {
        /// The program.
        file: String,
        /// Its line (1-based).
        line: usize,
        /// Why the engine refused it.
        message: String,
    },
    /// The run did not finish within the tick cap.
    #[error("the run did not finish within {0} ticks")]
    Timeout(u64),
    /// The configuration is invalid.
    #[error("{0}")]
    Config(String),
}

/// One programmed primitive, kept while its samples are checked.
#[derive(Clone, Copy, Debug)]
struct Programmed {
    seq: u64,
    start: Vector3<f64>,
    segment: Segment,
    length: f64,
}

impl Programmed {
    fn distance(&self, p: &Vector3<f64>) -> f64 {
        distance_from_programmed(p, &self.start, &self.segment, self.length)
    }
}

/// Distance (m) of `p` from the line or arc `segment` programs when it starts at `start` (m) and
/// is `length` (m) long; from its point for a dwell. The deviation every planner check measures.
pub fn distance_from_programmed(p: &Vector3<f64>, start: &Vector3<f64>, segment: &Segment, length: f64) -> f64 {
    match segment.kind {
        SegmentKind::Line => strand_core::distance_to_segment(p, start, &segment.end),
        SegmentKind::Arc => match arc_geometry(start, segment) {
            Some(g @ Geometry::Arc { .. }) => strand_core::distance_to_arc(p, &g, length),
            _ => (p - start).norm(),
        },
        SegmentKind::Dwell | SegmentKind::Heat => (p - start).norm(),
    }
}

/// Runs `program` through a path engine and an extruder ticking at `rate_hz` and measures it.
/// `file` names the source in errors; `warnings` are the parser's, passed through to the report.
pub fn time_program(
    program: impl Iterator<Item = Result<GcodeSegment, GcodeError>>,
    file: &str,
    path: &PathConfig,
    extruder: &ExtruderConfig,
    bed: &BedTransform,
    rate_hz: f64,
    mut on_sample: impl FnMut(&PathSample),
) -> Result<TimingReport, TimingError> {
    let dt = 1.0 / rate_hz;
    let start = bed.point(&Vector3::zeros());
    let mut engine = PathEngine::new(path, dt, start, bed.tool_orientation()).map_err(|e| TimingError::Config(e.to_string()))?;
    let mut extruder = Extruder::new(extruder, dt).map_err(|e| TimingError::Config(e.to_string()))?;
    let mut report = TimingReport { mode: path.mode.name().to_string(), ..TimingReport::default() };
    let mut program = program.peekable();
    let mut window: VecDeque<Programmed> = VecDeque::new();
    let mut last_end = start;
    let mut pending: Option<(Segment, usize)> = None;
    let mut previous_acc = 0.0;
    let mut tick: u64 = 0;
    let mut finished_feeding = false;
    let mut tick_cap = u64::MAX;
    loop {
        // Feed the engine what it has room for, as the feeder does under back-pressure.
        while !finished_feeding && engine.free_space() > 0 {
            let next = match pending.take() {
                Some(p) => Some(Ok(p)),
                None => program.next().map(|r| r.map(|g| (bed.segment(&g.segment), g.line))),
            };
            let Some(next) = next else {
                finished_feeding = true;
                // A program without a segment (or whose last one was already fed): bound the run.
                tick_cap = tick_cap.min(tick.saturating_add(1000));
                break;
            };
            let (mut segment, line) = next?;
            if program.peek().is_none() {
                segment.flags = segment.flags.with(SegmentFlags::LAST);
            }
            let length = segment_length(&last_end, &segment);
            if !matches!(segment.kind, SegmentKind::Dwell | SegmentKind::Heat)
                && length < 1e-9
                && !segment.flags.contains(SegmentFlags::LAST)
            {
                // The engine would skip it too; keep the numbers comparable.
                engine.push(&segment).map_err(|e| TimingError::Segment { file: file.to_string(), line, message: e.to_string() })?;
                continue;
            }
            engine.push(&segment).map_err(|e| TimingError::Segment { file: file.to_string(), line, message: e.to_string() })?;
            report.segments += 1;
            report.path_length_m += length;
            report.program_filament_m += segment.filament;
            let seconds = match segment.kind {
                SegmentKind::Dwell => segment.duration,
                SegmentKind::Heat => 0.0,
                _ => length / segment.feed.min(path.max_speed),
            };
            // Ticking through a month of one move is not a timing, it is a typo (F in the wrong
            // unit, a coordinate in the wrong place): say where instead of running for ever.
            if seconds > MAX_SEGMENT_SECONDS {
                return Err(TimingError::Segment {
                    file: file.to_string(),
                    line,
                    message: format!(
                        "segment {} would take {seconds:.3e} s (more than {MAX_SEGMENT_SECONDS} s): check its feed and end point",
                        segment.seq
                    ),
                });
            }
            report.lower_bound_s += seconds;
            window.push_back(Programmed { seq: segment.seq, start: last_end, segment, length });
            last_end = segment.end;
            if program.peek().is_none() {
                finished_feeding = true;
                // Saturating: a move that would take 1e15 s must time out, not overflow.
                let lower_bound_ticks = (20.0 * report.lower_bound_s / dt).min(1e18) as u64;
                tick_cap = tick.saturating_add(1000).saturating_add(lower_bound_ticks).saturating_add(report.segments.saturating_mul(100));
            }
        }
        if engine.waiting_at().is_some() {
            // A heat wait: the heaters are not modelled here (`strand check-job` predicts them).
            engine.release_wait();
            report.heat_waits += 1;
        }
        let sample = engine.step(1.0);
        let command = extruder.step(&sample);
        tick += 1;
        on_sample(&sample);
        report.max_speed = report.max_speed.max(sample.speed);
        report.max_acc = report.max_acc.max(sample.path_acceleration.abs());
        report.max_jerk = report.max_jerk.max(sample.path_jerk.abs()).max((sample.path_acceleration - previous_acc).abs() / dt);
        previous_acc = sample.path_acceleration;
        if sample.speed > 1e-9 {
            let t = sample.velocity / sample.speed;
            let normal = sample.acceleration - t * sample.acceleration.dot(&t);
            report.max_centripetal_acc = report.max_centripetal_acc.max(normal.norm());
        }
        while window.len() > 1 && window[0].seq < sample.seq && window[1].seq <= sample.seq {
            window.pop_front();
        }
        if let Some(programmed) = window.iter().find(|p| p.seq == sample.seq) {
            report.max_deviation_m = report.max_deviation_m.max(programmed.distance(&sample.position));
            let s = &programmed.segment;
            if !matches!(s.kind, SegmentKind::Dwell | SegmentKind::Heat) {
                report.max_feed_ratio = report.max_feed_ratio.max(sample.speed / s.feed.min(path.max_speed));
            }
            if s.flags.contains(SegmentFlags::EXTRUDE) && sample.motion == Motion::Moving && sample.speed > 1e-6 && programmed.length > 0.0
            {
                let expected = s.filament / programmed.length * sample.speed;
                // The motion's share: a dwell ending inside this tick adds its own.
                let error = ((command.path_rate - sample.dwell_filament_rate - expected) / expected).abs();
                report.max_flow_error = report.max_flow_error.max(error);
            }
        }
        if sample.motion == Motion::Finished && finished_feeding {
            break;
        }
        if tick > tick_cap {
            return Err(TimingError::Timeout(tick));
        }
    }
    report.ticks = tick;
    report.duration_s = tick as f64 * dt;
    report.extrude_length_m = extruder.position();
    let stats = engine.stats();
    report.underruns = stats.underruns;
    report.forced_brakes = stats.forced_brakes;
    if stats.skipped_zero_length > 0 {
        report.warnings.push(format!("{} zero-length moves skipped", stats.skipped_zero_length));
    }
    Ok(report)
}
